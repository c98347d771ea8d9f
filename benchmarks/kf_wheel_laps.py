"""Kept laps of benchmarks/bench_kf.py with the base's wheel odometry added.

Each lap of ``--source`` (a ``bench_kf.py --keep`` folder of drives without wheel
odometry) gets a copy in ``--out`` named as ``bench_kf.py --wheel-odometry`` names its
laps (``<world>-seed<N>-<D>s-wheels``): the scans, images, truth, rig and kept odometries
linked (never written), sequence.yaml written anew at schema 3 with the ``odometry``
mapping, and odometry.tum simulated by :func:`rigcal.sim.drive.wheel_odometry` from the
same motion and seed as ``rigcal simulate world --wheel-odometry`` would (its random
stream is its own, so the scans and images of such a drive are these). The copy's scans
are checked against the drive re-simulated from its seed (every range equal), so the
kept odometries are those of the copy.

    .venv/bin/python benchmarks/kf_wheel_laps.py --source DIR --out DIR2 [--seeds 1-10]
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench_tracks import seeds_of
from rigcal.io.wheel_odometry import checked, odometry_tum
from rigcal.recordings.sequence import SEQUENCE_SCHEMA_VERSION_ODOMETRY, read_sequence
from rigcal.sim.drive import (
    WHEEL_DRIFT_DEG_PER_M,
    WHEEL_NOISE,
    WHEEL_RATE_HZ,
    WHEEL_SCALE_ERROR,
    WHEEL_T_BASE_LASER,
    DriveSpec,
    Motion,
    laser_stamps,
    simulate_scans,
    wheel_odometry,
)
from rigcal.sim.world import BUILTIN

LINKED = ("scans.npz", "images", "images.csv", "rig.yaml", "groundtruth.tum", "odometries.pkl")


def same_drive(src: Path, name: str, spec: DriveSpec, out: Path, linked: tuple[str, ...]) -> Motion:
    """The drive of ``spec`` on world ``name``, its scans checked equal to the kept lap's
    in ``src`` (else exit), and ``out`` made with the lap's files of ``linked`` linked."""
    world = BUILTIN[name]()
    motion = Motion(world, spec)
    stamps = laser_stamps(motion, spec)
    kept = read_sequence(src)
    again = simulate_scans(world, motion.poses(stamps), stamps, spec)
    same = len(again) == len(kept.scans) and all(
        a.stamp_s == b.stamp_s and np.array_equal(a.ranges_m, b.ranges_m, equal_nan=True)
        for a, b in zip(again, kept.scans, strict=True)
    )
    if not same:
        raise SystemExit(f"{src}: its scans are not the drive of seed {spec.seed} re-simulated")
    out.mkdir(parents=True, exist_ok=False)
    for f in linked:
        if (src / f).exists():
            (out / f).symlink_to((src / f).resolve())
    return motion


def add_wheels(src: Path, out: Path, name: str, seed: int, duration_s: float) -> None:
    """One lap's copy with wheel odometry (see the module docstring)."""
    spec = DriveSpec(seed=seed, duration_s=duration_s, wheel_odometry=True)
    motion = same_drive(src, name, spec, out, LINKED)
    t, poses = wheel_odometry(motion, spec)
    od = checked(t, poses, WHEEL_T_BASE_LASER, "simulated wheel odometry")
    (out / "odometry.tum").write_text(odometry_tum(od), encoding="utf-8")
    doc = yaml.safe_load((src / "sequence.yaml").read_text(encoding="utf-8"))
    doc["schema_version"] = SEQUENCE_SCHEMA_VERSION_ODOMETRY
    doc["source"]["wheel_odometry"] = {
        "rate_hz": WHEEL_RATE_HZ,
        "scale_error": WHEEL_SCALE_ERROR,
        "drift_deg_per_m": WHEEL_DRIFT_DEG_PER_M,
        "noise_distance_fraction_heading_rad": list(WHEEL_NOISE),
    }
    doc["odometry"] = {"file": "odometry.tum", "T_base_laser": [float(v) for v in WHEEL_T_BASE_LASER]}
    write_yaml(out, doc)


def write_yaml(out: Path, doc: dict[str, Any]) -> None:
    """The copy's sequence.yaml."""
    (out / "sequence.yaml").write_text(
        "# rigcal sequence (docs/formats/sequence.md)\n" + yaml.safe_dump(doc, sort_keys=False),
        encoding="utf-8",
    )


def lap_parser() -> argparse.ArgumentParser:
    """The options of a script copying kept laps: their folder, the copies', which laps."""
    ap = argparse.ArgumentParser()
    ap.add_argument("--source", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--worlds", default="cubicle-loop,corridor-loop")
    ap.add_argument("--seeds", default="1-10")
    ap.add_argument("--duration-s", type=float, default=40.0)
    return ap


def main() -> None:
    ap = lap_parser()
    args = ap.parse_args()
    for seed in seeds_of(args.seeds):
        for name in args.worlds.split(","):
            lap = f"{name}-seed{seed}-{args.duration_s:g}s"
            out = args.out / f"{lap}-wheels"
            if (out / "sequence.yaml").exists():
                continue
            add_wheels(args.source / lap, out, name, seed, args.duration_s)
            print(f"{out}: wheel odometry added, scans identical to seed {seed}'s", flush=True)


if __name__ == "__main__":
    main()
