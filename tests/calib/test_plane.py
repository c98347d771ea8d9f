"""Plane-based (checkerboard) laser-camera calibration on synthetic board captures."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.board.plane import PlaneObservation, closed_form, point_to_plane, solve_plane
from rigcal.errors import CalibrationError
from rigcal.geometry import pose_error, rotvec_to_R
from rigcal.sim.box_session import default_T_cam_laser

T_TRUE = default_T_cam_laser()


def board_capture(rng: np.random.Generator, k: int, sigma_m: float, n_points: int = 60) -> PlaneObservation:
    """A board 1.5-3 m ahead of the laser, turned up to 40 deg about its vertical and
    tilted up to 30 deg back, crossing the scan plane: its plane in the camera frame and
    noisy returns along its cut with the scan plane."""
    dist = rng.uniform(1.5, 3.0)
    bearing = rng.uniform(-0.4, 0.4)
    centre = dist * np.array([np.cos(bearing), np.sin(bearing), 0.0])
    yaw = bearing + np.pi + rng.uniform(-0.7, 0.7)  # facing the scanner, turned
    tilt = rng.uniform(-0.5, 0.5)
    n_laser = rotvec_to_R([0.0, 0.0, yaw]) @ rotvec_to_R([0.0, tilt, 0.0]) @ np.array([1.0, 0.0, 0.0])
    # The cut with z = 0: direction perpendicular to n's horizontal part.
    u = np.array([-n_laser[1], n_laser[0], 0.0])
    u /= np.linalg.norm(u)
    s = np.linspace(-0.3, 0.3, n_points)
    pts = centre[None, :2] + s[:, None] * u[None, :2]
    r = np.linalg.norm(pts, axis=1)
    pts = pts * ((r + rng.normal(0.0, sigma_m, n_points)) / r)[:, None]
    # Plane in the camera frame: n_c . p_c = d_c.
    n_c = T_TRUE[:3, :3] @ n_laser
    d_c = float(n_c @ (T_TRUE[:3, :3] @ centre + T_TRUE[:3, 3]))
    if d_c < 0:
        n_c, d_c = -n_c, -d_c
    return PlaneObservation(k, f"board{k:02d}", n_c, d_c, pts, distance_sigma_m=1e-4)


def captures(seed: int, n: int = 12, sigma_m: float = 0.01) -> list[PlaneObservation]:
    rng = np.random.default_rng(seed)
    return [board_capture(rng, k, sigma_m) for k in range(n)]


def test_closed_form_is_exact_without_noise():
    T = closed_form(captures(1, sigma_m=0.0))
    rot, trans = pose_error(T, T_TRUE)
    assert rot < 1e-6
    assert trans < 1e-8


def test_true_pose_puts_every_return_on_its_plane():
    for o in captures(2, sigma_m=0.0):
        assert np.abs(point_to_plane(T_TRUE, o)).max() < 1e-12


@pytest.mark.parametrize("seed", [3, 4, 5])
def test_noisy_solve_is_within_its_uncertainty(seed):
    res = solve_plane(captures(seed), range_sigma_m=0.01)
    rot, trans = pose_error(res.T_cam_laser, T_TRUE)
    sig = np.sqrt(np.diag(res.covariance))
    assert rot < 4 * np.degrees(np.linalg.norm(sig[:3]))
    assert trans < 4 * np.linalg.norm(sig[3:])
    assert trans < 0.02
    assert res.inlier_captures.all()
    assert 0.7 < res.residual_scale < 1.3


def test_covariance_is_honest_over_trials():
    from rigcal.calib.report import truth_comparison
    from rigcal.calib.spread import few_dof_factor

    nees = []
    for k in range(30):
        res = solve_plane(captures(100 + k), 0.01)
        # With the noise known (given, and the model right) the covariance before the
        # widening for a noise estimated from few poses is the honest one; the widening is
        # F over chi-square for 2 x 12 - 6 dof, conservative by design here.
        assert res.few_poses_factor == pytest.approx(few_dof_factor(2 * 12 - 6))
        nees.append(truth_comparison(res.T_cam_laser, res.covariance / res.few_poses_factor, T_TRUE)["nees"])
    # Mean of 30 chi-square(6): 95 % band about [4.9, 7.2]; allow a little more.
    assert 4.5 < np.mean(nees) < 7.8


def test_a_capture_with_a_wrong_plane_is_rejected():
    obs = captures(6)
    bad = obs[3]
    obs[3] = PlaneObservation(bad.capture, bad.name, bad.normal_cam, bad.distance_m + 0.2, bad.points_laser)
    res = solve_plane(obs, 0.01)
    assert not res.inlier_captures[3]
    assert res.inlier_captures.sum() == len(obs) - 1
    # The outlier has no pull left: the answer is the solve without it.
    clean = solve_plane(obs[:3] + obs[4:], 0.01)
    assert pose_error(res.T_cam_laser, clean.T_cam_laser)[1] < 1e-5
    assert pose_error(res.T_cam_laser, T_TRUE)[1] < 0.03


def test_too_few_captures():
    with pytest.raises(CalibrationError, match="at least 5"):
        solve_plane(captures(7, n=4))


def test_parallel_boards_are_unobservable_and_named():
    obs = captures(8, n=6)
    same = [PlaneObservation(o.capture, o.name, obs[0].normal_cam, o.distance_m, o.points_laser) for o in obs]
    with pytest.raises(CalibrationError, match=r"board00, board01.*parallel"):
        solve_plane(same)


# --- noise from the data, stable verdicts, spread -------------------------------------------------
def repeated_pose_captures(seed: int, offsets_m: list[float], repeats: int = 3, sigma_m: float = 0.01):
    """Board poses each captured `repeats` times with fresh range noise; pose k's plane is
    offset by offsets_m[k] (a bad board pose or a wrong cut), shared by its repeats."""
    rng = np.random.default_rng(seed)
    out = []
    for k, off in enumerate(offsets_m):
        clean = board_capture(rng, k, 0.0)
        for j in range(repeats):
            p = clean.points_laser
            r = np.linalg.norm(p, axis=1)
            noisy = p * ((r + rng.normal(0.0, sigma_m, len(p))) / r)[:, None]
            out.append(
                PlaneObservation(
                    len(out),
                    f"pose{k}_{j}",
                    clean.normal_cam,
                    clean.distance_m + off,
                    noisy,
                    distance_sigma_m=0.004,
                )
            )
    return out


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_captures_at_one_pose_get_one_verdict(seed):
    offsets = [0.0] * 7 + [0.015, 0.025, 0.1]
    res = solve_plane(repeated_pose_captures(seed, offsets), None)
    verdicts = res.inlier_captures.reshape(len(offsets), 3)
    assert (verdicts == verdicts[:, :1]).all(), verdicts
    assert len(set(res.pose_group.tolist())) == len(offsets)
    assert verdicts[:7].all()
    assert not verdicts[-1].any()


@pytest.mark.parametrize("sigma", [0.015, 0.02])
def test_range_noise_is_estimated_and_the_covariance_stays_honest(sigma):
    from rigcal.calib.report import truth_comparison

    nees, est = [], []
    for k in range(12):
        res = solve_plane(captures(300 + k, n=15, sigma_m=sigma), None)
        est.append(res.range_noise.sigma_m)
        assert res.noise.range_sigma_m == res.range_noise.sigma_m
        nees.append(truth_comparison(res.T_cam_laser, res.covariance / res.few_poses_factor, T_TRUE)["nees"])
    assert np.median(est) == pytest.approx(sigma, rel=0.1)
    # Mean of 12 chi-square(6) draws: 95 % of such means lie within about [3.9, 8.3].
    assert 3.5 < np.mean(nees) < 8.5


def test_assumed_noise_too_small_is_absorbed_by_the_per_capture_error():
    """The data have 3 cm of range noise, the solve is told 5 mm: the captures disagree
    beyond chance, a per-capture error is estimated from them, and the covariance stays
    honest (before, a chi-square gate at the assumed noise threw most captures out)."""
    from rigcal.calib.report import truth_comparison

    nees = []
    for k in range(8):
        res = solve_plane(captures(400 + k, n=20, sigma_m=0.03), range_sigma_m=0.005)
        assert res.noise.capture_sigma_m > 0.002
        assert res.inlier_captures.sum() >= 19
        nees.append(truth_comparison(res.T_cam_laser, res.covariance, T_TRUE)["nees"])
    assert np.mean(nees) < 10.0


# --- planes of one rigid target posed by one PnP (pose_key) ----------------------------------
def v_target_views(seed: int, n: int = 10, range_sigma_m: float = 0.002, keyed: bool = True):
    """n views of a two-faced V (faces at 90 deg through a common edge crossing the scan
    plane), each posed by one PnP whose error (0.3 deg, 3 mm) moves both faces' planes
    together; returns with small range noise, so the shared pose error dominates."""
    from rigcal.calib.board.plane import PlaneObservation

    rng = np.random.default_rng(seed)
    C = np.diag([np.radians(0.3) ** 2] * 3 + [0.003**2] * 3)
    out = []
    for i in range(n):
        dist, bearing = rng.uniform(1.5, 2.5), rng.uniform(-0.3, 0.3)
        o = dist * np.array([np.cos(bearing), np.sin(bearing), 0.0])
        R = rotvec_to_R([0.0, 0.0, bearing + rng.uniform(-0.4, 0.4)]) @ rotvec_to_R(
            [rng.uniform(-0.4, 0.4), rng.uniform(-0.4, 0.4), 0.0]
        )
        w, dt = rng.multivariate_normal(np.zeros(6), C).reshape(2, 3)
        o_c = T_TRUE[:3, :3] @ o + T_TRUE[:3, 3]
        for k, a in enumerate((np.pi / 4, -np.pi / 4)):
            n_l = R @ np.array([-np.cos(a), np.sin(a), 0.0])
            u = np.cross(n_l, [0.0, 0.0, 1.0])
            u /= np.linalg.norm(u)
            s = np.linspace(0.03, 0.3, 40) * (1 if k == 0 else -1) * np.sign(u[1] or 1.0)
            pts = o[:2] + s[:, None] * u[:2]
            r = np.linalg.norm(pts, axis=1)
            pts = pts * ((r + rng.normal(0.0, range_sigma_m, len(r))) / r)[:, None]
            n_c = rotvec_to_R(w) @ T_TRUE[:3, :3] @ n_l
            origin = o_c + dt
            d = float(n_c @ origin)
            if d < 0:
                n_c, d = -n_c, -d
            key = f"view{i}" if keyed else None
            out.append(PlaneObservation(2 * i + k, f"view{i}/{k}", n_c, d, pts, 0.001, origin, C, key))
    return out


@pytest.mark.slow
def test_planes_of_one_pose_are_whitened_together_and_the_covariance_stays_honest():
    """With the shared pose error taken as one error (pose_key), the NEES over trials is
    about 6 (the 95 % band of a mean of 16 chi-square 6-dof values is 4.3-7.7)."""
    from rigcal.calib.report import truth_comparison

    nees = []
    for seed in range(16):
        obs = v_target_views(300 + seed)
        res = solve_plane(obs, range_sigma_m=0.002, use_ransac=False, uncertainty_checks=False)
        nees.append(truth_comparison(res.T_cam_laser, res.covariance_model, T_TRUE)["nees"])
    assert 4.0 < np.mean(nees) < 8.5


def test_joint_covariance_couples_only_planes_of_one_pose():
    from rigcal.calib.board.plane import PlaneNoise, _joint_cov, capture_cov, capture_line, pose_units

    obs = v_target_views(7, n=3)
    assert [list(u) for u in pose_units(obs)] == [[0, 1], [2, 3], [4, 5]]
    lines = [capture_line(o.points_laser) for o in obs]
    noise = PlaneNoise(0.002)
    J = _joint_cov(T_TRUE, obs[:2], lines[:2], noise)
    assert np.allclose(J[:2, :2], capture_cov(T_TRUE, obs[0], lines[0], noise))
    assert np.allclose(J[2:, 2:], capture_cov(T_TRUE, obs[1], lines[1], noise))
    assert np.abs(J[:2, 2:]).max() > 1e-7
    assert np.allclose(J[:2, 2:], J[2:, :2].T)
    assert [list(u) for u in pose_units(v_target_views(7, n=2, keyed=False))] == [[0], [1], [2], [3]]
