"""IASM's joint polish: how much to weigh the image correspondences against the walls.

The polish (``rigcal.localize.polish.joint_polish``) fits each step to the scans'
point-to-line alignment (1 cm noise per return) and the image correspondences together;
``IasmParams.sigma_match_m`` is the weight of a correspondence, as a noise. For each
weight, H-IASM runs over one lap of each simulated loop (seed 1, as
``bench_localize.py``) and is scored against the truth: end position error, average
position error, and, over the steps H-IASM or IASM made (not the ICP fallbacks), the mean
forward error as a fraction of the true step (a scale bias) and the mean yaw error.

    .venv/bin/python benchmarks/bench_polish.py [--keep DIR] [--weights 0.02,0.1,0.2,0.5]
        [--snap-max-m 0.03] [--dense] [--keyframe-m 2]

``--snap-max-m``, ``--dense`` and ``--keyframe-m`` set ``IasmParams.snap_max_m``,
``dense_window`` and ``keyframe_m`` (``bench_matching.py``); snapping and the keyframe
are off (0) unless asked for, as these weights were measured before either was the
default.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np

from rigcal.io.trajectory import read_tum
from rigcal.localize import image_matching
from rigcal.localize.iasm import IasmParams
from rigcal.localize.metrics import anchored, evaluate, steps
from rigcal.localize.pipeline import planar_at
from rigcal.localize.streams import open_streams
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import BUILTIN


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--keep", type=Path, help="Keep (or reuse) the sequences in this folder.")
    ap.add_argument("--weights", default="0.02,0.1,0.2,0.5")
    ap.add_argument("--snap-max-m", type=float, default=0.0, help="Snap returns onto their lines.")
    ap.add_argument("--dense", action="store_true", help="H-IASM's dense window search.")
    ap.add_argument("--keyframe-m", type=float, default=0.0, help="IasmParams.keyframe_m.")
    args = ap.parse_args()
    weights = [float(w) for w in args.weights.split(",")]
    print("| world | sigma_match_m | end position error (m) | avg position error (m) "
          "| own steps: forward bias (%) | own steps: yaw bias (mdeg) |")  # fmt: skip
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        root = args.keep or Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        for name in ("corridor-loop", "cubicle-loop"):
            seq = root / name
            if not (seq / "sequence.yaml").exists():
                write_drive(BUILTIN[name](), DriveSpec(seed=1), str(seq))
            streams = open_streams(seq)
            streams.start_laser_odometry()
            streams.feature_tracks()
            truth = read_tum(seq / "groundtruth.tum")
            for w in weights:
                params = dataclasses.replace(
                    IasmParams(),
                    sigma_match_m=w,
                    snap_max_m=args.snap_max_m,
                    dense_window=args.dense,
                    keyframe_m=args.keyframe_m,
                )
                stamps, poses, _, steps = image_matching.scan_matching(streams, "hiasm", params)
                gt = planar_at(truth, stamps)
                m = evaluate(anchored(poses, gt), gt)
                used = np.array([row.split(",")[2] for row in steps.splitlines()[1:]])
                fwd, yaw = own_step_bias(poses, gt, used != "icp")
                print(
                    f"| {name} | {w} | {m['end_position_error_m']:.4f} | {m['average_position_error_m']:.4f} "
                    f"| {fwd:.3f} | {yaw:.2f} |",
                    flush=True,
                )


def own_step_bias(poses: np.ndarray, gt: np.ndarray, own: np.ndarray) -> tuple[float, float]:
    """Mean forward error over the true step length (%) and mean yaw error (mdeg) of the
    steps in ``own`` that moved more than 1 cm."""
    est, true = steps(poses), steps(gt)
    length = np.linalg.norm(true[:, :2], axis=1)
    k = own & (length > 0.01)
    forward = np.einsum("ij,ij->i", est[k, :2] - true[k, :2], true[k, :2]) / length[k] ** 2
    return 100.0 * float(forward.mean()), float(np.degrees(np.mean(est[own, 2] - true[own, 2])) * 1000.0)


if __name__ == "__main__":
    main()
