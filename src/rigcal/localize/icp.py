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

A scan pair's ICP runs in one call of a compiled kernel (:mod:`rigcal.localize.icp_compiled`);
the numpy iterations here (``icp(..., kernel=False)``) are its reference in the tests.

The steps, by module: this one, the scan-pair API (:func:`icp`, its settings and result)
and the numpy iterations (pairing, rejection, convergence); the update steps, point-to-point
and point-to-line (:mod:`rigcal.localize.icp_steps`); the pairing normals from the model's
lines (:mod:`rigcal.localize.line_normals`); the compiled iterations
(:mod:`rigcal.localize.icp_compiled`); the covariance of the result
(:mod:`rigcal.localize.icp_covariance`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.localize.icp_compiled import icp_kernel
from rigcal.localize.icp_steps import DEGENERATE_EIGEN_RATIO, point_to_line, point_to_point
from rigcal.localize.line_normals import MIN_LINE_FRACTION, pairing_normals

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

# Point-to-point steps before point-to-line, while they still move the scan by more than
# COARSE_TOLERANCE (m, rad): from a good initial guess one closed-form step is all (more
# would pull the scan towards point-to-point's bias, and along a corridor away from the
# guess, for point-to-line to undo, at a k-d tree query each); a turn far from the guess
# (scans 0.5 m and tens of degrees apart) takes several.
COARSE_ITERATIONS = 10
COARSE_TOLERANCE = (0.01, 0.01)
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
    from scipy.spatial import cKDTree

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
            x, y, yaw = point_to_line(src, lines.take(pair, axis=0))
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
    """:func:`icp` in the compiled kernel :func:`icp_kernel` (the grid of the model, the
    three stages, the pairing normals and the degeneracy)."""
    if params.method == "point-to-line" and model_normals is not None and model_normals.shape != model.shape:
        raise ValueError(f"model_normals must be {model.shape}, got {np.shape(model_normals)}")
    pose = np.array([math.cos(yaw), math.sin(yaw), x, y])
    nearest = np.empty(len(data), dtype=np.int64)
    iterations, rms, frac, degeneracy = icp_kernel(
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
