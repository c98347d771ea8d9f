"""Levenberg-Marquardt refinement and its covariance (Algorithm 1 step 9)."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.box.refine import (
    EndpointSet,
    NoiseModel,
    RefineParams,
    loss_weights,
    refine_pose,
    whitened_residuals_and_jacobian,
    whitening,
)
from rigcal.camera import Camera
from rigcal.errors import CalibrationError
from rigcal.geometry import R_to_rotvec, make_T, pose_error, rotvec_to_R

R_BASE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])
T_TRUE = make_T(rotvec_to_R([0.087, 0.02, -0.01]) @ R_BASE, [0.02, 0.12, -0.05])


def cam() -> Camera:
    return Camera.from_opencv(
        [[520, 0, 319.5], [0, 520, 239.5], [0, 0, 1]], [-0.15, 0.05, 0.0005, -0.0003, 0.0], 640, 480
    )


def measurements(rng: np.random.Generator, n_caps: int, noise: NoiseModel, sigma_end_m: float = 0.004):
    """Box ends of n_caps captures with anisotropic laser-end noise and isotropic pick noise."""
    c = cam()
    pts, covs, caps, ends = [], [], [], []
    for k in range(n_caps):
        centre = np.array([rng.uniform(1.2, 4.0), 0.0])
        centre[1] = rng.uniform(-0.35, 0.35) * centre[0]
        yaw = rng.uniform(-0.8, 0.8) + np.arctan2(centre[1], centre[0]) + np.pi / 2
        u = np.array([np.cos(yaw), np.sin(yaw)])
        n = np.array([-u[1], u[0]])
        cov = sigma_end_m**2 * np.outer(u, u) + (0.2 * sigma_end_m) ** 2 * np.outer(n, n)
        for j, s in enumerate((-0.3, 0.3)):
            pts.append(centre + s * u)
            covs.append(cov)
            caps.append(k)
            ends.append(j)
    pts = np.array(pts)
    covs = np.array(covs)
    px = c.project(np.column_stack([pts, np.zeros(len(pts))]) @ T_TRUE[:3, :3].T + T_TRUE[:3, 3])
    noisy_pts = pts + np.array([rng.multivariate_normal(np.zeros(2), cv) for cv in covs])
    px = px + rng.normal(0, noise.pick_sigma_px, px.shape)
    return c, EndpointSet(noisy_pts, px, covs, np.array(caps), np.array(ends))


def perturbed(T, rng, angle=0.02, shift=0.02):
    return make_T(rotvec_to_R(rng.normal(0, angle, 3)) @ T[:3, :3], T[:3, 3] + rng.normal(0, shift, 3))


def test_noiseless_recovery_from_a_perturbed_start():
    rng = np.random.default_rng(1)
    noise = NoiseModel(pick_sigma_px=1.0)
    c, m = measurements(rng, 10, noise, sigma_end_m=0.004)
    exact = c.project(np.column_stack([m.points_laser, np.zeros(20)]) @ T_TRUE[:3, :3].T + T_TRUE[:3, 3])
    m = EndpointSet(m.points_laser, exact, m.cov_laser, m.capture, m.end)
    res = refine_pose(c, perturbed(T_TRUE, rng), m, noise)
    rot, trans = pose_error(res.T_cam_laser, T_TRUE)
    assert rot < 1e-7
    assert trans < 1e-9
    assert res.dof == 2 * 20 - 6


def test_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    noise = NoiseModel()
    c, m = measurements(rng, 5, noise)
    T = perturbed(T_TRUE, rng)
    W = whitening(c, T, m, noise)
    r0, J = whitened_residuals_and_jacobian(c, T, m, W)
    h = 1e-6
    num = np.zeros_like(J)
    for i in range(6):
        dx = np.zeros(6)
        dx[i] = h
        Tp = make_T(rotvec_to_R(dx[:3]) @ T[:3, :3], T[:3, 3] + dx[3:])
        Tm = make_T(rotvec_to_R(-dx[:3]) @ T[:3, :3], T[:3, 3] - dx[3:])
        num[:, i] = (
            whitened_residuals_and_jacobian(c, Tp, m, W)[0] - whitened_residuals_and_jacobian(c, Tm, m, W)[0]
        ) / (2 * h)
    np.testing.assert_allclose(J, num, rtol=1e-5, atol=1e-4)
    assert r0.shape == (2 * len(m.points_laser),)


def test_whitening_inverts_the_pixel_covariance():
    rng = np.random.default_rng(3)
    noise = NoiseModel(pick_sigma_px=0.7)
    c, m = measurements(rng, 3, noise)
    W = whitening(c, T_TRUE, m, noise)
    for k in range(len(W)):
        cov = np.linalg.inv(W[k].T @ W[k])
        assert np.all(np.linalg.eigvalsh(cov) >= 0.7**2 - 1e-9)


def test_covariance_is_honest_over_trials():
    """Mean NEES over seeded trials lies in a wide chi-square(6) band; errors scale with sigma."""
    rng = np.random.default_rng(4)
    noise = NoiseModel(pick_sigma_px=1.0)
    nees = []
    for _ in range(60):
        c, m = measurements(rng, 12, noise)
        res = refine_pose(c, perturbed(T_TRUE, rng), m, noise)
        d = R_to_rotvec(T_TRUE[:3, :3] @ res.T_cam_laser[:3, :3].T)
        e = T_TRUE[:3, 3] - res.T_cam_laser[:3, 3]
        x = np.concatenate([d, e])
        nees.append(x @ np.linalg.solve(res.covariance, x))
        assert 0.5 < res.residual_scale < 1.6
    assert 4.5 < np.mean(nees) < 8.0


def test_robust_loss_resists_an_outlier():
    rng = np.random.default_rng(5)
    noise = NoiseModel(pick_sigma_px=1.0)
    c, m = measurements(rng, 12, noise)
    px = m.pixels.copy()
    px[3] += [25.0, -20.0]
    bad = EndpointSet(m.points_laser, px, m.cov_laser, m.capture, m.end)
    plain = refine_pose(c, T_TRUE, bad, noise)
    robust = refine_pose(c, T_TRUE, bad, noise, RefineParams(loss="cauchy", loss_scale=2.0))
    assert pose_error(robust.T_cam_laser, T_TRUE)[1] < pose_error(plain.T_cam_laser, T_TRUE)[1]


def test_loss_weights():
    r = np.array([0.0, 1.0, 4.0])
    np.testing.assert_allclose(loss_weights(r, "linear", 2.0), 1.0)
    np.testing.assert_allclose(loss_weights(r, "huber", 2.0), [1, 1, 0.5])
    np.testing.assert_allclose(loss_weights(r, "cauchy", 1.0), [1, 0.5, 1 / 17])


def test_too_few_ends_and_unknown_loss():
    rng = np.random.default_rng(6)
    c, m = measurements(rng, 1, NoiseModel())
    with pytest.raises(CalibrationError, match="at least 4 box ends"):
        refine_pose(c, T_TRUE, m)
    c, m = measurements(rng, 3, NoiseModel())
    with pytest.raises(ValueError, match="loss"):
        refine_pose(c, T_TRUE, m, params=RefineParams(loss="tukey"))
