"""2D scan matching by ICP (paper Eq. (4)), point-to-point and point-to-line.

Given the previous scan's points m (the model) and the current scan's points d (the
data), find the 2D rigid transform [R, t] minimising

    sum_i | m_i - R d_i - t |^2                 (Eq. (4), point-to-point)
    sum_i ( n_i . (R d_i + t - m_i) )^2          (point-to-line, n_i the model's normals)

by alternating nearest neighbours (a k-d tree of the model) with a closed-form
(point-to-point: SVD) or Gauss-Newton (point-to-line) update. Pairs farther apart than
``max(reject_m, 3 x median pair distance)`` are outliers. The result maps current-scan
points into the previous scan's frame: T_prev_cur.

Degeneracy: a long featureless corridor constrains nothing along it. The point-to-line
Hessian's smallest eigenvalue over its largest (translation block) says how well the
least-constrained direction is determined; near 0 the step is degenerate and its
translation along that direction is a guess (reported per step).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

FloatArray = NDArray[np.float64]


# Point-to-point iterations before point-to-line (enough to take a turn's rotation).
COARSE_ITERATIONS = 10
# Information eigenvalues below this fraction of the largest count as unconstrained.
DEGENERATE_EIGEN_RATIO = 1e-3


@dataclass(frozen=True)
class IcpParams:
    """ICP settings.

    Attributes:
        method: "point-to-point" (Eq. (4)) or "point-to-line".
        max_iterations: iteration cap.
        tolerance_m, tolerance_rad: stop when an update moves less than these.
        reject_m: pairs farther apart than max(this, 3 x median distance) are dropped.
        normal_neighbours: points used to fit each model normal (point-to-line).
    """

    method: str = "point-to-line"
    max_iterations: int = 50
    tolerance_m: float = 1e-4
    tolerance_rad: float = 1e-5
    reject_m: float = 0.3
    normal_neighbours: int = 5


@dataclass(frozen=True)
class IcpResult:
    """T_prev_cur as (x, y, yaw), the fit's figures and its degeneracy indicator."""

    pose: FloatArray
    iterations: int
    rms_m: float
    inlier_fraction: float
    degeneracy: float


def se2(pose: FloatArray) -> FloatArray:
    """(3, 3) homogeneous matrix of (x, y, yaw)."""
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def pose_of(M: FloatArray) -> FloatArray:
    """(x, y, yaw) of a (3, 3) homogeneous matrix."""
    return np.array([M[0, 2], M[1, 2], np.arctan2(M[1, 0], M[0, 0])])


def icp(
    model: FloatArray, data: FloatArray, initial: FloatArray | None = None, params: IcpParams | None = None
) -> IcpResult:
    """Align ``data`` (N, 2) to ``model`` (M, 2); returns T_model_data.

    Raises:
        ValueError: fewer than 3 points in either scan.
    """
    params = params or IcpParams()
    if len(model) < 3 or len(data) < 3:
        raise ValueError("ICP needs at least 3 points in each scan")
    if params.method not in ("point-to-point", "point-to-line"):
        raise ValueError("method must be 'point-to-point' or 'point-to-line'")
    tree = cKDTree(model)
    pose = np.zeros(3) if initial is None else np.asarray(initial, dtype=float).copy()
    normals = None
    if params.method == "point-to-line":
        # Coarse to fine: point-to-point first, whose closed-form steps take large
        # rotations in turns, then point-to-line from there.
        coarse = IcpParams("point-to-point", COARSE_ITERATIONS, 1e-3, 1e-4, params.reject_m)
        pose = icp(model, data, pose, coarse).pose
        normals = _normals(model, tree, params.normal_neighbours)
    iterations = 0
    for iterations in range(1, params.max_iterations + 1):  # noqa: B007 - reported below
        M = se2(pose)
        moved = data @ M[:2, :2].T + M[:2, 2]
        dist, idx = tree.query(moved)
        thr = max(params.reject_m, 3.0 * float(np.median(dist)))
        inl = dist < thr
        if inl.sum() < 3:
            break
        src, dst = moved[inl], model[idx[inl]]
        step = _point_to_point(src, dst) if normals is None else _point_to_line(src, dst, normals[idx[inl]])
        pose = pose_of(se2(step) @ M)
        if np.hypot(step[0], step[1]) < params.tolerance_m and abs(step[2]) < params.tolerance_rad:
            break
    M = se2(pose)
    moved = data @ M[:2, :2].T + M[:2, 2]
    dist, idx = tree.query(moved)
    inl = dist < max(params.reject_m, 3.0 * float(np.median(dist)))
    rms = float(np.sqrt(np.mean(dist[inl] ** 2))) if inl.any() else float("inf")
    degeneracy = _degeneracy(moved[inl], model[idx[inl]], normals[idx[inl]] if normals is not None else None)
    return IcpResult(pose, iterations, rms, float(inl.mean()), degeneracy)


def _point_to_point(src: FloatArray, dst: FloatArray) -> FloatArray:
    """Closed-form 2D rigid step (Eq. (4)) moving src onto dst, as (x, y, yaw)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    H = (src - cs).T @ (dst - cd)
    yaw = float(np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1]))
    c, s = np.cos(yaw), np.sin(yaw)
    t = cd - np.array([[c, -s], [s, c]]) @ cs
    return np.array([t[0], t[1], yaw])


def _point_to_line(src: FloatArray, dst: FloatArray, n: FloatArray) -> FloatArray:
    """One Gauss-Newton step of the point-to-line error (small-angle linearisation)."""
    r = np.einsum("ij,ij->i", n, src - dst)
    J = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * src[:, 0] - n[:, 0] * src[:, 1]])
    H = J.T @ J
    # Solve only in the directions the scan constrains: along a featureless corridor the
    # information is ~0 and a full solve would slide the scan anywhere; keep the initial
    # guess (the previous motion) there instead.
    w, V = np.linalg.eigh(H)
    keep = w > DEGENERATE_EIGEN_RATIO * w[-1]
    g = V.T @ (J.T @ r)
    out: FloatArray = -(V[:, keep] @ (g[keep] / w[keep]))
    return out


def _normals(model: FloatArray, tree: cKDTree, k: int) -> FloatArray:
    """(M, 2) unit normals from each model point's k nearest neighbours (PCA)."""
    _, nb = tree.query(model, k=min(k, len(model)))
    P = model[nb] - model[nb].mean(axis=1, keepdims=True)
    C = np.einsum("nki,nkj->nij", P, P)
    _, V = np.linalg.eigh(C)
    out: FloatArray = V[:, :, 0]
    return out


def _degeneracy(src: FloatArray, dst: FloatArray, n: FloatArray | None) -> float:
    """Smallest over largest eigenvalue of the translation block of the point-to-line
    information (1: every direction as well constrained; near 0: a corridor)."""
    if len(src) < 3:
        return 0.0
    if n is None:
        # Point-to-point: use the spread of the matched points' directions instead.
        d = dst - dst.mean(axis=0)
        w = np.linalg.eigvalsh(d.T @ d)
    else:
        w = np.linalg.eigvalsh(n.T @ n)
    return float(w[0] / w[-1]) if w[-1] > 0 else 0.0
