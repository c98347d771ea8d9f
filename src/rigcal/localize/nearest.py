"""Exact k nearest neighbours among a scan's points on a uniform grid, compiled.

ICP asks for each data point's nearest model points every iteration. A k-d tree answers
from Python one batch at a time; inside a compiled ICP loop a grid serves instead: the
model's points are bucketed by square cells (a counting sort), and a query searches rings
of cells outward from its own until the k-th best distance is below the distance to any
cell not searched yet, so the answer is exact (the same neighbours as
``scipy.spatial.cKDTree.query``, up to ties).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from rigcal.jit import njit

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# Cells are at least this large (m), and the grid has at most MAX_CELLS_PER_SIDE cells a side.
MIN_CELL_M = 0.1
MAX_CELLS_PER_SIDE = 400


class Grid:
    """A model scan's points bucketed for nearest-neighbour queries.

    Attributes:
        points: (M, 2) float64, metres.
        origin: (2,) the grid's lower-left corner; ``cell``: its cell size (m).
        shape: (nx, ny) cells; ``starts`` (nx * ny + 1,) and ``order`` (M,): the points of
            cell ``ix * ny + iy`` are ``order[starts[c]:starts[c + 1]]``.
    """

    def __init__(self, points: FloatArray) -> None:
        self.points = np.ascontiguousarray(points, dtype=float)
        lo = self.points.min(axis=0)
        hi = self.points.max(axis=0)
        extent = float(max(hi[0] - lo[0], hi[1] - lo[1]))
        self.cell = max(MIN_CELL_M, extent / (MAX_CELLS_PER_SIDE - 1))
        self.origin = lo
        nx = int((hi[0] - lo[0]) / self.cell) + 1
        ny = int((hi[1] - lo[1]) / self.cell) + 1
        self.shape = (nx, ny)
        self.starts, self.order = _bucket(self.points, lo[0], lo[1], self.cell, nx, ny)

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

    def args(self) -> tuple[FloatArray, float, float, float, int, int, IntArray, IntArray]:
        """The grid as the tuple the compiled functions take."""
        return (
            self.points,
            float(self.origin[0]),
            float(self.origin[1]),
            self.cell,
            self.shape[0],
            self.shape[1],
            self.starts,
            self.order,
        )


@njit
def _bucket(
    points: FloatArray, x0: float, y0: float, cell: float, nx: int, ny: int
) -> tuple[IntArray, IntArray]:
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
    return starts, order


@njit
def knn(
    grid: tuple[FloatArray, float, float, float, int, int, IntArray, IntArray],
    queries: FloatArray,
    dist: FloatArray,
    idx: IntArray,
) -> None:
    """Fill ``dist``/``idx`` (Q, k) with each query's k nearest grid points, nearest first."""
    for j in range(queries.shape[0]):
        knn_one(grid, queries[j, 0], queries[j, 1], dist[j], idx[j])


@njit
def _distances(
    grid: tuple[FloatArray, float, float, float, int, int, IntArray, IntArray],
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
    grid: tuple[FloatArray, float, float, float, int, int, IntArray, IntArray],
    qx: float,
    qy: float,
    dist: FloatArray,
    idx: IntArray,
    upper_m: float = np.inf,
) -> None:
    """The k = len(dist) nearest grid points of (qx, qy), nearest first; the search
    stops once every point left is farther than ``upper_m`` (their slots: inf, -1)."""
    points, x0, y0, cell, nx, ny, starts, order = grid
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
                    c = ix * ny + iy
                    for t in range(starts[c], starts[c + 1]):
                        p = order[t]
                        dx = points[p, 0] - qx
                        dy = points[p, 1] - qy
                        d2 = dx * dx + dy * dy
                        if d2 < dist[k - 1]:
                            m = k - 1
                            while m > 0 and dist[m - 1] > d2:
                                dist[m] = dist[m - 1]
                                idx[m] = idx[m - 1]
                                m -= 1
                            dist[m] = d2
                            idx[m] = p
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
