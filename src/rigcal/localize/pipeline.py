"""The localization pipeline: a sequence folder in, trajectories and their metrics out.

``run`` reads like its steps: open the sequence's streams (scans, images, rig), estimate
the laser's trajectory with each chosen method, write each trajectory, the effective
configuration, per-stage timings and, when the sequence has ground truth, the metrics of
``rigcal.localize.metrics`` (the paper's Table 1) and a picture of the paths (Fig. 8).

Methods are registered in :data:`METHODS` (name -> function from the streams and IASM's
settings to an :class:`Estimate`), so adding one is a local change.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2
from rigcal.io.gyro import Gyro
from rigcal.io.trajectory import Trajectory, read_tum
from rigcal.io.wheel_odometry import WheelOdometry, across_gaps, gap_s, laser_motions
from rigcal.localize import kalman
from rigcal.localize.iasm import IasmParams
from rigcal.localize.icp import IcpParams
from rigcal.localize.image_matching import scan_matching
from rigcal.localize.loop_closure import (
    LoopParams,
    LoopResult,
    Proposal,
    close_loops,
    keyframes,
    nearest_scans,
    path_along,
    scans_at,
    step_covariances,
)
from rigcal.localize.metrics import anchored, evaluate
from rigcal.localize.odometry import DEGENERATE_BELOW, LASER_ODOMETRY, Odometry, icp_odometry
from rigcal.localize.place_recognition import Features, PlaceParams, orb_features, recognise
from rigcal.localize.streams import Streams, open_streams
from rigcal.localize.tracks import TrackParams
from rigcal.localize.vo import VoResult, VoStep, still_rotation_covariance, visual_odometry

log = logging.getLogger(__name__)


MIN_SCANS = 2


@dataclass(frozen=True)
class Estimate:
    """A method's trajectory: laser poses (x, y, yaw) at stamps, in its own start frame,
    and the method's counts (degenerate steps, failed steps, fallbacks, ...)."""

    stamps_s: FloatArray
    poses: FloatArray
    stats: dict[str, Any] = field(default_factory=dict)
    steps_csv: str | None = None
    closures: LoopResult | None = None


# Methods whose poses are laser poses that loop closure can take (at scan stamps; the
# Kalman filter's also at image stamps, each matched with the scan nearest it).
LOOP_CLOSURE_METHODS = ("icp", "icp-p2p", "kf", "iasm", "hiasm")
# Loop closure's image place recognition unless told otherwise (``--place-recognition``).
DEFAULT_PLACE = PlaceParams()


def _loop_closed(
    streams: Streams, est: Estimate, params: LoopParams, place: PlaceParams | None = DEFAULT_PLACE
) -> Estimate:
    """The estimate with loop closure (rigcal.localize.loop_closure): each pose takes the
    scan nearest its stamp, moved to the stamp by the laser odometry, and each step the
    laser odometry's covariance over it (ICP's Hessian, compounded) and the step's
    departure from it (:func:`rigcal.localize.loop_closure.step_covariances`). With
    ``place``, the keyframes' images propose closures too (:func:`image_proposals`)."""
    t0 = time.perf_counter()
    proposals, place_stats = image_proposals(streams, est, params, place)
    od = streams.laser_odometry()
    points = scans_at(streams.scans, streams.scan_stamps_s, od.poses, est.stamps_s)
    cov = None
    if od.covariance is not None:
        cov = step_covariances(streams.scan_stamps_s, od.poses, od.covariance, est.stamps_s, est.poses)
    res = close_loops(points, est.poses, params, cov, proposals)
    seconds = time.perf_counter() - t0
    path_m = float(path_along(est.poses)[-1]) if len(est.poses) else 0.0
    streams.timings_s["loop_closure_s"] = streams.timings_s.get("loop_closure_s", 0.0) + seconds
    stats = {
        "closures": res.counts,
        "closures_by_source": res.counts_by_source,
        "place_recognition": place_stats,
        "pose_graph": res.backend,
        "loop_closure_s": round(seconds, 3),
    }
    if path_m < params.min_loop_m:  # said on stderr too (rigcal localize), not an error
        stats["note"] = (
            f"a path of {path_m:.1f} m over {len(est.poses)} poses, shorter than the {params.min_loop_m:g} m "
            "a loop needs: no closure could be searched; the trajectory is the method's own"
        )
    return Estimate(est.stamps_s, res.poses, stats, None, res)


def image_proposals(
    streams: Streams, est: Estimate, params: LoopParams, place: PlaceParams | None
) -> tuple[list[Proposal], dict[str, Any]]:
    """Closures proposed by image place recognition (rigcal.localize.place_recognition)
    over the estimate's keyframes (those loop closure takes), each keyframe with the
    image nearest its stamp (within ``place.max_image_gap_s``), and what it did: the
    report's ``place_recognition`` entry. No images, or no rig, gives no proposals and
    says so there. Each image's features are computed once per run (the methods share
    them)."""
    if place is None:
        return [], {"used": "none"}
    if streams.n_images == 0 or streams.rig is None:
        why = "the sequence has no images" if streams.n_images == 0 else "the sequence has no rig (camera)"
        return [], {"used": "images", "note": f"{why}: no image proposals"}
    t0 = time.perf_counter()
    along = path_along(est.poses)
    keys = keyframes(along, params.keyframe_m)
    frames = nearest_scans(streams.image_stamps_s, est.stamps_s[keys])
    near = np.abs(streams.image_stamps_s[frames] - est.stamps_s[keys]) <= place.max_image_gap_s
    cache: dict[tuple[int, int], Features] = streams.results.setdefault("place_features", {})
    features: list[Features | None] = []
    for f, ok in zip(frames, near, strict=True):
        if ok and (int(f), place.n_features) not in cache:
            cache[int(f), place.n_features] = orb_features(streams.image(int(f)), place)
        features.append(cache[int(f), place.n_features] if ok else None)
    rig = streams.rig
    res = recognise(features, along[keys], rig.camera, rig.T_cam_laser, place, params.min_loop_m)
    proposals = [
        Proposal(int(keys[p.a]), int(keys[p.b]), "images", p.yaw_rad, place.window_m, place.window_rad)
        for p in res.proposals
    ]
    seconds = time.perf_counter() - t0
    return proposals, {"used": "images", **res.stats, "place_recognition_s": round(seconds, 3)}


def _icp_estimate(streams: Streams, od: Odometry) -> Estimate:
    degenerate = od.degeneracy < DEGENERATE_BELOW
    guess = streams.wheel_guess()
    from_wheels = 0 if guess is None else int(np.isfinite(guess).all(axis=1).sum())
    stats = {
        "degenerate_steps": int(degenerate[1:].sum()),
        "skipped_steps": od.skipped,
        "restarted_steps": od.restarts,
        # Steps started from the wheel odometry (the others: from the previous motion),
        # and those whose fit it overruled (beyond its error bound).
        "wheel_odometry_steps": from_wheels,
        "wheel_overruled_steps": od.overruled,
        # Steps across a gap in the wheel odometry that kept its motion there as their
        # guess (the scans did not contradict it: a logger paused, the base counting on).
        "wheel_gap_kept_steps": od.gap_kept,
    }
    # Per step: the degeneracy indicator (smallest over largest eigenvalue of the
    # translation information: near 0, a direction the scans do not constrain, as along
    # a featureless corridor).
    rows = ["scan,stamp_s,degeneracy,degenerate,rms_m,skipped"]
    for k in range(1, len(od.poses)):
        skipped = not np.isfinite(od.rms_m[k])
        rms = "" if skipped else f"{od.rms_m[k]:.5f}"
        rows.append(
            f"{k},{float(streams.scan_stamps_s[k])!r},{od.degeneracy[k]:.5f},{int(degenerate[k])},{rms},{int(skipped)}"
        )
    return Estimate(streams.scan_stamps_s, od.poses, stats, "\n".join(rows) + "\n")


def _vo_result(streams: Streams) -> VoResult:
    """Visual odometry over the sequence (computed once per run, shared by vo and kf)."""
    if "vo" in streams.results:
        out: VoResult = streams.results["vo"]
        return out
    rig = streams.require_rig("vo")
    streams.require_images("vo")
    tracks = streams.feature_tracks()  # shared with H-IASM (timed on its own)
    streams.laser_odometry()  # pairs scans with images (timed on its own)
    t0 = time.perf_counter()
    res = visual_odometry(
        tracks,
        streams.image,
        streams.image_stamps_s,
        rig.camera,
        rig.T_cam_laser,
        streams.laser_points_at_image,
        progress=lambda k: streams.report("visual odometry", k, streams.n_images),
        gain_compensation=streams.track_params.equalize == "gain",
    )
    streams.timings_s["vo_s"] = time.perf_counter() - t0
    streams.results["vo"] = res
    return res


def _vo_estimate(streams: Streams, res: VoResult) -> Estimate:
    counts: dict[str, int] = {}
    for s in res.steps:
        counts[s.status] = counts.get(s.status, 0) + 1
    stats = {"runs": len(res.steps), "run_status": counts, "frames_used": len(res.frames)}
    return Estimate(streams.image_stamps_s[res.frames], res.poses, stats)


def _kf_estimate(streams: Streams, params: kalman.KfParams | None = None) -> Estimate:
    params = params or kalman.KfParams()
    images = kf_has_images(streams)
    od, res = streams.laser_odometry(), _vo_result(streams) if images else None
    if not images:
        # ICP and the wheel odometry alone, over a long real log: the path from the
        # filter's relative estimates (KfParams.anchored; docs/localization.md).
        params = dataclasses.replace(params, anchored=True)
    t0 = time.perf_counter()
    ms = kf_measurements(streams, od, res, params)
    stats: dict[str, Any] = {
        "icp_measurements": sum(m.source == "icp" for m in ms),
        "vo_measurements": sum(m.source == "vo" for m in ms),
        "weights": params.weights,
        "prediction": f"{params.drive} steps" if params.drive else "constant velocity",
    }
    if not images:
        stats["inputs"] = "ICP and the wheel odometry (the sequence has no images)"
    if streams.wheel_odometry is not None:
        stats["wheel_measurements"] = sum(m.source == "wheel" for m in ms)
    kf = kalman.run_filter(ms, params)
    if len(kf.stamps_s):
        kf = kalman.path_at(kf, streams.scan_stamps_s)  # scored where ICP is
    if streams.gyro is not None:
        stats["gyro_measurements"] = sum(m.source == "gyro" for m in ms)
        # Its bias at the end and where it was learned: the seconds the rig stood still.
        stats["gyro_still_s"] = round(kf.gyro_still_s, 3)
        stats["gyro_bias_deg_s"] = _finite_or_none(np.degrees(kf.gyro_bias), 5)
        stats["gyro_bias_sigma_deg_s"] = _finite_or_none(np.degrees(kf.gyro_bias_sigma), 5)
    streams.timings_s["kf_s"] = time.perf_counter() - t0
    return Estimate(kf.stamps_s, kf.poses, stats)


def _finite_or_none(value: float, digits: int) -> float | None:
    """A figure for the summary (JSON has no NaN): rounded, or None where not finite."""
    return round(float(value), digits) if np.isfinite(value) else None


def kf_inputs(streams: Streams) -> tuple[Odometry, VoResult]:
    """The laser odometry and the visual odometry of the sequence (computed once per run)."""
    return streams.laser_odometry(), _vo_result(streams)


def kf_has_images(streams: Streams) -> bool:
    """Whether the Kalman filter takes VO: the sequence has images (and so must have the
    rig: :func:`_require_images`); without, it fuses ICP and the wheel odometry."""
    return streams.n_images >= 2


def kf_measurements(
    streams: Streams, od: Odometry, res: VoResult | None, params: kalman.KfParams
) -> list[kalman.Increment]:
    """The Kalman filter's inputs: ICP's steps (``od``), VO's runs (``res``; None: a
    sequence without images) and the wheel odometry's steps (when used:
    :func:`wheel_measurements`), each with its covariance (``params.weights``;
    docs/localization.md)."""
    icp = _icp_estimate(streams, od)
    own = None if params.weights == "fixed" else od.covariance  # None: the fixed covariances
    odom = streams.wheel_odometry
    wheel = wheel_measurements(odom, icp.stamps_s, own) if odom is not None else []
    if own is None:
        degenerate = od.degeneracy < DEGENERATE_BELOW
        ms = kalman.increments(icp.stamps_s, icp.poses, kalman.ICP_SIGMAS, degenerate, source="icp")
    else:
        # The covariance already opens a degenerate step along the corridor only.
        cov, wheel = overruled_as_odometry(icp.stamps_s, own, wheel)
        ms = kalman.increments(icp.stamps_s, icp.poses, cov, source="icp")
    if res is not None:
        vo = _vo_estimate(streams, res)
        statuses = [s.status for s in res.steps]
        if own is None:
            ms += kalman.vo_increments(vo.stamps_s, vo.poses, statuses)
        else:
            rig = streams.require_rig("kf")
            focal = float(np.mean(rig.camera.intrinsics[:2]))
            vo_cov = np.array([_run_covariance(s, focal) for s in res.steps])
            ms += kalman.vo_increments(vo.stamps_s, vo.poses, statuses, vo_cov.reshape(-1, 3, 3))
    ms += wheel
    if streams.gyro is not None:
        ms += gyro_measurements(streams.gyro, streams.scan_stamps_s, params)
    return ms


def wheel_measurements(
    odom: WheelOdometry, scan_stamps_s: FloatArray, icp_covariance: FloatArray | None = None
) -> list[kalman.Increment]:
    """The wheel odometry's steps between the scans within its span as the filter's
    measurements, under its noise model (:data:`rigcal.localize.kalman.WHEEL_SIGMAS`).
    None across a gap in the odometry (:func:`rigcal.io.wheel_odometry.across_gaps`),
    unless ICP measured nothing there (``icp_covariance`` (N, 3, 3) per scan, NaN: the
    scans kept the odometry's motion, :func:`rigcal.localize.odometry.icp_odometry`): the
    step is then the odometry's alone, and one measurement of it (ICP's step, the same
    motion, is not one), where without it the filter's model would carry the pose over the
    pause."""
    t = np.asarray(scan_stamps_s, dtype=float)
    within = (t >= odom.stamps_s[0]) & (t <= odom.stamps_s[-1])
    tw = t[within]
    if len(tw) < 2:
        return []
    steps = laser_motions(odom, tw, over_gaps=True)
    measured = ~across_gaps(odom, tw)
    if icp_covariance is not None:
        icp_none = ~np.isfinite(np.asarray(icp_covariance)[within]).all(axis=(1, 2))[1:]
        measured |= icp_none
    measured &= np.isfinite(steps).all(axis=1) & (np.diff(tw) > 0)
    return [
        kalman.Increment(
            float(tw[k]),
            float(tw[k + 1]),
            steps[k],
            kalman.rate_covariance(kalman.WHEEL_SIGMAS, float(tw[k + 1] - tw[k])),
            "wheel",
        )
        for k in np.flatnonzero(measured)
    ]


def overruled_as_odometry(
    stamps_s: FloatArray, icp_covariance: FloatArray, wheel: list[kalman.Increment]
) -> tuple[FloatArray, list[kalman.Increment]]:
    """ICP's steps the odometry overruled (no covariance: the scans kept the odometry's
    motion, which is ICP's step there) under the odometry's noise model, and the wheels'
    steps without those: each such step one measurement, of the odometry, where the
    filter would otherwise have none from ICP (the driven filter a hole in its drive)."""
    cov = np.array(icp_covariance, dtype=float)
    at = {float(t): k for k, t in enumerate(stamps_s)}
    kept = []
    for m in wheel:
        k = at.get(m.t1, -1)
        if k > 0 and stamps_s[k - 1] == m.t0 and not np.isfinite(cov[k]).all():
            cov[k] = m.covariance
        else:
            kept.append(m)
    return cov, kept


def gyro_measurements(
    gyro: Gyro, scan_stamps_s: FloatArray, params: kalman.KfParams
) -> list[kalman.Increment]:
    """The gyroscope's steps (:func:`rigcal.localize.kalman.gyro_increments`): its yaw
    turned between scans' stamps at least :data:`rigcal.localize.kalman.GYRO_STEP_S` apart
    (the first scan's and each next one that far from the last taken), within its span."""
    t = np.asarray(scan_stamps_s, dtype=float)
    t = t[(t >= gyro.stamps_s[0]) & (t <= gyro.stamps_s[-1])]
    if len(t) < 2:
        return []
    keep = [0]
    for k in range(1, len(t)):
        if t[k] - t[keep[-1]] >= kalman.GYRO_STEP_S - 1e-9:
            keep.append(k)
    at = t[keep]
    return kalman.gyro_increments(at, gyro.yaw_between(at), params.gyro_noise)


def _run_covariance(step: VoStep, focal_px: float) -> FloatArray:
    """A VO run's covariance as the filter takes it: a still run's with the rotation its
    still test lets through (:func:`rigcal.localize.vo.still_rotation_covariance`)."""
    if step.covariance is None:
        return np.full((3, 3), np.nan)
    if step.status == "still":
        return still_rotation_covariance(step.covariance, focal_px)
    return step.covariance


def _wheel_estimate(streams: Streams) -> Estimate:
    """The laser's path by the wheel odometry alone, at the scans' stamps within its span."""
    od = streams.sequence.odometry
    if od is None:
        raise InputError(
            f"{streams.sequence.folder}: no wheel odometry (key 'odometry' of sequence.yaml); method "
            "'odom' needs it: import the log with its odometry (docs/formats/sequence.md)"
        )
    t = streams.scan_stamps_s
    t = t[(t >= od.stamps_s[0]) & (t <= od.stamps_s[-1])]
    if len(t) < MIN_SCANS:
        raise InputError.at(
            streams.sequence.folder, "odometry", f"{len(t)} scan(s) within its span", f"at least {MIN_SCANS}"
        )
    T = np.eye(3)
    poses = [pose_of(T)]
    steps = laser_motions(od, t)
    gaps = ~np.isfinite(steps).all(axis=1)  # across a gap in the odometry: the pose is held
    for step in np.where(gaps[:, None], 0.0, steps):
        T = T @ se2(step)
        poses.append(pose_of(T))
    stats: dict[str, Any] = {"odometry_poses": len(od.stamps_s)}
    if gaps.any():
        stats["odometry_gaps_held"] = int(gaps.sum())
    return Estimate(t, np.array(poses), stats)


def _matching_estimate(streams: Streams, method: str, params: IasmParams) -> Estimate:
    stamps, poses, stats, steps = scan_matching(streams, method, params)
    return Estimate(stamps, poses, stats, steps)


def _icp_p2p(streams: Streams) -> Odometry:
    """Point-to-point ICP over the scans, started from the wheel odometry as the default
    laser odometry is (:meth:`Streams.wheel_starts`)."""
    guess, gap_guess = streams.wheel_starts()
    return icp_odometry(streams.scans, LASER_ODOMETRY["icp-p2p"], guess=guess, gap_guess=gap_guess)


# name -> the method's estimate from the streams and IASM's and H-IASM's settings.
METHODS: dict[str, Callable[[Streams, IasmParams], Estimate]] = {
    "icp": lambda s, _: _icp_estimate(s, s.laser_odometry()),
    "icp-p2p": lambda s, _: _icp_estimate(s, _icp_p2p(s)),
    "odom": lambda s, _: _wheel_estimate(s),
    "vo": lambda s, _: _vo_estimate(s, _vo_result(s)),
    "kf": lambda s, _: _kf_estimate(s),
    "iasm": lambda s, p: _matching_estimate(s, "iasm", p),
    "hiasm": lambda s, p: _matching_estimate(s, "hiasm", p),
}


# Methods that track image features (and use the laser odometry too): the laser odometry
# then runs beside the tracking on a second thread.
TRACKING = ("vo", "kf", "hiasm")
# Methods that read the images (and so the rig's camera).
IMAGE_METHODS = ("vo", "kf", "iasm", "hiasm")

# The shared stages (their keys in the stage timings) each method's estimate is built on;
# a method's own time leaves them out, wherever they ran (before the methods, or inside
# the first method that needed them).
SHARED_STAGES: dict[str, tuple[str, ...]] = {
    "icp": ("icp_s",),
    "icp-p2p": (),
    "vo": ("tracks_s", "icp_s", "vo_s"),
    "kf": ("tracks_s", "icp_s", "vo_s"),
    "iasm": ("icp_s",),
    "hiasm": ("tracks_s", "icp_s"),
    "odom": (),
}


@dataclass(frozen=True)
class MethodRun:
    """One method's output: its estimate in the world frame (anchored to the truth's first
    pose when there is ground truth), its metrics, and its time."""

    method: str
    stamps_s: FloatArray
    poses: FloatArray
    metrics: dict[str, Any] | None
    stats: dict[str, Any]
    seconds: float  # its own work, without the shared stages
    steps_csv: str | None = None
    shared_s: dict[str, float] = field(default_factory=dict)  # the shared stages it uses
    closures: LoopResult | None = None

    @property
    def total_s(self) -> float:
        """Its own seconds and those of the shared stages it uses (stages that ran side by
        side, as the laser odometry beside the feature tracks, count in full)."""
        return self.seconds + sum(self.shared_s.values())


@dataclass(frozen=True)
class Run:
    """What a run produced: one entry per method, the shared stage timings, the truth."""

    methods: list[MethodRun]
    timings_s: dict[str, float]
    duration_s: float
    truth: Trajectory | None
    wall_s: float = 0.0
    iasm: IasmParams = field(default_factory=IasmParams)
    cpu_s: float = 0.0  # CPU seconds over the same span as wall_s, all threads
    tracks: TrackParams = field(default_factory=TrackParams)
    wheel_odometry: str = "none"  # "used", "ignored" or "none" (the sequence has none)
    kf: kalman.KfParams = field(default_factory=kalman.KfParams)
    # Images left out of the image methods, stamped before the first scan or after the last.
    images_outside_scans: dict[str, int] = field(default_factory=lambda: {"before": 0, "after": 0})
    # The sequence's 16-bit frames, read as 8 bits (frames, max_level, shift_bits; empty: none).
    images_16_bit: dict[str, int] = field(default_factory=dict)
    gyro: str = "none"  # "used" (by method kf), "ignored" or "none" (the sequence has none)


def _shared_stages(streams: Streams, methods: list[str]) -> None:
    """Compute the stages several methods share, before the methods: the feature tracks
    (when a method tracks images) with the laser odometry beside them on a second thread,
    then the laser odometry (every method but icp-p2p pairs scans and images with it)."""
    tracking = [m for m in methods if m in TRACKING and (m != "kf" or kf_has_images(streams))]
    _require_images(streams, methods)  # a clear error before any work
    streams.results["images_outside_scans"] = _leave_out_outside(streams, methods)
    if tracking:
        streams.start_laser_odometry()
        streams.feature_tracks()
    if any(m != "icp-p2p" for m in methods):
        streams.laser_odometry()


def _warn_gaps(streams: Streams) -> None:
    """Read the wheel odometry and say (one warning) where it has gaps the scans cross."""
    od = streams.sequence.odometry
    if od is None or len(streams.scan_stamps_s) < 2:
        return
    gaps = across_gaps(od, streams.scan_stamps_s)
    if gaps.any():
        long = float(np.diff(od.stamps_s).max())
        log.warning(
            "the wheel odometry pauses for over %.3g s between %d pair(s) of scans (the longest pause "
            "%.3g s): its motion there starts ICP unless the scans contradict it, the filter takes it "
            "there only where they kept it, and method odom takes none",
            gap_s(od),
            int(gaps.sum()),
            long,
        )


def _leave_out_outside(streams: Streams, methods: list[str]) -> dict[str, int]:
    """Leave out of the image methods the images stamped before the first scan or after
    the last (:meth:`Streams.leave_out_images_outside_scans`), and say how many (none
    without an image method: nothing reads them)."""
    if not any(m in IMAGE_METHODS for m in methods):
        return {"before": 0, "after": 0}
    out = streams.leave_out_images_outside_scans()
    if out["before"] or out["after"]:
        _require_images(streams, methods)  # those left may be too few
    return out


def _require_images(streams: Streams, methods: list[str]) -> None:
    """An error naming every method given that needs images, and those that would run,
    when the sequence has fewer than 2; else each image method's own checks (the rig, the
    images' clock and size: :meth:`Streams.require_images`)."""
    need = [m for m in methods if m in IMAGE_METHODS]
    if streams.n_images < 2 and streams.wheel_odometry is not None and "kf" in need:
        need.remove("kf")  # the filter fuses ICP and the wheel odometry (:func:`kf_has_images`)
    if need and streams.n_images < 2:
        odom = streams.sequence.has_odometry
        wheels = streams.wheel_odometry is not None  # the filter runs on ICP and them
        can = [
            m for m in METHODS if (m not in IMAGE_METHODS or (m == "kf" and wheels)) and (m != "odom" or odom)
        ]
        raise InputError.at(
            streams._yaml(),
            "images.count",
            streams.n_images,
            f"at least 2 images for --method {','.join(need)}; without images, --method {','.join(can)} run",
        )
    for m in need:
        streams.require_images(m)


def parse_methods(text: str, key: str = "--method") -> list[str]:
    """A comma-separated method list, validated (``key`` names it in messages)."""
    names = [m.strip() for m in text.split(",") if m.strip()]
    for m in names:
        if m not in METHODS:
            raise InputError.at(None, key, m, f"one of {sorted(METHODS)} (comma-separated)")
    if not names or len(set(names)) != len(names):
        raise InputError.at(None, key, text, "one or more distinct methods, comma-separated")
    return names


def parse_iasm_settings(items: tuple[str, ...] | list[str]) -> IasmParams:
    """IASM's and H-IASM's settings from ``KEY=VALUE`` texts (``--iasm``), each KEY a field
    of :class:`IasmParams` and each VALUE of its type (a number, or true/false)."""
    return parse_settings(items, IasmParams(), "--iasm")


def parse_track_settings(items: tuple[str, ...] | list[str]) -> TrackParams:
    """The feature tracks' settings from ``KEY=VALUE`` texts (``--tracks``), each KEY a field
    of :class:`TrackParams`: e.g. ``detector=sift``, ``n_features=500``."""
    return parse_settings(items, TrackParams(), "--tracks")


def parse_settings[S: (IasmParams, TrackParams)](
    items: tuple[str, ...] | list[str], defaults: S, option: str
) -> S:
    """``defaults`` (a dataclass of settings) with the ``KEY=VALUE`` texts of ``option``
    applied: each KEY a field, each VALUE of the field's type (a number 0 to 1e9,
    true/false, or for a text field one of its ``choices``).

    Raises:
        InputError: naming the option, the item and what was expected.
    """
    fields = sorted(f.name for f in dataclasses.fields(defaults))
    changes: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep or key not in fields:
            raise InputError.at(None, option, item, f"KEY=VALUE with KEY one of {fields}")
        kind = type(getattr(defaults, key))
        text = text.strip()
        value: Any
        if kind is bool:
            if text.lower() not in ("true", "false", "1", "0"):
                raise InputError.at(None, f"{option} {key}", text, "true or false")
            value = text.lower() in ("true", "1")
        elif kind is str:
            choices: tuple[str, ...] = getattr(defaults, "choices", {}).get(key, ())
            if text not in choices:
                raise InputError.at(None, f"{option} {key}", text, f"one of {', '.join(choices)}")
            value = text
        else:
            try:
                value = kind(text)
                value = value if -1e18 < value < 1e18 else None
            except (ValueError, OverflowError):
                value = None
            if value is None or not math.isfinite(value) or not 0 <= value <= 1e9:
                what = "a whole number" if kind is int else "a number"
                raise InputError.at(None, f"{option} {key}", text, f"{what}, 0 or more (at most 1e9)")
        changes[key] = value
    try:
        return dataclasses.replace(defaults, **changes)
    except ValueError as e:  # a value the settings refuse (their __post_init__)
        raise InputError.at(None, option, " ".join(items), str(e)) from None


def run(
    sequence: str | Path,
    methods: list[str],
    rig_file: str | Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    iasm: IasmParams | None = None,
    tracks: TrackParams | None = None,
    wheel_odometry: bool = True,
    loop_closure: LoopParams | None = None,
    kf: kalman.KfParams | None = None,
    place_recognition: PlaceParams | None = DEFAULT_PLACE,
    gyro: bool = False,
) -> Run:
    """Localize a sequence with each method; :func:`rigcal.viz.localize_output.write_run`
    writes the output folder. ``iasm``: IASM's and H-IASM's settings, ``tracks`` the
    feature tracks' (the defaults unless given). ``wheel_odometry``: start ICP from the
    sequence's wheel odometry (when it has one) and fuse it in the Kalman filter; False
    ignores it. ``loop_closure``: also run each of :data:`LOOP_CLOSURE_METHODS` chosen with
    loop closure, as ``METHOD+lc``. ``kf``: the Kalman filter's settings
    (:data:`rigcal.localize.kalman.KF_MODES`; the weighted filter unless given).
    ``place_recognition``: loop closure's image place recognition's settings, None for
    the scan search alone. ``gyro``: the Kalman filter fuses the sequence's gyroscope
    (when it has one); False, the default, ignores it.

    Raises:
        InputError: an unknown method, or a sequence that cannot be localized.
    """
    for m in methods:
        if m not in METHODS:
            raise InputError.at(None, "--method", m, f"one of {sorted(METHODS)}")
    iasm = iasm or IasmParams()
    kf = kf or kalman.KfParams()
    streams = open_streams(sequence, rig_file)
    streams.progress = progress
    streams.track_params = tracks or TrackParams()
    streams.use_wheel_odometry = wheel_odometry
    streams.use_gyro = gyro
    if gyro and "kf" in methods:
        _ = streams.gyro  # its file read now, before any work (read only when used)
    if wheel_odometry or "odom" in methods:
        _warn_gaps(streams)  # its file read now, before any work (read only when used)
    if len(streams.scans) < MIN_SCANS:
        raise InputError.at(
            Path(sequence) / "sequence.yaml", "scans.count", len(streams.scans), f"at least {MIN_SCANS} scans"
        )
    truth = _ground_truth(Path(sequence), streams.sequence.groundtruth_file)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    results = []
    try:
        _shared_stages(streams, methods)
        for name in methods:
            shared = SHARED_STAGES[name]
            before = {k: streams.timings_s.get(k, 0.0) for k in shared}
            t0 = time.perf_counter()
            est = _kf_estimate(streams, kf) if name == "kf" else METHODS[name](streams, iasm)
            seconds = time.perf_counter() - t0
            # A shared stage first needed here ran inside this method's time: not its own.
            seconds -= sum(streams.timings_s.get(k, 0.0) - before[k] for k in shared)
            shared_s = {k: streams.timings_s[k] for k in shared if k in streams.timings_s}
            poses, metrics = est.poses, None
            if truth is not None:
                gt = planar_at(truth, est.stamps_s)
                poses = anchored(est.poses, gt)  # the estimate in the world frame
                metrics = evaluate(poses, gt)
            results.append(
                MethodRun(
                    name, est.stamps_s, poses, metrics, est.stats, max(seconds, 0.0), est.steps_csv, shared_s
                )
            )
            log.info("%s: %d poses in %.1f s of its own", name, len(est.stamps_s), seconds)
            if loop_closure is not None and name in LOOP_CLOSURE_METHODS:
                t0 = time.perf_counter()
                lc = _loop_closed(streams, est, loop_closure, place_recognition)
                seconds += time.perf_counter() - t0
                poses, metrics = lc.poses, None
                if truth is not None:
                    gt = planar_at(truth, lc.stamps_s)
                    poses = anchored(lc.poses, gt)
                    metrics = evaluate(poses, gt)
                results.append(
                    MethodRun(
                        f"{name}+lc",
                        lc.stamps_s,
                        poses,
                        metrics,
                        lc.stats,
                        max(seconds, 0.0),
                        None,
                        shared_s,
                        lc.closures,
                    )
                )
    finally:
        streams.stop_background()
    stamps = streams.scan_stamps_s
    duration = float(stamps[-1] - stamps[0])
    wall, cpu = time.perf_counter() - t_start, time.process_time() - cpu_start
    wheel = "none" if not streams.sequence.has_odometry else "used" if wheel_odometry else "ignored"
    outside = streams.results.get("images_outside_scans", {"before": 0, "after": 0})
    used = "used" if gyro and "kf" in methods else "ignored"
    return Run(
        results,
        dict(streams.timings_s),
        duration,
        truth,
        wall,
        iasm,
        cpu,
        streams.track_params,
        wheel,
        kf,
        outside,
        dict(streams.results.get("images_16_bit", {})),
        used if streams.sequence.has_gyro else "none",
    )


def summary(r: Run, sequence: Path) -> dict[str, Any]:
    """The run's summary (written as summary.yaml and summary.json)."""
    return {
        "config": {
            "sequence": str(sequence.resolve()),
            "methods": [m.method for m in r.methods],
            "settings": settings(r.iasm, r.tracks, r.kf),
            "wheel_odometry": r.wheel_odometry,
            "gyro": r.gyro,
        },
        "duration_s": round(r.duration_s, 3),
        **({"images_outside_scans": dict(out)} if any((out := r.images_outside_scans).values()) else {}),
        **({"images_16_bit": dict(r.images_16_bit)} if r.images_16_bit else {}),
        "wall_s": round(r.wall_s, 3),
        "x_real_time": round(r.duration_s / r.wall_s, 2) if r.wall_s > 0 else None,
        "stage_timings_s": {k: round(v, 3) for k, v in r.timings_s.items()},
        "methods": {
            m.method: {
                "poses": len(m.stamps_s),
                "seconds": round(m.seconds, 3),
                "shared_stages_s": {k: round(v, 3) for k, v in m.shared_s.items()},
                "total_s": round(m.total_s, 3),
                **m.stats,
                "metrics": m.metrics,
            }
            for m in r.methods
        },
    }


def settings(
    iasm: IasmParams | None = None, tracks: TrackParams | None = None, kf: kalman.KfParams | None = None
) -> dict[str, Any]:
    """The methods' effective settings (the defaults, as docs/localization.md describes
    them, with IASM's and H-IASM's ``iasm``, the feature tracks' ``tracks`` and the Kalman
    filter's ``kf`` when given)."""
    from dataclasses import asdict

    from rigcal.localize.vo import VoParams

    return {
        "icp": asdict(IcpParams(method="point-to-line")),
        "vo": asdict(VoParams()),
        "kf": {
            **asdict(kf or kalman.KfParams()),
            "icp_sigmas_forward_cross_yawrate": list(kalman.ICP_SIGMAS),
            "vo_sigmas_forward_cross_yawrate": list(kalman.VO_SIGMAS),
            "wheel_sigmas_forward_cross_yawrate": list(kalman.WHEEL_SIGMAS),
        },
        "iasm": asdict(iasm or IasmParams()),
        "hiasm_vo": asdict(VoParams()),
        "tracks": asdict(tracks or TrackParams()),
    }


def _ground_truth(folder: Path, name: str | None) -> Trajectory | None:
    if name is None:
        return None
    traj = read_tum(folder / name)
    if len(traj) < 2:
        raise InputError(f"{folder / name}: ground truth has {len(traj)} poses; expected at least 2")
    return traj


def planar_at(traj: Trajectory, stamps: FloatArray) -> FloatArray:
    """(N, 3) planar poses of a trajectory interpolated at the stamps."""
    assert traj.stamps_s is not None
    x = np.interp(stamps, traj.stamps_s, traj.poses[:, 0, 3])
    y = np.interp(stamps, traj.stamps_s, traj.poses[:, 1, 3])
    yaw = np.unwrap(np.arctan2(traj.poses[:, 1, 0], traj.poses[:, 0, 0]))
    return np.column_stack([x, y, np.interp(stamps, traj.stamps_s, yaw)])


def table(rows: list[tuple[str, dict[str, Any]]], precision: int | None = None) -> str:
    """The paper's Table 1 (plus ATE and RPE) as a Markdown table, each figure with
    ``precision`` decimals (None: as the figures are)."""
    keys = (
        "loop_closure_error_m",
        "loop_closure_error_percent",
        "average_position_error_m",
        "ate_rmse_m",
        "rpe_1m_rmse_m",
        "rpe_10m_rmse_m",
    )
    head = (
        "| method | loop closure (m) | loop closure (%) | avg position error (m) | ATE RMSE (m) "
        "| RPE 1 m (m) | RPE 10 m (m) |\n|---|---|---|---|---|---|---|"
    )
    lines = [head]
    lines += [f"| {label} | " + " | ".join(_cell(m[k], precision) for k in keys) + " |" for label, m in rows]
    return "\n".join(lines)


def _cell(v: Any, precision: int | None = None) -> str:
    """A table cell: "-" where a figure is undefined (no loop; a path shorter than the RPE)."""
    if v is None:
        return "-"
    return str(v) if precision is None else f"{v:.{precision}f}"
