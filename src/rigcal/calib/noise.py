"""Noise estimated from the session itself, not assumed.

A scanner's data sheet gives one range noise; a real scan of a real target is noisier
(14-20 mm on a Hokuyo URG against a board, heavy-tailed, with mixed pixels at edges), and
a solve whose weights assume 10 mm both mis-weights its captures and states an
uncertainty that is too small. Two estimates come from the data alone, before any
calibration exists:

- **range noise** from the returns on the target: in each capture they lie on one straight
  line (the box side, the board's cut with the scan plane). A robust total least-squares
  line (:func:`fit_line_robust`: trimmed at 3.5 robust sigmas, so mixed pixels and stray
  returns do not count) leaves residuals across the line; a return's range error e moves
  it across the line by e |cos(incidence)|, so each residual divided by |cos(incidence)|
  is a sample of the range noise (:func:`range_noise_from_lines`);
- **pixel noise** from reprojection residuals, once a pose exists: the box ends'
  (:func:`matching_noise` over the pick noise) and the board corners' under their PnP pose
  (:func:`corner_sigma_from_rms`).

The covariance of a fitted line's offset at any point along it (:func:`line_offset_covariance`)
is shared by the box method (the box ends) and the board method (the two ends of the
board's cut).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import brentq

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.lines import fit_line

# MAD_TO_SIGMA * MAD is the standard deviation of a normal sample.
# Returns farther than this many robust sigmas from the fitted line are not the target's
# (mixed pixels at edges, stray returns); 3.5 keeps 99.95 % of normal noise.
TRIM_SIGMAS = 3.5
# The cosine of incidence is floored here: a grazing beam's residual across the line says
# little about its range noise.
MIN_COS_INCIDENCE = 0.2
# Median of the chi-square distribution with 2 degrees of freedom.
CHI2_2DOF_MEDIAN = 1.3862943611198906


def robust_scale(x: FloatArray) -> float:
    """1.4826 times the median absolute deviation from the median (0 for fewer than 2)."""
    x = np.asarray(x, dtype=float)
    if len(x) < 2:
        return 0.0
    return float(MAD_TO_SIGMA * np.median(np.abs(x - np.median(x))))


@dataclass(frozen=True)
class LineFit:
    """A robust total least-squares line through a target's returns.

    Attributes:
        centroid: (2,) mean of the kept returns.
        direction: (2,) unit vector along the line.
        normal: (2,) unit normal of the line.
        residuals_m: (M,) signed distance of every return from the line.
        kept: (M,) bool, returns within TRIM_SIGMAS robust sigmas of the line.
        cos_incidence: (M,) |cos| of the angle between each return's beam and the normal
            (floored at MIN_COS_INCIDENCE).
        along_m: (M,) position of every return along the line, from the centroid.
    """

    centroid: FloatArray
    direction: FloatArray
    normal: FloatArray
    residuals_m: FloatArray
    kept: NDArray[np.bool_]
    cos_incidence: FloatArray
    along_m: FloatArray

    @property
    def range_residuals_m(self) -> FloatArray:
        """(K,) the kept returns' residuals as range errors (divided by |cos incidence|)."""
        out: FloatArray = self.residuals_m[self.kept] / self.cos_incidence[self.kept]
        return out

    @property
    def extent_m(self) -> FloatArray:
        """(2,) the kept returns' least and greatest position along the line (the
        extreme ones, whatever order the returns were given in)."""
        s = self.along_m[self.kept]
        return np.array([s.min(), s.max()])

    @property
    def ends(self) -> FloatArray:
        """(2, 2) the outermost kept returns projected on the line, in the line's direction."""
        out: FloatArray = self.centroid + self.extent_m[:, None] * self.direction
        return out


def _tls(points: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Centroid, direction and normal of the total least-squares line, the direction's sign
    fixed by the line alone (:func:`canonical_direction`), not by the points' order."""
    c, u, _ = fit_line(points)
    u = canonical_direction(c, u)
    return c, u, np.array([-u[1], u[0]])


def canonical_direction(point: FloatArray, direction: FloatArray) -> FloatArray:
    """The sign of a line's direction that depends on the line only: counter-clockwise as
    seen from the sensor's origin (``point x direction > 0``, ``point`` on the line), the
    order a counter-clockwise scanner sweeps it; for a line through the origin, the
    direction with positive x (then y). The same returns given in any order, or with
    their angles in -pi..pi or 0..2pi, give the same line with the same direction."""
    u = np.asarray(direction, dtype=float)
    cross = float(point[0] * u[1] - point[1] * u[0])
    if abs(cross) > 1e-12 * max(float(np.hypot(point[0], point[1])), 1e-300):
        flip = cross < 0
    else:
        flip = u[0] < 0 or (u[0] == 0 and u[1] < 0)
    return -u if flip else u


def fit_line_robust(points: FloatArray, iterations: int = 4) -> LineFit:
    """Fit a line to a target's returns, trimming returns that are not on it.

    The result depends on the set of returns, not on their order (the direction's sign is
    :func:`canonical_direction`'s, the ends are the extreme kept returns).

    Args:
        points: (M, 2) returns in the laser frame (M >= 2), in any order.
        iterations: fit-and-trim rounds.
    """
    given = np.asarray(points, dtype=float)
    # Work on the returns in one fixed order (the sums in floating point then come out to the
    # last bit the same for any order); the arrays returned follow the order given.
    order = canonical_order(given)
    p = given[order]
    kept = np.ones(len(p), dtype=bool)
    rays = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-12)
    for _ in range(iterations):
        c, u, n = _tls(p[kept])
        r = (p - c) @ n
        cos = np.maximum(np.abs(rays @ n), MIN_COS_INCIDENCE)
        scale = robust_scale((r / cos)[kept])
        if scale <= 0 or kept.sum() <= 3:
            break
        new = np.abs(r / cos) <= TRIM_SIGMAS * scale
        if new.sum() < max(2, kept.sum() // 2) or np.array_equal(new, kept):
            break
        kept = new
    c, u, n = _tls(p[kept])
    r = (p - c) @ n
    cos = np.maximum(np.abs(rays @ n), MIN_COS_INCIDENCE)
    back = np.empty_like(order)
    back[order] = np.arange(len(order))
    return LineFit(c, u, n, r[back], kept[back], cos[back], ((p - c) @ u)[back])


def canonical_order(points: FloatArray) -> NDArray[np.int64]:
    """(M,) the order that sorts (M, 2) points by x, then y: a fixed order for a set of
    returns, so that what is computed from them does not depend on the order they were
    listed in (a file's lines, a scan's start angle)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    return np.lexsort((p[:, 1], p[:, 0])).astype(np.int64)


@dataclass(frozen=True)
class RangeNoise:
    """Range noise of a session's target returns, estimated from their line fits.

    Attributes:
        sigma_m: the pooled estimate (1 sigma, metres): the RMS of every capture's kept
            residuals as range errors, with the line fits' 2 dof per capture taken out.
        robust_sigma_m: 1.4826 MAD of the same residuals (the core of a heavy-tailed
            distribution; well below ``sigma_m`` when the tails are heavy).
        per_capture_m: (C,) each capture's own estimate (nan where fewer than 4 returns).
        returns: kept returns in all.
        trimmed: returns trimmed as not on the target (mixed pixels, strays).
    """

    sigma_m: float
    robust_sigma_m: float
    per_capture_m: FloatArray
    returns: int
    trimmed: int

    def to_dict(self) -> dict[str, object]:
        """Plain form for reports."""
        return {
            "sigma_m": round(self.sigma_m, 6),
            "robust_sigma_m": round(self.robust_sigma_m, 6),
            "returns": self.returns,
            "trimmed": self.trimmed,
        }


def range_noise_from_lines(fits: Sequence[LineFit]) -> RangeNoise:
    """Pool the range residuals of every capture's target line (see the module docstring).

    Raises:
        ValueError: no capture has 3 or more kept returns (nothing to estimate from).
    """
    per, pooled = [], []
    dof = 0
    ss = 0.0
    trimmed = 0
    for f in fits:
        e = f.range_residuals_m
        trimmed += int((~f.kept).sum())
        if len(e) < 3:
            per.append(np.nan)
            continue
        # A TLS line takes 2 dof from its returns.
        ss += float(e @ e)
        dof += len(e) - 2
        per.append(float(np.sqrt(float(e @ e) / (len(e) - 2))) if len(e) >= 4 else np.nan)
        pooled.append(e)
    if dof <= 0:
        raise ValueError("no capture has 3 or more returns on its target")
    allr = np.concatenate(pooled)
    return RangeNoise(float(np.sqrt(ss / dof)), robust_scale(allr), np.array(per), len(allr), trimmed)


def line_offset_covariance(along_m: FloatArray, sigma_across_m: float, at_m: FloatArray) -> FloatArray:
    """(K, K) covariance of a least-squares line's offset across itself at positions
    ``at_m`` along it, fitted to returns at ``along_m`` (measured from their centroid) with
    noise ``sigma_across_m`` across the line each.

    Offset at the centroid and slope are independent: var d(s) = sigma^2 (1/M + s^2/S),
    cov(d(s0), d(s1)) = sigma^2 (1/M + s0 s1 / S), S the sum of squared positions.
    """
    a = np.asarray(along_m, dtype=float)
    s = np.asarray(at_m, dtype=float)
    S = max(float(a @ a), 1e-12)
    out: FloatArray = sigma_across_m**2 * (1.0 / len(a) + np.outer(s, s) / S)
    return out


def corner_sigma_from_rms(rms_px: FloatArray, corners: int) -> float:
    """Pixel noise of board corners (1 sigma per axis) from each capture's RMS
    reprojection error under its PnP pose: sum of squares over 2N - 6 dof per capture."""
    rms = np.asarray(rms_px, dtype=float)
    ss = float(np.sum(rms**2) * corners)  # RMS is over corners of the 2-vector error
    dof = len(rms) * (2 * corners - 6)
    return float(np.sqrt(ss / max(dof, 1)))


# Squared whitened 2-vectors are clipped here (the chi-square 99.9 % point for 2 dof) when
# a noise is matched to them, so that gross outliers count as no more than a bad inlier.
CLIP_CHI2 = 13.815510557964274


def clipped_chi2_target(dof_fraction: float = 1.0) -> float:
    """E[min(X, CLIP_CHI2)] for X chi-square with 2 dof (exponential, mean 2), times the
    fraction of the residuals' dof the fit leaves (1 - parameters / residuals)."""
    return float(2.0 * (1.0 - np.exp(-CLIP_CHI2 / 2.0)) * dof_fraction)


def matching_noise(
    chi2_at: Callable[[float], FloatArray], dof_fraction: float, lo: float, hi: float
) -> float:
    """The noise value s in [lo, hi] at which the clipped mean of the squared whitened
    errors (2 dof each) ``chi2_at(s)`` is what the noise model predicts. The clipped mean is
    nearly as efficient as the mean on clean data and as robust as a median to a few gross
    outliers. Where even ``lo`` over-explains the errors, ``lo``; where ``hi`` cannot
    explain them, ``hi``.

    Args:
        chi2_at: s -> (K,) squared whitened errors under noise s (decreasing in s).
        dof_fraction: 1 - (fitted parameters) / (residuals), the part of the errors' dof the
            fit leaves.
    """
    target = clipped_chi2_target(dof_fraction)

    def f(s: float) -> float:
        return float(np.mean(np.minimum(chi2_at(s), CLIP_CHI2))) - target

    if f(lo) <= 0:
        return lo
    if f(hi) > 0:
        return hi
    return float(brentq(f, lo, hi, xtol=1e-5 * max(hi, 1e-12)))


def connected_groups(adjacent: NDArray[np.bool_]) -> NDArray[np.int64]:
    """(n,) a group index per item from an (n, n) "taken at one pose" relation, closed
    transitively (captures repeated at one pose get one verdict)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    _, labels = connected_components(csr_matrix(np.asarray(adjacent, dtype=bool)), directed=False)
    return np.asarray(labels, dtype=np.int64)


def grouped_verdicts(
    chi2: FloatArray, groups: NDArray[np.int64], used: NDArray[np.bool_], gate: float
) -> NDArray[np.bool_]:
    """Inlier verdicts, one per same-pose group: a group is in when the median of its
    members' squared whitened errors (2 dof) is under ``gate`` times the robust scale of
    the ``used`` ones (their median over the chi-square median, at least 1). Captures
    repeated at one pose cannot get different verdicts from their noise alone."""
    scale = max(1.0, float(np.median(chi2[used])) / CHI2_2DOF_MEDIAN) if used.any() else 1.0
    group_chi2 = np.array([np.median(chi2[groups == g]) for g in range(int(groups.max()) + 1)])
    out: NDArray[np.bool_] = group_chi2[groups] < gate * scale
    return out
