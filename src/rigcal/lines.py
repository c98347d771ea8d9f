"""Line extraction from 2D scans: combined least-squares region growing (paper Section III-B).

The scan's returns are sorted by beam angle, so a line is a run of consecutive valid
returns; a scan that covers the full circle is a ring (its last and first beams are
neighbours), cut at its widest gap so that a line behind the scanner, over the seam
between angles +-180 deg, comes out whole. Following the paper, a seed line is formed at
the start of a run and grown one return at a time: a return farther than
``max_point_distance_m`` from the current line ends the segment; otherwise the line is
refitted by least squares with the return included, and if the refitted line turns by
more than ``max_angle_change_deg`` (the paper's "similar slope-intercept form" test)
the segment ends too.

Two changes make this work on real scanners, whose range noise (about 1 cm) is of the
order of the spacing of neighbouring returns at short range:

- the seed is not two returns but the shortest run of at least ``seed_points`` returns
  spanning ``seed_length_m``, accepted only if all its returns lie on its fitted line
  (otherwise the seed window slides by one return);
- a single return off the line, followed by one back on it, is a noisy return: it is
  left out of the segment (the paper notes the method "serves to filter noisy point
  returns") rather than ending it.

A gap of more than ``max_gap_m`` between neighbouring returns always ends a segment.
Neighbouring pieces of one line that noise has cut apart are joined again
(:func:`_merge_collinear`).
Segments shorter than ``min_length_m`` or with fewer than ``min_points`` returns are
dropped; the others are numbered 0, 1, ... in beam order: these are the ids that
``rigcal lines`` prints and picking files use. This module is shared with the
localization methods (IASM's line-angle histogram, H-IASM's plane normals).

The steps run in one compiled kernel (:mod:`rigcal.lines_kernel`), a loop per
return on index ranges; the Python functions below (``extract_lines(...,
kernel=False)``) are its reference, which the tests hold it to (the same segments, fits
to 1e-12).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from rigcal.arrays import MAD_TO_SIGMA, FloatArray, IntArray
from rigcal.scan import Scan

# An end return farther than this many robust sigmas (median absolute residual * 1.4826,
# at least END_TRIM_FLOOR_M) from the line of the other returns is trimmed.
END_TRIM_SIGMAS = 4.0
END_TRIM_FLOOR_M = 0.0005
# Two pieces of one line are joined only if their directions agree, when the smaller
# piece is at least this long (a shorter one's direction is mostly noise).
MERGE_ANGLE_TEST_M = 0.3


# The range noise the default thresholds are made for (a Hokuyo-class scanner).
DEFAULT_RANGE_SIGMA_M = 0.01


@dataclass(frozen=True)
class LineParams:
    """Thresholds of the region growing (defaults suit a Hokuyo-class scanner, 1 cm noise).

    Attributes:
        max_point_distance_m: a return farther than this from the growing line does not
            belong to it (3 sigma of the range noise).
        max_angle_change_deg: the refitted line may turn by at most this when a return is
            added (the paper's slope-intercept similarity threshold).
        max_gap_m: neighbouring returns farther apart than this are never on one segment.
        seed_points: least number of returns in a seed.
        seed_length_m: least length of a seed (its end returns' distance).
        min_points: segments with fewer returns are dropped.
        min_length_m: segments shorter than this are dropped.
    """

    max_point_distance_m: float = 0.03
    max_angle_change_deg: float = 10.0
    max_gap_m: float = 0.25
    seed_points: int = 5
    seed_length_m: float = 0.08
    min_points: int = 5
    min_length_m: float = 0.1

    @classmethod
    def for_range_noise(cls, range_sigma_m: float) -> LineParams:
        """Defaults for a scanner with this range noise (1 sigma): the distance thresholds
        scale with the noise above the 1 cm the defaults are made for, never below them."""
        k = max(1.0, range_sigma_m / DEFAULT_RANGE_SIGMA_M)
        d = cls()
        return cls(
            max_point_distance_m=d.max_point_distance_m * k,
            max_angle_change_deg=d.max_angle_change_deg,
            max_gap_m=max(d.max_gap_m, 10.0 * range_sigma_m),
            seed_points=d.seed_points,
            seed_length_m=d.seed_length_m * k,
            min_points=d.min_points,
            min_length_m=d.min_length_m,
        )

    def __post_init__(self) -> None:
        if not (self.max_point_distance_m > 0 and self.max_gap_m > 0 and self.max_angle_change_deg > 0):
            raise ValueError("LineParams: distances and angles must be > 0")
        if self.seed_points < 2 or self.min_points < 2:
            raise ValueError("LineParams: seed_points and min_points must be >= 2")


@dataclass(frozen=True, eq=False)
class Segment:
    """One extracted line segment.

    Attributes:
        id: number of the segment in its scan (beam order).
        indices: (M,) beam indices of its returns, in beam order (increasing, except on a
            360-degree scan where a segment over the seam runs from the last beams to the first).
        points: (M, 2) its returns, metres, laser frame.
        centroid: (2,) mean of the returns.
        direction: (2,) unit vector along the line, from ``start`` towards ``end``.
        start, end: (2,) the first and last returns projected onto the fitted line.
        rms_residual_m: RMS orthogonal distance of the returns to the line.
    """

    id: int
    indices: IntArray
    points: FloatArray
    centroid: FloatArray
    direction: FloatArray
    start: FloatArray
    end: FloatArray
    rms_residual_m: float

    @property
    def length_m(self) -> float:
        """Distance from ``start`` to ``end``."""
        return float(np.linalg.norm(self.end - self.start))

    @property
    def angle_rad(self) -> float:
        """Angle of the line in the laser frame, in (-pi/2, pi/2] (a line has no sense)."""
        a = float(np.arctan2(self.direction[1], self.direction[0]))
        if a <= -np.pi / 2:
            a += np.pi
        elif a > np.pi / 2:
            a -= np.pi
        return a

    @property
    def normal(self) -> FloatArray:
        """(2,) unit normal of the line, pointing away from the scanner (laser origin)."""
        n = np.array([-self.direction[1], self.direction[0]])
        out: FloatArray = n if n @ self.centroid >= 0 else -n
        return out

    @property
    def distance_m(self) -> float:
        """Distance from the scanner to the (infinite) line."""
        return float(abs(self.normal @ self.centroid))


def fit_line(points: ArrayLike) -> tuple[FloatArray, FloatArray, float]:
    """Total least-squares line through 2D points.

    Args:
        points: (M, 2) points, M >= 2.

    Returns:
        (centroid (2,), unit direction (2,), RMS orthogonal residual). The direction points
        from the first point towards the last.
    """
    p = np.asarray(points, dtype=float)
    c = p.mean(axis=0)
    q = p - c
    sxx, sxy, syy = float(q[:, 0] @ q[:, 0]), float(q[:, 0] @ q[:, 1]), float(q[:, 1] @ q[:, 1])
    u, resid2 = _principal_direction(sxx, sxy, syy)
    if u @ (p[-1] - p[0]) < 0:
        u = -u
    return c, u, float(np.sqrt(max(resid2, 0.0) / len(p)))


def _principal_direction(sxx: float, sxy: float, syy: float) -> tuple[FloatArray, float]:
    """Unit eigenvector of the larger eigenvalue of [[sxx, sxy], [sxy, syy]], and the smaller
    eigenvalue (the sum of squared orthogonal residuals)."""
    ux, uy = _direction(sxx, sxy, syy)
    half_trace = 0.5 * (sxx + syy)
    radius = math.hypot(0.5 * (sxx - syy), sxy)
    return np.array([ux, uy]), half_trace - radius


def _direction(sxx: float, sxy: float, syy: float) -> tuple[float, float]:
    """The principal direction of the scatter [[sxx, sxy], [sxy, syy]] (plain floats: the
    region growing calls it once per return)."""
    theta = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
    return math.cos(theta), math.sin(theta)


class _Grower:
    """Running sums of a growing segment: O(1) least-squares refits, on plain floats."""

    def __init__(self, pts: FloatArray) -> None:
        self.n = len(pts)
        self.sx, self.sy = float(pts[:, 0].sum()), float(pts[:, 1].sum())
        self.sxx = float(pts[:, 0] @ pts[:, 0])
        self.sxy = float(pts[:, 0] @ pts[:, 1])
        self.syy = float(pts[:, 1] @ pts[:, 1])

    def line(self, x: float, y: float) -> tuple[float, float, float, float]:
        """(centroid x, y, direction x, y) of the fit with one more point (x, y)."""
        n = self.n + 1
        sx, sy = self.sx + x, self.sy + y
        cx, cy = sx / n, sy / n
        ux, uy = _direction(
            self.sxx + x * x - n * cx * cx, self.sxy + x * y - n * cx * cy, self.syy + y * y - n * cy * cy
        )
        return cx, cy, ux, uy

    def add(self, x: float, y: float) -> None:
        self.n += 1
        self.sx += x
        self.sy += y
        self.sxx += x * x
        self.sxy += x * y
        self.syy += y * y


def _distance(p: FloatArray, centroid: FloatArray, direction: FloatArray) -> float:
    d = p - centroid
    return abs(float(d[0] * direction[1] - d[1] * direction[0]))


def extract_lines(scan: Scan, params: LineParams | None = None, *, kernel: bool = True) -> list[Segment]:
    """Line segments of a scan by least-squares region growing (paper Section III-B).

    Args:
        scan: the scan; invalid returns are skipped.
        params: thresholds (defaults: :class:`LineParams`).
        kernel: run the compiled kernel (:mod:`rigcal.lines_kernel`); False runs the Python
            region growing, its reference in the tests.

    Returns:
        The segments in beam order, numbered from 0.
    """
    params = params or LineParams()
    beams, pts, _ = ring_order(scan)
    if kernel:
        members, bounds, fits = _extract_compiled(pts, params)
        out = []
        for k, i in enumerate(np.argsort(beams[members[bounds[:-1]]], kind="stable").tolist()):
            g, f = members[bounds[i] : bounds[i + 1]], fits[i]
            out.append(Segment(k, beams[g], pts[g], f[0:2], f[2:4], f[4:6], f[6:8], float(f[8])))
        return out
    groups: list[IntArray] = []
    xy = (pts[:, 0].tolist(), pts[:, 1].tolist())  # plain floats for the growing loop
    for lo, hi in _runs(pts, params.max_gap_m):
        groups += _merge_collinear(pts, _grow_run(pts, xy, lo, hi, params), params)
    kept: list[IntArray] = []
    for g in groups:
        g = _trim_ends(pts, g, params)
        if len(g) >= params.min_points and _segment(0, beams[g], pts[g]).length_m >= params.min_length_m:
            kept.append(g)
    kept.sort(key=lambda g: int(beams[g[0]]))  # numbered by first beam, as without a ring
    return [_segment(k, beams[g], pts[g]) for k, g in enumerate(kept)]


def line_labels(scan: Scan, params: LineParams | None = None) -> IntArray:
    """``return_labels(scan, extract_lines(scan, params))`` straight from the compiled
    kernel, without building the segments (the laser odometry wants only the labels)."""
    params = params or LineParams()
    beams, pts, shift = ring_order(scan)
    members, bounds, _ = _extract_compiled(pts, params)
    rank = np.empty(len(bounds) - 1, dtype=np.int64)
    rank[np.argsort(beams[members[bounds[:-1]]], kind="stable")] = np.arange(len(rank))
    out = np.full(len(beams), -1, dtype=np.int64)
    # pts[i] is the valid return (i + shift) mod N in beam order.
    out[(members + shift) % max(len(beams), 1)] = np.repeat(rank, np.diff(bounds))
    return out


def ring_order(scan: Scan) -> tuple[IntArray, FloatArray, int]:
    """The scan's valid returns (beam indices, (N, 2) points) in the order the growing
    runs over them, and by how many returns that order is rotated from the beam order.

    A 360-degree scan is a ring: it starts after its widest gap between neighbouring
    returns (across the seam too), so that a line over the seam comes out whole."""
    beams = np.flatnonzero(scan.valid).astype(np.int64)
    pts = scan.points[beams]
    if not (is_full_circle(scan) and len(beams) > 1):
        return beams, pts, 0
    gaps = np.linalg.norm(np.roll(pts, -1, axis=0) - pts, axis=1)
    k = (int(np.argmax(gaps)) + 1) % len(beams)
    return np.roll(beams, -k), np.roll(pts, -k, axis=0), k


def is_full_circle(scan: Scan) -> bool:
    """Whether the scan's beams go all the way round (last beam one step short of the
    first, or closer): its first and last beams are then neighbours."""
    a = scan.angles_rad
    if len(a) <= 2:
        return False
    span, step = float(a[-1] - a[0]), scan.angle_increment_rad
    # A uniform scan's median step is its increment to within rounding (~1e-15 rad): away
    # from the boundary that decides it without the median (the odometry asks every scan).
    if step is not None and abs(span + 1.5 * step - 2.0 * np.pi) > 1e-6:
        return span + 1.5 * step >= 2.0 * np.pi
    return span + 1.5 * scan.step_rad >= 2.0 * np.pi


def return_labels(scan: Scan, segments: list[Segment]) -> IntArray:
    """(N,) the index in ``segments`` of each valid return's line (beam order), -1 for a
    return on no line."""
    beams = np.flatnonzero(scan.valid)
    out = np.full(len(beams), -1, dtype=np.int64)
    for k, seg in enumerate(segments):
        out[np.searchsorted(beams, seg.indices)] = k
    return out


def _runs(pts: FloatArray, max_gap_m: float) -> list[tuple[int, int]]:
    """[lo, hi) index ranges of returns with no gap wider than max_gap_m inside."""
    if len(pts) == 0:
        return []
    gaps = np.linalg.norm(np.diff(pts, axis=0), axis=1) > max_gap_m
    cuts = np.concatenate([[0], np.flatnonzero(gaps) + 1, [len(pts)]])
    return [(int(a), int(b)) for a, b in itertools.pairwise(cuts)]


def _grow_run(
    pts: FloatArray, xy: tuple[list[float], list[float]], lo: int, hi: int, params: LineParams
) -> list[IntArray]:
    """Region growing over the returns pts[lo:hi] (no gaps inside); ``xy`` holds the same
    coordinates as lists of floats."""
    out: list[IntArray] = []
    tol = params.max_point_distance_m
    cos_turn = math.cos(math.radians(params.max_angle_change_deg))
    xs, ys = xy
    i = lo
    while i < hi:
        seed_end = _seed_end(pts, i, hi, params)
        if seed_end is None:
            break
        seed = pts[i:seed_end]
        c, u, _ = fit_line(seed)
        cx, cy, ux, uy = float(c[0]), float(c[1]), float(u[0]), float(u[1])
        if max(abs((xs[k] - cx) * uy - (ys[k] - cy) * ux) for k in range(i, seed_end)) > tol:
            i += 1  # not a line here: slide the seed window
            continue
        grower = _Grower(seed)
        members = list(range(i, seed_end))
        j = seed_end
        while j < hi:
            x, y = xs[j], ys[j]
            if abs((x - cx) * uy - (y - cy) * ux) > tol:
                # One noisy return followed by one back on the line: filter it out.
                if j + 1 < hi and abs((xs[j + 1] - cx) * uy - (ys[j + 1] - cy) * ux) <= tol:
                    j += 1
                    continue
                break
            ncx, ncy, nux, nuy = grower.line(x, y)
            if abs(nux * ux + nuy * uy) < cos_turn:
                break
            grower.add(x, y)
            members.append(j)
            cx, cy, ux, uy = ncx, ncy, nux, nuy
            j += 1
        out.append(np.array(members, dtype=np.int64))
        # A filtered return just before the stop starts the next seed.
        i = members[-1] + 1
    return out


def _merge_collinear(pts: FloatArray, groups: list[IntArray], params: LineParams) -> list[IntArray]:
    """Join neighbouring segments of one run that are one line cut by noise.

    Two returns in a row that are each a little over 1.5 sigma off the line end a growing
    segment (the distance test is per return); the two pieces then lie on one line. They
    are joined when at most one return separates them, every return of the smaller piece
    lies within max_point_distance_m of the larger piece's line, the joined fit is as
    tight as the pieces (RMS residual at most 1.2 times the larger of theirs, plus 1 mm),
    and, when the smaller piece is long enough (MERGE_ANGLE_TEST_M) for its direction to
    mean something, the two directions differ by less than max_angle_change_deg. A corner
    or a step between parallel surfaces fails the distance test.
    """
    cos_turn = np.cos(np.radians(params.max_angle_change_deg))
    out: list[IntArray] = []
    for g in groups:
        if out and len(out[-1]) >= 2 and len(g) >= 2 and g[0] - out[-1][-1] <= 2:
            small, large = (out[-1], g) if len(out[-1]) < len(g) else (g, out[-1])
            cl, ul, rl = fit_line(pts[large])
            _, us, rs = fit_line(pts[small])
            q = pts[small] - cl
            off = np.abs(q[:, 0] * ul[1] - q[:, 1] * ul[0])
            joined = np.concatenate([out[-1], g])
            _, _, rj = fit_line(pts[joined])
            small_len = float(np.linalg.norm(pts[small[-1]] - pts[small[0]]))
            if (
                off.max() <= params.max_point_distance_m
                and rj <= 1.2 * max(rl, rs) + 0.001
                and (small_len < MERGE_ANGLE_TEST_M or abs(float(ul @ us)) >= cos_turn)
            ):
                out[-1] = joined
                continue
        out.append(g)
    return out


def _trim_ends(pts: FloatArray, members: IntArray, params: LineParams) -> IntArray:
    """Drop end returns that sit off the line of the others by more than END_TRIM_SIGMAS
    robust sigmas (a return from the next surface at a corner, which the distance test
    lets in when it is within max_point_distance_m)."""
    for _ in range(2 * params.seed_points):
        if len(members) <= params.min_points:
            break
        trimmed = False
        for end in (0, -1):
            rest = members[1:] if end == 0 else members[:-1]
            centroid, direction, _ = fit_line(pts[rest])
            q = pts[rest] - centroid
            d = np.abs(q[:, 0] * direction[1] - q[:, 1] * direction[0])
            sigma = max(MAD_TO_SIGMA * float(np.median(d)), END_TRIM_FLOOR_M)
            if _distance(pts[members[end]], centroid, direction) > END_TRIM_SIGMAS * sigma:
                members = rest
                trimmed = True
                break
        if not trimmed:
            break
    return members


def _seed_end(pts: FloatArray, i: int, hi: int, params: LineParams) -> int | None:
    """End (exclusive) of the shortest seed from i: >= seed_points returns spanning
    seed_length_m; None when the run has too few returns left."""
    j = i + params.seed_points
    if j > hi:
        return None
    while j <= hi:
        if np.linalg.norm(pts[j - 1] - pts[i]) >= params.seed_length_m:
            return j
        j += 1
    return None


def _segment(sid: int, beams: IntArray, pts: FloatArray) -> Segment:
    centroid, direction, rms = fit_line(pts)
    start = centroid + ((pts[0] - centroid) @ direction) * direction
    end = centroid + ((pts[-1] - centroid) @ direction) * direction
    return Segment(sid, beams, pts, centroid, direction, start, end, rms)


def segments_table(segments: list[Segment]) -> str:
    """A readable table of segments, one per line, as ``rigcal lines`` prints it."""
    head = f"{'id':>3} {'points':>6} {'beams':>11} {'start_m':>17} {'end_m':>17} {'length_m':>8} "
    head += f"{'angle_deg':>9} {'rms_mm':>6}"
    rows = [head]
    for g in segments:
        rows.append(
            f"{g.id:>3} {len(g.indices):>6} {f'{g.indices[0]}-{g.indices[-1]}':>11} "
            f"{f'({g.start[0]:.3f}, {g.start[1]:.3f})':>17} {f'({g.end[0]:.3f}, {g.end[1]:.3f})':>17} "
            f"{g.length_m:>8.3f} {np.degrees(g.angle_rad):>9.2f} {1000 * g.rms_residual_m:>6.1f}"
        )
    return "\n".join(rows) + "\n"


def _extract_compiled(pts: FloatArray, params: LineParams) -> tuple[IntArray, IntArray, FloatArray]:
    """The kept segments of the returns ``pts`` (N, 2), in the order the growing finds them:
    (members, bounds, fits): segment k's returns are ``members[bounds[k]:bounds[k + 1]]``
    (indices into pts), ``fits[k]`` its centroid, direction, start, end (2 each) and RMS
    residual, as :func:`_segment` computes them (:mod:`rigcal.lines_kernel`)."""
    from rigcal.lines_kernel import extract_kernel  # imports numba: on first use

    n = len(pts)
    members = np.empty(n, dtype=np.int64)
    bounds = np.empty(n + 1, dtype=np.int64)
    fits = np.empty((n // max(params.min_points, 1) + 1, 9))
    k = extract_kernel(
        np.ascontiguousarray(pts, dtype=np.float64),
        params.max_gap_m,
        params.max_point_distance_m,
        math.cos(math.radians(params.max_angle_change_deg)),
        params.seed_points,
        params.seed_length_m,
        params.min_points,
        params.min_length_m,
        MERGE_ANGLE_TEST_M,
        END_TRIM_SIGMAS,
        END_TRIM_FLOOR_M,
        members,
        bounds,
        fits,
    )
    return members[: bounds[k]], bounds[: k + 1], fits[:k]
