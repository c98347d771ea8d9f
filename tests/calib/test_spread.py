"""The spread over captures and the sensitivity to noise settings, on linear problems
with a known answer, and through both solvers."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.spread import (
    SPREAD_INFLATE_RATIO,
    Sensitivity,
    Spread,
    expected_jackknife,
    honest_covariance,
    leave_one_out,
    sensitivity,
    uncertainty_warnings,
)
from rigcal.geometry import make_T, rotvec_to_R, tangent_delta


def linear_problem(rng, C=15, rows=2):
    return [rng.normal(0, 1, (rows, 6)) for _ in range(C)]


def solve_linear(blocks, z, skip=None):
    J = np.concatenate([b for i, b in enumerate(blocks) if i != skip])
    y = np.concatenate([v for i, v in enumerate(z) if i != skip])
    return np.linalg.lstsq(J, y, rcond=None)[0]


def as_T(x):
    """A pose whose tangent coordinates about the identity are x (small)."""
    return make_T(rotvec_to_R(x[:3]), x[3:])


def test_expected_jackknife_matches_monte_carlo():
    rng = np.random.default_rng(0)
    blocks = linear_problem(rng, C=12)
    E = expected_jackknife(blocks)
    jacks = []
    for _ in range(3000):
        z = [rng.normal(0, 1, len(b)) for b in blocks]
        xs = np.array([solve_linear(blocks, z, i) for i in range(len(blocks))])
        d = xs - xs.mean(axis=0)
        jacks.append((len(blocks) - 1) / len(blocks) * d.T @ d)
    np.testing.assert_allclose(np.mean(jacks, axis=0), E, atol=0.06 * np.abs(E).max())


@pytest.mark.parametrize(("noise", "expect"), [(1.0, 1.0), (3.0, 3.0)])
def test_spread_scale_says_how_far_the_model_is_off(noise, expect):
    """Whitened with unit noise but the data have `noise`: the spread's scale is about it."""
    rng = np.random.default_rng(1)
    blocks = [100.0 * b for b in linear_problem(rng, C=20)]
    cov_model = np.linalg.inv(sum(b.T @ b for b in blocks))
    E = expected_jackknife(blocks)
    scales = []
    for _ in range(40):
        z = [rng.normal(0, noise, len(b)) for b in blocks]
        x = solve_linear(blocks, z)
        s = leave_one_out(
            lambda i, z=z: as_T(solve_linear(blocks, z, i)),
            as_T(x),
            [f"c{i}" for i in range(20)],
            cov_model,
            E,
        )
        assert isinstance(s, Spread)
        scales.append(s.scale)
    assert np.median(scales) == pytest.approx(expect, rel=0.2)


def test_too_few_captures_give_no_spread():
    assert leave_one_out(lambda i: np.eye(4), np.eye(4), ["a"] * 5, np.eye(6), np.eye(6)) is None


def test_honest_covariance_scales_only_a_clear_excess():
    cov = np.eye(6)
    spread = Spread(("a",), np.zeros((1, 6)), np.eye(6), 1.2, 1.4)
    assert honest_covariance(cov, spread) is cov
    assert honest_covariance(cov, None) is cov
    big = Spread(("a",), np.zeros((1, 6)), 9 * np.eye(6), 3.0, 3.0)
    assert SPREAD_INFLATE_RATIO < 3.0
    np.testing.assert_allclose(honest_covariance(cov, big), 9 * np.eye(6))


def test_tangent_delta_inverts_a_small_move():
    x = np.array([0.01, -0.02, 0.005, 0.1, 0.2, -0.3])
    T0 = make_T(rotvec_to_R([0.3, 0.1, -0.2]), [1.0, 2.0, 3.0])
    T1 = make_T(rotvec_to_R(x[:3]) @ T0[:3, :3], T0[:3, 3] + x[3:])
    np.testing.assert_allclose(tangent_delta(T1, T0), x, atol=1e-12)


def test_sensitivity_and_warnings_name_the_setting_and_the_captures():
    T = np.eye(4)
    cov = np.diag([1e-6] * 3 + [1e-6] * 3)

    def refit(name, value):
        return as_T(np.array([0, 0, 0, 0.005 * value / 0.01, 0, 0]) - np.array([0, 0, 0, 0.005, 0, 0]))

    sens = sensitivity(refit, {"range_sigma_m": 0.01}, T, cov)
    assert [s.factor for s in sens] == [0.5, 2.0]
    assert sens[1].translation_mm == pytest.approx(5.0)
    assert sens[1].sigmas == pytest.approx(5.0)
    spread = Spread(
        ("cap00", "cap01"), np.array([[0, 0, 0, 0.004, 0, 0], [0, 0, 0, 0.0001, 0, 0]]), 9 * cov, 3.0, 3.2
    )
    w = uncertainty_warnings(spread, sens, cov, "range noise")
    assert any("depends on which captures" in x and "cap00" in x for x in w)
    assert any("depends on the settings: range_sigma_m x2" in x for x in w)
    assert not uncertainty_warnings(None, [Sensitivity("x", 2.0, 1.0, 0.0, 0.0, 0.5)], cov, "noise")
