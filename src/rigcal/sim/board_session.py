"""Synthetic board sessions (checkerboard seen by camera and scanner) with a known T_cam_laser.

Per capture a flat checkerboard stands in front of the rig, turned and tilted at random,
crossing the scan plane. Its inner corners are projected through the true T_cam_laser and
the camera, with Gaussian pixel noise; the scan is ray-cast against the board's cut with
the scan plane and the room's walls, with range noise and dropouts; the board's segment
id is found as a user would pick it (``find_face_segment``). The session folder holds
``camera.yaml``, ``scans/``, ``board_session.yaml`` (corners listed, no images) and
``truth.yaml``. One seeded generator drives everything.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.calib.board_session import board_points
from rigcal.calib.intrinsics import Board
from rigcal.calib.lines import LineParams
from rigcal.camera import Camera
from rigcal.errors import InputError
from rigcal.geometry import make_T, rotvec_to_R, transform_points
from rigcal.io.files import atomic_folder
from rigcal.scan import Scan, write_scan
from rigcal.sim.box_session import (
    FACE_TOLERANCE_M,
    FACE_TOLERANCE_SIGMAS,
    _room_pose,
    _write_camera,
    default_camera,
    default_T_cam_laser,
    find_face_segment,
)
from rigcal.sim.raycast import beam_angles, cast_scan_hits, noisy_ranges
from rigcal.sim.render import Room

FloatArray = NDArray[np.float64]

_MAX_ATTEMPTS = 500


@dataclass(frozen=True)
class BoardSpec:
    """What to simulate.

    Attributes:
        n_captures: captures in the session.
        corner_sigma_px: 1-sigma noise of each corner's pixel coordinates.
        range_sigma_m: 1-sigma range noise.
        dropout_fraction: fraction of returns lost.
        distance_m: (min, max) distance of the board's centre from the laser.
        max_turn_deg, max_tilt_deg: the board is turned about the vertical and tilted about
            its horizontal axis by up to these.
        board: the checkerboard (inner corners, square size); margin_m: its border.
        seed: seed of the generator.
    """

    n_captures: int = 12
    corner_sigma_px: float = 0.3
    range_sigma_m: float = 0.01
    dropout_fraction: float = 0.01
    distance_m: tuple[float, float] = (1.2, 3.0)
    max_turn_deg: float = 45.0
    max_tilt_deg: float = 35.0
    board: Board = field(default_factory=lambda: Board(8, 6, 0.06))
    margin_m: float = 0.06
    seed: int = 0
    fov_deg: float = 270.0
    angle_increment_deg: float = 0.25
    range_min_m: float = 0.1
    range_max_m: float = 30.0
    wall_clearance_m: float = 0.5
    room: Room = field(default_factory=Room)


@dataclass(frozen=True, eq=False)
class BoardCapture:
    """One simulated capture: the board's pose, its corners, the scan and the segment id."""

    name: str
    T_laser_board: FloatArray
    corners_px: FloatArray
    scan: Scan
    segment_id: int


@dataclass(frozen=True, eq=False)
class SimBoardSession:
    spec: BoardSpec
    camera: Camera
    T_cam_laser: FloatArray
    captures: tuple[BoardCapture, ...]


def generate_board_session(
    spec: BoardSpec, camera: Camera | None = None, T_cam_laser: ArrayLike | None = None
) -> SimBoardSession:
    """Simulate a board session (deterministic for the spec's seed).

    Raises:
        InputError: no visible board placement crossing the scan plane was found.
    """
    camera = camera or default_camera()
    T = default_T_cam_laser() if T_cam_laser is None else np.asarray(T_cam_laser, dtype=float)
    rng = np.random.default_rng(spec.seed)
    angle_min, step, angles = beam_angles(spec.fov_deg, spec.angle_increment_deg)
    params = LineParams.for_range_noise(spec.range_sigma_m)
    captures = []
    for i in range(spec.n_captures):
        captures.append(_capture(spec, camera, T, rng, angles, angle_min, step, params, f"cap{i:02d}"))
    return SimBoardSession(spec, camera, T, tuple(captures))


def _capture(
    spec: BoardSpec,
    camera: Camera,
    T: FloatArray,
    rng: np.random.Generator,
    angles: FloatArray,
    angle_min: float,
    step: float,
    params: LineParams,
    name: str,
) -> BoardCapture:
    b = spec.board
    P = board_points(b)
    w = (b.width_n - 1) * b.spacing_m
    h = (b.height_n - 1) * b.spacing_m
    outline = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * spec.margin_m + np.array(
        [[0, 0], [w, 0], [w, h], [0, h]]
    )
    for _ in range(_MAX_ATTEMPTS):
        dist = rng.uniform(*spec.distance_m)
        bearing = rng.uniform(-0.45, 0.45)
        radial = np.array([np.cos(bearing), np.sin(bearing), 0.0])
        centre = dist * radial + np.array([0.0, 0.0, rng.uniform(-0.08, 0.08)])
        # Board axes before turning: x along the rows (to the scanner's right as seen from
        # it), y down, z away from the scanner.
        x0 = np.array([np.sin(bearing), -np.cos(bearing), 0.0])
        R_base = np.column_stack([x0, [0.0, 0.0, -1.0], radial])
        turn = rotvec_to_R([0.0, 0.0, np.radians(rng.uniform(-1, 1) * spec.max_turn_deg)])
        tilt = rotvec_to_R(np.radians(rng.uniform(-1, 1) * spec.max_tilt_deg) * R_base[:, 0])
        roll = rotvec_to_R(np.radians(rng.uniform(-15, 15)) * radial)
        R = roll @ tilt @ turn @ R_base
        origin = centre - R @ np.array([0.5 * w, 0.5 * h, 0.0])
        T_laser_board = make_T(R, origin)
        cut = _scan_plane_cut(T_laser_board, outline)
        if cut is None or np.linalg.norm(cut[1] - cut[0]) < 0.25:
            continue
        px = camera.project(transform_points(T @ T_laser_board, P))
        if not camera.in_image(px, 15.0).all():
            continue
        room_pose = _room_pose(spec, rng, cut)  # type: ignore[arg-type]
        if room_pose is None:
            continue
        walls = spec.room.wall_segments(room_pose)
        ranges, hit = cast_scan_hits(np.concatenate([walls, cut[None]]), angles, spec.range_max_m)
        board_beams = np.flatnonzero(hit == len(walls))
        ranges = noisy_ranges(rng, ranges, spec.range_sigma_m, spec.dropout_fraction)
        scan = Scan.from_uniform(angle_min, step, ranges, spec.range_min_m, spec.range_max_m)
        order = np.argsort(np.arctan2(cut[:, 1], cut[:, 0]))
        found = find_face_segment(
            scan,
            cut[order],
            board_beams,
            line_params=params,
            tolerance_m=max(FACE_TOLERANCE_M, FACE_TOLERANCE_SIGMAS * spec.range_sigma_m),
        )
        if found is None:
            continue
        noisy = px + rng.normal(0.0, spec.corner_sigma_px, px.shape)
        return BoardCapture(name, T_laser_board, np.round(noisy, 2), scan, found[0])
    raise InputError(f"cannot simulate {name}: no board placement was visible and crossed the scan plane")


def _scan_plane_cut(T_laser_board: FloatArray, outline: FloatArray) -> FloatArray | None:
    """(2, 2) the segment where the board's outline polygon crosses the laser's z = 0
    plane, laser frame, or None."""
    corners = transform_points(T_laser_board, outline)  # (4, 3)
    pts = []
    for k in range(4):
        a, b = corners[k], corners[(k + 1) % 4]
        if (a[2] > 0) != (b[2] > 0):
            s = a[2] / (a[2] - b[2])
            pts.append((a + s * (b - a))[:2])
    if len(pts) != 2:
        return None
    return np.array(pts)


def board_session_text(session: SimBoardSession, camera_file: str = "camera.yaml") -> str:
    """Text of the session's board session file (docs/formats/board-session.md)."""
    spec = session.spec
    b = spec.board
    lines = [
        "# rigcal board session (docs/formats/board-session.md)",
        f"# Synthetic (rigcal.sim.board_session), seed {spec.seed}: "
        f"corner noise {spec.corner_sigma_px:g} px, range noise {spec.range_sigma_m:g} m.",
        "schema_version: 1",
        "method: board",
        f"name: simulated board session, seed {spec.seed}",
        f"camera: {camera_file}",
        f"board: {{corners_x: {b.width_n}, corners_y: {b.height_n}, spacing_m: {b.spacing_m:g}, "
        f"corner_sigma_px: {max(spec.corner_sigma_px, 0.01):g}}}",
        "laser:",
        "  name: simulated 2D scanner (Hokuyo UTM-30LX-like)",
        f"  angle_increment_deg: {spec.angle_increment_deg:g}",
        f"  range_sigma_m: {spec.range_sigma_m:g}",
        "captures:",
    ]
    for c in session.captures:
        corners = ", ".join(f"[{u:.2f}, {v:.2f}]" for u, v in c.corners_px)
        lines += [
            f"  - name: {c.name}",
            f"    scan: scans/{c.name}.yaml",
            f"    laser_side: {{segment: {c.segment_id}}}",
            f"    corners_px: [{corners}]",
        ]
    return "\n".join(lines) + "\n"


def write_board_session(session: SimBoardSession, folder: str | Path, force: bool = False) -> Path:
    """Write the session folder atomically (refuses an existing folder unless ``force``)."""
    from rigcal.calib.truth import truth_to_text

    with atomic_folder(folder, force) as tmp:
        (tmp / "scans").mkdir()
        camera_file = _write_camera(session.camera, tmp)
        for c in session.captures:
            write_scan(tmp / "scans" / f"{c.name}.yaml", c.scan)
        (tmp / "board_session.yaml").write_text(board_session_text(session, camera_file), encoding="utf-8")
        spec = session.spec
        generator = {
            "tool": "rigcal.sim.board_session",
            "seed": spec.seed,
            "captures": len(session.captures),
            "corner_sigma_px": spec.corner_sigma_px,
            "range_sigma_m": spec.range_sigma_m,
        }
        (tmp / "truth.yaml").write_text(
            truth_to_text(np.array(session.T_cam_laser), generator), encoding="utf-8"
        )
    return Path(folder)


def T_cam_board(session: SimBoardSession, capture: BoardCapture) -> FloatArray:
    """The true board pose in the camera frame."""
    out: FloatArray = session.T_cam_laser @ capture.T_laser_board
    return out
