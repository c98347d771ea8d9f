"""2D scan matching by ICP (paper Eq. (4)), point-to-point and point-to-line.

Given the previous scan's points m (the model) and the current scan's points d (the
data), find the 2D rigid transform [R, t] minimising

    sum_i | m_i - R d_i - t |^2                 (Eq. (4), point-to-point)
    sum_i ( n_i . (R d_i + t - m_i) )^2          (point-to-line, n_i the model's normals)

by alternating nearest neighbours (a k-d tree of the model) with a closed-form
(point-to-point: SVD) or Gauss-Newton (point-to-line) update. Pairs farther apart than
``max(reject_m, 3 x median pair distance)`` are outliers. The result maps current-scan
points into the previous scan's frame: T_prev_cur.

Point-to-line normals: given the model's lines (the laser odometry passes each scan's
lines from the shared extraction, paper Section III-B), each return on a line takes the
line's normal, fitted over the whole wall, and a data point whose nearest model return
lies on no line (a corner, an edge, clutter) is not paired. Normals fitted to a few
nearest neighbours instead are noisy where returns are closer together than the range
noise (a wall at arm's length), and wrong at corners; the pairs there bias every step the
same way on a loop driven one way round (docs/benchmarks.md: the laser odometry's yaw
bias per 10 Hz step, 1.1 / -2.5 mdeg -> -0.4 / -0.2 mdeg on the simulated loops).
Without lines (or when too few returns lie on one) the normals come from
``normal_neighbours`` nearest neighbours.

Degeneracy: a long featureless corridor constrains nothing along it. The point-to-line
Hessian's smallest eigenvalue over its largest (translation block) says how well the
least-constrained direction is determined; near 0 the step is degenerate and its
translation along that direction is a guess (reported per step).

A scan pair's ICP runs in one call of a compiled kernel (:mod:`rigcal.jit`): the grid of
the model (:mod:`rigcal.localize.nearest`, nearest neighbours exact as the k-d tree), the
stages' iterations (pairing, rejection and the update in one loop on work arrays
allocated once), the pairing normals and the degeneracy. The numpy iterations
(``icp(..., kernel=False)``) are its reference in the tests. The lines' fits behind the
normals (:func:`line_fits`) run in a kernel too, with their numpy reference kept alike.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.jit import njit
from rigcal.localize.nearest import GridArgs, build, knn, knn_one

# Point-to-point steps before point-to-line, while they still move the scan by more than
# COARSE_TOLERANCE (m, rad): from a good initial guess one closed-form step is all (more
# would pull the scan towards point-to-point's bias, and along a corridor away from the
# guess, for point-to-line to undo, at a k-d tree query each); a turn far from the guess
# (scans 0.5 m and tens of degrees apart) takes several.
COARSE_ITERATIONS = 10
COARSE_TOLERANCE = (0.01, 0.01)
# Information eigenvalues below this fraction of the largest count as unconstrained.
DEGENERATE_EIGEN_RATIO = 1e-3
# icp_covariance: 1-sigma (m) of the translation along a direction the scans do not
# constrain, and the least residual 1-sigma (m) it takes (a noise-free scan).
OPEN_SIGMA_M = 10.0
COVARIANCE_SIGMA_FLOOR_M = 1e-4
# Line normals are used when at least this fraction of the model's returns lie on a line;
# otherwise (clutter, outdoors) every return takes a nearest-neighbour normal.
MIN_LINE_FRACTION = 0.85
# Full-resolution iterations pick each point's nearest model point among this many
# candidates from one k-d tree query, repeated once some point has moved this far.
CANDIDATES = 4
REQUERY_M = 0.005
# The sparse stages' exact nearest neighbours (a k-d tree query each iteration in the
# numpy reference) come from this many candidates per point, queried again for a point
# only when it has moved too far for its nearest to be sure to be among them.
SPARSE_CANDIDATES = 3


@dataclass(frozen=True)
class IcpParams:
    """ICP settings.

    Attributes:
        method: "point-to-point" (Eq. (4)) or "point-to-line".
        max_iterations: iteration cap.
        tolerance_m, tolerance_rad: stop when an update moves less than these.
        reject_m: pairs farther apart than max(this, 3 x median distance) are dropped.
        normals: "lines" (the laser odometry gives point-to-line the model scan's lines:
            normals fitted along each line, returns on no line left unpaired) or
            "neighbours" (``normal_neighbours`` nearest neighbours per return).
        normal_neighbours: points used to fit each model normal (point-to-line) without lines.
        subsample: the coarse stages use every this-many-th data point.
        restart_below_inliers: laser odometry (:func:`rigcal.localize.odometry.icp_odometry`)
            tries a step again from zero motion when the fit from the previous motion keeps
            fewer than this fraction of the points as inliers, and keeps the better fit
            (scans far apart, as logged keyframes, move unlike the step before; a failed
            step would otherwise hand its wrong motion on as the next guess).
    """

    method: str = "point-to-line"
    max_iterations: int = 50
    tolerance_m: float = 1e-4
    tolerance_rad: float = 1e-5
    reject_m: float = 0.3
    normals: str = "lines"
    normal_neighbours: int = 5
    subsample: int = 4
    restart_below_inliers: float = 0.9


@dataclass(frozen=True)
class IcpResult:
    """T_prev_cur as (x, y, yaw), the fit's figures and its degeneracy indicator.

    ``inlier_fraction``: of the data points that could be paired (with line normals: those
    whose nearest model return lies on a line), the fraction kept as inliers.
    ``nearest`` (N,): each data point's nearest model point in the last iteration (the
    laser odometry carries the model's lines over with it)."""

    pose: FloatArray
    iterations: int
    rms_m: float
    inlier_fraction: float
    degeneracy: float
    nearest: NDArray[np.intp] | None = None


def icp(
    model: FloatArray,
    data: FloatArray,
    initial: FloatArray | None = None,
    params: IcpParams | None = None,
    model_normals: FloatArray | None = None,
    *,
    kernel: bool = True,
) -> IcpResult:
    """Align ``data`` (N, 2) to ``model`` (M, 2); returns T_model_data.

    ``model_normals`` (M, 2), point-to-line only: each model return's normal, NaN for a
    return on no line (see :func:`line_normals`); such returns are never paired. Without
    it, or when fewer than ``MIN_LINE_FRACTION`` of the returns have one, normals come from
    ``params.normal_neighbours`` nearest neighbours.

    Coarse to fine: first every ``params.subsample``-th data point (a quarter of the
    nearest-neighbour queries), then all of them from there; point-to-line starts with
    point-to-point steps while they move the scan by more than ``COARSE_TOLERANCE`` (one
    from a good guess), whose closed form takes a turn's large rotation in one go.
    ``rms_m``, ``inlier_fraction`` and ``degeneracy`` are those of the last iteration's
    pairs. ``kernel=False`` runs the numpy iterations (the compiled kernel's reference).

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
    x, y, yaw = (0.0, 0.0, 0.0) if initial is None else (float(v) for v in np.asarray(initial, dtype=float))
    if kernel:
        return _icp_compiled(model, data, x, y, yaw, params, model_normals)
    tree = cKDTree(model)
    T = _Transform(math.cos(yaw), math.sin(yaw), x, y)
    sparse = data[:: params.subsample] if len(data) >= 3 * params.subsample else data
    coarse_tol = (10.0 * params.tolerance_m, 10.0 * params.tolerance_rad)
    normals = lines = usable = None
    if params.method == "point-to-line":
        T, _ = _iterate(tree, model, sparse, None, T, COARSE_ITERATIONS, COARSE_TOLERANCE, params.reject_m)
        normals, usable = pairing_normals(model, tree, params.normal_neighbours, model_normals)
        # Per model point: its normal and the normal's offset n . m (the line n . p = n . m).
        lines = np.column_stack([normals, np.einsum("ij,ij->i", normals, model)])
    T, _ = _iterate(tree, model, sparse, lines, T, params.max_iterations, coarse_tol, params.reject_m, usable)
    T, fit = _iterate(
        tree,
        model,
        data,
        lines,
        T,
        params.max_iterations,
        (params.tolerance_m, params.tolerance_rad),
        params.reject_m,
        usable,
        candidates=CANDIDATES,
    )
    pose_out = np.array([T.tx, T.ty, math.atan2(T.s, T.c)])
    dst = model.take(fit.pairs, axis=0)
    n = normals.take(fit.pairs, axis=0) if normals is not None else None
    degeneracy = _degeneracy(fit.src, dst, n)
    return IcpResult(pose_out, fit.iterations, fit.rms_m, fit.inlier_fraction, degeneracy, fit.nearest)


@dataclass(frozen=True)
class _Transform:
    """T_model_data as plain floats: rotation (cos, sin) and translation."""

    c: float
    s: float
    tx: float
    ty: float

    def after(self, x: float, y: float, yaw: float) -> _Transform:
        """The step (x, y, yaw) applied after this transform."""
        c, s = math.cos(yaw), math.sin(yaw)
        return _Transform(
            c * self.c - s * self.s,
            s * self.c + c * self.s,
            c * self.tx - s * self.ty + x,
            s * self.tx + c * self.ty + y,
        )


@dataclass(frozen=True)
class _Fit:
    """The last iteration's pairs: moved data points and the indices of their model points."""

    iterations: int
    rms_m: float
    inlier_fraction: float
    src: FloatArray
    pairs: NDArray[np.intp]
    nearest: NDArray[np.intp] | None = None


def _iterate(
    tree: cKDTree,
    model: FloatArray,
    data: FloatArray,
    lines: FloatArray | None,
    T: _Transform,
    max_iterations: int,
    tolerance: tuple[float, float],
    reject_m: float,
    usable: NDArray[np.bool_] | None = None,
    candidates: int = 1,
) -> tuple[_Transform, _Fit]:
    """ICP iterations from T_model_data until a step moves less than ``tolerance``
    (metres, radians): point-to-point without ``lines``, else point-to-line with the
    model's (normal x, normal y, offset) rows; data points whose nearest model point is
    not ``usable`` are left unpaired. Returns the new transform and the last pairs'
    figures."""
    fit = _Fit(0, float("inf"), 0.0, data[:0], np.zeros(0, dtype=np.intp))
    nearest = _Nearest(tree, model, candidates)
    half = len(data) // 2
    for k in range(1, max_iterations + 1):
        moved = data @ np.array([[T.c, T.s], [-T.s, T.c]])
        moved += (T.tx, T.ty)
        dist, idx = nearest(moved)
        median = float(np.partition(dist, half)[half])
        close = dist < max(reject_m, 3.0 * median)
        eligible = len(data)
        if usable is not None:
            on_line = usable.take(idx)
            close &= on_line
            eligible = max(int(on_line.sum()), 1)
        inl = np.flatnonzero(close)
        n_inl = len(inl)
        if n_inl < 3:
            break
        d_inl, pair, src = dist.take(inl), idx.take(inl), moved.take(inl, axis=0)
        fit = _Fit(k, math.sqrt(float(d_inl @ d_inl) / n_inl), n_inl / eligible, src, pair, idx)
        if lines is None:
            x, y, yaw = point_to_point(src, model.take(pair, axis=0)).tolist()
        else:
            x, y, yaw = _point_to_line(src, lines.take(pair, axis=0))
        T = T.after(x, y, yaw)
        if math.hypot(x, y) < tolerance[0] and abs(yaw) < tolerance[1]:
            break
    return T, fit


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
        self.nb = np.zeros(0, dtype=np.intp)
        self.cx = self.cy = np.zeros((0, 1))
        self.rows = np.zeros(0, dtype=np.intp)

    def __call__(self, moved: FloatArray) -> tuple[FloatArray, NDArray[np.intp]]:
        if self.k == 1:
            dist, idx = self.tree.query(moved)
            return dist, idx
        if self.anchor is None or float(np.abs(moved - self.anchor).max()) > REQUERY_M:
            _, nb = self.tree.query(moved, k=self.k)
            self.cx, self.cy = self.model[nb, 0], self.model[nb, 1]
            self.nb = nb.ravel()
            self.rows = np.arange(0, nb.size, self.k)
            self.anchor = moved
        d2 = self.cx - moved[:, 0, None]
        d2 *= d2
        dy = self.cy - moved[:, 1, None]
        dy *= dy
        d2 += dy
        pick = d2.argmin(axis=1)
        pick += self.rows
        return np.sqrt(d2.ravel().take(pick)), self.nb.take(pick)


def point_to_point(src: FloatArray, dst: FloatArray) -> FloatArray:
    """Closed-form 2D rigid step (Eq. (4)) moving src onto dst, as (x, y, yaw)."""
    X = np.concatenate((src, dst), axis=1)
    mean = X.sum(axis=0) / len(X)
    X -= mean
    (sx, sy, dx, dy), ((_, _, h00, h01), (_, _, h10, h11)) = mean.tolist(), (X.T[:2] @ X).tolist()
    yaw = math.atan2(h01 - h10, h00 + h11)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([dx - (c * sx - s * sy), dy - (s * sx + c * sy), yaw])


def _point_to_line(src: FloatArray, lines: FloatArray) -> tuple[float, float, float]:
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


def line_fits(
    points: FloatArray, labels: NDArray[np.integer], *, kernel: bool = True
) -> tuple[FloatArray, FloatArray]:
    """Each point's line, fitted (total least squares) over all the points of its line
    (``labels``: a line number per point, -1 for none): (N, 2) the line's centroid and
    (N, 2) its unit normal; NaN rows for points on no line. ``kernel=False`` runs the
    numpy version (the compiled kernel's reference)."""
    if kernel:
        centres = np.empty((len(points), 2))
        normals = np.empty((len(points), 2))
        _line_fits_kernel(
            np.ascontiguousarray(points, dtype=np.float64),
            np.asarray(labels, dtype=np.int64),
            centres,
            normals,
        )
        return centres, normals
    centres = np.full((len(points), 2), np.nan)
    normals = np.full((len(points), 2), np.nan)
    on = labels >= 0
    if not on.any():
        return centres, normals
    lab, p = labels[on], points[on]
    n = np.bincount(lab).astype(float)
    used = n > 0
    sums = [np.bincount(lab, weights=w, minlength=len(n)) for w in (p[:, 0], p[:, 1])]
    mx, my = (np.divide(s, n, out=np.zeros_like(s), where=used) for s in sums)
    dx, dy = p[:, 0] - mx[lab], p[:, 1] - my[lab]
    sxx, syy, sxy = (np.bincount(lab, weights=w, minlength=len(n)) for w in (dx * dx, dy * dy, dx * dy))
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)  # each line's direction (as in _normals)
    centres[on] = np.column_stack([mx, my])[lab]
    normals[on] = np.column_stack([-np.sin(phi), np.cos(phi)])[lab]
    return centres, normals


@njit
def label_runs(labels: NDArray[np.int64]) -> NDArray[np.int64]:
    """Bounds of the runs of equal labels: run r is ``labels[bounds[r]:bounds[r + 1]]``."""
    bounds = np.empty(len(labels) + 1, dtype=np.int64)
    bounds[0] = 0
    n = 1
    for i in range(1, len(labels)):
        if labels[i] != labels[i - 1]:
            bounds[n] = i
            n += 1
    if len(labels) > 0:
        bounds[n] = len(labels)
        n += 1
    return bounds[:n]


@njit
def _k_scatter_normal(sxx: float, syy: float, sxy: float) -> tuple[float, float]:
    """The unit normal of a 2-D scatter's major axis (as :func:`_normals`)."""
    phi = 0.5 * np.arctan2(2.0 * sxy, sxx - syy)
    return -np.sin(phi), np.cos(phi)


@njit
def _line_fits_kernel(
    points: FloatArray, labels: NDArray[np.int64], centres: FloatArray, normals: FloatArray
) -> None:
    """:func:`line_fits` into ``centres`` and ``normals`` (N, 2): each line's centroid, then
    its scatter about it and the normal of the scatter's major axis (as :func:`_normals`),
    summed over the points in order as ``np.bincount`` does."""
    n_lines = 0
    for i in range(len(labels)):
        n_lines = max(n_lines, labels[i] + 1)
    count = np.zeros(n_lines)
    mx = np.zeros(n_lines)
    my = np.zeros(n_lines)
    # The sums run in point order per line as np.bincount's; a line's returns come in runs,
    # so each run's sums are carried in registers and stored at its end.
    bounds = label_runs(labels)
    for r in range(len(bounds) - 1):
        k = labels[bounds[r]]
        if k < 0:
            continue
        c, sx, sy = count[k], mx[k], my[k]
        for i in range(bounds[r], bounds[r + 1]):
            c += 1.0
            sx += points[i, 0]
            sy += points[i, 1]
        count[k], mx[k], my[k] = c, sx, sy
    for k in range(n_lines):
        if count[k] > 0:
            mx[k] /= count[k]
            my[k] /= count[k]
    sxx = np.zeros(n_lines)
    syy = np.zeros(n_lines)
    sxy = np.zeros(n_lines)
    for r in range(len(bounds) - 1):
        k = labels[bounds[r]]
        if k < 0:
            continue
        axx, ayy, axy = sxx[k], syy[k], sxy[k]
        for i in range(bounds[r], bounds[r + 1]):
            dx, dy = points[i, 0] - mx[k], points[i, 1] - my[k]
            axx += dx * dx
            ayy += dy * dy
            axy += dx * dy
        sxx[k], syy[k], sxy[k] = axx, ayy, axy
    nx = np.empty(n_lines)
    ny = np.empty(n_lines)
    for k in range(n_lines):
        nx[k], ny[k] = _k_scatter_normal(sxx[k], syy[k], sxy[k])
    for i in range(len(labels)):
        k = labels[i]
        if k >= 0:
            centres[i, 0], centres[i, 1], normals[i, 0], normals[i, 1] = mx[k], my[k], nx[k], ny[k]
        else:
            centres[i, 0] = centres[i, 1] = normals[i, 0] = normals[i, 1] = np.nan


def line_normals(points: FloatArray, labels: NDArray[np.integer], *, kernel: bool = True) -> FloatArray:
    """(N, 2) unit normals of the lines the points lie on, each fitted over all the
    points of its line (``labels``: a line number per point, -1 for none: NaN rows)."""
    return line_fits(points, labels, kernel=kernel)[1]


def pairing_normals(
    model: FloatArray, tree: cKDTree, k: int, model_normals: FloatArray | None
) -> tuple[FloatArray, NDArray[np.bool_] | None]:
    """The model's point-to-line normals and which returns may be paired: the line
    normals (``model_normals``, NaN off a line; those returns unpaired) when at least
    MIN_LINE_FRACTION of the returns have one, else ``k``-nearest-neighbour normals for
    every return (None: all may be paired)."""
    if model_normals is not None:
        on_line = np.isfinite(model_normals[:, 0])
        if on_line.mean() >= MIN_LINE_FRACTION:
            return np.where(on_line[:, None], model_normals, 0.0), on_line
    return _normals(model, tree, k), None


def _normals(model: FloatArray, tree: cKDTree, k: int) -> FloatArray:
    """(M, 2) unit normals from each model point's k nearest neighbours (PCA)."""
    _, nb = tree.query(model, k=min(k, len(model)))
    x, y = model[nb, 0], model[nb, 1]
    x -= x.sum(axis=1, keepdims=True) / nb.shape[1]
    y -= y.sum(axis=1, keepdims=True) / nb.shape[1]
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


def icp_covariance(
    model: FloatArray,
    data: FloatArray,
    pose: FloatArray,
    nearest: NDArray[np.intp],
    normals: FloatArray | None,
    reject_m: float,
    open_below: float,
) -> FloatArray:
    """The covariance (3, 3) of ICP's T_model_data (x m, y m, yaw rad) at its solution
    ``pose``: the Gauss-Newton Hessian of Eq. (4)'s cost (point-to-line: the residuals
    n . (R d + t - m) along the model's ``normals`` (M, 2), NaN off a line; point-to-point
    without them) over the inlier pairs (each data point and its ``nearest`` model point,
    pairs farther apart than max(``reject_m``, 3 x median) left out, as ICP leaves them),

        Sigma = sigma^2 (J^T J)^-1,   sigma = 1.4826 MAD(residuals)  (robust),

    inflated along a direction the scans do not constrain: when the translation block of
    J^T J has its smaller eigenvalue below ``open_below`` times its larger (the
    degeneracy indicator of :func:`icp`; a corridor whose ends are out of reach), the
    translation along that eigenvector gets 1-sigma OPEN_SIGMA_M, for ICP's step along it
    is only its initial guess. NaN (3, 3) with fewer than 3 pairs."""
    out = np.full((3, 3), np.nan)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    moved = data @ np.array([[c, s], [-s, c]]) + pose[:2]
    m = model.take(nearest, axis=0)
    diff = moved - m
    dist = np.hypot(diff[:, 0], diff[:, 1])
    keep = dist < max(reject_m, 3.0 * float(np.median(dist))) if len(dist) else dist > 0
    # d(R(yaw) d + t) / d yaw = perp(R d) = (-(y - ty), x - tx).
    arm = np.column_stack([-(moved[:, 1] - pose[1]), moved[:, 0] - pose[0]])
    if normals is not None:
        n = normals.take(nearest, axis=0)
        keep &= np.isfinite(n[:, 0])
        n, arm, diff = n[keep], arm[keep], diff[keep]
        J = np.column_stack([n, np.einsum("ij,ij->i", n, arm)])
        r = np.einsum("ij,ij->i", n, diff)
    else:
        arm, diff = arm[keep], diff[keep]
        ones, zeros = np.ones(len(arm)), np.zeros(len(arm))
        J = np.vstack([np.column_stack([ones, zeros, arm[:, 0]]), np.column_stack([zeros, ones, arm[:, 1]])])
        r = diff.T.ravel()
    if len(arm) < 3:  # pairs
        return out
    sigma = _residual_sigma(model, normals, moved[keep], nearest[keep], r)
    info = J.T @ J
    w, v = np.linalg.eigh(info[:2, :2])
    weak = np.zeros((3, 3))
    if w[1] <= 0 or w[0] < open_below * w[1]:
        e = np.array([v[0, 0], v[1, 0], 0.0])
        weak = OPEN_SIGMA_M**2 * np.outer(e, e)
        # The unconstrained direction out of the Hessian before its inversion.
        info = info + (w[1] if w[1] > 0 else 1.0) * np.outer(e, e)
    try:
        cov = sigma**2 * np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return out
    return 0.5 * (cov + cov.T) + weak


def _mad_sigma(r: FloatArray) -> float:
    """1.4826 x the median absolute deviation: a robust 1-sigma."""
    return MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r)))) if len(r) else 0.0


def _residual_sigma(
    model: FloatArray, normals: FloatArray | None, moved: FloatArray, pairs: NDArray[np.intp], r: FloatArray
) -> float:
    """The 1-sigma of a residual n . (R d + t - m): with line normals (one normal per line,
    shared by its returns), the data returns' spread about the model's lines (each line's
    offset the mean n . m of its returns) and the model returns' own, added in quadrature;
    a residual's spread about its nearest model return would understate both, for the
    nearest of a wall's returns is the one whose noise brought it nearest. Else (nearest-
    neighbour normals, point-to-point) the residuals' robust spread. At least
    COVARIANCE_SIGMA_FLOOR_M."""
    sigma = _mad_sigma(r)
    if normals is not None:
        on = np.flatnonzero(np.isfinite(normals[:, 0]))
        _, line, count = np.unique(normals[on], axis=0, return_inverse=True, return_counts=True)
        if len(count) <= len(on) // 3:  # each line shared by its returns: line normals
            dot = np.einsum("ij,ij->i", normals[on], model[on])
            offset = np.bincount(line, weights=dot) / count
            model_res = dot - offset[line]
            of_line = np.full(len(model), -1)
            of_line[on] = line
            n = normals.take(pairs, axis=0)
            data_res = np.einsum("ij,ij->i", n, moved) - offset[of_line.take(pairs)]
            sigma = float(np.hypot(_mad_sigma(data_res), _mad_sigma(model_res)))
    return max(sigma, COVARIANCE_SIGMA_FLOOR_M)


# The compiled ICP: icp()'s steps for one scan pair in one call.


def _icp_compiled(
    model: FloatArray,
    data: FloatArray,
    x: float,
    y: float,
    yaw: float,
    params: IcpParams,
    model_normals: FloatArray | None,
) -> IcpResult:
    """:func:`icp` in the compiled kernel :func:`_icp_kernel` (the grid of the model, the
    three stages, the pairing normals and the degeneracy)."""
    if params.method == "point-to-line" and model_normals is not None and model_normals.shape != model.shape:
        raise ValueError(f"model_normals must be {model.shape}, got {np.shape(model_normals)}")
    pose = np.array([math.cos(yaw), math.sin(yaw), x, y])
    nearest = np.empty(len(data), dtype=np.int64)
    iterations, rms, frac, degeneracy = _icp_kernel(
        model,
        data,
        _NO_NORMALS if model_normals is None else np.ascontiguousarray(model_normals, dtype=float),
        model_normals is not None,
        params.method == "point-to-line",
        params.normal_neighbours,
        params.subsample,
        pose,
        params.max_iterations,
        params.tolerance_m,
        params.tolerance_rad,
        params.reject_m,
        COARSE_ITERATIONS,
        COARSE_TOLERANCE[0],
        COARSE_TOLERANCE[1],
        MIN_LINE_FRACTION,
        CANDIDATES,
        REQUERY_M,
        DEGENERATE_EIGEN_RATIO,
        nearest,
    )
    pose_out = np.array([pose[2], pose[3], math.atan2(pose[1], pose[0])])
    return IcpResult(pose_out, iterations, rms, frac, degeneracy, nearest if iterations else None)


_NO_NORMALS = np.zeros((0, 2))


@njit
def _icp_kernel(
    model: FloatArray,
    data: FloatArray,
    model_normals: FloatArray,
    have_normals: bool,
    point_to_line: bool,
    normal_neighbours: int,
    subsample: int,
    pose: FloatArray,
    max_iterations: int,
    tol_m: float,
    tol_rad: float,
    reject_m: float,
    coarse_iterations: int,
    coarse_tol_m: float,
    coarse_tol_rad: float,
    min_line_fraction: float,
    candidates: int,
    requery_m: float,
    degenerate_ratio: float,
    out_nearest: NDArray[np.int64],
) -> tuple[int, float, float, float]:
    """:func:`icp` from ``pose`` = (cos, sin, tx, ty) of T_model_data, updated in place:
    the model's grid, point-to-point steps on the sparse points (point-to-line only), the
    pairing normals, then the sparse and the full stage. Returns the last stage's
    iterations, RMS, inlier fraction and degeneracy; every data point's nearest model
    point in its last fit goes to ``out_nearest``."""
    grid = build(model)
    m, n = model.shape[0], data.shape[0]
    step = subsample if n >= 3 * subsample else 1
    sparse = data[::step].copy()
    n_sp = sparse.shape[0]
    k = min(candidates, m)
    # Work arrays, shared by the stages (each stage sizes its own views).
    moved = np.empty((n, 2))
    dist = np.empty(n)
    idx = np.empty(n, dtype=np.int64)
    select = np.empty(n)
    anchor = np.empty((n, 2))
    out_src = np.empty((n, 2))
    out_pairs = np.empty(n, dtype=np.int64)
    k_sp = min(SPARSE_CANDIDATES, m)
    nb_sp = np.empty((n_sp, k_sp), dtype=np.int64)
    nbd_sp = np.empty((n_sp, k_sp))
    lines = np.empty((m, 3))
    usable = np.ones(m, dtype=np.bool_)
    use_usable = False
    if point_to_line:
        _iterate_kernel(
            grid, sparse, lines, False, usable, False, pose, coarse_iterations, coarse_tol_m, coarse_tol_rad,
            reject_m, requery_m, degenerate_ratio, nb_sp, nbd_sp, True, False,
            moved, dist, idx, select, anchor, out_src, out_pairs, out_nearest,
        )  # fmt: skip
        use_usable = _k_pairing_normals(
            grid, normal_neighbours, model_normals, have_normals, min_line_fraction, lines, usable
        )
        for i in range(m):
            lines[i, 2] = lines[i, 0] * model[i, 0] + lines[i, 1] * model[i, 1]
    _iterate_kernel(
        grid, sparse, lines, point_to_line, usable, use_usable, pose, max_iterations,
        10.0 * tol_m, 10.0 * tol_rad, reject_m, requery_m, degenerate_ratio, nb_sp, nbd_sp, True,
        point_to_line and coarse_iterations > 0,
        moved, dist, idx, select, anchor, out_src, out_pairs, out_nearest,
    )  # fmt: skip
    nb = np.empty((n, k), dtype=np.int64)
    nbd = np.empty((n, k))
    fit_k, rms, frac, n_inl = _iterate_kernel(
        grid, data, lines, point_to_line, usable, use_usable, pose, max_iterations,
        tol_m, tol_rad, reject_m, requery_m, degenerate_ratio, nb, nbd, False, False,
        moved, dist, idx, select, anchor, out_src, out_pairs, out_nearest,
    )  # fmt: skip
    return fit_k, rms, frac, _k_degeneracy(model, lines, point_to_line, out_pairs, n_inl)


@njit
def _k_pairing_normals(
    grid: GridArgs,
    k: int,
    model_normals: FloatArray,
    have_normals: bool,
    min_line_fraction: float,
    lines: FloatArray,
    usable: NDArray[np.bool_],
) -> bool:
    """:func:`pairing_normals` into ``lines[:, :2]`` and ``usable``; returns whether
    ``usable`` applies (line normals) or every return may be paired."""
    model = grid[0]
    m = model.shape[0]
    if have_normals:
        on = 0
        for i in range(m):
            on += int(np.isfinite(model_normals[i, 0]))
        if on / m >= min_line_fraction:
            for i in range(m):
                usable[i] = np.isfinite(model_normals[i, 0])
                lines[i, 0] = model_normals[i, 0] if usable[i] else 0.0
                lines[i, 1] = model_normals[i, 1] if usable[i] else 0.0
            return True
    # :func:`_normals`: each return's k nearest neighbours' scatter, its minor axis.
    k = min(k, m)
    nb = np.empty((m, k), dtype=np.int64)
    nbd = np.empty((m, k))
    knn(grid, model, nbd, nb)
    for i in range(m):
        mx = my = 0.0
        for j in range(k):
            mx += model[nb[i, j], 0]
            my += model[nb[i, j], 1]
        mx /= k
        my /= k
        sxx = syy = sxy = 0.0
        for j in range(k):
            dx, dy = model[nb[i, j], 0] - mx, model[nb[i, j], 1] - my
            sxx += dx * dx
            syy += dy * dy
            sxy += dx * dy
        lines[i, 0], lines[i, 1] = _k_scatter_normal(sxx, syy, sxy)
    return False


@njit
def _k_degeneracy(
    model: FloatArray, lines: FloatArray, point_to_line: bool, pairs: NDArray[np.int64], n: int
) -> float:
    """:func:`_degeneracy` of the first n pairs: the 2x2 scatter of the paired normals
    (point-to-line) or of the paired model points about their mean, its smaller
    eigenvalue over its larger (closed form)."""
    if n < 3:
        return 0.0
    mx = my = 0.0
    if not point_to_line:
        for i in range(n):
            mx += model[pairs[i], 0]
            my += model[pairs[i], 1]
        mx /= n
        my /= n
    sxx = syy = sxy = 0.0
    for i in range(n):
        if point_to_line:
            dx, dy = lines[pairs[i], 0], lines[pairs[i], 1]
        else:
            dx, dy = model[pairs[i], 0] - mx, model[pairs[i], 1] - my
        sxx += dx * dx
        syy += dy * dy
        sxy += dx * dy
    mean = 0.5 * (sxx + syy)
    r = np.hypot(0.5 * (sxx - syy), sxy)
    hi = mean + r
    return (mean - r) / hi if hi > 0 else 0.0


@njit
def _median(values: FloatArray, n: int, work: FloatArray) -> float:
    """The (n // 2)-th smallest of ``values[:n]`` (``np.partition``'s), by quickselect on
    ``work``."""
    for i in range(n):
        work[i] = values[i]
    want = n // 2
    lo, hi = 0, n - 1
    while hi > lo:
        # Median of three as the pivot, then Hoare's partition.
        mid = (lo + hi) // 2
        a, b, c = work[lo], work[mid], work[hi]
        pivot = max(min(a, b), min(max(a, b), c))
        i, j = lo, hi
        while i <= j:
            while work[i] < pivot:
                i += 1
            while work[j] > pivot:
                j -= 1
            if i <= j:
                work[i], work[j] = work[j], work[i]
                i += 1
                j -= 1
        if want <= j:
            hi = j
        elif want >= i:
            lo = i
        else:
            break
    return work[want]


@njit
def _iterate_kernel(
    grid: GridArgs,
    data: FloatArray,
    lines: FloatArray,
    use_lines: bool,
    usable: NDArray[np.bool_],
    use_usable: bool,
    pose: FloatArray,
    max_iterations: int,
    tol_m: float,
    tol_rad: float,
    reject_m: float,
    requery_m: float,
    degenerate_ratio: float,
    nb: NDArray[np.int64],
    nbd: FloatArray,
    exact: bool,
    anchored: bool,
    moved: FloatArray,
    dist: FloatArray,
    idx: NDArray[np.int64],
    select: FloatArray,
    anchor: FloatArray,
    out_src: FloatArray,
    out_pairs: NDArray[np.int64],
    out_nearest: NDArray[np.int64],
) -> tuple[int, float, float, int]:
    """:func:`_iterate` and :class:`_Nearest`'s steps in one loop, from ``pose`` = (cos,
    sin, tx, ty) of T_model_data, updated in place. k = nb.shape[1] candidates per point
    (``nb``, their distances ``nbd`` where queried, at ``anchor``): all queried again
    after a move of ``requery_m`` (the full stage's rule), or, ``exact``, a point's own
    when its nearest model point may have left them (the sparse stages: the exact nearest,
    as the reference's k-d tree). ``anchored``: the candidates of an earlier stage are in
    place. The work arrays (``moved`` to ``anchor``) hold at least len(data) rows.

    Returns (iterations of the last fit, its RMS, inlier fraction, inlier count); the
    fit's moved inliers, their model points and every point's nearest model point go to
    ``out_src``, ``out_pairs`` and ``out_nearest``.
    """
    model = grid[0]
    n = data.shape[0]
    k = nb.shape[1]
    half = n // 2
    c, s, tx, ty = pose[0], pose[1], pose[2], pose[3]
    have_anchor = anchored
    fit_k, fit_rms, fit_frac, fit_n = 0, np.inf, 0.0, 0
    m_model = model.shape[0]
    for it in range(1, max_iterations + 1):
        for i in range(n):
            moved[i, 0] = data[i, 0] * c - data[i, 1] * s + tx
            moved[i, 1] = data[i, 0] * s + data[i, 1] * c + ty
        # Nearest model point (the _Nearest rules: k candidates re-queried after a move;
        # exact: each point's own when its nearest may have left them).
        if exact:
            requery = not have_anchor
        elif k > 1 and have_anchor:
            far = 0.0
            for i in range(n):
                far = max(far, abs(moved[i, 0] - anchor[i, 0]), abs(moved[i, 1] - anchor[i, 1]))
            requery = far > requery_m
        else:
            requery = True
        if requery:
            knn(grid, moved[:n], nbd, nb)
            if k > 1:
                anchor[:n] = moved[:n]
                have_anchor = True
        # Each point's nearest candidate, and how many lie within reject_m / 3: when more
        # than half do, the median's 3 x is below reject_m and the threshold is reject_m.
        below = 0
        for i in range(n):
            qx, qy = moved[i, 0], moved[i, 1]
            for attempt in range(2):
                best = np.inf
                pick = 0
                for j in range(k):
                    dx = model[nb[i, j], 0] - qx
                    dy = model[nb[i, j], 1] - qy
                    d2 = dx * dx + dy * dy
                    if d2 < best:
                        best, pick = d2, j
                if not exact or requery or attempt == 1 or k >= m_model:
                    break
                # Every other model point was at least the k-th candidate's distance from
                # where the point was queried, so at least that less the distance moved
                # since from where it is: the best candidate is the nearest when closer.
                ax, ay = qx - anchor[i, 0], qy - anchor[i, 1]
                if np.sqrt(best) + np.sqrt(ax * ax + ay * ay) + 1e-9 < nbd[i, k - 1]:
                    break
                knn_one(grid, qx, qy, nbd[i], nb[i])
                anchor[i, 0], anchor[i, 1] = qx, qy
            dist[i] = np.sqrt(best)
            idx[i] = nb[i, pick]
            below += int(3.0 * dist[i] <= reject_m)
        thr = reject_m if below > half else max(reject_m, 3.0 * _median(dist, n, select))
        eligible = n
        n_inl = 0
        if use_usable:
            eligible = 0
            for i in range(n):
                ok = usable[idx[i]]
                eligible += int(ok)
                n_inl += int(ok and dist[i] < thr)
            eligible = max(eligible, 1)
        else:
            for i in range(n):
                n_inl += int(dist[i] < thr)
        if n_inl < 3:
            break
        m_in = 0
        sq = 0.0
        for i in range(n):
            if dist[i] < thr and (not use_usable or usable[idx[i]]):
                out_src[m_in, 0] = moved[i, 0]
                out_src[m_in, 1] = moved[i, 1]
                out_pairs[m_in] = idx[i]
                sq += dist[i] * dist[i]
                m_in += 1
            out_nearest[i] = idx[i]
        fit_k, fit_rms, fit_frac, fit_n = it, np.sqrt(sq / n_inl), n_inl / eligible, n_inl
        if use_lines:
            x, y, yaw = _k_point_to_line(out_src, out_pairs, lines, n_inl, degenerate_ratio)
        else:
            x, y, yaw = _k_point_to_point(out_src, out_pairs, model, n_inl)
        cy, sy = np.cos(yaw), np.sin(yaw)
        c, s, tx, ty = cy * c - sy * s, sy * c + cy * s, cy * tx - sy * ty + x, sy * tx + cy * ty + y
        if np.hypot(x, y) < tol_m and abs(yaw) < tol_rad:
            break
    pose[0], pose[1], pose[2], pose[3] = c, s, tx, ty
    return fit_k, fit_rms, fit_frac, fit_n


@njit
def _k_point_to_point(
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
def _k_point_to_line(
    src: FloatArray, pairs: NDArray[np.int64], lines: FloatArray, n: int, degenerate_ratio: float
) -> tuple[float, float, float]:
    """:func:`_point_to_line` over the first n pairs."""
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
