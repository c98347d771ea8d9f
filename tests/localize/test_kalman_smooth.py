"""The Kalman filter's path at its inputs' stamps (path_at), and its Rauch-Tung-Striebel
backward pass (KfParams.smooth)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from odometry_paths import with_errors as _with_errors

from rigcal.localize import kalman
from rigcal.localize.metrics import evaluate

ICP_COV = np.diag([1e-6, 9e-8, 1e-10])


def _arc(n=801, dt=0.025, v=0.5, w=0.2):
    """A drive on a circle at v m/s, turning w rad/s: stamps (n,), poses (n, 3)."""
    t = np.arange(n) * dt
    yaw = w * t
    return t, np.column_stack([v / w * np.sin(yaw), v / w * (1 - np.cos(yaw)), yaw])


def _inputs(rng, vo_errors_m=0.0, vo_offset_s=0.0125):
    """ICP's steps at 40 Hz (honest: 1 mm forward, 0.3 mm sideways, 0.01 mrad) and VO's
    runs of 20 scans ending half a scan after them (an image's stamp), each ``vo_errors_m``
    too long plus 1.5 mm of noise, claiming 1.5 mm."""
    t, poses = _arc()
    icp_errors = rng.normal(0.0, [1e-3, 3e-4, 1e-5], (len(t) - 1, 3))
    icp_path = _with_errors(poses, icp_errors)
    icp = kalman.increments(t, icp_path, np.stack([ICP_COV] * len(t)), source="icp")
    tv = t[::20][:40] + vo_offset_s  # image stamps, and the truth there
    w, v = 0.2, 0.5
    pv = np.column_stack([v / w * np.sin(w * tv), v / w * (1 - np.cos(w * tv)), w * tv])
    vo_errors = np.zeros((39, 3))
    vo_errors[:, 0] = vo_errors_m + rng.normal(0.0, 1.5e-3, 39)
    vo = kalman.increments(
        tv, _with_errors(pv, vo_errors), np.stack([np.diag([2.25e-6, 1e-6, 1e-8])] * 40), source="vo"
    )
    return t, poses, icp_path, icp, vo


def _same_path(a, b, atol):
    """Poses (N, 3) equal to ``atol``, yaw up to whole turns."""
    d = a - b
    d[:, 2] = np.angle(np.exp(1j * d[:, 2]))
    np.testing.assert_allclose(d, 0.0, atol=atol)


def _ate(stamps, est, t, truth):
    gt = np.column_stack([np.interp(stamps, t, truth[:, i]) for i in range(3)])
    return evaluate(est, gt, rounded=False)["ate_rmse_m"]


def test_a_filter_on_icps_path_scores_icps_ate_at_the_scans():
    """icp-first with VO's runs 2 cm too long each (left out: ICP constrains every
    direction): the filter keeps poses at VO's image stamps too, between scans, so scored
    at all its stamps its ATE is not ICP's; at the scans' stamps (path_at) its poses are
    ICP's and so is its ATE, to rounding."""
    t, truth, icp_path, icp, vo = _inputs(np.random.default_rng(1), vo_errors_m=0.02)
    res = kalman.run_filter(icp + vo, kalman.KF_MODES["icp-first"])
    assert len(res.stamps_s) > len(t)  # the image stamps' poses besides the scans'
    at = kalman.path_at(res, t)
    np.testing.assert_array_equal(at.stamps_s, t)
    _same_path(at.poses, icp_path, 1e-9)
    icp_ate = _ate(t, icp_path, t, truth)
    assert _ate(at.stamps_s, at.poses, t, truth) == pytest.approx(icp_ate, abs=1e-12)
    assert abs(_ate(res.stamps_s, res.poses, t, truth) - icp_ate) > 1e-6
    # fuse(..., at=) is the pipeline's: the same path.
    _, poses = kalman.fuse(icp + vo, kalman.KF_MODES["icp-first"], at=t)
    np.testing.assert_array_equal(poses, at.poses)


def test_path_at_interpolates_on_the_twist_between_kept_poses_and_drops_stamps_outside():
    """Two kept poses on an arc: a stamp between them lands on the arc (the constant twist),
    a stamp before the first or after the last is dropped; a kept stamp is returned as is."""
    _, poses = _arc(n=3, dt=1.0)
    res = kalman.KfResult(np.array([0.0, 2.0]), poses[[0, 2]], np.stack([np.eye(3), 2 * np.eye(3)]))
    at = kalman.path_at(res, np.array([-1.0, 0.0, 1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(at.stamps_s, [0.0, 1.0, 2.0])
    np.testing.assert_allclose(at.poses, poses, atol=1e-12)
    np.testing.assert_array_equal(at.covariances[[0, 2]], res.covariances)


def test_the_backward_pass_changes_nothing_no_measurement_after_a_pose_moved():
    """icp-first with every VO run left out: no update at all, the smoothed path is the
    filtered one (ICP's steps chained)."""
    t, _, icp_path, icp, vo = _inputs(np.random.default_rng(2), vo_errors_m=0.02)
    params = kalman.KF_MODES["icp-first"]
    filtered = kalman.run_filter(icp + vo, params)
    smoothed = kalman.run_filter(icp + vo, dataclasses.replace(params, smooth=True))
    np.testing.assert_array_equal(smoothed.stamps_s, filtered.stamps_s)
    np.testing.assert_allclose(smoothed.poses, filtered.poses, atol=1e-10)
    _same_path(kalman.path_at(smoothed, t).poses, icp_path, 1e-9)


@pytest.mark.parametrize("mode", ["weighted", "driven"])
def test_the_backward_pass_takes_later_measurements_into_earlier_poses(mode):
    """ICP and honest VO fused: the smoothed path's last pose is the filtered one (no
    measurement after it), its covariances are at most the filter's, and over five seeds
    its ATE is below the filter's on average and on most seeds (a smoother's estimate
    takes every measurement; the filter's, those before)."""
    params = kalman.KF_MODES[mode]
    better, gains = 0, []
    for seed in range(5):
        t, truth, _, icp, vo = _inputs(np.random.default_rng(10 + seed))
        filtered = kalman.path_at(kalman.run_filter(icp + vo, params), t)
        smoothed = kalman.path_at(kalman.run_filter(icp + vo, dataclasses.replace(params, smooth=True)), t)
        np.testing.assert_allclose(smoothed.poses[-1], filtered.poses[-1], atol=1e-9)
        trace_f = np.trace(filtered.covariances, axis1=1, axis2=2)
        trace_s = np.trace(smoothed.covariances, axis1=1, axis2=2)
        assert (trace_s <= trace_f * (1 + 1e-6) + 1e-15).all()
        assert (trace_s[1:-1] < trace_f[1:-1]).mean() > 0.9
        a_f, a_s = _ate(t, filtered.poses, t, truth), _ate(t, smoothed.poses, t, truth)
        better += a_s < a_f
        gains.append(a_f - a_s)
    assert better >= 4
    assert np.mean(gains) > 0


def test_smoothing_is_off_in_every_mode_the_wheel_witness_and_calibration_on_but_the_papers():
    assert not any(p.smooth for p in kalman.KF_MODES.values())
    for mode, p in kalman.KF_MODES.items():
        assert (p.wheel_witness, p.wheel_calibrated, p.wheel_input) == ((mode != "fixed"),) * 2 + (True,)
