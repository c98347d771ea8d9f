"""Board sessions: captures of a checkerboard seen by both the camera and the scanner.

A board session file (docs/formats/board-session.md) is a picking file with
``method: board``: the camera, the board (inner corners and square size), and per capture
a scan, the board's corners in the image (listed, or detected in an image), and the
board's returns in the scan (a segment id as ``rigcal lines`` prints it, several ids for
a cut that line extraction split, two laser points, or ``auto``: found by
:mod:`rigcal.calib.board.detect`). :func:`read_board_session` validates it and turns each capture into a
:class:`~rigcal.calib.board.plane.PlaneObservation`: the board's pose by PnP from its corners
(through the full lens model: bearings, then PnP on normalised coordinates), its plane in
the camera frame, and the pose's covariance from the corners' reprojection Jacobian.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.calib.board.detect import BoardNotFoundError, BoardShape, board_shape, detect_board_returns
from rigcal.calib.board.level import LevelPriors, board_vertical, check_level_geometry
from rigcal.calib.board.plane import PlaneObservation, check_normals
from rigcal.calib.box.picks import (
    beams_near,
    capture_name,
    check_image,
    check_unique_names,
    file_entry,
    point_pairs,
    read_capture_scans,
    read_session_header,
    scan_entries,
    segment_by_id,
    segments_by_ids,
    session_file,
)
from rigcal.calib.intrinsics import Board, detect_corners, read_corners_vnl
from rigcal.camera import Camera
from rigcal.errors import CalibrationError, InputError
from rigcal.geometry import R_to_rotvec, make_T, rotvec_to_R
from rigcal.io.files import check_keys, get_float
from rigcal.lines import LineParams
from rigcal.scan import Scan
from rigcal.targets.board import sheet_size_m

BOARD_SESSION_SCHEMA_VERSION = 1
# Versions read: 2 adds board.size_m and laser_side: {segments: [...]}; 3 adds level: (the
# priors of the reduced solve for a level scanner and upright boards); 4 a capture's
# ``scans`` (the scans of one still moment, as marker sessions' version 2).
BOARD_SESSION_SCHEMA_VERSIONS = (1, 2, 3, 4)
BOARD_SESSION_SCANS_VERSION = 4
LEVEL_KEYS = ("roll_deg", "pitch_deg", "camera_height_m")


@dataclass(frozen=True)
class BoardSession:
    """A board session, resolved.

    Attributes:
        path: the session file.
        camera, camera_path: the camera and its file.
        board: the board.
        laser: the scanner's description.
        observations: one plane observation per capture.
        T_cam_board: (C, 4, 4) the boards' poses from PnP.
        corner_rms_px: (C,) RMS reprojection error of each board's corners under its pose.
        files: every file read (for provenance).
        corner_sigma_px: the corner noise the poses' covariances were computed with.
        corners_px: per capture, (N, 2) the board's corners in the image (to re-solve the
            board poses under other intrinsics).
        skipped: the captures left out because their image shows no board (with
            ``skip_unseen_boards``), each as "name (image): why".
        level: the priors of the reduced solve (:mod:`rigcal.calib.board.level`: the session's
            ``level:`` or the caller's), None for the full 6-dof solve.
        scans_per_capture: per capture name, how many scans its laser side is the mean of
            (captures with a scan file or scans).
    """

    path: Path
    camera: Camera
    camera_path: Path
    board: Board
    laser: dict[str, Any]
    observations: tuple[PlaneObservation, ...]
    T_cam_board: FloatArray
    corner_rms_px: FloatArray
    files: tuple[Path, ...]
    corner_sigma_px: float = 0.5
    corners_px: tuple[FloatArray, ...] = ()
    skipped: tuple[str, ...] = ()
    level: LevelPriors | None = None
    scans_per_capture: dict[str, int] = field(default_factory=dict)


def is_board_session(data: Any) -> bool:
    """Whether a parsed session file asks for the board method."""
    return isinstance(data, dict) and data.get("method") == "board"


@dataclass(frozen=True)
class BoardSessionFile:
    """A board session file as written, checked, before any image is searched or any pose
    computed (:func:`parse_board_session`).

    Attributes:
        path, version: the file and its ``schema_version``.
        camera, camera_path: the camera and its file.
        board, shape: the board and its outline for the returns' detection (the sheet's
            ``size_m`` when given).
        laser, params: the scanner's description and its line extraction settings.
        captures: per capture, in file order, its entry (keys checked) and its name.
        corners_vnl: the session's corners file by image name (None without ``corners_vnl``).
        corner_sigma_px: the corner noise: the file's ``board.corner_sigma_px``, else the
            caller's.
        level: the reduced solve's priors: the caller's, else the file's ``level:``, else None.
        files: the files read (the session, the camera, the corners file).
    """

    path: Path
    version: int
    camera: Camera
    camera_path: Path
    board: Board
    shape: BoardShape
    laser: dict[str, Any]
    params: LineParams
    captures: tuple[tuple[Mapping[str, Any], str], ...]
    corners_vnl: dict[str, FloatArray] | None
    corner_sigma_px: float
    level: LevelPriors | None
    files: tuple[Path, ...]


class _SeenBoard(NamedTuple):
    """A capture whose corners were found: its index in the file, entry and name, the
    board's pose by PnP, the pose's (6, 6) covariance and the corners' RMS error (px)."""

    capture: int
    entry: Mapping[str, Any]
    name: str
    T_cam_board: FloatArray
    pose_cov: FloatArray
    corner_rms_px: float


def read_board_session(
    path: str | Path,
    corner_sigma_px: float = 0.5,
    skip_unseen_boards: bool = False,
    level: LevelPriors | None = None,
) -> BoardSession:
    """Read and validate a board session and every file it names.

    The steps: :func:`parse_board_session` (the file), the boards' poses from their corners
    (listed, or detected in the images), the images-first check of the boards' normals, then
    each capture's scan and returns on the board (given, or detected: ``laser_side: auto``).

    Args:
        path: the session file.
        corner_sigma_px: noise of a board corner in the image (for the board pose's
            covariance), unless the file's ``board.corner_sigma_px`` gives it.
        skip_unseen_boards: leave out the captures whose image shows no board (listed in
            ``skipped``) instead of stopping.
        level: the reduced solve's priors, over the session's ``level:``.

    Raises:
        InputError: anything missing, unreadable or invalid, naming the file, key and value;
            images with no board are named all together in one error.
        CalibrationError: the boards' normals (from the images alone, checked before any
            laser return is looked at) cannot fix the pose: for the full solve they must
            span 3D, for the level solve two horizontal directions.
    """
    f = parse_board_session(path, corner_sigma_px, level)
    files = list(f.files)
    # What the images alone show comes first: the boards' poses, and whether their planes
    # can fix the pose at all, before any laser return is looked for.
    seen, unseen, corner_sets = _board_poses(f, files)
    board = f.board
    if unseen and not skip_unseen_boards:
        keys = ", ".join(f"captures[{i}].image" for i, _, _ in unseen)
        shown = ", ".join(repr(str(v)) for _, _, v in unseen)
        raise InputError(
            f"{f.path}: {keys}: got {shown}; expected images showing the {board.width_n}x{board.height_n} "
            f"board ({len(unseen)} of {len(f.captures)} captures show none; `rigcal solve "
            "--skip-unseen-boards` leaves them out with a warning)"
        )
    none = np.zeros((0, 2))
    planes = [(s.name, plane_observation(s.capture, s.name, s.T_cam_board, s.pose_cov, none)) for s in seen]
    _check_board_normals(f.path, planes, f.level)
    obs, scans, auto, n_scans = _laser_returns(f, seen, files)
    if auto:
        obs = _auto_returns(f, obs, auto, scans, seen)
    check_unique_names(f.path, [o.name for o in obs])
    return BoardSession(
        f.path,
        f.camera,
        f.camera_path,
        board,
        dict(f.laser),
        tuple(obs),
        np.array([s.T_cam_board for s in seen]),
        np.array([s.corner_rms_px for s in seen]),
        tuple(files),
        corner_sigma_px=f.corner_sigma_px,
        corners_px=tuple(corner_sets),
        skipped=tuple(
            f"{name} ({value}): no {board.width_n}x{board.height_n} board found" for _, name, value in unseen
        ),
        level=f.level,
        scans_per_capture=n_scans,
    )


def parse_board_session(
    path: str | Path, corner_sigma_px: float = 0.5, level: LevelPriors | None = None
) -> BoardSessionFile:
    """Read and check a board session file and its camera (and corners file), no image or
    scan yet: the top level, ``board``, ``level`` and each capture's keys and name.

    Args:
        path: the session file.
        corner_sigma_px: the corner noise, unless the file's ``board.corner_sigma_px`` gives it.
        level: the reduced solve's priors, over the file's ``level:``.

    Raises:
        InputError: anything missing or invalid, naming the file, key and value.
    """
    path = Path(path)
    head = read_session_header(
        path,
        "board session file",
        "board",
        BOARD_SESSION_SCHEMA_VERSIONS,
        ["board"],
        ["corners_vnl", "level"],
        _capture_entry,
        " (a box-target picking file has no method key)",
    )
    d, version, camera, camera_path = head.data, head.version, head.camera, head.camera_path
    if "level" in d and level is None:
        level = _level_priors(path, d["level"], version)
    b = check_keys(
        d["board"], path, "board", ["corners_x", "corners_y", "spacing_m"], ["corner_sigma_px", "size_m"]
    )
    if "corner_sigma_px" in b:
        corner_sigma_px = get_float(b, "corner_sigma_px", path, "board", positive=True)
    for key in ("corners_x", "corners_y"):
        v = b[key]
        if isinstance(v, bool) or not isinstance(v, int) or v < 2:
            raise InputError.at(path, f"board.{key}", v, "an integer >= 2 (inner corners)")
    board = Board(b["corners_x"], b["corners_y"], get_float(b, "spacing_m", path, "board", positive=True))
    size_m = _size_m(path, b, board, version) if "size_m" in b else None
    files = [path, camera_path]
    vnl: dict[str, FloatArray] | None = None
    if "corners_vnl" in d:
        vnl_path = session_file(path, "corners_vnl", d["corners_vnl"])
        files.append(vnl_path)
        det = read_corners_vnl(vnl_path, board, (camera.width_px, camera.height_px))
        vnl = {Path(p).name: g for p, g in zip(det.paths, det.corners, strict=True)}
    return BoardSessionFile(
        path,
        version,
        camera,
        camera_path,
        board,
        board_shape(board, size_m),
        head.laser,
        head.params,
        tuple(head.captures),
        vnl,
        corner_sigma_px,
        level,
        tuple(files),
    )


def _capture_entry(
    path: Path, version: int, i: int, c: Any
) -> tuple[tuple[Mapping[str, Any], str], list[tuple[str, Any]]]:
    """A board capture's entry checked (keys, name, exactly one of ``corners_px`` or
    ``image``, the scan entries) with its name, and the files it names; none looked at."""
    kp = f"captures[{i}]"
    many = version >= BOARD_SESSION_SCANS_VERSION
    c = check_keys(c, path, kp, ["laser_side"], ["scan", *["scans"] * many, "name", "corners_px", "image"])
    name = capture_name(path, kp, c, i)
    if ("corners_px" in c) == ("image" in c):
        raise InputError.at(
            path, kp, sorted(c), "exactly one of corners_px (listed corners) or image (detect them)"
        )
    named = scan_entries(path, kp, c, many, required=False)
    if "image" in c:
        named.insert(0, file_entry(path, f"{kp}.image", c["image"]))
    return (c, name), named


def _board_poses(
    f: BoardSessionFile, files: list[Path]
) -> tuple[list[_SeenBoard], list[tuple[int, str, Any]], list[FloatArray]]:
    """Each capture's board corners (listed, from the corners file, or detected in its image,
    which ``files`` gains) and the board's pose by PnP: the captures seen, those whose image
    shows no board (index, name, image) and the corners of each seen one."""
    seen: list[_SeenBoard] = []
    unseen: list[tuple[int, str, Any]] = []
    corner_sets: list[FloatArray] = []
    for i, (c, name) in enumerate(f.captures):
        corners = _corners(f.path, f"captures[{i}]", c, f.board, f.camera, files, f.corners_vnl)
        if corners is None:
            unseen.append((i, name, c["image"]))
            continue
        corner_sets.append(corners)
        T, cov, err = board_pose(f.camera, f.board, corners, f.corner_sigma_px)
        seen.append(_SeenBoard(i, c, name, T, cov, err))
    return seen, unseen, corner_sets


def _laser_returns(
    f: BoardSessionFile, seen: list[_SeenBoard], files: list[Path]
) -> tuple[list[PlaneObservation], list[Scan | None], list[int], dict[str, int]]:
    """Each seen capture's scan (``files`` gains it) and the board's returns in it, as a
    plane observation: given (segments, points, a returns file) or left empty for
    ``laser_side: auto``; also the scans, the positions of the auto captures and, per
    capture name, how many scans its scan is the mean of."""
    path = f.path
    obs: list[PlaneObservation] = []
    scans: list[Scan | None] = []
    auto: list[int] = []
    n_scans: dict[str, int] = {}
    for i, c, name, T, cov, _ in seen:
        kp = f"captures[{i}]"
        side = c["laser_side"]
        listed = isinstance(side, dict) and "returns_file" in side
        if "scan" not in c and "scans" not in c and not listed:
            raise InputError(
                f"{path}: {kp}.scan: missing; this key is required (unless laser_side lists "
                "the board's returns in a returns_file)"
            )
        scan = None
        if "scan" in c or "scans" in c:
            # One scan, or the per-beam robust mean of a still moment's scans.
            scan, scan_files = read_capture_scans(path, kp, c, f.version >= BOARD_SESSION_SCANS_VERSION)
            scan_path = scan_files[0]
            files += scan_files
            n_scans[name] = len(scan_files)
        scans.append(scan)
        if side == "auto":
            auto.append(len(obs))
            pts = np.zeros((0, 2))
        elif listed:
            pts = _listed_returns(path, f"{kp}.laser_side", side, files, f.version)
        else:
            assert scan is not None
            pts = _given_returns(path, f"{kp}.laser_side", side, scan, scan_path, f.params, f.version)
        obs.append(plane_observation(i, name, T, cov, pts))
    return obs, scans, auto, n_scans


def _auto_returns(
    f: BoardSessionFile,
    obs: list[PlaneObservation],
    auto: list[int],
    scans: list[Scan | None],
    seen: list[_SeenBoard],
) -> list[PlaneObservation]:
    """The ``laser_side: auto`` captures' returns, detected (:func:`_detect`): the full
    solve only, and every capture's scan is needed."""
    path = f.path
    index = [s.capture for s in seen]
    if f.level is not None:
        raise InputError.at(
            path,
            f"captures[{index[auto[0]]}].laser_side",
            "auto",
            "the board's segment ids (`rigcal lines`), returns_file or points: laser_side auto "
            "finds the returns with the full solve, which upright boards cannot support",
        )
    missing = [index[k] for k, sc in enumerate(scans) if sc is None]
    if missing:
        raise InputError(
            f"{path}: captures[{missing[0]}].scan: missing; laser_side auto compares every "
            "capture's scan, so each capture needs its scan"
        )
    poses = [s.T_cam_board for s in seen]
    present = [sc for sc in scans if sc is not None]
    return _detect(path, obs, auto, present, poses, f.shape, f.params, index)


def _check_board_normals(
    path: Path, planes: list[tuple[str, PlaneObservation]], level: LevelPriors | None
) -> None:
    """The images-first check: the boards' planes must be able to fix what the solve
    solves (all six dof; with level priors, yaw and the horizontal translations)."""
    if len(planes) < 3:
        return
    obs = [o for _, o in planes]
    try:
        if level is None:
            check_normals(obs)
        else:
            check_level_geometry(
                board_vertical(np.array([o.normal_cam for o in obs])), [n for n, _ in planes]
            )
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None


def _level_priors(path: Path, v: Any, version: int) -> LevelPriors:
    """The session's ``level:``: each of LEVEL_KEYS as [value, sigma]."""
    if version < 3:
        raise InputError.at(path, "level", v, "no level in schema_version 1 or 2 (level needs 3)")
    d = check_keys(v, path, "level", list(LEVEL_KEYS), [])
    out = []
    for key in LEVEL_KEYS:
        x = d[key]
        ok = isinstance(x, list) and len(x) == 2
        ok = ok and all(isinstance(a, (int, float)) and not isinstance(a, bool) and np.isfinite(a) for a in x)
        if not ok or x[1] <= 0:
            unit = "m" if key.endswith("_m") else "deg"
            raise InputError.at(
                path, f"level.{key}", x, f"[measured value, 1-sigma > 0] in {unit}, e.g. [0.0, 0.5]"
            )
        out.append((float(x[0]), float(x[1])))
    return LevelPriors(*out)


def _size_m(path: Path, b: Any, board: Board, version: int) -> tuple[float, float]:
    """board.size_m: [width, height] of the sheet, metres, at least the printed pattern's
    (inner corners plus one square all round)."""
    v = b["size_m"]
    if version < 2:
        raise InputError.at(path, "board.size_m", v, "no size_m in schema_version 1 (size_m needs 2)")
    return sheet_size_m(v, path, board.width_n, board.height_n, board.spacing_m)


def _listed_returns(path: Path, key: str, side: Any, files: list[Path], version: int) -> FloatArray:
    """The board's returns listed in a text file (``laser_side: {returns_file: FILE}``), as
    MATLAB laser-camera toolboxes save a capture's points on the board."""
    from rigcal.recordings.laser_text import read_board_points

    if len(side) != 1:
        raise InputError.at(path, key, side, "{returns_file: FILE} alone")
    if version < 2:
        raise InputError.at(
            path, f"{key}.returns_file", side["returns_file"], "no returns_file in schema_version 1 (needs 2)"
        )
    points_path = session_file(path, f"{key}.returns_file", side["returns_file"])
    files.append(points_path)
    return read_board_points(points_path)


def _given_returns(
    path: Path, key: str, side: Any, scan: Scan, scan_path: Path, params: LineParams, version: int
) -> FloatArray:
    """The board's returns a capture names: one segment, several, or two laser points."""
    forms = ("segment", "segments", "points")
    if not isinstance(side, dict) or len(side) != 1 or next(iter(side)) not in forms:
        raise InputError.at(
            path,
            key,
            side,
            "auto, {segment: ID}, {segments: [ID, ...]}, {points: [[x1, y1], [x2, y2]]} "
            "or {returns_file: FILE}",
        )
    if "segment" in side:
        return np.array(
            segment_by_id(path, f"{key}.segment", side["segment"], scan, scan_path, params).points
        )
    if "segments" in side:
        pieces = segments_by_ids(path, f"{key}.segments", side["segments"], scan, scan_path, params, version)
        return np.concatenate([np.array(g.points) for g in pieces])
    ends = point_pairs(side["points"], path, f"{key}.points", "laser point")
    if np.linalg.norm(ends[0] - ends[1]) < 0.05:
        raise InputError.at(path, f"{key}.points", ends.tolist(), "two distinct ends at least 5 cm apart")
    beams = beams_near(scan, ends)
    if len(beams) < 2:
        raise InputError.at(
            path, f"{key}.points", ends.tolist(), "two points on the board in the scan (no returns near)"
        )
    return np.array(scan.points[beams])


def _detect(
    path: Path,
    obs: list[PlaneObservation],
    auto: list[int],
    scans: list[Scan],
    poses: list[FloatArray],
    shape: BoardShape,
    params: LineParams,
    index: list[int],
) -> list[PlaneObservation]:
    """Fill in the returns of the ``laser_side: auto`` captures (board_detect); ``index``
    maps each capture's position to its index in the file, for the error's key."""
    from dataclasses import replace

    given = {i: o.points_laser for i, o in enumerate(obs) if i not in auto}
    planes = [(o.normal_cam, o.distance_m) for o in obs]
    try:
        found = detect_board_returns(scans, poses, planes, shape, given, params)
    except BoardNotFoundError as exc:
        raise InputError.at(path, f"captures[{index[exc.capture]}].laser_side", "auto", exc.detail) from None
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: laser_side auto: {exc}") from None
    return [replace(o, points_laser=found[i]) if i in auto else o for i, o in enumerate(obs)]


def _corners(
    path: Path,
    kp: str,
    c: Any,
    board: Board,
    camera: Camera,
    files: list[Path],
    vnl: dict[str, FloatArray] | None,
) -> FloatArray | None:
    """(N, 2) the board's corners in the image, row-major (corners_x per row): listed, or
    from the session's corners file for this image's name, or detected in the image (None
    when the image shows no board)."""
    n = board.width_n * board.height_n
    if "image" in c and vnl is not None:
        name = Path(str(c["image"])).name
        if name not in vnl:
            raise InputError.at(
                path, f"{kp}.image", c["image"], "an image listed with a board in corners_vnl"
            )
        grid = vnl[name]
        if (grid[..., 2] <= 0).any():
            raise InputError.at(
                path, f"{kp}.image", c["image"], "an image whose corners are all detected in corners_vnl"
            )
        return np.array(grid[..., :2].reshape(-1, 2))
    if "image" in c:
        image = session_file(path, f"{kp}.image", c["image"])
        check_image(path, f"{kp}.image", c["image"], image, camera)
        files.append(image)
        det = detect_corners([image], board)
        if not det.paths:
            return None
        return np.array(det.corners[0, :, :, :2].reshape(-1, 2))
    v = c["corners_px"]
    if not isinstance(v, list) or len(v) != n:
        shown = f"{len(v)} corners" if isinstance(v, list) else v
        raise InputError.at(path, f"{kp}.corners_px", shown, f"{n} [u, v] pairs, row-major")
    out = np.empty((n, 2))
    for j, uv in enumerate(v):
        if not (
            isinstance(uv, list)
            and len(uv) == 2
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in uv)
        ):
            raise InputError.at(path, f"{kp}.corners_px[{j}]", uv, "a pixel [u, v] of finite numbers")
        out[j] = uv
    if not camera.in_image(out).all():
        j = int(np.flatnonzero(~camera.in_image(out))[0])
        raise InputError.at(path, f"{kp}.corners_px[{j}]", out[j].tolist(), "a pixel inside the image")
    return out


def plane_observation(
    capture: int, name: str, T_cam_board: FloatArray, pose_cov: FloatArray, points_laser: FloatArray
) -> PlaneObservation:
    """A capture's plane observation from its board pose (the board's z = 0 plane, normal
    oriented so that the distance is positive) and its laser returns on the board."""
    n = T_cam_board[:3, 2]
    dist = float(n @ T_cam_board[:3, 3])
    if dist < 0:
        n, dist = -n, -dist
    return PlaneObservation(
        capture,
        name,
        n,
        dist,
        points_laser,
        board_origin_cam=T_cam_board[:3, 3].copy(),
        board_pose_cov=pose_cov,
    )


def board_points(board: Board) -> FloatArray:
    """(N, 3) the inner corners in the board frame, row-major: x along a row, y down the
    columns, z = 0 (the board's plane)."""
    j, i = np.meshgrid(np.arange(board.height_n), np.arange(board.width_n), indexing="ij")
    return np.column_stack([i.ravel() * board.spacing_m, j.ravel() * board.spacing_m, np.zeros(i.size)])


def board_pose(
    camera: Camera, board: Board, corners_px: FloatArray, corner_sigma_px: float
) -> tuple[FloatArray, FloatArray, float]:
    """T_cam_board by PnP, its (6, 6) covariance over [w, dt] (left perturbation, camera
    frame) and the corners' RMS reprojection error (px)."""
    return points_pose(camera, board_points(board), corners_px, corner_sigma_px)


def points_pose(
    camera: Camera,
    P: FloatArray,
    corners_px: FloatArray,
    corner_sigma_px: float,
    T_init: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, float]:
    """The pose of a pattern whose points ``P`` ((N, 3), its frame; planar or not) are seen
    at ``corners_px`` ((N, 2)): T_cam_pattern by PnP through the camera's full lens model
    (from ``T_init`` when given), its (6, 6) covariance over [w, dt] (left perturbation,
    camera frame, the rotation about the pattern's origin) from the reprojection Jacobian
    and ``corner_sigma_px``, and the RMS reprojection error (px)."""
    import cv2

    b = camera.bearings(corners_px)
    norm = b[:, :2] / b[:, 2:3]
    if T_init is None:
        ok, rvec, tvec = cv2.solvePnP(P, norm, np.eye(3), None, flags=cv2.SOLVEPNP_ITERATIVE)
    else:
        rvec0 = R_to_rotvec(T_init[:3, :3]).reshape(3, 1)
        tvec0 = np.asarray(T_init[:3, 3], dtype=float).reshape(3, 1).copy()
        ok, rvec, tvec = cv2.solvePnP(
            P, norm, np.eye(3), None, rvec0, tvec0, useExtrinsicGuess=True, flags=cv2.SOLVEPNP_ITERATIVE
        )
    if not ok:  # pragma: no cover - PnP on a full board does not fail
        raise InputError("PnP failed on a pattern's corners")
    T = make_T(rotvec_to_R(rvec.ravel()), tvec.ravel())

    def project(x: FloatArray) -> FloatArray:
        R = rotvec_to_R(x[:3]) @ T[:3, :3]
        return camera.project(P @ R.T + T[:3, 3] + x[3:]).ravel()

    q0 = project(np.zeros(6))
    J = np.empty((len(q0), 6))
    for k in range(6):
        h = 1e-6
        dx = np.zeros(6)
        dx[k] = h
        J[:, k] = (project(dx) - project(-dx)) / (2 * h)
    cov = corner_sigma_px**2 * np.linalg.inv(J.T @ J)
    err = float(np.sqrt(np.mean(np.sum((q0.reshape(-1, 2) - corners_px) ** 2, axis=1))))
    return T, 0.5 * (cov + cov.T), err
