"""How far the laser odometry the targetless check runs on errs, in the terms of the
odometry errors the check can estimate beside T (docs/benchmarks.md, "The targetless
check: the odometry's errors held where the photometric term judges alone").

The check's photometric term models the laser odometry's systematic errors between two
frames i and j (``drift/targetless.py``, ``_frames_terms``): a scale ``eps`` of the
step's translation, a yaw scale ``kappa`` and a yaw rate bias ``b`` (the turn
``yaw * kappa + dt * b``), a pivot ``l`` (a translation ``(R - I) l``: the odometry's
centre of rotation off the laser's) and a crab angle ``c`` (the step turned about z). Here,
for each drive, the pairs of frames the check compares (its frames at 5 Hz, its gaps,
degenerate steps left out) are taken from the odometry and from the simulator's true
motion, and the six errors that best map the odometry's motion onto the true one are
fitted by least squares (to first order: the true turn minus the odometry's is
``yaw * kappa + dt * b``; the true step minus the odometry's is ``eps t + c z x t + (R - I)
l``). Printed per drive and summarised over the drives: each error's root mean square in
the check's units (0.1 % scale, 0.1 % yaw scale, 1 mrad/s, 1 mm pivot, 1 mrad crab), the
size a prior on them would have to stand for.

    .venv/bin/python benchmarks/bench_targetless_odometry_errors.py --cache /tmp/odo/drives \\
        --seeds 300-339 --out /tmp/odo/errors.jsonl
    .venv/bin/python benchmarks/bench_targetless_odometry_errors.py --cache /tmp/odo/drives \\
        --seeds 300-339 --motion thinned --out /tmp/odo/errors_thinned.jsonl
"""

from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from bench_targetless import WORLDS
from bench_targetless_photometric_alone import development_arguments
from bench_targetless_rates import read_rows, seeds_of, simulate, small_rig

NAMES = ("scale", "yaw_scale", "yaw_rate_bias", "pivot_x", "pivot_y", "crab")


def pair_motions(streams, poses: np.ndarray, degenerate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    """(P, 3, 3) the laser at frame i in the laser frame at frame j (SE(2)) for the check's
    pairs, from the planar poses (N, 3) at the scans' stamps, the pairs across a
    degenerate step (N,) left out as the check leaves them; and (P,) the pairs' dt."""
    from rigcal.drift.frames import used_frames
    from rigcal.drift.targetless import TargetlessSettings
    from rigcal.geometry import se2
    from rigcal.localize.time_pairing import nearest_index, poses_at

    s = TargetlessSettings()
    t_img, t_scan = streams.image_stamps_s, streams.scan_stamps_s
    frames = [f for f in used_frames(t_img, s.frame_rate_hz) if t_scan[0] <= t_img[f] <= t_scan[-1]]
    at = poses_at(t_scan, poses, t_img[frames])
    k_of = {f: k for k, f in enumerate(frames)}
    Ms, dts = [], []
    for k, i in enumerate(frames):
        for gap in s.gaps_s:
            j = nearest_index(t_img, float(t_img[i]) + gap)
            if j == i or j not in k_of or abs(float(t_img[j] - t_img[i]) - gap) > 0.5 * gap:
                continue
            k0, k1 = nearest_index(t_scan, float(t_img[i])), nearest_index(t_scan, float(t_img[j]))
            if degenerate[k0 + 1 : k1 + 1].any():
                continue
            Ms.append(np.linalg.inv(se2(at[k_of[j]])) @ se2(at[k]))
            dts.append(float(t_img[j] - t_img[i]))
    return np.array(Ms), np.array(dts)


def fit_errors(M_od: np.ndarray, M_true: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(6,) the odometry's errors (the check's units) that best map its pair motions onto
    the true ones, to first order (see the module docstring)."""
    yaw_od = np.arctan2(M_od[:, 1, 0], M_od[:, 0, 0])
    yaw_true = np.arctan2(M_true[:, 1, 0], M_true[:, 0, 0])
    d_yaw = np.angle(np.exp(1j * (yaw_true - yaw_od)))
    turn, *_ = np.linalg.lstsq(np.column_stack([yaw_od, dt]), d_yaw, rcond=None)
    t = M_od[:, :2, 2]
    R_I = M_od[:, :2, :2] - np.eye(2)
    perp = np.column_stack([-t[:, 1], t[:, 0]])
    # Rows: x and y of each pair; columns: eps, pivot x, pivot y, crab.
    A = np.stack([t, R_I[:, :, 0], R_I[:, :, 1], perp], axis=2).reshape(-1, 4)
    step, *_ = np.linalg.lstsq(A, (M_true[:, :2, 2] - t).ravel(), rcond=None)
    eps, lx, ly, crab = step
    return np.array([eps, turn[0], turn[1], lx, ly, crab]) / 1e-3


def errors(folder: Path, rig_path: Path, motion: str) -> dict:  # type: ignore[type-arg]
    from rigcal.drift import targetless as tl
    from rigcal.drift.trajectory import trajectory_odometry
    from rigcal.localize.odometry import DEGENERATE_BELOW
    from rigcal.localize.streams import open_streams

    streams = open_streams(folder, rig_file=rig_path)
    c = time.process_time()
    run = tl.thinned(streams, 10.0) if motion == "thinned" else streams
    od = run.laser_odometry()
    truth = trajectory_odometry(folder / "groundtruth.tum", run)
    # Pairs across a degenerate step are left out by the check: here too.
    degenerate = od.degeneracy < DEGENERATE_BELOW
    degenerate[0] = False
    M_od, dt = pair_motions(run, od.poses, degenerate)
    M_true, _ = pair_motions(run, truth.poses, degenerate)
    x = fit_errors(M_od, M_true, dt)
    yaw_err = np.degrees(
        np.angle(
            np.exp(
                1j * (np.arctan2(M_true[:, 1, 0], M_true[:, 0, 0]) - np.arctan2(M_od[:, 1, 0], M_od[:, 0, 0]))
            )
        )
    )
    return {
        "errors_units": dict(zip(NAMES, np.round(x, 4).tolist(), strict=True)),
        "pairs": len(dt),
        "degenerate_steps": int(degenerate.sum()),
        "pair_yaw_error_rms_deg": round(float(np.sqrt(np.mean(yaw_err**2))), 4),
        "pair_step_error_rms_mm": round(
            1000.0 * float(np.sqrt(np.mean(np.sum((M_true[:, :2, 2] - M_od[:, :2, 2]) ** 2, axis=1)))), 3
        ),
        "cpu_s": round(time.process_time() - c, 2),
    }


def summary(rows: list[dict]) -> None:  # type: ignore[type-arg]
    rows = [r for r in rows if "errors_units" in r]
    if not rows:
        return
    x = np.array([[r["errors_units"][n] for n in NAMES] for r in rows])
    print(
        f"{len(rows)} drives; the odometry's errors fitted per drive "
        "(units: 0.1 %, 0.1 %, 1 mrad/s, 1 mm, 1 mm, 1 mrad):"
    )
    print("| error | rms | mean | largest |")
    print("|---|---|---|---|")
    for a, n in enumerate(NAMES):
        print(
            f"| {n} | {math.sqrt(float(np.mean(x[:, a] ** 2))):.3f} | {float(np.mean(x[:, a])):+.3f} | "
            f"{float(np.abs(x[:, a]).max()):.3f} |"
        )
    yaw = np.array([r["pair_yaw_error_rms_deg"] for r in rows])
    step = np.array([r["pair_step_error_rms_mm"] for r in rows])
    print(
        f"the pairs' own errors: yaw rms median {np.median(yaw):.4f} deg, "
        f"step rms median {np.median(step):.2f} mm"
    )


def main() -> None:
    ap = development_arguments(__doc__)  # the drives are simulated into --cache when missing
    ap.add_argument("--motion", choices=("every", "thinned"), default="every", help="the odometry measured")
    args = ap.parse_args()
    if not args.report:
        args.cache.mkdir(parents=True, exist_ok=True)
        rig = small_rig(args.cache)
        done = {r["seed"] for r in read_rows(args.out)}
        for seed in seeds_of(args.seeds):
            world = WORLDS[seed % len(WORLDS)]
            if seed in done:
                continue
            folder = simulate(args.cache, rig, world, seed, args.duration_s)
            if folder is None:
                continue
            row = {"world": world, "seed": seed, "motion": args.motion} | errors(folder, rig, args.motion)
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), file=sys.stderr, flush=True)
    summary(read_rows(args.out))


if __name__ == "__main__":
    main()
