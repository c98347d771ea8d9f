"""The gyroscope in the Kalman filter: its yaw steps with the bias as a random-walk state."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.localize import kalman


def _drive(rng, n=800, dt=0.025, speed=1.0):
    t = np.arange(n + 1) * dt
    w = 0.3 * np.sin(t / 3.0) if speed else np.zeros(n + 1)
    yaw = np.r_[0.0, np.cumsum(w[1:] * dt)]
    xy = np.zeros((n + 1, 2))
    for k in range(1, n + 1):
        xy[k] = xy[k - 1] + speed * dt * np.array([np.cos(yaw[k - 1]), np.sin(yaw[k - 1])])
    return t, np.column_stack([xy, yaw])


def _icp(rng, t, truth, sigmas):
    out = []
    for k in range(1, len(t)):
        d = pose_of(np.linalg.inv(se2(truth[k - 1])) @ se2(truth[k])) + sigmas * rng.standard_normal(3)
        out.append(kalman.Increment(t[k - 1], t[k], d, np.diag(np.square(sigmas)), "icp"))
    return out


def _gyro(rng, t, truth, bias, every=4):
    at = t[::every]
    yaw = np.diff(truth[::every, 2]) + bias * np.diff(at)
    yaw += np.radians(0.005) * np.sqrt(np.diff(at)) * rng.standard_normal(len(at) - 1)
    return kalman.gyro_increments(at, yaw)


def test_gyro_steps_measure_the_yaw_alone():
    ms = kalman.gyro_increments(np.array([0.0, 0.1, 0.2, 0.3]), np.array([0.01, np.nan, -0.02]))
    assert [(m.t0, m.t1, m.source) for m in ms] == [(0.0, 0.1, "gyro"), (0.2, 0.3, "gyro")]
    np.testing.assert_array_equal(ms[1].motion, [0.0, 0.0, -0.02])
    assert ms[0].covariance[0, 0] == ms[0].covariance[1, 1] == kalman.OPEN_SIGMA_M**2
    assert ms[0].covariance[2, 2] == pytest.approx(kalman.GYRO_NOISE**2 * 0.1)


# Each mode with the gyro fused (icp-first makes it the guard's witness alone).
FUSED = {
    m: dataclasses.replace(kalman.KF_MODES[m], gyro_witness=False, gyro_fused=True) for m in kalman.KF_MODES
}


@pytest.mark.parametrize("mode", ["weighted", "icp-first"])
def test_the_gyro_takes_the_heading_where_icp_turns_noisily(mode):
    """ICP's yaw white at 0.2 deg a step (its heading walks by degrees over 20 s): with the
    gyro (0.05 deg/s bias) the filter's heading error is less than half of ICP's alone."""
    rng = np.random.default_rng(1)
    t, truth = _drive(rng)
    icp = _icp(rng, t, truth, np.array([0.002, 0.002, np.radians(0.2)]))
    gyro = _gyro(rng, t, truth, np.radians(0.05))
    errs = []
    for ms in (icp, icp + gyro):
        r = kalman.path_at(kalman.run_filter(ms, FUSED[mode]), t)
        errs.append(float(np.sqrt(np.mean((r.poses[:, 2] - truth[:, 2]) ** 2))))
    assert errs[1] < 0.5 * errs[0]


def test_the_bias_is_learned_where_the_rig_stands_still():
    """A rig standing for 20 s, ICP's yaw good to 0.002 deg a step: the bias (0.1 deg/s)
    comes out to 0.005 deg/s, and the heading stays within ICP's reach (its walk over the
    800 steps: 0.057 deg 1-sigma)."""
    rng = np.random.default_rng(2)
    t, truth = _drive(rng, speed=0.0)
    icp = _icp(rng, t, truth, np.array([0.0005, 0.0005, np.radians(0.002)]))
    bias = np.radians(0.1)
    r = kalman.run_filter(icp + _gyro(rng, t, truth, bias), kalman.KF_MODES["weighted"])
    assert abs(r.gyro_bias - bias) < np.radians(0.005)
    assert abs(r.poses[-1, 2]) < np.radians(0.2)


def test_without_gyro_steps_the_filter_is_the_same_to_the_bit():
    """The gyro's settings change nothing where no gyro step is given (its state is added
    at its first step only)."""
    rng = np.random.default_rng(3)
    t, truth = _drive(rng, n=200)
    icp = _icp(rng, t, truth, np.array([0.002, 0.002, np.radians(0.05)]))
    for mode in ("weighted", "icp-first"):
        a = kalman.run_filter(icp, kalman.KF_MODES[mode])
        other = dataclasses.replace(
            kalman.KF_MODES[mode], gyro_noise=1.0, gyro_bias_sigma=1.0, gyro_bias_walk=1.0
        )
        b = kalman.run_filter(icp, other)
        assert np.array_equal(a.poses, b.poses)
        assert np.array_equal(a.covariances, b.covariances)
        assert np.isnan(a.gyro_bias)


def test_bad_gyro_settings_are_refused():
    with pytest.raises(ValueError, match=r"gyro_noise 0\.0"):
        kalman.KfParams(gyro_noise=0.0)
    with pytest.raises(ValueError, match="gyro_bias_walk -1"):
        kalman.KfParams(gyro_bias_walk=-1.0)


def test_the_bias_is_not_learned_from_a_moving_rigs_icp():
    """Where the rig moves, ICP's slow heading errors are not the gyro's bias: with ICP's
    yaw drifting by 0.05 deg/s while the rig drives, the bias stays near its prior (0) unless
    learned from every step (``gyro_still_only`` False), which takes ICP's drift for it."""
    rng = np.random.default_rng(4)
    t, truth = _drive(rng)
    icp = _icp(rng, t, truth, np.array([0.002, 0.002, np.radians(0.002)]))
    drift = np.radians(0.05)
    icp = [dataclasses.replace(m, motion=m.motion + np.array([0.0, 0.0, drift * (m.t1 - m.t0)])) for m in icp]
    gyro = _gyro(rng, t, truth, 0.0)
    still_only = kalman.run_filter(icp + gyro, kalman.KF_MODES["weighted"])
    everywhere = kalman.run_filter(
        icp + gyro, dataclasses.replace(kalman.KF_MODES["weighted"], gyro_still_only=False)
    )
    assert abs(still_only.gyro_bias) < 0.1 * drift
    assert abs(everywhere.gyro_bias + drift) < 0.3 * drift


def test_a_slow_turn_in_place_is_not_taken_for_the_bias():
    """A rig turning in place at 1.5 deg/s: ICP's steps are below the still thresholds (3
    deg/s), but the gyro reads a turn the bias's prior cannot explain, so its zero-turn
    update is refused (:data:`kalman.GYRO_ZERO_TURN_GATE`) and the steps are taken against
    ICP's turn: the bias (0.05 deg/s) comes out within 0.02 deg/s, not near 1.5."""
    rng = np.random.default_rng(5)
    t, truth = _drive(rng, speed=0.0)
    truth[:, 2] = np.radians(1.5) * t
    icp = _icp(rng, t, truth, np.array([0.0005, 0.0005, np.radians(0.002)]))
    bias = np.radians(0.05)
    r = kalman.run_filter(icp + _gyro(rng, t, truth, bias), kalman.KF_MODES["weighted"])
    assert r.gyro_still_s > 15.0
    assert abs(r.gyro_bias - bias) < np.radians(0.02)
    assert abs(r.poses[-1, 2] - truth[-1, 2]) < np.radians(0.2)
