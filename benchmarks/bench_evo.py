"""rigcal's trajectory figures against evo's, on `rigcal localize` output.

One lap of each simulated loop (10 Hz laser, no images) is localized by point-to-line ICP
as ``rigcal localize`` runs it; the written ``icp/trajectory.tum`` and the sequence's
``groundtruth.tum`` are then scored by rigcal (``rigcal.localize.metrics`` after evo's
stamp matching) and by evo's own functions (``evo.core.sync.associate_trajectories``,
``evo.core.metrics.APE``/``RPE``, ``PoseTrajectory3D.align``), as ``evo_ape`` and
``evo_rpe`` compute them (rigcal's figures unrounded here; ``rigcal evaluate`` prints them
to 0.1 mm). For comparison: the plain (unaligned) ``evo_ape`` of the same
estimate written at z = 0, as the trajectory files were before, and RPE by the former
pairing rule (every pose i with the first pose j whose true path from i reaches d).

    .venv/bin/python benchmarks/bench_evo.py
"""

from __future__ import annotations

import copy
import tempfile
from pathlib import Path

import numpy as np
from evo.core import metrics, sync
from evo.core.trajectory import PoseTrajectory3D

from rigcal.geometry import se2
from rigcal.io.trajectory import read_tum
from rigcal.localize.metrics import associate, ate_rmse, rpe_rmse
from rigcal.localize.pipeline import planar_at, run
from rigcal.sim.drive import DriveSpec, write_drive
from rigcal.sim.world import world_named
from rigcal.viz.localize_output import write_run


def evo_figures(ref: PoseTrajectory3D, est: PoseTrajectory3D) -> dict[str, float]:
    ref, est = sync.associate_trajectories(ref, est)
    out = {}
    for name, align in (("ape_plain", False), ("ape_align", True)):
        e = copy.deepcopy(est)
        if align:
            e.align(ref)
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((ref, e))
        out[name] = float(ape.get_statistic(metrics.StatisticsType.rmse))
    for d in (1.0, 10.0):
        rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=d, delta_unit=metrics.Unit.meters)
        rpe.process_data((ref, est))
        out[f"rpe_{d:g}m"] = float(rpe.get_statistic(metrics.StatisticsType.rmse))
    return out


def former_rpe(est: np.ndarray, gt: np.ndarray, d: float) -> float:
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(gt[:, :2], axis=0), axis=1))])
    errs = []
    for i in range(len(gt)):
        j = int(np.searchsorted(s, s[i] + d))
        if j >= len(gt):
            break
        e = np.linalg.inv(np.linalg.inv(se2(gt[i])) @ se2(gt[j])) @ (np.linalg.inv(se2(est[i])) @ se2(est[j]))
        errs.append(np.hypot(e[0, 2], e[1, 2]))
    return float(np.sqrt(np.mean(np.square(errs))))


def main() -> None:
    print(
        "| world | figure | rigcal | evo | rigcal - evo | before: z = 0 / former RPE pairs |\n"
        "|---|---|---|---|---|---|"
    )
    for world in ("cubicle-loop", "corridor-loop"):
        with tempfile.TemporaryDirectory() as tmp:
            seq, out = Path(tmp) / "seq", Path(tmp) / "out"
            write_drive(world_named(world), DriveSpec(laser_rate_hz=10.0, images=False, seed=1), seq)
            write_run(run(seq, ["icp"]), seq, out)
            est, truth = read_tum(out / "icp" / "trajectory.tum"), read_tum(seq / "groundtruth.tum")
        assert est.stamps_s is not None
        assert truth.stamps_s is not None
        ie, ig = associate(est.stamps_s, truth.stamps_s)
        p_est, p_gt = planar_at(est, est.stamps_s)[ie], planar_at(truth, truth.stamps_s)[ig]
        ref_e = PoseTrajectory3D(poses_se3=list(truth.poses), timestamps=truth.stamps_s)
        est_e = PoseTrajectory3D(poses_se3=list(est.poses), timestamps=est.stamps_s)
        theirs = evo_figures(ref_e, est_e)
        flat = est.poses.copy()
        flat[:, 2, 3] = 0.0
        plain_z0 = evo_figures(ref_e, PoseTrajectory3D(poses_se3=list(flat), timestamps=est.stamps_s))[
            "ape_plain"
        ]
        planar_plain = float(np.sqrt(np.mean(np.sum((p_est[:, :2] - p_gt[:, :2]) ** 2, axis=1))))
        rows = [
            ("APE plain (evo_ape)", planar_plain, theirs["ape_plain"], f"{plain_z0:.4f}"),
            ("ATE (evo_ape --align)", ate_rmse(p_est, p_gt), theirs["ape_align"], ""),
            (
                "RPE 1 m (evo_rpe)",
                rpe_rmse(p_est, p_gt, 1.0),
                theirs["rpe_1m"],
                f"{former_rpe(p_est, p_gt, 1.0):.4f}",
            ),
            (
                "RPE 10 m (evo_rpe)",
                rpe_rmse(p_est, p_gt, 10.0),
                theirs["rpe_10m"],
                f"{former_rpe(p_est, p_gt, 10.0):.4f}",
            ),
        ]
        for name, a, b, before in rows:
            print(f"| {world} | {name} | {a:.4f} | {b:.4f} | {a - b:+.1e} | {before} |")


if __name__ == "__main__":
    main()
