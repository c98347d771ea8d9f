"""The Kalman filter's model of VO's forward error: its Gauss-Markov memory, the forward
variance ratio matched on line, the whiteness test on the forward innovations."""

from __future__ import annotations

import numpy as np
import pytest
from odometry_paths import line as _line
from odometry_paths import with_errors as _with_errors

from rigcal.localize import kalman


def _plain(**changes):
    """The weighted filter without the remedies (each step's own covariance as it is, VO's
    forward without memory), with ``changes``."""
    base = {"icp_own": 1.0, "icp_shared": 0.0, "vo_own": 1.0, "vo_shared": 0.0, "adapt": False}
    base |= {"gate": 0.0, "gate_window": 1, "vo_weak_only": 0.0}
    base |= {"vo_memory_s": 0.0, "vo_forward_adapt": False, "vo_forward_window": 0}
    base |= {"vo_guard": 0, "vo_forward_reference": False}
    return kalman.KfParams(**{**base, **changes})


def _gauss_markov(rng, n, phi, share):
    """n unit-variance errors: an own white part (1 - share) and a first-order Gauss-Markov
    part (share) with phi from one to the next."""
    g = np.empty(n)
    g[0] = rng.normal()
    for k in range(1, n):
        g[k] = phi * g[k - 1] + np.sqrt(1 - phi**2) * rng.normal()
    return np.sqrt(share) * g + np.sqrt(1 - share) * rng.normal(size=n)


def test_a_gauss_markov_fit_recovers_its_share_and_time_constant():
    share, phi, tau = kalman.gauss_markov_fit([0.6 * 0.7**lag for lag in (1, 2, 3)], 0.5)
    assert (share, phi, tau) == pytest.approx((0.6, 0.7, -0.5 / np.log(0.7)))
    # Only the leading positive correlations count; a single one gives phi = share.
    assert kalman.gauss_markov_fit([0.49, -0.1, 0.2], 0.5)[:2] == pytest.approx((0.7, 0.7))
    assert kalman.gauss_markov_fit([-0.3, 0.1, 0.0], 0.5) == (0.0, 0.0, 0.0)
    # The share leaves a step a tenth of its error its own, as a two-run share does.
    assert kalman.gauss_markov_fit([0.95, 0.9, 0.85], 0.5)[0] == pytest.approx(2 * kalman.MAX_LAG1)
    # VO's constants are the fit of its laps 1-2 correlations.
    fit = kalman.gauss_markov_fit(kalman.VO_FORWARD_LAGS, kalman.VO_RUN_S)
    assert fit == (kalman.VO_MEMORY_SHARE, kalman.VO_MEMORY_PHI, kalman.VO_MEMORY_S)
    assert 0.5 < kalman.VO_MEMORY_S < 1.2
    assert (
        kalman.VO_MEMORY_PHI**kalman.VO_FORWARD_WINDOW
        < 0.05
        < kalman.VO_MEMORY_PHI ** (kalman.VO_FORWARD_WINDOW - 1)
    )
    for bad in ([0.5], [0.5, np.nan]):
        with pytest.raises(ValueError, match="expected two or more"):
            kalman.gauss_markov_fit(bad, 0.5)
    with pytest.raises(ValueError, match="runs > 0 s"):
        kalman.gauss_markov_fit([0.5, 0.3], 0.0)


def _corridor(rng, runs, run_s, forward_errors, sigma_f=2e-3):
    """ICP at 10 Hz precise across and in yaw, open along the travel (a corridor), and VO
    runs of ``run_s`` whose forward errors are ``forward_errors`` (runs,) x ``sigma_f``,
    each run claiming ``sigma_f``: (measurements, true end pose)."""
    per_run = round(run_s / 0.1)
    t, poses = _line(runs * per_run + 1, 0.1)
    icp_cov = np.diag([kalman.OPEN_SIGMA_M**2, 1e-8, 1e-10])
    icp = kalman.increments(t, poses, np.stack([icp_cov] * len(t)), source="icp")
    errors = np.zeros((runs, 3))
    errors[:, 0] = forward_errors * sigma_f
    vo_t, vo_poses = t[::per_run], _with_errors(poses[::per_run], errors)
    vo_cov = np.diag([sigma_f**2, 1e-6, 1e-8])
    vo = kalman.increments(vo_t, vo_poses, np.stack([vo_cov] * len(vo_t)), source="vo")
    return icp + vo, poses[-1]


def test_vo_forward_errors_with_memory_keep_the_filter_consistent():
    """VO runs whose forward errors are mostly a Gauss-Markov process (0.54 from one run to
    the next), ICP open along the travel: a chain of runs errs by about three times its
    runs' variances summed. With the memory state the filter's forward NEES at the end is
    about 1 (1 dof); taking the runs as independent it is about three times that."""
    rng = np.random.default_rng(7)
    run_s, share = 0.5, 0.9
    phi = np.exp(-run_s / kalman.VO_MEMORY_S)
    nees = {"memory": [], "independent": []}
    for _ in range(40):
        ms, end = _corridor(rng, 30, run_s, _gauss_markov(rng, 30, phi, share))
        for key, params in (
            ("memory", _plain(vo_memory_s=kalman.VO_MEMORY_S, vo_memory_share=share)),
            ("independent", _plain()),
        ):
            res = kalman.run_filter(ms, params)
            e = res.poses[-1, 0] - end[0]
            nees[key].append(e**2 / res.covariances[-1, 0, 0])
    memory, independent = np.mean(nees["memory"]), np.mean(nees["independent"])
    assert 0.5 < memory < 1.7
    assert independent > 2.0 * memory


@pytest.mark.parametrize(("sigma_ratio", "low", "high"), [(1.0, 0.6, 1.6), (3.0, 5.0, 14.0)])
def test_vos_forward_variance_ratio_is_matched_to_its_innovations(sigma_ratio, low, high):
    """VO runs erring forward by 1 or 3 times their claimed 1-sigma against a precise ICP:
    the forward ratio matched on line, starting from the laps' 0.72, ends near 1 or 9.
    Each run ends with an ICP step, which updates first (the shorter step at a common
    end), so the run is compared with ICP's whole chain, a prediction tight enough for the
    run's innovation to weigh fully."""
    rng = np.random.default_rng(11)
    t, poses = _line(1001, 0.1)
    icp = kalman.increments(t, poses, np.stack([np.diag([1e-8, 1e-8, 1e-10])] * len(t)), source="icp")
    errors = np.zeros((200, 3))
    errors[:, 0] = rng.normal(0.0, sigma_ratio * 2e-3, 200)
    vo_t = t[::5]
    vo = kalman.increments(
        vo_t, _with_errors(poses[::5], errors), np.stack([np.diag([4e-6, 1e-6, 1e-8])] * 201), source="vo"
    )
    params = _plain(vo_own=(0.072, 1.0, 1.0), vo_shared=(0.324, 0.0, 0.0), vo_memory_s=kalman.VO_MEMORY_S)
    fixed = kalman.run_filter(icp + vo, params)
    assert fixed.vo_forward_ratio == pytest.approx(0.72)
    matched = kalman.run_filter(icp + vo, _plain(**{**params.__dict__, "vo_forward_adapt": True}))
    assert low < matched.vo_forward_ratio < high


def test_a_forward_bias_within_every_gate_is_left_out_by_the_whiteness_test():
    """Twenty VO runs in a row 2.5 sigma long (squared distances about 6, within the single
    and the windowed gate): their standardized forward innovations summed over five runs
    fail the whiteness test, VO's forward is left out while they do, and the path ends
    less than half as far off as without the test."""
    t, poses = _line(401, 0.1)
    # ICP exact but claiming 1 mm a step: five steps' chain is as loose as a run.
    icp = kalman.increments(t, poses, np.stack([np.diag([1e-6, 1e-6, 1e-10])] * len(t)), source="icp")
    errors = np.zeros((80, 3))
    errors[20:40, 0] = 2.5 * np.sqrt(4e-6 + 5 * 1e-6)  # the innovation's 1-sigma: the run's and ICP's chain
    vo = kalman.increments(
        t[::5], _with_errors(poses[::5], errors), np.stack([np.diag([4e-6, 1e-6, 1e-8])] * 81), source="vo"
    )
    base = {"vo_memory_s": kalman.VO_MEMORY_S, "gate": kalman.VO_GATE, "gate_window": kalman.VO_WINDOW}
    tested = kalman.run_filter(icp + vo, _plain(**base, vo_forward_window=kalman.VO_FORWARD_WINDOW))
    untested = kalman.run_filter(icp + vo, _plain(**base))
    assert tested.vo_forward_left_out >= 10
    assert untested.vo_forward_left_out == 0
    off = {k: abs(r.poses[-1, 0] - poses[-1, 0]) for k, r in (("tested", tested), ("untested", untested))}
    assert off["tested"] < 0.5 * off["untested"]


def test_the_memorys_settings_are_checked():
    for bad, match in (
        ({"vo_memory_s": -1.0}, "vo_memory_s"),
        ({"vo_memory_share": 1.0}, "vo_memory_share"),
        ({"vo_forward_window": -1}, "vo_forward_window"),
    ):
        with pytest.raises(ValueError, match=match):
            kalman.KfParams(**bad)
    fixed = kalman.KF_MODES["fixed"]
    assert (fixed.vo_memory_s, fixed.vo_forward_adapt, fixed.vo_forward_window) == (0.0, False, 0)
    weighted = kalman.KF_MODES["weighted"]
    assert (weighted.vo_memory_s, weighted.vo_memory_share) == (kalman.VO_MEMORY_S, kalman.VO_MEMORY_SHARE)
    assert weighted.vo_forward_adapt
    assert weighted.vo_forward_window == kalman.VO_FORWARD_WINDOW
