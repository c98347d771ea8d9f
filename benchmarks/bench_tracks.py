"""The feature tracks' detector: SIFT (the paper's) against Shi-Tomasi corners.

New tracks start at SIFT keypoints (paper Section IV) or, with ``TrackParams(detector=
"shi-tomasi")``, at OpenCV's ``goodFeaturesToTrack`` corners, which are several times
cheaper to find. For each built-in loop (one lap, ``rigcal simulate world``, seed 1, as
``bench_localize.py`` simulates it), both detectors are run through VO and ICP + VO + KF
in one ``rigcal localize`` run each, in the same process: the methods' accuracy (loop
closure, average position error, ATE) and VO's runs, the tracking stage's time and the
run's wall time (real time = the lap's duration).

    .venv/bin/python benchmarks/bench_tracks.py [--worlds corridor-loop,cubicle-loop] [--keep DIR]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from bench_localize import sequence_name
from rigcal.localize.pipeline import run
from rigcal.localize.tracks import DETECTORS, TrackParams
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="corridor-loop,cubicle-loop")
    ap.add_argument("--keep", type=Path, help="Keep the sequences and outputs in this folder.")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        print(
            "| world | detector | method | loop closure (m) | avg position error (m) | ATE RMSE (m) "
            "| VO runs | tracks (s) | wall (s) | x real time |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|")
        for name in args.worlds.split(","):
            seq = root / sequence_name(name, 1, 30.0)
            if not (seq / "sequence.yaml").exists():
                write_drive(BUILTIN[name](), DriveSpec(seed=1), str(seq))
            run(seq, ["icp"], root / "warm", force=True)  # load the kernels
            for detector in DETECTORS:
                r = run(
                    seq,
                    ["vo", "kf"],
                    root / f"{seq.name}-{detector}",
                    force=True,
                    tracks=TrackParams(detector=detector),
                )
                for m in r.methods:
                    assert m.metrics is not None
                    runs = m.stats.get("run_status", "")
                    print(
                        f"| {name} | {detector} | {m.method} | {m.metrics['loop_closure_error_m']} "
                        f"| {m.metrics['average_position_error_m']} | {m.metrics['ate_rmse_m']} | {runs} "
                        f"| {r.timings_s['tracks_s']:.1f} | {r.wall_s:.1f} | {r.duration_s / r.wall_s:.2f} |",
                        flush=True,
                    )


if __name__ == "__main__":
    main()
