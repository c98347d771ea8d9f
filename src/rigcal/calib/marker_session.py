"""Marker sessions: captures of the V marker target, read with no hand input.

A marker session file (docs/formats/marker-session.md) names the camera, the targets file
(:mod:`rigcal.targets.marker`) and per capture a scan and an image. :func:`read_marker_session`
validates it and, for every capture:

1. reads the target in the image (:func:`rigcal.calib.marker_detect.detect_target`): each
   face's pose by PnP from its ChArUco corners, with its covariance; markers of other
   targets are ignored and counted;
2. finds each face's returns in the scan, as the board method finds a board's
   (:func:`rigcal.calib.board_detect.detect_board_returns`): the static background is
   dropped across captures, straight pieces of the moving returns as long as a cut of the
   face may be are the candidates, a RANSAC over captures and candidates picks the one on
   the face's plane, and the returns are re-picked near the cut the face's pose predicts.
   The two faces' returns are then told apart near the apex (each return goes to the
   face whose line it is nearer).

A capture whose faces are not both read, or whose V is not found in the scan, is set
aside with the reason, and the others go on. Each kept capture becomes two
:class:`~rigcal.calib.plane.PlaneObservation` (one per face, named ``CAPTURE/FACE``), so
the board method's solve takes them as they are.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.calib.board_detect import BoardNotFoundError, BoardShape, detect_board_returns
from rigcal.calib.board_session import plane_observation
from rigcal.calib.lines import LineParams, fit_line
from rigcal.calib.marker_detect import FaceView, detect_target
from rigcal.calib.picks import _check_image, _file, capture_name, check_unique_names, line_params_for
from rigcal.calib.plane import MIN_CAPTURES, PlaneObservation
from rigcal.camera import Camera, read_camera
from rigcal.errors import CalibrationError, InputError
from rigcal.io.files import check_keys, get_float, load_yaml
from rigcal.scan import Scan, read_scan
from rigcal.targets.marker import MarkerTarget, read_targets

FloatArray = NDArray[np.float64]

MARKER_SESSION_SCHEMA_VERSION = 1
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
        observations: two plane observations per kept capture (left face, right face).
        faces: the face views of the kept captures, in the observations' order.
        corner_rms_px: (2K,) each observation's RMS corner reprojection error.
        foreign_ids: per capture name, the ids of markers not on the target it showed.
        files: every file read (for provenance).
        corner_sigma_px: the corner noise the face poses' covariances were computed with.
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
    faces: tuple[FaceView, ...]
    corner_rms_px: FloatArray
    foreign_ids: dict[str, tuple[int, ...]]
    files: tuple[Path, ...]
    corner_sigma_px: float = DEFAULT_CORNER_SIGMA_PX


def is_marker_session(data: Any) -> bool:
    """Whether a parsed session file asks for the marker method."""
    return isinstance(data, dict) and data.get("method") == "marker"


def read_marker_session(path: str | Path) -> MarkerSession:
    """Read and validate a marker session, detect the target in every capture.

    Raises:
        InputError: anything missing, unreadable or invalid, naming the file, key and value.
        CalibrationError: fewer than MIN_CAPTURES captures with the target found.
    """
    path = Path(path)
    d = check_keys(
        load_yaml(path, "marker session file"),
        path,
        "",
        ["schema_version", "method", "camera", "targets", "captures"],
        ["name", "laser", "corner_sigma_px"],
    )
    version = d["schema_version"]
    if type(version) is not int or version != MARKER_SESSION_SCHEMA_VERSION:
        raise InputError.at(path, "schema_version", version, "1 (the version this rigcal reads)")
    if d["method"] != "marker":
        raise InputError.at(path, "method", d["method"], "'marker'")
    camera_path = _file(path, "camera", d["camera"])
    camera = read_camera(camera_path)
    targets_path = _file(path, "targets", d["targets"])
    target = read_targets(targets_path)
    sigma = (
        get_float(d, "corner_sigma_px", path, positive=True)
        if "corner_sigma_px" in d
        else DEFAULT_CORNER_SIGMA_PX
    )
    laser = d.get("laser", {})
    if not isinstance(laser, dict):
        raise InputError.at(path, "laser", laser, "a mapping describing the scanner")
    params = line_params_for(path, laser)
    captures = d["captures"]
    if not isinstance(captures, list) or not captures:
        raise InputError.at(path, "captures", captures, "a non-empty list of captures")
    files = [path, camera_path, targets_path]
    names: list[str] = []
    scans: list[Scan] = []
    views: list[tuple[FaceView, FaceView] | None] = []
    dropped: dict[str, str] = {}
    foreign: dict[str, tuple[int, ...]] = {}
    from rigcal.io.images import read_grey

    for i, c in enumerate(captures):
        kp = f"captures[{i}]"
        c = check_keys(c, path, kp, ["scan", "image"], ["name"])
        name = capture_name(path, kp, c, i)
        names.append(name)
        scan_path = _file(path, f"{kp}.scan", c["scan"])
        image_path = _file(path, f"{kp}.image", c["image"])
        _check_image(path, f"{kp}.image", c["image"], image_path, camera)
        files += [scan_path, image_path]
        scans.append(read_scan(scan_path))
        grey = read_grey(image_path)
        if grey is None:  # pragma: no cover - _check_image read it already
            raise InputError.at(path, f"{kp}.image", c["image"], "an image file OpenCV can read")
        view = detect_target(grey, camera, target, sigma)
        if view.foreign_ids:
            foreign[name] = view.foreign_ids
        a, b = view.faces
        if a is None or b is None:
            dropped[name] = "markers: " + view.missing(target)
            views.append(None)
        else:
            views.append((a, b))
    check_unique_names(path, names)
    keep = [i for i, v in enumerate(views) if v is not None]
    points = _find_v(
        path,
        target,
        [scans[i] for i in keep],
        [views[i] for i in keep],
        [names[i] for i in keep],
        params,
        dropped,
    )
    obs: list[PlaneObservation] = []
    faces: list[FaceView] = []
    found = []
    for j, i in enumerate(keep):
        if names[i] in dropped:
            continue
        v = views[i]
        pts = points[j]
        assert v is not None
        assert pts is not None
        found.append(names[i])
        for k in range(2):
            f = v[k]
            obs.append(
                plane_observation(
                    len(obs), f"{names[i]}/{target.faces[k].name}", f.T_cam_face, f.pose_cov, pts[k]
                )
            )
            faces.append(f)
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
        tuple(faces),
        np.array([f.rms_px for f in faces]),
        foreign,
        tuple(files),
        sigma,
    )


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
    added to ``dropped``)."""
    alive = list(range(len(scans)))
    while True:
        if len(alive) < MIN_CAPTURES:
            why = "; ".join(f"{n}: {r}" for n, r in dropped.items())
            raise CalibrationError(
                f"{path}: the target was found in {len(alive)} of {len(scans) + _early(dropped, names)} "
                f"captures; the marker method needs {MIN_CAPTURES} ({why})"
            )
        found: list[list[FloatArray]] = []
        try:
            for k in range(2):
                poses = [views[i][k].T_cam_face for i in alive]
                planes = [_plane(T) for T in poses]
                found.append(
                    detect_board_returns(
                        [scans[i] for i in alive], poses, planes, face_shape(target, k), {}, params
                    )
                )
        except BoardNotFoundError as exc:
            i = alive[exc.capture]
            dropped[names[i]] = f"the V in the scan: face {target.faces[k].name}: {exc.detail.split(';')[0]}"
            alive.remove(i)
            continue
        except CalibrationError as exc:
            raise CalibrationError(f"{path}: finding the V in the scans: {exc}") from None
        out: list[tuple[FloatArray, FloatArray] | None] = [None] * len(scans)
        for j, i in enumerate(alive):
            out[i] = split_faces(found[0][j], found[1][j])
        return out


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
