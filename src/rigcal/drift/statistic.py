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
