"""The odometry-driven Kalman filter (``--kf driven``): ICP's steps drive the prediction,
VO's runs and the wheels' steps are its measurements."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.localize import kalman

DRIVEN = kalman.KF_MODES["driven"]


def _bursts(n=241, dt=0.025, seed=0):
    """A drive that accelerates in bursts (speed and turn rate stepping every 0.3 s), as
    the simulated ones do, and its stamps."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    v = np.repeat(rng.uniform(0.0, 1.2, n // 12 + 1), 12)[:n]
    w = np.repeat(rng.uniform(-1.0, 1.0, n // 12 + 1), 12)[:n]
    poses = [np.zeros(3)]
    for k in range(1, n):
        p = poses[-1]
        poses.append(p + dt * np.array([v[k] * np.cos(p[2]), v[k] * np.sin(p[2]), w[k]]))
    return t, np.array(poses)


def _own(n, sigmas):
    return np.stack([np.diag(np.square(sigmas))] * n)


def _chained(ms):
    T, out = np.eye(3), [np.zeros(3)]
    for m in ms:
        T = T @ se2(m.motion)
        out.append(pose_of(T))
    return np.array(out)


def _noisy(poses, sigma_m, seed=1):
    rng = np.random.default_rng(seed)
    return poses + rng.normal(0.0, sigma_m, poses.shape) * np.array([1.0, 1.0, 0.1])


def test_without_vo_the_filter_is_icp_exactly():
    """ICP alone drives the filter: its poses are ICP's steps chained, at ICP's stamps, to
    rounding, in a drive with bursts of acceleration; the constant-velocity filter departs
    from them there."""
    t, poses = _bursts()
    icp = kalman.increments(t, _noisy(poses, 1e-3), _own(len(t), (1e-3, 1e-3, 1e-4)), source="icp")
    res = kalman.run_filter(icp, DRIVEN)
    assert np.array_equal(res.stamps_s, t)
    assert np.max(np.abs(res.poses - _chained(icp))) < 1e-12
    assert np.all(np.diff(np.trace(res.covariances[:, :2, :2], axis1=1, axis2=2)) >= 0)  # grows as it drives
    cv = kalman.run_filter(icp, kalman.KF_MODES["weighted"])
    assert np.max(np.abs(cv.poses - _chained(icp))) > 1e-4


def test_a_skipped_icp_step_is_crossed_at_the_last_velocity():
    """A scan pair ICP did not measure: the pose crosses it at the step before's velocity."""
    t = np.arange(41) * 0.025
    line = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])  # 1 m/s straight on
    icp = kalman.increments(t, line, _own(len(t), (1e-3, 1e-3, 1e-4)), source="icp")
    res = kalman.run_filter(icp[:20] + icp[21:], DRIVEN)
    assert np.array_equal(res.stamps_s, np.delete(t, 21))
    assert np.allclose(res.poses, np.delete(line, 21, axis=0), atol=1e-9)


def test_a_biased_vo_run_that_fails_the_gate_changes_nothing():
    t, poses = _bursts()
    icp = kalman.increments(t, poses, _own(len(t), (5e-3, 5e-3, 1e-3)), source="icp")
    vo = kalman.increments(t[1::4], poses[1::4], _own(len(t[1::4]), (1e-3, 1e-3, 1e-4)), source="vo")
    bad = vo[20]
    biased = kalman.Increment(bad.t0, bad.t1, bad.motion + np.array([0.1, 0.0, 0.0]), bad.covariance, "vo")
    without = kalman.run_filter(icp + vo[:20] + vo[21:], DRIVEN)
    gated = kalman.run_filter(icp + vo[:20] + [biased] + vo[21:], DRIVEN)
    assert (
        np.max(np.abs(gated.poses - without.poses[np.searchsorted(without.stamps_s, gated.stamps_s)])) < 1e-9
    )
    ungated = kalman.run_filter(
        icp + vo[:20] + [biased] + vo[21:],
        dataclasses.replace(DRIVEN, gate=0.0, vo_forward_window=0, vo_guard=0),
    )
    assert np.max(np.abs(ungated.poses[-1] - without.poses[-1])) > 0.01


def test_good_vo_runs_reduce_a_biased_icps_error():
    """ICP 5 % long with a 1-sigma that covers it; VO runs of a tenth of its error: the
    filter's end is nearer the truth than ICP's, and VO leaves ICP's path alone where it
    agrees with it (an unbiased ICP)."""
    t, poses = _bursts()
    n = len(t)
    long = [poses[0]]
    for k in range(1, n):
        d = pose_of(np.linalg.inv(se2(poses[k - 1])) @ se2(poses[k]))
        long.append(pose_of(se2(long[-1]) @ se2(d * np.array([1.05, 1.0, 1.0]))))
    icp = kalman.increments(t, np.array(long), _own(n, (2e-3, 1e-3, 1e-4)), source="icp")
    vo = kalman.increments(t[1::4], poses[1::4], _own(len(t[1::4]), (2e-4, 2e-4, 1e-4)), source="vo")
    res = kalman.run_filter(icp + vo, DRIVEN)
    icp_end = np.linalg.norm(_chained(icp)[-1, :2] - poses[-1, :2])
    kf_end = np.linalg.norm(res.poses[-1, :2] - poses[-1, :2])
    assert kf_end < 0.5 * icp_end


def test_where_icp_is_open_along_a_corridor_vo_carries_the_motion():
    t = np.arange(201) * 0.025
    line = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    guess = line * np.array([0.5, 1.0, 1.0])  # ICP's forward step is only its initial guess
    icp = kalman.increments(t, guess, _own(len(t), (kalman.OPEN_SIGMA_M, 1e-4, 1e-5)), source="icp")
    vo = kalman.increments(t[::4], line[::4], _own(len(t[::4]), (5e-3, 5e-3, 1e-3)), source="vo")
    res = kalman.run_filter(icp + vo, DRIVEN)
    assert res.poses[-1, 0] == pytest.approx(line[-1, 0], rel=0.02)


def test_the_wheels_are_measurements_where_icp_drives():
    """ICP open along a corridor, the wheels measuring each scan pair: the wheels' forward
    motion, not ICP's guess."""
    t = np.arange(201) * 0.025
    line = np.column_stack([t, np.zeros_like(t), np.zeros_like(t)])
    guess = line * np.array([0.5, 1.0, 1.0])
    icp = kalman.increments(t, guess, _own(len(t), (kalman.OPEN_SIGMA_M, 1e-4, 1e-5)), source="icp")
    wheel = kalman.increments(t, line, kalman.WHEEL_SIGMAS, source="wheel")
    res = kalman.run_filter(icp + wheel, DRIVEN)
    assert res.poses[-1, 0] == pytest.approx(line[-1, 0], rel=0.01)


def test_the_driving_input_is_checked():
    with pytest.raises(ValueError, match="drive 'vo'"):
        kalman.KfParams(drive="vo")
    assert kalman.KF_MODES["fixed"].drive == ""
    assert kalman.KF_MODES["driven"].weights == "covariance"
