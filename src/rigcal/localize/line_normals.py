"""Point-to-line ICP's normals: each return's line fitted over the whole line (total least
squares over the returns the shared extraction put on it, paper Section III-B), or, for a
model with too few returns on lines, fitted to a few nearest neighbours.

A data point whose nearest model return lies on no line (a corner, an edge, clutter) is not
paired; normals from a few neighbours are noisy where returns are closer together than the
range noise, and wrong at corners (:mod:`rigcal.localize.icp`). The fits run in a compiled
kernel (:mod:`rigcal.jit`) with their numpy reference kept alike; the laser odometry,
IASM's polish and the targetless drift check use them too.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.jit import njit
from rigcal.localize.nearest import GridArgs, knn

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

# Line normals are used when at least this fraction of the model's returns lie on a line;
# otherwise (clutter, outdoors) every return takes a nearest-neighbour normal.
MIN_LINE_FRACTION = 0.85


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


@njit
def k_pairing_normals(
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
