"""Feature tracks across the image sequence (paper Section IV: "SIFT features tracked
across frames until their count falls below a threshold").

Corners are detected in a frame and followed into each next frame by pyramidal
Lucas-Kanade optical flow (OpenCV's ``calcOpticalFlowPyrLK``). A track survives a step
when the flow converges, lands inside the image, its window still looks like the
previous frame's, and it flows back to within ``max_fb_px`` of where it started
(forward-backward check: a track that slid onto something else rarely comes back). When
fewer than ``redetect_below`` tracks are left, the detector runs again and its strongest
new points, away from the live tracks, start new tracks.

The detector is Shi-Tomasi's (OpenCV's ``goodFeaturesToTrack``: points whose window is
well conditioned for Lucas-Kanade, the window the tracker follows) by default, beyond
the paper; the paper's SIFT keypoints are ``TrackParams(detector="sift")``. On the
simulated loops the corners' tracks live longer, visual odometry and the Kalman filter
come out more accurate on most laps, H-IASM the same, and the tracking costs less than
SIFT's (``benchmarks/bench_tracks.py``; figures in docs/benchmarks.md).

Each track's search starts where its last displacement takes it (constant image
velocity; a new track takes the median of its nearest tracks' last displacements). From
a standing start, Lucas-Kanade converges to the nearest copy of a repeating pattern:
once the rig moves along it by more than half the period between frames (0.4 m at 1 m/s
and 2.5 Hz, against the simulator's 0.5 m period), every track on it jumps back a
period, the forward-backward check passes (the jump is the same both ways), and visual
odometry reports the rig moving backwards. Predicted, the search only has to cover the
change of the displacement from one frame to the next.

Tracking is what makes the odometry cheap: the detector runs only when tracks run out,
and Lucas-Kanade follows a thousand points, each to a fraction of a pixel, in a fraction
of the detector's time (figures in docs/benchmarks.md). A track's
identity is an integer; the correspondences between any two frames are the tracks alive
in both (:func:`common`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from functools import cached_property
from typing import ClassVar

import cv2
import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.localize.patches import sample_patches

Gray = NDArray[np.uint8]


DETECTORS = ("sift", "shi-tomasi")
EQUALIZERS = ("none", "gain", "clahe")


@dataclass(frozen=True)
class TrackParams:
    """Tracking settings.

    Attributes:
        n_features: tracks wanted per frame (the detector's strongest points fill up to this).
        redetect_below: the detector runs again when fewer tracks than this are alive...
        redetect_fraction: ... or fewer than this fraction of those alive after the
            last detection (a texture-poor view offers fewer than ``redetect_below``).
        window_px: Lucas-Kanade window side (pixels).
        levels: Lucas-Kanade pyramid levels above the full image.
        max_fb_px: a track is dropped when tracking it back misses its start by more.
        max_patch_error: ... or when its window differs from the previous frame's by more
            (mean absolute difference, grey levels): something else now covers the point.
        min_distance_px: new keypoints keep at least this far from live tracks.
        predict: each track's search starts where its last displacement takes it
            (constant image velocity; a new track takes the median of its
            ``predict_neighbours`` nearest tracks'), so that a displacement larger than
            the pyramid reaches, or than a repeating pattern's period, is still followed.
        predict_neighbours: tracks whose displacements a new track's prediction uses.
        detector: what starts new tracks: ``"shi-tomasi"`` (OpenCV's
            ``goodFeaturesToTrack``: corners whose window is well conditioned for
            Lucas-Kanade, cheaper to find) or ``"sift"`` (the paper's SIFT keypoints);
            compared in ``benchmarks/bench_tracks.py``.
        equalize: how the image side copes with a camera whose exposure changes from frame
            to frame (automatic exposure), which breaks Lucas-Kanade's and the patch
            searches' constant brightness: ``"gain"`` (the default), each frame pair's
            gain measured on the tracks (:func:`gain_between`) and divided out where two
            frames are compared (Lucas-Kanade, visual odometry's scale search), the frames
            left as they are, and a fixed exposure's frames left alone (a dead band);
            ``"none"``; or ``"clahe"``, contrast-limited adaptive histogram equalization
            (OpenCV's CLAHE, clip limit ``clahe_clip``, 8x8 tiles) of every frame before
            anything reads it (the tracks, the scale search, IASM's and H-IASM's
            patches), which maps each tile's grey levels by their own distribution, one
            a gain leaves unchanged (:func:`equalized`), but stretches flat tiles' noise.
        clahe_clip: CLAHE's clip limit (times the mean histogram bin): how far it may
            stretch the contrast of a flat tile, and so its noise.
    """

    n_features: int = 1000
    redetect_below: int = 300
    redetect_fraction: float = 0.7
    window_px: int = 15
    levels: int = 3
    max_fb_px: float = 1.0
    max_patch_error: float = 12.0
    min_distance_px: float = 8.0
    predict: bool = True
    predict_neighbours: int = 5
    detector: str = "shi-tomasi"
    equalize: str = "gain"
    clahe_clip: float = 3.0

    # The values a text setting takes (``rigcal localize --tracks detector=...``).
    choices: ClassVar[dict[str, tuple[str, ...]]] = {"detector": DETECTORS, "equalize": EQUALIZERS}

    def __post_init__(self) -> None:
        for key, allowed in self.choices.items():
            if getattr(self, key) not in allowed:
                raise ValueError(f"{key} must be one of {allowed}, not {getattr(self, key)!r}")
        if not 0.0 < self.clahe_clip <= 100.0:
            raise ValueError(f"clahe_clip in (0, 100], not {self.clahe_clip!r}")


def equalized(gray: Gray, params: TrackParams) -> Gray:
    """A frame as the image side sees it (``params.equalize``): equalized by CLAHE (a new
    CLAHE object per call: frames are decoded on several threads), else unchanged."""
    if params.equalize != "clahe":
        return gray
    clahe = cv2.createCLAHE(clipLimit=params.clahe_clip, tileGridSize=(8, 8))
    return np.asarray(clahe.apply(gray), dtype=np.uint8)


# gain_between: points whose quarter-size grey level is outside these are left out
# (too dark to give a ratio, or clipped by saturation), and fewer than this many points
# give no gain.
_GAIN_GREY = (16.0, 239.0)
_GAIN_MIN_POINTS = 20


def gain_between(
    a: Gray,
    pixels_a: NDArray[np.floating],
    b: Gray,
    pixels_b: NDArray[np.floating],
    dead_band: float = 0.02,
    block_px: int = 4,
) -> float:
    """The exposure gain of frame b against frame a, ``b ~ gain * a``, from points seen in
    both (pixels (N, 2) in each): the median ratio of their grey levels in copies of the
    frames reduced to ``block_px`` x ``block_px`` pixel means (so that a pixel or two of
    error in where a point is placed changes little). 1 when fewer than 20 points are
    usable, or when the gain is within ``dead_band`` of 1.

    The dead band keeps a camera of fixed exposure's frames as they are: its estimate
    strays by up to 1.8 % over a visual odometry run (4x4 means: the view's change of
    scale moves them a little; the default 2 % is 2-3 grey levels at mid-grey, which the
    comparisons bear), and by up to 2.6 % between consecutive frames where the tracks
    are only predicted (8x8 means; the tracker uses 3 %).

    An automatic exposure changes the gain because the scene's brightness changed, so the
    frames' mean grey levels stay put while the points seen in both do not: the gain is
    measured on the points."""
    if len(pixels_a) < _GAIN_MIN_POINTS:
        return 1.0
    f = 1.0 / block_px
    qa = np.asarray(cv2.resize(a, None, fx=f, fy=f, interpolation=cv2.INTER_AREA), dtype=np.uint8)
    qb = np.asarray(cv2.resize(b, None, fx=f, fy=f, interpolation=cv2.INTER_AREA), dtype=np.uint8)
    # A small pixel k covers full-size pixels kB..kB+B-1: centre (p + 0.5) / B - 0.5.
    c = 0.5 * (block_px - 1)
    ga = sample_patches(qa, (pixels_a - c) * f, 0)[:, 0].astype(float)
    gb = sample_patches(qb, (pixels_b - c) * f, 0)[:, 0].astype(float)
    lo, hi = _GAIN_GREY
    ok = (ga >= lo) & (ga <= hi) & (gb >= lo) & (gb <= hi)
    if int(ok.sum()) < _GAIN_MIN_POINTS:
        return 1.0
    gain = float(np.median(gb[ok] / ga[ok]))
    return gain if abs(gain - 1.0) > dead_band else 1.0


@dataclass(frozen=True, eq=False)
class FrameTracks:
    """The tracks alive in one frame: ids (increasing), pixels (N, 2), and ``unproject``,
    which gives their unit bearings (N, 3) from the pixels (the camera's
    :meth:`~rigcal.camera.Camera.bearings`)."""

    ids: NDArray[np.int64]
    pixels: FloatArray
    unproject: Callable[[FloatArray], FloatArray] = field(repr=False)

    @cached_property
    def bearings(self) -> FloatArray:
        """(N, 3) the tracks' unit bearings, computed when first asked for (visual odometry
        reads only its runs' first and last frames, about a third of them)."""
        return self.unproject(self.pixels)


def common(a: FrameTracks, b: FrameTracks) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Indices (ia, ib) of the tracks alive in both frames."""
    _, ia, ib = np.intersect1d(a.ids, b.ids, assume_unique=True, return_indices=True)
    return ia.astype(np.intp), ib.astype(np.intp)


class Tracker:
    """Follows corners (or SIFT keypoints) frame to frame; call :meth:`step` with each frame
    in order."""

    def __init__(self, camera: Camera, params: TrackParams | None = None) -> None:
        self.camera = camera
        self.params = params or TrackParams()
        self._sift = cv2.SIFT_create()  # type: ignore[attr-defined]
        self._prev: Gray | None = None
        self._ids = np.zeros(0, np.int64)
        self._px = np.zeros((0, 2), np.float32)
        self._vel = np.zeros((0, 2), np.float32)  # last displacement; NaN for a new track
        self._next_id = 0
        self.detections = 0
        self._after_detection = 0

    def step(self, gray: Gray) -> FrameTracks:
        """The tracks of the next frame."""
        if self._prev is not None and len(self._px):
            self._follow(self._prev, gray)
        p = self.params
        wanted = min(p.redetect_below, p.redetect_fraction * self._after_detection)
        if len(self._px) < wanted or not len(self._px):
            self._detect(gray)
            self._after_detection = len(self._px)
        self._prev = gray
        px = self._px.astype(float)
        return FrameTracks(self._ids.copy(), px, self.camera.bearings)

    def _follow(self, a: Gray, b: Gray) -> None:
        p = self.params
        lk = {
            "winSize": (p.window_px, p.window_px),
            "maxLevel": p.levels,
            "criteria": (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 20, 0.03),
        }
        p0 = self._px.reshape(-1, 1, 2)
        guess = self._guess() if p.predict else np.zeros_like(self._px)
        if p.predict:
            lk["flags"] = cv2.OPTFLOW_USE_INITIAL_FLOW
        start = (self._px + guess).reshape(-1, 1, 2)
        if p.equalize == "gain":
            # b's exposure against a's, where the tracks are predicted to be, in 8x8 pixel
            # means (a prediction can be some pixels off), past 3 %. Not where
            # Lucas-Kanade finds them: it finds each where the grey levels match best,
            # which hides part of the gain.
            gain = gain_between(a, self._px, b, start.reshape(-1, 2), dead_band=0.03, block_px=8)
            if gain != 1.0:
                b = np.asarray(cv2.convertScaleAbs(b, alpha=1.0 / gain), dtype=np.uint8)
        p1, st1, err = cv2.calcOpticalFlowPyrLK(a, b, p0, start, **lk)  # type: ignore[call-overload]
        p1 = p1.reshape(-1, 2)
        h, w = b.shape
        ok = (
            (st1.ravel() == 1)
            & (err.ravel() < p.max_patch_error)
            & (p1[:, 0] >= 0)
            & (p1[:, 1] >= 0)
            & (p1[:, 0] <= w - 1)
            & (p1[:, 1] <= h - 1)
        )
        # Only the tracks still alive are tracked back (each point is followed on its own,
        # so the others would change nothing).
        k = np.flatnonzero(ok)
        if len(k):
            back, st2, _ = cv2.calcOpticalFlowPyrLK(  # type: ignore[call-overload]
                b, a, p1[k].reshape(-1, 1, 2), (p1[k] - guess[k]).reshape(-1, 1, 2), **lk
            )
            fb = np.linalg.norm(back.reshape(-1, 2) - self._px[k], axis=1)
            ok[k] = (st2.ravel() == 1) & (fb < p.max_fb_px)
        self._vel = (p1 - self._px)[ok].astype(np.float32)
        self._ids, self._px = self._ids[ok], p1[ok].astype(np.float32)

    def _guess(self) -> NDArray[np.float32]:
        """Each track's predicted displacement: its last one, or for a new track the
        median of its nearest followed tracks' (none followed: zero)."""
        vel = self._vel.copy()
        new = np.isnan(vel[:, 0])
        known = ~new
        if new.any():
            if known.any():
                k = min(self.params.predict_neighbours, int(known.sum()))
                from scipy.spatial import cKDTree

                _, nb = cKDTree(self._px[known]).query(self._px[new], k=k)
                vel[new] = np.median(self._vel[known][nb.reshape(int(new.sum()), k)], axis=1)
            else:
                vel[new] = 0.0
        return vel

    def _detect(self, gray: Gray) -> None:
        p = self.params
        mask = np.full(gray.shape, 255, np.uint8)
        r = int(np.ceil(p.min_distance_px))
        for x, y in np.round(self._px).astype(int):
            cv2.circle(mask, (int(x), int(y)), r, 0, -1)
        self.detections += 1
        want = max(p.n_features - len(self._px), 0)
        if p.detector == "shi-tomasi":
            if want == 0:  # (OpenCV reads 0 corners as no limit)
                return
            found = cv2.goodFeaturesToTrack(gray, want, 0.01, p.min_distance_px, mask=mask, blockSize=5)
            if found is None:
                return
            pts = np.asarray(found, np.float32).reshape(-1, 2)
        else:
            kps = self._sift.detect(gray, mask)
            if not kps:
                return
            pts = np.array([k.pt for k in kps], np.float32)
            resp = np.array([k.response for k in kps])
            # One point per location (SIFT lists a keypoint once per orientation), strongest first.
            order = np.argsort(-resp)
            _, first = np.unique(np.round(pts[order]).astype(np.int64), axis=0, return_index=True)
            pts = pts[order[np.sort(first)]][:want]
        ids = np.arange(self._next_id, self._next_id + len(pts), dtype=np.int64)
        self._next_id += len(pts)
        self._ids = np.concatenate([self._ids, ids])
        self._px = np.concatenate([self._px, pts])
        self._vel = np.concatenate([self._vel, np.full((len(pts), 2), np.nan, np.float32)])


def track_sequence(
    frames: Iterable[Gray],
    camera: Camera,
    params: TrackParams | None = None,
    progress: Callable[[int], None] | None = None,
) -> list[FrameTracks]:
    """The tracks of every frame of a sequence, the frames given in order."""
    tracker = Tracker(camera, params)
    out = []
    for i, frame in enumerate(frames):
        out.append(tracker.step(frame))
        if progress is not None:
            progress(i + 1)
    return out
