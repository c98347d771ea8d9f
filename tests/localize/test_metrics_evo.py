"""rigcal's ATE, RPE and stamp matching against evo's own functions (evo.core.metrics,
evo.core.sync): the same figures for the same trajectories, and `rigcal localize`'s
trajectory files as plain `evo_ape` reads them."""

from __future__ import annotations

import copy
import itertools
import json

import numpy as np
import pytest
from evo.core import metrics, sync
from evo.core.trajectory import PoseTrajectory3D

from rigcal.cli.main import main
from rigcal.geometry import make_T, pose_of, rotvec_to_R, se2
from rigcal.io.trajectory import Trajectory, read_tum, tum_text
from rigcal.localize.metrics import anchored, associate, ate_rmse, rpe_rmse
from rigcal.localize.pipeline import planar_at

HEIGHT_M = 0.4


def loop(n: int, rng: np.random.Generator, drift: float) -> tuple[np.ndarray, np.ndarray]:
    """(truth, estimate) planar poses around a 40 m rounded square; the estimate
    integrates the truth's steps with noise and a small scale and heading drift."""
    s = np.linspace(0.0, 40.0, n, endpoint=False)
    ang = 2 * np.pi * s / 40.0
    r = 6.0 + 0.8 * np.cos(4 * ang)
    gt = np.column_stack([r * np.cos(ang), r * np.sin(ang), np.zeros(n)])
    gt[:, 2] = np.unwrap(np.arctan2(np.gradient(gt[:, 1]), np.gradient(gt[:, 0])))
    est = [gt[0]]
    for a, b in itertools.pairwise(gt):
        step = pose_of(np.linalg.inv(se2(a)) @ se2(b))
        step = step * np.array([1.0 + drift, 1.0, 1.0 + drift]) + rng.normal(0, [0.004, 0.002, 0.002])
        est.append(pose_of(se2(est[-1]) @ se2(step)))
    return gt, np.array(est)


def evo_traj(poses: np.ndarray, stamps: np.ndarray, z: float = HEIGHT_M) -> PoseTrajectory3D:
    T = [make_T(rotvec_to_R([0.0, 0.0, p[2]]), [p[0], p[1], z]) for p in poses]
    return PoseTrajectory3D(poses_se3=T, timestamps=stamps)


def evo_ape(ref: PoseTrajectory3D, est: PoseTrajectory3D, align: bool) -> float:
    ref, est = sync.associate_trajectories(ref, est)
    if align:
        est = copy.deepcopy(est)
        est.align(ref)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return float(ape.get_statistic(metrics.StatisticsType.rmse))


def evo_rpe(ref: PoseTrajectory3D, est: PoseTrajectory3D, delta_m: float) -> float:
    ref, est = sync.associate_trajectories(ref, est)
    rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=delta_m, delta_unit=metrics.Unit.meters)
    rpe.process_data((ref, est))
    return float(rpe.get_statistic(metrics.StatisticsType.rmse))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ate_and_rpe_equal_evos(seed):
    rng = np.random.default_rng(seed)
    gt, est = loop(800, rng, drift=0.01 * (seed + 1))
    stamps = np.arange(len(gt)) * 0.1
    moved = np.array([pose_of(se2([2.0, -1.0, 0.7]) @ se2(p)) for p in est])  # another start frame
    ref_e, est_e = evo_traj(gt, stamps), evo_traj(moved, stamps, z=0.0)
    assert ate_rmse(moved, gt) == pytest.approx(evo_ape(ref_e, evo_traj(moved, stamps), align=True), abs=1e-9)
    for delta in (1.0, 10.0):
        assert rpe_rmse(moved, gt, delta) == pytest.approx(evo_rpe(ref_e, est_e, delta), abs=1e-9)


@pytest.mark.parametrize("seed", [3, 4])
def test_stamp_matching_equals_evos(seed):
    rng = np.random.default_rng(seed)
    truth_t = np.cumsum(rng.uniform(0.02, 0.03, 600))
    est_t = np.sort(rng.uniform(truth_t[0] - 0.5, truth_t[-1] + 0.5, 150))
    for a, b in ((est_t, truth_t), (truth_t, est_t), (est_t, est_t + rng.uniform(-0.012, 0.012, 150))):
        b = np.sort(b)
        ia, ib = associate(a, b)
        ta, tb = sync.associate_trajectories(
            evo_traj(np.zeros((len(a), 3)), a), evo_traj(np.zeros((len(b), 3)), b)
        )
        np.testing.assert_array_equal(a[ia], ta.timestamps)
        np.testing.assert_array_equal(b[ib], tb.timestamps)
        assert 0 < len(ia) <= min(len(a), len(b))


def write_tum(path, poses: np.ndarray, stamps: np.ndarray, z: float) -> None:
    T = np.array([make_T(rotvec_to_R([0.0, 0.0, p[2]]), [p[0], p[1], z]) for p in poses])
    path.write_text(tum_text(Trajectory(T, stamps)))


def test_rigcal_evaluate_equals_evo_on_files_with_other_stamps(tmp_path, capsys):
    rng = np.random.default_rng(7)
    gt, est = loop(2000, rng, drift=0.02)
    stamps = np.arange(len(gt)) * 0.025
    keep = np.arange(0, len(gt), 4)  # the estimate at a quarter of the truth's stamps, jittered
    est_t = stamps[keep] + rng.uniform(-0.004, 0.004, len(keep))
    write_tum(tmp_path / "gt.tum", gt, stamps, HEIGHT_M)
    (tmp_path / "icp").mkdir()
    write_tum(tmp_path / "icp" / "trajectory.tum", anchored(est[keep], gt[keep]), est_t, HEIGHT_M)
    assert (
        main(
            ["evaluate", str(tmp_path / "icp" / "trajectory.tum"), "--gt", str(tmp_path / "gt.tum"), "--json"]
        )
        == 0
    )
    m = json.loads(capsys.readouterr().out)
    ref_e = evo_traj(gt, stamps)
    est_e = PoseTrajectory3D(
        poses_se3=list(read_tum(tmp_path / "icp" / "trajectory.tum").poses), timestamps=est_t
    )
    assert m["matched_poses"] == len(keep)
    assert m["ate_rmse_m"] == pytest.approx(evo_ape(ref_e, est_e, align=True), abs=6e-5)
    assert m["rpe_1m_rmse_m"] == pytest.approx(evo_rpe(ref_e, est_e, 1.0), abs=6e-5)
    assert m["rpe_10m_rmse_m"] == pytest.approx(evo_rpe(ref_e, est_e, 10.0), abs=6e-5)


def test_evaluate_labels_rows_by_method_folder(tmp_path, capsys):
    rng = np.random.default_rng(8)
    gt, est = loop(400, rng, drift=0.01)
    stamps = np.arange(len(gt)) * 0.1
    write_tum(tmp_path / "gt.tum", gt, stamps, HEIGHT_M)
    paths = []
    for run in ("a", "b"):
        for method in ("icp", "kf"):
            (tmp_path / run / method).mkdir(parents=True)
            paths.append(tmp_path / run / method / "trajectory.tum")
            write_tum(paths[-1], est, stamps, HEIGHT_M)
    assert main(["evaluate", *map(str, paths[:2]), "--gt", str(tmp_path / "gt.tum")]) == 0
    table = capsys.readouterr().out
    assert "| icp |" in table
    assert "| kf |" in table
    assert main(["evaluate", *map(str, paths), "--gt", str(tmp_path / "gt.tum"), "--json"]) == 0
    assert set(json.loads(capsys.readouterr().out)) == {"a/icp", "a/kf", "b/icp", "b/kf"}


def test_evaluate_without_matching_stamps_is_exit_3(tmp_path, capsys):
    gt, est = loop(50, np.random.default_rng(9), drift=0.0)
    write_tum(tmp_path / "gt.tum", gt, np.arange(50) * 0.1, HEIGHT_M)
    write_tum(tmp_path / "est.tum", est, 100 + np.arange(50) * 0.1, HEIGHT_M)
    assert main(["evaluate", str(tmp_path / "est.tum"), "--gt", str(tmp_path / "gt.tum")]) == 3
    assert "est.tum: timestamps: got '0 within 0.01 s" in capsys.readouterr().err


def test_localize_output_is_at_the_truths_height_for_plain_evo_ape(tmp_path, capsys):
    seq = tmp_path / "seq"
    args = ["simulate", "world", "--world", "cubicle-loop", "-o", str(seq), "--laser-rate-hz", "10"]
    assert main([*args, "--no-images", "--duration-s", "15"]) == 0
    assert main(["localize", str(seq), "--method", "icp", "-o", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    est, truth = read_tum(tmp_path / "out" / "icp" / "trajectory.tum"), read_tum(seq / "groundtruth.tum")
    assert truth.poses[0, 2, 3] > 0.1  # the laser's height above the floor
    np.testing.assert_allclose(est.poses[:, 2, 3], truth.poses[0, 2, 3], atol=1e-12)
    # Plain evo_ape (no alignment) is then the planar position error, the height adds nothing.
    ref_e = PoseTrajectory3D(poses_se3=list(truth.poses), timestamps=truth.stamps_s)
    est_e = PoseTrajectory3D(poses_se3=list(est.poses), timestamps=est.stamps_s)
    assert est.stamps_s is not None
    gt = planar_at(truth, est.stamps_s)
    planar = float(np.sqrt(np.mean(np.sum((planar_at(est, est.stamps_s)[:, :2] - gt[:, :2]) ** 2, axis=1))))
    assert evo_ape(ref_e, est_e, align=False) == pytest.approx(planar, abs=1e-9)
