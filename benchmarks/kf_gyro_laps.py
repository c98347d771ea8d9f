"""Kept laps of benchmarks/bench_kf.py with the simulated gyroscope added.

Each lap of ``--source`` (a ``bench_kf.py --keep`` folder) gets a copy in ``--out`` under
the same name: the scans, images, truth, rig, wheel odometry (where the lap has one) and
kept odometries linked (never written), sequence.yaml written anew at schema 4 with the
``gyro`` mapping, and gyro.csv simulated by :func:`rigcal.sim.drive.gyro_rates` from the
same motion and seed as ``rigcal simulate world --gyro`` would (its random stream is its
own, so the scans and images of such a drive are these). The copy's scans are checked
against the drive re-simulated from its seed (every range equal), so the kept odometries
are those of the copy. ``bench_kf.py --keep OUT --reuse`` then runs the filters with the
gyro, ``--without gyro`` without it.

    .venv/bin/python benchmarks/kf_gyro_laps.py --source DIR --out DIR3 [--seeds 1-10] [--wheel-odometry]
"""

from __future__ import annotations

from pathlib import Path

import yaml

from bench_tracks import seeds_of
from kf_wheel_laps import lap_parser, same_drive, write_yaml
from rigcal.io.gyro import checked, gyro_csv
from rigcal.recordings.sequence import SEQUENCE_SCHEMA_VERSION_GYRO
from rigcal.sim.drive import (
    GYRO_BIAS_DEG_S,
    GYRO_BIAS_WALK_DEG_S_RT_S,
    GYRO_NOISE_DEG_S_RT_HZ,
    GYRO_RATE_HZ,
    DriveSpec,
    gyro_rates,
)

LINKED = (
    "scans.npz",
    "images",
    "images.csv",
    "rig.yaml",
    "groundtruth.tum",
    "odometries.pkl",
    "odometry.tum",
)


def add_gyro(src: Path, out: Path, name: str, seed: int, duration_s: float) -> None:
    """One lap's copy with the gyroscope (see the module docstring)."""
    spec = DriveSpec(seed=seed, duration_s=duration_s, gyro=True)
    motion = same_drive(src, name, spec, out, LINKED)
    gyro = checked(*gyro_rates(motion, spec), "simulated gyroscope")
    (out / "gyro.csv").write_text(gyro_csv(gyro), encoding="utf-8")
    doc = yaml.safe_load((src / "sequence.yaml").read_text(encoding="utf-8"))
    doc["schema_version"] = SEQUENCE_SCHEMA_VERSION_GYRO
    doc["source"]["gyro"] = {
        "rate_hz": GYRO_RATE_HZ,
        "noise_deg_s_rt_hz": GYRO_NOISE_DEG_S_RT_HZ,
        "bias_deg_s": GYRO_BIAS_DEG_S,
        "bias_walk_deg_s_rt_s": GYRO_BIAS_WALK_DEG_S_RT_S,
    }
    doc["gyro"] = {"file": "gyro.csv"}
    write_yaml(out, doc)


def main() -> None:
    ap = lap_parser()
    ap.add_argument("--wheel-odometry", action="store_true", help="The laps of bench_kf.py --wheel-odometry.")
    args = ap.parse_args()
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            lap = f"{name}-seed{seed}-{args.duration_s:g}s{'-wheels' if args.wheel_odometry else ''}"
            out = args.out / lap
            if (out / "sequence.yaml").exists():
                continue
            if not (args.source / lap / "odometries.pkl").exists():
                print(f"{args.source / lap}: no kept odometries yet, skipped", flush=True)
                continue
            add_gyro(args.source / lap, out, name, seed, args.duration_s)
            print(f"{out}: gyroscope added, scans identical to seed {seed}'s", flush=True)


if __name__ == "__main__":
    main()
