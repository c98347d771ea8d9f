"""The distributions' tails and quantiles rigcal's tests use, as scipy.special's functions.

The drift checks (chi-square, Hotelling's F, the targetless check's detectable change),
the Kalman filter's gates and the calibration's coverage factors need a few tail
probabilities and quantiles. ``scipy.stats`` gives them, but importing it builds every
distribution's docstring and pulls in scipy.optimize, scipy.spatial and scipy.interpolate:
about a second of each command's start-up. These are the functions its ``chi2``, ``f``,
``ncx2`` and ``norm`` call underneath (scipy.stats' ``_continuous_distns``), so the
values are the same (tests/test_stats.py compares them).

Scalars in, floats out; degrees of freedom may be fractional (Satterthwaite's counts). The
non-central chi-square's tail is one minus its distribution function (scipy.stats uses
Boost's tail, not public in scipy.special): the same to about 1e-15, but it reaches 0 where
the tail is below about 1e-16.

scipy.special is imported at the first call (about 0.2 CPU s, with scipy.linalg, which
the drift check's first seconds do without).
"""

from __future__ import annotations

from types import ModuleType


def _special() -> ModuleType:
    from scipy import special

    return special


def chi2_sf(x: float, dof: float) -> float:
    """P(X > x) for X chi-square with ``dof`` degrees of freedom (``chi2.sf``)."""
    return float(_special().chdtrc(dof, max(x, 0.0)))  # 1 below the support, as scipy.stats


def chi2_isf(q: float, dof: float) -> float:
    """The x with P(X > x) = q, X chi-square with ``dof`` dof (``chi2.isf``)."""
    return float(_special().chdtri(dof, q))


def chi2_ppf(p: float, dof: float) -> float:
    """The x with P(X <= x) = p, X chi-square with ``dof`` dof (``chi2.ppf``: twice the
    inverse of the regularized lower incomplete gamma function at dof / 2)."""
    return float(2.0 * _special().gammaincinv(dof / 2.0, p))


def f_sf(x: float, dfn: float, dfd: float) -> float:
    """P(X > x) for X F-distributed with (dfn, dfd) degrees of freedom (``f.sf``)."""
    return float(_special().fdtrc(dfn, dfd, max(x, 0.0)))


def f_ppf(p: float, dfn: float, dfd: float) -> float:
    """The x with P(X <= x) = p, X F(dfn, dfd) (``f.ppf``)."""
    return float(_special().fdtri(dfn, dfd, p))


def f_isf(q: float, dfn: float, dfd: float) -> float:
    """The x with P(X > x) = q, X F(dfn, dfd) (``f.isf``: the quantile at 1 - q)."""
    return float(_special().fdtri(dfn, dfd, 1.0 - q))


def ncx2_sf(x: float, dof: float, nc: float) -> float:
    """P(X > x) for X non-central chi-square with ``dof`` dof and non-centrality ``nc``
    (``ncx2.sf``; the central chi-square's at nc = 0)."""
    if nc == 0.0:
        return chi2_sf(x, dof)
    return float(1.0 - _special().chndtr(max(x, 0.0), dof, nc))


def norm_ppf(p: float) -> float:
    """The standard normal's quantile at p (``norm.ppf``)."""
    return float(_special().ndtri(p))


def norm_sf(x: float) -> float:
    """P(Z > x) for Z standard normal (``norm.sf``)."""
    return float(_special().ndtr(-x))
