"""The wheel odometry as the guard's third witness: calibrated against ICP, it tells which of
ICP and VO errs where the two disagree; without wheel odometry the filter is as before."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from odometry_paths import line
from odometry_paths import with_errors as _with_errors

from rigcal.localize import kalman

ICP_FIRST = kalman.KF_MODES["icp-first"]
WEIGHTED = kalman.KF_MODES["weighted"]


def _line(n=1601, dt=0.025, v=0.5):
    return line(n, dt, v)


def _wheels(rng, t, poses, scale=0.02, drift_deg_per_m=0.5):
    """Wheel odometry at the scans: each step's distance off by ``scale`` (and 1 % noise),
    its heading drifting by ``drift_deg_per_m`` per metre (and 2 mrad noise), as
    rigcal.sim.drive models a wheeled base."""
    errors = np.zeros((len(t) - 1, 3))
    dist = np.hypot(*np.diff(poses[:, :2], axis=0).T)
    errors[:, 0] = dist * (scale + 0.01 * rng.standard_normal(len(dist)))
    errors[:, 2] = np.radians(drift_deg_per_m) * dist + 2e-3 * rng.standard_normal(len(dist))
    return kalman.increments(t, _with_errors(poses, errors), kalman.WHEEL_SIGMAS, source="wheel")


def _drive(rng, icp_short_m):
    """A 20 m line at 0.5 m/s: ICP's steps (claiming 1 mm forward, erring by that, and from
    15 s to 25 s each ``icp_short_m`` short: beyond its model), VO's runs of 20 scans
    honest (claiming and erring by 1.5 mm), the wheels (:func:`_wheels`)."""
    t, poses = _line()
    icp_errors = np.zeros((len(t) - 1, 3))
    icp_errors[:, 0] = rng.normal(0.0, 1e-3, len(t) - 1)
    icp_errors[600:1000, 0] -= icp_short_m
    icp = kalman.increments(
        t, _with_errors(poses, icp_errors), np.stack([np.diag([1e-6, 9e-8, 1e-10])] * len(t)), source="icp"
    )
    vo_errors = np.zeros((80, 3))
    vo_errors[:, 0] = rng.normal(0.0, 1.5e-3, 80)
    vo_cov = np.diag([2.25e-6, 1e-6, 1e-8])
    vo = kalman.increments(
        t[::20], _with_errors(poses[::20], vo_errors), np.stack([vo_cov] * 81), source="vo"
    )
    return poses, icp, vo, _wheels(rng, t, poses)


@pytest.mark.parametrize("mode", ["weighted", "icp-first"])
def test_the_wheels_convict_icp_erring_beyond_its_model_and_vo_carries_the_filter(mode):
    """ICP's steps 1 mm short each for 10 s (40 cm in all, its model allows 2 cm): the guard
    alone blames VO (weighted) or follows ICP (icp-first) and the filter ends 43-45 cm short;
    with the wheels as witness ICP is found erring forward over those runs, VO is kept
    and ICP's path loosened there, and the filter ends within 5 cm."""
    poses, icp, vo, wheels = _drive(np.random.default_rng(1), 1e-3)
    params = kalman.KF_MODES[mode]
    alone = kalman.run_filter(
        icp + vo + wheels, dataclasses.replace(params, wheel_input=False, wheel_witness=False)
    )
    witnessed = kalman.run_filter(
        icp + vo + wheels, dataclasses.replace(params, wheel_witness=True, wheel_input=False)
    )
    assert alone.icp_witnessed == (0, 0, 0)
    assert witnessed.icp_witnessed[0] >= 10
    assert abs(alone.poses[-1, 0] - poses[-1, 0]) > 0.25
    assert abs(witnessed.poses[-1, 0] - poses[-1, 0]) < 0.05


def test_the_wheels_keep_an_honest_icp_and_leave_out_a_biased_vo():
    """ICP honest, VO's runs 8 mm too long each: the wheels side with ICP; no ICP verdict,
    VO's forward left out at least as often as by the guard alone, the filter as near the
    truth as with it."""
    rng = np.random.default_rng(2)
    poses, icp, _, wheels = _drive(rng, 0.0)
    t = np.arange(1601) * 0.025
    vo_errors = np.zeros((80, 3))
    vo_errors[:, 0] = 8e-3
    vo = kalman.increments(
        t[::20],
        _with_errors(poses[::20], vo_errors),
        np.stack([np.diag([2.25e-6, 1e-6, 1e-8])] * 81),
        source="vo",
    )
    params = dataclasses.replace(WEIGHTED, wheel_witness=True, wheel_input=False)
    res = kalman.run_filter(icp + vo + wheels, params)
    alone = kalman.run_filter(icp + vo + wheels, dataclasses.replace(params, wheel_witness=False))
    assert res.icp_witnessed == (0, 0, 0)
    assert res.vo_guarded[0] >= max(50, alone.vo_guarded[0])
    assert abs(res.poses[-1, 0] - poses[-1, 0]) <= abs(alone.poses[-1, 0] - poses[-1, 0]) + 1e-3


def test_without_wheel_odometry_the_witness_changes_nothing():
    """The witness and the calibration on a drive without wheel steps: the filter's path as
    without them, to the bit, in every mode (their default)."""
    _, icp, vo, _ = _drive(np.random.default_rng(3), 1e-3)
    for mode in ("weighted", "icp-first", "driven"):
        params = kalman.KF_MODES[mode]
        off = kalman.run_filter(
            icp + vo, dataclasses.replace(params, wheel_witness=False, wheel_calibrated=False)
        )
        on = kalman.run_filter(
            icp + vo, dataclasses.replace(params, wheel_witness=True, wheel_calibrated=True)
        )
        np.testing.assert_array_equal(on.poses, off.poses)
        assert on.icp_witnessed == (0, 0, 0)


def test_wheel_input_off_leaves_the_wheels_out_of_the_fusion():
    """wheel_input False: the filter on ICP and VO alone, the wheels only a witness."""
    _, icp, vo, wheels = _drive(np.random.default_rng(4), 0.0)
    params = dataclasses.replace(WEIGHTED, wheel_input=False)
    np.testing.assert_array_equal(
        kalman.run_filter(icp + vo + wheels, params).poses, kalman.run_filter(icp + vo, params).poses
    )


def test_the_witness_calibrates_the_wheels_scale_and_drift_against_icp_after_5_m():
    """Wheels 2 % long and drifting 0.5 deg/m: before 5 m of calibration no verdict; after,
    their motion over a 2 m window is the truth's within 5 mm forward, where the raw wheels
    are 4 cm off, and its heading within its model."""
    rng = np.random.default_rng(5)
    t, poses = _line()
    icp = kalman.increments(t, poses, np.stack([np.diag([1e-6, 9e-8, 1e-10])] * len(t)), source="icp")
    wheels = _wheels(rng, t, poses)
    ref = kalman._IcpReference(icp, WEIGHTED)
    witness = kalman._WheelWitness(wheels, ref, WEIGHTED)
    assert witness.between(5.0, 9.0, 9.0) is None  # 4.5 m driven
    got = witness.between(30.0, 34.0, 34.0, 8)
    raw = kalman._IcpReference(wheels, WEIGHTED, "wheel").between(30.0, 34.0, 34.0)
    assert got is not None
    assert raw is not None
    truth = np.array([2.0, 0.0, 0.0])
    assert abs(raw[0][0] - truth[0]) > 0.03
    assert abs(got[0][0] - truth[0]) < 5e-3
    # The heading: a random walk of 2 mrad a step, within three of the model's sigmas.
    assert abs(got[0][2]) < 3.0 * np.sqrt(got[1][2, 2])
    # Its covariance: the steps' rate covariances times the measured ratio of 8-run windows.
    ratio = np.asarray(kalman.WHEEL_WINDOW_RATIO[3])
    R = kalman._rotation3(float(got[0][2]))
    np.testing.assert_allclose(np.diag(R.T @ got[1] @ R), np.diag(R.T @ raw[1] @ R) * ratio, rtol=1e-2)


def test_the_witness_verdict_names_the_input_that_disagrees_with_both_others():
    """Three chains over one window: the one off the other two beyond both models is the
    one that errs; ICP's squared excess comes back where ICP errs."""
    cov = np.diag([1e-6, 1e-6, 1e-8])
    runs = [
        (kalman.Increment(k * 0.5, (k + 1) * 0.5, np.array([0.25, 0.0, 0.0]), cov, "vo"), cov)
        for k in range(4)
    ]
    small = np.diag([4e-6, 4e-6, 4e-8])
    truth = np.array([1.0, 0.0, 0.0])
    gate = kalman._guard_gate(kalman.VO_GUARD_RUNS)
    no_corr = np.zeros((3, 3))
    icp_off = (truth + np.array([0.05, 0.0, 0.0]), small)
    icp_errs, vo_errs, excess = kalman._witness(runs, icp_off, (truth, small), no_corr, gate)
    assert icp_errs.tolist() == [True, False, False]
    assert not vo_errs.any()
    assert excess[0] == pytest.approx(0.05**2 - 8e-6)
    assert excess[1:].tolist() == [0.0, 0.0]
    vo_icp_agree = (truth + np.array([-0.05, 0.0, 0.0]), small)
    icp_errs, vo_errs, excess = kalman._witness(runs, vo_icp_agree, (vo_icp_agree[0], small), no_corr, gate)
    assert vo_errs.tolist() == [True, False, False]
    assert not icp_errs.any()
    assert not excess.any()
    # ICP open along the travel: VO carries the filter there, the wheels do not leave it out.
    open_icp = (vo_icp_agree[0], np.diag([kalman.OPEN_SIGMA_M**2, 4e-6, 4e-8]))
    assert not kalman._witness(runs, open_icp, (vo_icp_agree[0], small), no_corr, gate)[1].any()


def test_the_wheels_fused_calibrated_do_not_pull_the_filter_by_their_scale():
    """ICP honest, the wheels 2 % long: fused as they come (WHEEL_SIGMAS) they pull the
    driven filter's 20 m about 10 cm long; calibrated against ICP (wheel_calibrated:
    forward and yaw, after the first 5 m; before, left out where ICP constrains the travel)
    they leave it within 2 cm of the truth."""
    poses, icp, _, wheels = _drive(np.random.default_rng(6), 0.0)
    driven = dataclasses.replace(kalman.KF_MODES["driven"], vo_guard=0, vo_forward_reference=False)
    raw = kalman.run_filter(icp + wheels, dataclasses.replace(driven, wheel_calibrated=False))
    calibrated = kalman.run_filter(icp + wheels, dataclasses.replace(driven, wheel_calibrated=True))
    assert raw.poses[-1, 0] - poses[-1, 0] > 0.05
    assert abs(calibrated.poses[-1, 0] - poses[-1, 0]) < 0.02
    steps = kalman._WheelWitness(wheels, kalman._IcpReference(icp, driven), driven).calibrated_steps()
    # Before 5 m by the wheels (2 % long, 1 % noise, at 0.5 m/s: 9.8 s) left out (ICP
    # constrains the travel), then calibrated.
    assert 9.7 < min(m.t1 for m in steps) < 9.9
    assert all(m.covariance[1, 1] == kalman.OPEN_SIGMA_M**2 for m in steps)
    # No ICP to calibrate against: the wheels fused as they came.
    np.testing.assert_array_equal(
        kalman.run_filter(wheels, driven).poses,
        kalman.run_filter(wheels, dataclasses.replace(driven, wheel_calibrated=False)).poses,
    )


def test_the_wheels_calibration_skips_where_icp_leaves_the_travel_open():
    """A corridor ICP cannot fix along the travel from 12 s on (its steps forward open and
    measuring half the motion there): the wheels' scale is calibrated on the blocks before
    alone, so at the end their calibrated motion over 2 m is still within 1 cm of the truth
    (taking those blocks in, it would read about half the distance)."""
    rng = np.random.default_rng(7)
    t, poses = _line()
    errors = np.zeros((len(t) - 1, 3))
    errors[480:, 0] = -0.5 * 0.5 * 0.025  # half of each step's forward motion missing
    covs = np.stack([np.diag([1e-6, 9e-8, 1e-10])] * len(t))
    covs[481:, 0, 0] = kalman.OPEN_SIGMA_M**2
    icp = kalman.increments(t, _with_errors(poses, errors), covs, source="icp")
    witness = kalman._WheelWitness(_wheels(rng, t, poses), kalman._IcpReference(icp, WEIGHTED), WEIGHTED)
    cal = witness.calibration(40.0)
    assert cal is not None
    assert cal[0] == pytest.approx(1.02, abs=0.01)
    got = witness.between(36.0, 40.0, 40.0, 8)
    assert got is not None
    assert abs(got[0][0] - 2.0) < 0.01
