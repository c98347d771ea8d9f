"""The Kalman filter's causal path as its relative estimates chained (KfParams.anchored):
on a long drive far from the origin, with ICP's shared error in the state and the wheels'
steps fused, the world pose's updates leak into a pose and its clone alike; the anchored
path does not take that move."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.localize import kalman


def _chain(steps):
    """Poses (N + 1, 3) from the origin by steps (N, 3), each in the frame before it."""
    out = [np.zeros(3)]
    for step in steps:
        out.append(pose_of(se2(out[-1]) @ se2(step)))
    return np.array(out)


def _long_drive(n=2000, dt=0.44):
    """A 260 m drive, nearly straight (small turns both ways), scans 0.44 s apart: stamps
    (n + 1,), the true poses and the filter's inputs, ICP's steps (3 cm, 7 mrad, honest)
    and the wheels' (under their noise model)."""
    rng = np.random.default_rng(1)
    steps = np.tile([0.13, 0.0, 0.0], (n, 1))
    steps[::7, 2], steps[3::7, 2] = 0.05, -0.05
    truth = _chain(steps)
    t = np.arange(n + 1) * dt
    icp_sigma, wheel_sigma = np.array([0.003, 0.003, 0.0007]) * 10.0, np.array([0.02, 0.01, 0.02])
    icp = _chain(steps + rng.normal(size=steps.shape) * icp_sigma)
    wheels = _chain(steps + rng.normal(size=steps.shape) * wheel_sigma)
    cov = np.tile(np.diag(icp_sigma**2), (n + 1, 1, 1))
    ms = kalman.increments(t, icp, cov, source="icp")
    ms += kalman.increments(t, wheels, tuple(wheel_sigma / dt), source="wheel")
    return t, truth, ms


def _relative_errors(poses, truth):
    """The consecutive relative displacements' errors (m)."""
    out = []
    for k in range(len(poses) - 1):
        est = pose_of(np.linalg.inv(se2(poses[k])) @ se2(poses[k + 1]))
        ref = pose_of(np.linalg.inv(se2(truth[k])) @ se2(truth[k + 1]))
        out.append(np.hypot(*(est[:2] - ref[:2])))
    return np.array(out)


@pytest.mark.parametrize("mode", ["driven", "weighted"])
def test_the_anchored_path_does_not_take_the_world_poses_leak(mode):
    t, truth, ms = _long_drive()
    raw = {"wheel_witness": False, "wheel_calibrated": False, "adapt": False}
    params = dataclasses.replace(kalman.KF_MODES[mode], **raw)
    world = kalman.path_at(kalman.run_filter(ms, params), t)
    anchored = kalman.path_at(kalman.run_filter(ms, dataclasses.replace(params, anchored=True)), t)
    # The world pose jumps by decimetres on some steps (a metre in the driven filter);
    # each step's error in the anchored path stays at the inputs' (a few cm).
    assert _relative_errors(world.poses, truth).max() > 0.2
    assert _relative_errors(anchored.poses, truth).max() < 0.08
    assert _relative_errors(anchored.poses, truth).mean() < 0.02


def test_without_updates_the_anchored_path_is_the_driving_steps_chained():
    t, _, ms = _long_drive(n=300)
    icp = [m for m in ms if m.source == "icp"]
    params = dataclasses.replace(kalman.KF_MODES["driven"], anchored=True)
    res = kalman.path_at(kalman.run_filter(icp, params), t)
    chained = kalman.path_at(kalman.run_filter(icp, kalman.KF_MODES["driven"]), t)
    np.testing.assert_allclose(res.poses, chained.poses, atol=1e-9)


def test_the_smoothed_path_is_the_backward_passs_either_way():
    _, _, ms = _long_drive(n=200)
    params = dataclasses.replace(kalman.KF_MODES["weighted"], smooth=True)
    a = kalman.run_filter(ms, params)
    b = kalman.run_filter(ms, dataclasses.replace(params, anchored=True))
    np.testing.assert_allclose(a.poses, b.poses, atol=1e-12)
