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
# Full-resolution iterations pick each point's nearest model point among this many
# candidates from one k-d tree query, repeated once some point has moved this far.
CANDIDATES = 4
REQUERY_M = 0.005


@dataclass(frozen=True)
class IcpParams:
    """ICP settings.

    Attributes:
        method: "point-to-point" (Eq. (4)) or "point-to-line".
        max_iterations: iteration cap.
        tolerance_m, tolerance_rad: stop when an update moves less than these.
        reject_m: pairs farther apart than max(this, 3 x median distance) are dropped.
        normal_neighbours: points used to fit each model normal (point-to-line).
        subsample: the coarse stages use every this-many-th data point.
    """

    method: str = "point-to-line"
    max_iterations: int = 50
    tolerance_m: float = 1e-4
    tolerance_rad: float = 1e-5
    reject_m: float = 0.3
    normal_neighbours: int = 5
    subsample: int = 4


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

    Coarse to fine: first every ``params.subsample``-th data point (a quarter of the
    nearest-neighbour queries), then all of them from there; point-to-line starts with a
    few point-to-point steps, whose closed form takes a turn's large rotation in one go.
    ``rms_m``, ``inlier_fraction`` and ``degeneracy`` are those of the last iteration's
    pairs.

    Raises:
        ValueError: fewer than 3 points in either scan.
    """
    params = params or IcpParams()
    if len(model) < 3 or len(data) < 3:
        raise ValueError("ICP needs at least 3 points in each scan")
    if params.method not in ("point-to-point", "point-to-line"):
        raise ValueError("method must be 'point-to-point' or 'point-to-line'")
    model = np.ascontiguousarray(model, dtype=float)
    data = np.ascontiguousarray(data, dtype=float)
    tree = cKDTree(model)
    pose = np.zeros(3) if initial is None else np.asarray(initial, dtype=float)
    c, s = np.cos(pose[2]), np.sin(pose[2])
    R, t = np.array([[c, -s], [s, c]]), pose[:2].copy()
    sparse = data[:: params.subsample] if len(data) >= 3 * params.subsample else data
    coarse_tol = (10.0 * params.tolerance_m, 10.0 * params.tolerance_rad)
    normals = None
    if params.method == "point-to-line":
        R, t, _ = _iterate(tree, model, sparse, None, R, t, COARSE_ITERATIONS, (1e-3, 1e-4), params.reject_m)
        normals = _normals(model, tree, params.normal_neighbours)
    R, t, _ = _iterate(tree, model, sparse, normals, R, t, params.max_iterations, coarse_tol, params.reject_m)
    R, t, fit = _iterate(
        tree,
        model,
        data,
        normals,
        R,
        t,
        params.max_iterations,
        (params.tolerance_m, params.tolerance_rad),
        params.reject_m,
        candidates=CANDIDATES,
    )
    pose_out = np.array([t[0], t[1], np.arctan2(R[1, 0], R[0, 0])])
    degeneracy = _degeneracy(fit.src, fit.dst, fit.normals)
    return IcpResult(pose_out, fit.iterations, fit.rms_m, fit.inlier_fraction, degeneracy)


@dataclass(frozen=True)
class _Fit:
    """The last iteration's pairs: moved data points, their model points (and normals)."""

    iterations: int
    rms_m: float
    inlier_fraction: float
    src: FloatArray
    dst: FloatArray
    normals: FloatArray | None


def _iterate(
    tree: cKDTree,
    model: FloatArray,
    data: FloatArray,
    normals: FloatArray | None,
    R: FloatArray,
    t: FloatArray,
    max_iterations: int,
    tolerance: tuple[float, float],
    reject_m: float,
    candidates: int = 1,
) -> tuple[FloatArray, FloatArray, _Fit]:
    """ICP iterations from T_model_data = [R, t] until a step moves less than
    ``tolerance`` (metres, radians); returns the new R, t and the last pairs' figures."""
    fit = _Fit(0, float("inf"), 0.0, data[:0], data[:0], None)
    nearest = _Nearest(tree, model, candidates)
    for k in range(1, max_iterations + 1):
        moved = data @ R.T + t
        dist, idx = nearest(moved)
        half = len(dist) // 2
        median = float(np.partition(dist, half)[half])
        inl = dist < max(reject_m, 3.0 * median)
        n_inl = int(np.count_nonzero(inl))
        if n_inl < 3:
            break
        pair = idx[inl]
        src, dst = moved[inl], model.take(pair, axis=0)
        n = normals.take(pair, axis=0) if normals is not None else None
        fit = _Fit(k, float(np.sqrt(np.mean(dist[inl] ** 2))), n_inl / len(data), src, dst, n)
        step = _point_to_point(src, dst) if n is None else _point_to_line(src, dst, n)
        c, s = np.cos(step[2]), np.sin(step[2])
        Rs = np.array([[c, -s], [s, c]])
        R, t = Rs @ R, Rs @ t + step[:2]
        if np.hypot(step[0], step[1]) < tolerance[0] and abs(step[2]) < tolerance[1]:
            break
    return R, t, fit


class _Nearest:
    """Nearest model point of each moved data point.

    With ``candidates`` = k > 1 the k-d tree is asked for each point's k nearest model
    points once, and later calls pick the nearest among those until some point has moved
    more than REQUERY_M since: the fine iterations move the scan by millimetres, so the
    answer stays exact (the true nearest point is among the candidates while
    k-th distance > first distance + 2 x motion) at a fraction of a query's cost.
    """

    def __init__(self, tree: cKDTree, model: FloatArray, candidates: int) -> None:
        self.tree, self.model = tree, model
        self.k = min(candidates, len(model))
        self.anchor: FloatArray | None = None
        self.nb = np.zeros((0, 1), dtype=np.intp)
        self.cx = self.cy = np.zeros((0, 1))
        self.rows = np.zeros(0, dtype=np.intp)

    def __call__(self, moved: FloatArray) -> tuple[FloatArray, NDArray[np.intp]]:
        if self.k == 1:
            dist, idx = self.tree.query(moved)
            return dist, idx
        if self.anchor is None or float(np.abs(moved - self.anchor).max()) > REQUERY_M:
            _, self.nb = self.tree.query(moved, k=self.k)
            self.cx, self.cy = self.model[self.nb, 0], self.model[self.nb, 1]
            self.rows = np.arange(len(moved))
            self.anchor = moved
        dx = self.cx - moved[:, 0, None]
        dy = self.cy - moved[:, 1, None]
        d2 = dx * dx
        d2 += dy * dy
        j = d2.argmin(axis=1)
        return np.sqrt(d2[self.rows, j]), self.nb[self.rows, j]


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
    J = np.empty((len(src), 3))
    J[:, :2] = n
    np.subtract(n[:, 1] * src[:, 0], n[:, 0] * src[:, 1], out=J[:, 2])
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
    x, y = model[nb, 0], model[nb, 1]
    x -= x.mean(axis=1, keepdims=True)
    y -= y.mean(axis=1, keepdims=True)
    sxx = np.einsum("nk,nk->n", x, x)
    syy = np.einsum("nk,nk->n", y, y)
    sxy = np.einsum("nk,nk->n", x, y)
    # The 2x2 scatter's major axis is at 0.5 atan2(2 sxy, sxx - syy); the normal is
    # perpendicular to it (closed form of the smallest eigenvector).
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    out: FloatArray = np.column_stack([-np.sin(phi), np.cos(phi)])
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
