"""The inputs' step covariances for the Kalman filter: ICP's from its Hessian (inflated
along a corridor), VO's from its tracks' fit and its scale's votes."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rigcal.lines import extract_lines, return_labels
from rigcal.localize.icp import IcpParams, icp
from rigcal.localize.icp_covariance import OPEN_SIGMA_M, icp_covariance
from rigcal.localize.line_normals import line_normals
from rigcal.localize.vo import ScaleEstimate, essential_covariance, run_covariance
from rigcal.scan import Scan
from rigcal.sim.raycast import cast_scan

ANGLES = np.radians(np.arange(-135, 135.001, 0.25))
ROOM = np.array(
    [[[-3, -2], [5, -2]], [[5, -2], [5, 3]], [[5, 3], [-3, 3]], [[-3, 3], [-3, -2]], [[1, 0.5], [1.6, 1.2]]],
    dtype=float,
)

CHI2_99_3DOF = 11.34


def _scan(walls: np.ndarray, pose: np.ndarray, rng: np.random.Generator, sigma_m: float = 0.01) -> Scan:
    c, s = np.cos(pose[2]), np.sin(pose[2])
    r = cast_scan((walls - pose[:2]) @ np.array([[c, s], [-s, c]]).T, ANGLES, 30.0)
    r = np.where(np.isfinite(r), r + rng.normal(0, sigma_m, len(r)), 0.0)
    return Scan(ANGLES, r, 0.05, 30.0)


def _icp_with_covariance(walls, b, rng, sigma_m=0.01):
    A, B = _scan(walls, np.zeros(3), rng, sigma_m), _scan(walls, b, rng, sigma_m)
    pa, pb = A.points[A.valid], B.points[B.valid]
    normals = line_normals(pa, return_labels(A, extract_lines(A)))
    res = icp(
        pa,
        pb,
        initial=b + np.array([0.01, -0.01, 0.005]),
        model_normals=normals,
        params=IcpParams(max_iterations=100),
    )
    # The covariance's pairs: each data point's nearest model return at the solution.
    c, s = np.cos(res.pose[2]), np.sin(res.pose[2])
    nearest = cKDTree(pa).query(pb @ np.array([[c, s], [-s, c]]) + res.pose[:2])[1]
    return res, icp_covariance(pa, pb, res.pose, nearest, normals, 0.3, 0.01)


def test_icp_covariance_matches_its_errors_in_a_room():
    """Monte Carlo: the errors' NEES under the covariance averages 3 for a consistent
    3-dof estimate; the Hessian's is a little optimistic (about 6 here, the pairs' noise
    is not all independent), the residuals' spread about each nearest return instead of
    the lines would make it 15."""
    rng = np.random.default_rng(3)
    nees = []
    for _ in range(40):
        b = np.array([rng.uniform(-0.05, 0.05), rng.uniform(-0.05, 0.05), rng.uniform(-0.03, 0.03)])
        res, cov = _icp_with_covariance(ROOM, b, rng)
        e = res.pose - b
        nees.append(float(e @ np.linalg.solve(cov, e)))
    assert 1.0 < np.mean(nees) < 10.0
    assert np.mean(np.array(nees) < CHI2_99_3DOF) > 0.7


def test_icp_covariance_grows_with_the_range_noise():
    rng = np.random.default_rng(4)
    b = np.array([0.02, 0.01, 0.01])
    _, small = _icp_with_covariance(ROOM, b, rng, 0.005)
    _, large = _icp_with_covariance(ROOM, b, rng, 0.02)
    assert np.trace(large[:2, :2]) > 8 * np.trace(small[:2, :2])  # 16x in variance, 4x noise


def test_icp_covariance_opens_along_a_corridor_only():
    rng = np.random.default_rng(5)
    corridor = np.array([[[-20, -1], [20, -1]], [[-20, 1], [20, 1]]], dtype=float)
    b = np.array([0.05, 0.01, 0.002])
    _, cov = _icp_with_covariance(corridor, b, rng)
    assert np.sqrt(cov[0, 0]) == pytest.approx(OPEN_SIGMA_M, rel=0.01)  # along: unmeasured
    assert np.sqrt(cov[1, 1]) < 0.005  # across: the walls pin it
    assert np.sqrt(cov[2, 2]) < 0.005


def test_icp_covariance_needs_three_pairs():
    pts = np.array([[1.0, 0.0], [1.0, 0.1]])
    cov = icp_covariance(pts, pts, np.zeros(3), np.array([0, 1]), None, 0.3, 0.01)
    assert np.isnan(cov).all()


def _bearings(rng, n, R, t, noise_rad):
    P = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1, 1, n), rng.uniform(3, 8, n)])
    b1 = P / np.linalg.norm(P, axis=1, keepdims=True)
    P2 = P @ R.T + t
    b2 = P2 / np.linalg.norm(P2, axis=1, keepdims=True)
    b1 = b1 + rng.normal(0, noise_rad, b1.shape)
    b2 = b2 + rng.normal(0, noise_rad, b2.shape)
    return b1 / np.linalg.norm(b1, axis=1, keepdims=True), b2 / np.linalg.norm(b2, axis=1, keepdims=True)


def test_essential_covariance_shrinks_with_more_tracks_and_grows_with_noise():
    rng = np.random.default_rng(6)
    R, t = np.eye(3), np.array([1.0, 0.0, 0.1]) / np.hypot(1.0, 0.1)
    covs = {}
    for n, noise in ((50, 1e-3), (400, 1e-3), (400, 4e-3)):
        b1, b2 = _bearings(rng, n, R, 0.3 * t, noise)
        covs[n, noise] = np.trace(essential_covariance(R, t, b1, b2, 500.0))
    assert covs[400, 1e-3] < 0.3 * covs[50, 1e-3]
    assert covs[400, 4e-3] > 5 * covs[400, 1e-3]


def test_a_run_without_a_scale_is_open_along_its_travel_only():
    """The laser's x axis is the camera's z here: a run forward along it with no scale
    has a 10 m 1-sigma forward, and the tracks' precision across and in yaw."""
    T_cam_laser = np.array([[0, -1, 0, 0], [0, 0, -1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], dtype=float)
    t = np.array([0.0, 0.0, -0.1])  # x2 = R x1 + t: the camera moved 0.1 m along its z
    rel = np.diag([1e-8, 1e-8, 1e-8, 1e-6, 1e-6])
    cov = run_covariance(np.eye(3), t, rel, OPEN_SIGMA_M, T_cam_laser)
    assert np.sqrt(cov[0, 0]) == pytest.approx(OPEN_SIGMA_M, rel=1e-3)
    assert np.sqrt(cov[1, 1]) < 1e-3
    scaled = run_covariance(np.eye(3), t, rel, 0.002, T_cam_laser)
    assert np.sqrt(scaled[0, 0]) == pytest.approx(0.002, rel=1e-2)


def test_scale_sigma_from_the_votes_and_the_search_spacing():
    votes = np.array([0.10, 0.11, 0.09, 0.10, 0.12, 0.08, 0.10, 0.10, 0.5])
    est = ScaleEstimate(0.10, 8, votes)
    assert 0.002 < est.sigma(1e-4) < 0.02
    same = ScaleEstimate(0.10, 8, np.full(8, 0.10))
    assert same.sigma(0.01) == pytest.approx(0.01 / np.sqrt(12))
    assert np.isnan(ScaleEstimate(float("nan"), 0, votes).sigma(0.01))


def test_laser_odometry_carries_each_steps_covariance():
    from rigcal.localize.odometry import icp_odometry

    rng = np.random.default_rng(7)
    poses = [np.array([0.02 * k, 0.01 * k, 0.005 * k]) for k in range(4)]
    od = icp_odometry([_scan(ROOM, p, rng) for p in poses])
    assert od.covariance is not None
    assert od.covariance.shape == (4, 3, 3)
    assert np.isnan(od.covariance[0]).all()  # the first scan ends no step
    sigmas = np.sqrt(np.diagonal(od.covariance[1:], axis1=1, axis2=2))
    assert np.all((sigmas > 1e-5) & (sigmas < 5e-3))


def test_laser_odometry_without_the_covariances_has_the_same_poses():
    """``covariance=False`` (the targetless check's odometry) leaves the steps' covariances
    out (NaN) and changes nothing else."""
    from rigcal.localize.odometry import icp_odometry

    rng = np.random.default_rng(7)
    scans = [_scan(ROOM, np.array([0.02 * k, 0.01 * k, 0.005 * k]), rng) for k in range(4)]
    with_cov, without = icp_odometry(scans), icp_odometry(scans, covariance=False)
    np.testing.assert_array_equal(without.poses, with_cov.poses)
    np.testing.assert_array_equal(without.degeneracy, with_cov.degeneracy)
    assert without.covariance is not None
    assert np.isnan(without.covariance).all()
