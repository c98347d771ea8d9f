"""Exact k nearest neighbours among a scan's points on a uniform grid, compiled.

ICP asks for each data point's nearest model points every iteration. A k-d tree answers
from Python one batch at a time; inside a compiled ICP loop a grid serves instead: the
model's points are bucketed by square cells (a counting sort), and a query searches rings
of cells outward from its own until the k-th best distance is below the distance to any
cell not searched yet, so the answer is exact (the same neighbours as
``scipy.spatial.cKDTree.query``, up to ties). Within a cell the points are sorted along
the cell's longer side, so a query walks them outwards from its own coordinate and stops
where that coordinate's gap alone exceeds the k-th distance found (returns lie along
walls: a few of a cell's points are looked at).
"""

from __future__ import annotations

import numpy as np

from rigcal.arrays import FloatArray, IntArray
from rigcal.jit import njit

# Cells are at least this large (m), and the grid has at most MAX_CELLS_PER_SIDE cells a side.
MIN_CELL_M = 0.1
MAX_CELLS_PER_SIDE = 400

GridArgs = tuple[FloatArray, float, float, float, int, int, IntArray, IntArray, FloatArray]


class Grid:
    """A model scan's points bucketed for nearest-neighbour queries.

    Attributes:
        points: (M, 2) float64, metres.

    The grid itself is the tuple :func:`build` makes (:meth:`args`): the lower-left corner,
    the cell size (m), (nx, ny) cells, ``starts`` (nx * ny + 1,) and ``order`` (M,) -- the
    points of cell ``ix * ny + iy`` are ``order[starts[c]:starts[c + 1]]``, sorted along
    the cell's axis (0: x, 1: y; the longer side of the cell's points' bounds) -- and
    (M, 4) the points in that order, each as (coordinate along its cell's axis, x, y,
    axis): a query walks a cell outwards from its own coordinate and stops where the gap
    along the axis alone exceeds the k-th distance found.
    """

    def __init__(self, points: FloatArray) -> None:
        self.points = np.ascontiguousarray(points, dtype=float)
        if len(self.points) == 0:
            raise ValueError("Grid needs at least one point")
        self._args = build(self.points)

    def query(self, queries: FloatArray, k: int = 1) -> tuple[FloatArray, IntArray]:
        """(Q, k) distances and indices of each query's k nearest points, nearest first
        (k = 1: (Q,) each, as cKDTree.query)."""
        q = np.ascontiguousarray(queries, dtype=float)
        k = min(k, len(self.points))
        dist = np.empty((len(q), k))
        idx = np.empty((len(q), k), dtype=np.int64)
        knn(self.args(), q, dist, idx)
        return (dist[:, 0], idx[:, 0]) if k == 1 else (dist, idx)

    def distances(self, queries: FloatArray, upper_m: float) -> FloatArray:
        """(Q,) each query's distance to its nearest point, ``upper_m`` where that is
        farther (the search stops there)."""
        q = np.ascontiguousarray(queries, dtype=float)
        out = np.empty(len(q))
        _distances(self.args(), q, upper_m, out)
        return out

    def args(self) -> GridArgs:
        """The grid as the tuple the compiled functions take."""
        return self._args


@njit
def build(points: FloatArray) -> GridArgs:
    """The grid of (M, 2) ``points`` (M >= 1) as the tuple the compiled functions take:
    cells at least MIN_CELL_M, at most MAX_CELLS_PER_SIDE a side over the points' bounds."""
    lo_x = hi_x = points[0, 0]
    lo_y = hi_y = points[0, 1]
    for i in range(1, points.shape[0]):
        lo_x, hi_x = min(lo_x, points[i, 0]), max(hi_x, points[i, 0])
        lo_y, hi_y = min(lo_y, points[i, 1]), max(hi_y, points[i, 1])
    extent = max(hi_x - lo_x, hi_y - lo_y)
    cell = max(MIN_CELL_M, extent / (MAX_CELLS_PER_SIDE - 1))
    nx = int((hi_x - lo_x) / cell) + 1
    ny = int((hi_y - lo_y) / cell) + 1
    starts, order, srt = _bucket(points, lo_x, lo_y, cell, nx, ny)
    return points, lo_x, lo_y, cell, nx, ny, starts, order, srt


@njit
def _bucket(
    points: FloatArray, x0: float, y0: float, cell: float, nx: int, ny: int
) -> tuple[IntArray, IntArray, FloatArray]:
    """The points counting-sorted by cell, then (insertion sort: a scan's returns come
    nearly in order along a wall) along each cell's longer axis."""
    n = points.shape[0]
    cells = np.empty(n, dtype=np.int64)
    starts = np.zeros(nx * ny + 1, dtype=np.int64)
    for i in range(n):
        ix = min(max(int((points[i, 0] - x0) / cell), 0), nx - 1)
        iy = min(max(int((points[i, 1] - y0) / cell), 0), ny - 1)
        cells[i] = ix * ny + iy
        starts[cells[i] + 1] += 1
    for c in range(nx * ny):
        starts[c + 1] += starts[c]
    fill = starts[:-1].copy()
    order = np.empty(n, dtype=np.int64)
    for i in range(n):
        order[fill[cells[i]]] = i
        fill[cells[i]] += 1
    srt = np.empty((n, 4))
    lo = 0
    while lo < n:  # each occupied cell: its run of points in ``order``
        c = cells[order[lo]]
        hi = starts[c + 1]
        ax = bx = points[order[lo], 0]
        ay = by = points[order[lo], 1]
        for t in range(lo + 1, hi):
            ax, bx = min(ax, points[order[t], 0]), max(bx, points[order[t], 0])
            ay, by = min(ay, points[order[t], 1]), max(by, points[order[t], 1])
        a = 0 if bx - ax >= by - ay else 1
        for t in range(lo, hi):
            p = order[t]
            key = points[p, a]
            u = t
            while u > lo and srt[u - 1, 0] > key:
                srt[u, 0], srt[u, 1], srt[u, 2] = srt[u - 1, 0], srt[u - 1, 1], srt[u - 1, 2]
                order[u] = order[u - 1]
                u -= 1
            srt[u, 0], srt[u, 1], srt[u, 2], srt[u, 3] = key, points[p, 0], points[p, 1], a
            order[u] = p
        lo = hi
    return starts, order, srt


@njit
def knn(
    grid: GridArgs,
    queries: FloatArray,
    dist: FloatArray,
    idx: IntArray,
) -> None:
    """Fill ``dist``/``idx`` (Q, k) with each query's k nearest grid points, nearest first."""
    for j in range(queries.shape[0]):
        knn_one(grid, queries[j, 0], queries[j, 1], dist[j], idx[j])


@njit
def _distances(
    grid: GridArgs,
    queries: FloatArray,
    upper_m: float,
    out: FloatArray,
) -> None:
    dist = np.empty(1)
    idx = np.empty(1, dtype=np.int64)
    for j in range(queries.shape[0]):
        knn_one(grid, queries[j, 0], queries[j, 1], dist, idx, upper_m)
        out[j] = min(dist[0], upper_m)


@njit
def knn_one(
    grid: GridArgs,
    qx: float,
    qy: float,
    dist: FloatArray,
    idx: IntArray,
    upper_m: float = np.inf,
) -> None:
    """The k = len(dist) nearest grid points of (qx, qy), nearest first; the search
    stops once every point left is farther than ``upper_m`` (their slots: inf, -1)."""
    _, x0, y0, cell, nx, ny, starts, order, srt = grid
    k = dist.shape[0]
    for m in range(k):
        dist[m] = np.inf
        idx[m] = -1
    fx = (qx - x0) / cell
    fy = (qy - y0) / cell
    cx = min(max(int(np.floor(fx)), 0), nx - 1)
    cy = min(max(int(np.floor(fy)), 0), ny - 1)
    r = 0
    while True:
        for ix in range(max(cx - r, 0), min(cx + r, nx - 1) + 1):
            edge_x = ix == cx - r or ix == cx + r
            step = 1 if edge_x else 2 * r
            iy = cy - r
            while iy <= cy + r:
                if 0 <= iy < ny:
                    _scan_cell(starts, order, srt, ix * ny + iy, qx, qy, dist, idx)
                iy += step if step > 0 else 1
        # The nearest point not searched yet is beyond one of the sides that still has
        # cells outside the searched square.
        bound = np.inf
        if cx - r > 0:
            bound = min(bound, qx - (x0 + (cx - r) * cell))
        if cx + r < nx - 1:
            bound = min(bound, x0 + (cx + r + 1) * cell - qx)
        if cy - r > 0:
            bound = min(bound, qy - (y0 + (cy - r) * cell))
        if cy + r < ny - 1:
            bound = min(bound, y0 + (cy + r + 1) * cell - qy)
        if bound == np.inf or bound >= upper_m:
            break
        if idx[k - 1] >= 0 and dist[k - 1] <= bound * bound and bound > 0:
            break
        r += 1
    for m in range(k):
        dist[m] = np.sqrt(dist[m])


@njit
def _scan_cell(
    starts: IntArray,
    order: IntArray,
    srt: FloatArray,
    c: int,
    qx: float,
    qy: float,
    dist: FloatArray,
    idx: IntArray,
) -> None:
    """Merge the points of cell ``c`` closer to (qx, qy) than the k-th so far into the
    sorted squared distances ``dist`` and their indices ``idx``: outwards from the
    query's coordinate along the cell's axis (rightwards, then leftwards), each way until
    the gap along it alone (the exact dx or dy of the distance) is too large."""
    lo, hi = starts[c], starts[c + 1]
    if lo == hi:
        return
    key = qx if srt[lo, 3] == 0.0 else qy
    a, b = lo, hi
    while a < b:
        mid = (a + b) // 2
        if srt[mid, 0] < key:
            a = mid + 1
        else:
            b = mid
    k = dist.shape[0]
    t, step = a, 1  # rightwards from the query's place, then leftwards from a - 1
    while True:
        if t == hi or (t >= a and (srt[t, 0] - key) * (srt[t, 0] - key) > dist[k - 1]):
            t, step = a - 1, -1
            continue
        if t < lo or (t < a and (key - srt[t, 0]) * (key - srt[t, 0]) > dist[k - 1]):
            break
        dx = srt[t, 1] - qx
        dy = srt[t, 2] - qy
        d2 = dx * dx + dy * dy
        if d2 < dist[k - 1]:
            m = k - 1
            while m > 0 and dist[m - 1] > d2:
                dist[m] = dist[m - 1]
                idx[m] = idx[m - 1]
                m -= 1
            dist[m] = d2
            idx[m] = order[t]
        t += step
