"""The Kalman filter's guard against VO where ICP knows better: VO's chained runs against
ICP's own steps over the same interval, and VO's forward variance ratio matched against
ICP's steps alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from odometry_paths import line as _line
from odometry_paths import with_errors as _with_errors
from scipy.stats import chi2

from rigcal.geometry import pose_of, se2
from rigcal.localize import kalman

WEIGHTED = kalman.KF_MODES["weighted"]
UNGUARDED = dataclasses.replace(WEIGHTED, vo_guard=0, vo_forward_reference=False)
GATE = float(chi2.isf(0.001, 1))


def _icp(t, poses, cov):
    return kalman.increments(t, poses, np.stack([cov] * len(t)), source="icp")


def test_the_constants_are_the_whiteness_tests():
    # Windows of 1, 2, 4, 8 runs (8 spans the forward memory's 5), the 0.001 tail shared.
    assert kalman.VO_FORWARD_WINDOW <= kalman.VO_GUARD_RUNS < 2 * kalman.VO_FORWARD_WINDOW
    assert kalman._guard_windows(kalman.VO_GUARD_RUNS) == [1, 2, 4, 8]
    assert kalman._guard_windows(5) == [1, 2, 4]
    assert pytest.approx(chi2.isf(0.001 / 4, 1)) == kalman._guard_gate(kalman.VO_GUARD_RUNS)
    assert WEIGHTED.vo_guard == kalman.VO_GUARD_RUNS
    assert WEIGHTED.vo_forward_reference
    assert kalman.KF_MODES["driven"].vo_guard == kalman.VO_GUARD_RUNS
    fixed = kalman.KF_MODES["fixed"]
    assert (fixed.vo_guard, fixed.vo_forward_reference) == (0, False)
    with pytest.raises(ValueError, match="vo_guard"):
        kalman.KfParams(vo_guard=-1)


def test_icps_reference_chains_its_ended_steps_and_carries_the_last_across_a_scan():
    """An arc at 40 Hz: ICP's motion from a to b is the truth's; b between two scans is
    reached at the last ended step's twist (the step containing b has not ended: causal),
    its covariance the steps' own parts summed plus the two ends' shared parts."""
    dt, v, w = 0.025, 0.8, 0.5
    t = np.arange(81) * dt
    poses = np.column_stack([np.sin(w * t) * v / w, (1 - np.cos(w * t)) * v / w, w * t])
    cov = np.diag([1e-6, 4e-6, 1e-8])
    ref = kalman._IcpReference(_icp(t, poses, cov), WEIGHTED)
    a, b = 0.3125, 1.2125  # image stamps between scans
    motion, C = ref.between(a, b, now=b)
    truth = lambda s: np.array([np.sin(w * s) * v / w, (1 - np.cos(w * s)) * v / w, w * s])  # noqa: E731
    expected = pose_of(np.linalg.inv(se2(truth(a))) @ se2(truth(b)))
    assert motion == pytest.approx(expected, abs=1e-12)
    own, share = kalman._error_model("icp", WEIGHTED)
    steps = (b - a) / dt
    assert np.trace(C) == pytest.approx(
        steps * np.trace(kalman._scaled(cov, own)) + 2 * share @ np.diag(cov), rel=0.05
    )
    # On scan stamps, all steps ended: the steps' own covariances, each turned into the
    # frame at a, summed (crossed at once by the prefix sums), plus the two ends' shared parts.
    anisotropic = np.diag([1e-6, 9e-6, 1e-8])
    full = kalman._IcpReference(_icp(t, poses, anisotropic), WEIGHTED)
    motion, C = full.between(t[10], t[60], now=2.0)
    expected_C = np.zeros((3, 3))
    for k in range(10, 60):
        G = kalman._rotation3(w * (t[k] - t[10]))
        expected_C += G @ kalman._scaled(anisotropic, own) @ G.T
        if k in (10, 59):
            expected_C += G @ kalman._finite_part(kalman._scaled(anisotropic, share)) @ G.T
    np.testing.assert_allclose(C, expected_C, rtol=1e-9, atol=1e-18)
    assert motion == pytest.approx(pose_of(np.linalg.inv(se2(poses[10])) @ se2(poses[60])), abs=1e-12)
    # A step not ended by `now` is not read: a different last step changes nothing.
    bent = poses.copy()
    bent[49:, 1] += 0.05  # the step ending at scan 49 (1.225 s) and after
    assert ref.between(a, b, now=b)[0] == pytest.approx(
        kalman._IcpReference(_icp(t, bent, cov), WEIGHTED).between(a, b, now=b)[0]
    )
    # A gap in ICP's steps longer than a step: no reference.
    gap = [m for m in _icp(t, poses, cov) if not 0.5 <= m.t0 < 0.6]
    assert kalman._IcpReference(gap, WEIGHTED).between(a, b, now=b) is None


def _runs(n, run_s, motion, cov):
    return [
        (kalman.Increment(k * run_s, (k + 1) * run_s, np.array(motion), cov, "vo"), cov) for k in range(n)
    ]


def test_the_guard_fires_along_a_disagreeing_direction_unless_icp_leaves_it_open():
    """Five VO runs 2 cm too long each against ICP's chain: forward disagrees far beyond
    both inputs' errors and is left out, cross-track and yaw agree. ICP open along the
    travel (a corridor): its variance there is its open one, the test cannot fire, VO
    stays."""
    cov = np.diag([1e-6, 1e-6, 1e-8])
    runs = _runs(5, 0.5, [0.27, 0.0, 0.0], cov)
    icp = (np.array([1.25, 0.0, 0.0]), np.diag([5e-6, 5e-6, 5e-8]))
    no_corr = np.zeros((4, 3))
    out, stat = kalman._vo_guard(runs, icp, no_corr, GATE)
    assert out.tolist() == [True, False, False]
    assert stat[0] == pytest.approx(0.1**2 / (5e-6 + 5e-6))
    open_icp = (icp[0], np.diag([kalman.OPEN_SIGMA_M**2, 5e-6, 5e-8]))
    assert not kalman._vo_guard(runs, open_icp, no_corr, GATE)[0].any()
    # VO's errors correlated from run to run make a chain err more: the same difference
    # weighs less (all 20 pairs of runs at +0.5: the chain's variance 5 + 20 x 0.5 runs').
    corr = np.zeros((4, 3))
    corr[:, 0] = 0.5
    small = (np.array([1.35 - 0.012, 0.0, 0.0]), icp[1])
    assert kalman._vo_guard(runs, small, no_corr, GATE)[0][0]
    assert not kalman._vo_guard(runs, small, corr, GATE)[0][0]


def _drive(icp_cov, vo_forward_error, icp_forward_error=0.0, n=801, per_run=20):
    """A straight drive at 40 Hz: ICP's steps (covariance ``icp_cov``, each ``icp_forward_error``
    m too short) and VO runs of ``per_run`` scans, each ``vo_forward_error`` m too long,
    claiming 1.5 mm forward; the true end."""
    t, poses = _line(n, 0.025)
    icp_errors = np.zeros((n - 1, 3))
    icp_errors[:, 0] = -icp_forward_error
    icp = _icp(t, _with_errors(poses, icp_errors), icp_cov)
    runs = (n - 1) // per_run
    vo_errors = np.zeros((runs, 3))
    vo_errors[:, 0] = vo_forward_error
    vo = kalman.increments(
        t[::per_run],
        _with_errors(poses[::per_run], vo_errors),
        np.stack([np.diag([2.25e-6, 1e-6, 1e-8])] * (runs + 1)),
        source="vo",
    )
    return icp + vo, poses[-1]


@pytest.mark.parametrize("mode", ["weighted", "driven", "icp-first"])
def test_a_degenerate_corridor_the_filter_follows_vo_along_the_travel(mode):
    """ICP degenerate along the travel (its Hessian opens it: 10 m 1-sigma) and its steps
    there its initial guess, 2 mm a step short of the truth; VO's runs good (0.2 mm off
    each): the guard never fires along the travel and the filter follows VO there, a few
    millimetres from the truth after 10 m where ICP is 1.6 m off."""
    icp_cov = np.diag([kalman.OPEN_SIGMA_M**2, 1e-8, 1e-10])
    ms, end = _drive(icp_cov, vo_forward_error=2e-4, icp_forward_error=2e-3)
    params = dataclasses.replace(kalman.KF_MODES[mode])
    res = kalman.run_filter(ms, params)
    assert res.vo_guarded[0] == 0
    icp_end = sum(m.motion[0] for m in ms if m.source == "icp")
    vo_end = sum(m.motion[0] for m in ms if m.source == "vo")
    assert abs(icp_end - end[0]) > 1.5
    assert abs(res.poses[-1, 0] - vo_end) < 0.02
    assert abs(res.poses[-1, 0] - end[0]) < 0.03


def _line_icp_vo(rng, vo_forward_errors, vo_cov):
    """A 20 m straight line: ICP's 800 steps, constrained and honest (1 mm forward, drawn
    first from rng), and VO's 40 runs erring forward by vo_forward_errors() under vo_cov."""
    t, poses = _line(801, 0.025)
    icp_errors = np.zeros((800, 3))
    icp_errors[:, 0] = rng.normal(0.0, 1e-3, 800)
    icp_path = _with_errors(poses, icp_errors)
    icp = _icp(t, icp_path, np.diag([1e-6, 9e-8, 1e-10]))
    vo_errors = np.zeros((40, 3))
    vo_errors[:, 0] = vo_forward_errors()
    vo_path = _with_errors(poses[::20], vo_errors)
    vo = kalman.increments(t[::20], vo_path, np.stack([vo_cov] * 41), source="vo")
    return poses, icp_path, icp, vo


@pytest.mark.parametrize("mode", ["weighted", "driven"])
def test_vo_biased_beyond_its_errors_against_a_constrained_icp_is_left_out_forward(mode):
    """ICP constrained and honest (1 mm a step, erring by that); VO's runs 8 mm too long
    each, claiming 1.5 mm: each run is within the chi-square gate against the filter's
    prediction (ICP's chain over a run is looser, 7.7 mm), but over four and eight runs VO's
    chain disagrees with ICP's beyond both errors. The guard leaves VO's forward out of
    most runs (never its cross-track or yaw, which agree), and the filter ends at least a
    third closer to the truth than without it (10 m: 5-6 cm off against 9-10 cm)."""
    rng = np.random.default_rng(3)
    poses, _, icp, vo = _line_icp_vo(rng, lambda: np.full(40, 8e-3), np.diag([2.25e-6, 1e-6, 1e-8]))
    params = kalman.KF_MODES[mode]
    guarded = kalman.run_filter(icp + vo, params)
    unguarded = kalman.run_filter(icp + vo, dataclasses.replace(params, vo_guard=0))
    assert guarded.vo_guarded[0] >= 25
    assert guarded.vo_guarded[1:] == (0, 0)
    assert unguarded.vo_guarded == (0, 0, 0)
    off = {k: abs(r.poses[-1, 0] - poses[-1, 0]) for k, r in (("guarded", guarded), ("unguarded", unguarded))}
    assert off["guarded"] < 0.67 * off["unguarded"]


def test_the_rule_leaves_vo_out_where_its_chain_is_looser_than_icps_unless_icp_is_open():
    """VO's chain agreeing with ICP's (no disagreement to test) but, under both models,
    with four times ICP's variance forward and a quarter of it cross-track: at q* = 1 the
    rule leaves forward out and keeps cross-track; at q* = 8 it keeps both; along a
    direction ICP leaves open VO always stays."""
    cov = np.diag([4e-6, 1e-6, 1e-8])
    runs = _runs(4, 0.5, [0.25, 0.0, 0.0], cov)
    no_corr = np.zeros((3, 3))
    icp = (np.array([1.0, 0.0, 0.0]), np.diag([4e-6, 16e-6, 4e-8]))
    assert not kalman._vo_guard(runs, icp, no_corr, GATE)[0].any()
    assert kalman._vo_guard(runs, icp, no_corr, GATE, pays=1.0)[0].tolist() == [True, False, False]
    assert not kalman._vo_guard(runs, icp, no_corr, GATE, pays=8.0)[0].any()
    open_icp = (icp[0], np.diag([kalman.OPEN_SIGMA_M**2, 16e-6, 4e-8]))
    assert not kalman._vo_guard(runs, open_icp, no_corr, GATE, pays=1.0)[0].any()
    with pytest.raises(ValueError, match="vo_pays"):
        kalman.KfParams(vo_pays=-1.0)


@pytest.mark.parametrize("mode", ["weighted", "driven"])
def test_vo_much_worse_than_a_constrained_icp_leaves_the_filter_on_icps_path(mode):
    """ICP constrained (1 mm a step forward, honest: its chain over a run of 20 steps
    3.7 mm under its model); VO's runs claiming 3 mm forward (2.5 mm under VO's model,
    more over several runs, whose errors it correlates) and erring by it at random, within
    every gate and looser than the filter's prediction: fused as round 7 does, VO moves the
    filter; with the rule at q* = 0.25 (VO's chain has more than a quarter of ICP's
    variance over every window) the filter's path is the filter's on ICP alone (driven:
    ICP's steps chained), to rounding."""
    rng = np.random.default_rng(5)
    _, icp_path, icp, vo = _line_icp_vo(rng, lambda: rng.normal(0.0, 3e-3, 40), np.diag([9e-6, 1e-4, 1e-6]))
    params = dataclasses.replace(kalman.KF_MODES[mode], vo_pays=0.25)
    alone = kalman.run_filter(icp, params)
    ruled = kalman.run_filter(icp + vo, params)
    fused = kalman.run_filter(icp + vo, dataclasses.replace(params, vo_pays=0.0))
    at = np.searchsorted(ruled.stamps_s, alone.stamps_s)
    np.testing.assert_allclose(ruled.poses[at], alone.poses, atol=1e-9)
    assert np.abs(fused.poses[-1] - alone.poses[-1]).max() > 1e-5
    if mode == "driven":
        np.testing.assert_allclose(alone.poses[-1], icp_path[-1], atol=1e-9)


@pytest.mark.parametrize("mode", ["weighted", "driven"])
def test_with_the_rule_vo_still_carries_the_filter_along_icps_open_direction(mode):
    """The degenerate corridor above with the rule on (q* = 1): ICP open along the travel,
    VO carries the filter there."""
    icp_cov = np.diag([kalman.OPEN_SIGMA_M**2, 1e-8, 1e-10])
    ms, end = _drive(icp_cov, vo_forward_error=2e-4, icp_forward_error=2e-3)
    res = kalman.run_filter(ms, dataclasses.replace(kalman.KF_MODES[mode], vo_pays=1.0))
    assert res.vo_guarded[0] == 0
    assert abs(res.poses[-1, 0] - end[0]) < 0.03


def test_icp_first_is_icps_path_where_icp_constrains_the_motion():
    """--kf icp-first on ICP constrained in every direction and VO runs erring at random
    within their claims: VO is left out along every direction of every run, and the
    filter's path is ICP's steps chained."""
    rng = np.random.default_rng(11)
    t, poses = _line(401, 0.025)
    icp_errors = rng.normal(0.0, 1.0, (400, 3)) * [1e-3, 3e-4, 1e-5]
    icp_path = _with_errors(poses, icp_errors)
    icp = _icp(t, icp_path, np.diag([1e-6, 9e-8, 1e-10]))
    vo_errors = rng.normal(0.0, 1.0, (20, 3)) * [3e-4, 3e-4, 1e-5]
    vo = kalman.increments(
        t[::20],
        _with_errors(poses[::20], vo_errors),
        np.stack([np.diag([1e-7, 1e-7, 1e-10])] * 21),
        source="vo",
    )
    params = kalman.KF_MODES["icp-first"]
    assert (params.drive, params.vo_pays) == ("icp", kalman.VO_OPEN_ONLY)
    res = kalman.run_filter(icp + vo, params)
    at = np.searchsorted(res.stamps_s, t)
    np.testing.assert_allclose(res.poses[at], icp_path, atol=1e-9)
    assert sum(res.vo_guarded) > 0
