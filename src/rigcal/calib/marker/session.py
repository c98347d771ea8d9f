"""Marker sessions: captures of the V marker target, read with no hand input.

A marker session file (docs/formats/marker-session.md) names the camera, the targets file
(:mod:`rigcal.targets.marker`) and per capture a scan and an image. :func:`read_marker_session`
validates it and, for every capture:

1. reads the target in the image (:func:`rigcal.calib.marker.detect.detect_target`): the
   target's pose by one PnP over the ChArUco corners of both faces, with its covariance,
   each face's own pose checked against it; markers of other targets are ignored and
   counted;
2. finds the V in the scan (:func:`_search_v`): the static background dropped across
   captures, straight pieces of the moving returns that meet at an apex are candidate
   Vs, a RANSAC over captures and candidate arms gives a rough pose, and each face's
   returns are re-picked near the cut its pose predicts, as the board method re-picks a
   board's (:mod:`rigcal.calib.board.detect`).

A capture whose target pose is not read, or whose V is not found in the scan, is set
aside with the reason, and the others go on. Each kept capture becomes two
:class:`~rigcal.calib.board.plane.PlaneObservation` (one per face, named ``CAPTURE/FACE``) that
share the target's pose (``pose_key``: the plane solve whitens them together, their errors
from the one pose being one error), so the board method's solve takes them as they are.

A capture's laser side is one scan, or (schema version 2) the scans of its still moment,
``scans``, reduced to their per-beam robust mean (:func:`rigcal.scan.mean_scan`): the
independent range noise averages down, what every scan repeats stays, and the solve
estimates the noise left from the mean's own line fits.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.calib.board.detect import BoardShape
from rigcal.calib.board.plane import MIN_CAPTURES, PlaneObservation
from rigcal.calib.board.session import plane_observation
from rigcal.calib.box.picks import (
    capture_name,
    check_image,
    check_unique_names,
    file_entry,
    read_capture_scans,
    read_session_header,
    scan_entries,
    session_file,
)
from rigcal.calib.marker.detect import MIN_FACE_CORNERS, TargetView, detect_target
from rigcal.camera import Camera
from rigcal.errors import CalibrationError, InputError
from rigcal.geometry import line_intersection
from rigcal.io.files import check_keys, get_float
from rigcal.lines import LineParams, fit_line
from rigcal.scan import Scan
from rigcal.targets.marker import MarkerTarget, read_targets

MARKER_SESSION_SCHEMA_VERSION = 2
# Versions read: 2 adds a capture's ``scans`` (the scans of one still moment).
MARKER_SESSION_SCHEMA_VERSIONS = (1, 2)
DEFAULT_CORNER_SIGMA_PX = 0.3


@dataclass(frozen=True)
class MarkerSession:
    """A marker session, read and detected.

    Attributes:
        path: the session file.
        camera, camera_path: the camera and its file.
        target: the marker target.
        laser: the scanner's description.
        captures: every capture's name, in file order.
        found: the names of the captures kept (both faces read, the V found).
        dropped: (name, reason) of the captures set aside.
        observations: two plane observations per kept capture (left face, right face),
            sharing the capture's target pose.
        views: the target as read in each kept capture, in the captures' order.
        corner_rms_px: (2K,) each observation's RMS corner reprojection error (its
            capture's, over both faces' corners).
        foreign_ids: per capture name, the ids of markers not on the target it showed.
        files: every file read (for provenance).
        corner_sigma_px: the corner noise the target poses' covariances were computed with.
        disagreements: (name, why) of the kept captures where a face's own pose disagrees
            with the target's.
        scans_per_capture: per capture name, how many scans its laser side is the mean of.
        rigid: the faces were posed as one target (False: they disagreed with the targets
            file in most captures, :func:`faces_agree`, or one pose per face was asked for,
            and each face was posed on its own).
        joint: one pose for the whole target was asked for (``read_marker_session``'s
            ``joint``).
        pose_fits: (RMS reprojection error px, corners) of every pose the planes came from.
    """

    path: Path
    camera: Camera
    camera_path: Path
    target: MarkerTarget
    laser: dict[str, Any]
    captures: tuple[str, ...]
    found: tuple[str, ...]
    dropped: tuple[tuple[str, str], ...]
    observations: tuple[PlaneObservation, ...]
    views: tuple[TargetView, ...]
    corner_rms_px: FloatArray
    foreign_ids: dict[str, tuple[int, ...]]
    files: tuple[Path, ...]
    corner_sigma_px: float = DEFAULT_CORNER_SIGMA_PX
    disagreements: tuple[tuple[str, str], ...] = ()
    scans_per_capture: dict[str, int] = field(default_factory=dict)
    rigid: bool = True
    pose_fits: tuple[tuple[float, int], ...] = ()
    joint: bool = True
    # The board report's "left out" list; a marker session's set-aside captures are ``dropped``.
    skipped: tuple[str, ...] = ()


def is_marker_session(data: Any) -> bool:
    """Whether a parsed session file asks for the marker method."""
    return isinstance(data, dict) and data.get("method") == "marker"


def _capture_entry(
    path: Path, version: int, i: int, c: Any
) -> tuple[tuple[Mapping[str, Any], str], list[tuple[str, Any]]]:
    """A marker capture's entry checked (keys, name, the scan entries) with its name, and
    the files it names; none looked at."""
    kp = f"captures[{i}]"
    many = version >= 2
    required, optional = (["image"], ["name", "scan", "scans"]) if many else (["scan", "image"], ["name"])
    c = check_keys(c, path, kp, required, optional)
    name = capture_name(path, kp, c, i)
    return (c, name), [file_entry(path, f"{kp}.image", c["image"]), *scan_entries(path, kp, c, many)]


def read_marker_session(path: str | Path, joint: bool = True) -> MarkerSession:
    """Read and validate a marker session, detect the target in every capture.

    ``joint``: pose the target as one rigid body from both faces' corners (unless the
    faces disagree with the targets file, :func:`faces_agree`); False poses each face on
    its own from its own corners, as a target whose faces' placement is not known would
    be (a capture without both faces' own poses is then set aside).

    Raises:
        InputError: anything missing, unreadable or invalid, naming the file, key and value.
        CalibrationError: fewer than MIN_CAPTURES captures with the target found.
    """
    path = Path(path)
    head = read_session_header(
        path,
        "marker session file",
        "marker",
        MARKER_SESSION_SCHEMA_VERSIONS,
        ["targets"],
        ["corner_sigma_px"],
        _capture_entry,
    )
    d, version, camera, camera_path = head.data, head.version, head.camera, head.camera_path
    targets_path = session_file(path, "targets", d["targets"])
    target = read_targets(targets_path)
    sigma = (
        get_float(d, "corner_sigma_px", path, positive=True)
        if "corner_sigma_px" in d
        else DEFAULT_CORNER_SIGMA_PX
    )
    laser, params, captures = head.laser, head.params, head.captures
    files = [path, camera_path, targets_path]
    names: list[str] = []
    scans: list[Scan] = []
    views: list[TargetView | None] = []
    n_scans: dict[str, int] = {}
    dropped: dict[str, str] = {}
    foreign: dict[str, tuple[int, ...]] = {}
    from rigcal.io.images import read_grey_at_depth, sixteen_bit_levels

    images: list[tuple[str, Path]] = []
    for i, (c, name) in enumerate(captures):
        names.append(name)
        kp = f"captures[{i}]"
        scan, scan_files = read_capture_scans(path, kp, c, version >= 2)
        image_path = session_file(path, f"{kp}.image", c["image"])
        check_image(path, f"{kp}.image", c["image"], image_path, camera)
        files += [*scan_files, image_path]
        scans.append(scan)
        n_scans[name] = len(scan_files)
        images.append((name, image_path))
    # 16-bit images made 8-bit, every one shifted by the same bits (a 12-bit camera's
    # frames would read black by their top byte): the rule of rigcal.io.images.
    depth = sixteen_bit_levels([p for _, p in images])
    for name, image_path in images:
        grey = read_grey_at_depth(image_path, depth)
        if grey is None:  # pragma: no cover - check_image read it already
            raise InputError(f"{image_path}: not a readable image")
        view = detect_target(grey, camera, target, sigma)
        if view.foreign_ids:
            foreign[name] = view.foreign_ids
        if view.T_cam_target is None:
            dropped[name] = "markers: " + view.missing(target)
            views.append(None)
        else:
            views.append(view)
    check_unique_names(path, names)
    rigid = joint and faces_agree(views)
    if not rigid:
        for i, v in enumerate(views):
            lacking = (
                [] if v is None else [k for k, f in enumerate(v.faces) if f is None or f.T_cam_face is None]
            )
            if lacking:
                need = (
                    "the faces disagree with the targets file, so each needs a pose of its own"
                    if joint
                    else "one pose per face was asked for"
                )
                dropped[names[i]] = (
                    f"markers: {need}, "
                    f"and face {target.faces[lacking[0]].name} has fewer than {MIN_FACE_CORNERS} corners "
                    "on two rows and columns"
                )
                views[i] = None
    keep = [i for i, v in enumerate(views) if v is not None]
    points = _find_v(
        path,
        target,
        [scans[i] for i in keep],
        [_face_poses(target, views[i], rigid) for i in keep],
        [names[i] for i in keep],
        params,
        dropped,
    )
    obs: list[PlaneObservation] = []
    kept_views: list[TargetView] = []
    found = []
    for j, i in enumerate(keep):
        if names[i] in dropped:
            continue
        v = views[i]
        pts = points[j]
        assert v is not None
        assert pts is not None
        found.append(names[i])
        kept_views.append(v)
        assert v.T_cam_target is not None
        assert v.pose_cov is not None
        for k in range(2):
            name = f"{names[i]}/{target.faces[k].name}"
            if not rigid:
                f = v.faces[k]
                assert f is not None
                assert f.T_cam_face is not None
                assert f.pose_cov is not None
                obs.append(plane_observation(len(obs), name, f.T_cam_face, f.pose_cov, pts[k]))
                continue
            o = plane_observation(len(obs), name, v.T_cam_face(target, k), v.pose_cov, pts[k])
            # The pose's covariance is about the target's origin, on both faces' planes.
            obs.append(replace(o, board_origin_cam=v.T_cam_target[:3, 3].copy(), pose_key=names[i]))
    return MarkerSession(
        path,
        camera,
        camera_path,
        target,
        dict(laser),
        tuple(names),
        tuple(found),
        tuple((n, dropped[n]) for n in names if n in dropped),
        tuple(obs),
        tuple(kept_views),
        np.array([v.rms_px for v in kept_views for _ in range(2)]),
        foreign,
        tuple(files),
        sigma,
        tuple((n, v.disagreement) for n, v in zip(found, kept_views, strict=True) if v.disagreement),
        n_scans,
        rigid,
        tuple(_pose_fits(kept_views, rigid)),
        joint,
    )


# The faces are taken as one rigid target unless more than this share of the captures
# whose faces both have a pose of their own show a face disagreeing with the target's
# pose (at least DISAGREE_MIN of them): then the targets file does not describe the
# target (a wrong angle, a print at the wrong scale) and each face is posed on its own.
DISAGREE_SHARE = 0.5
DISAGREE_MIN = 3


def faces_agree(views: list[TargetView | None]) -> bool:
    """Whether the faces may be posed as one rigid target (see DISAGREE_SHARE)."""
    both = [
        v for v in views if v is not None and all(f is not None and f.T_cam_face is not None for f in v.faces)
    ]
    bad = sum(1 for v in both if v.disagreement)
    return not (bad >= DISAGREE_MIN and bad > DISAGREE_SHARE * len(both))


def _pose_fits(views: list[TargetView], rigid: bool) -> list[tuple[float, int]]:
    """(RMS reprojection error, corners) of every pose the planes came from: the target's
    per capture, or each face's own."""
    if rigid:
        return [(v.rms_px, v.n_corners) for v in views]
    return [(f.own_rms_px, f.own_corners) for v in views for f in v.faces if f is not None]


def _face_poses(target: MarkerTarget, view: TargetView | None, rigid: bool) -> tuple[FloatArray, FloatArray]:
    """Both faces' frames in the camera frame: from the target's pose, or (not ``rigid``)
    each face's own."""
    assert view is not None
    if rigid:
        return view.T_cam_face(target, 0), view.T_cam_face(target, 1)
    a, b = view.faces
    assert a is not None
    assert b is not None
    assert a.T_cam_face is not None
    assert b.T_cam_face is not None
    return a.T_cam_face, b.T_cam_face


def face_shape(target: MarkerTarget, k: int) -> BoardShape:
    """Face k's outline (face frame) and the lengths its cut by the scan plane may have:
    at least a fifth of its smaller side, at most its diagonal."""
    w, h = target.faces[k].width_m, target.edge_m
    return BoardShape(target.outline(k), 0.2 * min(w, h), float(np.hypot(w, h)))


def _find_v(
    path: Path,
    target: MarkerTarget,
    scans: list[Scan],
    views: list[Any],
    names: list[str],
    params: LineParams,
    dropped: dict[str, str],
) -> list[tuple[FloatArray, FloatArray] | None]:
    """Each face's returns in each capture (None for a capture set aside here, its reason
    added to ``dropped``).

    A pattern printed at the wrong scale puts every face too near or too far by one
    factor; the cuts the faces' poses predict then miss the returns, or a consensus
    settles on a wrong pose and picks others. So the search's returns are checked: under
    the closed-form pose at the scale searched, each face's returns must lie on its plane
    about as closely as on their own line (median over faces of the RMS distance from the
    plane at most ON_PLANE_FACTOR times the median of the returns' robust scatter about
    their line, plus ON_PLANE_FLOOR_M). When they do not, the search is repeated with the
    faces' distances scaled by SEARCH_SCALES in turn and the scale whose returns lie
    best on their planes is kept; the solve's scale check then reports the factor.
    """
    best: tuple[float, list[tuple[FloatArray, FloatArray] | None], dict[str, str]] | None = None
    error: CalibrationError | None = None
    for scale in SEARCH_SCALES:
        lost = dict(dropped)
        try:
            out = _search_v(path, target, scans, views, names, params, lost, scale)
        except CalibrationError as exc:
            error = error or exc
            continue
        misfit = _misfit(views, out, scale)
        if best is None or misfit < best[0]:
            best = (misfit, out, lost)
        if misfit <= 1.0:
            break
    if best is None:
        assert error is not None
        raise error
    # The returns found say at what scale the faces stand; search again there while that
    # moves (the first search's scale is only the nearest tried).
    searched = scale
    for _ in range(MAX_SCALE_ROUNDS):
        shown = _returns_scale(views, best[1], searched)
        if abs(shown - searched) < SCALE_SETTLED:
            break
        lost = dict(dropped)
        try:
            out = _search_v(path, target, scans, views, names, params, lost, shown)
        except CalibrationError:
            break
        misfit = _misfit(views, out, shown)
        if misfit > max(best[0], 1.0):
            break
        best, searched = (misfit, out, lost), shown
    dropped.update(best[2])
    return best[1]


# Scales of the faces' distances the V search tries in turn (see _find_v).
SEARCH_SCALES = (1.0, 1.04, 0.96, 1.08, 0.92, 1.15, 0.87)
ON_PLANE_FACTOR = 2.0
ON_PLANE_FLOOR_M = 0.003
SCALE_SETTLED = 0.005
MAX_SCALE_ROUNDS = 2


def _returns_scale(
    views: list[Any], found: list[tuple[FloatArray, FloatArray] | None], scale: float
) -> float:
    """The factor on the faces' distances that best puts the found returns on their
    planes (:func:`fit_scale` from the closed-form pose at ``scale``)."""
    from rigcal.calib.board.plane import closed_form

    planes = [_plane(views[i][k]) for i, pair in enumerate(found) if pair is not None for k in range(2)]
    points = [p for pair in found if pair is not None for p in pair]
    obs = [
        PlaneObservation(j, str(j), n, scale * d, p)
        for j, ((n, d), p) in enumerate(zip(planes, points, strict=True))
    ]
    try:
        T0 = closed_form(obs)
    except CalibrationError:
        return scale
    return fit_scale(T0, planes, points, scale)[0]


def _misfit(views: list[Any], found: list[tuple[FloatArray, FloatArray] | None], scale: float) -> float:
    """How far the found returns lie off their faces' planes, under the closed-form pose
    with the faces' distances scaled by ``scale``, in units of what the returns' own
    scatter allows (at most 1: as expected; see :func:`_find_v`)."""
    from rigcal.calib.board.plane import closed_form, point_to_plane

    obs: list[PlaneObservation] = []
    for i, pair in enumerate(found):
        if pair is None:
            continue
        for k in range(2):
            n, d = _plane(views[i][k])
            obs.append(PlaneObservation(len(obs), str(len(obs)), n, scale * d, pair[k]))
    try:
        T = closed_form(obs)
    except CalibrationError:
        return float("inf")
    rms = [float(np.sqrt(np.mean(point_to_plane(T, o) ** 2))) for o in obs if len(o.points_laser)]
    allowed = ON_PLANE_FACTOR * _scatter([o.points_laser for o in obs]) + ON_PLANE_FLOOR_M
    return float(np.median(rms)) / allowed


def _search_v(
    path: Path,
    target: MarkerTarget,
    scans: list[Scan],
    views: list[Any],
    names: list[str],
    params: LineParams,
    dropped: dict[str, str],
    scale: float,
) -> list[tuple[FloatArray, FloatArray] | None]:
    """The V search with the faces' distances scaled by ``scale``.

    1. The moving returns (:func:`rigcal.calib.board.detect.static_returns` drops the
       background seen in most captures) give straight pieces as long as a cut of a face
       may be (:func:`rigcal.calib.board.detect.line_candidates`); two pieces whose lines
       cross within APEX_GAP_M of an end of each, at more than MIN_V_DEG, are a candidate
       V, its left arm (as seen from the sensors: the larger bearing) on the left face.
    2. A RANSAC over the captures with a candidate V and their candidate arms (each face
       of each capture one plane, :func:`rigcal.calib.board.plane.candidate_consensus`)
       gives a rough T_cam_laser; it needs MIN_SEED_CAPTURES such captures (when fewer
       show one, the others' candidates are sought among all their valid returns).
    3. In every capture, with a candidate V or not, each face's returns are picked near
       the cut its pose predicts under that pose
       (:func:`rigcal.calib.board.detect.pick_near_cut`; among all valid returns when the
       moving ones have too few there: with few captures the background is not told
       apart reliably, and a target standing where others stood can be taken for it).
       The V so found is checked against the target (:func:`check_v`); the pose is
       re-solved by the closed form from the captures that pass and the picking
       repeated with a tighter window, as for a board.

    A capture whose V fails the check under the final pose is set aside with the reason.
    """
    from rigcal.calib.board import detect as bd
    from rigcal.calib.board.plane import candidate_consensus, closed_form

    static = bd.static_returns(scans)
    moving = [sc.valid & ~st for sc, st in zip(scans, static, strict=True)]
    shapes = [face_shape(target, k) for k in range(2)]
    either = BoardShape(shapes[0].outline, min(x.min_cut_m for x in shapes), max(x.max_cut_m for x in shapes))
    pairs: dict[int, list[tuple[NDArray[np.int64], NDArray[np.int64]]]] = {}
    reasons: dict[int, str] = {}
    for i, sc in enumerate(scans):
        pairs[i] = v_candidates(sc, bd.line_candidates(sc, moving[i], either, params, seed=i))
        if not pairs[i]:
            reasons[i] = (
                "the V in the scan: no two straight pieces of the moving returns meet at an apex "
                f"({int(moving[i].sum())} moving returns)"
            )
    seeded = [i for i in range(len(scans)) if pairs[i]]
    if len(seeded) < MIN_SEED_CAPTURES:
        # Too few captures show a V among the moving returns: the background was not told
        # apart (few captures, a target standing where others stood). Their candidates
        # are then sought among all valid returns; the consensus sorts them out.
        for i in [i for i in range(len(scans)) if not pairs[i]]:
            sc = scans[i]
            pairs[i] = v_candidates(sc, bd.line_candidates(sc, sc.valid, either, params, seed=i))
        seeded = [i for i in range(len(scans)) if pairs[i]]
    if len(seeded) < MIN_SEED_CAPTURES:
        dropped.update({names[i]: r for i, r in reasons.items()})
        _too_few(path, dropped, names, len(scans), len(seeded), MIN_SEED_CAPTURES, "a rough pose")
    poses = {(i, k): _scaled(views[i][k], scale) for i in range(len(scans)) for k in range(2)}
    planes = [_plane(poses[i, k]) for i in seeded for k in range(2)]
    arms = [_unique([scans[i].points[p[k]] for p in pairs[i]]) for i in seeded for k in range(2)]
    threshold = max(bd.LINE_TOLERANCE_M, bd.LINE_SIGMAS * _scatter([a for c in arms for a in c]))
    try:
        T, chosen, agree = candidate_consensus(
            planes,
            arms,
            threshold_m=threshold,
            advice="take more views with the target's V in the scanner's plane, or check the targets "
            "file's face sizes and angle",
        )
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: finding the V in the scans: {exc}") from None
    picked: dict[tuple[int, int], FloatArray] = {}
    for j, i in enumerate(seeded):
        if agree[2 * j] and agree[2 * j + 1]:
            for k in range(2):
                picked[i, k] = arms[2 * j + k][chosen[2 * j + k]]
    window = bd.FIRST_WINDOW_M
    sigma = max(_scatter([a for c in arms for a in c]), bd.MIN_RANGE_SIGMA_M)
    for _ in range(bd.REFINE_PASSES):
        for i in range(len(scans)):
            for k in range(2):
                cut = bd.predicted_cut(T, poses[i, k], shapes[k])
                if cut is None:
                    continue
                near = bd.pick_near_cut(scans[i], moving[i], cut, window, params.min_points)
                if not len(near):
                    near = bd.pick_near_cut(scans[i], scans[i].valid, cut, window, params.min_points)
                if len(near):
                    picked[i, k] = scans[i].points[near]
        good = [
            i
            for i in range(len(scans))
            if check_v(T, (poses[i, 0], poses[i, 1]), shapes, _pair(picked, i), params.min_points, sigma)
            is None
        ]
        if len(good) < MIN_SEED_CAPTURES:
            break
        obs = [
            PlaneObservation(len(good), "", *_plane(poses[i, k]), picked[i, k])
            for i in good
            for k in range(2)
        ]
        try:
            T = closed_form(obs)
        except CalibrationError:
            break
        window = max(bd.WINDOW_FLOOR_M, bd.WINDOW_SIGMAS * threshold / bd.LINE_SIGMAS)
    out: list[tuple[FloatArray, FloatArray] | None] = [None] * len(scans)
    for i in range(len(scans)):
        pair = _pair(picked, i)
        why = check_v(T, (poses[i, 0], poses[i, 1]), shapes, pair, params.min_points, sigma)
        if why is not None:
            dropped[names[i]] = f"the V in the scan: {why}" + (
                f" (and {reasons[i].removeprefix('the V in the scan: ')})" if i in reasons else ""
            )
            continue
        assert pair[0] is not None
        assert pair[1] is not None
        out[i] = split_faces(pair[0], pair[1])
    found = sum(o is not None for o in out)
    if found < MIN_CAPTURES:
        _too_few(path, dropped, names, len(scans), found, MIN_CAPTURES, "the marker method")
    return out


# The captures with a candidate V a rough pose is sought from (two face planes each: the
# closed form needs five planes of different orientations).
MIN_SEED_CAPTURES = 3
# A V found near its predicted cut is the target's when its arms meet where and at the
# angle the faces' poses predict: the apex within APEX_OFF_M, the angle within
# V_ANGLE_FLOOR_DEG or V_ANGLE_SIGMAS of the arms' own direction uncertainty, and each arm
# at least MIN_ARM_SHARE of the cut its face's pose predicts.
APEX_OFF_M = 0.05
V_ANGLE_FLOOR_DEG = 5.0
V_ANGLE_SIGMAS = 4.0
MIN_ARM_SHARE = 0.3


def _pair(picked: dict[tuple[int, int], FloatArray], i: int) -> tuple[FloatArray | None, FloatArray | None]:
    return picked.get((i, 0)), picked.get((i, 1))


def _too_few(
    path: Path, dropped: dict[str, str], names: list[str], n: int, found: int, need: int, what: str
) -> None:
    why = "; ".join(f"{k}: {r}" for k, r in dropped.items())
    raise CalibrationError(
        f"{path}: the target was found in {found} of {n + _early(dropped, names)} captures; "
        f"{what} needs {need} ({why})"
    )


def check_v(
    T_cam_laser: FloatArray,
    T_cam_faces: tuple[FloatArray, FloatArray],
    shapes: list[BoardShape],
    arms: tuple[FloatArray | None, FloatArray | None],
    min_points: int,
    sigma_m: float,
) -> str | None:
    """Whether two arms of returns are the target's V under a (rough) T_cam_laser: None
    when they are, else why not.

    Under the pose the faces' poses predict each face's cut in the scan plane
    (:func:`rigcal.calib.board.detect.predicted_cut`), hence the V's apex (where the
    scan plane crosses the faces' common edge) and the angle at which its arms meet
    (the targets file's face angle, as the scan plane cuts it). The arms must have
    ``min_points`` returns each, span at least MIN_ARM_SHARE of their predicted cuts,
    meet within APEX_OFF_M of the predicted apex, and at the predicted angle within
    V_ANGLE_FLOOR_DEG or V_ANGLE_SIGMAS of their fitted directions' uncertainty
    (``sigma_m`` across each line).
    """
    from rigcal.calib.board.detect import predicted_cut

    fits = []
    for k in range(2):
        side = "left" if k == 0 else "right"
        pts = arms[k]
        cut = predicted_cut(T_cam_laser, T_cam_faces[k], shapes[k])
        if cut is None:
            return f"the {side} face's pose puts it off the scan plane"
        n = 0 if pts is None else len(pts)
        if pts is None or n < min_points:
            return f"{n} returns near the {side} face's predicted cut (at least {min_points} needed)"
        c, u, _ = fit_line(pts)
        along = (pts - c) @ u
        length = float(np.linalg.norm(cut[1] - cut[0]))
        if np.ptp(along) < MIN_ARM_SHARE * length:
            return (
                f"the {side} arm spans {100 * np.ptp(along):.0f} cm of the {100 * length:.0f} cm its face's "
                f"pose predicts (at least {100 * MIN_ARM_SHARE:.0f} %)"
            )
        sigma_dir = sigma_m / max(float(np.sqrt(np.sum((along - along.mean()) ** 2))), 1e-9)
        fits.append((c, u, cut, sigma_dir))
    (ca, ua, cut_a, sa), (cb, ub, cut_b, sb) = fits
    apex, angle = _meet(ca, ua, cb, ub)
    da, db = cut_a[1] - cut_a[0], cut_b[1] - cut_b[0]
    apex_pred, angle_pred = _meet(
        cut_a.mean(axis=0), da / np.linalg.norm(da), cut_b.mean(axis=0), db / np.linalg.norm(db)
    )
    if apex is None or apex_pred is None:
        return "the arms are parallel"
    off = float(np.linalg.norm(apex - apex_pred))
    if off > APEX_OFF_M:
        return (
            f"the arms meet {100 * off:.0f} cm from the apex the faces' pose predicts "
            f"(at most {100 * APEX_OFF_M:.0f} cm)"
        )
    tol = max(V_ANGLE_FLOOR_DEG, V_ANGLE_SIGMAS * float(np.degrees(np.hypot(sa, sb))))
    if abs(angle - angle_pred) > tol:
        return (
            f"the arms meet at {angle:.0f} deg where the faces' pose predicts {angle_pred:.0f} deg "
            f"(tolerance {tol:.0f} deg)"
        )
    return None


def _meet(ca: FloatArray, ua: FloatArray, cb: FloatArray, ub: FloatArray) -> tuple[FloatArray | None, float]:
    """Where two arms' lines (a point of the arm, the line's unit direction) cross in the
    plane, and the angle between the arms there (degrees, 0-180: from the crossing towards
    each arm's point); (None, 0) when parallel."""
    apex = line_intersection(ca, ua, cb, ub, parallel_below=1e-9)
    if apex is None:
        return None, 0.0
    a, b = ca - apex, cb - apex
    cos = float(a @ b) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), 1e-12)
    return apex, float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


# Two straight pieces are a candidate V when their lines cross within APEX_GAP_M of an
# end of each and at more than MIN_V_DEG.
APEX_GAP_M = 0.08
MIN_V_DEG = 15.0


def v_candidates(
    scan: Scan, lines: list[NDArray[np.int64]]
) -> list[tuple[NDArray[np.int64], NDArray[np.int64]]]:
    """Pairs (left arm, right arm) of straight pieces (beam indices) that make a V: their
    lines cross within APEX_GAP_M of an end of each, at more than MIN_V_DEG; the left arm
    (as seen from the sensors) is the one at the larger bearing."""
    fits = []
    for beams in lines:
        p = scan.points[beams]
        c, u, _ = fit_line(p)
        along = (p - c) @ u
        fits.append((c, u, c + along.min() * u, c + along.max() * u))
    out = []
    for a in range(len(lines)):
        for b in range(len(lines)):
            if a == b:
                continue
            ca, ua, *ends_a = fits[a]
            cb, ub, *ends_b = fits[b]
            cross = float(ua[0] * ub[1] - ua[1] * ub[0])
            if abs(cross) < np.sin(np.radians(MIN_V_DEG)):
                continue
            s = np.linalg.solve(np.column_stack([ua, -ub]), cb - ca)
            apex = ca + s[0] * ua
            if min(np.linalg.norm(e - apex) for e in ends_a) > APEX_GAP_M:
                continue
            if min(np.linalg.norm(e - apex) for e in ends_b) > APEX_GAP_M:
                continue
            if np.arctan2(ca[1], ca[0]) > np.arctan2(cb[1], cb[0]):
                out.append((lines[a], lines[b]))
    return out


def _unique(arms: list[FloatArray]) -> list[FloatArray]:
    """The arms with repeats (one piece in several candidate Vs) listed once."""
    out: list[FloatArray] = []
    for a in arms:
        if not any(len(a) == len(b) and np.array_equal(a, b) for b in out):
            out.append(a)
    return out


def _scatter(point_sets: list[FloatArray]) -> float:
    """The median over point sets of their robust scatter about their own line."""
    sig = []
    for p in point_sets:
        if len(p) >= 3:
            c, u, _ = fit_line(p)
            sig.append(MAD_TO_SIGMA * float(np.median(np.abs((p - c) @ np.array([-u[1], u[0]])))))
    return float(np.median(sig)) if sig else 0.0


def _scaled(T: FloatArray, scale: float) -> FloatArray:
    out = T.copy()
    out[:3, 3] *= scale
    return out


def fit_scale(
    T0: FloatArray, planes: list[tuple[FloatArray, float]], points: list[FloatArray], scale0: float = 1.0
) -> tuple[float, float]:
    """The pose refitted with every plane's distance multiplied by a free factor s,
    n . (R p + t) = s d, from T0 (unweighted least squares on the given laser points, (M, 2)
    per plane). Returns s and its 1-sigma from the fit's residual scale."""
    from scipy.optimize import least_squares

    from rigcal.geometry import make_T, rotvec_to_R

    R0 = T0[:3, :3]

    def residuals(x: FloatArray) -> FloatArray:
        T = make_T(rotvec_to_R(x[:3]) @ R0, x[3:6])
        return np.concatenate(
            [
                (p @ T[:3, :2].T + T[:3, 3]) @ np.asarray(n) - x[6] * d
                for (n, d), p in zip(planes, points, strict=True)
            ]
        )

    sol = least_squares(residuals, np.concatenate([np.zeros(3), T0[:3, 3], [scale0]]), method="lm")
    dof = max(len(sol.fun) - 7, 1)
    try:
        cov = float(sol.fun @ sol.fun) / dof * np.linalg.inv(sol.jac.T @ sol.jac)
    except np.linalg.LinAlgError:
        return float(sol.x[6]), float("inf")
    return float(sol.x[6]), float(np.sqrt(max(cov[6, 6], 0.0)))


def _early(dropped: dict[str, str], names: list[str]) -> int:
    """Captures dropped before the scans were looked at (their markers)."""
    return sum(1 for n in dropped if n not in names)


def _plane(T_cam_face: FloatArray) -> tuple[FloatArray, float]:
    n = T_cam_face[:3, 2]
    dist = float(n @ T_cam_face[:3, 3])
    return (n, dist) if dist > 0 else (-n, -dist)


def split_faces(a: FloatArray, b: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Each face's returns, those near the apex told apart: a return found for both faces
    goes to the face whose line is nearer; one found for one face only stays with it
    unless it lies more than twice as near the other face's line (then it is dropped)."""
    pts = np.unique(np.vstack([a, b]), axis=0)
    ca, ua, _ = fit_line(a)
    cb, ub, _ = fit_line(b)
    da = np.abs((pts - ca) @ np.array([-ua[1], ua[0]]))
    db = np.abs((pts - cb) @ np.array([-ub[1], ub[0]]))
    in_a = (pts[:, None, :] == a[None]).all(axis=2).any(axis=1)
    in_b = (pts[:, None, :] == b[None]).all(axis=2).any(axis=1)
    nearer_a = da <= db
    to_a = np.where(in_a & in_b, nearer_a, in_a & (da <= 2.0 * db))
    to_b = np.where(in_a & in_b, ~nearer_a, in_b & (db <= 2.0 * da))
    return pts[to_a], pts[to_b]


def with_corner_scale(session: MarkerSession, k: float) -> tuple[PlaneObservation, ...]:
    """The observations with every face pose's covariance scaled by ``k``."""
    return tuple(
        replace(o, board_pose_cov=None if o.board_pose_cov is None else k * o.board_pose_cov)
        for o in session.observations
    )


def capture_markers(images: Path, name: str, camera: Camera, target: MarkerTarget) -> str:
    """What one captured image shows of the target, for ``rigcal capture``'s table: each
    face's markers seen, or why the capture will be set aside."""
    from rigcal.io.images import read_grey

    found = sorted(images.glob(f"{name}.*"))
    grey = read_grey(found[0]) if found else None
    if grey is None:
        return "image unreadable"
    view = detect_target(grey, camera, target)
    seen = ", ".join(
        f"{f.name} {n}/{f.n_markers}" for f, n in zip(target.faces, view.markers_seen, strict=True)
    )
    why = view.missing(target)
    extra = f"; {len(view.foreign_ids)} markers of another target ignored" if view.foreign_ids else ""
    return f"markers {seen}" + (f" (set aside: {why})" if why else "") + extra
