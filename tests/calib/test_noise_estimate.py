"""Noise estimated from the session: robust line fits, range and pixel noise, same-pose groups."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.noise import (
    CLIP_CHI2,
    clipped_chi2_target,
    connected_groups,
    corner_sigma_from_rms,
    fit_line_robust,
    line_offset_covariance,
    matching_noise,
    range_noise_from_lines,
    robust_scale,
)


def wall_returns(rng, sigma_m, n=120, dist=2.0, turn=0.6, noise="normal"):
    """Returns of a straight target `dist` ahead, turned by `turn` rad, range noise added
    along each beam."""
    s = np.linspace(-0.5, 0.5, n)
    u = np.array([np.sin(turn), np.cos(turn)])
    pts = np.array([dist, 0.0]) + s[:, None] * u
    r = np.linalg.norm(pts, axis=1)
    # Normal, or Student-t with 3 dof scaled to the same standard deviation.
    e = rng.normal(0.0, sigma_m, n) if noise == "normal" else rng.standard_t(3, n) * sigma_m / np.sqrt(3.0)
    return pts * ((r + e) / r)[:, None]


def test_robust_scale_of_a_normal_sample():
    x = np.random.default_rng(0).normal(0, 2.0, 20000)
    assert robust_scale(x) == pytest.approx(2.0, rel=0.03)
    assert robust_scale(np.array([1.0])) == 0.0


def test_line_fit_trims_mixed_pixels_and_keeps_the_line():
    rng = np.random.default_rng(1)
    pts = wall_returns(rng, 0.005)
    # Mixed pixels at both edges: returns half-way to a background 1 m behind.
    for k in (0, 1, -2, -1):
        pts[k] *= 1.0 + 0.5 / np.linalg.norm(pts[k])
    fit = fit_line_robust(pts)
    assert not fit.kept[[0, 1, -2, -1]].any()
    assert fit.kept[2:-2].all()
    assert np.std(fit.range_residuals_m) == pytest.approx(0.005, rel=0.2)
    # The ends are on the line, in scan order.
    assert np.abs((fit.ends - fit.centroid) @ fit.normal).max() < 1e-12
    assert (fit.ends[1] - fit.ends[0]) @ (pts[-1] - pts[0]) > 0


@pytest.mark.parametrize("noise", ["normal", "t3"])
@pytest.mark.parametrize("sigma", [0.01, 0.018])
def test_range_noise_is_recovered_from_turned_targets(noise, sigma):
    rng = np.random.default_rng(2)
    fits = [
        fit_line_robust(wall_returns(rng, sigma, turn=t, noise=noise)) for t in np.linspace(-0.9, 0.9, 15)
    ]
    est = range_noise_from_lines(fits)
    if noise == "normal":
        assert est.sigma_m == pytest.approx(sigma, rel=0.08)
        assert est.robust_sigma_m == pytest.approx(sigma, rel=0.1)
    else:
        # The trimmed tails (3.5 robust sigmas) are not in the fit, so what counts is the
        # standard deviation of the noise within the trim: for Student-t(3) about 0.66 of
        # its full one.
        from scipy.stats import t

        scale = sigma / np.sqrt(3.0)
        robust = 1.482602218505602 * t.ppf(0.75, 3) * scale
        c = 3.5 * robust / scale
        inside = t.expect(lambda x: x**2, args=(3,), lb=-c, ub=c, conditional=True)
        assert est.robust_sigma_m == pytest.approx(robust, rel=0.15)
        assert est.sigma_m == pytest.approx(np.sqrt(inside) * scale, rel=0.15)
        assert est.robust_sigma_m < 0.9 * est.sigma_m
    assert est.returns + est.trimmed == 15 * 120
    assert len(est.per_capture_m) == 15


def test_range_noise_needs_three_returns():
    fit = fit_line_robust(np.array([[1.0, 0.0], [1.0, 0.1]]))
    with pytest.raises(ValueError, match="3 or more"):
        range_noise_from_lines([fit])


def test_line_offset_covariance_matches_monte_carlo():
    rng = np.random.default_rng(3)
    along = np.linspace(-0.4, 0.4, 30)
    at = np.array([-0.5, 0.5])
    off = []
    for _ in range(4000):
        d = rng.normal(0, 0.01, len(along))
        slope, icpt = np.polyfit(along, d, 1)
        off.append(icpt + slope * at)
    np.testing.assert_allclose(np.cov(np.array(off).T), line_offset_covariance(along, 0.01, at), rtol=0.08)


def test_corner_sigma_from_rms():
    rng = np.random.default_rng(4)
    n = 48
    rms = []
    for _ in range(20):
        e = rng.normal(0, 0.4, (n, 2))
        # A pose fit takes 6 dof: emulate by removing 3 of every 48 corners' worth.
        rms.append(np.sqrt(np.sum(e**2) * (2 * n - 6) / (2 * n) / n))
    assert corner_sigma_from_rms(np.array(rms), n) == pytest.approx(0.4, rel=0.05)


def test_matching_noise_finds_the_sigma_and_resists_outliers():
    rng = np.random.default_rng(5)
    e = rng.normal(0, 1.5, (400, 2))
    e[:8] = 50.0  # gross outliers

    def chi2_at(s):
        return np.sum((e / s) ** 2, axis=1)

    s = matching_noise(chi2_at, 1.0, 0.01, 100.0)
    assert s == pytest.approx(1.5, rel=0.1)
    assert matching_noise(chi2_at, 1.0, 100.0, 200.0) == 100.0
    assert matching_noise(chi2_at, 1.0, 1e-4, 1e-3) == 1e-3
    assert clipped_chi2_target() == pytest.approx(2 * (1 - np.exp(-CLIP_CHI2 / 2)))


def test_connected_groups_are_transitive():
    same = np.eye(5, dtype=bool)
    same[0, 1] = same[1, 0] = True
    same[1, 3] = same[3, 1] = True
    g = connected_groups(same)
    assert g[0] == g[1] == g[3]
    assert len({g[0], g[2], g[4]}) == 3


def test_grouped_verdicts_give_repeats_one_verdict():
    from rigcal.calib.noise import grouped_verdicts

    gate = 18.42
    # Three repeats of a pose straddle the gate; alone they would be split 1 in, 2 out.
    chi2 = np.array([1.0, 2.0, 0.5, 1.5, 1.2, 17.0, 20.0, 21.3])
    groups = np.array([0, 1, 2, 3, 4, 5, 5, 5])
    used = np.arange(8) < 5
    v = grouped_verdicts(chi2, groups, used, gate)
    assert v.tolist() == [True] * 5 + [False] * 3
    assert (chi2 < gate).tolist() != v.tolist()
    # The gate scales with the robust size of the used ones (never below 1).
    assert grouped_verdicts(chi2 * 10, groups, used, gate)[:5].all()
