"""Targetless drift check: is T_cam_laser still right, judged from an ordinary drive?

The paper's IASM projects each scan's returns into the camera image with T_cam_laser and
compares the image patches around them across frames (Section III, III-A). With the right
T the projections of one return land on the same scene point in every frame that sees it;
with a wrong T they land on different points and the patches disagree. This module turns
that into a measurement of T:

1. The laser's motion from the point-to-line laser odometry (Eq. (4)), interpolated to the
   images' stamps (:mod:`rigcal.localize.streams`). Pairs of frames across a step where
   the odometry is degenerate (a featureless corridor) are left out.
2. For each used image i, returns on the scan's lines (snapped onto them, the range noise
   taken out) well inside the image; around each, a small grid of points on its wall (the
   vertical plane through the scan's line): along the line and up, spaced about
   ``patch_step_px`` apart in image i. The grid is a patch that warps with the wall, so the
   right T makes the two frames' samples the same surface points whatever the viewpoint.
   Which returns take part (their grids well inside both frames and on texture) is
   decided under the T the patches are chosen with: where the photometric term alone
   judges, they are chosen again under its estimate (:func:`_reselected`), so that the
   stored T's error does not decide its own estimate's data.
3. Each grid is projected into image i and into image j (a fraction of a second later,
   moved by the odometry) with T = T_stored * Exp(xi), xi = (rotation, translation) in the
   laser frame. The residual is the difference of the zero-mean patches, frame j's scaled
   by the pair's exposure gain (the camera's automatic exposure moves; the gain is
   re-measured at every iteration), on blurred images (coarse to fine).
3b. The scans' depth discontinuities (corners, occluding line ends) projected onto the
   images' edges (:mod:`rigcal.drift.edges`, after Levinson & Thrun, RSS 2013): one frame
   observes the camera's translation across the view and its yaw, free of the odometry.
4. Gauss-Newton on xi with image gradients, robust (Cauchy) weights per patch and per
   edge band, each term weighed by its own noise; when edges are seen they alone
   estimate the yaw and the translations (the photometric term's are confounded with
   the odometry's crab angle and pivot), the photometric term the roll and pitch. The
   edge bands are paired with their image edges once, at the start estimate; a step is
   accepted only when the Newton correction at its end is shorter than the step
   (natural monotonicity; damped and retried otherwise), and an estimate that does not
   settle or runs off its pairing is "cannot tell". The laser odometry's errors (scale,
   yaw scale, yaw rate bias, pivot, crab angle) are estimated beside xi under a weak
   prior on the thinned scans' odometry (where the edges estimate the yaw and the
   translations); on every scan's odometry (where the photometric term alone judges)
   they are held at zero, since the photometric term's model errors, not the odometry's,
   moved them along one ridge of its cost with the yaw (:func:`_prior`), and the last
   stage iterates until it settles (``max_iterations``).
5. The covariance of xi: the clusters' jackknife (:mod:`rigcal.drift.statistic`), the
   clusters being the photometric patches of each block of ``block_s`` seconds
   (neighbouring frames share odometry and images) and the edge bands of each physical
   corner (one corner's error is one error, however many frames see it), so model
   errors (odometry drift, rendering, range noise, a corner's foot) count as they show
   in the data rather than as assumed; plus a systematic floor derived on simulated
   drives.
6. Which directions are observed: those whose 1-sigma is below the resolution (0.3 deg, 2
   cm by default) over the detection factor (a change of one resolution is then detected
   95 % of the time at the level). A 2D laser moving in its scan plane never observes the
   camera's height above the laser (laser z): lifting every return along its wall keeps it
   on the same surface point in every frame, and slides a vertical edge's projection
   along itself. Edges at several depths observe the translations across the plane; the
   physical corners judge the edges' directions (yaw, translations) only as far as they
   outnumber them: G corners fixing m directions test at most G - m - 1 (none with fewer
   than m + 2 corners). A drive that keeps one heading (a straight corridor) and sees no edge does not observe
   a shift along the travel nor a roll about it (both slide the returns along their
   walls, alike in every frame). Without edges the translations are not observed
   either: the photometric term's errors there are common to every block and its floor
   (``floor_m``) is above the resolution over the detection factor; its yaw is, with the
   odometry's errors held (step 4): its floor (``photo_floor_deg``) is under it.
7. The test: the correction on the observed directions against its covariance plus the
   stored calibration's (Hotelling's T^2 with the clusters' effective count: an F test
   that tends to the chi-square with k dof as the clusters grow). Drifted when p <
   level. When the check with the edges cannot tell (their few corners determine no
   direction, or too few of them), or its estimate with the edges did not settle or ran
   away (step 5), or its edges were usable at the start estimate and lost on the way to
   it (made with the odometry's errors estimated, its yaw is not observed), it is made
   again with the edge term off, the photometric term alone on every scan's odometry
   (:func:`_photometric_alone`); an estimate that was already that one (the drive's
   edges found but unusable) and could not tell is not made twice, and only an estimate
   that used the edges is held to their projections' search window. When the
   drive is too short, sees no returns, or observes no direction, the verdict is "cannot
   tell".
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import math
import sys
import threading
import time
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.drift.blur_stack import BlurStack
from rigcal.drift.edges import (
    EdgeImages,
    Edges,
    band_points,
    corner_clusters,
    edge_residuals,
    scan_discontinuities,
    search_boxes,
)
from rigcal.drift.frames import FRAME_RATE_HZ, frames_ahead, used_frames
from rigcal.drift.sampling import GRAD_STEP_PX, GREY_SCALE, project_sample
from rigcal.drift.statistic import (
    BOOTSTRAP_FROM_CLUSTERS,
    cluster_covariance,
    effective_clusters,
    hotelling,
    hotelling_critical,
    spread_dof,
    wild_cluster_bootstrap,
)
from rigcal.errors import InputError
from rigcal.geometry import R_to_rotvec, make_T, rotvec_to_R, se2
from rigcal.io.stamps import outside_scans
from rigcal.lines import return_labels
from rigcal.localize.iasm import snap_to_lines
from rigcal.localize.line_normals import line_fits
from rigcal.localize.odometry import DEGENERATE_BELOW
from rigcal.localize.prefetch import Ahead
from rigcal.localize.streams import Streams
from rigcal.localize.time_pairing import nearest_index, poses_at
from rigcal.rig import Rig
from rigcal.stats import ncx2_sf, norm_ppf

AXES = ("rx", "ry", "rz", "tx", "ty", "tz")
AXIS_WORDS = (
    "rotation about the laser's x (forward: roll)",
    "rotation about the laser's y (left: pitch)",
    "rotation about the laser's z (up: yaw)",
    "translation along the laser's x (forward)",
    "translation along the laser's y (left)",
    "translation along the laser's z (up)",
)

VERDICTS = ("ok", "drifted", "cannot_tell")


@dataclass(frozen=True)
class TargetlessSettings:
    """Settings of the targetless check (docs/calibration.md, "Drift from ordinary drives").

    Attributes:
        level: chance of a false alarm on an unmoved rig.
        resolution_deg, resolution_m: the smallest change the check is meant to detect; a
            direction counts as observed when a change this large along it would be
            detected 95 % of the time.
        frame_rate_hz: images used at most at this rate (the rest skipped).
        gaps_s: each used image is compared with the images this long after it.
        returns_per_frame: returns used per image (spread evenly along the scan).
        patch_half: each return's grid is (2h+1) x (2h+1) points on its wall.
        patch_step_px: the grid's spacing, in image i's pixels.
        blur_px: the images' Gaussian blur at each stage (coarse to fine).
        iterations: Gauss-Newton iterations per stage.
        min_range_m, max_range_m: returns used.
        min_texture: patches whose grey levels' standard deviation is below this are flat.
        block_s: length of the blocks the covariance treats as independent.
        min_blocks: fewer blocks: "cannot tell" (too short).
        min_returns: fewer patches in all: "cannot tell" (no overlap).
        min_travel_m: a drive shorter than this: "cannot tell" (no parallax).
        native_blur_px: the camera's own blur (1 sigma) assumed when matching the blur of
            two frames.
        floor_deg: the systematic floor of the roll, pitch and yaw (1-sigma, added to
            each one's variance): what no drive's own spread shows (errors common to
            all of its blocks and corners: the image model, the lens model, the
            odometry's errors beyond those estimated). Derived on simulated
            development drives (seeds 100-121, docs/benchmarks.md, round 4): the root
            mean square of the unperturbed corrections less the mean of their
            jackknife variances, per axis (0.013-0.020, 0.018-0.029, 0.030-0.038
            deg), rounded up.
        photo_floor_deg: the rotations' floor when the photometric term alone estimates
            them (no edge used: it then estimates the yaw too, on every scan's odometry,
            the odometry's errors held), derived as floor_deg's on development drives
            (seeds 300-319) checked with the edge term off (0.020, 0.026 and 0.041 deg;
            docs/benchmarks.md, "The targetless check: the odometry's errors held where
            the photometric term judges alone"), rounded up. The yaw's error there is
            common to every block (every scan's odometry's errors, the image model's),
            so no block's spread shows it; its floor is under the resolution over the
            detection factor (0.071 deg), so the yaw is observed without edges. With the
            odometry's errors estimated it was 0.14 deg (round 8): they took up the image
            model's errors and dragged the yaw.
        photo_floor_free_deg: the photometric term's rotations' floor on an estimate
            whose odometry's errors were estimated (its edges used at the start, lost on
            the way to the estimate): round 8's (0.028, 0.030 and 0.136 deg on seeds
            300-339, rounded up), above the limit on the yaw, which is then not observed.
        max_iterations: with the odometry's errors held, the last stage's Gauss-Newton
            iterations at most (it stops once a step is under ``SETTLED_UNITS``; on
            development drives it took 7-19 steps in all).
        floor_m: the translations' floor when the photometric term estimates them (no
            edges): its translations reach 1-1.5 cm on simulated drives (the
            odometry's crab angle and pivot take up a shifted camera), so without
            edges no translation counts as observed at 2 cm.
        edge_floor_m: the translations' floor when the edges estimate them, derived as
            the rotations' (0.8-1.5 mm), rounded up.
        scan_rate_hz: with edges, the check's own laser odometry runs on the scans
            thinned to about this rate (every k-th scan; 40 Hz to 10 Hz: a quarter of
            the ICP's cost, steps of a few centimetres); a drive showing fewer than
            :data:`MIN_EDGE_BANDS` edges, or fewer usable at the start estimate, is
            checked on every scan's odometry (the photometric term alone needs it). None: on
            every scan (and reuse the odometry the streams have computed, as after a
            ``localize`` run).
        edges: use the depth discontinuities against the image edges.
        edge_window_px: the image's edge is searched this far either side of each
            projected edge, per stage (coarse to fine).
    """

    level: float = 0.01
    resolution_deg: float = 0.3
    resolution_m: float = 0.02
    frame_rate_hz: float = FRAME_RATE_HZ
    gaps_s: tuple[float, ...] = (0.2, 0.6)
    returns_per_frame: int = 40
    patch_half: int = 1
    patch_step_px: float = 2.0
    blur_px: tuple[float, ...] = (3.0, 1.2)
    iterations: int = 6
    min_range_m: float = 0.5
    max_range_m: float = 10.0
    min_texture: float = 3.0
    block_s: float = 2.0
    min_blocks: int = 8
    min_returns: int = 200
    min_travel_m: float = 1.0
    native_blur_px: float = 0.8
    floor_deg: tuple[float, float, float] = (0.02, 0.03, 0.04)
    photo_floor_deg: tuple[float, float, float] = (0.03, 0.03, 0.05)
    photo_floor_free_deg: tuple[float, float, float] = (0.03, 0.04, 0.14)
    max_iterations: int = 30
    floor_m: float = 0.01
    edge_floor_m: float = 0.0015
    scan_rate_hz: float | None = 10.0
    edges: bool = True
    edge_window_px: tuple[float, ...] = (12.0, 6.0)

    def __post_init__(self) -> None:
        if not 0.0 < self.level < 1.0:
            raise ValueError("TargetlessSettings: level must be in (0, 1)")

    @property
    def scale(self) -> FloatArray:
        """(6,) xi per resolution unit: rotations in rad, translations in m."""
        r = math.radians(self.resolution_deg)
        return np.array([r, r, r, self.resolution_m, self.resolution_m, self.resolution_m])

    def detection_factor(self) -> float:
        """How many sigmas a resolution must span to be detected 95 % of the time in a
        one-dof test at ``level`` (two-sided)."""
        return norm_ppf(1.0 - self.level / 2.0) + norm_ppf(0.95)


@dataclass(frozen=True)
class TargetlessResult:
    """Outcome of a targetless check.

    Attributes:
        verdict: "ok", "drifted" or "cannot_tell".
        level: the false-alarm level.
        correction: (6,) xi on the observed directions: T_new = T_stored Exp(xi), laser
            frame, [rotation (rad), translation (m)]; NaN when nothing could be estimated.
        covariance: (6, 6) its covariance on the observed directions (zero elsewhere).
        record: the drift log's ``targetless`` block (JSON-ready).
        reasons: sentences behind the verdict.
        details: ``groups``: each test's pieces in its observed basis ``V`` (resolution
            units): the correction ``z``, its covariance from the data ``C_data``, the
            floor's and the rig's ``C_known``, the clusters' effective count ``n_data``
            (for benchmarks that study the statistic; not logged).
    """

    verdict: str
    level: float
    correction: FloatArray
    covariance: FloatArray
    record: dict[str, Any]
    reasons: list[str]
    details: dict[str, Any] = field(default_factory=dict)

    @property
    def drifted(self) -> bool:
        return self.verdict == "drifted"


@dataclass
class _Patches:
    """Every compared patch: the grid points in the laser frame at image i's time, the
    laser motion to image j, which images, which block."""

    X: FloatArray  # (P, S, 3) grid points, laser frame at frame i's stamp
    M: FloatArray  # (P, 4, 4) laser at i in the laser frame at j
    img_i: NDArray[np.int64]  # (P,) image index of frame i
    img_j: NDArray[np.int64]  # (P,) image index of frame j
    pair: NDArray[np.int64]  # (P,) pair index (for the gain)
    ratio: FloatArray  # (P,) depth in frame i over depth in frame j (the view's change of scale)
    yaw: FloatArray  # (P,) the laser's turn from frame i to frame j, rad
    dt: FloatArray  # (P,) time from frame i to frame j, s
    block: NDArray[np.int64]  # (P,) block index
    n_pairs: int
    info: dict[str, Any] = field(default_factory=dict)
    edges: Edges | None = None  # the scans' depth discontinuities (module docstring, step 3b)
    gray_of: dict[int, NDArray[np.uint8]] = field(default_factory=dict)  # the edges' frames
    rows: tuple[float, float] | None = None  # _rows's, made once
    projected: tuple[FloatArray, FloatArray] | None = None  # _projected's, made once
    stacks_ahead: dict[tuple[Any, ...], Future[Any]] = field(default_factory=dict)  # _stacks_ahead's


class _CannotTellError(Exception):
    """The drive cannot decide (a reason for the verdict, not an error).
    ``photometric_alone``: the estimate that could not tell was already the photometric
    term alone on every scan's odometry with its errors held, so the fallback
    (:func:`_photometric_alone`) would only make it again."""

    def __init__(self, reason: str, photometric_alone: bool = False) -> None:
        super().__init__(reason)
        self.photometric_alone = photometric_alone


class _EdgesUnusableError(Exception):
    """The estimate ran on the odometry of thinned scans, which serves only where the edges
    estimate the yaw and the translations, and too few edge bands were usable at its start
    (:data:`MIN_EDGE_BANDS`): the photometric term alone must run on every scan's odometry."""


def check_targetless(
    rig: Rig, streams: Streams, settings: TargetlessSettings | None = None
) -> TargetlessResult:
    """Check the rig's T_cam_laser against a drive (see the module docstring).

    Args:
        rig: the stored calibration (its covariance, when it has one, is part of the test).
        streams: the drive's scans and images (:func:`rigcal.localize.streams.open_streams`).

    Raises:
        InputError: the sequence has no images, or images of another size than the rig's
            camera.
    """
    settings = settings or TargetlessSettings()
    t_start = time.perf_counter()
    _import_ahead()
    if streams.n_images < 2:
        raise InputError.at(
            streams._yaml(), "images.count", streams.n_images, "a drive with camera images (at least 2)"
        )
    streams.rig = rig
    streams.require_images("targetless check")
    reasons: list[str] = []
    duration = float(streams.image_stamps_s[-1] - streams.image_stamps_s[0])
    base: dict[str, Any] = {"duration_s": round(duration, 3), "images": streams.n_images}
    if depth := streams.first_image_depth():  # 16-bit frames read as 8 bits, one shift for all
        base["images_16_bit"] = dict(depth)
    outside = outside_scans(streams.image_stamps_s, streams.scan_stamps_s)
    if outside["before"] or outside["after"]:  # left out of the check (no laser pose there)
        base["images_outside_scans"] = outside
    try:
        # The odometry of the thinned scans serves where the edges estimate the yaw and
        # the translations; the photometric term alone needs the odometry of every scan
        # (its yaw trades off against the odometry's errors).
        thin = thinned(streams, settings.scan_rate_hz) if settings.edges else streams
        patches = _build_patches(rig, thin, settings)
        if thin is not streams and (patches.edges is None or len(patches.edges.img) < MIN_EDGE_BANDS):
            thin = streams
            patches = _build_patches(rig, thin, settings)
        base.update(patches.info)
        try:
            # The later stages' images blur on a second thread while the first stage iterates.
            with _stacks_ahead(rig, thin, patches, settings):
                est = _estimate(
                    rig,
                    thin,
                    patches,
                    settings,
                    edges_required=thin is not streams,
                    hold_odometry=thin is streams,
                )
        except _EdgesUnusableError:
            # Edges were found but too few of them are clear in the images to be used: the
            # photometric term alone judges, on every scan's odometry.
            thin = streams
            patches = _build_patches(rig, thin, settings)
            base.update(patches.info)
            with _stacks_ahead(rig, thin, patches, settings):
                est = _estimate(rig, thin, patches, settings)
        if _held_alone(est):
            try:
                patches, est = _reselected(rig, streams, est, settings)
            except _CannotTellError as exc:
                exc.photometric_alone = True
                raise
            # The patches' counts of the estimate; the edges found stay those of the drive.
            base.update({k: v for k, v in patches.info.items() if k != "edges"})
    except _CannotTellError as exc:
        if not (settings.edges and base.get("edges")) or exc.photometric_alone:
            return _cannot_tell(base, str(exc), reasons, t_start, settings)
        unsettled: _CannotTellError | None = exc
    else:
        unsettled = None
    if unsettled is not None:
        # The estimate with the edges did not settle or ran away.
        why: str | None = f"{UNSETTLED}: {unsettled}"
    else:
        res = _test(rig, est, patches, settings, reasons)
        lost = not est.edge_stats and not est.solve.get("odometry_errors_held", False)
        # The edges' few corners could not judge (no direction determined, too few of
        # them), or the edges usable at the start were lost on the way to the estimate
        # (made with the odometry's errors estimated, which leaves the yaw unobserved:
        # photo_floor_free_deg).
        cornered = res["verdict"] == "cannot_tell" and bool(est.edge_stats)
        why = LOST if lost else "the check with the edges could not tell" if cornered else None
    if why is not None:
        # The photometric term alone, on every scan's odometry with its errors held,
        # judges what it observes; where it cannot either, the first verdict stands.
        alone = _photometric_alone(rig, streams, settings)
        if alone is not None:
            patches, res, reasons = alone
            base.update(patches.info)
            base["photometric_alone"] = why
        elif unsettled is not None:
            return _cannot_tell(base, str(unsettled), reasons, t_start, settings)
    rec = base | res["record"] | {"check_s": round(time.perf_counter() - t_start, 3)}
    return TargetlessResult(
        res["verdict"], settings.level, res["xi"], res["cov"], _json(rec), reasons, res.get("details", {})
    )


def _cannot_tell(
    base: dict[str, Any], reason: str, reasons: list[str], t_start: float, settings: TargetlessSettings
) -> TargetlessResult:
    """The "cannot tell" result with its reason, the record what the check had found."""
    reasons.append(reason)
    rec = base | {"check_s": round(time.perf_counter() - t_start, 3)}
    return TargetlessResult(
        "cannot_tell", settings.level, np.full(6, np.nan), np.zeros((6, 6)), _json(rec), reasons
    )


def _photometric_alone(
    rig: Rig, streams: Streams, settings: TargetlessSettings
) -> tuple[_Patches, dict[str, Any], list[str]] | None:
    """The check made again with the edge term off, on every scan's odometry with its
    errors held (module docstring, step 4): (its patches, its test, its reasons) when it
    observes a direction, else None."""
    alone = dataclasses.replace(settings, edges=False)
    reasons: list[str] = []
    try:
        patches = _build_patches(rig, streams, alone)
        with _stacks_ahead(rig, streams, patches, alone):
            est = _estimate(rig, streams, patches, alone)
        patches, est = _reselected(rig, streams, est, alone)
    except _CannotTellError:
        return None
    res = _test(rig, est, patches, alone, reasons)
    return None if res["verdict"] == "cannot_tell" else (patches, res, reasons)


LOST = "the edges were lost on the way to the estimate"
"""The record's ``photometric_alone`` where the edges usable at the start estimate were lost
on the way to it."""
UNSETTLED = "the estimate with the edges could not tell"
"""The start of the record's ``photometric_alone`` where the estimate with the edges did not
settle or ran away (the reason follows it)."""


def _held_alone(est: _Estimate) -> bool:
    """Whether the photometric term alone made the estimate, the odometry's errors held."""
    return not est.edge_stats and bool(est.solve.get("odometry_errors_held", False))


RESELECT_UNITS = 0.1
"""A correction (resolution units, largest over the calibration's axes) under which the
patches chosen under it are taken as those of the estimate (:func:`_reselected`)."""
MAX_RESELECTIONS = 2
"""Times the patches are chosen again under the estimate at most."""


def _reselected(
    rig: Rig, streams: Streams, est: _Estimate, s: TargetlessSettings
) -> tuple[_Patches, _Estimate]:
    """The photometric term alone's estimate made again on patches chosen under it
    (module docstring, step 2): the patches, and the estimate with its xi from the stored T.

    The patches are the returns whose grids project well inside both frames and on
    texture under the T they are chosen with; chosen under the stored T, a yaw error of
    the stored T decides which returns and which side of their texture take part, and
    the estimate moved past the truth by about a tenth of the error (a gain of 1.13 on
    69 held-out drives, 1.03 with the patches chosen under the true T;
    docs/benchmarks.md, "The targetless check: the photometric yaw's gain"). Chosen
    again under the estimate, the choice no longer depends on the stored T's error but
    on the estimate's (a few hundredths of a degree): made again until the correction
    on the new patches is under :data:`RESELECT_UNITS`, at most
    :data:`MAX_RESELECTIONS` times. The estimate's covariance is the last one's, at
    its start (the stored T's tangent differs by a second-order term)."""
    # From the estimate the last stage's blur alone (the coarser stages bring a far start
    # near; the estimate is the last stage's solution).
    alone = dataclasses.replace(s, edges=False, blur_px=s.blur_px[-1:])
    T0 = rig.T_cam_laser
    steps = dict(est.solve)
    patches: _Patches | None = None
    for n in range(1, MAX_RESELECTIONS + 1):
        at = dataclasses.replace(rig, T_cam_laser=T0 @ _exp(est.xi))
        patches = _build_patches(at, streams, alone)
        with _stacks_ahead(at, streams, patches, alone):
            again = _estimate(at, streams, patches, alone)
        moved = float(np.abs(again.xi[:5] / alone.scale[:5]).max())
        steps = again.solve | {
            "steps": steps["steps"] + again.solve["steps"],
            "steps_refused": steps["steps_refused"] + again.solve["steps_refused"],
            "reselected": n,
        }
        delta = np.linalg.inv(T0) @ at.T_cam_laser @ _exp(again.xi)
        est = dataclasses.replace(again, xi=np.r_[R_to_rotvec(delta[:3, :3]), delta[:3, 3]], solve=steps)
        if moved < RESELECT_UNITS:
            break
    assert patches is not None
    return patches, est


def _exp(xi: FloatArray) -> FloatArray:
    """(4, 4) the move xi = (rotation vector, translation) as the estimate composes it."""
    return make_T(rotvec_to_R(xi[:3]), xi[3:])


LATER_IMPORTS = ("scipy.special", "scipy.spatial", "scipy.sparse.csgraph")
"""Modules the check imports only where it first uses them (the test's tails, rotation
vectors, the corners' clusters): a third of a second of the interpreter's time, imported
on a second thread while the laser odometry runs (its compiled ICP releases the
interpreter) rather than on the main thread later."""


def _import_ahead() -> None:
    """Import :data:`LATER_IMPORTS` on a daemon thread, unless imported already (an import
    error there is left for the import where the module is used to raise)."""
    missing = [m for m in LATER_IMPORTS if m not in sys.modules]
    if not missing:
        return

    def run() -> None:
        for name in missing:
            with contextlib.suppress(ImportError):
                importlib.import_module(name)

    threading.Thread(target=run, name="rigcal-imports", daemon=True).start()


def same_camera(rig: Rig, streams: Streams, rig_path: Any = None) -> None:
    """An error when the sequence says it comes from another camera than the rig's (its
    own camera file or rig file naming another lens model or image size).

    Raises:
        InputError: naming the sequence's file, the key, its value and the rig's.
    """
    from rigcal.camera import read_camera
    from rigcal.rigfile import read_rig

    seq = streams.sequence
    if seq.folder is None:
        return
    own = []
    if seq.camera_file is not None:
        own.append((seq.folder / seq.camera_file, lambda p: read_camera(p)))
    if seq.rig_file is not None:
        own.append((seq.folder / seq.rig_file, lambda p: read_rig(p).camera))
    for path, read in own:
        cam = read(path)
        theirs = rig.camera
        where = f"the rig's camera{f' ({rig_path})' if rig_path else ''}"
        if cam.lensmodel != theirs.lensmodel:
            raise InputError.at(
                path, "lensmodel", cam.lensmodel, f"{theirs.lensmodel!r}, {where}: a drive of another rig?"
            )
        if (cam.width_px, cam.height_px) != (theirs.width_px, theirs.height_px):
            raise InputError.at(
                path,
                "image size",
                f"{cam.width_px}x{cam.height_px}",
                f"{theirs.width_px}x{theirs.height_px}, {where}: a drive of another rig?",
            )


def thinned(streams: Streams, rate_hz: float | None) -> Streams:
    """The streams with every k-th scan, k the largest that keeps ``rate_hz`` or more
    (the same streams when None or already that slow). Made once per streams (kept in
    its ``results``), so that repeated checks of one drive share its odometry and
    decoded images."""
    t = streams.scan_stamps_s
    if rate_hz is None or len(t) < 3:
        return streams
    key = f"targetless: scans at {rate_hz:g} Hz"
    if key in streams.results:
        out: Streams = streams.results[key]
        out.rig = streams.rig
        return out
    k = int((len(t) - 1) / max(float(t[-1] - t[0]), 1e-9) // rate_hz)
    if k <= 1:
        return streams
    seq = dataclasses.replace(streams.sequence, scans=streams.sequence.scans[::k])
    # The same images (one cache); the odometry's poses only (the steps' covariances are
    # most of its cost, and the check does not use them).
    out = Streams(
        seq,
        streams.rig,
        progress=streams.progress,
        use_wheel_odometry=streams.use_wheel_odometry,
        odometry_covariance=False,
        _image_cache=streams._image_cache,
    )
    streams.results[key] = out
    return out


# --- the problem ----------------------------------------------------------------------


def _se3_of_se2(T2: FloatArray) -> FloatArray:
    T = np.eye(4)
    T[:2, :2] = T2[:2, :2]
    T[:2, 3] = T2[:2, 2]
    return T


def _build_patches(rig: Rig, streams: Streams, s: TargetlessSettings) -> _Patches:
    cam = rig.camera
    frames = used_frames(streams.image_stamps_s, s.frame_rate_hz)
    # Frames before the first scan or after the last have no laser pose (it would be held
    # at the drive's ends, projecting the returns at the wrong place): left out.
    t_img, t_scan = streams.image_stamps_s, streams.scan_stamps_s
    frames = [f for f in frames if t_scan[0] <= t_img[f] <= t_scan[-1]]
    # The used frames decode on two other threads from here on, while the laser odometry
    # runs (its compiled ICP releases the interpreter), as far ahead as FRAMES_AHEAD_BYTES
    # allows; then while each frame's grids are made (decoding two at a time keeps both
    # cores busy where the grids would otherwise wait on the decoding).
    ahead = frames_ahead(cam.width_px, cam.height_px)
    with streams.images_ahead(frames, ahead, DECODE_THREADS) as decoded:
        return _patches_of(rig, streams, s, frames, decoded)


DECODE_THREADS = 2
"""Threads decoding the used frames ahead of the check's use."""
FRAME_PARTS_AHEAD = 4
"""Frames whose own work (:func:`_patches_of`) is under way ahead of their pairing."""


def _patches_of(
    rig: Rig, streams: Streams, s: TargetlessSettings, frames: list[int], decoded: Iterator[NDArray[np.uint8]]
) -> _Patches:
    """The patches of the used ``frames`` (decoded, in order, by ``decoded``)."""
    cam = rig.camera
    T0 = rig.T_cam_laser
    od = streams.laser_odometry()
    scan_t = streams.scan_stamps_s
    img_t = streams.image_stamps_s
    poses = poses_at(scan_t, od.poses, img_t[frames])
    travel = float(np.sum(np.linalg.norm(np.diff(poses[:, :2], axis=0), axis=1))) if len(frames) > 1 else 0.0
    heading = np.unwrap(poses[:, 2]) if len(frames) else np.zeros(0)
    info: dict[str, Any] = {
        "frames_used": len(frames),
        "travel_m": round(travel, 3),
        "heading_range_deg": round(float(np.degrees(np.ptp(heading))) if len(heading) else 0.0, 2),
    }
    if travel < s.min_travel_m:
        raise _CannotTellError(
            f"degenerate motion: the rig moved {travel:.2f} m over the drive; the check needs at "
            f"least {s.min_travel_m:g} m of travel (parallax between the frames)"
        )
    degenerate = od.degeneracy < DEGENERATE_BELOW
    degenerate[0] = False
    f_mean = float(np.mean(cam.intrinsics[:2]))
    h = s.patch_half
    grid = np.arange(-h, h + 1, dtype=float)
    ga, gb = (g.ravel() for g in np.meshgrid(grid, grid))
    frame_of_image = {img: k for k, img in enumerate(frames)}
    Xs, Ms, ii, jj, pairs, blocks, ratios, yaws, dts = [], [], [], [], [], [], [], [], []
    n_pairs = 0
    n_degenerate = 0
    seen_returns = 0
    feet_all: list[FloatArray] = []
    feet_img: list[NDArray[np.int64]] = []
    feet_block: list[NDArray[np.int64]] = []
    feet_world: list[FloatArray] = []
    gray_of: dict[int, NDArray[np.uint8]] = {}
    frames_in = iter(decoded)
    taken: dict[int, NDArray[np.uint8]] = {}
    n_taken = [0]
    failed: list[BaseException] = []
    take = threading.Lock()

    def gray_at(k: int) -> NDArray[np.uint8]:
        """Frame k's image: the decoded frames are taken in order, whichever thread asks. A
        frame that does not decode (its error) fails every frame from it on, so the error
        comes out at that frame's place whichever thread took it."""
        with take:
            while n_taken[0] <= k:
                if failed:
                    raise failed[0]
                try:
                    taken[n_taken[0]] = next(frames_in)
                except BaseException as exc:
                    failed.append(exc)
                    raise
                n_taken[0] += 1
            return taken.pop(k)

    def frame_parts(k: int) -> tuple[NDArray[np.uint8], list[int], int, FloatArray | None, FloatArray | None]:
        """Frame k's own work (its image, its partners, the pairs left out as degenerate,
        its edges' feet, its grids), on two other threads a few frames ahead of the
        pairing below (the scans' lines, OpenCV's sampling and the kernels run outside
        the interpreter's lock); each frame's work depends on that frame alone."""
        i = frames[k]
        gray = gray_at(k)
        t_i = float(img_t[i])
        partners = []
        skipped = 0
        for gap in s.gaps_s:
            j = nearest_index(img_t, t_i + gap)
            if j == i or j not in frame_of_image or abs(float(img_t[j]) - t_i - gap) > 0.5 * gap:
                continue
            k0, k1 = nearest_index(scan_t, t_i), nearest_index(scan_t, float(img_t[j]))
            if degenerate[k0 + 1 : k1 + 1].any():
                skipped += 1
                continue
            partners.append(j)
        feet = _frame_edges(streams, i, T0, cam, s) if s.edges else None
        X = _frame_grid(streams, i, gray, T0, cam, s, f_mean, ga, gb) if partners else None
        return gray, partners, skipped, feet, X

    # Left early (an error), the frames not yet started are dropped.
    with Ahead(frame_parts, len(frames), FRAME_PARTS_AHEAD, workers=2) as parts:
        for k, (gray, partners, skipped, feet, X) in parts:
            i = frames[k]
            streams.report("targetless check: frames", k + 1, len(frames))
            t_i = float(img_t[i])
            n_degenerate += skipped
            if feet is not None and len(feet):
                feet_all.append(feet)
                feet_img.append(np.full(len(feet), i))
                feet_block.append(np.full(len(feet), int((t_i - float(img_t[frames[0]])) // s.block_s)))
                P_w = se2(poses[k])
                feet_world.append(feet @ P_w[:2, :2].T + P_w[:2, 2])
                gray_of[i] = gray
            if X is None:
                continue
            seen_returns += len(X)
            P_i = se2(poses[k])
            block = int((t_i - float(img_t[frames[0]])) // s.block_s)
            for j in dict.fromkeys(partners):
                P_j = se2(poses[frame_of_image[j]])
                M = _se3_of_se2(np.linalg.inv(P_j) @ P_i)
                # Keep the grids wholly inside image j under the stored T (margin for the blur).
                Y = X @ M[:3, :3].T + M[:3, 3]
                q = cam.project((Y @ T0[:3, :3].T + T0[:3, 3]).reshape(-1, 3)).reshape(len(X), -1, 2)
                inside = cam.in_image(q.reshape(-1, 2), margin_px=8.0).reshape(len(X), -1).all(axis=1)
                if inside.sum() < 5:
                    continue
                n = int(inside.sum())
                z_i = X[inside, X.shape[1] // 2] @ T0[2, :3] + T0[2, 3]
                z_j = Y[inside, X.shape[1] // 2] @ T0[2, :3] + T0[2, 3]
                ratios.append(z_i / z_j)
                yaws.append(np.full(n, float(np.arctan2(M[1, 0], M[0, 0]))))
                dts.append(np.full(n, float(img_t[j]) - t_i))
                Xs.append(X[inside])
                Ms.append(np.broadcast_to(M, (n, 4, 4)))
                ii.append(np.full(n, i))
                jj.append(np.full(n, j))
                pairs.append(np.full(n, n_pairs))
                blocks.append(np.full(n, block))
                n_pairs += 1
    info |= {"pairs": n_pairs, "pairs_degenerate": n_degenerate}
    if not Xs or sum(len(x) for x in Xs) < s.min_returns:
        got = sum(len(x) for x in Xs)
        raise _CannotTellError(
            "no overlap: "
            + (
                f"{got} textured laser returns on walls project into frames that see them twice "
                f"(at least {s.min_returns} needed)"
                if seen_returns
                else "no laser return on a wall falls inside the camera's image under the stored T_cam_laser"
            )
        )
    block_of = np.concatenate(blocks)
    edge_block = np.concatenate(feet_block) if feet_block else np.zeros(0, np.int64)
    used_blocks = np.unique(np.r_[block_of, edge_block])
    info |= {"patches": len(block_of), "blocks": len(used_blocks), "edges": len(edge_block)}
    if len(used_blocks) < s.min_blocks:
        raise _CannotTellError(
            f"too short: {len(used_blocks)} blocks of {s.block_s:g} s with usable frame pairs; at least "
            f"{s.min_blocks} are needed (a drive of about {s.min_blocks * s.block_s:g} s seeing "
            "textured walls)"
        )
    remap = {b: n for n, b in enumerate(used_blocks)}
    edges = None
    if feet_all:
        feet = np.concatenate(feet_all)
        corner = corner_clusters(np.concatenate(feet_world))
        edges = Edges(
            band_points(feet),
            np.concatenate(feet_img),
            np.array([remap[b] for b in edge_block], dtype=np.int64),
            corner,
            np.linalg.norm(feet, axis=1),
        )
        depth = np.array([np.mean(edges.depth_m[corner == c]) for c in range(int(corner.max()) + 1)])
        info["edge_corners"] = len(depth)
        info["edge_depth_m"] = [round(float(np.quantile(depth, q)), 2) for q in (0.1, 0.9)]
    return _Patches(
        np.concatenate(Xs),
        np.concatenate(Ms),
        np.concatenate(ii),
        np.concatenate(jj),
        np.concatenate(pairs),
        np.concatenate(ratios),
        np.concatenate(yaws),
        np.concatenate(dts),
        np.array([remap[b] for b in block_of], dtype=np.int64),
        n_pairs,
        info,
        edges,
        gray_of,
    )


def _frame_grid(
    streams: Streams,
    i: int,
    gray: NDArray[np.uint8],
    T0: FloatArray,
    cam: Any,
    s: TargetlessSettings,
    f_mean: float,
    ga: FloatArray,
    gb: FloatArray,
) -> FloatArray | None:
    """(R, S, 3) grids on the walls around image i's (``gray``) chosen returns (laser frame
    at the image's stamp), or None when none is usable."""
    k, T_img_scan = streams.scan_to_image(i)
    scan = streams.scans[k]
    labels = return_labels(scan, streams.lines(k))
    pts = snap_to_lines(scan.points[scan.valid], labels, 0.03)
    pts = pts @ T_img_scan[:2, :2].T + T_img_scan[:2, 2]
    _, normals = line_fits(pts, labels)
    # Returns on a line, not its two outermost on either end (a corner, an edge).
    lab = labels
    first = np.r_[True, lab[1:] != lab[:-1]]
    last = np.r_[lab[1:] != lab[:-1], True]
    near_end = first | last | np.r_[False, first[:-1]] | np.r_[last[1:], False]
    r = np.linalg.norm(pts, axis=1)
    ok = (lab >= 0) & ~near_end & (r >= s.min_range_m) & (r <= s.max_range_m) & np.isfinite(normals[:, 0])
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return None
    p3 = np.column_stack([pts[idx], np.zeros(len(idx))])
    P = p3 @ T0[:3, :3].T + T0[:3, 3]
    front = P[:, 2] > 0.2
    idx, p3, P = idx[front], p3[front], P[front]
    if len(idx) == 0:
        return None
    q = cam.project(P)
    margin = (s.patch_half * s.patch_step_px) + 8.0
    inside = cam.in_image(q, margin_px=margin)
    idx, p3, P, q = idx[inside], p3[inside], P[inside], q[inside]
    if len(idx) == 0:
        return None
    tang = np.column_stack([-normals[idx, 1], normals[idx, 0], np.zeros(len(idx))])
    step_m = s.patch_step_px * P[:, 2] / f_mean
    up = np.array([0.0, 0.0, 1.0])
    X = (
        p3[:, None, :]
        + (ga[None, :, None] * step_m[:, None, None]) * tang[:, None, :]
        + (gb[None, :, None] * step_m[:, None, None]) * up[None, None, :]
    )
    # Texture: the grid's grey levels in image i under the stored T.
    qs = cam.project((X @ T0[:3, :3].T + T0[:3, 3]).reshape(-1, 3))
    v = _sample_grey(gray, qs).reshape(len(X), -1)
    textured = np.nanstd(v, axis=1) >= s.min_texture
    X = X[textured]
    if len(X) == 0:
        return None
    if len(X) > s.returns_per_frame:
        X = X[np.linspace(0, len(X) - 1, s.returns_per_frame).round().astype(int)]
    out: FloatArray = X
    return out


def _frame_edges(streams: Streams, i: int, T0: FloatArray, cam: Any, s: TargetlessSettings) -> FloatArray:
    """(N, 2) the feet of the vertical edges in image i's scan (laser frame at the image's
    stamp) with a height band projecting inside the image under the stored T, with room
    for the edge's search window (:func:`rigcal.drift.edges.scan_discontinuities`)."""
    k, T_img_scan = streams.scan_to_image(i)
    feet = scan_discontinuities(streams.scans[k], streams.lines(k))
    if not len(feet):
        return feet
    feet = feet @ T_img_scan[:2, :2].T + T_img_scan[:2, 2]
    r = np.linalg.norm(feet, axis=1)
    feet = feet[(r >= s.min_range_m) & (r <= s.max_range_m)]
    if not len(feet):
        return feet
    X = band_points(feet)
    P = X.reshape(-1, 3) @ T0[:3, :3].T + T0[:3, 3]
    q = cam.project(P)
    ok = (P[:, 2] > 0.2) & cam.in_image(q, margin_px=max(s.edge_window_px) + BAND_MARGIN_PX)
    out: FloatArray = feet[ok.reshape(len(feet), -1).any(axis=1)]
    return out


def _sample_grey(gray: NDArray[np.uint8], q: FloatArray) -> FloatArray:
    """:func:`_sample` of an 8-bit image at q, the image cut to the points' rows and
    columns first (2 px around them: every pixel the bilinear reads) so that only those
    are made float; the same values as sampling the whole image but for the float32
    rounding of the shifted coordinates (under 0.01 grey level)."""
    ok = np.isfinite(q).all(axis=1)
    if not ok.any():
        return np.full(len(q), np.nan)
    h, w = gray.shape
    u0, v0 = np.clip(np.floor(q[ok].min(axis=0)).astype(int) - 2, 0, [w, h])
    u1, v1 = np.clip(np.ceil(q[ok].max(axis=0)).astype(int) + 3, 0, [w, h])
    if u1 - u0 < 2 or v1 - v0 < 2:
        return _sample(gray.astype(np.float32), q)
    return _sample(gray[v0:v1, u0:u1].astype(np.float32), q - [u0, v0])


def _sample(img: NDArray[np.float32], q: FloatArray) -> FloatArray:
    """Bilinear samples at sub-pixel points (pixel centres at integers; NaN outside)."""
    qf = np.nan_to_num(q, nan=-1e6).astype(np.float32)
    out = cv2.remap(
        img, qf[:, 0:1], qf[:, 1:2], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan
    )
    return np.asarray(out, dtype=np.float64).ravel()


# --- the estimate ---------------------------------------------------------------------

# Blur levels: the nearer frame of a pair is blurred by the view's change of scale more, so
# that both frames see the wall's texture through the same blur in metres (a fixed blur
# in pixels shows the nearer frame sharper, a difference no T explains). Level k blurs
# the image to LEVEL_STEP**k times the stage's blur in all.
LEVEL_STEP = 1.1
LEVELS = 8
_FIXED = 5  # laser z: never observed by a planar drive (module docstring, step 6)
# The odometry's errors, per unit: scale 0.1 %, yaw scale 0.1 %, yaw rate 1 mrad/s, pivot 1 mm,
# crab angle 1 mrad.
_NUISANCE_UNITS = (1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3)
PRIOR_UNITS = 10.0  # the weak prior's sigma, in resolutions (and odometry error units)


ODOMETRY_HELD = 1e8
"""The prior's information (per odometry error unit squared) that holds the odometry's
errors at zero on every scan's odometry (:func:`_prior`)."""


def _prior(hold_odometry: bool) -> FloatArray:
    """(11, 11) the prior's information on the free parameters (xi without laser z in
    resolutions, the odometry's errors in their units): weak on xi (``PRIOR_UNITS``); on
    the odometry's errors as weak, or, on every scan's odometry (``hold_odometry``),
    holding them at zero (:data:`ODOMETRY_HELD`). There the photometric term does not
    estimate them: its model's hundredth-pixel errors pulled them along one ridge of
    its cost with the camera's yaw and sideways shift (the yaw 0.14 deg off, root mean
    square on development drives), and a prior of the size every scan's odometry errs
    by (root mean square 0.19 % scale, 0.07 % yaw scale, 0.3 mrad/s, 5.6 and 5.2 mm
    pivot, 0.9 mrad crab on development drives), even weighed up 50 times, did not hold
    them: the pivot went to 23 mm, the crab to 3 mrad and the yaw stayed off (-0.08 to
    -0.31 deg; docs/benchmarks.md, "The targetless check: the odometry's errors held
    where the photometric term judges alone"). What every scan's odometry really errs
    by then passes into T, and is counted in the photometric floor (``photo_floor_deg``,
    derived on development drives with them held)."""
    odometry = np.full(6, ODOMETRY_HELD if hold_odometry else 1.0 / PRIOR_UNITS**2)
    out: FloatArray = np.diag(np.r_[np.full(5, 1.0 / PRIOR_UNITS**2), odometry])
    return out


def _levels(ratio: FloatArray) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """(P,) blur levels of frame i and of frame j of each patch."""
    step = math.log(LEVEL_STEP)
    li = np.clip(np.round(np.log(np.maximum(1.0 / ratio, 1.0)) / step), 0, LEVELS - 1).astype(np.int64)
    lj = np.clip(np.round(np.log(np.maximum(ratio, 1.0)) / step), 0, LEVELS - 1).astype(np.int64)
    return li, lj


DOWNSAMPLE_BLUR_PX = 2.5
"""A stage whose blur (1 sigma, with the camera's own) is at least this is read from
images of half the size (a quarter of the blurring and the memory; the blur still spans
more than a pixel of the smaller image)."""


BAND_MARGIN_PX = 24.0
"""The stacks hold the band of rows the patches fall in under the stored T, this much
wider on either side (a correction of 2 deg moves a return about 18 px)."""


class _Images:
    """The blurred images of a stage: every (image, blur level) the patches read, in one
    stack (:class:`rigcal.drift.blur_stack.BlurStack`), grey levels x 64 as uint16 (an
    eighth of float64's memory, 1/64 grey level steps), the band of rows the patches
    fall in only, each made only around its patches (widened where a read needs more);
    half size when the stage's blur is wide. A stage's stack made ahead
    (:func:`_stacks_ahead`) is taken as it is."""

    def __init__(
        self, streams: Streams, patches: _Patches, rows: tuple[float, float], blur_px: float, native_px: float
    ) -> None:
        ahead = patches.stacks_ahead.pop((rows, blur_px, native_px), None)
        made: _Stack = (
            ahead.result() if ahead is not None else _stack(streams, patches, rows, blur_px, native_px)
        )
        self.down, self.key_i, self.key_j, self.row0, self.stack = made

    def widen(self, keys: NDArray[np.int64], need: NDArray[np.int64]) -> None:
        """Make the images ``keys`` over the regions ``need`` reads fall in (beyond
        their boxes), :data:`BOX_MARGIN_PX` wider."""
        assert self.stack is not None
        self.stack.widen(keys, need, math.ceil(BOX_MARGIN_PX / self.down))


_Stack = tuple[int, NDArray[np.int64], NDArray[np.int64], int, BlurStack | None]

BOX_MARGIN_PX = 8.0
"""Each blurred image is first made over the box its patches' samples fall in under the
stored T, this much wider on every side (full-size pixels): the correction moves them
by a few pixels; a read beyond its box widens it (the same values, made later)."""


def _stack(
    streams: Streams, patches: _Patches, rows: tuple[float, float], blur_px: float, native_px: float
) -> _Stack:
    """A stage's stack (:class:`_Images`): (downsampling, key of frame i and of frame j of
    each patch, first row, the stack); its images are blurred on two threads (OpenCV
    releases the interpreter), each over its patches' box."""
    total = math.hypot(blur_px, native_px)
    down = 2 if total >= DOWNSAMPLE_BLUR_PX else 1
    li, lj = _levels(patches.ratio)
    keys = np.unique(np.r_[patches.img_i * LEVELS + li, patches.img_j * LEVELS + lj])
    key_i = np.searchsorted(keys, patches.img_i * LEVELS + li)
    key_j = np.searchsorted(keys, patches.img_j * LEVELS + lj)
    # A pixel (u, v) of a half-size image is the mean of full-size pixels (2u, 2v) to
    # (2u + 1, 2v + 1): a box of 2 pixels adds a variance of 0.25 pixel^2 to the blur.
    base = native_px**2 + (0.25 if down > 1 else 0.0)
    sigmas = [math.sqrt(max((total * LEVEL_STEP**k) ** 2 - base, 0.04)) / down for k in range(LEVELS)]
    height = streams.rig.camera.height_px // down if streams.rig is not None else 0
    lo = max(math.floor((rows[0] - BAND_MARGIN_PX - 0.5) / down), 0)
    hi = min(math.ceil((rows[1] + BAND_MARGIN_PX - 0.5) / down) + 1, height)
    if not len(keys):
        return down, key_i, key_j, lo, None
    width = streams.image(int(keys[0] // LEVELS)).shape[1] // down

    def source(img: int, a: int, b: int) -> NDArray[np.uint16]:
        """Rows a:b of image img, grey levels x 64, of half size when the stage is."""
        full = streams.image(img)
        if down == 1:
            out: NDArray[np.uint16] = full[a:b].astype(np.uint16) * np.uint16(GREY_SCALE)
            return out
        # A half-size pixel is the mean of its 2 x 2 full-size pixels (OpenCV's area
        # resize at a scale of exactly 2): the rows' own, for an image of even size.
        even = full.shape[0] % 2 == 0 and full.shape[1] % 2 == 0
        g = (full[2 * a : 2 * b] if even else full).astype(np.uint16) * np.uint16(GREY_SCALE)
        half = (g.shape[1] // 2, g.shape[0] // 2)
        g = np.asarray(cv2.resize(g, half, interpolation=cv2.INTER_AREA), dtype=np.uint16)
        return g if even else g[a:b]

    stack = BlurStack(keys // LEVELS, np.array(sigmas)[keys % LEVELS], lo, hi - lo, width, source, height)
    assert streams.rig is not None
    stack.fill(_boxes(streams.rig, patches, key_i, key_j, len(keys), down, lo))
    return down, key_i, key_j, lo, stack


def _boxes(
    rig: Rig,
    patches: _Patches,
    key_i: NDArray[np.int64],
    key_j: NDArray[np.int64],
    n_keys: int,
    down: int,
    row0: int,
) -> NDArray[np.int64]:
    """(K, 4) each key's box (rows r0:r1, columns c0:c1 of the stack): the pixels its
    patches' samples read under the stored T (:func:`_projected`), :data:`BOX_MARGIN_PX`
    wider."""
    box = np.zeros((n_keys, 4))
    box[:, 0] = box[:, 2] = np.inf
    box[:, 1] = box[:, 3] = -np.inf
    m = BOX_MARGIN_PX / down + GRAD_STEP_PX
    for q, key in zip(_projected(rig, patches), (key_i, key_j), strict=True):
        u = (q[..., 0] - 0.5) / down if down > 1 else q[..., 0]
        v = ((q[..., 1] - 0.5) / down if down > 1 else q[..., 1]) - row0
        with np.errstate(invalid="ignore"):
            np.minimum.at(box[:, 0], key, np.nanmin(v, axis=1) - m)
            np.maximum.at(box[:, 1], key, np.nanmax(v, axis=1) + m)
            np.minimum.at(box[:, 2], key, np.nanmin(u, axis=1) - m)
            np.maximum.at(box[:, 3], key, np.nanmax(u, axis=1) + m)
    empty = ~np.isfinite(box).all(axis=1)
    box[empty] = 0.0
    out = np.empty((n_keys, 4), dtype=np.int64)
    out[:, 0] = np.floor(box[:, 0])
    out[:, 1] = np.floor(box[:, 1]) + 2
    out[:, 2] = np.floor(box[:, 2])
    out[:, 3] = np.floor(box[:, 3]) + 2
    out[empty] = 0
    return out


def _stacks_ahead(rig: Rig, streams: Streams, patches: _Patches, s: TargetlessSettings) -> ThreadPoolExecutor:
    """Start making, on a second thread, the edges' blurred frames of every stage (the
    first stage's while the calling thread makes its stack) and the stacks of the stages
    after the first (while the first stage iterates); returns the pool, to shut down after
    the estimate. Each is taken by :class:`_Images` and :func:`_edge_images` as made."""
    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="stages")
    for stage, blur in enumerate(s.blur_px):
        if s.edges and patches.edges is not None:
            edge_blur = math.hypot(blur, s.native_blur_px)
            patches.stacks_ahead[("edges", edge_blur)] = pool.submit(_edge_stack, rig, patches, edge_blur, s)
        if stage > 0:
            rows = _rows(rig, patches)  # after the first edges' frames are under way
            key = (rows, blur, s.native_blur_px)
            patches.stacks_ahead[key] = pool.submit(_stack, streams, patches, rows, blur, s.native_blur_px)
    return pool


def _edge_images(
    rig: Rig, patches: _Patches, blur_px: float, s: TargetlessSettings
) -> Future[EdgeImages] | None:
    """The edges' frames blurred by ``blur_px`` in all (as made ahead, possibly still
    under way; else made here), or None without edges."""
    if patches.edges is None:
        return None
    ahead: Future[EdgeImages] | None = patches.stacks_ahead.pop(("edges", blur_px), None)
    if ahead is not None:
        return ahead
    made: Future[EdgeImages] = Future()
    made.set_result(_edge_stack(rig, patches, blur_px, s))
    return made


def _edge_stack(rig: Rig, patches: _Patches, blur_px: float, s: TargetlessSettings) -> EdgeImages:
    """The edges' frames blurred by ``blur_px``, each over the box its search reads."""
    assert patches.edges is not None
    boxes = search_boxes(rig.camera, rig.T_cam_laser, patches.edges, max(s.edge_window_px))
    return EdgeImages(patches.gray_of, patches.edges.img, blur_px, _edge_rows(rig, patches.edges), boxes)


def _rows(rig: Rig, patches: _Patches) -> tuple[float, float]:
    """The image rows the patches fall in, in both frames, under the stored T (made once
    per patches)."""
    if patches.rows is None:
        patches.rows = _rows_of(rig, patches)
    return patches.rows


def _rows_of(rig: Rig, patches: _Patches) -> tuple[float, float]:
    v = np.concatenate([q[..., 1].ravel() for q in _projected(rig, patches)])
    v = v[np.isfinite(v)]
    return (float(v.min()), float(v.max())) if len(v) else (0.0, float(rig.camera.height_px))


def _projected(rig: Rig, patches: _Patches) -> tuple[FloatArray, FloatArray]:
    """(P, S, 2) the patches' samples in frame i and in frame j under the stored T
    (pixels), made once per patches."""
    if patches.projected is None:
        T = rig.T_cam_laser
        X = patches.X.reshape(-1, 3)
        Y = patches.X @ patches.M[:, :3, :3].transpose(0, 2, 1) + patches.M[:, None, :3, 3]
        Y = Y.reshape(-1, 3)
        q = rig.camera.project(np.concatenate([X, Y]) @ T[:3, :3].T + T[:3, 3])
        P, S, _ = patches.X.shape
        patches.projected = (q[: P * S].reshape(P, S, 2), q[P * S :].reshape(P, S, 2))
    return patches.projected


def _residuals(
    rig: Rig, T: FloatArray, nuis: FloatArray, patches: _Patches, images: _Images
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """(P, S) residuals, (P, S, 12) their derivatives with respect to a right update of T
    (T Exp(w, v), laser frame) and to the odometry's errors ``nuis`` (its scale, its yaw's
    scale, its yaw rate's bias, its pivot: a translation (R - I) l for a turn R, its crab
    angle: the step turned about z), (P,) usable patches.

    Above :data:`SPLIT_PATCHES_ABOVE` patches, in two halves of the patches on two threads
    (numpy and the sampling kernel release the interpreter); each patch's values are its
    own but for the pairs' gains, summed over the whole in patch order as in one pass: the
    same numbers."""
    Pn, S, _ = patches.X.shape
    r = np.empty((Pn, S))
    J = np.empty((Pn, S, 12))
    usable = np.empty(Pn, dtype=bool)
    a0 = np.empty((Pn, S))
    Ja = np.empty((Pn, S, 6))
    halves = [slice(0, Pn)] if Pn <= SPLIT_PATCHES_ABOVE else [slice(0, Pn // 2), slice(Pn // 2, Pn)]

    def first(h: slice) -> None:
        _frames_terms(rig, T, nuis, patches, images, h, r, J, usable, a0, Ja)

    def second(h: slice) -> None:
        # r = b0 gain - a0; J = Jb0 gain - Ja0, in place (frame i's columns past the sixth
        # are zero).
        g = gain[h][:, None]
        r[h] *= g
        r[h] -= a0[h]
        J[h] *= g[:, :, None]
        J[h, :, :6] -= Ja[h]

    if len(halves) == 1:
        first(halves[0])
    else:
        with ThreadPoolExecutor(max_workers=2, thread_name_prefix="residuals") as pool:
            list(pool.map(first, halves))
    # The pair's gain (the automatic exposure): the square root of the ratio of the
    # zero-mean patches' energies (r holds frame j's zero-mean patches here).
    ea = np.bincount(patches.pair, np.where(usable, (a0**2).sum(axis=1), 0.0), patches.n_pairs)
    eb = np.bincount(patches.pair, np.where(usable, (r**2).sum(axis=1), 0.0), patches.n_pairs)
    gain = np.sqrt(np.where(eb > 0, ea / np.where(eb > 0, eb, 1.0), 1.0))[patches.pair]
    if len(halves) == 1:
        second(halves[0])
    else:
        with ThreadPoolExecutor(max_workers=2, thread_name_prefix="residuals") as pool:
            list(pool.map(second, halves))
    return r, J, usable


SPLIT_PATCHES_ABOVE = 2000
"""More patches than this have their residuals made in two halves on two threads."""


def _frames_terms(
    rig: Rig,
    T: FloatArray,
    nuis: FloatArray,
    patches: _Patches,
    images: _Images,
    h: slice,
    b0: FloatArray,
    Jb: FloatArray,
    usable: NDArray[np.bool_],
    a0: FloatArray,
    Ja: FloatArray,
) -> None:
    """:func:`_residuals`' per-patch part for the patches ``h``: frame j's zero-mean
    patches into ``b0[h]`` and their derivatives into ``Jb[h]`` (12 columns), frame i's
    into ``a0[h]`` and ``Ja[h]`` (6: T only, the odometry's errors move frame j alone),
    ``usable[h]``."""
    cam = rig.camera
    X = patches.X[h]
    M = patches.M[h]
    yaw, dt = patches.yaw[h], patches.dt[h]
    Pn, S, _ = X.shape
    eps, kappa, bias, lx, ly, crab = nuis
    R_I = M[:, :3, :3] - np.eye(3)
    t0 = M[:, :3, 3]
    crabbed = t0 + crab * np.column_stack([-t0[:, 1], t0[:, 0], np.zeros(len(t0))])
    t_M = crabbed * (1.0 + eps) + R_I @ np.array([lx, ly, 0.0])
    RX = X @ M[:, :3, :3].transpose(0, 2, 1)
    turn = yaw * kappa + dt * bias
    c, sn = np.cos(turn)[:, None], np.sin(turn)[:, None]
    RX = np.stack([c * RX[..., 0] - sn * RX[..., 1], sn * RX[..., 0] + c * RX[..., 1], RX[..., 2]], axis=-1)
    Y = RX + t_M[:, None, :]
    out_v = []
    assert images.stack is not None
    Jb_h = Jb[h]
    Ja_h = Ja[h]
    for pts, key, J in ((X, images.key_i[h], Ja_h), (Y, images.key_j[h], Jb_h)):
        which = np.repeat(key, S)
        v, d_point, d_rot = project_sample(
            pts.reshape(-1, 3), T[:3, :3], T[:3, 3], cam, images.stack.stack, which, images.down, images.row0,
            images.stack.box, images.widen,
        )  # fmt: skip
        # x' = Exp(w) x + v: d grey / d w = x cross d grey / d x, d grey / d v = d grey / d x.
        J[:, :, :3] = d_rot.reshape(Pn, S, 3)
        J[:, :, 3:6] = d_point.reshape(Pn, S, 3)
        out_v.append(v.reshape(Pn, S))
    a, b = out_v
    # The odometry's errors move frame j's points: its scale along the step (d y / d eps =
    # t_M), its yaw about the laser's z (d y / d turn = z cross R x).
    gRb = Jb_h[:, :, 3:6]
    Jb_h[:, :, 6] = (gRb @ M[:, :3, 3:4])[..., 0]
    d_turn = gRb[..., 1] * RX[..., 0] - gRb[..., 0] * RX[..., 1]
    Jb_h[:, :, 7] = d_turn * yaw[:, None]
    Jb_h[:, :, 8] = d_turn * dt[:, None]
    Jb_h[:, :, 9:11] = gRb @ R_I[:, :, :2]
    Jb_h[:, :, 11] = gRb[..., 1] * t0[:, None, 0] - gRb[..., 0] * t0[:, None, 1]
    ok = np.isfinite(a).all(axis=1) & np.isfinite(b).all(axis=1)
    unusable = ~ok
    usable[h] = ok
    for arr in (a, b, Ja_h, Jb_h):  # in place: these arrays are this call's own
        arr[unusable] = 0.0
    # Zero-mean patches (an offset between the frames drops out).
    a0[h] = a - a.mean(axis=1, keepdims=True)
    b0[h] = b - b.mean(axis=1, keepdims=True)
    Ja_h -= Ja_h.mean(axis=1, keepdims=True)
    Jb_h -= Jb_h.mean(axis=1, keepdims=True)


def _weights(r: FloatArray, usable: NDArray[np.bool_], med: float | None = None) -> tuple[FloatArray, float]:
    """Cauchy weights per patch (or edge band) from its mean squared residual
    (occlusions, a patch across an edge or off the wall weigh little), and the median
    they are scaled by (given: that one, so that two estimates weigh alike)."""
    e = (r**2).mean(axis=1)
    if med is None:
        med = float(np.median(e[usable])) if usable.any() else 1.0
    w = 1.0 / (1.0 + e / (4.0 * max(med, 1e-9)))
    return np.where(usable, w, 0.0), med


def _variance(r: FloatArray, w: FloatArray) -> float:
    """The weighted residual variance (each patch's samples weighed by its weight)."""
    wf = np.repeat(w, r.shape[1])
    return float(np.sum(wf * r.ravel() ** 2) / max(np.sum(wf), 1.0))


@dataclass
class _Terms:
    """Both terms evaluated at one (T, odometry errors): the photometric residuals (P, S)
    with their derivatives (P, S, K) over the free parameters; the edge bands' (N,) and
    (N, K), or None when the edges are not used; where each band's edge was found."""

    r: FloatArray
    J: FloatArray
    usable: NDArray[np.bool_]
    er: FloatArray | None = None
    eJ: FloatArray | None = None
    eusable: NDArray[np.bool_] | None = None
    found: FloatArray | None = None


@dataclass(frozen=True)
class _Scales:
    """The robust weights' medians and each term's residual variance, fixed for one
    step so that the step's trial point is weighed as its start was."""

    photo_med: float
    photo_var: float
    edge_med: float = math.nan
    edge_var: float = math.nan


def _scales(t: _Terms) -> _Scales:
    w, med = _weights(t.r, t.usable)
    var = max(_variance(t.r, w), 1e-12)
    if t.er is None or t.eusable is None:
        return _Scales(med, var)
    we, emed = _weights(t.er[:, None], t.eusable)
    return _Scales(med, var, emed, max(_variance(t.er[:, None], we), 1e-12))


def _system(t: _Terms, sc: _Scales, keep: NDArray[np.bool_]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The normal equations of both terms (module docstring, step 4): A (K, K), g (K,)
    and the symmetric information H_sym (K, K). Each term is weighed by its own noise
    (its weighted residual variance: grey levels, pixels). With edges, the photometric
    term's equations for the yaw and the translations are dropped (their rows ``~keep``):
    they are confounded with the odometry's errors (its crab angle and pivot take up a
    shifted or turned camera); its dependence on them stays (A is not symmetric), so the
    covariance counts how the edges' errors move its roll and pitch."""
    w, _ = _weights(t.r, t.usable, sc.photo_med)
    K = t.J.shape[2]
    Jf = t.J.reshape(-1, K)
    wf = np.repeat(w, t.r.shape[1])
    H = (Jf * wf[:, None]).T @ Jf / sc.photo_var
    g = Jf.T @ (wf * t.r.ravel()) / sc.photo_var
    if t.er is None or t.eJ is None or t.eusable is None:
        return H, g, H
    we, _ = _weights(t.er[:, None], t.eusable, sc.edge_med)
    He = (t.eJ * we[:, None]).T @ t.eJ / sc.edge_var
    ge = t.eJ.T @ (we * t.er) / sc.edge_var
    A = np.where(keep[:, None], H, 0.0) + He
    H_sym = np.where(keep[:, None] & keep[None, :], H, 0.0) + He
    return A, np.where(keep, g, 0.0) + ge, H_sym


def _cluster_parts(
    t: _Terms, sc: _Scales, keep: NDArray[np.bool_], patches: _Patches
) -> tuple[FloatArray, FloatArray, int, int]:
    """Each cluster's part of A and of g (:func:`_system`): (G, K, K), (G, K). The
    clusters: the photometric patches of each block of the drive (they share the
    odometry's errors and the exposure), and the edge bands of each physical corner
    (:func:`rigcal.drift.edges.corner_clusters`: one corner's errors are one error,
    however many frames see it). Also the counts of blocks and corners."""
    w, _ = _weights(t.r, t.usable, sc.photo_med)
    Jw = t.J * (w[:, None, None] / sc.photo_var)
    Hp = np.einsum("psk,psl->pkl", Jw, t.J)
    gp = np.einsum("psk,ps->pk", Jw, t.r)
    if t.er is not None:
        Hp[:, ~keep, :] = 0.0
        gp[:, ~keep] = 0.0
    parts_A, parts_g = [], []
    blocks = np.unique(patches.block[t.usable & (w > 0)])
    for b in blocks:
        m = patches.block == b
        parts_A.append(Hp[m].sum(axis=0))
        parts_g.append(gp[m].sum(axis=0))
    n_corners = 0
    if t.er is not None and t.eJ is not None and t.eusable is not None and patches.edges is not None:
        we, _ = _weights(t.er[:, None], t.eusable, sc.edge_med)
        B = len(t.er) // len(patches.edges.img)
        corner = np.repeat(patches.edges.corner, B)
        eJw = t.eJ * (we / sc.edge_var)[:, None]
        for c in np.unique(corner[t.eusable & (we > 0)]):
            m = corner == c
            parts_A.append(eJw[m].T @ t.eJ[m])
            parts_g.append(eJw[m].T @ t.er[m])
            n_corners += 1
    K = t.J.shape[2]
    return (
        np.array(parts_A).reshape(-1, K, K),
        np.array(parts_g).reshape(-1, K),
        len(blocks),
        n_corners,
    )


@dataclass(frozen=True)
class _Estimate:
    """xi (6,) laser frame; its covariance in resolution units (6, 6; laser z's row and
    column zero: held); the odometry's errors; the clusters; the directions determined."""

    xi: FloatArray
    cov_z: FloatArray
    odometry: FloatArray  # (6,) the odometry's scale, yaw scale, yaw rate bias (rad/s), pivot (m), crab
    odometry_sigma: FloatArray
    blocks: int  # photometric clusters (blocks of the drive)
    corners: int  # edge clusters (physical corners)
    moves: FloatArray  # (G, 6) each cluster's leave-one-out move of xi, resolution units
    determined: FloatArray  # (6, m) basis, resolution units
    edge_stats: dict[str, Any] = field(default_factory=dict)  # the edge term's at the estimate
    solve: dict[str, Any] = field(default_factory=dict)  # steps taken, refused, the last step
    # (6, 6) the information on xi (resolution units) once the odometry's errors are free:
    # how well the drive's design determines each direction, whatever its residuals.
    information: FloatArray = field(default_factory=lambda: np.eye(6))
    # The linearised problem the jackknife and the bootstrap work on (free parameters: xi
    # without laser z, then the odometry's errors; resolution and odometry error units):
    # the normal matrix (K, K), each cluster's part of it (G, K, K) and of the gradient (G, K).
    normal: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    cluster_normal: FloatArray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    cluster_gradient: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))


SETTLED_UNITS = 0.01
"""A step on T (resolution units, largest over the calibration's axes) below which the
estimate has settled: the stage stops iterating."""
RUNAWAY_UNITS = 0.3
"""The last accepted step (resolution units, largest over the calibration's axes) above
which the estimate has not settled: the verdict is "cannot tell"."""
MAX_TRIES = 4
"""Steps tried per iteration (each refusal raises the damping tenfold)."""


def _evaluate(
    rig: Rig,
    T: FloatArray,
    nuis: FloatArray,
    patches: _Patches,
    images: _Images,
    edge_images: Future[EdgeImages] | None,
    anchor: FloatArray | None,
    window_px: float,
    free: list[int],
    s: TargetlessSettings,
) -> _Terms:
    edges = patches.edges
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="edge-terms") as pool:
        # The edge term on a second thread beside the photometric one (both mostly numpy
        # and compiled code outside the interpreter's lock; independent of each other),
        # there waiting for its frames if they are still being blurred.
        def edge_term(images: Future[EdgeImages], edges: Edges) -> tuple[Any, ...]:
            return edge_residuals(rig.camera, T, edges, images.result(), window_px, anchor)

        edge_terms = None
        if edge_images is not None and edges is not None:
            edge_terms = pool.submit(edge_term, edge_images, edges)
        r, J12, usable = _residuals(rig, T, nuis, patches, images)
        edge = edge_terms.result() if edge_terms is not None else None
    if usable.sum() < s.min_returns:
        raise _CannotTellError(
            f"no overlap: only {int(usable.sum())} patches stay inside both frames as T_cam_laser "
            "is corrected (the stored calibration may be far off)"
        )
    out = _Terms(r, J12[:, :, free], usable)
    if edge is not None:
        er, J6, eusable, found = edge
        if int(eusable.sum()) >= MIN_EDGE_BANDS:
            eJ = np.zeros((len(er), 12))
            eJ[:, :6] = J6
            out.er, out.eJ, out.eusable, out.found = er, eJ[:, free], eusable, found
    return out


def _estimate(
    rig: Rig,
    streams: Streams,
    patches: _Patches,
    s: TargetlessSettings,
    edges_required: bool = False,
    hold_odometry: bool = True,
) -> _Estimate:
    """Gauss-Newton on (xi without laser z, the odometry's errors), coarse to fine, each
    step accepted only when it brings the estimate nearer the solution (a trust region),
    then the clusters' jackknife covariance (module docstring, steps 4-5).

    Raises:
        _EdgesUnusableError: ``edges_required`` (the streams' odometry is of thinned scans)
            and too few edge bands are usable at the start estimate, or at the estimate.
    """
    T0 = rig.T_cam_laser
    free = [0, 1, 2, 3, 4, 6, 7, 8, 9, 10, 11]  # rx ry rz tx ty, the odometry's errors; laser z (5) held
    D = np.diag(np.r_[s.scale, _NUISANCE_UNITS])[np.ix_(free, free)]
    T = T0.copy()
    nuis = np.zeros(6)
    rows = _rows(rig, patches)
    use_edges = patches.edges is not None
    keep = np.ones(len(free), dtype=bool)
    keep[list(_EDGE_ONLY)] = False
    anchor: FloatArray | None = None
    steps = refused = 0
    last_step = math.inf
    for stage, blur in enumerate(s.blur_px):
        images = _Images(streams, patches, rows, blur, s.native_blur_px)
        edge_images = _edge_images(rig, patches, math.hypot(blur, s.native_blur_px), s) if use_edges else None
        window = s.edge_window_px[min(stage, len(s.edge_window_px) - 1)]
        cur = _evaluate(rig, T, nuis, patches, images, edge_images, anchor, window, free, s)
        if stage == 0:
            if cur.er is None:
                if edges_required:
                    for ahead in patches.stacks_ahead.values():
                        ahead.cancel()
                    raise _EdgesUnusableError
                use_edges = False  # too few edges seen clearly: the photometric term alone
                edge_images = None
                for key in [k for k in patches.stacks_ahead if k[0] == "edges"]:
                    patches.stacks_ahead.pop(key).cancel()
            else:
                # The bands are paired with their image edges once, here, at the start
                # estimate; later evaluations re-measure them within a gate of it.
                anchor = cur.found
            # Every scan's odometry's errors are held where the photometric term alone
            # judges (_prior); with edges they are estimated as before.
            held = hold_odometry and not use_edges
            prior = _prior(held)
        last_step = math.inf
        # With the odometry's errors held, the last stage iterates until it settles (the
        # iterations a stage takes otherwise may stop part of the way).
        last_stage = stage == len(s.blur_px) - 1
        for _ in range(s.max_iterations if held and last_stage else s.iterations):
            sc = _scales(cur)
            A_raw, g, H_sym = _system(cur, sc, keep)
            # Steps are measured in the information's metric (sigmas): the odometry's
            # weakly determined errors, which the prior barely holds, then count little.
            metric = D @ H_sym @ D + prior
            # The directions the drive does not determine are held (_held).
            A = D @ A_raw @ D + prior + _held(metric)
            F = D @ g
            lam = 0.0
            remaining = float(np.abs(np.linalg.solve(A, F)[:5]).max())  # the undamped Newton step
            for _try in range(MAX_TRIES):
                M = A + lam * np.diag(np.diag(A))
                dz = -np.linalg.solve(M, F)
                # At most 3 resolutions a step on T (the odometry's errors follow freely).
                dz *= min(1.0, 3.0 / max(float(np.abs(dz[:5]).max()), 1e-12))
                d = D @ dz
                T_try = T @ _exp(np.r_[d[:5], 0.0])
                nuis_try = nuis + d[5:]
                trial = _evaluate(rig, T_try, nuis_try, patches, images, edge_images, anchor, window, free, s)
                if use_edges and trial.er is None:
                    ok = False  # the step lost the edges
                else:
                    # Deuflhard's natural monotonicity test: the (simplified) Newton
                    # correction at the trial point, with this step's matrix, must be
                    # shorter than the step. The system is not the gradient of one cost
                    # (the photometric term's equations for the yaw and the translations
                    # are dropped), so this, not a cost, says whether the step brought
                    # the estimate nearer the solution of both terms' equations.
                    _, g_try, _ = _system(trial, sc, keep)
                    bar = np.linalg.solve(M, D @ g_try)
                    ok = bool(bar @ metric @ bar < dz @ metric @ dz) or float(np.abs(bar[:5]).max()) < 0.01
                if ok:
                    break
                refused += 1
                lam = 1e-2 if lam == 0.0 else 10.0 * lam
            else:
                # No step brings it nearer: as settled as this stage goes; what is left
                # of the Newton step says whether that is settled.
                last_step = remaining
                break
            T, nuis, cur = T_try, nuis_try, trial
            steps += 1
            last_step = float(np.abs(dz[:5]).max())
            if last_step < SETTLED_UNITS:
                break
        del images  # the next stage's stack replaces it
    try:
        # The edges' projections are checked only where the estimate used them.
        _runaway(rig, T0, T, patches.edges if use_edges else None, last_step, s)
    except _CannotTellError as exc:
        exc.photometric_alone = held
        raise
    Delta = np.linalg.inv(T0) @ T
    xi = np.concatenate([R_to_rotvec(Delta[:3, :3]), Delta[:3, 3]])
    sc = _scales(cur)
    A_raw, _, H_sym = _system(cur, sc, keep)
    metric = D @ H_sym @ D + prior
    A = D @ A_raw @ D + prior + _held(metric)  # the estimator as solved, for its jackknife
    # What the drive determines of xi once the odometry's errors are free (resolution
    # units): the directions not held.
    ev, U = _schur_eig(metric)
    determined = np.zeros((6, int((ev > 1.0 / HELD_UNITS**2).sum())))
    determined[free[:5]] = U[:, ev > 1.0 / HELD_UNITS**2]
    information = np.zeros((6, 6))
    information[np.ix_(free[:5], free[:5])] = (U * ev) @ U.T
    if determined.shape[1] == 0:
        raise _CannotTellError(
            "degenerate motion: the drive determines no direction of T_cam_laser to the "
            f"resolution ({s.resolution_deg:g} deg, {100 * s.resolution_m:g} cm)",
            photometric_alone=held,
        )
    # The clusters' jackknife (rigcal.drift.statistic): each block's patches and each
    # corner's bands left out in turn, by one Newton step from the estimate.
    A_c, g_c, n_blocks, n_corners = _cluster_parts(cur, sc, keep, patches)
    A_c = D[None] @ A_c @ D[None]
    g_c = g_c @ D
    C_free, d = cluster_covariance(A, A_c, g_c)
    cov_z = np.zeros((6, 6))
    cov_z[np.ix_(free[:5], free[:5])] = C_free[:5, :5]  # the odometry's errors marginalised out
    moves = np.zeros((len(d), 6))
    moves[:, free[:5]] = d[:, :5]
    sig = np.sqrt(np.clip(np.diag(C_free)[5:], 0.0, None)) * np.array(_NUISANCE_UNITS)
    edge_stats: dict[str, Any] = {}
    if use_edges and cur.er is not None and cur.eusable is not None:
        edge_stats = {
            "edge_bands": int(cur.eusable.sum()),
            "edge_rms_px": _r(math.sqrt(sc.edge_var), 3),
            "edge_corners_used": n_corners,
        }
    elif edges_required:
        raise _EdgesUnusableError  # the edges were lost on the way: the photometric term alone
    solve = {
        "steps": steps,
        "steps_refused": refused,
        "last_step_units": _r(last_step, 4),
        "odometry_errors_held": held,
    }
    return _Estimate(
        xi,
        cov_z,
        nuis,
        sig,
        n_blocks,
        n_corners,
        moves,
        determined,
        edge_stats,
        solve,
        information,
        normal=A,
        cluster_normal=A_c,
        cluster_gradient=g_c,
    )


HELD_UNITS = 1.0
"""A direction of xi whose 1-sigma (the odometry's errors free) is above this many
resolutions is not determined by the drive: it is held at the stored value while
solving, as laser z is."""
HELD_STIFFNESS = 1e6
"""The information (per resolution squared) that holds such a direction."""


def _schur_eig(metric: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Eigenvalues (ascending) and vectors of the information on xi's five free
    directions (resolution units) once the odometry's errors (the last rows of
    ``metric``, its prior in it) are free: the Schur complement of their block."""
    schur = metric[:5, :5] - metric[:5, 5:] @ np.linalg.solve(metric[5:, 5:], metric[5:, :5])
    ev, U = np.linalg.eigh(0.5 * (schur + schur.T))
    return ev, U


def _held(metric: FloatArray) -> FloatArray:
    """(K, K) a stiff prior along the directions of xi the drive does not determine
    (1-sigma above :data:`HELD_UNITS` resolutions): they are held at the stored value, as
    laser z is, not moved by what little the data say of them. Two corners at about one
    depth leave the yaw against a sideways shift to the corners' own errors (a valley
    along which one corner's wrong pairing moved the estimate by metres, and no damped
    step brought it nearer the solution); such a direction is neither observed nor
    tested, and moving along it would only drag the observed ones."""
    ev, U = _schur_eig(metric)
    W = U[:, ev <= 1.0 / HELD_UNITS**2]
    out = np.zeros_like(metric)
    out[:5, :5] = HELD_STIFFNESS * (W @ W.T)
    return out


def _runaway(
    rig: Rig, T0: FloatArray, T: FloatArray, edges: Edges | None, last_step: float, s: TargetlessSettings
) -> None:
    """ "Cannot tell" when the estimate left the region where its linearisation holds:
    it did not settle, or it moved the edges' projections farther than their image edges
    were searched (the first pairing cannot stand for it)."""
    Delta = np.linalg.inv(T0) @ T
    rot = math.degrees(float(np.linalg.norm(R_to_rotvec(Delta[:3, :3]))))
    mm = 1000.0 * float(np.linalg.norm(Delta[:3, 3]))
    what = f"the correction ({rot:.2f} deg, {mm:.0f} mm)"
    if last_step > RUNAWAY_UNITS:
        raise _CannotTellError(
            f"the estimate did not settle: {what} still moved by {last_step:.2f} resolutions in its last "
            "step; the drive does not pin T_cam_laser down (or the stored calibration is far off)"
        )
    if edges is None:
        return
    Xc = edges.X[:, :, edges.X.shape[2] // 2].reshape(-1, 3)
    q0 = rig.camera.project(Xc @ T0[:3, :3].T + T0[:3, 3])
    q1 = rig.camera.project(Xc @ T[:3, :3].T + T[:3, 3])
    move = np.linalg.norm(q1 - q0, axis=1)
    move = move[np.isfinite(move)]
    window = max(s.edge_window_px)
    if len(move) and float(np.median(move)) > window:
        raise _CannotTellError(
            f"the estimate ran away: {what} moves the edges' projections by {float(np.median(move)):.0f} px "
            f"(median), beyond the {window:g} px their image edges were searched in; the linearisation "
            "does not hold there (the stored calibration may be far off)"
        )


_EDGE_ONLY = (2, 3, 4)
"""Rows of the free parameters (rz, tx, ty) the edges alone estimate when they are seen."""
MIN_EDGE_BANDS = 10
"""Fewer usable edge bands: the edge term is left out of that step."""


def _edge_rows(rig: Rig, edges: Edges | None) -> tuple[float, float]:
    """The image rows the edges' bands fall in under the stored T, with room for a
    correction (:data:`BAND_MARGIN_PX`)."""
    if edges is None:
        return (0.0, 0.0)
    T = rig.T_cam_laser
    q = rig.camera.project(edges.X.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3])
    v = q[np.isfinite(q[:, 1]), 1]
    if not len(v):
        return (0.0, float(rig.camera.height_px))
    return (float(v.min()) - BAND_MARGIN_PX, float(v.max()) + BAND_MARGIN_PX)


def _floors(s: TargetlessSettings, est: _Estimate) -> tuple[tuple[float, float, float], float]:
    """The rotations' floors (deg) and the translations' (m): the edges' when they
    estimated the yaw and the translations, else the photometric term's alone (with the
    odometry's errors held, or estimated: edges lost on the way to the estimate)."""
    if est.edge_stats:
        return s.floor_deg, s.edge_floor_m
    if est.solve.get("odometry_errors_held", False):
        return s.photo_floor_deg, s.floor_m
    return s.photo_floor_free_deg, s.floor_m


def _floor_limited(s: TargetlessSettings, floors: tuple[tuple[float, float, float], float]) -> set[int]:
    """Axes whose floor alone is above the observed threshold."""
    floor_deg, floor_m = floors
    limit = 1.0 / s.detection_factor()
    out = {a for a in range(3) if floor_deg[a] / s.resolution_deg >= limit}
    if floor_m / s.resolution_m >= limit:
        out |= {3, 4}
    return out


def _floor_z(s: TargetlessSettings, floors: tuple[tuple[float, float, float], float]) -> FloatArray:
    """(6, 6) the systematic floor in resolution units (laser z's row and column zero)."""
    floor_deg, floor_m = floors
    f = np.array([math.radians(x) for x in floor_deg] + [floor_m] * 3) / s.scale
    f[_FIXED] = 0.0
    out: FloatArray = np.diag(f**2)
    return out


@dataclass(frozen=True)
class _Group:
    """Observed directions tested together: their basis (6, k; resolution units), which
    clusters carry them (rows of the estimate's ``moves``), a name, and the degrees of
    freedom the clusters' spread has left to judge them (:func:`_group_parts`)."""

    name: str
    V: FloatArray
    clusters: slice
    spread_dof: int


def _group_parts(est: _Estimate) -> list[tuple[str, list[int], slice, FloatArray]]:
    """The groups of directions each tested on its own clusters: with the edge term, the
    roll and pitch (the photometric term, its blocks) and the yaw and translations
    across the plane (the edges alone, their corners); without it, all five on the
    blocks. Each with the directions the drive determines among its axes (6, m;
    resolution units): those its clusters fit."""
    if est.edge_stats:
        parts = [
            ("roll and pitch", [0, 1], slice(0, est.blocks)),
            ("yaw and translations", list(_EDGE_ONLY), slice(est.blocks, est.blocks + est.corners)),
        ]
    else:
        parts = [("all", [0, 1, 2, 3, 4], slice(0, est.blocks))]
    out = []
    for name, axes, clusters in parts:
        P = np.zeros((6, 6))
        P[axes, axes] = 1.0
        U, sv, _ = np.linalg.svd(P @ est.determined, full_matrices=False)
        out.append((name, axes, clusters, U[:, sv > 0.5]))
    return out


def _observed_groups(est: _Estimate, s: TargetlessSettings) -> list[_Group]:
    """The observed directions (resolution units) per group (:func:`_group_parts`). A
    direction is observed when the drive determines it once the odometry's errors are
    free and its sigma (the clusters' jackknife plus the floor) is under one resolution
    over the detection factor.

    The clusters' spread judges a group's directions only as far as it has degrees of
    freedom left: G clusters (one error each: a corner's, seen in however many frames)
    that fix m directions leave G - m to show their own errors (a cluster-level
    regression's residual count; with G = m each cluster is fitted exactly and its
    leave-one-out move says nothing of its error; :func:`statistic.spread_dof`). So at
    most G - m - 1 directions are tested: three or four corners fixing the yaw and both
    shifts judge none, five judge one. Which ones: those the drive's design determines
    best (its information), not those whose spread happens to come out narrowest (the
    narrowest of a few clusters' spreads is narrow by chance as often as not, and a test
    on it alarms too often)."""
    C = est.cov_z + _floor_z(s, _floors(s, est))
    limit = (1.0 / s.detection_factor()) ** 2
    out = []
    for name, _axes, clusters, Q in _group_parts(est):
        dof = spread_dof(clusters.stop - clusters.start, Q.shape[1])
        if Q.shape[1] == 0 or dof < 2:
            continue
        _, W_info = np.linalg.eigh(Q.T @ est.information @ Q)
        S = Q @ W_info[:, ::-1][:, : dof - 1]  # the best determined by design
        ev, W = np.linalg.eigh(S.T @ C @ S)  # ascending
        k = int((ev < limit).sum())
        if k > 0:
            out.append(_Group(name, S @ W[:, :k], clusters, dof))
    return out


def _observed_basis(est: _Estimate, s: TargetlessSettings) -> FloatArray:
    """(6, k) every observed direction (:func:`_observed_groups`)."""
    groups = _observed_groups(est, s)
    out: FloatArray = np.concatenate([g.V for g in groups], axis=1) if groups else np.zeros((6, 0))
    return out


# --- the test -------------------------------------------------------------------------


def _test(
    rig: Rig, est: _Estimate, patches: _Patches, s: TargetlessSettings, reasons: list[str]
) -> dict[str, Any]:
    D = np.diag(s.scale)
    groups = _observed_groups(est, s)
    V_obs = np.concatenate([g.V for g in groups], axis=1) if groups else np.zeros((6, 0))
    k = V_obs.shape[1]
    info = patches.info
    if est.edge_stats:
        fixed = {name: Q.shape[1] for name, _, _, Q in _group_parts(est)}["yaw and translations"]
        info = info | {"edge_corners": est.corners, "edge_fixed": fixed}
    unobserved = _unobserved_words(V_obs, info, _floor_limited(s, _floors(s, est)))
    record: dict[str, Any] = (
        est.edge_stats
        | est.solve
        | {
            "unobserved": unobserved,
            "odometry_errors": {
                "scale_pct": [_r(100.0 * est.odometry[0], 4), _r(100.0 * est.odometry_sigma[0], 4)],
                "yaw_scale_pct": [_r(100.0 * est.odometry[1], 4), _r(100.0 * est.odometry_sigma[1], 4)],
                "yaw_rate_bias_deg_s": [
                    _r(math.degrees(est.odometry[2]), 5),
                    _r(math.degrees(est.odometry_sigma[2]), 5),
                ],
                "crab_deg": [
                    _r(math.degrees(est.odometry[5]), 4),
                    _r(math.degrees(est.odometry_sigma[5]), 4),
                ],
                "pivot_mm": [
                    [_r(1000.0 * est.odometry[3], 2), _r(1000.0 * est.odometry[4], 2)],
                    [_r(1000.0 * est.odometry_sigma[3], 2), _r(1000.0 * est.odometry_sigma[4], 2)],
                ],
            },
        }
    )
    nothing = {"xi": np.full(6, np.nan), "cov": np.zeros((6, 6))}
    if k == 0:
        reasons.append(
            "degenerate motion: no direction of T_cam_laser is observed to the resolution "
            f"({s.resolution_deg:g} deg, {100 * s.resolution_m:g} cm) by this drive"
        )
        return {"verdict": "cannot_tell", "record": record} | nothing
    # Each group's directions (resolution units): Hotelling's T^2 of the estimate
    # against the clusters' jackknife plus the known parts (the floor, the stored
    # calibration's covariance), referred with 12 clusters or more to its wild cluster
    # bootstrap under no change on the linearised problem (statistic.wild_cluster_bootstrap:
    # the F with Kish's count alarmed too often with many unequal clusters), with fewer to
    # the F (statistic.BOOTSTRAP_FROM_CLUSTERS). The clusters' effective count
    # along the group's directions (a few corners carrying the yaw count as few, however
    # many frames see them), at most one more than the spread's degrees of freedom
    # (_observed_groups), says whether there are enough to judge them (F(k, n - k)
    # needs n > k + 1) and sizes the detectable change. The groups' tests are combined
    # by Bonferroni: drifted when one group's p is under the level over the groups' count.
    F_z, R_z = _floor_z(s, _floors(s, est)), _rig_cov_z(rig, D)
    z_all = V_obs.T @ np.linalg.solve(D, est.xi)
    free = [0, 1, 2, 3, 4]  # xi's rows among the free parameters (laser z held)
    tests = []
    for g in groups:
        z_g = g.V.T @ np.linalg.solve(D, est.xi)
        C_g = g.V.T @ est.cov_z @ g.V
        n_g = min(effective_clusters(est.moves[g.clusters], g.V), float(g.spread_dof + 1))
        known = g.V.T @ (F_z + R_z) @ g.V
        level_g = s.level / len(groups)
        h = hotelling(z_g, C_g, known, n_g, level_g)
        if math.isfinite(h.p) and g.clusters.stop - g.clusters.start >= BOOTSTRAP_FROM_CLUSTERS:
            V_free = np.zeros((len(est.normal), g.V.shape[1]))
            V_free[: len(free)] = g.V[free]
            b = wild_cluster_bootstrap(
                est.normal, est.cluster_normal, est.cluster_gradient, V_free, z_g, known, level_g
            )
            h = dataclasses.replace(h, p=b.p, critical=b.critical)
        tests.append((g, h, n_g, C_g, known, z_g))
    if any(not math.isfinite(t.p) for _, t, *_ in tests):
        reasons.append(
            f"too short: {est.blocks} blocks of {s.block_s:g} s and {est.corners} corners amount to too few "
            f"independent pieces for the {k} observed directions"
        )
        return {"verdict": "cannot_tell", "record": record} | nothing
    p = min(1.0, len(tests) * min(t.p for _, t, *_ in tests))
    g_min, test, n_data, *_ = min(tests, key=lambda x: x[1].p)
    t2, n = test.t2, test.n
    drifted = p < s.level
    Ck = V_obs.T @ (est.cov_z + F_z) @ V_obs
    z = z_all
    xi_obs = D @ V_obs @ z
    cov_obs = D @ V_obs @ Ck @ V_obs.T @ D
    sig = np.sqrt(np.clip(np.diag(cov_obs), 0.0, None))
    observed = [AXES[a] for a in range(6) if _axis_observed(V_obs, a)]
    record |= {
        "observed_axes": observed,
        "observed_directions": k,
        "correction_rotation_deg": [_r(math.degrees(x), 4) for x in xi_obs[:3]],
        "correction_translation_mm": [_r(1000.0 * x, 2) for x in xi_obs[3:]],
        "sigma_rotation_deg": [_r(math.degrees(x), 4) for x in sig[:3]],
        "sigma_translation_mm": [_r(1000.0 * x, 2) for x in sig[3:]],
        "rotation_deg": _r(math.degrees(float(np.linalg.norm(xi_obs[:3]))), 4),
        "translation_mm": _r(1000.0 * float(np.linalg.norm(xi_obs[3:])), 2),
        "t2": _r(t2, 4),
        "t2_critical": _r(test.critical, 4),
        "dof": k,
        "blocks": est.blocks,
        "corners": est.corners,
        "corner_directions": info.get("edge_fixed", 0),
        "effective_clusters": _r(n_data, 1),
        "effective_blocks": _r(n, 1),
        "p_value": float(f"{p:.4g}"),
        "tests": [
            {
                "directions": g.name,
                "axes": [AXES[a] for a in range(6) if _axis_observed(g.V, a)],
                "dof": t.k,
                "t2": _r(t.t2, 4),
                "t2_critical": _r(t.critical, 4),
                "effective_clusters": _r(n_g, 1),
                "p_value": float(f"{t.p:.4g}"),
            }
            for g, t, n_g, *_ in tests
        ],
        "detects": _detectable(V_obs.T @ (est.cov_z + F_z + R_z) @ V_obs, k, n, s),
    }
    if rig.covariance is None:
        reasons.append("the rig has no covariance: the stored calibration is taken as exact")
    for u in unobserved:
        reasons.append(f"not observed by this drive: {u['direction']} ({u['why']})")
    if drifted:
        reasons.append(
            f"the drive is most consistent with T_cam_laser corrected by {record['rotation_deg']:.3f} deg "
            f"and {record['translation_mm']:.1f} mm (its {g_min.name}: T^2 {t2:.1f} over {test.k} observed "
            f"directions, {n_data:.1f} effective clusters of {est.blocks} blocks and {est.corners} corners; "
            f"p = {p:.2g} over {len(tests)} tests)"
        )
    details = {
        "groups": [
            {"z": z_g, "C_data": C_g, "C_known": known, "n_data": n_g, "V": g.V}
            for g, _, n_g, C_g, known, z_g in tests
        ],
    }
    return {
        "verdict": "drifted" if drifted else "ok",
        "xi": xi_obs,
        "cov": cov_obs,
        "record": record,
        "details": details,
    }


def _detectable(C: FloatArray, k: int, n: float, s: TargetlessSettings) -> dict[str, float]:
    """The smallest change along the least-determined observed direction detected 95 %
    of the time at the level, as rotation deg and translation mm (for the record)."""
    lam = _noncentrality(k, hotelling_critical(k, n, s.level))
    sig_max = float(np.sqrt(np.linalg.eigvalsh(C).max()))
    return {
        "resolution_units": _r(sig_max * math.sqrt(lam), 3),
        "rotation_deg": _r(sig_max * math.sqrt(lam) * s.resolution_deg, 4),
        "translation_mm": _r(sig_max * math.sqrt(lam) * 1000.0 * s.resolution_m, 2),
    }


def _noncentrality(k: int, crit: float) -> float:
    lo, hi = 0.0, 400.0
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        if ncx2_sf(crit, k, mid) < 0.95:
            lo = mid
        else:
            hi = mid
    return hi


def _rig_cov_z(rig: Rig, D: FloatArray) -> FloatArray:
    """The rig's covariance (camera-frame tangent: R = Exp(d) R0, t = t0 + e) in xi's
    resolution units (T = T0 Exp(xi): d = R0 w, e = R0 v)."""
    if rig.covariance is None:
        return np.zeros((6, 6))
    R0 = rig.T_cam_laser[:3, :3]
    A = np.zeros((6, 6))
    A[:3, :3] = R0.T
    A[3:, 3:] = R0.T
    Dinv = np.linalg.inv(D)
    out: FloatArray = Dinv @ A @ rig.covariance @ A.T @ Dinv
    return out


def _axis_observed(V_obs: FloatArray, a: int) -> bool:
    """An axis counts as observed when most of it lies in the observed subspace."""
    return float(np.sum(V_obs[a] ** 2)) > 0.5


def _unobserved_words(
    V_obs: FloatArray, info: dict[str, Any], floor_limited: set[int] | None = None
) -> list[dict[str, Any]]:
    """The directions the drive leaves open, in words, with why (``floor_limited``: axes
    whose determination the systematic floor, not the drive, limits)."""
    P = np.eye(6) - V_obs @ V_obs.T
    evals, evecs = np.linalg.eigh(P)
    out = []
    straight = float(info.get("heading_range_deg", 0.0)) < 30.0
    for n in np.flatnonzero(evals > 0.5):
        u = evecs[:, n]
        u = u * (1.0 if u[np.argmax(np.abs(u))] > 0 else -1.0)
        parts = [(abs(float(c)), a) for a, c in enumerate(u) if abs(c) >= 0.3]
        parts.sort(reverse=True)
        words = " with ".join(AXIS_WORDS[a] for _, a in parts)
        main = parts[0][1]
        if main == 5:
            why = (
                "a 2D laser moving in its own scan plane: raising the camera's idea of where the returns "
                "are slides each one up its wall, onto a surface point seen alike from every frame"
            )
        elif floor_limited and main in floor_limited:
            why = (
                "the laser odometry's own errors (its crab angle, its pivot in turns) and the image model "
                "leave it uncertain by the systematic floor, more than the resolution allows"
            )
            if main in _EDGE_ONLY:
                why += (
                    "; the drive shows no corner, pillar or wall end clearly enough in the images to "
                    "measure it by their edges"
                )
        elif main in _EDGE_ONLY and 0 < info.get("edge_corners", 0) < info.get("edge_fixed", 3) + 2:
            lo, hi = info.get("edge_depth_m", [0.0, 0.0])
            fixed = info.get("edge_fixed", 3)
            why = (
                f"the drive shows {info['edge_corners']} corners (at {lo:.1f}-{hi:.1f} m), each one error "
                f"however many frames see it; fitting {fixed} directions to them leaves too few (at least "
                f"{fixed + 2} corners) to tell the yaw and the shifts across the view from the corners' "
                "own errors"
            )
        elif abs(u[2]) >= 0.3 and max(abs(u[3]), abs(u[4])) >= 0.3 and info.get("edge_corners"):
            lo, hi = info.get("edge_depth_m", [0.0, 0.0])
            why = (
                f"the edges this drive sees ({info['edge_corners']} corners) stand at about one depth "
                f"({lo:.1f}-{hi:.1f} m), where a yaw and a sideways shift move their projections alike, "
                "so the two are not told apart; corners at several depths separate them"
            )
        elif main in (3, 4) and info.get("edge_corners"):
            lo, hi = info.get("edge_depth_m", [0.0, 0.0])
            why = (
                f"the drive shows {info['edge_corners']} corners (at {lo:.1f}-{hi:.1f} m), each one error "
                "however many frames see it: too few to pin a shift across the view"
            )
        elif straight and main in (0, 3, 4):
            why = (
                f"the drive keeps one heading (within {info.get('heading_range_deg', 0):.0f} deg): "
                "as along a straight corridor, a shift along the travel or a roll about it slides the "
                "returns along their walls alike in every frame; turns observe it"
            )
        else:
            why = "the walls this drive sees, and the views it sees them from, leave it loose"
        out.append(
            {
                "direction": words,
                "components": {AXES[a]: _r(float(u[a]), 3) for _, a in parts},
                "why": why,
            }
        )
    return out


def _r(x: float, digits: int) -> float:
    return round(float(x), digits)


def _json(x: Any) -> Any:
    if isinstance(x, dict):
        return {k: _json(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json(v) for v in x]
    if isinstance(x, (np.floating, float)):
        return None if not math.isfinite(float(x)) else float(x)
    if isinstance(x, np.integer):
        return int(x)
    return x
