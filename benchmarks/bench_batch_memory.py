"""What a long manifest costs the driver of ``rigcal batch``, and what it holds in the
pool or the cluster: how many items are in flight at most, and the driver's memory per
item.

One real item (an ``evaluate`` of a short trajectory, run by ``run_item`` in this
process) gives a worker's answer as it is; then ``run_batch`` runs ``--items`` items
whose workers (threads) return that answer with the longest stderr a record keeps
(4000 characters), through the driver's real code: the window of submitted items, the
records, the ``item.json`` files. Python's allocator tracing (tracemalloc) gives the
driver's peak memory, with and without the batch.

    .venv/bin/python benchmarks/bench_batch_memory.py [--items 4000] [--window 8]
"""

from __future__ import annotations

import argparse
import concurrent.futures as cf
import contextlib
import tempfile
import threading
import time
import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np

import rigcal.batch.runner as runner
from rigcal.batch.manifest import Item
from rigcal.batch.runner import BatchSettings, run_batch, run_item


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--items", type=int, default=4000)
    ap.add_argument("--window", type=int, default=8, help="items in flight (twice the CPUs or -j)")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-batch-memory-") as tmp:
        base = Path(tmp)
        t = base / "a.tum"
        xs = np.linspace(0, 1, 50)
        t.write_text("\n".join(f"{0.1 * i:.1f} {x:.3f} 0 0 0 0 0 1" for i, x in enumerate(xs)) + "\n")
        answer = run_item(Item("warm", "evaluate", {"trajectory": t, "gt": t}), base / "warm", "bench")
        assert answer["exit_code"] == 0, answer["stderr"]
        items = [Item(f"i{k:06d}", "evaluate", {"trajectory": t, "gt": t}) for k in range(args.items)]
        live, peak, lock = [0], [0], threading.Lock()
        pool = cf.ThreadPoolExecutor(args.window)

        def work(task: Any) -> dict:
            with lock:
                live[0] += 1
                peak[0] = max(peak[0], live[0])
            time.sleep(0.002)  # a worker busy for a moment, so that the window fills
            with lock:
                live[0] -= 1
            # each item's own stderr, as long as a record keeps (4000 characters)
            return answer | {"stderr": (task.command + "x" * 4000)[-4000:]}

        @contextlib.contextmanager
        def executor(settings, address, n_items, log):  # type: ignore[no-untyped-def]
            yield (lambda task: pool.submit(work, task)), args.window

        runner._executor = executor  # type: ignore[assignment]
        tracemalloc.start()
        before, _ = tracemalloc.get_traced_memory()
        t0 = time.perf_counter()
        outcomes = run_batch(items, base / "out", BatchSettings())
        seconds = time.perf_counter() - t0
        held, peak_bytes = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        pool.shutdown()
        assert all(o.record["status"] == "ok" for o in outcomes)
        per_item = (held - before) / args.items
        print(f"items                         {args.items}")
        print(f"window (items in flight)      {args.window}; peak in flight {peak[0]}")
        kb = per_item / 1e3
        print(f"driver memory after the batch {(held - before) / 1e6:.1f} MB ({kb:.2f} kB per item)")
        print(f"driver peak memory            {(peak_bytes - before) / 1e6:.1f} MB")
        ms = 1e3 * seconds / args.items
        print(f"driver time per item          {ms:.2f} ms (records, item.json files)")
        print(f"1,000,000 items would hold    {per_item * 1e6 / 1e9:.1f} GB in the driver")


if __name__ == "__main__":
    main()
