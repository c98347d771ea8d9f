"""A scan pair's ICP in one call of a compiled kernel (:mod:`rigcal.jit`): the grid of the
model (:mod:`rigcal.localize.nearest`, nearest neighbours exact as the k-d tree), the
coarse and fine stages' iterations (pairing, rejection and the update of
:mod:`rigcal.localize.icp_steps` in one loop on work arrays allocated once), the pairing
normals (:mod:`rigcal.localize.line_normals`) and the degeneracy.

:func:`rigcal.localize.icp.icp` calls it; its numpy iterations (``kernel=False``) are the
kernel's reference in the tests.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.jit import njit
from rigcal.localize.icp_steps import k_point_to_line, k_point_to_point
from rigcal.localize.line_normals import k_pairing_normals
from rigcal.localize.nearest import GridArgs, build, knn, knn_one

# The sparse stages' exact nearest neighbours (a k-d tree query each iteration in the
# numpy reference) come from this many candidates per point, queried again for a point
# only when it has moved too far for its nearest to be sure to be among them.
SPARSE_CANDIDATES = 3


@njit
def icp_kernel(
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
        use_usable = k_pairing_normals(
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
            x, y, yaw = k_point_to_line(out_src, out_pairs, lines, n_inl, degenerate_ratio)
        else:
            x, y, yaw = k_point_to_point(out_src, out_pairs, model, n_inl)
        cy, sy = np.cos(yaw), np.sin(yaw)
        c, s, tx, ty = cy * c - sy * s, sy * c + cy * s, cy * tx - sy * ty + x, sy * tx + cy * ty + y
        if np.hypot(x, y) < tol_m and abs(yaw) < tol_rad:
            break
    pose[0], pose[1], pose[2], pose[3] = c, s, tx, ty
    return fit_k, fit_rms, fit_frac, fit_n
