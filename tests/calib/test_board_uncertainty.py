"""The board method's covariance with few poses and with the camera's own uncertainty."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2, f

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.plane import solve_plane
from rigcal.calib.board.session import board_pose, plane_observation
from rigcal.calib.spread import few_dof_factor, propagated_covariance
from rigcal.errors import InputError
from rigcal.geometry import make_T, rotvec_to_R, tangent_delta
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session


def test_few_dof_factor_is_the_f_over_chi_square_ratio():
    assert few_dof_factor(3) == pytest.approx(6 * f.ppf(0.95, 6, 3) / chi2.ppf(0.95, 6))
    assert few_dof_factor(3) == pytest.approx(4.26, abs=0.01)
    values = [few_dof_factor(d) for d in (1, 3, 9, 13, 33, 1000)]
    assert all(a > b for a, b in itertools.pairwise(values))
    assert values[-1] == pytest.approx(1.0, abs=0.01)
    assert few_dof_factor(0) == few_dof_factor(1)


def test_f_factor_makes_a_student_t_error_covered_95_percent():
    """An estimate whose noise scale comes from nu dof: its d^2 under the estimated scale,
    widened by the factor, is inside the chi-square 95 % bound 95 % of the time."""
    rng = np.random.default_rng(0)
    nu, trials = 4, 20000
    x = rng.normal(size=(trials, 6))
    s2 = rng.chisquare(nu, size=trials) / nu  # the estimated variance factor
    d2 = (x**2).sum(axis=1) / (s2 * few_dof_factor(nu))
    assert np.mean(d2 <= chi2.ppf(0.95, 6)) == pytest.approx(0.95, abs=0.01)


def test_propagated_covariance_of_a_linear_answer_is_exact():
    a = np.array([[0.01, 0.0, 0.02, 0.1, 0.0, -0.3], [0.0, 0.03, 0.0, 0.0, 0.2, 0.1]])
    values, sigmas = np.array([1.0, 2.0]), np.array([0.5, 0.1])
    T = np.eye(4)

    def changed(v: np.ndarray) -> np.ndarray:
        x = (v - values) @ a
        return make_T(rotvec_to_R(x[:3]), x[3:])

    cov = propagated_covariance(changed, T, values, np.diag(sigmas**2))
    expect = sum(s**2 * np.outer(g, g) for g, s in zip(a, sigmas, strict=True))
    # The tangent delta is T -> changed, i.e. minus the move: the outer product is the same.
    assert np.allclose(cov, expect, atol=1e-8)
    assert np.allclose(propagated_covariance(changed, T, values, np.zeros((2, 2))), 0.0)
    # Correlated inputs: J cov J^T whatever the covariance's axes.
    full = np.array([[0.25, 0.04], [0.04, 0.01]])
    assert np.allclose(propagated_covariance(changed, T, values, full), a.T @ full @ a, atol=1e-8)


@pytest.fixture(scope="module")
def session_file(tmp_path_factory) -> Path:
    sim = generate_board_session(BoardSpec(n_captures=8, seed=4))
    return write_board_session(sim, tmp_path_factory.mktemp("unc") / "s") / "board_session.yaml"


def test_camera_share_follows_one_intrinsic_through_a_whole_resolve(session_file):
    """With a sigma on fx alone, the propagated covariance is g g^T for g the move of the
    answer when fx changes by 1 sigma; a full re-solve under fx + sigma moves it by g."""
    base = calibrate_board(session_file)
    cam = base.session.camera
    sig = np.zeros(len(cam.intrinsics))
    sig[0] = 0.5
    cal = calibrate_board(session_file, intrinsics_sigma=sig.tolist())
    camera = cal.report["uncertainty"]["camera"]
    assert camera["included"]
    assert len(camera["variance_share"]) == 6
    assert all(0.0 <= s <= 1.0 for s in camera["variance_share"])
    added = cal.result.covariance - base.result.covariance
    intr = cam.intrinsics.copy()
    intr[0] += sig[0]
    moved_cam = replace(cam, intrinsics=intr)
    obs = []
    for i, o in enumerate(base.session.observations):
        T_cb, cov, _ = board_pose(moved_cam, base.session.board, base.session.corners_px[i], 0.3)
        obs.append(replace(plane_observation(i, o.name, T_cb, cov, o.points_laser)))
    res = solve_plane(obs, uncertainty_checks=False, fit_range_bias=True)
    g = tangent_delta(res.T_cam_laser, base.result.T_cam_laser)
    sigma_prop = np.sqrt(np.diag(added))
    big = sigma_prop > 0.2 * sigma_prop.max()
    assert np.allclose(np.abs(g)[big], sigma_prop[big], rtol=0.15)


def test_without_sigmas_the_report_says_the_camera_is_missing(session_file):
    cal = calibrate_board(session_file)
    cam = cal.report["uncertainty"]["camera"]
    assert cam["included"] is False
    assert "--intrinsics-sigma" in cam["note"]


def test_a_sigma_list_of_the_wrong_length_is_refused(session_file):
    with pytest.raises(InputError, match=r"--intrinsics-sigma: got '1,2'; expected 9 non-negative numbers"):
        calibrate_board(session_file, intrinsics_sigma=[1.0, 2.0])
    with pytest.raises(InputError, match="expected 9 non-negative"):
        calibrate_board(session_file, intrinsics_sigma=[-1.0] + [0.0] * 8)


def test_few_poses_widen_the_covariance_and_say_so(tmp_path):
    sim = generate_board_session(BoardSpec(n_captures=6, seed=9))
    path = write_board_session(sim, tmp_path / "s") / "board_session.yaml"
    cal = calibrate_board(path)
    s = cal.report["summary"]
    assert s["poses_used"] == 6
    assert s["noise_dof"] == 2 * 6 - 7
    assert s["few_poses_factor"] == pytest.approx(few_dof_factor(5), rel=1e-3)
    assert np.allclose(cal.result.covariance, cal.result.covariance_model * few_dof_factor(5)) or (
        cal.result.spread is not None and cal.result.spread.scale > 1.5
    )
    assert any(
        w.startswith("the session is too small to trust: 6 board poses") for w in cal.report["warnings"]
    )
    assert cal.report["uncertainty"]["scaled_to_spread"] is bool(
        cal.result.spread is not None and cal.result.spread.scale > 1.5
    )


def test_handheld_repeats_are_grouped_as_one_pose(tmp_path):
    """A hand-held board's repeats (1-3 deg, 2-5 cm apart) share a pose group, so they get
    one verdict and count as one pose in the dof of the noise estimate."""
    sim = generate_board_session(BoardSpec(n_captures=7, seed=3, repeats=3, handheld=True))
    moved = [
        np.degrees(
            np.arccos(np.clip(np.trace(a.T_laser_board[:3, :3].T @ b.T_laser_board[:3, :3]) / 2 - 0.5, -1, 1))
        )
        for a, b in zip(sim.captures[::3], sim.captures[1::3], strict=True)
    ]
    assert min(moved) >= 1.0
    assert max(moved) <= 3.0 + 1e-9
    path = write_board_session(sim, tmp_path / "s") / "board_session.yaml"
    res = calibrate_board(path).result
    groups = res.pose_group.reshape(-1, 3)
    together = (groups == groups[:, :1]).all(axis=1)
    assert together.sum() >= 6
    verdicts = res.inlier_captures
    for g in np.unique(res.pose_group):
        assert len(set(verdicts[res.pose_group == g].tolist())) == 1
    assert res.poses_used <= 8
