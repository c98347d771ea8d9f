"""RANSAC over P3P + Horn triples (Algorithm 1 steps 3-8)."""

from __future__ import annotations

import numpy as np
import pytest

import rigcal.calib.box.ransac as ransac_module
from rigcal.calib.box.horn import horn_batch
from rigcal.calib.box.p3p import P3PPoses, p3p
from rigcal.calib.box.ransac import RansacParams, _iterations_needed, ransac_pose, reprojection_errors
from rigcal.camera import Camera
from rigcal.errors import CalibrationError
from rigcal.geometry import make_T, pose_error, rotvec_to_R

# Camera looking along laser +x, 12 cm above the laser, pitched 5 deg down.
R_BASE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
T_TRUE = make_T(rotvec_to_R([0.087, 0.02, -0.01]) @ R_BASE, [0.02, 0.12, -0.05])


def cam() -> Camera:
    return Camera.from_opencv(
        [[520, 0, 319.5], [0, 520, 239.5], [0, 0, 1]], [-0.15, 0.05, 0.0005, -0.0003, 0.0], 640, 480
    )


def correspondences(rng: np.random.Generator, n: int, sigma_px: float, outliers: float):
    c = cam()
    pts = np.column_stack([rng.uniform(1.2, 4.0, n), rng.uniform(-0.4, 0.4, n)])
    pts[:, 1] *= pts[:, 0]
    px = c.project(np.column_stack([pts, np.zeros(n)]) @ T_TRUE[:3, :3].T + T_TRUE[:3, 3])
    px += rng.normal(0, sigma_px, px.shape)
    bad = rng.random(n) < outliers
    px[bad] += rng.choice([-1, 1], size=(bad.sum(), 2)) * rng.uniform(30, 80, (bad.sum(), 2))
    return c, pts, px, bad


def test_recovers_pose_and_rejects_outliers():
    rng = np.random.default_rng(3)
    c, pts, px, bad = correspondences(rng, 40, 0.5, 0.2)
    res = ransac_pose(c, pts, px, RansacParams(threshold_px=4.0, seed=1))
    rot_deg, trans_m = pose_error(res.T_cam_laser, T_TRUE)
    assert rot_deg < 0.5
    assert trans_m < 0.03
    np.testing.assert_array_equal(res.inliers, ~bad)
    assert res.hypotheses > 0
    assert res.triples_drawn >= RansacParams().min_iterations


def test_noiseless_is_exact():
    rng = np.random.default_rng(4)
    c, pts, px, _ = correspondences(rng, 12, 0.0, 0.0)
    res = ransac_pose(c, pts, px)
    rot_deg, trans_m = pose_error(res.T_cam_laser, T_TRUE)
    assert rot_deg < 1e-6
    assert trans_m < 1e-8
    assert res.inliers.all()


def test_same_seed_same_answer_other_seed_runs():
    rng = np.random.default_rng(5)
    c, pts, px, _ = correspondences(rng, 30, 1.0, 0.3)
    a = ransac_pose(c, pts, px, RansacParams(seed=7))
    b = ransac_pose(c, pts, px, RansacParams(seed=7))
    np.testing.assert_array_equal(a.T_cam_laser, b.T_cam_laser)
    assert a.triples_drawn == b.triples_drawn


def test_too_few_points():
    c = cam()
    with pytest.raises(CalibrationError, match="at least 3"):
        ransac_pose(c, np.zeros((2, 2)), np.zeros((2, 2)))


def test_collinear_laser_points_give_no_consensus():
    rng = np.random.default_rng(6)
    c, _, px, _ = correspondences(rng, 10, 0.0, 0.0)
    line = np.column_stack([np.linspace(1.5, 3.5, 10), np.full(10, 0.3)])
    with pytest.raises(CalibrationError, match="no consensus"):
        ransac_pose(c, line, px, RansacParams(max_iterations=200))


def test_garbage_pixels_give_no_consensus():
    rng = np.random.default_rng(8)
    c, pts, _, _ = correspondences(rng, 20, 0.0, 0.0)
    px = rng.uniform([0, 0], [640, 480], (20, 2))
    with pytest.raises(CalibrationError, match=r"explains \d+ of 20"):
        ransac_pose(c, pts, px, RansacParams(threshold_px=0.5, max_iterations=300))


def test_reprojection_errors_batch_matches_single_and_flags_points_behind():
    rng = np.random.default_rng(9)
    c, pts, px, _ = correspondences(rng, 8, 0.0, 0.0)
    R = np.stack([T_TRUE[:3, :3], rotvec_to_R([0.0, 0.01, 0.0]) @ T_TRUE[:3, :3]])
    t = np.stack([T_TRUE[:3, 3], T_TRUE[:3, 3]])
    batch = reprojection_errors(c, R, t, pts, px)
    for k in range(2):
        np.testing.assert_allclose(batch[k], reprojection_errors(c, R[k], t[k], pts, px))
    assert np.all(batch[0] < 1e-6)
    behind = np.array([[-2.0, 0.0]])
    assert np.isinf(reprojection_errors(c, T_TRUE[:3, :3], T_TRUE[:3, 3], behind, px[:1]))[0]


def test_iteration_bound():
    assert _iterations_needed(1.0, 0.99) == 0
    assert _iterations_needed(0.5, 0.99) == int(np.ceil(np.log(0.01) / np.log(1 - 0.125)))
    assert _iterations_needed(0.0, 0.99) > 10**8


def reference_poses(bearings: np.ndarray, points: np.ndarray) -> P3PPoses:
    """P3P then Horn's method in numpy (horn_batch), the compiled p3p_poses' reference."""
    sol = p3p(bearings, points)
    R, t, ok = horn_batch(sol.depths[:, :, None] * bearings[sol.triple], points[sol.triple])
    return P3PPoses(sol.triple, sol.depths, R, t, ok)


@pytest.mark.parametrize(("seed", "sigma_px", "outliers"), [(3, 0.5, 0.2), (4, 0.0, 0.0), (10, 2.0, 0.4)])
def test_compiled_poses_leave_ransac_unchanged(monkeypatch, seed, sigma_px, outliers):
    rng = np.random.default_rng(seed)
    c, pts, px, _ = correspondences(rng, 40, sigma_px, outliers)
    params = RansacParams(threshold_px=4.0, seed=seed)
    got = ransac_pose(c, pts, px, params)
    monkeypatch.setattr(ransac_module, "p3p_poses", reference_poses)
    ref = ransac_pose(c, pts, px, params)
    assert (got.triples_drawn, got.hypotheses) == (ref.triples_drawn, ref.hypotheses)
    np.testing.assert_array_equal(got.inliers, ref.inliers)
    np.testing.assert_allclose(got.T_cam_laser, ref.T_cam_laser, atol=1e-12, rtol=0)
    np.testing.assert_allclose(got.errors_px, ref.errors_px, atol=1e-9, rtol=0)


def test_compiled_poses_leave_the_box_calibration_unchanged(monkeypatch):
    from rigcal.calib.box.solve import CalibProblem, SolveSettings, solve
    from rigcal.sim.box_session import SessionSpec, generate_session, session_observations

    sess = generate_session(SessionSpec(n_captures=20, wrong_pick_fraction=0.2, seed=5))
    problem = CalibProblem(
        sess.camera, tuple(session_observations(sess)), SolveSettings(uncertainty_checks=False)
    )
    got = solve(problem)
    monkeypatch.setattr(ransac_module, "p3p_poses", reference_poses)
    ref = solve(problem)
    assert (got.ransac.triples_drawn, got.ransac.hypotheses) == (
        ref.ransac.triples_drawn,
        ref.ransac.hypotheses,
    )
    np.testing.assert_array_equal(got.ransac.inliers, ref.ransac.inliers)
    np.testing.assert_allclose(got.ransac.T_cam_laser, ref.ransac.T_cam_laser, atol=1e-12, rtol=0)
    # The refinement stops at its own tolerance, so the last digits of its start move its
    # answer by up to that tolerance (observed 1.5e-10): far below the pose's uncertainty.
    np.testing.assert_array_equal(got.inliers, ref.inliers)
    np.testing.assert_allclose(got.T_cam_laser, ref.T_cam_laser, atol=1e-8, rtol=0)
