"""Synthetic board sessions (checkerboard seen by camera and scanner) with a known T_cam_laser.

Per capture a flat checkerboard stands in front of the rig, turned and tilted at random,
crossing the scan plane. Its inner corners are projected through the true T_cam_laser and
the camera, with Gaussian pixel noise; the scan is ray-cast against the board's cut with
the scan plane and the room's walls, with range noise and dropouts; the board's segment
id is found as a user would pick it (``find_face_segment``). The session folder holds
``camera.yaml``, ``scans/``, ``board_session.yaml`` (corners listed, no images) and
``truth.yaml``. One seeded generator drives everything.

With ``BoardSpec(noise=RealisticNoise())`` (``--noise realistic``) the scanner and room
are those of :mod:`rigcal.sim.noise`: heavy-tailed range noise, mixed pixels, grazing
bias and dropouts; the rig stands still in one room with static clutter while the board
moves; the board's sheet is larger than its pattern (written as ``board.size_m``). The
board's cut may then come out of line extraction in pieces: the session lists every
segment that lies on it (``laser_side: {segments: [...]}``). The session file does not
state the true noise (a user does not know it); truth.yaml's generator block does.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.calib.board.detect import plane_cut
from rigcal.calib.board.session import board_points
from rigcal.calib.intrinsics import Board
from rigcal.camera import Camera
from rigcal.errors import InputError
from rigcal.geometry import make_T, rotvec_to_R, transform_points
from rigcal.io.files import atomic_folder
from rigcal.lines import LineParams
from rigcal.scan import Scan, write_scan
from rigcal.sim.box_session import (
    FACE_TOLERANCE_M,
    FACE_TOLERANCE_SIGMAS,
    default_camera,
    default_T_cam_laser,
    find_face_segment,
    random_room_pose,
    write_camera,
)
from rigcal.sim.noise import RealisticNoise, realistic_ranges, static_scene
from rigcal.sim.raycast import beam_angles, cast_scan_hits, noisy_ranges
from rigcal.sim.render import Room

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
        max_roll_deg: and rolled about the line from the laser to it by up to this (0
            with max_tilt_deg a few degrees: an upright board turned against a wall).
        board: the checkerboard (inner corners, square size); margin_m: its border
            beyond the inner corners (None: one square, the printed pattern's edge).
        seed: seed of the generator.
        noise: None for the clean model, or the realistic scanner, room and board
            (:class:`rigcal.sim.noise.RealisticNoise`; its ``board_border_m`` is added to
            ``margin_m``).
        repeats: captures taken at each board pose, each with fresh scan and corner noise
            (a session has n_captures x repeats captures); a solve should give captures
            at one pose one verdict.
        handheld: the repeats of a pose are of a hand-held board, not exactly at one
            pose: each after the first is turned by 1-3 deg about a random axis through
            the board's centre and moved by 2-5 cm in a random direction.
        holder: a person holds the board in the scan plane, as on a real hand-held set: at
            each end of its cut the scan goes on for 0.1-0.3 m along the board's line but
            50-100 mm off it (hands, arms, the body, touching the board's ends), moving with
            the board, so that auto's returns can take stretches off the board's line.
        spread: place the boards as a careful lab does, covering the ranges of distance,
            bearing, turn and tilt evenly (each capture in its own stratum of each, a
            Latin hypercube), instead of independently at random (False), which can
            leave a range uncovered and the solve uncertain.
    """

    n_captures: int = 12
    corner_sigma_px: float = 0.3
    range_sigma_m: float = 0.01
    dropout_fraction: float = 0.01
    distance_m: tuple[float, float] = (1.2, 3.0)
    max_turn_deg: float = 45.0
    max_tilt_deg: float = 35.0
    max_roll_deg: float = 15.0
    board: Board = field(default_factory=lambda: Board(8, 6, 0.06))
    margin_m: float | None = None
    seed: int = 0
    fov_deg: float = 270.0
    angle_increment_deg: float = 0.25
    range_min_m: float = 0.1
    range_max_m: float = 30.0
    wall_clearance_m: float = 0.5
    room: Room = field(default_factory=Room)
    noise: RealisticNoise | None = None
    repeats: int = 1
    handheld: bool = False
    spread: bool = False
    holder: bool = False

    @property
    def sheet_margin_m(self) -> float:
        """The board sheet's border beyond its inner corners, metres."""
        margin = self.board.spacing_m if self.margin_m is None else self.margin_m
        return margin + (self.noise.board_border_m if self.noise else 0.0)

    @property
    def size_m(self) -> tuple[float, float]:
        """The board sheet's (width, height), metres."""
        b = self.board
        m = 2.0 * self.sheet_margin_m
        return (b.width_n - 1) * b.spacing_m + m, (b.height_n - 1) * b.spacing_m + m


@dataclass(frozen=True, eq=False)
class BoardCapture:
    """One simulated capture: the board's pose, its corners, the scan, the ids of the
    segments on the board (one in the clean model) and the beams whose true ray hits it."""

    name: str
    T_laser_board: FloatArray
    corners_px: FloatArray
    scan: Scan
    segment_ids: tuple[int, ...]
    board_beams: NDArray[np.int64]

    @property
    def segment_id(self) -> int:
        """The first (in the clean model the only) segment on the board."""
        return self.segment_ids[0]


@dataclass(frozen=True, eq=False)
class SimBoardSession:
    """A simulated session; ``clutter`` (S, 2, 2) is the static scene in the laser frame
    (the room's walls and the clutter) when the rig stands still, else empty."""

    spec: BoardSpec
    camera: Camera
    T_cam_laser: FloatArray
    captures: tuple[BoardCapture, ...]
    static_scene: FloatArray = field(default_factory=lambda: np.zeros((0, 2, 2)))


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
    static = _static_scene(spec, rng) if spec.noise else None
    # The ids a reader of the written session gets: the clean session states its range
    # noise, the realistic one does not (defaults).
    params = LineParams() if spec.noise else LineParams.for_range_noise(spec.range_sigma_m)
    captures: list[BoardCapture] = []
    strata = _strata(rng, spec.n_captures) if spec.spread else None
    for i in range(spec.n_captures):
        names = [f"cap{spec.repeats * i + j:02d}" for j in range(spec.repeats)]
        stratum = None if strata is None else strata[i]
        captures += _capture(spec, camera, T, rng, params, names, static, stratum)
    scene = np.zeros((0, 2, 2)) if static is None else static[1]
    return SimBoardSession(spec, camera, T, tuple(captures), scene)


# Boards stand within this bearing of the laser's +x (radians).
_BOARD_BEARING = 0.45


def _static_scene(spec: BoardSpec, rng: np.random.Generator) -> tuple[tuple[float, float, float], FloatArray]:
    """The still rig's room pose and its static segments (walls, then clutter)."""
    assert spec.noise is not None
    try:
        return static_scene(
            rng,
            spec.room,
            spec.wall_clearance_m,
            (-_BOARD_BEARING, _BOARD_BEARING),
            spec.distance_m[1],
            spec.noise.n_clutter,
        )
    except ValueError as exc:
        raise InputError(f"cannot simulate: {exc}") from None


# A spread pose's draws stay in their strata for this many attempts, then go free (a
# stratum whose poses are all out of sight, e.g. near and far to the side).
_STRATUM_ATTEMPTS = 200


def _strata(rng: np.random.Generator, n: int) -> FloatArray:
    """(n, 4) a Latin hypercube over (distance, bearing, turn, tilt): capture i's stratum
    of each as [k, k+1) / n, each stratum used once per column."""
    return np.column_stack([rng.permutation(n) for _ in range(4)]).astype(np.float64)


def _capture(
    spec: BoardSpec,
    camera: Camera,
    T: FloatArray,
    rng: np.random.Generator,
    params: LineParams,
    names: list[str],
    static: tuple[tuple[float, float, float], FloatArray] | None,
    stratum: FloatArray | None = None,
) -> list[BoardCapture]:
    """One board pose and its captures (one per name), each with fresh noise; with a
    ``stratum`` (from :func:`_strata`) the pose's draws come from it."""
    b = spec.board
    P = board_points(b)
    w = (b.width_n - 1) * b.spacing_m
    h = (b.height_n - 1) * b.spacing_m
    outline = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * spec.sheet_margin_m + np.array(
        [[0, 0], [w, 0], [w, h], [0, h]]
    )
    for attempt in range(_MAX_ATTEMPTS):
        strata = stratum if attempt < _STRATUM_ATTEMPTS else None

        def draw(k: int, lo: float, hi: float, strata: FloatArray | None = strata) -> float:
            """Uniform in [lo, hi), within stratum k of the capture while it has one."""
            if strata is None:
                return float(rng.uniform(lo, hi))
            return lo + (hi - lo) * (strata[k] + float(rng.uniform())) / spec.n_captures

        dist = draw(0, *spec.distance_m)
        bearing = draw(1, -_BOARD_BEARING, _BOARD_BEARING)
        radial = np.array([np.cos(bearing), np.sin(bearing), 0.0])
        centre = dist * radial + np.array([0.0, 0.0, rng.uniform(-0.08, 0.08)])
        # Board axes before turning: x along the rows (to the scanner's right as seen from
        # it), y down, z away from the scanner.
        x0 = np.array([np.sin(bearing), -np.cos(bearing), 0.0])
        R_base = np.column_stack([x0, [0.0, 0.0, -1.0], radial])
        turn = rotvec_to_R([0.0, 0.0, np.radians(draw(2, -1, 1) * spec.max_turn_deg)])
        tilt = rotvec_to_R(np.radians(draw(3, -1, 1) * spec.max_tilt_deg) * R_base[:, 0])
        roll = rotvec_to_R(np.radians(rng.uniform(-spec.max_roll_deg, spec.max_roll_deg)) * radial)
        R = roll @ tilt @ turn @ R_base
        origin = centre - R @ np.array([0.5 * w, 0.5 * h, 0.0])
        T_laser_board = make_T(R, origin)
        cut = plane_cut(T_laser_board, outline)
        if cut is None or np.linalg.norm(cut[1] - cut[0]) < 0.25:
            continue
        px = camera.project(transform_points(T @ T_laser_board, P))
        if not camera.in_image(px, 15.0).all():
            continue
        if static is None:
            room_pose = random_room_pose(spec, rng, cut)  # type: ignore[arg-type]
            if room_pose is None:
                continue
            scene = spec.room.wall_segments(room_pose)
        elif spec.room.contains(static[0], cut, spec.wall_clearance_m):
            scene = static[1]
        else:
            continue
        out = []
        for j, name in enumerate(names):
            T_j, cut_j, px_j = T_laser_board, cut, px
            if spec.handheld and j > 0:
                moved = _handheld(rng, T_laser_board, centre, outline, T, camera, P)
                if moved is None:
                    break
                T_j, cut_j, px_j = moved
            segments = np.concatenate([scene, cut_j[None]])
            if spec.holder:
                segments = np.concatenate([segments, _holder(rng, cut_j)])
            capture = _noisy_capture(spec, rng, segments, len(scene), cut_j, px_j, T_j, params, name)
            if capture is None:
                break
            out.append(capture)
        if len(out) == len(names):
            return out
    raise InputError(f"cannot simulate {names[0]}: no board placement was visible and crossed the scan plane")


def _holder(rng: np.random.Generator, cut: FloatArray) -> FloatArray:
    """(2, 2, 2) the person holding a board (:class:`BoardSpec` ``holder``): at each end of
    the cut a stretch 0.1-0.3 m long continuing the board's line, 50-100 mm off it (towards
    or away from the scanner), its near end touching the board's end."""
    u = (cut[1] - cut[0]) / np.linalg.norm(cut[1] - cut[0])
    n = np.array([-u[1], u[0]])
    out = []
    for end, out_dir in ((cut[0], -u), (cut[1], u)):
        off = rng.uniform(0.05, 0.1) * rng.choice([-1.0, 1.0]) * n
        length = rng.uniform(0.1, 0.3)
        out.append([end + off + 0.01 * out_dir, end + off + length * out_dir])
    return np.array(out)


def _handheld(
    rng: np.random.Generator,
    T_laser_board: FloatArray,
    centre: FloatArray,
    outline: FloatArray,
    T_cam_laser: FloatArray,
    camera: Camera,
    P: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray] | None:
    """A hand-held repeat of a board pose: turned by 1-3 deg about a random axis through
    the board's centre and moved by 2-5 cm; (pose, cut, corners' pixels), or None when the
    board then misses the scan plane or leaves the image."""
    axis = rng.normal(size=3)
    turn = rotvec_to_R(np.radians(rng.uniform(1.0, 3.0)) * axis / np.linalg.norm(axis))
    shift = rng.normal(size=3)
    shift *= rng.uniform(0.02, 0.05) / np.linalg.norm(shift)
    R = turn @ T_laser_board[:3, :3]
    t = turn @ (T_laser_board[:3, 3] - centre) + centre + shift
    T_j = make_T(R, t)
    cut = plane_cut(T_j, outline)
    if cut is None or np.linalg.norm(cut[1] - cut[0]) < 0.25:
        return None
    px = camera.project(transform_points(T_cam_laser @ T_j, P))
    if not camera.in_image(px, 15.0).all():
        return None
    return T_j, cut, px


def _noisy_capture(
    spec: BoardSpec,
    rng: np.random.Generator,
    segments: FloatArray,
    n_scene: int,
    cut: FloatArray,
    px: FloatArray,
    T_laser_board: FloatArray,
    params: LineParams,
    name: str,
) -> BoardCapture | None:
    """A capture of a placed board: its scan and corners with noise, or None when the
    board's returns do not make a segment a user could pick."""
    angle_min, step, angles = beam_angles(spec.fov_deg, spec.angle_increment_deg)
    if spec.noise is None:
        ranges, hit = cast_scan_hits(segments, angles, spec.range_max_m)
        ranges = noisy_ranges(rng, ranges, spec.range_sigma_m, spec.dropout_fraction)
    else:
        ranges, hit = realistic_ranges(rng, segments, angles, spec.range_max_m, spec.noise)
    board_beams = np.flatnonzero(hit == n_scene)
    scan = Scan.from_uniform(angle_min, step, ranges, spec.range_min_m, spec.range_max_m)
    order = np.argsort(np.arctan2(cut[:, 1], cut[:, 0]))
    if spec.noise is None:
        found = find_face_segment(
            scan,
            cut[order],
            board_beams,
            line_params=params,
            tolerance_m=max(FACE_TOLERANCE_M, FACE_TOLERANCE_SIGMAS * spec.range_sigma_m),
        )
        ids: tuple[int, ...] | None = None if found is None else (found[0],)
    else:
        ids = _segments_on(scan, cut, board_beams, params, spec.noise.range_sigma_m)
    if ids is None:
        return None
    noisy = px + rng.normal(0.0, spec.corner_sigma_px, px.shape)
    return BoardCapture(name, T_laser_board, np.round(noisy, 2), scan, ids, board_beams)


# A segment is on the board when this share of its returns is (the rest: mixed pixels).
_ON_BOARD_SHARE = 0.8
# The segments on the board must hold this share of the board's returns.
_BOARD_COVERED = 0.6


def _segments_on(
    scan: Scan, cut: FloatArray, board_beams: NDArray[np.int64], params: LineParams, sigma_m: float
) -> tuple[int, ...] | None:
    """The ids of the segments a user would list for the board (most of their returns
    within 3 sigma of the true cut), if they hold most of the board's returns; else None."""
    from rigcal.lines import extract_lines
    from rigcal.sim.box_session import distance_to_segment

    board = board_beams[scan.valid[board_beams]]
    if len(board) < params.min_points:
        return None
    ids, covered = [], 0
    for seg in extract_lines(scan, params):
        on = distance_to_segment(np.asarray(seg.points), cut) < max(FACE_TOLERANCE_M, 3.0 * sigma_m)
        if on.mean() >= _ON_BOARD_SHARE:
            ids.append(seg.id)
            covered += int(np.isin(seg.indices, board).sum())
    return tuple(ids) if ids and covered >= _BOARD_COVERED * len(board) else None


def session_head_lines(
    method: str,
    seed: int,
    noise_text: str,
    schema_version: int,
    camera_file: str,
    extra: list[str],
    angle_increment_deg: float,
    range_sigma_m: float | None,
) -> list[str]:
    """The lines a simulated plane-method session file (board, marker) starts with, up to
    and including ``captures:``: the comment naming its format and simulator, the version,
    method, name, camera, the ``extra`` top-level lines and the simulated scanner (its range
    noise when the clean model's)."""
    lines = [
        f"# rigcal {method} session (docs/formats/{method}-session.md)",
        f"# Synthetic (rigcal.sim.{method}_session), seed {seed}: {noise_text}",
        f"schema_version: {schema_version}",
        f"method: {method}",
        f"name: simulated {method} session, seed {seed}",
        f"camera: {camera_file}",
        *extra,
        "laser:",
        "  name: simulated 2D scanner (Hokuyo UTM-30LX-like)",
        f"  angle_increment_deg: {angle_increment_deg:g}",
    ]
    if range_sigma_m is not None:
        lines.append(f"  range_sigma_m: {range_sigma_m:g}")
    return [*lines, "captures:"]


def board_session_text(session: SimBoardSession, camera_file: str = "camera.yaml") -> str:
    """Text of the session's board session file (docs/formats/board-session.md)."""
    spec = session.spec
    b = spec.board
    noise = spec.noise
    size = f", size_m: [{spec.size_m[0]:g}, {spec.size_m[1]:g}]" if noise else ""
    lines = session_head_lines(
        "board",
        spec.seed,
        f"corner noise {spec.corner_sigma_px:g} px, range noise {spec.range_sigma_m:g} m."
        if noise is None
        else "realistic scanner and cluttered room (the true noise is in truth.yaml).",
        2 if noise else 1,
        camera_file,
        [
            f"board: {{corners_x: {b.width_n}, corners_y: {b.height_n}, spacing_m: {b.spacing_m:g}, "
            f"corner_sigma_px: {max(spec.corner_sigma_px, 0.01):g}{size}}}"
        ],
        spec.angle_increment_deg,
        spec.range_sigma_m if noise is None else None,
    )
    for c in session.captures:
        corners = ", ".join(f"[{u:.2f}, {v:.2f}]" for u, v in c.corners_px)
        lines += [
            f"  - name: {c.name}",
            f"    scan: scans/{c.name}.yaml",
            f"    laser_side: {{segment: {c.segment_id}}}"
            if len(c.segment_ids) == 1
            else f"    laser_side: {{segments: {list(c.segment_ids)}}}",
            f"    corners_px: [{corners}]",
        ]
    return "\n".join(lines) + "\n"


def write_board_session(session: SimBoardSession, folder: str | Path, force: bool = False) -> Path:
    """Write the session folder atomically (refuses an existing folder unless ``force``)."""
    from rigcal.calib.truth import truth_to_text

    with atomic_folder(folder, force) as tmp:
        (tmp / "scans").mkdir()
        camera_file = write_camera(session.camera, tmp)
        for c in session.captures:
            write_scan(tmp / "scans" / f"{c.name}.yaml", c.scan)
        (tmp / "board_session.yaml").write_text(board_session_text(session, camera_file), encoding="utf-8")
        spec = session.spec
        generator = {
            "tool": "rigcal.sim.board_session",
            "seed": spec.seed,
            "captures": len(session.captures),
            "corner_sigma_px": spec.corner_sigma_px,
            "range_sigma_m": spec.noise.range_sigma_m if spec.noise else spec.range_sigma_m,
            "poses": "spread" if spec.spread else "random",
        }
        if spec.repeats > 1:
            generator["repeats"] = {"per_pose": spec.repeats, "handheld": spec.handheld}
        if spec.noise:
            generator["noise"] = {"model": "realistic", **spec.noise.as_dict()}
            generator["board_size_m"] = [float(x) for x in spec.size_m]
        (tmp / "truth.yaml").write_text(
            truth_to_text(np.array(session.T_cam_laser), generator), encoding="utf-8"
        )
    return Path(folder)


def T_cam_board(session: SimBoardSession, capture: BoardCapture) -> FloatArray:
    """The true board pose in the camera frame."""
    out: FloatArray = session.T_cam_laser @ capture.T_laser_board
    return out
