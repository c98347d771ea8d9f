"""Finding a calibration board's returns in scans of a cluttered room (``laser_side: auto``).

A board session's captures share the rig's place: the room, its furniture and its walls
stay put while the board moves. Two things set the board apart from the room:

1. **It moves.** A return that lies on a surface seen at the same place in most other
   captures' scans is background (:func:`static_returns`). What remains are the board,
   the person holding it, and noise; its straight pieces whose length could be the
   board's cut with the scan plane (:func:`board_cut_lengths`: from the sheet's size
   when known, else the printed pattern's) are the candidates (:func:`line_candidates`).
2. **Its plane is known from the image.** The board's pose by PnP fixes where the board
   must cut the scan plane once a rough T_cam_laser is known. A RANSAC over captures and
   candidates gives that rough pose (:func:`rigcal.calib.board.plane.candidate_consensus`);
   then each capture's returns are re-picked near the cut its board's pose predicts
   (:func:`predicted_cut`, :func:`pick_near_cut`: the returns that fit one line within the
   range noise, over the cut's full extent), the pose is re-solved from them by the closed
   form, and the re-picking repeated with a tighter window. This finds a board that line
   extraction cut into pieces, and keeps mixed pixels at its edges and clutter touching its
   ends off its line out. A sheet size (``board.size_m``) widens the extent and the cut
   lengths allowed; the returns along the printed pattern are taken too, so giving it never
   leaves fewer.

:func:`detect_board_returns` runs the steps; when a capture has nothing to offer it raises
:class:`BoardNotFoundError` with what was tried, which the session reader turns into an error
naming the file and key.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray, IntArray
from rigcal.calib.board.plane import PlaneObservation, candidate_consensus, closed_form
from rigcal.calib.intrinsics import Board
from rigcal.calib.noise import MIN_COS_INCIDENCE, TRIM_SIGMAS, canonical_order, fit_line_robust, robust_scale
from rigcal.errors import CalibrationError
from rigcal.geometry import inv_T, transform_points
from rigcal.lines import LineParams, extract_lines, fit_line, ring_order
from rigcal.scan import Scan

# A return is background when another capture has a return within STATIC_TOLERANCE_M
# (or STATIC_SIGMAS range sigmas) of it, within STATIC_BEAMS beams of its angle, in at
# least STATIC_SHARE of the other captures. Needs MIN_STATIC_CAPTURES captures.
STATIC_TOLERANCE_M = 0.05
STATIC_SIGMAS = 5.0
STATIC_BEAMS = 2
STATIC_SHARE = 0.4
MIN_STATIC_CAPTURES = 5
# Consecutive moving returns farther apart than this are separate objects.
CLUSTER_GAP_M = 0.25
# A candidate line's returns lie within LINE_SIGMAS robust sigmas (at least
# LINE_TOLERANCE_M) of it; at most MAX_LINES lines are taken from one cluster.
LINE_SIGMAS = 3.0
LINE_TOLERANCE_M = 0.03
MAX_LINES = 3
# The cut may come out this much longer than the board allows (range noise at its ends).
LENGTH_SLACK_M = 0.05
# Re-picking near the predicted cut: first window (rough pose), then the tight one.
FIRST_WINDOW_M = 0.15
WINDOW_SIGMAS = 4.0
WINDOW_FLOOR_M = 0.05
# How far beyond the predicted cut's ends returns are still taken (the sheet's size and
# the pose are not exact).
END_MARGIN_M = 0.1
REFINE_PASSES = 2
# A floor on the range noise a board's returns are taken within (a noise-free simulator).
MIN_RANGE_SIGMA_M = 0.002
# Runs at the cut's ends whose median of END_RUN returns lies more than END_OFFSET_SIGMAS
# range sigmas off the board's line are clutter touching the board, not the board.
END_RUN = 7
END_OFFSET_SIGMAS = 2.0
# The board's line is the one with the least squared distances of its returns, each capped
# at MSAC_SIGMAS range sigmas (tight, so clutter a few sigmas off costs the cap whatever
# the line, and cannot tilt it).
MSAC_SIGMAS = 2.0


class BoardNotFoundError(Exception):
    """A capture in which no board returns were found.

    Attributes:
        capture: index of the capture.
        detail: what was tried.
    """

    def __init__(self, capture: int, detail: str) -> None:
        super().__init__(detail)
        self.capture = capture
        self.detail = detail


@dataclass(frozen=True)
class BoardShape:
    """The board as the detection needs it.

    Attributes:
        outline: (4, 2) the sheet's corners in the board frame (x along the rows, y down
            the columns, origin at the first inner corner), metres.
        min_cut_m, max_cut_m: the lengths a cut of the sheet by the scan plane may have.
        pattern_outline: (4, 2) the printed pattern's outline (inner corners plus one
            square all round) when the sheet's size is given: returns are picked along
            both, so that giving the size never leaves fewer (None: the outline is it).
    """

    outline: FloatArray
    min_cut_m: float
    max_cut_m: float
    pattern_outline: FloatArray | None = None


def board_shape(board: Board, size_m: tuple[float, float] | None = None) -> BoardShape:
    """The sheet's outline and allowed cut lengths: a sheet of ``size_m`` (width along the
    rows, height) centred on the pattern, else the printed pattern (inner corners plus one
    square all round). A cut is at least a fifth of the sheet's smaller side (a board cut
    near its corner shows too few returns to fit) and at most its diagonal."""
    w0 = (board.width_n - 1) * board.spacing_m
    h0 = (board.height_n - 1) * board.spacing_m
    pattern = (w0 + 2 * board.spacing_m, h0 + 2 * board.spacing_m)

    def outline_of(W: float, H: float) -> FloatArray:
        mx, my = 0.5 * (W - w0), 0.5 * (H - h0)
        return np.array([[-mx, -my], [w0 + mx, -my], [w0 + mx, h0 + my], [-mx, h0 + my]])

    W, H = size_m if size_m is not None else pattern
    # The shortest cut allowed is the pattern's (a larger sheet must not turn away a
    # candidate the pattern alone would take), the longest the larger one's diagonal.
    shortest = 0.2 * min(min(W, H), min(pattern))
    longest = float(max(np.hypot(W, H), np.hypot(*pattern)))
    return BoardShape(outline_of(W, H), shortest, longest, None if size_m is None else outline_of(*pattern))


def plane_cut(T_laser_board: FloatArray, outline: FloatArray) -> FloatArray | None:
    """(2, 2) the segment where the board's outline polygon ((K, 2), board frame, z = 0)
    crosses the laser's z = 0 plane, laser frame; None when it does not cross."""
    corners = transform_points(T_laser_board, np.column_stack([outline, np.zeros(len(outline))]))
    pts = []
    for k in range(len(corners)):
        a, b = corners[k], corners[(k + 1) % len(corners)]
        if (a[2] > 0) != (b[2] > 0):
            s = a[2] / (a[2] - b[2])
            pts.append((a + s * (b - a))[:2])
    if len(pts) != 2:
        return None
    return np.array(pts)


def predicted_cut(T_cam_laser: FloatArray, T_cam_board: FloatArray, shape: BoardShape) -> FloatArray | None:
    """Where a board at ``T_cam_board`` cuts the scan plane of a laser at ``T_cam_laser``."""
    return plane_cut(inv_T(T_cam_laser) @ T_cam_board, shape.outline)


def static_returns(scans: Sequence[Scan], tolerance_m: float = STATIC_TOLERANCE_M) -> list[NDArray[np.bool_]]:
    """Per scan, (N,) which valid returns lie on the static background.

    A return is background when, in at least STATIC_SHARE of the other scans, a return
    within STATIC_BEAMS beams of its angle lies within ``tolerance_m`` of it. With fewer
    than MIN_STATIC_CAPTURES scans nothing is background.
    """
    C = len(scans)
    if C < MIN_STATIC_CAPTURES:
        return [np.zeros(len(s.ranges_m), dtype=bool) for s in scans]
    # Beams are matched by their direction, angles taken modulo a turn (one scan's angles may
    # run -pi..pi and another's 0..2pi) and neighbours round the circle.
    wrapped = [_wrap(s.angles_rad) for s in scans]
    sorted_angles = [np.sort(a) for a in wrapped]
    by_angle = [np.argsort(a, kind="stable") for a in wrapped]
    out = []
    for i, s in enumerate(scans):
        votes = np.zeros(len(s.ranges_m))
        for j, o in enumerate(scans):
            if j == i:
                continue
            k = np.searchsorted(sorted_angles[j], wrapped[i])
            near = np.full(len(k), np.inf)
            for dk in range(-STATIC_BEAMS, STATIC_BEAMS):
                kk = by_angle[j][(k + dk) % len(o.angles_rad)]
                d = np.linalg.norm(o.points[kk] - s.points, axis=1)
                near = np.fmin(near, d)
            votes += near < tolerance_m
        out.append(s.valid & (votes >= STATIC_SHARE * (C - 1)))
    return out


def _wrap(angles_rad: FloatArray) -> FloatArray:
    """Angles in [-pi, pi)."""
    out: FloatArray = np.mod(np.asarray(angles_rad, dtype=float) + np.pi, 2.0 * np.pi) - np.pi
    return out


def line_candidates(
    scan: Scan, moving: NDArray[np.bool_], shape: BoardShape, params: LineParams, seed: int = 0
) -> list[IntArray]:
    """The straight pieces of the moving returns that could be the board's cut.

    The moving returns are split into clusters at gaps (CLUSTER_GAP_M) and at background
    returns; in each cluster up to MAX_LINES lines are found by RANSAC (most returns within
    the tolerance), each refitted; a line whose returns span an allowed cut length becomes
    a candidate.

    The returns are taken round the scan as line extraction takes them (a 360-degree scan
    from its widest gap, :func:`rigcal.lines.extract_lines`), so a board behind the
    scanner, over the seam between its last and first beams, is one cluster, and the same
    returns with the angles written -pi..pi or 0..2pi give the same candidates.

    Returns:
        (M,) beam indices per candidate, in that order round the scan.
    """
    rng = np.random.default_rng(seed)
    beams, pts, _ = ring_order(scan)
    mov = moving[beams]
    out: list[IntArray] = []
    for lo, hi in _clusters(pts, mov):
        idx = np.arange(lo, hi)
        for _ in range(MAX_LINES):
            if len(idx) < params.min_points:
                break
            inliers = _ransac_line(pts[idx], rng)
            if inliers.sum() < params.min_points:
                break
            members = idx[inliers]
            c, u, _ = fit_line(pts[members])
            along = (pts[members] - c) @ u
            length = float(along.max() - along.min())
            if shape.min_cut_m <= length <= shape.max_cut_m + LENGTH_SLACK_M:
                out.append(beams[members])
            idx = idx[~inliers]
    return out


def _clusters(pts: FloatArray, moving: NDArray[np.bool_]) -> list[tuple[int, int]]:
    """[lo, hi) ranges of consecutive moving returns with no gap wider than CLUSTER_GAP_M."""
    out = []
    n = len(pts)
    i = 0
    while i < n:
        if not moving[i]:
            i += 1
            continue
        j = i + 1
        while j < n and moving[j] and float(np.linalg.norm(pts[j] - pts[j - 1])) <= CLUSTER_GAP_M:
            j += 1
        out.append((i, j))
        i = j
    return out


def _ransac_line(p: FloatArray, rng: np.random.Generator, tries: int = 40) -> NDArray[np.bool_]:
    """The returns of the line through most of ``p`` (M, 2): RANSAC over pairs with a
    tolerance of LINE_SIGMAS robust sigmas of the best line's residuals (at least
    LINE_TOLERANCE_M), then one refit."""
    best = np.zeros(len(p), dtype=bool)
    for _ in range(tries):
        a, b = rng.choice(len(p), size=2, replace=False)
        d = p[b] - p[a]
        L = float(np.linalg.norm(d))
        if L < 1e-6:
            continue
        n = np.array([-d[1], d[0]]) / L
        ok = np.abs((p - p[a]) @ n) < LINE_TOLERANCE_M
        if ok.sum() > best.sum():
            best = ok
    if best.sum() < 2:
        return best
    return _line_inliers(p, best)


def _line_inliers(p: FloatArray, seed_mask: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """Returns within LINE_SIGMAS robust sigmas (at least LINE_TOLERANCE_M) of the line
    fitted to ``p[seed_mask]``."""
    c, u, _ = fit_line(p[seed_mask])
    r = np.abs((p - c) @ np.array([-u[1], u[0]]))
    sigma = MAD_TO_SIGMA * float(np.median(r[seed_mask]))
    out: NDArray[np.bool_] = r < max(LINE_TOLERANCE_M, LINE_SIGMAS * sigma)
    return out


def pick_near_cut(
    scan: Scan,
    moving: NDArray[np.bool_],
    cut: FloatArray,
    window_m: float,
    min_points: int,
    range_sigma_m: float = 0.0,
) -> IntArray:
    """Beams of the board's returns near the cut its image pose predicts.

    A board is flat, so its returns are those that fit one line within the range noise:
    the moving returns within ``window_m`` of the predicted cut's line (and within
    END_MARGIN_M of its ends) give the line (MSAC, :func:`_msac_line`, from a robust fit:
    clutter touching the board's ends cannot tilt it); then every
    moving return within TRIM_SIGMAS range sigmas of that line (its distance as a range
    error, divided by the beam's incidence) over the full extent of the predicted cut is
    taken: a board the rough pose puts a little askew is taken whole, and clutter touching
    its ends off its line (hands, a body, a wall behind) is left out. The range sigma is
    ``range_sigma_m`` (the session's), else the returns' own robust scatter. Empty when
    fewer than ``min_points``."""
    beams = np.flatnonzero(moving & scan.valid)
    beams = beams[canonical_order(scan.points[beams])]  # the same set, the same fit to the last bit
    p = scan.points[beams]
    d = cut[1] - cut[0]
    L = float(np.linalg.norm(d))
    u = d / L
    rel = p - cut[0]
    along = rel @ u
    extent = (along > -END_MARGIN_M) & (along < L + END_MARGIN_M)
    near = extent & (np.abs(rel @ np.array([-u[1], u[0]])) < window_m)
    if near.sum() < min_points:
        return np.zeros(0, dtype=np.int64)
    fit = fit_line_robust(p[near])
    if fit.kept.sum() < min_points:
        return np.zeros(0, dtype=np.int64)
    # The session's range noise (over every capture's candidates: clutter in this one
    # cannot inflate it), else these returns' own robust scatter.
    sigma = max(
        range_sigma_m if range_sigma_m > 0 else robust_scale(fit.range_residuals_m), MIN_RANGE_SIGMA_M
    )
    centroid, normal = _msac_line(p[near], (fit.centroid, fit.normal), MSAC_SIGMAS * sigma)
    r = (p - centroid) @ normal
    rays = p / np.maximum(np.linalg.norm(p, axis=1, keepdims=True), 1e-12)
    cos = np.maximum(np.abs(rays @ normal), MIN_COS_INCIDENCE)
    on = extent & (np.abs(r / cos) <= TRIM_SIGMAS * sigma)
    on[on] = _trim_offset_ends(((p[on] - centroid) @ np.array([normal[1], -normal[0]])), (r / cos)[on], sigma)
    return beams[on] if on.sum() >= min_points else np.zeros(0, dtype=np.int64)


def _trim_offset_ends(
    along_m: FloatArray, range_residuals_m: FloatArray, sigma_m: float
) -> NDArray[np.bool_]:
    """(M,) the returns kept once runs at either end of the cut that lie off the line are
    trimmed: going in from each end (by position along the line), returns are dropped while
    the median of END_RUN consecutive ones is more than END_OFFSET_SIGMAS range sigmas off
    the line (a hand or a body touching the board's end, 50-100 mm off its line, passes a
    per-return band of a few sigmas but not this; a board's true end has median 0)."""
    keep = np.ones(len(along_m), dtype=bool)
    if len(along_m) < 3 * END_RUN:
        return keep
    order = np.argsort(along_m, kind="stable")
    r = range_residuals_m[order]
    med = np.array([np.median(r[max(0, k - END_RUN // 2) : k + END_RUN // 2 + 1]) for k in range(len(r))])
    off = np.abs(med) > END_OFFSET_SIGMAS * sigma_m
    lo, hi = 0, len(r)
    while lo < hi and off[lo]:
        lo += 1
    while hi > lo and off[hi - 1]:
        hi -= 1
    keep[order[:lo]] = False
    keep[order[hi:]] = False
    return keep


def _msac_line(
    p: FloatArray, start: tuple[FloatArray, FloatArray], band_m: float, tries: int = 200
) -> tuple[FloatArray, FloatArray]:
    """The line through (M, 2) returns with the least truncated squared distances (MSAC:
    each return costs min(r^2, band^2)), from ``start`` (centroid, unit normal) and lines
    through pairs of returns drawn with a fixed seed, refitted on its returns within the
    band. Unlike a least-squares fit, a stretch of clutter touching the board's end a
    little off its line cannot tilt it (a tilted line costs the board's returns more than
    it saves on the clutter's). Returns (a point of the line, its unit normal)."""
    rng = np.random.default_rng(0)
    b2 = band_m**2

    def cost(c: FloatArray, n: FloatArray) -> float:
        return float(np.minimum(((p - c) @ n) ** 2, b2).sum())

    best = (cost(*start), start[0], start[1])
    for _ in range(tries):
        i, j = rng.choice(len(p), size=2, replace=False)
        d = p[j] - p[i]
        L = float(np.linalg.norm(d))
        if L < 1e-6:
            continue
        n = np.array([-d[1], d[0]]) / L
        k = cost(p[i], n)
        if k < best[0]:
            best = (k, p[i], n)
    c, n = np.asarray(best[1], dtype=float), np.asarray(best[2], dtype=float)
    for _ in range(3):
        inl = np.abs((p - c) @ n) <= band_m
        if inl.sum() < 2:
            break
        c, u, _ = fit_line(p[inl])
        n = np.array([-u[1], u[0]])
    return c, n


def detect_board_returns(
    scans: Sequence[Scan],
    T_cam_board: Sequence[FloatArray],
    planes: Sequence[tuple[FloatArray, float]],
    shape: BoardShape,
    given: dict[int, FloatArray],
    params: LineParams,
) -> list[FloatArray]:
    """The board's returns in every capture; captures in ``given`` keep theirs.

    Args:
        scans: every capture's scan.
        T_cam_board: (4, 4) per capture, the board's pose from PnP.
        planes: per capture, the board plane (unit normal (3,), distance m), camera frame.
        shape: the board's outline and allowed cut lengths.
        given: capture index -> (M, 2) returns the session names for it.
        params: line extraction thresholds (for the least number of returns).

    Returns:
        Per capture, (M, 2) the board's returns, laser frame.

    Raises:
        BoardNotFoundError: a capture with no candidate.
        CalibrationError: too few captures agree on any calibration.
    """
    C = len(scans)
    static = static_returns(scans)
    moving = [s.valid & ~st for s, st in zip(scans, static, strict=True)]
    cands: dict[int, list[IntArray]] = {
        i: line_candidates(scans[i], moving[i], shape, params, seed=i) for i in range(C) if i not in given
    }
    for i, found in cands.items():
        if not found:
            raise BoardNotFoundError(i, _nothing_found(scans[i], static[i], shape, params))
    usable = list(range(C))
    point_sets = [[given[i]] if i in given else [scans[i].points[b] for b in cands[i]] for i in usable]
    noise = _noise_scale(point_sets)
    threshold = max(LINE_TOLERANCE_M, LINE_SIGMAS * noise)
    T, chosen, _ = candidate_consensus([planes[i] for i in usable], point_sets, threshold_m=threshold)
    picks: dict[int, IntArray] = {
        i: cands[i][k] for i, k in zip(usable, chosen, strict=True) if i not in given
    }
    window = FIRST_WINDOW_M
    for _ in range(REFINE_PASSES):
        for i in range(C):
            if i in given:
                continue
            near = np.zeros(0, dtype=np.int64)
            # Along the sheet and, when its size is given, along the printed pattern too:
            # the size can only add returns.
            for outline in (shape.outline, shape.pattern_outline):
                cut = None if outline is None else plane_cut(inv_T(T) @ T_cam_board[i], outline)
                if cut is not None:
                    got = pick_near_cut(scans[i], moving[i], cut, window, params.min_points, noise)
                    near = np.union1d(near, got).astype(np.int64)
            if len(near):
                picks[i] = near
        obs = [
            PlaneObservation(
                i, str(i), np.asarray(planes[i][0]), float(planes[i][1]), _points(i, scans, given, picks)
            )
            for i in range(C)
            if i in given or i in picks
        ]
        try:
            T = closed_form(obs)
        except CalibrationError:
            break
        window = max(WINDOW_FLOOR_M, WINDOW_SIGMAS * threshold / LINE_SIGMAS)
    return [_points(i, scans, given, picks) for i in range(C)]


def _points(
    i: int, scans: Sequence[Scan], given: dict[int, FloatArray], picks: dict[int, IntArray]
) -> FloatArray:
    return given[i] if i in given else np.array(scans[i].points[picks[i]])


def _noise_scale(point_sets: Sequence[Sequence[FloatArray]]) -> float:
    """The range noise the candidates show: the median over candidates of their robust
    residual sigma about their own line."""
    sigmas = []
    for cands in point_sets:
        for p in cands:
            if len(p) >= 3:
                c, u, _ = fit_line(p)
                sigmas.append(MAD_TO_SIGMA * float(np.median(np.abs((p - c) @ np.array([-u[1], u[0]])))))
    return float(np.median(sigmas)) if sigmas else 0.0


def _nothing_found(scan: Scan, static: NDArray[np.bool_], shape: BoardShape, params: LineParams) -> str:
    """What was tried in a capture where no board was found, for the error message."""
    segments = extract_lines(scan, params)
    n_static = sum(1 for g in segments if static[g.indices].mean() >= 0.5)
    n_sized = sum(1 for g in segments if shape.min_cut_m <= g.length_m <= shape.max_cut_m + LENGTH_SLACK_M)
    return (
        f"the board's returns: cut lengths {shape.min_cut_m:.2f}-{shape.max_cut_m:.2f} m allowed "
        f"(set board.size_m for a sheet larger than its pattern), {len(segments)} line segments "
        f"seen, {n_static} of them on static background (seen in most other captures), "
        f"{n_sized} of an allowed length, {int((scan.valid & ~static).sum())} moving returns, "
        "none on a line of an allowed length or near the cut the board's pose predicts; "
        "give {segment: ID} or {segments: [ID, ...]} (see `rigcal lines`)"
    )
