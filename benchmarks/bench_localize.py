"""The paper's Table 1 on the simulated loops: ICP, VO, KF, IASM and H-IASM on one sequence.

For each built-in loop (``corridor-loop``, 60 m; ``cubicle-loop``, 35 m) one lap is
simulated (``rigcal simulate world``: 40 Hz laser with 1 cm noise and 1 % dropouts, 10 Hz
camera with 2 grey levels of noise, seed 1) and localized by every method in the same
process (``rigcal localize --method icp,vo,kf,iasm,hiasm``), scored against the ground
truth. Speed is each method's time as a ratio to the lap's duration (real time = 1; the
shared stages -- reading, the laser odometry that pairs scans with images -- are timed
once and listed apart).

    .venv/bin/python benchmarks/bench_localize.py [--worlds corridor-loop,cubicle-loop] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from rigcal.localize.pipeline import run, table
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN

METHODS = ["icp", "vo", "kf", "iasm", "hiasm"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="corridor-loop,cubicle-loop")
    ap.add_argument("--keep", type=Path, help="Keep the sequences and outputs in this folder.")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for name in args.worlds.split(","):
            seq = root / name
            if not (seq / "sequence.yaml").exists():
                write_drive(BUILTIN[name](), DriveSpec(seed=1), str(seq))
            r = run(seq, METHODS, root / f"{name}-out", force=True)
            print(f"\n### {name}: {r.methods[0].metrics['path_length_m']} m lap in {r.duration_s:.1f} s\n")  # type: ignore[index]
            print(table([(m.method, m.metrics) for m in r.methods if m.metrics is not None]))
            print("\n| method | poses | seconds | x real time | steps (H-IASM / IASM / ICP) |")
            print("|---|---|---|---|---|")
            for m in r.methods:
                steps = m.stats.get("steps_by")
                s = f"{steps['hiasm']} / {steps['iasm']} / {steps['icp']}" if steps else ""
                ratio = r.duration_s / m.seconds
                print(f"| {m.method} | {len(m.stamps_s)} | {m.seconds:.1f} | {ratio:.2f} | {s} |")
            shared = ", ".join(f"{k} {v:.1f} s" for k, v in r.timings_s.items())
            print(f"\nstage timings: {shared}", flush=True)


if __name__ == "__main__":
    main()
