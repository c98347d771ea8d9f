"""rigcal.stats against scipy.stats: the same tails and quantiles."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from rigcal import stats as rs

Case = tuple[float, float, float, float, float]


def _cases(seed: int, n: int = 300) -> list[Case]:
    """(x, p, dof, dfd, nc): integer and fractional degrees of freedom, tails near 0 and 1."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        dof = float(rng.choice([1.0, 2.0, 3.0, 6.0, rng.uniform(0.5, 60.0)]))
        x = float(rng.exponential(2.0 * dof))
        p = float(rng.choice([1e-9, 0.001, 0.01, 0.05, 0.95, 0.99, 1 - 1e-9, rng.uniform(0, 1)]))
        out.append((x, p, dof, float(rng.uniform(1.01, 200.0)), float(rng.uniform(0.0, 60.0))))
    return out


def _close(a: float, b: float, rel: float = 1e-12) -> None:
    assert math.isfinite(a)
    assert a == pytest.approx(b, rel=rel, abs=1e-300)


@pytest.mark.parametrize("case", _cases(1))
def test_chi_square_and_f_match_scipy_stats(case: Case) -> None:
    x, p, dof, dfd, _ = case
    _close(rs.chi2_sf(x, dof), float(stats.chi2.sf(x, dof)))
    _close(rs.chi2_isf(p, dof), float(stats.chi2.isf(p, dof)))
    _close(rs.chi2_ppf(p, dof), float(stats.chi2.ppf(p, dof)))
    _close(rs.f_sf(x, dof, dfd), float(stats.f.sf(x, dof, dfd)))
    _close(rs.f_ppf(p, dof, dfd), float(stats.f.ppf(p, dof, dfd)))
    _close(rs.f_isf(p, dof, dfd), float(stats.f.isf(p, dof, dfd)))


@pytest.mark.parametrize("case", _cases(2))
def test_normal_and_noncentral_chi_square_match_scipy_stats(
    case: tuple[float, float, float, float, float],
) -> None:
    x, p, dof, _, nc = case
    _close(rs.norm_ppf(p), float(stats.norm.ppf(p)))
    z = x - 2.0 * dof
    _close(rs.norm_sf(z), float(stats.norm.sf(z)))
    # One minus the distribution function: equal in absolute terms (the tail's last
    # digits below 1e-12 differ from Boost's).
    assert abs(rs.ncx2_sf(x, dof, nc) - float(stats.ncx2.sf(x, dof, nc))) < 1e-12
    assert rs.ncx2_sf(x, dof, 0.0) == rs.chi2_sf(x, dof)


@pytest.mark.parametrize("x", [0.0, -1.0, -1e-300])
def test_tails_at_and_below_the_support_are_one(x: float) -> None:
    assert rs.chi2_sf(x, 3) == float(stats.chi2.sf(x, 3)) == 1.0
    assert rs.f_sf(x, 3, 7.5) == float(stats.f.sf(x, 3, 7.5)) == 1.0
    assert rs.ncx2_sf(x, 3, 2.0) == pytest.approx(float(stats.ncx2.sf(x, 3, 2.0)), abs=1e-15)


def test_the_values_the_project_quotes() -> None:
    """Known table values: chi2(1) at 0.999 is 10.83; the two-sided 1 % normal point 2.576."""
    assert rs.chi2_isf(0.001, 1) == pytest.approx(10.827566, abs=1e-6)
    assert rs.chi2_ppf(0.95, 6) == pytest.approx(12.591587, abs=1e-6)
    assert rs.norm_ppf(0.995) == pytest.approx(2.5758293, abs=1e-7)
    assert rs.f_isf(0.05, 3, 10) == pytest.approx(3.7082648, abs=1e-6)
