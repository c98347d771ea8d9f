"""Pick assist: proposing the box ends in the images (paper Algorithm 1, step 2, automated).

The box side seen by the laser is a segment of known length at the laser's height. Given a
pose (a rough rig, or a solve over the captures the user picked by hand), each laser box
end projects to a predicted pixel (Eq. (3), then Eq. (1) with distortion). The true end
lies on the box's vertical edge, so the prediction is refined by a sub-pixel edge search:

1. the face's colour is sampled along the projected side between the ends;
2. at each end, a profile is sampled across the edge along the projected laser line
   (``t`` px outward, 0.25 px steps), each sample the mean over a short stretch of the
   edge's own image direction (the projection of the laser frame's vertical over
   ``edge_span_m``), by bilinear interpolation;
3. the profile's colour distance to the face rises where the face ends: candidate edges
   are the peaks of its smoothed outward derivative with face colour inside and a clear
   step outside; the one with the largest step, weighted by a Gaussian prior around the
   prediction, wins, located at the step's 50 % crossing;
4. confidence = (1 - second-best score / best score) x min(1, step / CONTRAST_REF):
   low when two edges compete (e.g. the box's corner and the far edge of its side) or the
   step is faint.

The picks are refined in rounds (re-solving with the confident ones), then solved all
together: an automatic pick the solve rejects is marked for review.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.calib.box.picks import (
    BoxObservation,
    CaptureDraft,
    PickDraft,
    extended_ends,
    resolve_capture,
    side_ends,
)
from rigcal.calib.box.solve import CalibProblem, CalibResult, SolveSettings, solve
from rigcal.camera import Camera
from rigcal.errors import CalibrationError, InputError
from rigcal.geometry import transform_points
from rigcal.lines import Segment, extract_lines

# Profile sampling step along the search line, px.
STEP_PX = 0.25
# Smoothing of the profile before differentiating, px (about the blur of a sharp edge).
SMOOTH_PX = 0.6
# The edge's step in colour distance (grey levels, BGR Euclidean) that counts as clear.
CONTRAST_REF = 40.0
# Below this step no edge is considered at all.
MIN_CONTRAST = 12.0
# An edge of the face has the face's colour inside it: within this distance (BGR levels;
# another face of the box in other light, e.g. its side, differs by more).
FACE_TOLERANCE = 30.0
# A dark line of the face's hue along its edge (outline, bevel shadow), up to this wide,
# belongs to the box: darker than this fraction of the face, chromaticity within this.
DARK_BAND_PX = 2.5
DARK_BAND_LUMINANCE = 0.6
DARK_BAND_CHROMA = 0.05
# The box's top and bottom edges are searched up to this far along its end edge, this far
# inside the face (px).
MAX_EXTENT_PX = 80.0
INSIDE_PX = 3.0
# The ends' fractions of the laser's height on the box face must agree within this (median
# distance in pixels from their mean) for the height cue to be used.
HEIGHT_AGREEMENT_PX = 1.5
# Inside/outside levels are read this far from a candidate edge (px).
LEVEL_NEAR_PX, LEVEL_FAR_PX = 1.0, 3.0


@dataclass(frozen=True)
class PickSettings:
    """Settings of the pick assist.

    Attributes:
        search_px: half-width of the edge search around each predicted end.
        prior_sigma_px: 1-sigma of the prediction's error, weighting edge candidates.
        edge_span_m: length of the vertical edge averaged into the profile, centred on the
            laser plane; must lie within the box's height.
        review_below: picks with a lower confidence are marked for review.
        box_width_m: the box side's length, to find the side in scans whose picking file
            gives no ``laser_side`` (None: every capture must give it).
        width_tolerance_m: a segment is the box side when its length is within this of
            ``box_width_m``.
        rounds: prediction-refinement rounds (each re-solves with the confident picks).
        solve: settings of the solves.
    """

    search_px: float = 12.0
    prior_sigma_px: float = 4.0
    edge_span_m: float = 0.03
    review_below: float = 0.5
    box_width_m: float | None = None
    width_tolerance_m: float = 0.06
    rounds: int = 2
    solve: SolveSettings = field(default_factory=SolveSettings)


@dataclass(frozen=True)
class EdgeFit:
    """One end's edge search.

    Attributes:
        pixel: (2,) the refined end, or the prediction when no edge was found.
        predicted: (2,) the prediction.
        found: whether an edge was found.
        confidence: 0-1 (see the module's docstring).
        contrast: the edge's step in colour distance.
        along: (2,) unit image direction of the laser line at the end, outward.
        up: (2,) unit image direction of the box's vertical edge (laser frame +z).
    """

    pixel: FloatArray
    predicted: FloatArray
    found: bool
    confidence: float
    contrast: float
    along: FloatArray = field(default_factory=lambda: np.full(2, np.nan))
    up: FloatArray = field(default_factory=lambda: np.full(2, np.nan))


@dataclass(frozen=True)
class CapturePick:
    """The picks of one capture after ``rigcal pick``.

    Attributes:
        index, name: the capture.
        laser_side: the ``laser_side`` mapping to write (None: the side was not found).
        image_endpoints_px: (2, 2) pixels, or None when nothing could be proposed.
        predicted_px: (2, 2) the ends predicted through the pose, or None.
        source: ``"manual"`` (kept as the user picked it) or ``"auto"``.
        confidence: 0-1 (1 for manual picks); the lower of the two ends'.
        review: whether to check the pick by eye.
        reasons: why it is marked for review.
    """

    index: int
    name: str
    laser_side: dict[str, object] | None
    image_endpoints_px: FloatArray | None
    predicted_px: FloatArray | None
    source: str
    confidence: float
    review: bool
    reasons: tuple[str, ...] = ()


@dataclass(frozen=True)
class PickRun:
    """Outcome of :func:`auto_pick`.

    Attributes:
        draft: the picking file it started from.
        picks: one per capture, in the file's order.
        T_cam_laser: (4, 4) the pose of the last prediction round.
        seeded_from: ``"rig"`` or ``"N manual picks"``.
        final: the solve over every pick (None when it failed).
        height_fraction: where the laser cuts the box face (fraction of its height from
            the bottom) as the manual picks show it, used for the automatic picks' height;
            None when not used (see :func:`height_fraction`).
    """

    draft: PickDraft
    picks: tuple[CapturePick, ...]
    T_cam_laser: FloatArray
    seeded_from: str
    final: CalibResult | None
    height_fraction: float | None = None


# --- the pipeline ------------------------------------------------------------------------
def auto_pick(
    draft: PickDraft, settings: PickSettings | None = None, T_cam_laser: FloatArray | None = None
) -> PickRun:
    """Propose the image box ends of every capture not picked by hand.

    Args:
        draft: the picking file (captures may be unpicked).
        settings: see :class:`PickSettings`.
        T_cam_laser: (4, 4) a rough calibration; None: solve over the manual picks (at
            least 3 captures).

    Raises:
        InputError: a capture's box side cannot be found and is needed, or too few
            manual picks and no rig.
        CalibrationError: the manual picks do not determine a pose.
    """
    settings = settings or PickSettings()
    sides = _sides(draft, settings)
    seeds = [c for c in draft.captures if _is_manual(c)]
    seed_obs = [
        _observation(draft, c, sides[c.index], c.image_endpoints_px)
        for c in seeds
        if c.image_endpoints_px is not None
    ]
    if T_cam_laser is not None:
        T = np.asarray(T_cam_laser, dtype=float)
        seeded_from = "rig"
    else:
        if len(seeds) < 3:
            raise InputError(
                f"{draft.path}: captures: {len(seeds)} picked by hand; expected at least 3 "
                "(pick the image ends of 3 or more captures, or give a rough rig with --rig)"
            )
        T = _solve(draft.camera, seed_obs, settings).T_cam_laser
        seeded_from = f"{len(seeds)} manual picks"
    images = {c.index: _read_float_image(c) for c in draft.captures}
    manual_px = {c.index: c.image_endpoints_px for c in seeds if c.image_endpoints_px is not None}
    fraction = height_fraction(draft, T, images, sides, settings, manual_px)
    fits: dict[int, tuple[EdgeFit, EdgeFit] | None] = {}
    for round_ in range(max(1, settings.rounds)):
        fits = {
            c.index: _propose(draft.camera, T, images[c.index], sides[c.index], settings, fraction)
            for c in draft.captures
            if not _is_manual(c)
        }
        if fraction is None and round_ == 0:
            # The manual picks did not give it (none, too few, or they disagree): the
            # fraction the pose predicts, over every capture (the pose's height error stays
            # in it, its tilt errors average out); None again when those disagree too.
            at = {
                i: np.array([f[0].pixel, f[1].pixel])
                for i, f in fits.items()
                if f and f[0].found and f[1].found
            }
            fraction = height_fraction(draft, T, images, sides, settings, at)
            if fraction is not None:
                fits = {
                    c.index: _propose(draft.camera, T, images[c.index], sides[c.index], settings, fraction)
                    for c in draft.captures
                    if not _is_manual(c)
                }
        if round_ == settings.rounds - 1:
            break
        confident = [
            _observation(draft, c, sides[c.index], np.array([f[0].pixel, f[1].pixel]))
            for c in draft.captures
            if (f := fits.get(c.index)) is not None
            and min(f[0].confidence, f[1].confidence) >= settings.review_below
        ]
        try:
            T = _solve(draft.camera, seed_obs + confident, settings).T_cam_laser
        except CalibrationError:
            break
    picks = [_capture_pick(c, sides[c.index], fits.get(c.index), settings) for c in draft.captures]
    final = _final_solve(draft, picks, sides, seed_obs, settings)
    if final is not None:
        picks = _mark_rejected(picks, final)
    return PickRun(draft, tuple(picks), T, seeded_from, final, fraction)


def _is_manual(c: CaptureDraft) -> bool:
    return c.image_endpoints_px is not None and (c.pick is None or c.pick.source == "manual")


@dataclass(frozen=True)
class _Side:
    """A capture's box side in the scan: its ``laser_side`` mapping, the ends (2, 2), and
    why it is doubtful (empty when it is not)."""

    laser_side: dict[str, object] | None
    ends: FloatArray | None
    doubt: str = ""


def _sides(draft: PickDraft, settings: PickSettings) -> dict[int, _Side]:
    out = {}
    width = settings.box_width_m or draft.box.get("width_m")
    for c in draft.captures:
        if c.laser_side is not None:
            out[c.index] = _Side(dict(c.laser_side), side_ends(draft, c, c.laser_side))
            continue
        if width is None:
            raise InputError(
                f"{draft.path}: captures[{c.index}].laser_side: missing; give the box width "
                "(--box-width-m or the file's box.width_m) so that the box side can be found, or set it"
            )
        out[c.index] = _find_side(c, draft, float(width), settings.width_tolerance_m)
    return out


def _find_side(c: CaptureDraft, draft: PickDraft, width_m: float, tolerance_m: float) -> _Side:
    """The segment whose extended ends are the box's width apart; the nearest such
    segment when several are (a box stands in front of the walls), with a doubt."""
    candidates: list[tuple[float, Segment, FloatArray]] = []
    for seg in extract_lines(c.scan, draft.line_params):
        ends, _ = extended_ends(seg.points, seg.indices, c.scan)
        length = float(np.linalg.norm(ends[1] - ends[0]))
        if abs(length - width_m) <= tolerance_m:
            candidates.append((float(np.linalg.norm(seg.centroid)), seg, ends))
    if not candidates:
        return _Side(None, None, f"no segment of the box's width {width_m:g} m in the scan")
    candidates.sort(key=lambda x: x[0])
    _, seg, ends = candidates[0]
    doubt = f"{len(candidates)} segments of the box's width; took the nearest" if len(candidates) > 1 else ""
    return _Side({"segment": seg.id}, ends, doubt)


def _observation(draft: PickDraft, c: CaptureDraft, side: _Side, px: FloatArray) -> BoxObservation:
    """The solver's observation of a capture with the image ends ``px`` (2, 2)."""
    if side.laser_side is None:
        raise InputError(
            f"{draft.path}: captures[{c.index}].laser_side: missing, and {side.doubt}; set it for this "
            "capture picked by hand"
        )
    return resolve_capture(draft, replace(c, laser_side=side.laser_side, image_endpoints_px=px))


def _solve(camera: Camera, obs: list[BoxObservation], settings: PickSettings) -> CalibResult:
    return solve(CalibProblem(camera, tuple(obs), settings.solve))


def _propose(
    camera: Camera,
    T: FloatArray,
    image: NDArray[np.float32],
    side: _Side,
    settings: PickSettings,
    height_fraction: float | None,
) -> tuple[EdgeFit, EdgeFit] | None:
    """Both ends of a capture: along the laser line by the edge search; across it (the
    laser's height on the box) by the seeds' height fraction when there is one, else by
    the pose."""
    if side.ends is None:
        return None
    ends = side.ends
    face = _face_colour(camera, T, image, ends, settings.edge_span_m)
    if face is None:
        return None
    u = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    fits = []
    for end, outward in ((ends[0], -u), (ends[1], u)):
        fit = refine_end(camera, T, image, end, outward, face, settings)
        if height_fraction is not None and fit.found:
            extent = edge_extent(image, fit, face)
            if extent is None:  # the box's top or bottom not seen: the pose's height, less sure
                fit = replace(fit, confidence=0.5 * fit.confidence)
            else:
                lo, hi = extent
                fit = replace(fit, pixel=fit.pixel + (lo + height_fraction * (hi - lo)) * fit.up)
        fits.append(fit)
    return fits[0], fits[1]


def height_fraction(
    draft: PickDraft,
    T: FloatArray,
    images: dict[int, NDArray[np.float32]],
    sides: dict[int, _Side],
    settings: PickSettings,
    at_px: dict[int, FloatArray],
) -> float | None:
    """Where the laser cuts the box face, as a fraction of the face's height from its bottom,
    measured at the given image ends (``at_px``: capture index -> (2, 2) pixels on the
    box's end edges, e.g. the manual picks). When at least 3 ends give it and they agree
    (the median end within HEIGHT_AGREEMENT_PX of the mean): their mean weighted by the
    face's image height squared, without the ends beyond 3 robust sigmas; else None. A box
    that stays on one stand while the rig rolls on a flat floor keeps this fraction in
    every capture."""
    fractions: list[float] = []
    heights: list[float] = []
    for c in draft.captures:
        side = sides[c.index]
        px = at_px.get(c.index)
        if px is None or side.ends is None:
            continue
        ends = side.ends
        face = _face_colour(draft.camera, T, images[c.index], ends, settings.edge_span_m)
        if face is None:
            continue
        u = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
        for j, outward in ((0, -u), (1, u)):
            dirs = _end_directions(draft.camera, T, ends[j], outward, settings.edge_span_m)
            if dirs is None:
                continue
            pred, along, d = dirs
            fit = EdgeFit(px[j], pred, True, 1.0, 0.0, along, d / np.linalg.norm(d))
            extent = edge_extent(images[c.index], fit, face)
            if extent is not None and extent[1] - extent[0] > 2.0:
                fractions.append(-extent[0] / (extent[1] - extent[0]))
                heights.append(extent[1] - extent[0])
    if len(fractions) < 3:
        return None
    f, h = np.array(fractions), np.array(heights)

    # Each end's fraction carries its pick's noise divided by the face's height in the
    # image: the inverse-variance (height squared) weighted mean. The ends agree when they
    # put the laser within HEIGHT_AGREEMENT_PX of that mean in pixels (robustly: the
    # median); ends beyond 3 robust sigmas of it are left out of the mean.
    def weighted(sel: NDArray[np.bool_]) -> float:
        return float(np.sum(h[sel] ** 2 * f[sel]) / np.sum(h[sel] ** 2))

    mean = weighted(np.ones(len(f), bool))
    off = np.abs(f - mean) * h
    if float(np.median(off)) > HEIGHT_AGREEMENT_PX:
        return None
    keep = off <= max(3.0 * MAD_TO_SIGMA * float(np.median(off)), HEIGHT_AGREEMENT_PX)
    return weighted(keep)


def _capture_pick(
    c: CaptureDraft, side: _Side, fit: tuple[EdgeFit, EdgeFit] | None, settings: PickSettings
) -> CapturePick:
    if _is_manual(c):
        assert c.image_endpoints_px is not None
        return CapturePick(c.index, c.name, side.laser_side, c.image_endpoints_px, None, "manual", 1.0, False)
    if fit is None:
        reason = side.doubt or "the box side projects outside the image or behind the camera"
        return CapturePick(c.index, c.name, side.laser_side, None, None, "auto", 0.0, True, (reason,))
    px = np.array([fit[0].pixel, fit[1].pixel])
    pred = np.array([fit[0].predicted, fit[1].predicted])
    conf = float(min(fit[0].confidence, fit[1].confidence))
    reasons = []
    if side.doubt:
        reasons.append(side.doubt)
    for j, f in enumerate(fit):
        if not f.found:
            reasons.append(f"end {j}: no edge found near the prediction")
    if conf < settings.review_below:
        reasons.append(f"confidence {conf:.2f} below {settings.review_below:g}")
    return CapturePick(
        c.index, c.name, side.laser_side, px, pred, "auto", conf, bool(reasons), tuple(reasons)
    )


def _final_solve(
    draft: PickDraft,
    picks: list[CapturePick],
    sides: dict[int, _Side],
    seed_obs: list[BoxObservation],
    settings: PickSettings,
) -> CalibResult | None:
    obs = list(seed_obs)
    for p, c in zip(picks, draft.captures, strict=True):
        side = sides[c.index]
        if p.source == "auto" and p.image_endpoints_px is not None and side.laser_side is not None:
            obs.append(_observation(draft, c, side, p.image_endpoints_px))
    try:
        return _solve(draft.camera, obs, settings)
    except CalibrationError:
        return None


def _mark_rejected(picks: list[CapturePick], final: CalibResult) -> list[CapturePick]:
    out = []
    m = final.measurements
    for p in picks:
        sel = m.capture == p.index
        if p.source == "auto" and sel.any() and not final.inliers[sel].all():
            worst = float(final.errors_px[sel].max())
            reason = f"rejected by the solve over all picks ({worst:.1f} px)"
            p = replace(p, review=True, reasons=(*p.reasons, reason))
        out.append(p)
    return out


# --- the image side ----------------------------------------------------------------------
def _read_float_image(c: CaptureDraft) -> NDArray[np.float32]:
    from rigcal.io.images import read_image

    return read_image(c.image_path).astype(np.float32)


def _project(camera: Camera, T: FloatArray, points_laser_3d: FloatArray) -> FloatArray | None:
    """Pixels (N, 2) of laser-frame points (N, 3), or None if any is behind the camera."""
    pc = transform_points(T, points_laser_3d)
    if np.any(pc[:, 2] <= 0.05):
        return None
    return camera.project(pc)


def _sample(image: NDArray[np.float32], xy: FloatArray) -> NDArray[np.float32]:
    """Bilinear colours at pixels ``xy`` (..., 2) (pixel-centre convention: (0, 0) is the
    first pixel's centre); (..., C)."""
    import cv2

    shape = xy.shape[:-1]
    flat = xy.reshape(-1, 2).astype(np.float32)
    out = cv2.remap(
        image,
        flat[:, 0].reshape(1, -1),
        flat[:, 1].reshape(1, -1),
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REPLICATE,
    )
    out = out.reshape(*shape, -1) if out.ndim == 3 else out.reshape(*shape, 1)
    return np.asarray(out, dtype=np.float32)


def _edge_points(camera: Camera, T: FloatArray, P: FloatArray, span_m: float, n: int) -> FloatArray | None:
    """Pixels (n, 2) along the vertical through laser point P, from -span/2 to +span/2."""
    z = np.linspace(-0.5 * span_m, 0.5 * span_m, n)
    pts = np.column_stack([np.full(n, P[0]), np.full(n, P[1]), z])
    return _project(camera, T, pts)


def _end_directions(
    camera: Camera, T: FloatArray, P: FloatArray, outward: FloatArray, span_m: float
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """A laser end's predicted pixel (2,), the unit image direction of the laser line
    outward (2,), and the image vector (2,) of the vertical edge over ``span_m`` (from
    -span/2 to +span/2 in laser z); None when behind the camera."""
    q = _project(
        camera, T, np.array([[P[0], P[1], 0.0], [P[0] + 0.01 * outward[0], P[1] + 0.01 * outward[1], 0.0]])
    )
    edge = _edge_points(camera, T, P, span_m, 2)
    if q is None or edge is None:
        return None
    along = (q[1] - q[0]) / np.linalg.norm(q[1] - q[0])
    return q[0], along, edge[1] - edge[0]


def _face_colour(
    camera: Camera, T: FloatArray, image: NDArray[np.float32], ends: FloatArray, span_m: float
) -> FloatArray | None:
    """Median colour of the box face along its middle half at the laser's height."""
    s = np.linspace(0.25, 0.75, 15)
    pts = ends[0] + s[:, None] * (ends[1] - ends[0])
    z = np.linspace(-0.5 * span_m, 0.5 * span_m, 5)
    p3 = np.array([[x, y, zz] for x, y in pts for zz in z])
    q = _project(camera, T, p3)
    if q is None or not camera.in_image(q).any():
        return None
    colours = _sample(image, q[camera.in_image(q)])
    return np.asarray(np.median(colours, axis=0), dtype=float)


def refine_end(
    camera: Camera,
    T: FloatArray,
    image: NDArray[np.float32],
    end_laser: FloatArray,
    outward_laser: FloatArray,
    face_colour: FloatArray,
    settings: PickSettings,
) -> EdgeFit:
    """Refine one predicted box end to the box's vertical edge (see the module docstring).

    Args:
        camera, T: the camera and T_cam_laser (4, 4) of the prediction.
        image: (H, W, C) float32.
        end_laser: (2,) the box end in the laser plane, metres.
        outward_laser: (2,) unit vector along the box side, away from the box.
        face_colour: (C,) the face's colour.
        settings: search width, prior, edge span.
    """
    from scipy.ndimage import gaussian_filter1d

    P = np.asarray(end_laser, dtype=float)
    dirs = _end_directions(camera, T, P, outward_laser, settings.edge_span_m)
    if dirs is None:
        nan = np.full(2, np.nan)
        return EdgeFit(nan, nan, False, 0.0, 0.0)
    pred, along, d = dirs
    if not camera.in_image(pred[None, :]).all():
        return EdgeFit(pred, pred, False, 0.0, 0.0)
    n_v = max(3, int(np.ceil(np.linalg.norm(d))) + 1)
    v = np.linspace(-0.5, 0.5, n_v)[:, None] * d  # (V, 2) offsets along the edge
    t = np.arange(-settings.search_px, settings.search_px + 0.5 * STEP_PX, STEP_PX)
    grid = pred + t[:, None, None] * along + v[None, :, :]  # (T, V, 2)
    profile = _sample(image, grid).mean(axis=1).astype(float)  # (T, C)
    D = np.linalg.norm(profile - face_colour[None, :], axis=1)
    rise = gaussian_filter1d(D, SMOOTH_PX / STEP_PX, order=1) / STEP_PX
    peaks = np.flatnonzero((rise[1:-1] > 0) & (rise[1:-1] >= rise[:-2]) & (rise[1:-1] > rise[2:])) + 1
    candidates = []
    for k in peaks:
        inside = D[(t >= t[k] - LEVEL_FAR_PX) & (t <= t[k] - LEVEL_NEAR_PX)]
        outside = D[(t >= t[k] + LEVEL_NEAR_PX) & (t <= t[k] + LEVEL_FAR_PX)]
        if not len(inside) or not len(outside):
            continue
        d_in, d_out = float(np.median(inside)), float(np.median(outside))
        step = d_out - d_in
        if step < MIN_CONTRAST or d_in > FACE_TOLERANCE:
            continue
        score = step * float(np.exp(-0.5 * (t[k] / settings.prior_sigma_px) ** 2))
        candidates.append((score, int(k), d_in, d_out))
    if not candidates:
        return EdgeFit(pred, pred, False, 0.0, 0.0)
    candidates.sort(reverse=True)
    score, k_best, d_in, d_out = candidates[0]
    second = candidates[1][0] if len(candidates) > 1 else 0.0
    t_edge = _half_crossing(t, D, k_best, 0.5 * (d_in + d_out))
    t_edge = _past_dark_band(t, profile, face_colour, t_edge)
    step = d_out - d_in
    confidence = (1.0 - second / score) * min(1.0, step / CONTRAST_REF)
    return EdgeFit(
        pred + t_edge * along, pred, True, float(confidence), float(step), along, d / np.linalg.norm(d)
    )


def edge_extent(
    image: NDArray[np.float32], fit: EdgeFit, face_colour: FloatArray, at: FloatArray | None = None
) -> tuple[float, float] | None:
    """Where the box face ends below and above a point on its end edge, along the edge
    (px from ``at``, default the fit's pixel; negative below): the face's bottom and top
    edges seen just inside its end, each at its 50 % colour step (dark outline included).
    None when either is not found within MAX_EXTENT_PX."""
    p = fit.pixel if at is None else np.asarray(at, dtype=float)
    if not (fit.found and np.all(np.isfinite(fit.up))):
        return None
    s = np.arange(-MAX_EXTENT_PX, MAX_EXTENT_PX + 0.5 * STEP_PX, STEP_PX)
    inward = -fit.along * np.array([INSIDE_PX, INSIDE_PX + 1.0, INSIDE_PX + 2.0])[:, None]  # (3, 2)
    grid = p + s[:, None, None] * fit.up + inward[None, :, :]
    profile = _sample(image, grid).mean(axis=1).astype(float)
    D = np.linalg.norm(profile - face_colour[None, :], axis=1)
    zero = int(np.argmin(np.abs(s)))
    out = []
    for direction in (-1, 1):
        order = np.arange(zero, -1, -1) if direction < 0 else np.arange(zero, len(s))
        edge = _first_step(direction * s[order], profile[order], D[order], face_colour)
        if edge is None:
            return None
        out.append(direction * edge)
    return out[0], out[1]


def _first_step(t: FloatArray, profile: FloatArray, D: FloatArray, face: FloatArray) -> float | None:
    """The first face-to-other colour step along an increasing t (from inside the face),
    at its 50 % crossing, past a dark outline; None when there is none."""
    outside = np.flatnonzero(max(MIN_CONTRAST, 0.5 * CONTRAST_REF) < D)
    if not len(outside) or outside[0] == 0:
        return None
    k = int(outside[0])
    beyond = D[(t >= t[k]) & (t <= t[k] + LEVEL_FAR_PX)]
    inside = D[(t >= t[k] - LEVEL_FAR_PX) & (t < t[k] - LEVEL_NEAR_PX)]
    d_in = float(np.median(inside)) if len(inside) else float(D[0])
    level = 0.5 * (d_in + float(np.median(beyond)))
    t_edge = _half_crossing(t, D, k, level)
    return _past_dark_band(t, profile, face, t_edge)


def _past_dark_band(t: FloatArray, profile: FloatArray, face: FloatArray, t_edge: float) -> float:
    """A thin dark line of the face's own hue along its edge (a painted outline, the
    shadow of a bevel) belongs to the box: when the profile just beyond the edge is such a
    line, at most DARK_BAND_PX wide, the edge moves to its outer side (the midpoint between
    its last sample and the first sample beyond it)."""
    lum = profile.mean(axis=1)
    chroma = profile / np.maximum(profile.sum(axis=1, keepdims=True), 1.0)
    face_chroma = face / max(float(face.sum()), 1.0)
    band = (np.linalg.norm(chroma - face_chroma, axis=1) < DARK_BAND_CHROMA) & (
        lum < DARK_BAND_LUMINANCE * float(face.mean())
    )
    near = np.flatnonzero(band & (t >= t_edge) & (t <= t_edge + 1.0))
    if not len(near):
        return t_edge
    j = int(near[0])
    while j < len(t) and band[j]:
        j += 1
    if j >= len(t) or t[j] - t_edge > DARK_BAND_PX:
        return t_edge
    return float(0.5 * (t[j - 1] + t[j]))


def _half_crossing(t: FloatArray, D: FloatArray, k: int, level: float) -> float:
    """Where the profile D crosses ``level`` upward nearest sample k (linear
    interpolation), i.e. the edge's 50 % point; t[k] if it does not."""
    lo = max(0, k - int(LEVEL_FAR_PX / STEP_PX))
    hi = min(len(t) - 1, k + int(LEVEL_FAR_PX / STEP_PX))
    best = None
    for i in range(lo, hi):
        if D[i] < level <= D[i + 1]:
            x = t[i] + (level - D[i]) / (D[i + 1] - D[i]) * (t[i + 1] - t[i])
            if best is None or abs(x - t[k]) < abs(best - t[k]):
                best = float(x)
    return best if best is not None else float(t[k])


# --- writing -----------------------------------------------------------------------------
def pick_file_text(run: PickRun, output: Path) -> str:
    """The picking file (schema 2, docs/formats/session.md) with every proposed pick, its
    paths relative to ``output``'s folder."""
    import os

    import yaml

    d = run.draft
    base = output.resolve().parent

    def rel(p: Path) -> str:
        return os.path.relpath(p, base)

    review = [p.name for p in run.picks if p.review]
    head = [
        "# rigcal picking file (docs/formats/session.md)",
        f"# Image ends proposed by rigcal pick from {d.path.name} (pose from {run.seeded_from});",
        f"# {len(review)} captures to check by eye (pick.review: true)"
        + (": " + ", ".join(review) if review else "")
        + ". Edit a pick, set its source to manual and run rigcal pick again.",
    ]
    doc: dict[str, object] = {"schema_version": 2}
    if d.name is not None:
        doc["name"] = d.name
    doc["camera"] = rel(d.camera_path)
    if d.laser:
        doc["laser"] = d.laser
    if d.box:
        doc["box"] = d.box
    caps = []
    for p, c in zip(run.picks, d.captures, strict=True):
        entry: dict[str, object] = {"name": c.name, "scan": rel(c.scan_path), "image": rel(c.image_path)}
        if p.laser_side is not None:
            entry["laser_side"] = p.laser_side
        if p.image_endpoints_px is not None:
            entry["image_endpoints_px"] = [[round(float(x), 2) for x in e] for e in p.image_endpoints_px]
        meta: dict[str, object] = {"source": p.source}
        if p.source == "auto":
            meta |= {"confidence": round(p.confidence, 3), "review": p.review}
        entry["pick"] = meta
        caps.append(entry)
    doc["captures"] = caps
    body = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110)
    return "\n".join(head) + "\n" + body
