"""A per-thread timeline of ``rigcal check RIG --sequence SEQ``: which stage runs on which
thread, when, and when each thread waits.

The command runs in this process (``rigcal.cli.main.main``, the console script's entry,
imports included: run this script in a fresh interpreter) while a sampler thread reads
every thread's stack and CPU clock every ``--every-ms``. Each sample's CPU time since
the previous one is charged to the thread's innermost ``rigcal`` function (or to the
import under way, or to "wait" when the thread's innermost frame is a lock, a join or a
future's result). Printed as JSON: each thread's CPU seconds, its span, its CPU by stage
(the largest first), and its stage in each ``--bin-s`` slice of the wall clock (a stage
per slice: the one with most CPU, or "wait"/"idle"). The sampler's own CPU is reported
and not charged to any thread. On a machine shared with other jobs the wall clock and the
slices stretch with the load; the CPU by stage does not. ``slices`` shows the threads
side by side, slice by slice; ``projected_idle_wall_s`` the wall time on two idle cores
that the slices' CPU times project (:func:`projected_idle_wall`).

    .venv/bin/python benchmarks/bench_targetless_timeline.py /work/tmp/c60
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import shutil
import sys
import tempfile
import threading
import time
from collections import defaultdict
from pathlib import Path
from types import FrameType

_WAITS = ("wait", "join", "acquire", "result", "_wait_for_tstate_lock", "get", "sleep")


def _label(frame: FrameType | None) -> str:
    """The innermost rigcal function of a stack, with what it is doing below it."""
    inner = frame
    importing = None
    f = frame
    while f is not None:
        name = f.f_code.co_filename
        if "importlib._bootstrap" in name and importing is None:
            importing = f.f_locals.get("name") if f.f_code.co_name == "_find_and_load" else importing
        if "/rigcal/" in name and "bench_targetless_timeline" not in name:
            mod = name.split("/rigcal/", 1)[1].removesuffix(".py")
            where = f"{mod}:{f.f_code.co_name}"
            if importing is not None:
                return f"import {str(importing).split('.')[0]} (from {where})"
            waiting = inner is not None and inner.f_code.co_name in _WAITS
            if waiting and inner.f_code.co_filename.endswith(("threading.py", "_base.py", "queue.py")):
                return f"wait (in {where})"
            return where
        f = f.f_back
    if importing is not None:
        return f"import {str(importing).split('.')[0]}"
    if inner is not None and inner.f_code.co_name in _WAITS:
        return "wait"
    return "other"


class Sampler:
    """Every thread's CPU clock and innermost rigcal function, every ``every_s``."""

    def __init__(self, every_s: float) -> None:
        self.every_s = every_s
        self.rows: list[tuple[float, str, float, str]] = []
        self.own_cpu_s = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="sampler", daemon=True)
        self.t0 = time.perf_counter()
        self._thread.start()

    def _run(self) -> None:
        me = threading.get_ident()
        while not self._stop.is_set():
            t = time.perf_counter() - self.t0
            frames = sys._current_frames()
            for th in threading.enumerate():
                if th.ident is None or th.ident == me or th.ident not in frames:
                    continue
                try:
                    cpu = time.clock_gettime(time.pthread_getcpuclockid(th.ident))
                except (OSError, ProcessLookupError):
                    continue
                # Idents are reused by later threads; the kernel's thread id with the name
                # tells them apart.
                self.rows.append((t, f"{th.name}#{th.native_id}", cpu, _label(frames[th.ident])))
            self.own_cpu_s = time.thread_time()
            time.sleep(self.every_s)

    def stop(self) -> float:
        self._stop.set()
        self._thread.join()
        return self.own_cpu_s


def summary(rows: list[tuple[float, str, float, str]], bin_s: float) -> dict[str, object]:
    by_thread: dict[str, list[tuple[float, float, str]]] = defaultdict(list)
    for t, name, cpu, label in rows:
        by_thread[name].append((t, cpu, label))
    out: dict[str, object] = {}
    for name, seq in by_thread.items():
        stage: dict[str, float] = defaultdict(float)
        bins: dict[int, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        for (t0, c0, _), (t1, c1, label) in itertools.pairwise(seq):
            d = max(c1 - c0, 0.0)
            key = "wait" if label.startswith("wait") and d < 0.3 * (t1 - t0) else label
            stage[key] += d
            bins[int(t1 // bin_s)][key] += max(d, 1e-6)
        total = seq[-1][1] - seq[0][1] if len(seq) > 1 else 0.0
        line = []
        for b in range(int(seq[0][0] // bin_s), int(seq[-1][0] // bin_s) + 1):
            if b not in bins:
                line.append(f"{b * bin_s:.2f} idle")
                continue
            top = max(bins[b].items(), key=lambda kv: kv[1])
            line.append(f"{b * bin_s:.2f} {sum(bins[b].values()):.2f} {top[0]}")
        out[name] = {
            "cpu_s": round(total, 3),
            "span_s": [round(seq[0][0], 2), round(seq[-1][0], 2)],
            "by_stage_cpu_s": {
                k: round(v, 3) for k, v in sorted(stage.items(), key=lambda kv: -kv[1]) if v > 0.01
            },
            "timeline": line,
        }
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sequence", type=Path)
    ap.add_argument("--every-ms", type=float, default=5.0)
    ap.add_argument("--bin-s", type=float, default=0.25)
    args = ap.parse_args()
    rig = Path(tempfile.mkdtemp()) / "rig.yaml"
    shutil.copy(args.sequence / "rig.yaml", rig)
    load0 = os.getloadavg()[0]
    sampler = Sampler(args.every_ms / 1000)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    from rigcal.cli.main import main as rigcal_main

    stdout = sys.stdout
    sys.stdout = open(os.devnull, "w")  # noqa: SIM115  (the record, not needed here)
    try:
        rc = rigcal_main(["-q", "check", str(rig), "--sequence", str(args.sequence), "--no-log", "--json"])
    finally:
        sys.stdout.close()
        sys.stdout = stdout
    wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
    sampler_cpu = sampler.stop()
    doc = {
        "exit_code": rc,
        "load": [round(load0, 1), round(os.getloadavg()[0], 1)],
        "wall_s": round(wall, 2),
        "process_cpu_s": round(cpu, 2),
        "process_cpu_s_without_sampler": round(cpu - sampler_cpu, 2),
        "sampler_cpu_s": round(sampler_cpu, 2),
        "threads": summary(sampler.rows, args.bin_s),
    }
    doc["slices"] = slices(doc["threads"])  # type: ignore[arg-type]
    doc["projected_idle_wall_s"] = round(projected_idle_wall(sampler.rows, args.bin_s / 5), 2)
    print(json.dumps(doc, indent=1))


def projected_idle_wall(rows: list[tuple[float, str, float, str]], slice_s: float, cores: int = 2) -> float:
    """The wall time on ``cores`` idle cores, projected slice by slice: in each, the larger of
    the busiest thread's CPU and all threads' CPU over the cores (the load taken to slow
    every thread alike; the interpreter's lock is not modelled, so work that holds it on
    two threads at once projects short: a lower bound)."""
    per: dict[int, dict[str, float]] = defaultdict(lambda: defaultdict(float))
    last: dict[str, tuple[float, float]] = {}
    for t, name, cpu, _ in rows:
        if name in last:
            per[int(t // slice_s)][name] += max(cpu - last[name][1], 0.0)
        last[name] = (t, cpu)
    return sum(max(max(c.values()), sum(c.values()) / cores) for c in per.values() if c)


def slices(threads: dict[str, dict[str, object]], min_cpu_s: float = 0.05) -> list[str]:
    """The threads side by side: per slice of the wall clock, each busy thread's CPU in it
    and its stage (threads of under ``min_cpu_s`` in all left out)."""
    out: dict[float, list[str]] = defaultdict(list)
    for name, t in threads.items():
        if float(t["cpu_s"]) < min_cpu_s:  # type: ignore[arg-type]
            continue
        for row in t["timeline"]:  # type: ignore[attr-defined]
            start, rest = row.split(" ", 1)
            if rest != "idle":
                out[float(start)].append(f"{name.split('#')[0]}: {rest}")
    return [f"{k:.2f} " + " | ".join(v) for k, v in sorted(out.items())]


if __name__ == "__main__":
    main()
