"""ICP's update steps (paper Eq. (4)): the closed-form point-to-point step and the
Gauss-Newton point-to-line step, each in numpy and compiled (:mod:`rigcal.jit`).

A point-to-line step solves only in the directions the pairs constrain: along a featureless
corridor the information is ~0 and a full solve would slide the scan anywhere, so the step
keeps the initial guess there (``DEGENERATE_EIGEN_RATIO``). The iterations that call these
steps are :mod:`rigcal.localize.icp` (numpy) and :mod:`rigcal.localize.icp_compiled`.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.jit import njit

# Information eigenvalues below this fraction of the largest count as unconstrained.
DEGENERATE_EIGEN_RATIO = 1e-3


def point_to_point(src: FloatArray, dst: FloatArray) -> FloatArray:
    """Closed-form 2D rigid step (Eq. (4)) moving src onto dst, as (x, y, yaw)."""
    X = np.concatenate((src, dst), axis=1)
    mean = X.sum(axis=0) / len(X)
    X -= mean
    (sx, sy, dx, dy), ((_, _, h00, h01), (_, _, h10, h11)) = mean.tolist(), (X.T[:2] @ X).tolist()
    yaw = math.atan2(h01 - h10, h00 + h11)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([dx - (c * sx - s * sy), dy - (s * sx + c * sy), yaw])


def point_to_line(src: FloatArray, lines: FloatArray) -> tuple[float, float, float]:
    """One Gauss-Newton step of the point-to-line error (small-angle linearisation):
    ``lines`` holds each pair's model normal n and offset n . m."""
    # Rows of A: the Jacobian's columns (n_x, n_y, n x src) and the residual n . src - n . m.
    nx, ny, sx, sy = lines[:, 0], lines[:, 1], src[:, 0], src[:, 1]
    A = np.empty((4, len(src)))
    A[0], A[1] = nx, ny
    np.multiply(ny, sx, out=A[2])
    A[2] -= nx * sy
    np.multiply(nx, sx, out=A[3])
    A[3] += ny * sy
    A[3] -= lines[:, 2]
    (h00, h01, h02, g0), (_, h11, h12, g1), (_, _, h22, g2), _ = (A @ A.T).tolist()
    # Solve only in the directions the scan constrains: along a featureless corridor the
    # information is ~0 and a full solve would slide the scan anywhere; keep the initial
    # guess (the previous motion) there instead. Clearly well-posed systems (the usual
    # case) are solved in closed form, the others through the eigenvectors.
    lo, hi = _eigen_range(h00, h01, h02, h11, h12, h22)
    if lo > 2.0 * DEGENERATE_EIGEN_RATIO * hi:
        return _newton_step(h00, h01, h02, h11, h12, h22, g0, g1, g2)
    H = np.array([[h00, h01, h02], [h01, h11, h12], [h02, h12, h22]])
    w, V = np.linalg.eigh(H)
    keep = w > DEGENERATE_EIGEN_RATIO * w[-1]
    g = V.T @ np.array([g0, g1, g2])
    x, y, yaw = (-(V[:, keep] @ (g[keep] / w[keep]))).tolist()
    return x, y, yaw


def _newton_step(
    h00: float, h01: float, h02: float, h11: float, h12: float, h22: float, g0: float, g1: float, g2: float
) -> tuple[float, float, float]:
    """step = -H^-1 g for a well-posed symmetric 3x3 H, by its cofactors."""
    c00, c01, c02 = h11 * h22 - h12 * h12, h02 * h12 - h01 * h22, h01 * h12 - h02 * h11
    c11, c12, c22 = h00 * h22 - h02 * h02, h01 * h02 - h00 * h12, h00 * h11 - h01 * h01
    det = h00 * c00 + h01 * c01 + h02 * c02
    return (
        -(c00 * g0 + c01 * g1 + c02 * g2) / det,
        -(c01 * g0 + c11 * g1 + c12 * g2) / det,
        -(c02 * g0 + c12 * g1 + c22 * g2) / det,
    )


def _eigen_range(
    h00: float, h01: float, h02: float, h11: float, h12: float, h22: float
) -> tuple[float, float]:
    """Smallest and largest eigenvalue of a symmetric 3x3 matrix (trigonometric closed
    form; absolute error of order 1e-15 x the largest)."""
    q = (h00 + h11 + h22) / 3.0
    a, b, c = h00 - q, h11 - q, h22 - q
    off = h01 * h01 + h02 * h02 + h12 * h12
    p = math.sqrt((a * a + b * b + c * c + 2.0 * off) / 6.0)
    if p == 0.0:
        return q, q
    det = a * (b * c - h12 * h12) - h01 * (h01 * c - h12 * h02) + h02 * (h01 * h12 - b * h02)
    phi = math.acos(min(1.0, max(-1.0, det / (2.0 * p * p * p)))) / 3.0
    return q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0), q + 2.0 * p * math.cos(phi)


@njit
def k_point_to_point(
    src: FloatArray, pairs: NDArray[np.int64], model: FloatArray, n: int
) -> tuple[float, float, float]:
    """:func:`point_to_point` over the first n pairs (Eq. (4))."""
    msx = msy = mdx = mdy = 0.0
    for i in range(n):
        msx += src[i, 0]
        msy += src[i, 1]
        mdx += model[pairs[i], 0]
        mdy += model[pairs[i], 1]
    msx, msy, mdx, mdy = msx / n, msy / n, mdx / n, mdy / n
    h00 = h01 = h10 = h11 = 0.0
    for i in range(n):
        ax, ay = src[i, 0] - msx, src[i, 1] - msy
        bx, by = model[pairs[i], 0] - mdx, model[pairs[i], 1] - mdy
        h00 += ax * bx
        h01 += ax * by
        h10 += ay * bx
        h11 += ay * by
    yaw = np.arctan2(h01 - h10, h00 + h11)
    c, s = np.cos(yaw), np.sin(yaw)
    return mdx - (c * msx - s * msy), mdy - (s * msx + c * msy), yaw


@njit
def k_point_to_line(
    src: FloatArray, pairs: NDArray[np.int64], lines: FloatArray, n: int, degenerate_ratio: float
) -> tuple[float, float, float]:
    """:func:`point_to_line` over the first n pairs."""
    h00 = h01 = h02 = h11 = h12 = h22 = g0 = g1 = g2 = 0.0
    for i in range(n):
        nx, ny, off = lines[pairs[i], 0], lines[pairs[i], 1], lines[pairs[i], 2]
        sx, sy = src[i, 0], src[i, 1]
        a2 = ny * sx - nx * sy
        a3 = nx * sx + ny * sy - off
        h00 += nx * nx
        h01 += nx * ny
        h02 += nx * a2
        h11 += ny * ny
        h12 += ny * a2
        h22 += a2 * a2
        g0 += nx * a3
        g1 += ny * a3
        g2 += a2 * a3
    lo, hi = _k_eigen_range(h00, h01, h02, h11, h12, h22)
    if lo > 2.0 * degenerate_ratio * hi:
        return _k_newton_step(h00, h01, h02, h11, h12, h22, g0, g1, g2)
    H = np.array([[h00, h01, h02], [h01, h11, h12], [h02, h12, h22]])
    w, V = np.linalg.eigh(H)
    g = V.T @ np.array([g0, g1, g2])
    step = np.zeros(3)
    for j in range(3):
        if w[j] > degenerate_ratio * w[2]:
            for i in range(3):
                step[i] -= V[i, j] * g[j] / w[j]
    return step[0], step[1], step[2]


_k_eigen_range = njit(_eigen_range)


_k_newton_step = njit(_newton_step)
