"""The feature tracks' settings compared over laps: the detector, SIFT (the paper's) against
Shi-Tomasi corners, or any other ``TrackParams`` setting (``--variants``).

New tracks start at SIFT keypoints (paper Section IV) or, with ``TrackParams(detector=
"shi-tomasi")``, at OpenCV's ``goodFeaturesToTrack`` corners, which are several times
cheaper to find. For each built-in loop and seed (one lap, ``rigcal simulate world``, as
``bench_localize.py`` simulates it), both detectors are run through VO and ICP + VO + KF
(``--methods``; H-IASM too, whose visual odometry comes from the same tracks) in one
``rigcal localize`` run each, in the same process: the methods' accuracy (loop
closure, average position error, ATE) and VO's runs, the tracking stage's time and the
run's wall time (real time = the lap's duration). With more than one seed a second table
gives, per loop, detector and method, the mean and the worst loop closure and ATE over
the seeds, and the tracking time against the first variant's on the same laps.

``--variants`` compares sets of settings instead of detectors: sets separated by ``;``,
each a comma-separated list of ``KEY=VALUE`` as ``rigcal localize --tracks`` takes them
(``"window_px=15;window_px=11"``; an empty set is the defaults). ``--drive`` changes the
simulated laps (``DriveSpec`` fields, e.g. a harsher camera:
``"image_noise_sigma=4,image_blur_sigma_px=1,exposure_walk=0.03"``).

    .venv/bin/python benchmarks/bench_tracks.py [--worlds corridor-loop,cubicle-loop]
        [--seeds 1] [--range-max-m 30] [--methods vo,kf] [--detectors sift,shi-tomasi]
        [--variants "KEY=VALUE,...;..."] [--drive KEY=VALUE,...] [--keep DIR]
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np

from bench_localize import sequence_name
from rigcal.localize.pipeline import parse_settings, run
from rigcal.localize.tracks import DETECTORS, TrackParams
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN


def seeds_of(text: str) -> list[int]:
    """``"1"``, ``"1,3,5"`` or ``"1-10"``."""
    if "-" in text:
        a, b = (int(v) for v in text.split("-"))
        return list(range(a, b + 1))
    return [int(v) for v in text.split(",")]


def variants_of(text: str) -> dict[str, TrackParams]:
    """``"KEY=VALUE,KEY=VALUE;KEY=VALUE"`` -> {label: the settings}."""
    out = {}
    for part in text.split(";"):
        items = [i for i in part.split(",") if i.strip()]
        out[part.strip() or "defaults"] = parse_settings(items, TrackParams(), "--variants")
    return out


def drive_of(text: str) -> dict[str, float]:
    """``"KEY=VALUE,..."`` -> DriveSpec fields (numbers)."""
    fields = {f.name: f.type for f in dataclasses.fields(DriveSpec)}
    out: dict[str, float] = {}
    for item in filter(None, (i.strip() for i in text.split(","))):
        key, _, value = item.partition("=")
        if key not in fields or key in ("seed", "range_max_m"):
            raise SystemExit(f"--drive {item!r}: KEY one of {sorted(fields)} but seed, range_max_m")
        out[key] = int(value) if fields[key] in ("int", int) else float(value)
    return out


def folder_of(label: str, prefix: str = "") -> str:
    """A folder name for a label (empty for an empty label)."""
    return prefix + "".join(c if c.isalnum() or c in "-_" else "_" for c in label) if label else ""


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--worlds", default="corridor-loop,cubicle-loop")
    ap.add_argument("--seeds", default="1", help='The simulation seeds: "1", "1,2,3" or "1-10".')
    ap.add_argument("--range-max-m", type=float, default=30.0, help="The simulated laser's range.")
    ap.add_argument("--methods", default="vo,kf", help="The methods run on each lap (vo, kf, hiasm).")
    ap.add_argument("--detectors", default=",".join(DETECTORS), help="The detectors compared.")
    ap.add_argument("--variants", help='Settings compared instead: "KEY=VALUE,...;KEY=VALUE,...".')
    ap.add_argument("--drive", default="", help="DriveSpec fields of the laps: KEY=VALUE,...")
    ap.add_argument("--keep", type=Path, help="Keep the sequences and outputs in this folder.")
    args = ap.parse_args()
    drive = drive_of(args.drive)
    seeds = seeds_of(args.seeds)
    variants = (
        variants_of(args.variants)
        if args.variants
        else {d: TrackParams(detector=d) for d in args.detectors.split(",")}
    )
    first = next(iter(variants))
    # (world, variant, method) -> [(loop closure, ATE)]; (world, variant) -> [tracks_s]
    scores: dict[tuple[str, str, str], list[tuple[float, float]]] = defaultdict(list)
    tracking: dict[tuple[str, str], list[float]] = defaultdict(list)
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        laser = f", {args.range_max_m:g} m laser" if args.range_max_m != 30.0 else ""
        laser += f", {args.drive}" if args.drive else ""
        print(f"\n### Each lap{laser}\n")
        print(
            "| world | seed | tracks | method | loop closure (m) | avg position error (m) | ATE RMSE (m) "
            "| VO runs | tracks (s) | wall (s) | x real time |"
        )
        print("|---|---|---|---|---|---|---|---|---|---|---|")
        warm = False
        for name in args.worlds.split(","):
            for seed in seeds:
                seq = root / (sequence_name(name, seed, args.range_max_m) + folder_of(args.drive, "-"))
                if not (seq / "sequence.yaml").exists():
                    spec = DriveSpec(seed=seed, range_max_m=args.range_max_m, **drive)
                    write_drive(BUILTIN[name](), spec, str(seq))
                if not warm:
                    run(seq, ["icp"])  # load the kernels
                    warm = True
                for variant, params in variants.items():
                    r = run(seq, args.methods.split(","), tracks=params)
                    tracking[name, variant].append(r.timings_s["tracks_s"])
                    speed = (
                        f"| {r.timings_s['tracks_s']:.1f} | {r.wall_s:.1f} | {r.duration_s / r.wall_s:.2f} |"
                    )
                    for m in r.methods:
                        assert m.metrics is not None
                        runs = ", ".join(f"{k} {v}" for k, v in m.stats.get("run_status", {}).items())
                        lc, ate = m.metrics["loop_closure_error_m"], m.metrics["ate_rmse_m"]
                        scores[name, variant, m.method].append((float(lc), float(ate)))
                        print(
                            f"| {name} | {seed} | {variant} | {m.method} | {lc} "
                            f"| {m.metrics['average_position_error_m']} | {ate} | {runs} " + speed,
                            flush=True,
                        )
    if len(seeds) < 2:
        return
    print(f"\n### Over seeds {args.seeds}{laser}\n")
    print(
        "| world | tracks | method | loop closure mean (m) | loop closure worst (m) "
        f"| ATE mean (m) | ATE worst (m) | tracking time / {first}'s |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for (name, variant, method), v in scores.items():
        a = np.array(v)
        ratio = np.sum(tracking[name, variant]) / np.sum(tracking[name, first])
        print(
            f"| {name} | {variant} | {method} | {a[:, 0].mean():.3f} | {a[:, 0].max():.3f} "
            f"| {a[:, 1].mean():.3f} | {a[:, 1].max():.3f} | {ratio:.2f} |"
        )


if __name__ == "__main__":
    main()
