"""Multi-resolution branch-and-bound correlative scan matching (Olson 2009, "Real-time
correlative scan matching", Section IV; Hess et al. 2016, "Real-time loop closure in 2D
LIDAR SLAM", Section V.C, Algorithm 3).

The score of a pose T (x, y, yaw) of the points (P, 2) on a model is the mean over the
points of the model's likelihood at the point's cell, exp(-d^2 / 2 r^2), d the distance
from the cell to the nearest occupied cell of side r (Olson 2009, Eq. (6); normalised per
point, 1 when every point lies on a model return). The search covers a window of
translations (cells of r) and yaws (steps of about r over the points' farthest range,
Hess et al. 2016, Eq. (7); the full circle when asked).

Branch and bound: the pyramid's level h holds, at each cell, the maximum of the
likelihood over the 2^h x 2^h cells from it (Hess et al. 2016, Eq. (14), the precomputed
grids), so that a node of level h (a yaw and a block of 2^h x 2^h translations) scores at
least as high as each of its translations: an exact bound (Eq. (15)). The nodes of the top
level are scored and searched depth first, best first; a node whose bound is not above
the best leaf found so far is cut with all it holds (Algorithm 3). The result is the
exhaustive search's best, found scoring a small fraction of the poses
(:func:`exhaustive_match` is the reference it is tested against).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import distance_transform_edt

from rigcal.arrays import FloatArray
from rigcal.jit import njit


@dataclass(frozen=True)
class Pyramid:
    """A model's likelihood pyramid (module docstring).

    Attributes:
        grids: (H, U, V) level h's maximum of the likelihood over the 2^h x 2^h cells
            from each cell (level 0: the likelihood), 0 on the border.
        lo: (2,) the corner of cell (0, 0), metres, in the model's frame.
        r: the cell side, metres.
    """

    grids: NDArray[np.float64]
    lo: FloatArray
    r: float

    @property
    def levels(self) -> int:
        return int(self.grids.shape[0])


def likelihood_grid(model: FloatArray, r: float, pad: int) -> tuple[FloatArray, FloatArray, NDArray[np.int_]]:
    """The model's (M, 2) likelihood grid of cell ``r``: exp(-d^2 / 2 r^2), d the distance
    to the nearest occupied cell (Olson 2009), 0 on a border of ``pad`` cells; its lower
    corner (2,) and last cell index (2,)."""
    lo = model.min(axis=0) - pad * r
    shape = tuple(np.ceil((model.max(axis=0) + pad * r - lo) / r).astype(int) + 1)
    occupied = np.zeros(shape, dtype=bool)
    cells = np.floor((model - lo) / r).astype(int)
    occupied[cells[:, 0], cells[:, 1]] = True
    like = np.exp(-0.5 * distance_transform_edt(~occupied) ** 2)
    like[:pad], like[-pad:], like[:, :pad], like[:, -pad:] = 0.0, 0.0, 0.0, 0.0
    return like, lo, np.array(shape) - 1


def pyramid(model: FloatArray, r: float, levels: int) -> Pyramid:
    """The likelihood pyramid of ``levels`` levels of the model's points (M, 2) on cells
    of ``r`` metres (module docstring)."""
    if levels < 1 or not r > 0 or len(model) == 0:
        raise ValueError("a pyramid needs a model point, a positive cell and at least one level")
    # A border of 0: the cells a point beyond the grid is clipped to.
    like, lo, _ = likelihood_grid(model, r, 2)
    grids = np.empty((levels, *like.shape))
    grids[0] = like
    for h in range(1, levels):
        half = 1 << (h - 1)
        prev = grids[h - 1]
        g = prev.copy()
        g[:-half] = np.maximum(g[:-half], prev[half:])
        g2 = g.copy()
        g2[:, :-half] = np.maximum(g2[:, :-half], g[:, half:])
        grids[h] = g2
    return Pyramid(grids, lo, r)


def yaw_step(points: FloatArray, r: float) -> float:
    """The yaw step that moves the farthest point by about one cell (Hess et al. 2016,
    Eq. (7))."""
    d_max = float(np.max(np.hypot(*points.T))) if len(points) else 0.0
    if d_max <= r:
        return float(np.pi / 4)
    return float(np.arccos(1.0 - r**2 / (2.0 * d_max**2)))


def search_yaws(center_rad: float, window_rad: float, step_rad: float) -> FloatArray:
    """The yaws searched: ``center_rad`` +- ``window_rad`` by ``step_rad``, or the full
    circle from ``center_rad`` when the window reaches half a turn."""
    if window_rad >= np.pi:
        n = int(np.ceil(2 * np.pi / step_rad))
        return np.asarray(center_rad + np.arange(n) * (2 * np.pi / n), dtype=float)
    n = int(np.ceil(window_rad / step_rad))
    return np.asarray(center_rad + np.arange(-n, n + 1) * step_rad, dtype=float)


@dataclass(frozen=True)
class Match:
    """The best pose (x, y, yaw) of the points on the model and its score; ``elsewhere``:
    the best score of the poses farther than the exclusion radius from it (0 when none),
    and ``nodes``: the nodes the two searches scored."""

    pose: FloatArray
    score: float
    elsewhere: float
    nodes: int


def match(
    pyr: Pyramid,
    points: FloatArray,
    guess: FloatArray,
    window_m: float,
    window_rad: float,
    *,
    step_rad: float | None = None,
    away_m: float = 0.0,
    away_ratio: float = 0.0,
    min_score: float = 0.0,
) -> Match:
    """The pose within ``window_m`` (square half-width) / ``window_rad`` of ``guess``
    (x, y, yaw; the full circle when ``window_rad`` >= pi) that scores the points (P, 2)
    best on the pyramid's model, by branch and bound (module docstring); with ``away_m`` >
    0 also the best score farther than ``away_m`` from it (a second search with the poses
    near the best cut), searched only above ``away_ratio`` times the best score (0 when
    none is: the ambiguity test needs no more, and the cut makes the search cheap).
    ``min_score``: scores at or below it are not searched (the best is then ``guess``
    with score 0)."""
    yaws = search_yaws(float(guess[2]), window_rad, step_rad or yaw_step(points, pyr.r))
    bu, bv, n_t = _bases(pyr, points, guess, window_m, yaws)
    n = 2 * n_t + 1
    args = (pyr.grids, bu, bv, n, n, min_score)
    y, u, v, score, nodes = _bnb(*args, -1, -1, -1.0)
    if y < 0:
        return Match(np.asarray(guess, dtype=float).copy(), 0.0, 0.0, nodes)
    pose = np.array([guess[0] + (u - n_t) * pyr.r, guess[1] + (v - n_t) * pyr.r, yaws[y]])
    elsewhere = 0.0
    if away_m > 0:
        floor = max(min_score, away_ratio * score)
        _, _, _, second, more = _bnb(pyr.grids, bu, bv, n, n, floor, u, v, away_m / pyr.r)
        second = second if second > floor else 0.0
        elsewhere, nodes = max(second, 0.0), nodes + more
    return Match(pose, float(score), float(elsewhere), nodes)


def exhaustive_match(
    pyr: Pyramid, points: FloatArray, guess: FloatArray, window_m: float, window_rad: float, step_rad: float
) -> tuple[FloatArray, float]:
    """The reference of :func:`match`: every pose of the window scored on level 0."""
    yaws = search_yaws(float(guess[2]), window_rad, step_rad)
    bu, bv, n_t = _bases(pyr, points, guess, window_m, yaws)
    hi_u, hi_v = pyr.grids.shape[1] - 1, pyr.grids.shape[2] - 1
    shifts = np.arange(2 * n_t + 1)
    best, at = -1.0, (0, 0, 0)
    for y in range(len(yaws)):
        iu = np.clip(bu[y][None, :] + shifts[:, None], 0, hi_u)
        iv = np.clip(bv[y][None, :] + shifts[:, None], 0, hi_v)
        s = pyr.grids[0][iu[:, None, :], iv[None, :, :]].mean(axis=2)
        u, v = np.unravel_index(np.argmax(s), s.shape)
        if s[u, v] > best:
            best, at = float(s[u, v]), (y, int(u), int(v))
    return np.array([guess[0] + (at[1] - n_t) * pyr.r, guess[1] + (at[2] - n_t) * pyr.r, yaws[at[0]]]), best


def _bases(
    pyr: Pyramid, points: FloatArray, guess: FloatArray, window_m: float, yaws: FloatArray
) -> tuple[NDArray[np.int64], NDArray[np.int64], int]:
    """(Y, P) the cells of the points at each yaw with the window's lowest translation, and
    the window's half-width in cells."""
    n_t = max(0, int(np.ceil(window_m / pyr.r)))
    c, s = np.cos(yaws)[:, None], np.sin(yaws)[:, None]
    qx = c * points[:, 0] - s * points[:, 1] + guess[0] - n_t * pyr.r
    qy = s * points[:, 0] + c * points[:, 1] + guess[1] - n_t * pyr.r
    bu = np.floor((qx - pyr.lo[0]) / pyr.r).astype(np.int64)
    bv = np.floor((qy - pyr.lo[1]) / pyr.r).astype(np.int64)
    return bu, bv, n_t


@njit
def _score(
    grid: FloatArray, bu: NDArray[np.int64], bv: NDArray[np.int64], y: int, u: int, v: int
) -> float:  # pragma: no cover - compiled; exhaustive_match is its reference
    hi_u, hi_v = grid.shape[0] - 1, grid.shape[1] - 1
    total = 0.0
    for p in range(bu.shape[1]):
        a = min(max(bu[y, p] + u, 0), hi_u)
        b = min(max(bv[y, p] + v, 0), hi_v)
        total += grid[a, b]
    return total / bu.shape[1]


@njit
def _inside(u: int, v: int, size: int, ex_u: int, ex_v: int, ex_r: float) -> bool:  # pragma: no cover
    """Whether the block of ``size`` cells from (u, v) lies within ``ex_r`` cells of
    (ex_u, ex_v) (its farthest corner does)."""
    du = max(abs(u - ex_u), abs(u + size - 1 - ex_u))
    dv = max(abs(v - ex_v), abs(v + size - 1 - ex_v))
    return float(du * du + dv * dv) <= ex_r * ex_r


@njit
def _bnb(
    grids: FloatArray,
    bu: NDArray[np.int64],
    bv: NDArray[np.int64],
    n_u: int,
    n_v: int,
    min_score: float,
    ex_u: int,
    ex_v: int,
    ex_r: float,
) -> tuple[int, int, int, float, int]:  # pragma: no cover - compiled; exhaustive_match is its reference
    """Depth-first branch and bound (Hess et al. 2016, Algorithm 3): the best leaf (yaw
    index, u, v), its score and the nodes scored; leaves within ``ex_r`` cells of (ex_u,
    ex_v) are left out (ex_r < 0: none)."""
    n_y = bu.shape[0]
    top = grids.shape[0] - 1
    step = 1 << top
    n_top_u = (n_u + step - 1) // step
    n_top_v = (n_v + step - 1) // step
    n0 = n_y * n_top_u * n_top_v
    cap = n0 + 4 * (top + 1) + 4
    s_h = np.empty(cap, dtype=np.int64)
    s_y = np.empty(cap, dtype=np.int64)
    s_u = np.empty(cap, dtype=np.int64)
    s_v = np.empty(cap, dtype=np.int64)
    s_s = np.empty(cap)
    scores = np.empty(n0)
    ys = np.empty(n0, dtype=np.int64)
    us = np.empty(n0, dtype=np.int64)
    vs = np.empty(n0, dtype=np.int64)
    k = 0
    for y in range(n_y):
        for a in range(n_top_u):
            for b in range(n_top_v):
                ys[k], us[k], vs[k] = y, a * step, b * step
                if ex_r >= 0 and _inside(a * step, b * step, step, ex_u, ex_v, ex_r):
                    scores[k] = -1.0
                else:
                    scores[k] = _score(grids[top], bu, bv, y, a * step, b * step)
                k += 1
    nodes = n0
    order = np.argsort(scores)  # ascending: the best is pushed last, popped first
    sp = 0
    for q in order:
        if scores[q] > min_score:
            s_h[sp], s_y[sp], s_u[sp], s_v[sp], s_s[sp] = top, ys[q], us[q], vs[q], scores[q]
            sp += 1
    best, by, bu_, bv_ = min_score, -1, -1, -1
    c_u = np.empty(4, dtype=np.int64)
    c_v = np.empty(4, dtype=np.int64)
    c_s = np.empty(4)
    while sp > 0:
        sp -= 1
        h, y, u, v, s = s_h[sp], s_y[sp], s_u[sp], s_v[sp], s_s[sp]
        if s <= best:
            continue
        if h == 0:
            best, by, bu_, bv_ = s, y, u, v
            continue
        half = 1 << (h - 1)
        m = 0
        for du in (0, half):
            for dv in (0, half):
                cu, cv = u + du, v + dv
                if cu >= n_u or cv >= n_v:
                    continue
                if ex_r >= 0 and _inside(cu, cv, half, ex_u, ex_v, ex_r):
                    continue
                cs = _score(grids[h - 1], bu, bv, y, cu, cv)
                nodes += 1
                if cs <= best:
                    continue
                # insertion, ascending
                w = m
                while w > 0 and c_s[w - 1] > cs:
                    c_u[w], c_v[w], c_s[w] = c_u[w - 1], c_v[w - 1], c_s[w - 1]
                    w -= 1
                c_u[w], c_v[w], c_s[w] = cu, cv, cs
                m += 1
        for w in range(m):
            s_h[sp], s_y[sp], s_u[sp], s_v[sp], s_s[sp] = h - 1, y, c_u[w], c_v[w], c_s[w]
            sp += 1
    return by, bu_, bv_, best, nodes
