"""The laser's depth discontinuities against the image's edges (targetless check, edge term).

Where a scan's lines meet at a corner, or a line ends in front of a farther surface (a
pillar's side, a wall's end), the world has a vertical edge: two surfaces of different
texture or lighting meet, or one occludes the other. The scan locates that edge's
foot in the laser plane; the image shows the edge as a line of strong gradient. Projected
with the right T_cam_laser, the vertical line through the scan's discontinuity lands on
the image's edge in every frame, whatever the odometry says: one frame observes the
camera's translation across the view (a shift of t moves the projection by f t / depth,
different at different depths, unlike a turn) and its roll and pitch (they tilt the
projected line). This is the depth-discontinuity to image-edge alignment of Levinson &
Thrun (RSS 2013, Section III), posed as least squares: for each discontinuity and each of
a few height bands, the residual is the offset (pixels, across the projected line) from
the projection to the image's edge; the edge is the peak of the image gradient across
the line, summed along the band (a vertical edge adds up, texture does not). Each band is
paired with its image edge once, at the start estimate, searched a window either side of
the projection; later steps re-measure the edge only within :data:`REPAIR_GATE_PX` of that
first pairing, so that a moving estimate cannot re-pair a band with another image edge
(which once let an estimate run away).

A corner seen in many frames is one physical edge: whatever error its foot or its image
edge carries (the scan's corner fit, the texture beside it, the lens model there) it
carries in every frame. :func:`corner_clusters` groups the observations by the edge's
position in the world (the foot through the odometry), so that the check's covariance
counts each corner once (:mod:`rigcal.drift.statistic`).

Vertical edges say nothing of the camera's height: a shift along the laser's z slides the
projection along the edge itself. The edge term, like the photometric one, leaves laser z
unobserved.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray, IntArray
from rigcal.drift.blur_stack import BlurStack
from rigcal.geometry import line_intersection
from rigcal.lines import Segment
from rigcal.scan import Scan

BAND_HEIGHTS_M = (-0.15, 0.3, 0.75)
"""The centres of the height bands (laser frame z, metres) along each discontinuity's
vertical line: below the laser plane, at the camera's height, above it (the cubicles'
partitions stand 1.1 m above the laser)."""
BAND_SPAN_M = 0.3
"""Each band's extent along the edge, metres."""
BAND_SAMPLES = 5
"""Points per band along the edge (their gradients across the line are summed)."""
STEP_PX = 0.5
"""Spacing of the samples across the projected line, pixels."""
MIN_CORNER_DEG = 25.0
"""Two consecutive lines meeting at less than this are one wall (not a corner)."""
MAX_CORNER_GAP_M = 0.15
"""Two consecutive lines whose ends are farther apart than this do not meet at a corner."""
MIN_JUMP_M = 0.3
"""A line's end with the next return at least this much farther is an occluding edge."""
MIN_CONTRAST = 1.0
"""An edge's gradient across the line, grey levels per pixel (mean over the band), below
which the band is not used."""
MAX_SECOND_PEAK = 0.7
"""A band whose second-highest gradient peak (2 px or more from the first) is above this
fraction of the highest is ambiguous (a textured wall beside the edge) and not used."""
REPAIR_GATE_PX = 2.0
"""After the first pairing, a band's image edge is re-measured only this far either side
of where it was first found (the edge stays where it is in the image; only the projected
line's direction and position along it change with the estimate)."""
BAND_AGREE_PX = 2.0
"""At the first pairing, a band is used only when another band of the same edge (one
frame's discontinuity) found its image edge within this of its own offset across the
line. A vertical edge projects to one line: its bands' offsets differ by their edge
finding's noise (0.75 px median on simulated drives at the true T) and by the tilt a
wrong T gives the line (under 1 px for 1 deg over the bands' 0.9 m at 4 m), far less
than a neighbouring image edge's offset."""
CORNER_RADIUS_M = 0.1
"""Observations whose feet lie within this of each other in the world (through the
odometry; chained) are one physical edge. Below the closest distinct edges the scans
show (a 0.3 m pillar's corners), above the odometry's drift over a short drive."""


def scan_discontinuities(scan: Scan, segments: list[Segment]) -> FloatArray:
    """(N, 2) the feet of the world's vertical edges the scan shows, laser frame, metres.

    Corners: consecutive lines (beam order) whose ends are within
    :data:`MAX_CORNER_GAP_M` and whose directions differ by :data:`MIN_CORNER_DEG` or
    more meet at their lines' intersection (more accurate than either end: the fits
    average the range noise). Occluding edges: a line's end whose next beam returns from
    :data:`MIN_JUMP_M` or farther; the edge lies between the two beams, so its foot is
    the line's point on the bisecting ray (within half a beam step either way, unbiased,
    where the last return would fall short by half a step on average).
    """
    out: list[FloatArray] = []
    segs = sorted(segments, key=lambda s: int(s.indices[0]))
    r = scan.ranges_m
    valid = scan.valid
    n = len(r)
    for a, b in itertools.pairwise(segs):
        cos = abs(float(a.direction @ b.direction))
        if np.linalg.norm(a.end - b.start) <= MAX_CORNER_GAP_M and cos <= math.cos(
            math.radians(MIN_CORNER_DEG)
        ):
            p = line_intersection(a.centroid, a.direction, b.centroid, b.direction)
            if (
                p is not None
                and min(np.linalg.norm(p - a.end), np.linalg.norm(p - b.start)) <= MAX_CORNER_GAP_M
            ):
                out.append(p)
    for s in segs:
        for end, beam, step in ((s.start, int(s.indices[0]), -1), (s.end, int(s.indices[-1]), 1)):
            nb = beam + step
            if not 0 <= nb < n or not valid[nb] or r[nb] - r[beam] < MIN_JUMP_M:
                continue
            mid = 0.5 * (scan.angles_rad[beam] + scan.angles_rad[nb])
            ray = np.array([math.cos(mid), math.sin(mid)])
            p = line_intersection(np.zeros(2), ray, s.centroid, s.direction)
            if p is not None and np.linalg.norm(p - end) <= 0.1:
                out.append(p)
    return np.array(out).reshape(-1, 2)


def band_points(feet: FloatArray) -> FloatArray:
    """(N, B, K, 3) points on the vertical lines through the feet (laser frame): B height
    bands of K points each."""
    z = np.array(
        [
            [c + BAND_SPAN_M * (k / (BAND_SAMPLES - 1) - 0.5) for k in range(BAND_SAMPLES)]
            for c in BAND_HEIGHTS_M
        ]
    )
    out = np.empty((len(feet), *z.shape, 3))
    out[..., 0] = feet[:, 0, None, None]
    out[..., 1] = feet[:, 1, None, None]
    out[..., 2] = z[None]
    return out


@dataclass
class Edges:
    """Every discontinuity's height bands, and the frame each was seen in."""

    X: FloatArray  # (E, B, K, 3) band points, laser frame at the frame's stamp
    img: IntArray  # (E,) image index
    block: IntArray  # (E,) block index
    corner: IntArray  # (E,) the physical edge (:func:`corner_clusters`)
    depth_m: FloatArray  # (E,) the foot's range from the laser, metres


def corner_clusters(feet_world: FloatArray, radius_m: float = CORNER_RADIUS_M) -> IntArray:
    """(N,) a label per observation: the physical edge its foot belongs to.

    Args:
        feet_world: (N, 2) the feet in one world frame (each frame's feet moved by the
            odometry's pose at its stamp), metres.
        radius_m: feet closer than this are linked; labels are the linked groups
            (single linkage), numbered 0.. in order of first appearance.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(feet_world)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    pairs = cKDTree(feet_world).query_pairs(radius_m, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(np.argsort(first))  # renumber by first appearance
    out: IntArray = order[labels].astype(np.int64)
    return out


class EdgeImages:
    """The frames the edges are seen in, blurred for one stage, in one uint16 stack (grey
    levels x 64) of the band of rows the edges fall in: one image per edge (each
    discontinuity seen in a frame), made only over the box its band is searched in
    (:class:`rigcal.drift.blur_stack.BlurStack`; widened where a read needs more)."""

    GREY_SCALE = 64.0

    def __init__(
        self,
        gray_of: dict[int, NDArray[np.uint8]],
        frames: IntArray,
        blur_px: float,
        rows: tuple[float, float],
        boxes: IntArray | None = None,
    ) -> None:
        """``boxes``: (E, 4) where each edge's reads fall (image rows r0:r1, columns
        c0:c1; :func:`search_boxes`); None: the whole band."""
        self.frames = np.asarray(frames)
        self.key = np.arange(len(self.frames))
        first = gray_of[int(self.frames[0])]
        self.row0 = max(math.floor(rows[0]), 0)
        hi = min(math.ceil(rows[1]) + 1, first.shape[0])

        def source(i: int, a: int, b: int) -> NDArray[np.uint16]:
            out: NDArray[np.uint16] = gray_of[i][a:b].astype(np.uint16) * np.uint16(self.GREY_SCALE)
            return out

        sigmas = np.full(len(self.frames), blur_px)
        height, width = first.shape
        narrow = boxes is not None
        self.images = BlurStack(self.frames, sigmas, self.row0, hi - self.row0, width, source, height, narrow)
        if boxes is None:
            need = np.tile([0, hi - self.row0, 0, width], (len(self.frames), 1))
        else:
            need = np.asarray(boxes, dtype=np.int64) - [self.row0, self.row0, 0, 0]
        # Two threads (OpenCV releases the interpreter): the check waits on these frames
        # while its first stage iterates.
        self.images.fill(need)

    def sample(self, which: IntArray, q: FloatArray) -> FloatArray:
        """Bilinear grey levels at full-size pixels q (..., 2) of the stack's images
        ``which`` (broadcast against q's leading axes); NaN outside the band."""
        H, W = self.images.height, self.images.width
        u = q[..., 0]
        v = q[..., 1] - self.row0
        inside = (u >= 0.0) & (u <= W - 1.0) & (v >= 0.0) & (v <= H - 1.0)
        u = np.clip(np.nan_to_num(u, nan=0.0), 0.0, W - 1.0)
        v = np.clip(np.nan_to_num(v, nan=0.0), 0.0, H - 1.0)
        u0 = np.minimum(u.astype(np.int64), W - 2)
        v0 = np.minimum(v.astype(np.int64), H - 2)
        k = np.broadcast_to(which, u.shape)
        # Reads beyond their image's box: made first (the whole band's values there).
        kin, vin, uin = k[inside], v0[inside], u0[inside]
        need = np.column_stack([vin, vin + 2, uin, uin + 2])
        missed = ~self.images.covers(kin, need)
        if missed.any():
            self.images.widen(kin[missed], need[missed], SEARCH_MARGIN_PX)
        fu, fv = u - u0, v - v0
        s = self.images.stack
        # Each image's own columns (a narrow stack's window; points outside the band read
        # anything there, and NaN below).
        at = np.clip(u0 - self.images.col0[k], 0, s.shape[2] - 2)
        top = s[k, v0, at] * (1.0 - fu) + s[k, v0, at + 1] * fu
        bottom = s[k, v0 + 1, at] * (1.0 - fu) + s[k, v0 + 1, at + 1] * fu
        out: FloatArray = np.where(inside, (top * (1.0 - fv) + bottom * fv) / self.GREY_SCALE, np.nan)
        return out


SEARCH_MARGIN_PX = 2
"""The edges' boxes reach this much beyond their search (pixels): the bilinear's own."""


def search_boxes(camera: object, T: FloatArray, edges: Edges, window_px: float) -> IntArray:
    """(E, 4) the image box (rows r0:r1, columns c0:c1) each edge's search reads under
    the stored T: its bands' points projected, a search window either side (the first
    pairing), then :data:`REPAIR_GATE_PX` about where it was found (the later steps,
    :func:`edge_residuals`), and :data:`SEARCH_MARGIN_PX`."""
    E = len(edges.X)
    q = camera.project(edges.X.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]).reshape(E, -1, 2)  # type: ignore[attr-defined]
    m = window_px + REPAIR_GATE_PX + SEARCH_MARGIN_PX
    with np.errstate(invalid="ignore"):
        lo = np.floor(np.nan_to_num(np.nanmin(q, axis=1), nan=0.0) - m)
        hi = np.floor(np.nan_to_num(np.nanmax(q, axis=1), nan=-1.0) + m) + 2
    out: IntArray = np.column_stack([lo[:, 1], hi[:, 1], lo[:, 0], hi[:, 0]]).astype(np.int64)
    return out


def edge_residuals(
    camera: object,
    T: FloatArray,
    edges: Edges,
    images: EdgeImages,
    window_px: float,
    anchor: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], FloatArray]:
    """Offsets from the projected edges to the image's edges, and their derivatives.

    Args:
        camera: the :class:`rigcal.camera.Camera`.
        T: (4, 4) T_cam_laser.
        window_px: with no anchor, the image's edge is searched this far either side of
            the projection (the first pairing).
        anchor: (E, B, K, 2) where each band's edge was first found (the ``found`` of
            the first pairing), or None. Given, the edge is re-measured only within
            :data:`REPAIR_GATE_PX` of it, across the projected line.

    Returns:
        r: (E * B,) per edge and band: the image edge's offset from the projected line,
            pixels, across the line (0 where not usable).
        J: (E * B, 6) d r / d xi for a right update T Exp(w, v) (laser frame).
        usable: (E * B,) bands whose edge was found: inside the image, a clear single
            peak of the gradient inside the window (or the gate).
        found: (E, B, K, 2) the image edge's points found, pixels (an anchor).
    """
    E, B, K, _ = edges.X.shape
    R, t = T[:3, :3], T[:3, 3]
    P = edges.X.reshape(-1, 3) @ R.T + t
    q = camera.project(P).reshape(E, B, K, 2)  # type: ignore[attr-defined]
    d = q[:, :, -1] - q[:, :, 0]
    d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
    nrm = np.stack([d[..., 1], -d[..., 0]], axis=-1)  # (E, B, 2) across the line
    # The search lines' centres: the projection (first pairing) or the first pairing's
    # edge points, whose offset from the projected line adds to the residual.
    centre = q if anchor is None else anchor
    base = np.einsum("ebi,ebi->eb", centre[:, :, K // 2] - q[:, :, K // 2], nrm)
    half = window_px if anchor is None else REPAIR_GATE_PX
    off = np.arange(-half, half + 0.5 * STEP_PX, STEP_PX)
    s = centre[:, :, :, None, :] + off[None, None, None, :, None] * nrm[:, :, None, None, :]
    which = images.key[:, None, None, None]
    grey = images.sample(which, s)  # (E, B, K, O)
    grad = np.diff(grey, axis=-1) / STEP_PX  # at the offsets' midpoints
    prof = np.abs(np.sum(grad, axis=2)) / K  # (E, B, O - 1): a vertical edge adds up along the band
    finite = np.isfinite(prof).all(axis=-1)
    prof = np.nan_to_num(prof, nan=0.0)
    mid = 0.5 * (off[1:] + off[:-1])
    m = np.argmax(prof, axis=-1)
    peak = np.take_along_axis(prof, m[..., None], axis=-1)[..., 0]
    far = np.abs(mid[None, None, :] - mid[m][..., None]) >= 2.0
    second = np.max(np.where(far, _local_max(prof), 0.0), axis=-1)
    interior = (m >= 1) & (m <= len(mid) - 2)
    usable = finite & interior & (peak >= MIN_CONTRAST) & (second <= MAX_SECOND_PEAK * peak)
    mc = np.clip(m, 1, len(mid) - 2)
    # The peak to a fraction of a sample: a parabola through the logarithms of the three
    # samples around it (exact for a blurred step, whose gradient is a Gaussian).
    y0, y1, y2 = (
        np.log(np.maximum(np.take_along_axis(prof, (mc + k)[..., None], axis=-1)[..., 0], 1e-6))
        for k in (-1, 0, 1)
    )
    den = y0 - 2.0 * y1 + y2
    frac = np.where(den < 0.0, 0.5 * (y0 - y2) / np.where(den < 0.0, den, -1.0), 0.0)
    o = mid[mc] + np.clip(frac, -0.5, 0.5) * STEP_PX
    found = centre + o[:, :, None, None] * nrm[:, :, None, :]
    r = base + o
    if anchor is None:
        # The first pairing: a band counts only when another band of the same edge
        # found its image edge on the same line; a band that is not paired here is
        # never used (its anchor is NaN: nothing is searched around it later).
        usable &= _agreeing(r, usable)
        found = np.where(usable[:, :, None, None], found, np.nan)
    # r(xi) = n . (q_edge - q(T Exp(xi) x)) at the band's middle point x.
    Xc = edges.X[:, :, K // 2].reshape(-1, 3)
    _, dq = camera.project_with_gradient(Xc @ R.T + t)  # type: ignore[attr-defined]
    a = -np.einsum("ni,nij->nj", nrm.reshape(-1, 2), dq) @ R  # d r / d x (laser frame)
    J = np.concatenate([np.cross(Xc, a), a], axis=1)
    usable = usable.ravel() & np.isfinite(J).all(axis=1)
    r = np.where(usable, r.ravel(), 0.0)
    J = np.where(usable[:, None], J, 0.0)
    return r, J, usable, found


def _agreeing(r: FloatArray, usable: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """(E, B) bands whose offset r (E, B) lies within :data:`BAND_AGREE_PX` of another
    usable band's of the same edge: one vertical edge is one line across its heights,
    so bands that disagree were paired with different image edges (a texture beside it,
    a farther edge in its window), and a band alone cannot be told from such a pairing."""
    diff = np.abs(r[:, :, None] - r[:, None, :])
    B = r.shape[1]
    other = usable[:, None, :] & ~np.eye(B, dtype=bool)[None]
    out: NDArray[np.bool_] = usable & np.any(other & (diff <= BAND_AGREE_PX), axis=2)
    return out


def _local_max(p: FloatArray) -> FloatArray:
    """p where it is a local maximum along the last axis, 0 elsewhere."""
    left = np.concatenate([np.full((*p.shape[:-1], 1), -np.inf), p[..., :-1]], axis=-1)
    right = np.concatenate([p[..., 1:], np.full((*p.shape[:-1], 1), -np.inf)], axis=-1)
    out: FloatArray = np.where((p >= left) & (p >= right), p, 0.0)
    return out
