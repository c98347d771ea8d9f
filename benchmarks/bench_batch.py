"""Throughput of ``rigcal batch``: the same items on 1, 2 and N local workers and on Ray.

Simulated box-target sessions (``--items`` of them, 20 captures each, placeholder images)
are solved as a batch (``rigcal solve`` per item: RANSAC, refinement, the report folder
with its overlay PNGs) into a fresh folder each time: one after the other in this process
(the reference: no worker processes at all), on the local process pool with 1, 2 and N
workers, and as Ray tasks on a local Ray instance with 2 CPUs. Each figure is items per
second over the whole run (pool or Ray start-up included) and its ratio to the in-process
run, in the same run of this script; a resumed run (every item finished) is timed too.

    .venv/bin/python benchmarks/bench_batch.py [--items 12] [--workers 1,2,4]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import yaml

from rigcal.batch.manifest import read_manifest
from rigcal.batch.runner import BatchSettings, run_batch, run_item
from rigcal.sim.box_session import SessionSpec, generate_session, write_session


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--items", type=int, default=12)
    ap.add_argument("--workers", default="1,2,4")
    ap.add_argument("--no-ray", action="store_true")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        items = []
        for k in range(args.items):
            write_session(
                generate_session(SessionSpec(n_captures=20, seed=100 + k)), root / f"s{k:02d}", False
            )
            items.append({"name": f"s{k:02d}", "picks": f"s{k:02d}/picks.yaml"})
        manifest = root / "batch.yaml"
        manifest.write_text(yaml.safe_dump({"schema_version": 1, "command": "solve", "items": items}))
        batch = read_manifest(manifest)

        t0 = time.perf_counter()
        for item in batch:
            ran = run_item(item.argv((root / "inline" / item.name).resolve()))
            assert ran["exit_code"] == 0, ran["error"]
        t_inline = time.perf_counter() - t0
        rows = [("in this process, one after the other", t_inline)]
        for w in (int(x) for x in args.workers.split(",")):
            rows.append(
                (
                    f"local pool, {w} worker{'s' if w > 1 else ''}",
                    timed(batch, root / f"pool{w}", BatchSettings(w)),
                )
            )
        if not args.no_ray:
            rows.append(
                ("Ray, local instance with 2 CPUs", timed(batch, root / "ray", BatchSettings(2, "local")))
            )
        rows.append(
            ("local pool, 2 workers, resumed (all finished)", timed(batch, root / "pool2", BatchSettings(2)))
        )
    print(f"## rigcal batch: {args.items} solves of 20-capture sessions\n")
    print("| run | seconds | items/s | x in-process |\n|---|---|---|---|")
    for label, t in rows:
        print(f"| {label} | {t:.1f} | {args.items / t:.2f} | {t_inline / t:.2f} |")


def timed(batch: list, out: Path, settings: BatchSettings) -> float:
    t0 = time.perf_counter()
    outcomes = run_batch(batch, out, settings)
    assert all(o.record["status"] == "ok" for o in outcomes), [o.record["error"] for o in outcomes]
    return time.perf_counter() - t0


if __name__ == "__main__":
    main()
