"""The Kalman filter of Section VI: constant velocity, velocity measurements from increments."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.localize import kalman


def _arc(n=200, dt=0.1, v=1.0, w=0.2):
    t = np.arange(n) * dt
    yaw = w * t
    x = v / w * np.sin(yaw)
    y = v / w * (1 - np.cos(yaw))
    return t, np.column_stack([x, y, yaw])


def test_exact_increments_reproduce_the_path():
    t, poses = _arc()
    st, est = kalman.fuse(kalman.increments(t, poses, kalman.ICP_SIGMAS))
    assert np.allclose(st, t)
    # A velocity measured over a step lags half a step at most: centimetres over 20 m.
    assert np.max(np.linalg.norm(est[:, :2] - poses[:, :2], axis=1)) < 0.1
    assert np.max(np.abs(est[:, 2] - poses[:, 2])) < 0.01


def _scaled(poses, forward, cross):
    """Odometry whose every step is stretched forward and sideways in the rig's frame."""
    out = [poses[0]]
    for k in range(1, len(poses)):
        c, s = np.cos(poses[k - 1, 2]), np.sin(poses[k - 1, 2])
        d = poses[k, :2] - poses[k - 1, :2]
        lx, ly = c * d[0] + s * d[1], -s * d[0] + c * d[1]
        lx, ly = lx * forward, lx * cross + ly
        p = out[-1]
        cc, ss = np.cos(p[2]), np.sin(p[2])
        out.append(
            np.array(
                [p[0] + cc * lx - ss * ly, p[1] + ss * lx + cc * ly, p[2] + poses[k, 2] - poses[k - 1, 2]]
            )
        )
    return np.array(out)


def test_forward_speed_follows_vo_and_cross_track_follows_icp():
    t, poses = _arc(w=1e-6)
    icp = _scaled(poses, 1.2, 0.0)  # ICP overestimates forward motion by 20 %
    vo = _scaled(poses, 1.0, 0.1)  # VO drifts sideways by 10 % of the distance
    ms = kalman.increments(t, icp, kalman.ICP_SIGMAS) + kalman.increments(t, vo, kalman.VO_SIGMAS)
    _, est = kalman.fuse(ms)
    travelled = est[-1, 0]
    assert travelled == pytest.approx(poses[-1, 0], rel=0.05)  # nearer VO's 1.0 than ICP's 1.2
    assert abs(est[-1, 1]) < 0.3 * abs(vo[-1, 1])  # most of VO's sideways drift rejected


def test_no_measurements_give_an_empty_path():
    st, est = kalman.fuse([])
    assert st.shape == (0,)
    assert est.shape == (0, 3)


def test_repeated_stamps_are_skipped():
    t = np.array([0.0, 0.1, 0.1, 0.2])
    p = np.array([[0, 0, 0], [0.1, 0, 0], [0.1, 0, 0], [0.2, 0, 0]], dtype=float)
    assert len(kalman.increments(t, p, kalman.ICP_SIGMAS)) == 2


def test_icp_steps_the_walls_do_not_constrain_leave_the_forward_speed_to_vo():
    """Along a corridor whose ends the laser cannot see, ICP's forward step is only the
    motion it started from (here 50 % too long): flagged, it does not pull the path."""
    t, poses = _arc(w=1e-6)
    icp = _scaled(poses, 1.5, 0.0)
    vo = _scaled(poses, 1.0, 0.0)
    open_forward = np.ones(len(t), dtype=bool)
    for flag, near_vo in ((None, False), (open_forward, True)):
        ms = kalman.increments(t, icp, kalman.ICP_SIGMAS, flag) + kalman.increments(t, vo, kalman.VO_SIGMAS)
        _, est = kalman.fuse(ms)
        assert bool(est[-1, 0] == pytest.approx(poses[-1, 0], rel=0.01)) is near_vo


def test_vo_runs_without_a_scale_leave_the_forward_speed_to_icp():
    """A VO run whose length is a guess (no scale: the last measured speed, here a tenth
    of the true one) measures no forward speed, and a failed run (a constant-velocity
    guess, here a standstill) nothing: flagged, neither pulls the path off ICP's."""
    t, poses = _arc(w=1e-6)
    icp = _scaled(poses, 1.0, 0.0)
    vo = _scaled(poses, 0.1, 0.0)
    icp_ms = kalman.increments(t, icp, kalman.ICP_SIGMAS)
    unflagged = kalman.fuse(icp_ms + kalman.increments(t, vo, kalman.VO_SIGMAS))[1]
    assert unflagged[-1, 0] < 0.5 * poses[-1, 0]  # VO's weight on forward speed: pulled back
    guessed = np.ones(len(t), dtype=bool)
    flagged = kalman.fuse(icp_ms + kalman.increments(t, vo, kalman.VO_SIGMAS, open_forward=guessed))[1]
    assert flagged[-1, 0] == pytest.approx(poses[-1, 0], rel=0.01)
    still = _scaled(poses, 0.0, 0.0)
    failed = np.zeros(len(t), dtype=bool)
    assert kalman.increments(t, still, kalman.VO_SIGMAS, measured=failed) == []
    alone = kalman.fuse(icp_ms + kalman.increments(t, still, kalman.VO_SIGMAS, measured=failed))[1]
    assert np.allclose(alone, kalman.fuse(icp_ms)[1])


def test_vo_runs_become_measurements_by_their_status():
    t, poses = _arc(n=5)
    ms = kalman.vo_increments(t, poses, ["ok", "no-scale", "failed", "carried"])
    assert [(m.t0, m.t1) for m in ms] == [(t[0], t[1]), (t[1], t[2]), (t[3], t[4])]
    assert [m.sigmas[0] for m in ms] == [kalman.VO_SIGMAS[0], kalman.OPEN_FORWARD_SIGMA, kalman.VO_SIGMAS[0]]
    assert all(m.sigmas[1:] == kalman.VO_SIGMAS[1:] for m in ms)
    with pytest.raises(ValueError, match="3 run statuses for 5 poses"):
        kalman.vo_increments(t, poses, ["ok", "ok", "ok"])
