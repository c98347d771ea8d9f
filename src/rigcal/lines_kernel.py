"""The compiled line extraction: :func:`rigcal.lines.extract_lines`' steps in numba
kernels (:mod:`rigcal.jit`), combined least-squares region growing after the paper's
Section III-B as :mod:`rigcal.lines` describes it.

The runs of returns without gaps, the region growing (:func:`grow`, with the running
sums of an O(1) refit per return), the joining of pieces of one line (:func:`merge`),
the end trimming (:func:`trim`), the size filter and the segments' fits
(:func:`fit`) run in one call (:func:`extract_kernel`) over index ranges into buffers,
each step following its Python reference in :mod:`rigcal.lines`, which the tests
hold it to. A module apart so that importing :mod:`rigcal.lines` (calibration,
plots) does not import numba; :func:`rigcal.lines.extract_lines` imports it on
its first compiled call.
"""

from __future__ import annotations

import math

import numpy as np

from rigcal.arrays import MAD_TO_SIGMA, FloatArray, IntArray
from rigcal.jit import njit


@njit
def extract_kernel(
    pts: FloatArray,
    max_gap_m: float,
    tol: float,
    cos_turn: float,
    seed_points: int,
    seed_length_m: float,
    min_points: int,
    min_length_m: float,
    merge_angle_test_m: float,
    trim_sigmas: float,
    trim_floor_m: float,
    members: IntArray,
    bounds: IntArray,
    fits: FloatArray,
) -> int:
    """Line segments of the returns ``pts`` (N, 2) by least-squares region growing (paper
    Section III-B), as ``lines.extract_lines`` without the numbering: the returns are cut
    into runs at gaps wider than ``max_gap_m`` (``lines._runs``), each run is grown
    (:func:`grow`, the reference ``lines._grow_run``), its pieces of one line joined
    (:func:`merge`, ``lines._merge_collinear``), each segment's ends trimmed
    (:func:`trim`, ``lines._trim_ends``), and the segments with at least ``min_points``
    returns and ``min_length_m`` length kept. Segment k's returns go to
    ``members[bounds[k]:bounds[k + 1]]``, its fit to ``fits[k]`` (centroid, direction,
    start, end, RMS residual). Returns the number of segments."""
    n = pts.shape[0]
    grown = np.empty(n, dtype=np.int64)
    grown_at = np.empty(n + 1, dtype=np.int64)
    merged = np.empty(n, dtype=np.int64)
    merged_at = np.empty(n + 1, dtype=np.int64)
    scratch = np.empty(n)
    kept = 0
    bounds[0] = 0
    lo = 0
    while lo < n:
        hi = lo + 1
        while hi < n:
            dx, dy = pts[hi, 0] - pts[hi - 1, 0], pts[hi, 1] - pts[hi - 1, 1]
            if math.sqrt(dx * dx + dy * dy) > max_gap_m:
                break
            hi += 1
        n_grown = grow(pts, lo, hi, tol, cos_turn, seed_points, seed_length_m, grown, grown_at)
        n_merged = merge(pts, grown, grown_at, n_grown, tol, cos_turn, merge_angle_test_m, merged, merged_at)
        for g in range(n_merged):
            a, b = trim(
                pts,
                merged,
                merged_at[g],
                merged_at[g + 1],
                seed_points,
                min_points,
                trim_sigmas,
                trim_floor_m,
                scratch,
            )
            if b - a < min_points:
                continue
            cx, cy, ux, uy, rms = fit(pts, merged, a, b)
            first, last = merged[a], merged[b - 1]
            t0 = (pts[first, 0] - cx) * ux + (pts[first, 1] - cy) * uy
            t1 = (pts[last, 0] - cx) * ux + (pts[last, 1] - cy) * uy
            sx, sy, ex, ey = cx + t0 * ux, cy + t0 * uy, cx + t1 * ux, cy + t1 * uy
            if math.sqrt((ex - sx) * (ex - sx) + (ey - sy) * (ey - sy)) < min_length_m:
                continue
            at = bounds[kept]
            for m in range(a, b):
                members[at + m - a] = merged[m]
            f = fits[kept]
            f[0], f[1], f[2], f[3], f[4], f[5], f[6], f[7], f[8] = cx, cy, ux, uy, sx, sy, ex, ey, rms
            kept += 1
            bounds[kept] = at + b - a
        lo = hi
    return kept


@njit
def fit(pts: FloatArray, idx: IntArray, a: int, b: int) -> tuple[float, float, float, float, float]:
    """``lines.fit_line`` of the returns ``pts[idx[a:b]]``: (centroid x, y, direction x, y,
    RMS residual), the direction from the first return towards the last."""
    n = b - a
    sx = sy = 0.0
    for k in range(a, b):
        sx += pts[idx[k], 0]
        sy += pts[idx[k], 1]
    cx, cy = sx / n, sy / n
    sxx = sxy = syy = 0.0
    for k in range(a, b):
        qx, qy = pts[idx[k], 0] - cx, pts[idx[k], 1] - cy
        sxx += qx * qx
        sxy += qx * qy
        syy += qy * qy
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)  # as _direction
    ux, uy = math.cos(theta), math.sin(theta)
    resid2 = 0.5 * (sxx + syy) - math.hypot(0.5 * (sxx - syy), sxy)  # as _principal_direction
    first, last = idx[a], idx[b - 1]
    if ux * (pts[last, 0] - pts[first, 0]) + uy * (pts[last, 1] - pts[first, 1]) < 0:
        ux, uy = -ux, -uy
    return cx, cy, ux, uy, math.sqrt(max(resid2, 0.0) / n)


@njit
def grow(
    pts: FloatArray,
    lo: int,
    hi: int,
    tol: float,
    cos_turn: float,
    seed_points: int,
    seed_length_m: float,
    out: IntArray,
    out_at: IntArray,
) -> int:
    """``lines._grow_run`` over the returns pts[lo:hi]: a seed (``lines._seed_end``) all
    on its line, grown one return at a time with the running sums of ``lines._Grower``
    (an O(1) refit per return), a return off the line ending the segment unless the next
    is back on it, a refit turning by more than the threshold ending it too. Segment g's
    returns go to ``out[out_at[g]:out_at[g + 1]]``; returns the number of segments."""
    n_out = 0
    at = 0
    out_at[0] = 0
    i = lo
    while i < hi:
        # _seed_end: the shortest seed from i with >= seed_points returns spanning seed_length_m.
        seed_end = -1
        j = i + seed_points
        while j <= hi:
            dx, dy = pts[j - 1, 0] - pts[i, 0], pts[j - 1, 1] - pts[i, 1]
            if math.sqrt(dx * dx + dy * dy) >= seed_length_m:
                seed_end = j
                break
            j += 1
        if seed_end < 0:
            break
        m = at
        for k in range(i, seed_end):
            out[m] = k
            m += 1
        cx, cy, ux, uy, _ = fit(pts, out, at, m)
        worst = 0.0
        for k in range(i, seed_end):
            worst = max(worst, abs((pts[k, 0] - cx) * uy - (pts[k, 1] - cy) * ux))
        if worst > tol:
            i += 1  # not a line here: slide the seed window
            continue
        count = seed_end - i
        sx = sy = sxx = sxy = syy = 0.0
        for k in range(i, seed_end):
            x, y = pts[k, 0], pts[k, 1]
            sx += x
            sy += y
            sxx += x * x
            sxy += x * y
            syy += y * y
        j = seed_end
        while j < hi:
            x, y = pts[j, 0], pts[j, 1]
            if abs((x - cx) * uy - (y - cy) * ux) > tol:
                # One noisy return followed by one back on the line: filter it out.
                if j + 1 < hi and abs((pts[j + 1, 0] - cx) * uy - (pts[j + 1, 1] - cy) * ux) <= tol:
                    j += 1
                    continue
                break
            # _Grower.line: the least-squares line with (x, y) added.
            c1 = count + 1
            ncx, ncy = (sx + x) / c1, (sy + y) / c1
            theta = 0.5 * math.atan2(
                2.0 * (sxy + x * y - c1 * ncx * ncy),
                (sxx + x * x - c1 * ncx * ncx) - (syy + y * y - c1 * ncy * ncy),
            )
            nux, nuy = math.cos(theta), math.sin(theta)
            if abs(nux * ux + nuy * uy) < cos_turn:
                break
            count = c1
            sx += x
            sy += y
            sxx += x * x
            sxy += x * y
            syy += y * y
            out[m] = j
            m += 1
            cx, cy, ux, uy = ncx, ncy, nux, nuy
            j += 1
        n_out += 1
        out_at[n_out] = m
        at = m
        # A filtered return just before the stop starts the next seed.
        i = out[m - 1] + 1
    return n_out


@njit
def merge(
    pts: FloatArray,
    groups: IntArray,
    groups_at: IntArray,
    n_groups: int,
    tol: float,
    cos_turn: float,
    angle_test_m: float,
    out: IntArray,
    out_at: IntArray,
) -> int:
    """``lines._merge_collinear`` of one run's segments
    (``groups[groups_at[g]:groups_at[g + 1]]``): a segment joins the one before when at
    most one return separates them, the smaller piece's returns lie within ``tol`` of the
    larger's line, the joined fit is as tight as the pieces' and (for a long enough
    smaller piece) their directions agree. The joined segments go to
    ``out[out_at[g]:out_at[g + 1]]``; returns their number."""
    n_out = 0
    out_at[0] = 0
    for g in range(n_groups):
        ga, gb = groups_at[g], groups_at[g + 1]
        at = out_at[n_out]
        end = at + gb - ga
        for k in range(ga, gb):
            out[at + k - ga] = groups[k]
        if n_out > 0:
            pa = out_at[n_out - 1]
            if at - pa >= 2 and end - at >= 2 and out[at] - out[at - 1] <= 2:
                if at - pa < end - at:
                    sa, sb, la, lb = pa, at, at, end
                else:
                    sa, sb, la, lb = at, end, pa, at
                cl_x, cl_y, ul_x, ul_y, rl = fit(pts, out, la, lb)
                _, _, us_x, us_y, rs = fit(pts, out, sa, sb)
                off = 0.0
                for k in range(sa, sb):
                    off = max(off, abs((pts[out[k], 0] - cl_x) * ul_y - (pts[out[k], 1] - cl_y) * ul_x))
                rj = fit(pts, out, pa, end)[4]
                dx, dy = pts[out[sb - 1], 0] - pts[out[sa], 0], pts[out[sb - 1], 1] - pts[out[sa], 1]
                small_len = math.sqrt(dx * dx + dy * dy)
                if (
                    off <= tol
                    and rj <= 1.2 * max(rl, rs) + 0.001
                    and (small_len < angle_test_m or abs(ul_x * us_x + ul_y * us_y) >= cos_turn)
                ):
                    out_at[n_out] = end  # joined to the segment before
                    continue
        n_out += 1
        out_at[n_out] = end
    return n_out


@njit
def trim(
    pts: FloatArray,
    idx: IntArray,
    a: int,
    b: int,
    seed_points: int,
    min_points: int,
    sigmas: float,
    floor_m: float,
    scratch: FloatArray,
) -> tuple[int, int]:
    """``lines._trim_ends`` of the segment ``idx[a:b]``: drop an end return farther than
    ``sigmas`` robust sigmas (median absolute residual x 1.4826, at least ``floor_m``)
    from the line of the others, up to 2 x seed_points times. Returns the new (a, b)."""
    for _ in range(2 * seed_points):
        if b - a <= min_points:
            break
        trimmed = False
        for end in range(2):
            ra, rb = (a + 1, b) if end == 0 else (a, b - 1)
            cx, cy, ux, uy, _ = fit(pts, idx, ra, rb)
            for k in range(ra, rb):
                scratch[k - ra] = abs((pts[idx[k], 0] - cx) * uy - (pts[idx[k], 1] - cy) * ux)
            sigma = max(MAD_TO_SIGMA * np.median(scratch[: rb - ra]), floor_m)
            e = idx[a] if end == 0 else idx[b - 1]
            if abs((pts[e, 0] - cx) * uy - (pts[e, 1] - cy) * ux) > sigmas * sigma:
                a, b = ra, rb
                trimmed = True
                break
        if not trimmed:
            break
    return a, b
