"""rigcal's Python API: calibrate and localize from files or from arrays in memory.

Everything here is importable from ``rigcal`` itself (``rigcal.solve_box``, ...); the
functions wrap the library's own entry points (the ones ``rigcal solve`` and ``rigcal
localize`` call), so a result is the same whichever way it was asked for. They raise
:mod:`rigcal.errors` exceptions and never print. docs/api.md is the guide.
"""

from __future__ import annotations

import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.camera import Camera
from rigcal.errors import InputError
from rigcal.rig import Rig
from rigcal.scan import Scan

FloatArray = NDArray[np.float64]

__all__ = [
    "BoardCapture",
    "BoxCapture",
    "Localization",
    "Solution",
    "localize",
    "read_rig",
    "solve_board",
    "solve_box",
    "write_rig",
]


@dataclass(frozen=True)
class BoxCapture:
    """One box-target capture in memory (what a picking file's capture says).

    Attributes:
        scan: the laser scan.
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
    """One checkerboard capture in memory.

    Attributes:
        T_cam_board: (4, 4) the board's pose in the camera frame (e.g. from solvePnP on
            its corners); the board is its own z = 0 plane.
        points_laser: (M, 2) metres, laser frame: the laser returns on the board.
        pose_cov: (6, 6) covariance of the board's pose over [rotation (rad), translation
            (m)] in the camera frame, or None (then a 1 mm plane-distance sigma is used).
        name: the capture's name (default capture00, ...).
    """

    T_cam_board: ArrayLike
    points_laser: ArrayLike
    pose_cov: ArrayLike | None = None
    name: str = ""


@dataclass(frozen=True)
class Solution:
    """A finished calibration.

    Attributes:
        rig: the calibrated rig (T_cam_laser, camera, covariance); :func:`write_rig` saves it.
        report: the residual report, as ``rigcal solve`` writes report.json.
        result: the solver's own result (rigcal.calib.solve.CalibResult or
            rigcal.calib.plane.PlaneResult): every measurement, inlier flags, residuals.
    """

    rig: Rig
    report: dict[str, Any]
    result: Any


def read_rig(path: str | Path) -> Rig:
    """Read a rig file (docs/formats/rig.md).

    Raises:
        InputError: a missing, malformed or invalid file, naming the key and value.
    """
    from rigcal.rigfile import read_rig as read

    return read(path)


def write_rig(path: str | Path, rig: Rig, force: bool = False) -> Path:
    """Write a rig file atomically (refused if it exists, unless ``force``).

    Raises:
        OutputError: the file exists and ``force`` is False, or it cannot be written.
    """
    from rigcal.rigfile import write_rig as write

    return write(path, rig, force=force)


def solve_box(
    captures: str | Path | Sequence[BoxCapture],
    camera: Camera | None = None,
    *,
    range_sigma_m: float | None = None,
    pick_sigma_px: float = 1.0,
    seed: int = 0,
    T_truth: ArrayLike | None = None,
) -> Solution:
    """Box-target calibration (the paper's Algorithm 1), as ``rigcal solve``.

    Args:
        captures: a picking file (docs/formats/session.md), or the captures in memory.
        camera: the camera model; needed for in-memory captures (a picking file names its own).
        range_sigma_m: the laser's range noise (1 sigma); default: the picking file's
            ``laser.range_sigma_m``, else 1 cm.
        pick_sigma_px: the pick noise (1 sigma).
        seed: RANSAC's seed.
        T_truth: (4, 4) a known T_cam_laser: the report then holds the error against it.

    Raises:
        InputError: a bad picking file or capture (a segment id the scan does not have,
            picks outside the image, ...).
        CalibrationError: too few captures, degenerate geometry, no consensus.
    """
    from rigcal.calib.ransac import RansacParams
    from rigcal.calib.refine import NoiseModel
    from rigcal.calib.report import build_report
    from rigcal.calib.session import box_rig, calibrate, scanner_description
    from rigcal.calib.solve import CalibProblem, SolveSettings, solve
    from rigcal.rigfile import provenance

    settings = SolveSettings(ransac=RansacParams(seed=seed), noise=NoiseModel(pick_sigma_px=pick_sigma_px))
    truth = None if T_truth is None else np.asarray(T_truth, dtype=float)
    if isinstance(captures, (str, Path)):
        cal = calibrate(captures, settings, command="rigcal.solve_box", range_sigma_m=range_sigma_m)
        report = cal.report if truth is None else build_report(cal.result, truth)
        return Solution(cal.rig, report, cal.result)
    if camera is None:
        raise InputError.at(None, "camera", None, "a Camera for captures given in memory")
    sigma = 0.01 if range_sigma_m is None else range_sigma_m
    settings = replace(settings, noise=replace(settings.noise, range_sigma_m=sigma))
    observations = tuple(_box_observation(i, c, camera, sigma) for i, c in enumerate(captures))
    result = solve(CalibProblem(camera, observations, settings))
    report = build_report(result, truth)
    laser = {"range_sigma_m": sigma, **scanner_description(observations)}
    prov = provenance("rigcal.solve_box", [], {"method": "box-target (Algorithm 1)", **settings.to_dict()})
    return Solution(box_rig(result, report, laser, prov), report, result)


def _box_observation(i: int, c: BoxCapture, camera: Camera, range_sigma_m: float) -> Any:
    from rigcal.calib.lines import LineParams, extract_lines
    from rigcal.calib.picks import side_observation

    key = f"captures[{i}]"
    px = np.asarray(c.image_endpoints_px, dtype=float)
    if px.shape != (2, 2) or not np.all(np.isfinite(px)) or not np.all(camera.in_image(px)):
        raise InputError.at(
            None, f"{key}.image_endpoints_px", px.tolist(), "two pixels [[u, v], [u, v]] inside the image"
        )
    if isinstance(c.side, (int, np.integer)):
        segments = extract_lines(c.scan, LineParams.for_range_noise(range_sigma_m))
        if not 0 <= int(c.side) < len(segments):
            raise InputError.at(None, f"{key}.side", c.side, f"a segment id from 0 to {len(segments) - 1}")
        beams = np.array(segments[int(c.side)].indices, dtype=np.int64)
    else:
        beams = np.asarray(c.side, dtype=np.int64).reshape(-1)
        n = len(c.scan.ranges_m)
        if len(beams) < 2 or beams.min() < 0 or beams.max() >= n or not np.all(c.scan.valid[beams]):
            raise InputError.at(
                None, f"{key}.side", beams.tolist(), f"2 or more valid beam indices below {n}"
            )
    name = c.name or f"capture{i:02d}"
    # In-memory captures have no files; the observation's file fields name the capture.
    where = Path(f"<memory>/{name}")
    return side_observation(i, name, where, where, c.scan, beams, px)


def solve_board(
    captures: str | Path | Sequence[BoardCapture],
    camera: Camera | None = None,
    *,
    range_sigma_m: float | None = None,
    seed: int = 0,
    T_truth: ArrayLike | None = None,
) -> Solution:
    """Plane-based (checkerboard) calibration, as ``rigcal solve`` on a board session.

    Args:
        captures: a board session file (docs/formats/board-session.md), or the captures
            in memory.
        camera: the camera model; recorded in the rig of in-memory captures (required).
        range_sigma_m: the laser's range noise; default: the session's
            ``laser.range_sigma_m``, else 1 cm.
        seed: RANSAC's seed.
        T_truth: (4, 4) a known T_cam_laser, compared with in the report.

    Raises:
        InputError: a bad session file or capture.
        CalibrationError: too few captures, boards too alike, no consensus.
    """
    from rigcal.calib.board_calibrate import calibrate_board
    from rigcal.calib.board_session import plane_observation
    from rigcal.calib.plane import PlaneObservation, solve_plane
    from rigcal.calib.report import truth_comparison
    from rigcal.rigfile import provenance

    truth = None if T_truth is None else np.asarray(T_truth, dtype=float)
    if isinstance(captures, (str, Path)):
        cal = calibrate_board(captures, range_sigma_m, command="rigcal.solve_board", seed=seed)
        doc = dict(cal.report)
        if truth is not None:
            doc["truth"] = truth_comparison(cal.result.T_cam_laser, cal.result.covariance, truth)
        return Solution(cal.rig, doc, cal.result)
    if camera is None:
        raise InputError.at(None, "camera", None, "a Camera for captures given in memory")
    observations: list[PlaneObservation] = []
    for i, c in enumerate(captures):
        T = np.asarray(c.T_cam_board, dtype=float)
        pts = np.asarray(c.points_laser, dtype=float)
        if T.shape != (4, 4) or pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 2:
            raise InputError.at(
                None,
                f"captures[{i}]",
                (T.shape, pts.shape),
                "T_cam_board (4, 4) and points_laser (M >= 2, 2)",
            )
        cov = None if c.pose_cov is None else np.asarray(c.pose_cov, dtype=float)
        observations.append(plane_observation(i, c.name or f"capture{i:02d}", T, cov, pts))  # type: ignore[arg-type]
    sigma = max(0.01 if range_sigma_m is None else range_sigma_m, 1e-4)
    result = solve_plane(observations, range_sigma_m=sigma, seed=seed)
    residuals = np.concatenate(
        [r for r, keep in zip(result.residuals_m, result.inlier_captures, strict=True) if keep]
    )
    summary = {
        "captures": len(observations),
        "captures_used": int(result.inlier_captures.sum()),
        "rms_mm": round(1000.0 * float(np.sqrt(np.mean(residuals**2))), 3),
        "max_mm": round(1000.0 * float(np.abs(residuals).max()), 3),
        "residual_scale": round(float(result.residual_scale), 3),
    }
    report: dict[str, Any] = {"summary": summary}
    if truth is not None:
        report["truth"] = truth_comparison(result.T_cam_laser, result.covariance, truth)
    settings = {
        "method": "board planes (Zhang and Pless)",
        "noise": {"range_sigma_m": sigma},
        "ransac": {"seed": seed},
    }
    rig = Rig(
        T_cam_laser=result.T_cam_laser,
        camera=camera,
        covariance=result.covariance,
        laser={"range_sigma_m": sigma},
        residuals=summary,
        provenance=provenance("rigcal.solve_board", [], settings),
    )
    return Solution(rig, report, result)


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


def localize(
    sequence: str | Path,
    methods: Sequence[str] = ("icp",),
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
        methods: one or more of icp, icp-p2p, vo, kf, iasm, hiasm, odom.
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
        InputError: an unknown method or a sequence that cannot be localized.
        OutputError: ``output`` exists and ``force`` is False.
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.localize.iasm import IasmParams
    from rigcal.localize.pipeline import parse_settings, run
    from rigcal.localize.tracks import TrackParams

    # The same checks as the command line's, each error naming the argument.
    track_params = parse_settings([f"{k}={v}" for k, v in (tracks or {}).items()], TrackParams(), "tracks")
    iasm_params = parse_settings([f"{k}={v}" for k, v in (iasm or {}).items()], IasmParams(), "iasm")
    if output is not None:
        check_folder_writable(output, force)  # refuse before the work
    with tempfile.TemporaryDirectory(prefix="rigcal-") as tmp:
        out = Path(output) if output is not None else Path(tmp) / "out"
        r = run(
            sequence,
            list(methods),
            out,
            force=force,
            rig_file=rig,
            iasm=iasm_params,
            tracks=track_params,
            wheel_odometry=wheel_odometry,
        )
    return {m.method: Localization(m.method, m.stamps_s, m.poses, m.metrics) for m in r.methods}
