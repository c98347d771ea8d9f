"""rigcal's Python API: calibrate and localize from files or from arrays in memory.

Everything here is importable from ``rigcal`` itself (``rigcal.solve_box``, ...). The
functions call the library's own entry points, the ones ``rigcal solve`` and ``rigcal
localize`` call (one solve path per method: :func:`rigcal.calib.box.session.calibrate_session`
and :func:`rigcal.calib.board.calibrate.calibrate_board_session`), so a result is the same
to the last digit whichever way it was asked for. Every argument is checked as the
command line checks its option (the same objects, :mod:`rigcal.calib.options`), and a bad
one raises :class:`~rigcal.errors.ArgumentError` naming the function, the argument and the
value; the functions never print. docs/api.md is the guide.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NotRequired, TypedDict, cast

import numpy as np
from numpy.typing import ArrayLike

from rigcal.arrays import FloatArray
from rigcal.calib.intrinsics import Board
from rigcal.camera import Camera
from rigcal.errors import ArgumentError, InputError
from rigcal.io.trajectory import Trajectory
from rigcal.rig import Rig
from rigcal.scan import Scan

if TYPE_CHECKING:
    from rigcal.calib.board.level import LevelPriors
    from rigcal.calib.board.plane import PlaneResult
    from rigcal.calib.box.picks import BoxObservation
    from rigcal.calib.box.solve import CalibResult


__all__ = [
    "Board",
    "BoardCapture",
    "BoardReport",
    "BoxCapture",
    "BoxReport",
    "LaserOdometry",
    "Localization",
    "Solution",
    "Trajectory",
    "localize",
    "read_rig",
    "read_scans",
    "read_trajectory",
    "solve_board",
    "solve_box",
    "write_rig",
    "write_trajectory",
]


# --- records ----------------------------------------------------------------------------


@dataclass(frozen=True)
class BoxCapture:
    """One box-target capture in memory (what a picking file's capture says).

    Attributes:
        scan: the laser scan (:class:`rigcal.Scan`).
        side: the box side in the scan: a segment id as ``rigcal lines`` numbers the
            scan's segments (for the same ``range_sigma_m``), or the beam indices of the
            returns on the box side.
        image_endpoints_px: (2, 2) the two box ends picked in the image, end 0 first (the
            end at the smaller beam angle, docs/conventions.md).
        name: the capture's name in reports (default capture00, capture01, ...).
    """

    scan: Scan
    side: int | ArrayLike
    image_endpoints_px: ArrayLike
    name: str = ""


@dataclass(frozen=True)
class BoardCapture:
    """One checkerboard capture in memory (what a board session's capture says).

    Attributes:
        corners_px: (N, 2) the board's inner corners in the image, row-major
            (``board.width_n`` per row), as ``cv2.findChessboardCorners`` gives them
            (reshaped to (N, 2)).
        points_laser: (M, 2) metres, laser frame: the laser returns on the board (e.g.
            ``segment.points`` of its line in the scan).
        name: the capture's name (default capture00, ...).
    """

    corners_px: ArrayLike
    points_laser: ArrayLike
    name: str = ""


class TruthComparison(TypedDict):
    """The error against a known T_cam_laser (``T_truth``), in the covariance's tangent
    space, and its normalised squared size (NEES, chi-square with 6 dof if honest)."""

    rotation_error_deg: float
    translation_error_mm: float
    nees: float


class NoiseEntry(TypedDict):
    """One noise of the model: assumed (options, files), estimated from the data (None
    when it could not be) and used."""

    assumed: float
    estimated: float | None
    used: float


class BoxSummary(TypedDict):
    """The box solve's summary (docs/formats/report.md)."""

    captures: int
    captures_used: int
    box_ends: int
    inlier_ends: int
    rms_px: float
    median_px: float
    max_px: float
    residual_scale: float
    sigma_rotation_deg: list[float]
    sigma_translation_mm: list[float]
    ransac_triples: int
    ransac_hypotheses: int


class BoardSummary(TypedDict):
    """The board solve's summary (docs/formats/report.md, board variant)."""

    method: str
    captures: int
    captures_used: int
    returns: int
    rms_mm: float
    max_mm: float
    residual_scale: float
    capture_sigma_mm: float
    range_bias_mm: float
    range_bias_sigma_mm: float | None
    sigma_rotation_deg: list[float]
    sigma_translation_mm: list[float]


class BoxReport(TypedDict):
    """A box solve's report, as ``rigcal solve --report`` writes report.json."""

    summary: BoxSummary
    noise: dict[str, NoiseEntry]
    uncertainty: dict[str, Any]
    rejected: list[dict[str, Any]]
    warnings: list[str]
    per_capture: list[dict[str, Any]]
    ends: list[dict[str, Any]]
    truth: NotRequired[TruthComparison]


class BoardReport(TypedDict):
    """A board solve's report, as ``rigcal solve --report`` writes report.json."""

    summary: BoardSummary
    noise: dict[str, NoiseEntry]
    uncertainty: dict[str, Any]
    per_capture: list[dict[str, Any]]
    warnings: list[str]
    truth: NotRequired[TruthComparison]


@dataclass(frozen=True)
class Solution[ReportT, ResultT]:
    """A finished calibration: ``Solution[BoxReport, CalibResult]`` from
    :func:`solve_box`, ``Solution[BoardReport, PlaneResult]`` from :func:`solve_board`.

    Attributes:
        rig: the calibrated rig (T_cam_laser, camera, covariance); :func:`write_rig` saves it.
        report: the report, as ``rigcal solve`` writes report.json (with ``T_truth``,
            the error against it under ``truth``).
        result: the solver's own result (:class:`rigcal.calib.box.solve.CalibResult` or
            :class:`rigcal.calib.board.plane.PlaneResult`): every measurement, inlier flags,
            residuals.
    """

    rig: Rig
    report: ReportT
    result: ResultT


@dataclass(frozen=True)
class Localization:
    """One method's trajectory through a sequence.

    Attributes:
        method: the method's name (icp, icp-p2p, vo, kf, iasm, hiasm, odom).
        stamps_s: (N,) the pose stamps, seconds.
        poses: (N, 3) the laser's planar poses (x m, y m, yaw rad), in the truth's frame
            when the sequence has ground truth, else in the first pose's.
        metrics: the Table 1 figures, ATE and RPE against the truth, or None.
    """

    method: str
    stamps_s: FloatArray
    poses: FloatArray
    metrics: dict[str, Any] | None

    def trajectory(self, z_m: float = 0.0) -> Trajectory:
        """The poses as a :class:`Trajectory` (4x4 T_world_laser at height ``z_m``).

        Raises:
            ArgumentError: ``z_m`` is not a finite number, or the poses are not (N, 3).
        """
        return _planar(self.stamps_s, self.poses, z_m, "rigcal.Localization.trajectory")


def _planar(stamps_s: Any, poses: Any, z_m: Any, where: str) -> Trajectory:
    from rigcal.io.trajectory import planar_trajectory
    from rigcal.io.validate import finite_array, real

    with _arguments():
        z = real(z_m, where, "z_m")
        planar = finite_array(poses, where, "poses", shape=(None, 3))
    return planar_trajectory(stamps_s, planar, z)


# --- argument checks --------------------------------------------------------------------


@contextmanager
def _arguments() -> Iterator[None]:
    """Checks of a call's arguments: their InputErrors become ArgumentErrors."""
    try:
        yield
    except ArgumentError:
        raise
    except InputError as e:
        raise ArgumentError(str(e)) from None


def _path(value: Any, where: str, key: str) -> Path:
    if isinstance(value, bytes) or not isinstance(value, (str, os.PathLike)):
        raise InputError.at(where, key, value, "a path (str or pathlib.Path)")
    p = Path(value)
    if not str(p) or "\0" in str(p):
        raise InputError.at(where, key, str(value), "a path without NUL bytes")
    return p


def _instance[T](value: Any, kind: type[T], where: str, key: str, what: str) -> T:
    if not isinstance(value, kind):
        raise InputError.at(where, key, value, what)
    return value


def _camera(camera: Any, where: str) -> Camera:
    """A Camera, checked as a rig file's camera is read (:func:`rigcal.camera.camera_from_dict`)."""
    from rigcal.camera import camera_from_dict

    _instance(camera, Camera, where, "camera", "a rigcal.Camera (see docs/api.md for building one)")
    try:
        doc = camera.to_dict()
    except (TypeError, ValueError) as e:
        raise InputError.at(where, "camera", camera.lensmodel, f"a valid camera ({e})") from None
    camera_from_dict(doc, where, "camera")
    return cast(Camera, camera)


def _truth(T_truth: Any, where: str) -> FloatArray | None:
    from rigcal.io.transform import rigid_transform

    return None if T_truth is None else rigid_transform(T_truth, where, "T_truth")


def _captures[C](captures: Any, kind: type[C], where: str) -> list[C]:
    what = f"a session file path or a non-empty list of rigcal.{kind.__name__}"
    if isinstance(captures, (str, bytes)) or not isinstance(captures, Sequence) or not captures:
        raise InputError.at(where, "captures", captures, what)
    for i, c in enumerate(captures):
        _instance(c, kind, where, f"captures[{i}]", f"a rigcal.{kind.__name__}")
    return list(captures)


def _name(c: BoxCapture | BoardCapture, i: int, where: str) -> str:
    from rigcal.io.validate import path_component

    return path_component(c.name or f"capture{i:02d}", where, f"captures[{i}].name")


# --- calibration --------------------------------------------------------------------------


def read_rig(path: str | Path) -> Rig:
    """Read a rig file (docs/formats/rig.md).

    Raises:
        ArgumentError: ``path`` is not a path.
        InputError: a missing, malformed or invalid file, naming the key and value.
    """
    from rigcal.rigfile import read_rig as read

    with _arguments():
        p = _path(path, "rigcal.read_rig", "path")
    return read(p)


def write_rig(path: str | Path, rig: Rig, force: bool = False) -> Path:
    """Write a rig file atomically (refused if it exists, unless ``force``).

    The rig is checked first by the rig file reader's own validation, so a rig that
    :func:`read_rig` would refuse (a NaN translation, a matrix that is no rotation) is
    not written.

    Raises:
        ArgumentError: a bad argument or an invalid rig (nothing is written).
        OutputError: the file exists and ``force`` is False, or it cannot be written.
    """
    from rigcal.io.files import atomic_write_text
    from rigcal.io.validate import flag
    from rigcal.rigfile import checked_rig_text

    where = "rigcal.write_rig"
    with _arguments():
        p = _path(path, where, "path")
        _instance(rig, Rig, where, "rig", "a rigcal.Rig")
        _instance(rig.camera, Camera, where, "rig.camera", "a rigcal.Camera")
        force = flag(force, where, "force")
        text = checked_rig_text(rig, where, "rig")
    return atomic_write_text(p, text, force=force)


def solve_box(
    captures: str | Path | Sequence[BoxCapture],
    camera: Camera | None = None,
    *,
    range_sigma_m: float | None = None,
    pick_sigma_px: float = 1.0,
    threshold_px: float = 6.0,
    noise: str = "auto",
    loss: str = "cauchy",
    paper_endpoints: bool = False,
    seed: int = 0,
    T_truth: ArrayLike | None = None,
) -> Solution[BoxReport, CalibResult]:
    """Box-target calibration (the paper's Algorithm 1), as ``rigcal solve``.

    Args:
        captures: a picking file (docs/formats/session.md), or the captures in memory.
        camera: the camera model; needed for in-memory captures (a picking file names its own).
        range_sigma_m: the laser's range noise (1 sigma), ``--range-sigma-m``; default:
            the picking file's ``laser.range_sigma_m``, else 1 cm.
        pick_sigma_px: the pick noise (1 sigma), ``--pick-sigma-px``.
        threshold_px: RANSAC's inlier threshold, ``--threshold-px``.
        noise: "auto" estimates the range and pick noise from the session and uses them;
            "assumed" uses the values given (``--noise``).
        loss: the refinement's robust loss: linear, huber, soft_l1 or cauchy (``--loss``).
        paper_endpoints: use only the first and last returns of each box side,
            unweighted, as the paper does (``--paper-endpoints``).
        seed: RANSAC's seed (``--seed``).
        T_truth: (4, 4) a known T_cam_laser: the report then holds the error against it.

    Raises:
        ArgumentError: a bad argument (a type, a value the option would refuse, a segment
            id the scan does not have, picks outside the image, ...).
        InputError: a bad picking file or a file it names.
        CalibrationError: too few captures, degenerate geometry, no consensus.
    """
    from rigcal.calib import options
    from rigcal.calib.box.picks import PickSession
    from rigcal.calib.box.session import calibrate, calibrate_session
    from rigcal.io.validate import flag

    where = "rigcal.solve_box"
    with _arguments():
        sigma = _range_sigma(range_sigma_m, where)
        settings = options.box_settings(
            threshold_px=options.THRESHOLD_PX.check(threshold_px, where, "threshold_px"),
            seed=options.SEED.check(seed, where, "seed"),
            pick_sigma_px=options.PICK_SIGMA_PX.check(pick_sigma_px, where, "pick_sigma_px"),
            loss=options.LOSS.check(loss, where, "loss"),
            paper_endpoints=flag(paper_endpoints, where, "paper_endpoints"),
            noise=options.NOISE.check(noise, where, "noise"),
        )
        truth = _truth(T_truth, where)
        if isinstance(captures, (str, os.PathLike)):
            path = _path(captures, where, "captures")
            if camera is not None:
                raise InputError.at(
                    where, "camera", type(camera).__name__, "None with a picking file (it names its camera)"
                )
        else:
            caps = _captures(captures, BoxCapture, where)
            if camera is None:
                raise InputError.at(where, "camera", None, "a rigcal.Camera for captures given in memory")
            cam = _camera(camera, where)
            laser = {} if sigma is None else {"range_sigma_m": sigma}
            observations = tuple(_box_observation(i, c, cam, sigma, where) for i, c in enumerate(caps))
            _unique_names([o.name for o in observations], where)
    if isinstance(captures, (str, os.PathLike)):
        cal = calibrate(path, settings, command=where, range_sigma_m=sigma)
    else:
        memory = Path("<memory>")
        session = PickSession(memory, cam, memory, laser, observations)
        cal = calibrate_session(session, settings, command=where, range_sigma_m=sigma)
    return Solution(cal.rig, cast(BoxReport, _with_truth(cal.report, cal.result, truth)), cal.result)


def _range_sigma(value: Any, where: str) -> float | None:
    from rigcal.calib.options import RANGE_SIGMA_M

    return None if value is None else RANGE_SIGMA_M.check(value, where, "range_sigma_m")


def _with_truth(report: dict[str, Any], result: Any, truth: FloatArray | None) -> dict[str, Any]:
    """The report with the error against a known T_cam_laser (as ``--truth`` adds it)."""
    from rigcal.calib.report import truth_comparison

    if truth is None:
        return report
    return report | {"truth": truth_comparison(result.T_cam_laser, result.covariance, truth)}


def _unique_names(names: list[str], where: str) -> None:
    from rigcal.calib.box.picks import check_unique_names

    check_unique_names(where, names)  # type: ignore[arg-type]


def _box_observation(
    i: int, c: BoxCapture, camera: Camera, range_sigma_m: float | None, where: str
) -> BoxObservation:
    """A capture given in memory as the picking file reader resolves one (a segment id
    numbered as for the file's ``laser.range_sigma_m``)."""
    from rigcal.calib.box.picks import side_observation
    from rigcal.io.validate import finite_array
    from rigcal.lines import LineParams, extract_lines

    key = f"captures[{i}]"
    scan = _instance(c.scan, Scan, where, f"{key}.scan", "a rigcal.Scan")
    px = finite_array(c.image_endpoints_px, where, f"{key}.image_endpoints_px", shape=(2, 2))
    if not np.all(camera.in_image(px)):
        raise InputError.at(
            where, f"{key}.image_endpoints_px", px.tolist(), "two pixels [[u, v], [u, v]] inside the image"
        )
    side = c.side
    if isinstance(side, (int, np.integer)) and not isinstance(side, (bool, np.bool_)):
        params = LineParams() if range_sigma_m is None else LineParams.for_range_noise(range_sigma_m)
        segments = extract_lines(scan, params)
        if not 0 <= int(side) < len(segments):
            expected = (
                f"a segment id from 0 to {len(segments) - 1}"
                if segments
                else "a segment id, but the scan has no line segments"
            )
            raise InputError.at(where, f"{key}.side", side, expected)
        beams = np.array(segments[int(side)].indices, dtype=np.int64)
    else:
        n = len(scan.ranges_m)
        expected = f"a segment id, or 2 or more distinct valid beam indices below {n}, increasing"
        try:
            raw = np.asarray(side)
        except (TypeError, ValueError):
            raise InputError.at(where, f"{key}.side", side, expected) from None
        if raw.ndim != 1 or len(raw) < 2 or raw.dtype.kind not in "iu":
            raise InputError.at(where, f"{key}.side", side, expected)
        beams = raw.astype(np.int64)
        if (
            beams.min() < 0
            or beams.max() >= n
            or not np.all(np.diff(beams) > 0)
            or not np.all(scan.valid[beams])
        ):
            raise InputError.at(where, f"{key}.side", beams.tolist(), expected)
    name = _name(c, i, where)
    # In-memory captures have no files; the observation's file fields name the capture.
    memory = Path(f"<memory>/{name}")
    return side_observation(i, name, memory, memory, scan, beams, px)


def solve_board(
    captures: str | Path | Sequence[BoardCapture],
    camera: Camera | None = None,
    board: Board | None = None,
    *,
    range_sigma_m: float | None = None,
    corner_sigma_px: float = 0.5,
    noise: str = "auto",
    range_bias: bool = True,
    seed: int = 0,
    T_truth: ArrayLike | None = None,
    level: LevelPriors | None = None,
) -> Solution[BoardReport, PlaneResult]:
    """Plane-based (checkerboard) calibration, as ``rigcal solve`` on a board session.

    Args:
        captures: a board session file (docs/formats/board-session.md), or the captures
            in memory: each board's corners in the image and its returns in the scan; the
            board's pose comes from its corners by PnP, as for a session file.
        camera: the camera model (in-memory captures only: a file names its own).
        board: the board, ``rigcal.Board(width_n, height_n, spacing_m)``: inner corners
            per row and per column and the square size (in-memory captures only).
        range_sigma_m: the laser's range noise, ``--range-sigma-m``; default: the
            session's ``laser.range_sigma_m``, else 1 cm.
        corner_sigma_px: the corner noise assumed (1 sigma) for in-memory captures (a
            session file gives its own ``board.corner_sigma_px``, else 0.5).
        noise: "auto" estimates the range noise and the corner noise from the session and
            uses them; "assumed" uses the values given (``--noise``).
        range_bias: estimate the scanner's range bias by incidence with the pose
            (``--range-bias/--no-range-bias``).
        seed: RANSAC's seed (``--seed``).
        T_truth: (4, 4) a known T_cam_laser, compared with in the report.
        level: the reduced solve for boards that never tilt
            (``rigcal.calib.board.level.LevelPriors``: roll, pitch and camera height priors;
            ``--level-prior``), over a session file's ``level:``.

    Raises:
        ArgumentError: a bad argument (a type, a value the option would refuse, corners
            outside the image, ...).
        InputError: a bad session file or a file it names.
        CalibrationError: too few captures, boards too alike, no consensus.
    """
    from rigcal.calib import options
    from rigcal.calib.board.calibrate import calibrate_board, calibrate_board_session
    from rigcal.calib.board.level import LevelPriors
    from rigcal.io.validate import flag

    where = "rigcal.solve_board"
    with _arguments():
        sigma = _range_sigma(range_sigma_m, where)
        corner_sigma = options.CORNER_SIGMA_PX.check(corner_sigma_px, where, "corner_sigma_px")
        mode = options.NOISE.check(noise, where, "noise")
        bias = flag(range_bias, where, "range_bias")
        rng_seed = options.SEED.check(seed, where, "seed")
        truth = _truth(T_truth, where)
        if level is not None:
            _instance(level, LevelPriors, where, "level", "a rigcal.calib.board.level.LevelPriors")
        if isinstance(captures, (str, os.PathLike)):
            path = _path(captures, where, "captures")
            for key, value in (("camera", camera), ("board", board)):
                if value is not None:
                    raise InputError.at(
                        where, key, type(value).__name__, "None with a session file (it names its own)"
                    )
        else:
            caps = _captures(captures, BoardCapture, where)
            if camera is None:
                raise InputError.at(where, "camera", None, "a rigcal.Camera for captures given in memory")
            cam = _camera(camera, where)
            session = _board_session(caps, cam, _board(board, where), sigma, corner_sigma, where)
    if isinstance(captures, (str, os.PathLike)):
        cal = calibrate_board(
            path, sigma, command=where, seed=rng_seed, noise=mode, range_bias=bias, level=level
        )
    else:
        cal = calibrate_board_session(
            replace(session, level=level), sigma, command=where, seed=rng_seed, noise=mode, range_bias=bias
        )
    return Solution(cal.rig, cast(BoardReport, _with_truth(cal.report, cal.result, truth)), cal.result)


def _board(board: Any, where: str) -> Board:
    from rigcal.io.validate import real, whole

    if board is None:
        raise InputError.at(
            where, "board", None, "a rigcal.Board(width_n, height_n, spacing_m) for captures given in memory"
        )
    _instance(board, Board, where, "board", "a rigcal.Board(width_n, height_n, spacing_m)")
    whole(board.width_n, where, "board.width_n", lo=2, hi=10_000)
    whole(board.height_n, where, "board.height_n", lo=2, hi=10_000)
    real(board.spacing_m, where, "board.spacing_m", positive=True)
    return cast(Board, board)


def _board_session(
    captures: list[BoardCapture],
    camera: Camera,
    board: Board,
    range_sigma_m: float | None,
    corner_sigma_px: float,
    where: str,
) -> Any:
    """A board session from captures in memory, as :func:`read_board_session` builds one
    from a file: each board's pose by PnP on its corners, its plane, the laser returns."""
    from rigcal.calib.board.session import BoardSession, board_pose, plane_observation
    from rigcal.io.validate import finite_array

    n = board.width_n * board.height_n
    observations, poses, rms, names = [], [], [], []
    for i, c in enumerate(captures):
        key = f"captures[{i}]"
        corners = finite_array(c.corners_px, where, f"{key}.corners_px", shape=(n, 2))
        outside = ~camera.in_image(corners)
        if outside.any():
            j = int(np.flatnonzero(outside)[0])
            raise InputError.at(
                where, f"{key}.corners_px[{j}]", corners[j].tolist(), "a pixel inside the image"
            )
        points = finite_array(c.points_laser, where, f"{key}.points_laser", shape=(None, 2))
        if len(points) < 2:
            raise InputError.at(
                where, f"{key}.points_laser", points.tolist(), "2 or more laser returns (M, 2) on the board"
            )
        name = _name(c, i, where)
        T, cov, err = board_pose(camera, board, corners, corner_sigma_px)
        observations.append(plane_observation(i, name, T, cov, points))
        poses.append(T)
        rms.append(err)
        names.append(name)
    _unique_names(names, where)
    memory = Path("<memory>")
    laser = {} if range_sigma_m is None else {"range_sigma_m": range_sigma_m}
    return BoardSession(
        memory,
        camera,
        memory,
        board,
        laser,
        tuple(observations),
        np.array(poses),
        np.array(rms),
        (),
        corner_sigma_px=corner_sigma_px,
    )


# --- localization ---------------------------------------------------------------------------


def localize(
    sequence: str | Path,
    methods: str | Sequence[str] = ("icp",),
    *,
    output: str | Path | None = None,
    rig: str | Path | None = None,
    force: bool = False,
    tracks: Mapping[str, object] | None = None,
    iasm: Mapping[str, object] | None = None,
    wheel_odometry: bool = True,
) -> dict[str, Localization]:
    """Localize a sequence folder (docs/formats/sequence.md), as ``rigcal localize``.

    Args:
        sequence: the sequence folder.
        methods: one method or several (a name, a comma-separated text as ``--method``
            takes, or a list): icp, icp-p2p, vo, kf, iasm, hiasm, odom.
        output: also write the output folder ``rigcal localize`` writes (trajectories,
            summary, paths picture); default: nothing is written.
        rig: a rig file to use instead of the sequence's own.
        force: replace an existing ``output``.
        tracks, iasm: settings of the feature tracks and of IASM / H-IASM, as
            ``--tracks`` and ``--iasm`` take them (``{"equalize": "clahe"}``,
            ``{"snap_max_m": 0}``); default: the defaults.
        wheel_odometry: start ICP from the sequence's wheel odometry, when it has one,
            and fuse it in the Kalman filter (``--wheel-odometry use``).

    Returns:
        Each method's trajectory, by method name.

    Raises:
        ArgumentError: a bad argument (an unknown method, a setting the option refuses).
        InputError: a sequence that cannot be localized.
        OutputError: ``output`` exists and ``force`` is False.
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.io.validate import flag
    from rigcal.localize.iasm import IasmParams
    from rigcal.localize.pipeline import parse_methods, parse_settings, run
    from rigcal.localize.tracks import TrackParams
    from rigcal.viz.localize_output import write_run

    where = "rigcal.localize"
    # The same checks as the command line's, each error naming the argument.
    with _arguments():
        seq = _path(sequence, where, "sequence")
        out_path = None if output is None else _path(output, where, "output")
        rig_path = None if rig is None else _path(rig, where, "rig")
        force = flag(force, where, "force")
        use_wheels = flag(wheel_odometry, where, "wheel_odometry")
        if isinstance(methods, str):
            names = parse_methods(methods, f"{where}: methods")
        elif (
            isinstance(methods, Sequence)
            and methods
            and all(isinstance(m, str) and "," not in m for m in methods)
        ):
            names = parse_methods(",".join(methods), f"{where}: methods")
        else:
            raise InputError.at(where, "methods", methods, "a method name or a non-empty list of them")
        settings = {}
        for key, given in (("tracks", tracks), ("iasm", iasm)):
            if given is not None and not isinstance(given, Mapping):
                raise InputError.at(where, key, given, "a mapping of settings, e.g. {'equalize': 'clahe'}")
            settings[key] = [f"{k}={v}" for k, v in (given or {}).items()]
        track_params = parse_settings(settings["tracks"], TrackParams(), f"{where}: tracks")
        iasm_params = parse_settings(settings["iasm"], IasmParams(), f"{where}: iasm")
    if out_path is not None:
        check_folder_writable(out_path, force)  # refuse before the work
    with tempfile.TemporaryDirectory(prefix="rigcal-") as tmp:
        out = out_path if out_path is not None else Path(tmp) / "out"
        r = run(
            seq,
            names,
            rig_file=rig_path,
            iasm=iasm_params,
            tracks=track_params,
            wheel_odometry=use_wheels,
        )
        write_run(r, seq, out, force=force)
    return {m.method: Localization(m.method, m.stamps_s, m.poses, m.metrics) for m in r.methods}


class LaserOdometry:
    """Laser odometry inside a robot's own loop: feed it scans one at a time (as
    KISS-ICP's ``register_frame``); each call returns the current pose.

    It runs the same ICP odometry, step for step, as ``rigcal localize --method icp``
    (or ``icp-p2p``) over a recorded sequence (:class:`rigcal.localize.odometry.ScanOdometry`
    serves both), so the poses equal the batch run's to the last digit::

        odom = rigcal.LaserOdometry()
        for scan in scans:                       # rigcal.Scan, e.g. from a driver
            x, y, yaw = odom.register_scan(scan)

    Args:
        method: "icp" (point-to-line, the default) or "icp-p2p" (point-to-point, Eq. (4)).
    """

    def __init__(self, method: str = "icp") -> None:
        from rigcal.localize.odometry import LASER_ODOMETRY, ScanOdometry

        with _arguments():
            if not isinstance(method, str) or method not in LASER_ODOMETRY:
                raise InputError.at(
                    "rigcal.LaserOdometry", "method", method, "one of " + ", ".join(LASER_ODOMETRY)
                )
        self.method = method
        self._odometry = ScanOdometry(LASER_ODOMETRY[method])
        self._stamps: list[float] = []

    def register_scan(self, scan: Scan, guess: ArrayLike | None = None) -> FloatArray:
        """Match a scan to the previous one and return the laser's pose (x m, y m, yaw rad)
        in the first scan's frame (the first scan's pose is 0, 0, 0).

        Args:
            scan: the new scan; its ``stamp_s``, when given, must be after the previous one's.
            guess: the motion since the previous scan, T_prev_cur as (x m, y m, yaw rad)
                in the previous scan's frame (e.g. from wheel odometry), to start ICP
                from, used as ``rigcal localize`` uses a sequence's wheel odometry (a fit
                beyond its error bound keeps the guess); default: the previous step's
                motion (constant velocity).

        Raises:
            ArgumentError: not a Scan, a stamp not after the previous one, a bad guess.
        """
        from rigcal.io.validate import finite_array

        where = "rigcal.LaserOdometry.register_scan"
        with _arguments():
            _instance(scan, Scan, where, "scan", "a rigcal.Scan")
            stamp = float("nan") if scan.stamp_s is None else float(scan.stamp_s)
            if (
                self._stamps
                and np.isfinite(stamp)
                and np.isfinite(self._stamps[-1])
                and not stamp > self._stamps[-1]
            ):
                raise InputError.at(
                    where, "scan.stamp_s", stamp, f"a stamp after the previous scan's {self._stamps[-1]!r}"
                )
            step = None if guess is None else finite_array(guess, where, "guess", shape=(3,))
        pose = self._odometry.add(scan, step)
        self._stamps.append(stamp)
        return pose.copy()

    def __len__(self) -> int:
        """The number of scans registered."""
        return len(self._odometry)

    @property
    def poses(self) -> FloatArray:
        """(N, 3) every pose so far (x m, y m, yaw rad), in the first scan's frame."""
        return self._odometry.odometry().poses.reshape(-1, 3)

    @property
    def stamps_s(self) -> FloatArray:
        """(N,) the scans' stamps (NaN where a scan had none)."""
        return np.array(self._stamps, dtype=float)

    @property
    def degeneracy(self) -> FloatArray:
        """(N,) per step, the smallest over the largest eigenvalue of the translation's
        information: below 0.01 the scans did not constrain a direction (a corridor)."""
        return self._odometry.odometry().degeneracy

    def trajectory(self, z_m: float = 0.0) -> Trajectory:
        """The poses so far as a :class:`Trajectory` at height ``z_m`` (for
        :func:`write_trajectory`).

        Raises:
            ArgumentError: ``z_m`` is not a finite number.
        """
        return _planar(self.stamps_s, self.poses, z_m, "rigcal.LaserOdometry.trajectory")


def read_scans(sequence: str | Path) -> tuple[Scan, ...]:
    """The scans of a sequence folder (docs/formats/sequence.md), in time order, as
    ``rigcal localize`` reads them (a clockwise scanner's turned counter-clockwise).

    Raises:
        ArgumentError: ``sequence`` is not a path.
        InputError: a missing or invalid sequence.
    """
    from rigcal.recordings.sequence import read_sequence

    with _arguments():
        folder = _path(sequence, "rigcal.read_scans", "sequence")
    return read_sequence(folder).scans


# --- trajectories ---------------------------------------------------------------------------

TRAJECTORY_FORMATS = ("tum", "kitti")


def _format(path: Path, format: str | None, where: str) -> str:
    from rigcal.io.validate import OneOf

    if format is None:
        return "kitti" if path.suffix.lower() == ".kitti" else "tum"
    return OneOf(TRAJECTORY_FORMATS).check(format, where, "format")


def read_trajectory(path: str | Path, format: str | None = None) -> Trajectory:
    """Read a trajectory file: TUM (``timestamp tx ty tz qx qy qz qw``) or KITTI (the
    3x4 matrix per line, no stamps), as evo and most SLAM tools write them.

    Args:
        path: the file.
        format: "tum" or "kitti"; default: "kitti" for a ``.kitti`` file, else "tum".

    Returns:
        The poses T_world_body (N, 4, 4) and their stamps (None for KITTI).

    Raises:
        ArgumentError: a bad argument.
        InputError: a missing or invalid file, naming the line.
    """
    from rigcal.io.trajectory import read_kitti, read_tum

    where = "rigcal.read_trajectory"
    with _arguments():
        p = _path(path, where, "path")
        kind = _format(p, format, where)
    return read_kitti(p) if kind == "kitti" else read_tum(p)


def write_trajectory(
    path: str | Path,
    trajectory: Trajectory | Localization,
    format: str | None = None,
    force: bool = False,
) -> Path:
    """Write a trajectory file atomically (refused if it exists, unless ``force``).

    Args:
        path: the file.
        trajectory: a :class:`Trajectory`, or a :class:`Localization` (its planar poses
            at height 0).
        format: "tum" or "kitti"; default: "kitti" for a ``.kitti`` file, else "tum"
            (which needs stamps).

    Raises:
        ArgumentError: a bad argument (a TUM file of a trajectory without stamps, poses
            that are not rigid transforms).
        OutputError: the file exists and ``force`` is False, or it cannot be written.
    """
    from rigcal.io.trajectory import write_kitti, write_tum
    from rigcal.io.transform import rigid_transform
    from rigcal.io.validate import finite_array, flag

    where = "rigcal.write_trajectory"
    with _arguments():
        p = _path(path, where, "path")
        force = flag(force, where, "force")
        kind = _format(p, format, where)
        if isinstance(trajectory, Localization):
            n = len(finite_array(trajectory.poses, where, "trajectory.poses", shape=(None, 3)))
            stamps = None if trajectory.stamps_s is None else np.asarray(trajectory.stamps_s, dtype=float)
            if stamps is not None and stamps.shape != (n,):
                raise InputError.at(where, "trajectory.stamps_s", f"{stamps.shape}", f"({n},) stamps")
            trajectory = _planar(trajectory.stamps_s, trajectory.poses, 0.0, where)
        _instance(trajectory, Trajectory, where, "trajectory", "a rigcal.Trajectory or rigcal.Localization")
        poses = finite_array(trajectory.poses, where, "trajectory.poses", shape=(None, 4, 4))
        if not len(poses):
            raise InputError.at(where, "trajectory.poses", "no poses", "one pose or more")
        for k, T in enumerate(poses):
            rigid_transform(T, where, f"trajectory.poses[{k}]")
        if kind == "tum":
            if trajectory.stamps_s is None:
                raise InputError.at(
                    where, "trajectory.stamps_s", None, "stamps for a TUM file (or format='kitti')"
                )
            stamps = finite_array(trajectory.stamps_s, where, "trajectory.stamps_s", shape=(len(poses),))
            if not np.all(np.diff(stamps) > 0):
                raise InputError.at(where, "trajectory.stamps_s", "not increasing", "increasing stamps")
    return write_kitti(p, trajectory, force) if kind == "kitti" else write_tum(p, trajectory, force)
