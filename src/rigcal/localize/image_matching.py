"""IASM and H-IASM over a sequence (paper Fig. 7), with the documented fallbacks.

:class:`ScanMatcher` builds each image's frame (its scan moved to the image's time and
projected) and runs one step between two frames: H-IASM when visual odometry between the
two images and a scale are available, else IASM, else -- H-IASM only, where the laser
odometry is degenerate between the two images -- visual odometry with the carried scale
aligned with the walls (:func:`rigcal.localize.hiasm.visual_fallback`), else ICP between
the two scans (H-IASM -> IASM -> VO -> ICP). ICP's motion is the laser odometry's
(point-to-line over every scan) between the two images' stamps; an H-IASM or IASM motion
that lies more than ``IasmParams.odometry_gate_m`` from it, where the odometry is
constrained, fails as well. Each step's joint polish aligns scan t+1 with a keyframe's
scan (``IasmParams.keyframe_m``), and so does a fallback to ICP. Each fallback is logged
(logger ``rigcal.localize``) and counted in the run's summary.
:func:`scan_matching` chains the steps over a sequence; :func:`step_matches` finds one
step's correspondences (the paper's Fig. 5).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.geometry import pose_of, se2
from rigcal.localize.hiasm import camera_motion, hiasm_step, visual_fallback
from rigcal.localize.iasm import Frame, IasmParams, Matches, StepResult, iasm_step, make_frame
from rigcal.localize.odometry import DEGENERATE_BELOW
from rigcal.localize.polish import LaserReference, joint_polish, keyframe_reference, new_keyframe
from rigcal.localize.prefetch import computed_ahead
from rigcal.localize.streams import Streams
from rigcal.localize.tracks import FrameTracks, Tracker, common
from rigcal.localize.vo import RelativePose, VoParams, planar_motion, relative_pose

log = logging.getLogger("rigcal.localize")

# A step whose camera moved less than this (m) stood still.
STILL_SCALE_M = 0.005
# Frames built in advance of the steps.
FRAMES_AHEAD = 4


@dataclass(frozen=True)
class Step:
    """One step's outcome: the motion T_t_t1, the method that gave it, its details."""

    motion: FloatArray
    used: str  # "hiasm", "iasm", "vo" or "icp"
    result: StepResult | None
    matches: Matches | None
    why_fallback: str | None


class ScanMatcher:
    """IASM (``hierarchical=False``) or H-IASM (``True``) on one sequence's streams."""

    def __init__(
        self,
        streams: Streams,
        method: str,
        params: IasmParams | None = None,
        tracks: Mapping[int, FrameTracks] | Sequence[FrameTracks] | None = None,
    ) -> None:
        rig = streams.require_rig(method)
        streams.require_images(method)
        self.streams = streams
        self.camera = rig.camera
        self.T_cam_laser = rig.T_cam_laser
        self.params = params or IasmParams()
        self.vo_params = VoParams()
        self.hierarchical = method == "hiasm"
        # H-IASM's visual odometry between successive images: the shared feature tracks.
        self.tracks = None
        if self.hierarchical:
            self.tracks = streams.feature_tracks() if tracks is None else tracks
        self.focal = float(np.mean(self.camera.intrinsics[:2]))
        self.rng = np.random.default_rng(0)
        # The scale of the last step that moved: visual odometry's fallback takes it after
        # a stop (a still step's scale is 0; visual odometry itself sees a stop).
        self.moving_scale: float | None = None
        self.timings_s = {"frames_s": 0.0, "matching_s": 0.0}

    def frame(self, i: int) -> tuple[Frame, FrameTracks | None]:
        """Image i's frame and, for H-IASM, its feature tracks."""
        t0 = time.perf_counter()
        k, T_image_scan = self.streams.scan_to_image(i)
        f = make_frame(
            self.streams.image(i),
            self.streams.scans[k],
            self.camera,
            self.T_cam_laser,
            self.params,
            self.streams.lines(k),
            T_image_scan,
        )
        self.timings_s["frames_s"] += time.perf_counter() - t0
        return f, None if self.tracks is None else self.tracks[i]

    def carry(self, motion: FloatArray) -> float:
        """A step's scale, carried to the next step (the paper's s_{t-1}); the last moving
        step's is kept as well (:attr:`moving_scale`)."""
        scale = self.scale_of(motion)
        if scale > STILL_SCALE_M:
            self.moving_scale = scale
        return scale

    def scale_of(self, motion: FloatArray) -> float:
        """The length of the camera's translation for a laser motion (x, y, yaw)."""
        return float(np.linalg.norm(camera_motion(motion, self.T_cam_laser)[1]))

    def odometry_gap(self, motion: FloatArray, odometry: FloatArray, constrained: bool) -> str | None:
        """Why an image step's motion cannot be right, or None: it moves more than
        ``odometry_gate_m`` away from the laser odometry's motion between the two images
        while every scan step between them constrains the odometry (``constrained``,
        :meth:`odometry_constrained`)."""
        gate = self.params.odometry_gate_m
        gap = float(np.hypot(*(motion[:2] - odometry[:2])))
        if gate <= 0 or gap <= gate or not constrained:
            return None
        return f"{gap:.2f} m off the laser odometry"

    def odometry_constrained(self, i1: int, i2: int) -> bool:
        """Whether the walls constrain every scan step of the laser odometry between images
        i1 and i2 (degeneracy indicator at least DEGENERATE_BELOW): not along a corridor
        whose ends are out of the laser's range."""
        t, ts = self.streams.image_stamps_s, self.streams.scan_stamps_s
        between = (ts > t[i1]) & (ts <= t[i2])
        degeneracy = self.streams.laser_odometry().degeneracy[between]
        return not (len(degeneracy) and float(degeneracy.min()) < DEGENERATE_BELOW)

    def visual_odometry(self, tr1: FrameTracks, tr2: FrameTracks) -> tuple[RelativePose | None, str]:
        """Visual odometry between two images (rotation, unit translation) from the shared
        feature tracks, or None and why it cannot be trusted."""
        ia, ib = common(tr1, tr2)
        rel = relative_pose(
            tr1.bearings[ia], tr2.bearings[ib], self.focal, self.vo_params, self.T_cam_laser[:3, 0]
        )
        if rel is None:
            return None, "no visual odometry between the images"
        if not planar_motion(rel.R, rel.t_unit, self.T_cam_laser[:3, 2]):
            return None, "visual odometry gives a motion a ground rig cannot make"
        return rel, ""

    def try_hiasm(
        self,
        f1: Frame,
        f2: Frame,
        rel: RelativePose | None,
        vo_why: str,
        scale: float | None,
        reference: LaserReference | None = None,
    ) -> tuple[StepResult | None, Matches | None, str]:
        """An H-IASM step (the result, its matches), or None and why it could not be made;
        ``rel``: visual odometry between the two images (None: ``vo_why``)."""
        if scale is None:
            return None, None, "no scale yet (first pair)"
        if rel is None:
            return None, None, vo_why
        res, m = hiasm_step(
            f1, f2, rel.R, rel.t_unit, scale, self.camera, self.T_cam_laser, self.params, self.rng, reference
        )
        return res, m, "no motion consistent with the correspondences (and the scans)"

    def step(
        self,
        f1: Frame,
        f2: Frame,
        tr1: FrameTracks | None,
        tr2: FrameTracks | None,
        scale: float | None,
        i1: int,
        i2: int,
        reference: LaserReference | None = None,
    ) -> Step:
        """The motion between frames of images i1 and i2, falling back H-IASM -> IASM -> VO
        (H-IASM only, where the laser odometry is degenerate) -> ICP.

        ``scale``: the previous step's (the paper's, carried over); H-IASM takes the laser
        odometry's between the two images instead with ``IasmParams.odometry_scale``,
        where the walls constrain the odometry (:meth:`odometry_constrained`; along a
        corridor they do not, and the odometry's step is short).
        """
        t0 = time.perf_counter()
        why = None
        t = self.streams.image_stamps_s
        odometry = self.streams.odometry_motion(float(t[i1]), float(t[i2]))
        constrained = self.odometry_constrained(i1, i2)
        if self.params.odometry_scale and (scale is None or constrained):
            scale = self.scale_of(odometry)
        rel = None
        if tr1 is not None and tr2 is not None:
            rel, vo_why = self.visual_odometry(tr1, tr2)
            res, m, why = self.try_hiasm(f1, f2, rel, vo_why, scale, reference)
            if res is not None:
                gap = self.odometry_gap(res.motion, odometry, constrained)
                if gap is None:
                    self.timings_s["matching_s"] += time.perf_counter() - t0
                    return Step(res.motion, "hiasm", res, m, None)
                res, why = None, gap
        res, m = iasm_step(f1, f2, self.camera, self.T_cam_laser, self.params, self.rng, reference)
        self.timings_s["matching_s"] += time.perf_counter() - t0
        gap = None if res is None else self.odometry_gap(res.motion, odometry, constrained)
        if res is not None and gap is None:
            return Step(res.motion, "iasm", res, m, why)
        failed = gap or "too few correspondences"
        why = failed if why is None else f"{why}; IASM: {failed}"
        if rel is not None and scale is not None and not constrained:
            # H-IASM along a corridor whose ends the laser cannot see: visual odometry.
            vo_scale = scale if self.moving_scale is None else self.moving_scale
            motion = visual_fallback(
                f1, f2, rel.R, rel.t_unit, vo_scale, self.T_cam_laser, self.params, reference
            )
            return Step(motion, "vo", None, m, why)
        # ICP: the laser odometry's motion (point-to-line over every scan) between the stamps.
        motion = odometry
        if reference is not None:
            # Aligned with the keyframe's scan as well, as the image steps are.
            none = np.zeros((0, 2))
            motion = joint_polish(
                motion, none, none, reference.points, f2.points, self.params, reference.normals, motion
            )
        return Step(motion, "icp", None, m, why)


def scan_matching(
    streams: Streams, method: str, params: IasmParams | None = None
) -> tuple[FloatArray, FloatArray, dict[str, Any], str]:
    """Chain IASM or H-IASM steps over successive images (``params``: the defaults unless given).

    Returns:
        the image stamps, the laser's poses there (first at the origin), the counts
        (steps by method, fallbacks, metric chosen, mean inliers) and a CSV table of
        every step (image, stamp, method used, metric, correspondences, inliers, why it
        fell back).
    """
    sm = ScanMatcher(streams, method, params)
    streams.laser_odometry()  # pairs scans with images (timed on its own)
    # Each image's frame depends on the streams alone: built ahead on a second thread
    # while the steps run (their kernels release the interpreter).
    frames = computed_ahead(sm.frame, streams.n_images, FRAMES_AHEAD)
    _, (f1, tr1) = next(frames)
    used = {"hiasm": 0, "iasm": 0, "vo": 0, "icp": 0}
    metric = {"laser": 0, "image": 0}
    inliers: list[int] = []
    motions: list[FloatArray] = []
    scale: float | None = None
    rows = ["image,stamp_s,used,metric,correspondences,inliers,fallback"]
    key, T_key, n_keys = f1, np.eye(3), 1  # the keyframe, frame f1's pose in its frame
    for i, (f2, tr2) in frames:
        streams.report(method.upper(), i + 1, streams.n_images)
        reference = None if key is f1 else keyframe_reference(key, T_key)
        st = sm.step(f1, f2, tr1, tr2, scale, i - 1, i, reference)
        T_key = T_key @ se2(st.motion)
        if new_keyframe(T_key, sm.params):
            key, T_key, n_keys = f2, np.eye(3), n_keys + 1
        used[st.used] += 1
        n_corr = 0 if st.matches is None else len(st.matches.i1)
        res = st.result
        rows.append(
            f"{i},{float(streams.image_stamps_s[i])!r},{st.used},{res.metric if res else ''},"
            f"{n_corr},{res.inliers if res else ''},{(st.why_fallback or '').replace(',', ';')}"
        )
        if st.why_fallback is not None:
            log.info(
                "image %d: %s falls back to %s (%s)", i, method.upper(), st.used.upper(), st.why_fallback
            )
        if st.result is not None:
            metric[st.result.metric] += 1
            inliers.append(st.result.inliers)
        # The paper's scale, carried to the next step (H-IASM takes the laser odometry's
        # between the two images instead where the walls constrain it).
        scale = sm.carry(st.motion)
        motions.append(st.motion)
        f1, tr1 = f2, tr2
    for k, v in sm.timings_s.items():
        streams.timings_s[f"{method}_{k}"] = v
    own = used["hiasm"] if sm.hierarchical else used["iasm"]
    stats = {
        "steps_by": used,
        "fallbacks": len(motions) - own,
        "metric": metric,
        "mean_inliers": round(float(np.mean(inliers)), 1) if inliers else 0.0,
        "keyframes": n_keys,
    }
    return streams.image_stamps_s, chain(motions), stats, "\n".join(rows) + "\n"


@dataclass(frozen=True)
class StepMatches:
    """The correspondences of one step between two images (the paper's Fig. 5), as
    :func:`rigcal.viz.matches_plot.step_figure` draws them.

    Attributes:
        gray1, gray2: the two images.
        returns1, returns2: (N, 2) pixels of each scan's visible returns.
        match1, match2: (M, 2) pixels of the matched returns in image 1 and image 2.
        inlier: (M,) which matches agree with the final motion.
        title, labels: the picture's title and the two images' titles.
        step: the step itself (its motion, method used, result).
    """

    gray1: NDArray[np.uint8]
    gray2: NDArray[np.uint8]
    returns1: FloatArray
    returns2: FloatArray
    match1: FloatArray
    match2: FloatArray
    inlier: NDArray[np.bool_]
    title: str
    labels: tuple[str, str]
    step: Step


def step_matches(streams: Streams, i: int, method: str) -> StepMatches:
    """The correspondences of the step from image i to image i+1 (Fig. 5), with pixels.

    H-IASM's scale is, as in a run, the laser odometry's between the two images where
    the walls constrain it, else (and with ``IasmParams.odometry_scale`` False) that of
    a step on the images before (i-1, i).
    """
    tracks = None
    if method == "hiasm":
        rig = streams.require_rig(method)
        tracker = Tracker(rig.camera)
        tracks = {k: tracker.step(streams.image(k)) for k in range(max(i - 1, 0), i + 2)}
    sm = ScanMatcher(streams, method, tracks=tracks)
    f1, tr1 = sm.frame(i)
    f2, tr2 = sm.frame(i + 1)
    scale = None
    if sm.hierarchical and i > 0:
        f0, tr0 = sm.frame(i - 1)
        prev = sm.step(f0, f1, tr0, tr1, None, i - 1, i)
        scale = sm.carry(prev.motion)
    st = sm.step(f1, f2, tr1, tr2, scale, i, i + 1)
    m = st.matches
    if m is None or len(m.i1) == 0:
        p1 = p2 = np.zeros((0, 2))
        inl = np.zeros(0, dtype=bool)
    else:
        p1, p2 = f1.pixels[m.i1], f2.pixels[m.i2]
        inl = st.result.inlier_mask if st.result is not None else np.zeros(len(m.i1), dtype=bool)
    n_in = int(inl.sum())
    metric = st.result.metric if st.result is not None else "-"
    title = f"{st.used.upper()} images {i}->{i + 1}: {len(p1)} matches, {n_in} inliers, {metric} metric"
    return StepMatches(
        f1.gray,
        f2.gray,
        f1.pixels[f1.visible],
        f2.pixels[f2.visible],
        p1,
        p2,
        inl,
        title,
        (f"image {i}", f"image {i + 1}"),
        st,
    )


def chain(motions: list[FloatArray]) -> FloatArray:
    """(N+1, 3) poses from successive motions, starting at the origin."""
    T = np.eye(3)
    out = [pose_of(T)]
    for m in motions:
        T = T @ se2(m)
        out.append(pose_of(T))
    return np.array(out)
