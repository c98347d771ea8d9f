"""The targetless check's statistic: a cluster-robust covariance and the test on it.

An M-estimate theta solves sum_c g_c(theta) = 0 over clusters c of observations whose
errors may be alike within a cluster (one physical corner seen in many frames; the
patches of one stretch of the drive, which share the odometry's errors) and are
independent between clusters. Its covariance is then what the clusters' spread shows,
not what each observation's noise assumes:

- :func:`cluster_covariance`: the delete-one-cluster jackknife (CR3; Bell and McCaffrey,
  2002; MacKinnon, Nielsen and Webb, 2023), by one Newton step from the estimate:
  theta_(-c) - theta = (A - A_c)^-1 g_c, with A the normal matrix and A_c the cluster's
  part of it. A direction that only a few clusters determine (a yaw against a sideways
  shift, when every corner stands at one depth) moves far when one of them is left out,
  and so shows wide; the plain sandwich A^-1 (sum g_c g_c^T) A^-T would not.
- :func:`effective_clusters`: how many independent clusters the covariance stands on
  along the tested directions (Kish's effective count of the clusters' whitened shares:
  G when all contribute alike, fewer when a few dominate).
- :func:`spread_dof`: how many degrees of freedom the clusters' spread has left to judge
  the directions fitted from them (G - m), which bounds both the directions a group
  tests and its effective count.
- :func:`hotelling`: Hotelling's T^2 of the estimate against that covariance plus known
  parts (a systematic floor, the stored calibration's covariance), referred to the F
  distribution with the effective count (Satterthwaite's for the known parts), which
  tends to the chi-square with k dof as the clusters grow.
- :func:`wild_cluster_bootstrap`: the same T^2 referred instead to its own distribution
  under no change, drawn by the wild cluster bootstrap with restricted scores on the
  linearised problem: calibrated with many unequal clusters, where the F with Kish's
  count is not (the count is estimated from the same spread it refers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.stats import f_isf, f_sf


def cluster_covariance(A: FloatArray, A_c: FloatArray, g_c: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The delete-one-cluster jackknife covariance of theta (module docstring).

    Args:
        A: (K, K) the normal matrix at the estimate (not necessarily symmetric), with any
            prior in it.
        A_c: (G, K, K) each cluster's part of A.
        g_c: (G, K) each cluster's part of the gradient at the estimate.

    Returns:
        cov: (K, K) (G - 1) / G * sum_c (d_c - mean d)(d_c - mean d)^T, d_c = (A - A_c)^-1 g_c.
        d: (G, K) the clusters' leave-one-out moves d_c (for :func:`effective_clusters`).
    """
    G = len(g_c)
    d = np.linalg.solve(A[None] - A_c, g_c[..., None])[..., 0] if G else np.zeros((0, len(A)))
    dc = d - d.mean(axis=0) if G else d
    cov: FloatArray = (G - 1) / max(G, 1) * (dc.T @ dc)
    return cov, d


def effective_clusters(d: FloatArray, V: FloatArray) -> float:
    """Kish's effective count of the clusters' shares of the covariance along the columns
    of V (K, k): k^2 / sum_c |w_c|^4, w_c the clusters' moves whitened by their own
    covariance in that subspace (sum_c w_c w_c^T = I), times (k + 2) / k for the shares
    being estimated; about G when all clusters contribute alike, fewer when a few
    dominate, at most G."""
    k = V.shape[1]
    if k == 0 or len(d) < 2:
        return float(len(d))
    y = d @ V
    y = y - y.mean(axis=0)
    S = y.T @ y
    ev, U = np.linalg.eigh(S)
    if ev.max() <= 0.0:
        return float(len(d))
    inv_sqrt = U @ np.diag(1.0 / np.sqrt(np.maximum(ev, 1e-12 * ev.max()))) @ U.T
    w2 = np.sum((y @ inv_sqrt) ** 2, axis=1)
    # (k + 2) / k: the shares are estimated, one draw each (|w|^2 ~ chi-square_k / G for
    # G like clusters, whose fourth moment is (k^2 + 2k) / G^2): G for G like clusters.
    return float(min(k * (k + 2) / max(float(np.sum(w2**2)), 1e-300), len(d)))


def spread_dof(clusters: int, fitted: int) -> int:
    """The degrees of freedom the spread of ``clusters`` has left to judge the ``fitted``
    directions estimated from them: G - m, as a regression on G cluster-level errors
    leaves G - m residuals. With G = m each cluster is fitted exactly and its
    leave-one-out move says nothing of its own error; the jackknife's variance is then
    about one draw whatever its clusters' count (Bell and McCaffrey, 2002: the
    degrees of freedom of a cluster-robust covariance follow the clusters' leverage).
    Hotelling's test of k directions on such a covariance refers to F(k, G - m - k + 1)
    and needs that count 2 or more (a reference with a mean): k <= G - m - 1."""
    return clusters - fitted


@dataclass(frozen=True)
class Test:
    """Hotelling's T^2 on k directions: the statistic, its F form, the count it refers
    to, the p-value and the critical T^2 at the level."""

    t2: float
    F: float
    k: int
    n: float
    p: float
    critical: float


def satterthwaite(C_data: FloatArray, C_total: FloatArray, n_data: float) -> float:
    """A covariance estimated from n_data clusters (n_data - 1 dof) plus known parts is
    as sure as one estimated from this many (Satterthwaite, by the traces)."""
    a = float(np.trace(C_data))
    b = float(np.trace(C_total))
    if a <= 0.0:
        return 1e6
    return float(min(1.0 + (n_data - 1.0) * (b / a) ** 2, 1e6))


def hotelling(z: FloatArray, C_data: FloatArray, C_known: FloatArray, n_data: float, level: float) -> Test:
    """Hotelling's T^2 of z (k,) against C_data (from n_data clusters) plus C_known:
    (n - k) / (k (n - 1)) T^2 ~ F(k, n - k) under no change, n Satterthwaite's count.
    Needs n > k + 1 (else the p-value is NaN)."""
    k = len(z)
    C = C_data + C_known
    t2 = float(z @ np.linalg.solve(C, z))
    n = satterthwaite(C_data, C, n_data)
    if n - k <= 1.0:
        return Test(t2, math.nan, k, n, math.nan, math.nan)
    F = t2 * (n - k) / (k * (n - 1))
    p = f_sf(F, k, n - k)
    return Test(t2, F, k, n, p, hotelling_critical(k, n, level))


def hotelling_critical(k: int, n: float, level: float) -> float:
    """The T^2 that k directions from n clusters exceed with probability ``level`` under
    no change: F(k, n - k)'s upper point times k (n - 1) / (n - k)."""
    return f_isf(level, k, n - k) * k * (n - 1) / (n - k)


WEBB_WEIGHTS = np.array([-math.sqrt(1.5), -1.0, -math.sqrt(0.5), math.sqrt(0.5), 1.0, math.sqrt(1.5)])
"""Webb's six-point weights (Webb, 2023, "Reworking wild bootstrap-based inference for
clustered errors"): mean 0, variance 1; with G clusters they give 6^G distinct draws,
where Rademacher's two points give 2^G, half of them the same T^2 (too few to reach a
1 % tail below 8 clusters: a drive's 5-7 corners)."""
BOOTSTRAP_DRAWS = 4999
"""Draws of the wild cluster bootstrap: (B + 1) times the level an integer for every level
the check uses (1 %, and 0.5 % for two groups), and the p-value's Monte Carlo error about
0.001 at the 1 % level."""
BOOTSTRAP_FROM_CLUSTERS = 12
"""A group of directions judged by this many clusters or more is referred to the wild
cluster bootstrap; by fewer, to the F with Kish's count capped by the spread's degrees of
freedom. On synthetic clustered problems (benchmarks/bench_targetless_few_clusters.py)
the F holds the 1 % level with 5-8 clusters (0.25-0.65 %) and exceeds it from 12 on
(1.7-1.9 % with unequal clusters, about 4 % with wildly unequal ones), where the
bootstrap holds it at about the F's power; with 6-8 clusters the bootstrap holds it too
but detects a third to a half as often (its restricted scores carry the change)."""
BOOTSTRAP_SEED = 20080801
"""The bootstrap's generator is seeded with this (a constant: the same drive gives the same
verdict on every run and machine)."""


def wild_cluster_bootstrap(
    A: FloatArray,
    A_c: FloatArray,
    g_c: FloatArray,
    V: FloatArray,
    z: FloatArray,
    C_known: FloatArray,
    level: float,
    draws: int = BOOTSTRAP_DRAWS,
    seed: int = BOOTSTRAP_SEED,
) -> Test:
    """The T^2 of z = V^T theta against the clusters' jackknife plus C_known, referred to its
    wild cluster bootstrap with restricted scores on the linearised problem (WCR;
    Cameron, Gelbach and Miller, 2008), studentized by the jackknife (CV3) as MacKinnon,
    Nielsen and Webb (2023) pair them for few or unequal clusters.

    The F reference of :func:`hotelling` assumes the jackknife's spread to be a Wishart
    draw of Kish's effective count (:func:`effective_clusters`); with clusters of unequal
    size and leverage it is not, and from 12 unequal clusters on a 1 % test alarmed 1.7-
    1.9 % of the time. The bootstrap draws the statistic's own distribution under no
    change instead, clusters, leverages and all: the estimate is restricted to V^T theta = 0
    (theta_r = theta + delta, delta = -A^-1 V (V^T A^-1 V)^-1 z: restricted least squares,
    and its analogue for a non-symmetric A), each cluster's score there is
    g_c + A_c delta, and each draw multiplies the scores by one weight per cluster (Webb's
    six points, :data:`WEBB_WEIGHTS`), solves the linearised problem again (theta* - theta_r
    = -A^-1 sum_c w_c g_c^r), recomputes the jackknife at theta* exactly as for the data
    and adds a normal draw of the known part (the floor, the stored calibration's
    covariance: errors no cluster shows). The p-value is the share of draws whose T^2 is
    at or above the data's, (1 + #) / (B + 1).

    Args:
        A: (K, K) the normal matrix (as :func:`cluster_covariance`).
        A_c: (G, K, K) each cluster's part of A.
        g_c: (G, K) each cluster's part of the gradient at the estimate (the estimate
            solves sum_c g_c(theta) = 0, dg_c / dtheta = A_c).
        V: (K, k) the directions tested (the estimate's units; the change is measured
            from 0).
        z: (k,) V^T theta, the estimate along them.
        C_known: (k, k) the known part of the covariance along them.
        level: the test's level (for the critical T^2 reported).
        draws: B, the bootstrap's draws.
        seed: the generator's seed.

    Returns:
        The test: T^2, its F form NaN (no F is referred to), k, n the number of clusters,
        the bootstrap p-value and critical T^2 (the draws' upper ``level`` quantile).
    """
    G, k = len(g_c), V.shape[1]
    A_inv = np.linalg.inv(A)
    VQ = np.einsum("ki,gkl->gil", V, np.linalg.inv(A[None] - A_c))  # (G, k, K): V^T (A - A_c)^-1

    def t2_of(dV: FloatArray, zz: FloatArray) -> FloatArray:
        """T^2 of zz (B, k) against the jackknife of the moves dV (B, G, k) plus C_known."""
        dV = dV - dV.mean(axis=1, keepdims=True)
        C = (G - 1) / G * np.einsum("bgi,bgj->bij", dV, dV) + C_known
        out: FloatArray = np.einsum("bi,bi->b", zz, np.linalg.solve(C, zz[..., None])[..., 0])
        return out

    t2 = float(t2_of(np.einsum("gil,gl->gi", VQ, g_c)[None], z[None])[0])
    AiV = A_inv @ V
    delta = -AiV @ np.linalg.solve(V.T @ AiV, z)
    g_r = g_c + np.einsum("gkl,l->gk", A_c, delta)  # the restricted scores
    rng = np.random.default_rng(seed)
    w = WEBB_WEIGHTS[rng.integers(0, 6, size=(draws, G))]
    u = -(w @ g_r) @ A_inv.T  # (B, K): theta* - theta_r
    # The draws' scores at theta* are w_c g_c^r + A_c u; only their moves along V are
    # needed, V^T (A - A_c)^-1 (w_c g_c^r + A_c u), formed from (G, k) and (G, k, K) parts
    # (matrix products; not the (B, G, K) scores themselves).
    h = np.einsum("gil,gl->gi", VQ, g_r)
    M = VQ @ A_c  # (G, k, K)
    dV = w[..., None] * h[None] + np.moveaxis(M @ u.T, 2, 0)  # (B, G, k)
    ev, U = np.linalg.eigh(0.5 * (C_known + C_known.T))
    e = (rng.normal(size=(draws, k)) * np.sqrt(np.clip(ev, 0.0, None))) @ U.T
    t2_star = t2_of(dV, u @ V + e)
    p = float((1 + np.count_nonzero(t2_star >= t2)) / (draws + 1))
    return Test(t2, math.nan, k, float(G), p, float(np.quantile(t2_star, 1.0 - level)))
