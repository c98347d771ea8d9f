"""The gyroscope as the guard's heading witness: its yaw chained over the guard's windows,
its bias learned at a standstill, tells which of ICP and VO errs in yaw where the two
disagree; without gyro steps the filter is as before."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from odometry_paths import with_errors

from rigcal.localize import kalman

DT = 0.025  # the scans' period (s)
STILL = 120  # 3 s standing before the rig moves (the gyro's bias learned there)
MOVING = 800  # then 20 s along x at 0.5 m/s
BIAS = np.radians(0.05)  # the gyro's bias (rad/s)


def _path():
    n = STILL + MOVING + 1
    t = np.arange(n) * DT
    x = 0.5 * DT * np.maximum(0, np.arange(n) - STILL)
    return t, np.column_stack([x, np.zeros(n), np.zeros(n)])


def _gyro(rng, t, poses, every=4):
    """The gyro's steps of 0.1 s: the truth's turn, its bias and its angle random walk."""
    at = t[::every]
    yaw = np.diff(poses[::every, 2]) + BIAS * np.diff(at)
    yaw += kalman.GYRO_NOISE / 2 * np.sqrt(np.diff(at)) * rng.standard_normal(len(at) - 1)
    return kalman.gyro_increments(at, yaw)


def _drive(rng, icp_yaw_sigma, icp_yaw_error, vo_yaw_error):
    """ICP's steps (translation good to 1 mm, yaw to ``icp_yaw_sigma`` a step, as claimed,
    plus ``icp_yaw_error`` (per step, (n,))), VO's runs of 20 scans (claiming 1.5 mm and
    0.1 mrad, erring by that plus ``vo_yaw_error`` a run) and the gyro's steps."""
    t, poses = _path()
    n = len(t) - 1
    icp_errors = np.zeros((n, 3))
    icp_errors[:, :2] = rng.normal(0.0, 1e-3, (n, 2)) * (np.arange(n) >= STILL)[:, None]
    icp_errors[:, 2] = rng.normal(0.0, icp_yaw_sigma, n) + icp_yaw_error
    icp_cov = np.diag([1e-6, 1e-6, icp_yaw_sigma**2])
    icp = kalman.increments(t, with_errors(poses, icp_errors), np.stack([icp_cov] * len(t)), source="icp")
    runs = n // 20
    vo_errors = np.zeros((runs, 3))
    vo_errors[:, :2] = rng.normal(0.0, 1.5e-3, (runs, 2))
    vo_errors[:, 2] = rng.normal(0.0, 1e-4, runs) + vo_yaw_error
    vo_cov = np.diag([2.25e-6, 2.25e-6, 1e-8])
    vo = kalman.increments(
        t[::20], with_errors(poses[::20], vo_errors), np.stack([vo_cov] * (runs + 1)), source="vo"
    )
    return poses, icp, vo, _gyro(rng, t, poses)


def _heading(mode, **changes):
    return dataclasses.replace(kalman.KF_MODES[mode], gyro_witness=True, gyro_fused=False, **changes)


@pytest.mark.parametrize("turn", [False, True])
@pytest.mark.parametrize("mode", ["weighted", "icp-first"])
def test_the_gyro_convicts_icps_heading_and_vo_carries_the_yaw(mode, turn):
    """ICP's yaw 0.2 mrad a step off from 8 s to 13 s (40 mrad in all; its model 0.14
    mrad over those 200 steps), VO and the gyro honest: without the witness the guard blames VO (weighted) or
    follows ICP (icp-first) and the filter ends with ICP's heading error; with the gyro as
    witness (not fused) ICP's yaw is found erring over those runs, VO is kept there and ICP's
    path loosened, and the heading ends within a fifth of that (``turn``: with the gyro's turn
    over those runs fused too, ``gyro_where_icp_errs``)."""
    rng = np.random.default_rng(1)
    n = STILL + MOVING
    bad = np.zeros(n)
    bad[320:520] = 2e-4
    poses, icp, vo, gyro = _drive(rng, 1e-5, bad, 0.0)
    alone = kalman.run_filter(icp + vo + gyro, dataclasses.replace(_heading(mode), gyro_witness=False))
    witnessed = kalman.run_filter(icp + vo + gyro, _heading(mode, gyro_where_icp_errs=turn))
    assert alone.gyro_witnessed == (0, 0)
    assert witnessed.gyro_witnessed[0] >= 10
    assert witnessed.icp_witnessed[2] == witnessed.gyro_witnessed[0]
    assert abs(alone.poses[-1, 2] - poses[-1, 2]) > 0.035
    assert abs(witnessed.poses[-1, 2] - poses[-1, 2]) < 0.008


def test_the_gyro_convicts_vos_heading_and_the_filter_keeps_icps():
    """ICP's yaw noisy but honest (1 mrad a step, as claimed), VO's runs each turning 3 mrad
    too far (140 mrad in all; its model allows 0.1 mrad, but against ICP's loose chain the
    guard tells on a few runs alone): the weighted filter takes VO's yaw and ends 75 mrad
    off; with the gyro as witness (not fused) VO's yaw is found erring on nearly every run
    and left out, and the heading ends within half of that (measured 11 mrad)."""
    rng = np.random.default_rng(2)
    poses, icp, vo, gyro = _drive(rng, 1e-3, 0.0, 3e-3)
    alone = kalman.run_filter(icp + vo + gyro, dataclasses.replace(_heading("weighted"), gyro_witness=False))
    witnessed = kalman.run_filter(icp + vo + gyro, _heading("weighted"))
    assert alone.vo_guarded[2] <= 15
    assert witnessed.gyro_witnessed[1] >= 30
    assert witnessed.vo_guarded[2] >= 30
    assert witnessed.gyro_witnessed[0] <= 2
    err_alone = abs(alone.poses[-1, 2] - poses[-1, 2])
    assert err_alone > 0.06
    assert abs(witnessed.poses[-1, 2] - poses[-1, 2]) < 0.5 * err_alone


def test_witness_only_fuses_the_gyro_at_the_standstill_alone():
    """``gyro_fused`` off: the gyro's still steps learn its bias (as fused), its moving ones
    enter no update; without the witness the filter's path is then that of ICP and VO with
    the still steps alone, to the bit."""
    rng = np.random.default_rng(3)
    _, icp, vo, gyro = _drive(rng, 1e-5, 0.0, 0.0)
    params = dataclasses.replace(_heading("weighted"), gyro_witness=False)
    still = [m for m in gyro if m.t1 <= STILL * DT]
    res = kalman.run_filter(icp + vo + gyro, params)
    np.testing.assert_array_equal(res.poses, kalman.run_filter(icp + vo + still, params).poses)
    assert 2.8 <= res.gyro_still_s <= 3.0
    assert abs(res.gyro_bias - BIAS) < 3 * res.gyro_bias_sigma
    fused = kalman.run_filter(icp + vo + gyro, kalman.KF_MODES["weighted"])
    assert not np.array_equal(fused.poses, res.poses)


def test_without_gyro_steps_the_heading_witness_changes_nothing():
    """The witness on a drive without gyro steps: the filter's path as without it, to the
    bit, in every mode."""
    _, icp, vo, _ = _drive(np.random.default_rng(4), 1e-5, 0.0, 0.0)
    for mode in ("weighted", "icp-first", "driven"):
        off = kalman.run_filter(icp + vo, kalman.KF_MODES[mode])
        on = kalman.run_filter(icp + vo, _heading(mode))
        np.testing.assert_array_equal(on.poses, off.poses)
        assert on.gyro_witnessed == (0, 0)


def test_the_gyros_yaw_between_two_stamps():
    """Gyro steps of 0.1 s turning 0.01 then 0.03 rad, ICP's of 0.05 s turning 2 mrad each:
    over [0.05, 0.25] the gyro's whole step within (0.1 to 0.2) less the bias over it, and
    ICP's turn over the parts before and after it; the variance the gyro step's own, the
    bias's over its span and ICP's over the parts. The gyro's steps end by ``now``: one not
    ended is ICP's part; none within, or a gap, gives none."""
    at = np.arange(6) * 0.1
    yaw = np.array([0.01, 0.01, 0.03, 0.03, 0.03])
    t = np.arange(11) * 0.05
    icp_cov = np.diag([1e-6, 1e-6, 1e-8])
    icp = [kalman.Increment(t[k], t[k + 1], np.array([0.0, 0.0, 0.002]), icp_cov, "icp") for k in range(10)]
    reference = kalman._IcpReference(icp, kalman.KF_MODES["weighted"])
    witness = kalman._GyroWitness(kalman.gyro_increments(at, yaw), reference)
    got = witness.between(0.05, 0.25, 0.5, 0.02, 1e-6)
    assert got is not None
    motion, cov = got
    assert motion[2] == pytest.approx(0.002 + 0.01 - 0.02 * 0.1 + 0.002)
    parts = sum(reference.between(a, b, 0.5)[1][2, 2] for a, b in ((0.05, 0.1), (0.2, 0.25)))
    assert cov[2, 2] == pytest.approx(kalman.GYRO_NOISE**2 * 0.1 + 1e-6 * 0.1**2 + parts)
    assert cov[0, 0] == cov[1, 1] == kalman.OPEN_SIGMA_M**2
    # At 0.35 the step ending at 0.4 has not ended: ICP's turn carries the window from 0.3.
    carried = witness.between(0.1, 0.35, 0.35, 0.0, 0.0)
    assert carried is not None
    assert carried[0][2] == pytest.approx(0.01 + 0.03 + 0.002)
    assert witness.between(0.12, 0.18, 0.5, 0.0, 0.0) is None
    gap = kalman._GyroWitness(
        kalman.gyro_increments(at, np.array([0.01, np.nan, 0.03, 0.03, 0.03])), reference
    )
    assert gap.between(0.05, 0.35, 0.5, 0.0, 0.0) is None


def test_the_gyros_turn_over_a_convicted_run_moves_the_heading_towards_the_gyros():
    """ICP's yaw off as above and VO's yaw noisy (1 mrad a run, as claimed): fused over the
    runs where the gyro finds ICP's yaw erring, the gyro's turn brings the heading nearer the
    truth than VO's runs alone."""
    rng = np.random.default_rng(5)
    bad = np.zeros(STILL + MOVING)
    bad[320:520] = 2e-4
    poses, icp, vo, gyro = _drive(rng, 1e-5, bad, 0.0)
    noisy = []
    for m in vo:
        cov = m.covariance.copy()
        cov[2, 2] = 1e-6
        motion = m.motion + np.array([0.0, 0.0, rng.normal(0.0, 1e-3)])
        noisy.append(kalman.Increment(m.t0, m.t1, motion, cov, "vo"))
    errs = []
    for turn in (False, True):
        res = kalman.run_filter(icp + noisy + gyro, _heading("icp-first", gyro_where_icp_errs=turn))
        assert res.gyro_witnessed[0] >= 5
        errs.append(abs(res.poses[-1, 2] - poses[-1, 2]))
    assert errs[1] < 0.5 * errs[0]
