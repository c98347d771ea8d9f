"""The localization pipeline: a sequence folder in, a trajectory and its metrics out.

``run`` reads like its steps: read the sequence, estimate the laser's trajectory with the
chosen method, write the trajectory, the effective configuration and, when the sequence
has ground truth, the metrics of ``rigcal.localize.metrics``. Methods are registered in
:data:`METHODS` (name -> function from scans to an Odometry), so adding one is local.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from rigcal.errors import InputError
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.io.files import atomic_folder
from rigcal.io.sequence import read_sequence
from rigcal.io.trajectory import Trajectory, kitti_text, read_tum, tum_text
from rigcal.localize.icp import IcpParams
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.odometry import Odometry, icp_odometry
from rigcal.scan import Scan

FloatArray = NDArray[np.float64]

MIN_SCANS = 2

METHODS: dict[str, Callable[[Sequence[Scan]], Odometry]] = {
    "icp": lambda scans: icp_odometry(scans, IcpParams(method="point-to-line")),
    "icp-p2p": lambda scans: icp_odometry(scans, IcpParams(method="point-to-point")),
}


@dataclass(frozen=True)
class Run:
    """What a run produced."""

    stamps_s: FloatArray
    poses: FloatArray
    metrics: dict[str, Any] | None
    timings_s: dict[str, float]
    degenerate_steps: int


def run(
    sequence: str | Path, method: str, output: str | Path, force: bool = False, kitti: bool = False
) -> Run:
    """Localize a sequence with one method and write the output folder.

    Raises:
        InputError: an unknown method, or a sequence that cannot be localized.
    """
    if method not in METHODS:
        raise InputError.at(None, "--method", method, f"one of {sorted(METHODS)}")
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    seq = read_sequence(sequence)
    timings["read_s"] = time.perf_counter() - t0
    if len(seq.scans) < MIN_SCANS:
        raise InputError.at(
            Path(sequence) / "sequence.yaml", "scans.count", len(seq.scans), f"at least {MIN_SCANS} scans"
        )
    t0 = time.perf_counter()
    od = METHODS[method](seq.scans)
    timings["estimate_s"] = time.perf_counter() - t0
    stamps = np.array([s.stamp_s for s in seq.scans], dtype=float)
    gt = _ground_truth(Path(sequence), stamps)
    metrics = None
    poses = od.poses
    if gt is not None:
        # Express the estimate in the world frame: start it at the true first pose.
        poses = anchored(od.poses, gt)
        metrics = evaluate(poses, gt)
    traj = Trajectory(
        np.array([make_T(rotvec_to_R([0.0, 0.0, p[2]]), [p[0], p[1], 0.0]) for p in poses]), stamps
    )
    degenerate = int((od.degeneracy < 0.01).sum())
    config = {"method": method, "sequence": str(Path(sequence).resolve()), "scans": len(stamps)}
    summary = {"config": config, "timings_s": {k: round(v, 3) for k, v in timings.items()},
               "ms_per_scan": round(1000.0 * timings["estimate_s"] / len(stamps), 2),
               "degenerate_steps": degenerate, "skipped_steps": od.skipped, "metrics": metrics}  # fmt: skip
    with atomic_folder(output, force) as tmp:
        (tmp / "trajectory.tum").write_text(tum_text(traj), encoding="utf-8")
        if kitti:
            (tmp / "trajectory.kitti").write_text(kitti_text(traj), encoding="utf-8")
        (tmp / "summary.yaml").write_text(yaml.safe_dump(summary, sort_keys=False), encoding="utf-8")
        (tmp / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    return Run(stamps, poses, metrics, timings, degenerate)


def _ground_truth(folder: Path, stamps: FloatArray) -> FloatArray | None:
    """The sequence's true laser poses (x, y, yaw) at the scan stamps, or None."""
    f = folder / "groundtruth.tum"
    if not f.is_file():
        return None
    return planar_at(read_tum(f), stamps)


def planar_at(traj: Trajectory, stamps: FloatArray) -> FloatArray:
    """(N, 3) planar poses of a trajectory interpolated at the stamps."""
    assert traj.stamps_s is not None
    x = np.interp(stamps, traj.stamps_s, traj.poses[:, 0, 3])
    y = np.interp(stamps, traj.stamps_s, traj.poses[:, 1, 3])
    yaw = np.unwrap(np.arctan2(traj.poses[:, 1, 0], traj.poses[:, 0, 0]))
    return np.column_stack([x, y, np.interp(stamps, traj.stamps_s, yaw)])
