"""What the targetless check's photometric term alone makes of the yaw: its error on
unmoved rigs against what the blocks' jackknife says of it (docs/calibration.md, "Drift
from ordinary drives", steps 5-7).

Where a drive shows no edges clearly (a bare corridor), the photometric term alone
estimates all five free directions, on every scan's odometry with the odometry's errors
held at zero (estimated, they traded off against its yaw: a crab angle turns the travel
as a camera yaw turns the view; ``--odometry-prior`` puts a prior on them instead), and
an error common to every block (the odometry's, the exposure walk's drift) moves all
blocks alike, so the blocks' spread cannot show it. Here each kept drive is
checked with the edge term off (``TargetlessSettings(edges=False)``: the photometric
term alone, on every scan's odometry, as on a drive without edges) against its true rig,
and per drive are printed the correction's roll, pitch and yaw, the jackknife sigma of
each, and how much of the yaw's information is left once the odometry's errors are free
(the Schur complement over the information with them held). The summary: per axis, the
root mean square of the corrections, the mean jackknife variance, and the floor they
imply (the square root of the difference: round 4's derivation of the floors), with the
z-scores against the jackknife plus the current floor.

    .venv/bin/python benchmarks/bench_targetless_photometric_alone.py --cache /tmp/rates31/drives \
        --seeds 300-339 --out /tmp/photo_alone.jsonl
    .venv/bin/python benchmarks/bench_targetless_photometric_alone.py --cache /tmp/rates31/drives \
        --seeds 300-319 --motion true --out /tmp/photo_alone_true.jsonl
    .venv/bin/python benchmarks/bench_targetless_photometric_alone.py --cache /tmp/rates31/drives \
        --seeds 300-305 --odometry-prior 2,1,0.5,6,6,1 --prior-weight 50 --out /tmp/photo_alone_prior.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from bench_targetless import WORLDS
from bench_targetless_rates import read_rows, seeds_of, small_rig


def odometry_prior(sigmas: str, weight: float) -> None:
    """Instead of holding every scan's odometry's errors at zero, put a prior of these
    sigmas on them (comma-separated, the check's units: 0.1 % scale, 0.1 % yaw scale, 1
    mrad/s, 1 mm pivot x and y, 1 mrad crab), its information weighed up ``weight``
    times (the check iterating as it does with them held)."""
    from rigcal.drift import targetless as tl

    held = tl._prior
    info = weight / np.array([float(x) for x in sigmas.split(",")]) ** 2

    def prior(hold_odometry: bool) -> np.ndarray:
        out = held(False)
        if hold_odometry:
            out[5:, 5:] = np.diag(info)
        return out

    tl._prior = prior


def alone(folder: Path, rig_path: Path, motion: str) -> dict:  # type: ignore[type-arg]
    """The photometric term's estimate alone on one drive, at the true rig, with the laser
    motion ``motion``: "every" scan's odometry (as the check runs it without edges),
    "thinned" (the odometry of the scans thinned to 10 Hz, as the check runs it with
    edges) or "true" (the simulator's ground truth: no odometry error)."""
    from rigcal.drift import targetless as tl
    from rigcal.drift.trajectory import trajectory_odometry
    from rigcal.localize.streams import open_streams

    streams = open_streams(folder, rig_file=rig_path)
    rig = streams.rig
    assert rig is not None
    s = tl.TargetlessSettings(edges=False)
    streams.require_images("targetless check")
    if motion == "thinned":
        streams = tl.thinned(streams, 10.0)
    elif motion == "true":
        streams.use_laser_odometry(trajectory_odometry(folder / "groundtruth.tum", streams))
    c = time.process_time()
    patches = tl._build_patches(rig, streams, s)
    try:
        with tl._stacks_ahead(rig, streams, patches, s):
            # The odometry's errors held on every scan's odometry (and the true motion),
            # as the check runs; estimated under the weak prior on the thinned one.
            est = tl._estimate(rig, streams, patches, s, hold_odometry=motion != "thinned")
    except tl._CannotTellError as exc:
        return {"cannot_tell": str(exc)}
    z = est.xi / s.scale  # resolution units
    sd = np.sqrt(np.clip(np.diag(est.cov_z), 0.0, None))
    # The yaw's information with the odometry's errors held and free (resolution units).
    held = float(est.information[2, 2])
    A = est.normal
    raw = float(A[2, 2])
    # Neighbouring blocks share the frames of the pairs across their border (a pair's later
    # frame is up to 0.6 s on): the lag-1 correlation of the blocks' leave-one-out moves
    # (in time order), about -1 / G if the blocks are independent.
    dc = est.moves[: est.blocks, :3] - est.moves[: est.blocks, :3].mean(axis=0)
    lag1 = [float(dc[1:, a] @ dc[:-1, a] / max(float(dc[:, a] @ dc[:, a]), 1e-300)) for a in range(3)]
    return {
        "lag1_corr": np.round(lag1, 3).tolist(),
        "z": z[:5].round(4).tolist(),
        "sd_jackknife": sd[:5].round(4).tolist(),
        "yaw_info_free": round(held, 3),
        "yaw_info_held": round(raw, 3),
        "crab_deg": round(math.degrees(float(est.odometry[5])), 4),
        "odometry_units": np.round(est.odometry / 1e-3, 3).tolist(),
        "solve": est.solve,
        "blocks": est.blocks,
        "heading_range_deg": patches.info.get("heading_range_deg"),
        "edges": patches.info.get("edges"),
        "cpu_s": round(time.process_time() - c, 2),
    }


def summary(rows: list[dict], floors: dict[str, tuple[float, float, float]]) -> None:  # type: ignore[type-arg]
    """Per axis: the corrections' and the jackknife's root mean square, the floor they
    imply, and the drives whose correction is beyond 2.58 sigmas with each floor."""
    rows = [r for r in rows if "z" in r]
    if not rows:
        return
    res_deg = 0.3
    z = np.array([r["z"][:3] for r in rows]) * res_deg
    sd = np.array([r["sd_jackknife"][:3] for r in rows]) * res_deg
    print(f"{len(rows)} drives judged by the photometric term alone (deg):")
    names = list(floors)
    print(
        "| axis | rms correction | mean correction | rms jackknife sigma | implied floor | "
        + " | ".join(f"{n} floor: value, drives beyond 2.58 sigma" for n in names)
        + " |"
    )
    print("|---" * (5 + len(names)) + "|")
    for a, name in enumerate(("roll", "pitch", "yaw")):
        rms = float(np.sqrt(np.mean(z[:, a] ** 2)))
        jk = float(np.sqrt(np.mean(sd[:, a] ** 2)))
        implied = math.sqrt(max(rms**2 - jk**2, 0.0))
        cells = []
        for n in names:
            zs = np.abs(z[:, a]) / np.sqrt(sd[:, a] ** 2 + floors[n][a] ** 2)
            cells.append(f"{floors[n][a]:.2f}, {int((zs > 2.5758).sum())} / {len(rows)}")
        mean = float(z[:, a].mean())
        print(f"| {name} | {rms:.4f} | {mean:+.4f} | {jk:.4f} | {implied:.4f} | {' | '.join(cells)} |")
    lag = np.array([r["lag1_corr"] for r in rows if "lag1_corr" in r])
    if len(lag):
        G = np.mean([r["blocks"] for r in rows])
        print(
            f"neighbouring blocks' moves, lag-1 correlation (roll, pitch, yaw): mean "
            f"{', '.join(f'{x:.3f}' for x in lag.mean(axis=0))} over {len(lag)} drives "
            f"(independent blocks: about {-1.0 / G:.3f}, sd of the mean {1.0 / math.sqrt(G * len(lag)):.3f})"
        )
    ratio = np.array([r["yaw_info_free"] / max(r["yaw_info_held"], 1e-12) for r in rows])
    print(
        f"yaw information left once the odometry's errors are free: median {np.median(ratio):.3g} "
        f"(5-95 %: {np.quantile(ratio, 0.05):.3g}-{np.quantile(ratio, 0.95):.3g})"
    )


def development_arguments(doc: str | None) -> argparse.ArgumentParser:
    """The options of a script run over the development drives: --cache, --seeds (300-339),
    --duration-s, --out, --report."""
    ap = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, required=True, help="the drives (bench_targetless_rates --keep)")
    ap.add_argument("--seeds", default="300-339", help="a range of seeds, a-b (the world by the parity)")
    ap.add_argument("--duration-s", type=float, default=24.0)
    ap.add_argument("--out", type=Path, required=True, help="JSON lines, appended (a stopped run resumes)")
    ap.add_argument("--report", action="store_true", help="only print the summary of --out")
    return ap


def main() -> None:
    ap = development_arguments(__doc__)
    ap.add_argument("--motion", choices=("every", "thinned", "true"), default="every", help="laser motion")
    ap.add_argument(
        "--odometry-prior",
        help="sigmas of a prior on the odometry's errors instead of holding them (e.g. 2,1,0.5,6,6,1)",
    )
    ap.add_argument("--prior-weight", type=float, default=1.0, help="that prior's information times this")
    args = ap.parse_args()
    if args.odometry_prior:
        odometry_prior(args.odometry_prior, args.prior_weight)
    from rigcal.drift.targetless import TargetlessSettings

    if not args.report:
        rig = small_rig(args.cache)
        done = {r["seed"] for r in read_rows(args.out)}
        for seed in seeds_of(args.seeds):
            world = WORLDS[seed % len(WORLDS)]
            folder = args.cache / f"{world}-320-s{seed}-{args.duration_s:g}s"
            if seed in done or not (folder / "sequence.yaml").exists():
                continue
            row = {"world": world, "seed": seed, "motion": args.motion} | alone(folder, rig, args.motion)
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), file=sys.stderr, flush=True)
    s = TargetlessSettings()
    summary(read_rows(args.out), {"edges'": s.floor_deg, "photometric": s.photo_floor_deg})


if __name__ == "__main__":
    main()
