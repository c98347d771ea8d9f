"""The Kalman filter's states for VO's errors over seconds: a forward scale factor, a
cross-track drift per metre and a yaw-rate bias (kalman._bias_decay, kalman._learn_bias)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from rigcal.geometry import pose_of, se2
from rigcal.localize import kalman

WEIGHTED = kalman.KF_MODES["weighted"]
# A VO whose biases hold over the whole drive (a scale error of its own, not the simulated
# laps' 1.3 s): time constants of 100 s.
STEADY = dataclasses.replace(WEIGHTED, vo_bias_sigma=(0.02, 0.02, 0.01), vo_bias_s=(100.0, 100.0, 100.0))


def _biased(poses, scale, cross, yaw_rate, dt):
    """Odometry whose every step errs by ``scale`` of its forward motion forward, ``cross``
    of it sideways and ``yaw_rate`` x dt in yaw."""
    out = [poses[0]]
    for k in range(1, len(poses)):
        step = pose_of(np.linalg.inv(se2(poses[k - 1])) @ se2(poses[k]))
        step = step + np.array([scale * step[0], cross * step[0], yaw_rate * dt])
        out.append(pose_of(se2(out[-1]) @ se2(step)))
    return np.array(out)


def _drive(rng, bias, open_after_s=None, w=0.0):
    """A 40 s drive at 0.5 m/s (an arc of w rad/s): ICP at 40 Hz with small white errors
    (after ``open_after_s`` open along the travel: a corridor whose ends are out of range,
    its forward motion there a guess), VO runs of 0.5 s off by ``bias`` (scale, cross-track
    per metre, yaw rate) and white errors of a tenth of their claimed 1-sigma (2 mm, 2 mm,
    0.5 mrad). Returns the increments, ICP's stamps and the truth there."""
    t = np.arange(1601) * 0.025
    truth = np.column_stack([0.5 * t, np.zeros_like(t), w * t])
    if w:
        truth[:, 0], truth[:, 1] = np.sin(w * t) * 0.5 / w, (1 - np.cos(w * t)) * 0.5 / w
    sigma = np.array([5e-5, 5e-5, 5e-6])
    icp = [truth[0]]
    covs = np.stack([np.diag(sigma**2)] * len(t))
    for k in range(1, len(t)):
        step = pose_of(np.linalg.inv(se2(truth[k - 1])) @ se2(truth[k])) + rng.normal(size=3) * sigma
        if open_after_s is not None and t[k] > open_after_s:
            step[0] += rng.normal() * 0.01  # the guess's error
            covs[k] = np.diag([kalman.OPEN_SIGMA_M**2, *sigma[1:] ** 2])
        icp.append(pose_of(se2(icp[-1]) @ se2(step)))
    ms = kalman.increments(t, np.array(icp), covs, source="icp")
    t_vo = t[::20]
    vo_sigma = np.array([2e-3, 2e-3, 5e-4])
    vo = _biased(truth[::20], *bias, 0.5)
    noisy = [vo[0]]
    for k in range(1, len(vo)):
        step = pose_of(np.linalg.inv(se2(vo[k - 1])) @ se2(vo[k])) + 0.1 * vo_sigma * rng.normal(size=3)
        noisy.append(pose_of(se2(noisy[-1]) @ se2(step)))
    run_covs = np.stack([np.diag(vo_sigma**2)] * (len(t_vo) - 1))
    ms += kalman.vo_increments(t_vo, np.array(noisy), ["ok"] * (len(t_vo) - 1), run_covs)
    return ms, t, truth


def _ate(res, t, truth):
    g = np.column_stack([np.interp(res.stamps_s, t, truth[:, i]) for i in range(2)])
    return float(np.sqrt(np.mean(np.sum((res.poses[:, :2] - g) ** 2, axis=1))))


def test_the_bias_constants_are_the_fits_of_laps_1_2():
    for k in range(3):
        share, _, tau = kalman.gauss_markov_fit(kalman.VO_BIAS_LAGS[k], kalman.VO_RUN_S)
        assert kalman.VO_BIAS_SIGMA[k] == pytest.approx(kalman.VO_BIAS_RMS[k] * np.sqrt(share))
        assert kalman.VO_BIAS_S[k] == pytest.approx(tau)
        assert kalman.VO_BIAS_SHARE[k] == pytest.approx(share)
    assert kalman.VO_BIASED.vo_bias_share == kalman.VO_BIAS_SHARE
    # Seconds: each longer than the forward memory's.
    assert min(kalman.VO_BIAS_S) > kalman.VO_MEMORY_S
    # Measured options, off in the CLI's modes.
    assert kalman.VO_BIASED.vo_bias_sigma == kalman.VO_BIAS_SIGMA
    for mode in kalman.KF_MODES.values():
        assert mode.vo_bias_sigma == (0.0, 0.0, 0.0)
    assert (kalman.DRIVE_PROCESS.accel_sigma, kalman.DRIVE_PROCESS.yaw_accel_sigma) == (5.1, 4.7)
    with pytest.raises(ValueError, match="vo_bias_sigma"):
        kalman.KfParams(vo_bias_sigma=(-1.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="time constants"):
        kalman.KfParams(vo_bias_sigma=(0.01, 0.0, 0.0), vo_bias_s=(0.0, 1.0, 1.0))
    with pytest.raises(ValueError, match="shares in"):
        kalman.KfParams(vo_bias_share=(1.0, 0.0, 0.0))


def test_the_bias_state_decays_to_its_stationary_variance():
    x, P = np.zeros(6), np.eye(6)
    blocks: list[tuple[str, float]] = []
    x, P = kalman._bias_decay(x, P, blocks, 1.0, kalman.VO_BIASED)
    var = np.square(kalman.VO_BIAS_SIGMA)
    assert np.diag(P)[6:] == pytest.approx(var)
    x[6:] = [0.01, 0.002, 0.001]
    x, P = kalman._bias_decay(x, P, blocks, 2.0, kalman.VO_BIASED)
    phi = np.exp(-1.0 / np.array(kalman.VO_BIAS_S))
    assert x[6:] == pytest.approx(phi * [0.01, 0.002, 0.001])
    assert np.diag(P)[6:] == pytest.approx(var)  # stationary: phi^2 var + (1 - phi^2) var
    assert blocks == [("bias", 2.0)]


@pytest.mark.parametrize("bias", [(0.02, 0.0, 0.0), (0.0, 0.0, 2e-3), (0.0, 0.01, 0.0)])
def test_a_biased_vo_has_its_bias_learned_against_icp(bias):
    """Where ICP fixes the motion the filter knows it better than any VO run, so VO moves
    no pose (its path is ICP's), but its bias is learned: the state converges to VO's."""
    ms, t, truth = _drive(np.random.default_rng(3), bias, w=0.2)
    res = kalman.run_filter(ms, STEADY)
    assert res.vo_bias is not None
    # Each within a tenth of VO's bias, and of a tenth of the prior's sigma (the other axes
    # take a little of what the one biased axis shows).
    tolerance = 0.1 * np.abs(bias) + 0.1 * np.array(STEADY.vo_bias_sigma)
    assert np.all(np.abs(res.vo_bias - np.array(bias)) < tolerance), res.vo_bias
    icp_alone = kalman.run_filter([m for m in ms if m.source == "icp"], STEADY)
    assert _ate(res, t, truth) == pytest.approx(_ate(icp_alone, t, truth), rel=0.02)


def test_a_learned_scale_bias_carries_the_filter_along_a_corridor():
    """20 s where ICP fixes the motion, then 20 s along a corridor ICP leaves open: VO
    carries the filter there (as without the bias states), corrected by the scale error it
    was found to have, so the filter ends near the truth where without the bias states it
    ends VO's 2 % short of it."""
    ms, _, truth = _drive(np.random.default_rng(5), (-0.02, 0.0, 0.0), open_after_s=20.0)
    res = kalman.run_filter(ms, STEADY)
    without = kalman.run_filter(ms, dataclasses.replace(STEADY, vo_bias_sigma=(0.0, 0.0, 0.0)))
    assert without.vo_bias is None
    end_with, end_without = abs(res.poses[-1, 0] - truth[-1, 0]), abs(without.poses[-1, 0] - truth[-1, 0])
    assert end_without > 0.15  # 2 % of the corridor's 10 m
    assert end_with < 0.2 * end_without
    # Unobserved along the corridor, the estimate decays with its time constant.
    assert res.vo_bias is not None
    assert res.vo_bias[0] == pytest.approx(-0.02 * np.exp(-20.0 / STEADY.vo_bias_s[0]), abs=0.002)


def test_an_unbiased_vo_leaves_the_bias_states_within_their_spread():
    ms, _, _ = _drive(np.random.default_rng(4), (0.0, 0.0, 0.0), w=0.2)
    res = kalman.run_filter(ms, kalman.VO_BIASED)
    assert res.vo_bias is not None
    assert np.all(np.abs(res.vo_bias) < 2.0 * np.array(kalman.VO_BIAS_SIGMA))
