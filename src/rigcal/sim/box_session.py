"""Synthetic box-target calibration sessions with a known T_cam_laser.

A session is what a user would record for the paper's Algorithm 1 (Section II): per capture
a laser scan and a camera image of the box target, the id of the scan's line segment on the
box's face, and the two box ends picked in the image. Here everything is simulated:

1. the box is placed at a random distance, bearing and yaw in a rectangular room (the whole
   box inside the image, its face seen within about +/-50 deg of incidence);
2. the scan is ray-cast against the walls and the box's footprint, with Gaussian range
   noise and random dropouts (:mod:`rigcal.sim.raycast`);
3. the scan's lines are extracted (:func:`rigcal.lines.extract_lines`) and the
   segment lying on the true face is found (if none does, the placement is redrawn);
4. the true box ends are projected through T_cam_laser and the camera; the picks are those
   pixels plus Gaussian noise, and a chosen fraction of captures get gross pick errors;
5. :func:`write_session` renders the images (:mod:`rigcal.sim.render`) and writes the
   session folder (docs/formats/session.md) with its truth file.

One ``numpy.random.default_rng(seed)`` drives everything, so a seed gives the same session,
byte for byte.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from rigcal.arrays import FloatArray
from rigcal.calib.box.picks import BoxObservation, extended_ends, side_observation
from rigcal.camera import Camera
from rigcal.errors import InputError, OutputError
from rigcal.geometry import inv_T, make_T, transform_points
from rigcal.io.files import atomic_folder
from rigcal.lines import LineParams, Segment, extract_lines
from rigcal.scan import Scan
from rigcal.sim.noise import RealisticNoise, realistic_ranges, static_scene
from rigcal.sim.raycast import beam_angles, cast_scan_hits, noisy_ranges
from rigcal.sim.render import Room, Scene
from rigcal.targets.box import FRONT_FACE_SEGMENT, BoxTarget

# A laser return belongs to the box face when it lies within this distance of it (or
# within FACE_TOLERANCE_SIGMAS range sigmas, for noisier scanners).
FACE_TOLERANCE_M = 0.02
FACE_TOLERANCE_SIGMAS = 2.0
# Share of a segment's returns that must lie on the face for it to be the face's segment.
FACE_SHARE = 0.8
# The chosen segment's box ends (as picks.py computes them) must lie this close to the
# true ends, or the line extraction has cut or merged the face and the placement is redrawn.
END_TOLERANCE_M = 0.1
# Ranges are kept to 0.1 mm, finer than any scanner reports, so that they are written
# and read back exactly.
RANGE_DECIMALS = 4
# Picked pixels are kept to 0.1 px, as the picking file writes them.
PICK_DECIMALS = 1
# Gross pick errors move an end by this much (px).
WRONG_PICK_SHIFT_PX = (15.0, 60.0)
SCANNER_NAME = "simulated 2D scanner (Hokuyo UTM-30LX-like)"

_MAX_ATTEMPTS = 400


@dataclass(frozen=True)
class SessionSpec:
    """What to simulate.

    Attributes:
        n_captures: number of captures (scan + image) in the session.
        pick_sigma_px: 1-sigma Gaussian noise of each picked pixel coordinate.
        range_sigma_m: 1-sigma Gaussian noise of each laser range.
        wrong_pick_fraction: fraction of captures (rounded to a whole number) whose image
            picks are grossly wrong: one or both ends moved by 15-60 px, or the two swapped.
        dropout_fraction: fraction of laser returns lost at random (written as range 0).
        distance_m: (min, max) distance from the laser to the centre of the box's face.
            Distances are stratified over the captures, so that even a few captures span
            the range.
        seed: seed of the one random generator.
        fov_deg, angle_increment_deg, range_min_m, range_max_m: the scanner
            (default: Hokuyo UTM-30LX-like, 1081 beams over 270 deg, symmetric about +x).
        max_incidence_deg: the face is seen at an incidence (angle between its normal and
            the direction to the laser) uniform within +/- this.
        image_margin_px: every corner of the box projects at least this far inside the image.
        wall_clearance_m: the box stays at least this far from the room's walls.
        room: the room around the rig (a fresh room pose is drawn per capture, as if the
            rig had moved; with ``noise`` one room pose for the whole session).
        box: the box target.
        noise: None for the clean model (Gaussian range noise, ``range_sigma_m``), or the
            realistic scanner and room of :class:`rigcal.sim.noise.RealisticNoise`: its
            range noise and dropouts replace ``range_sigma_m`` and ``dropout_fraction``,
            the rig stands still in one room with static clutter (in the scans; the
            rendered images show the room and the box), and the picking file does not
            state the range noise.
    """

    n_captures: int = 20
    pick_sigma_px: float = 1.0
    range_sigma_m: float = 0.01
    wrong_pick_fraction: float = 0.0
    dropout_fraction: float = 0.01
    distance_m: tuple[float, float] = (1.2, 4.0)
    seed: int = 0
    fov_deg: float = 270.0
    angle_increment_deg: float = 0.25
    range_min_m: float = 0.1
    range_max_m: float = 30.0
    max_incidence_deg: float = 50.0
    image_margin_px: float = 20.0
    wall_clearance_m: float = 0.5
    room: Room = field(default_factory=Room)
    box: BoxTarget = field(default_factory=BoxTarget)
    noise: RealisticNoise | None = None

    def __post_init__(self) -> None:
        checks = [
            (self.n_captures >= 1, "n_captures must be >= 1"),
            (self.pick_sigma_px >= 0, "pick_sigma_px must be >= 0"),
            (self.range_sigma_m >= 0, "range_sigma_m must be >= 0"),
            (0 <= self.wrong_pick_fraction <= 1, "wrong_pick_fraction must be in [0, 1]"),
            (0 <= self.dropout_fraction < 1, "dropout_fraction must be in [0, 1)"),
            (0 < self.distance_m[0] <= self.distance_m[1], "distance_m must be (min, max), 0 < min <= max"),
            (0 < self.fov_deg <= 360 and self.angle_increment_deg > 0, "bad scanner fov or increment"),
            (0 <= self.range_min_m < self.range_max_m, "range_min_m must be below range_max_m"),
            (0 <= self.max_incidence_deg < 90, "max_incidence_deg must be in [0, 90)"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"SessionSpec: {message}")

    @property
    def true_range_sigma_m(self) -> float:
        """The range noise the scans were made with (1 sigma, metres)."""
        return self.noise.range_sigma_m if self.noise else self.range_sigma_m

    @property
    def line_params(self) -> LineParams:
        """The line extraction a reader of the written picking file uses: scaled to the
        stated range noise; the realistic session states none (defaults)."""
        return LineParams() if self.noise else LineParams.for_range_noise(self.range_sigma_m)

    @property
    def n_beams(self) -> int:
        """Number of beams per scan (the field of view's both ends included)."""
        return len(beam_angles(self.fov_deg, self.angle_increment_deg)[2])

    @property
    def angle_min_rad(self) -> float:
        """Angle of the first beam: the field of view is symmetric about the laser's +x."""
        return beam_angles(self.fov_deg, self.angle_increment_deg)[0]

    @property
    def n_wrong_picks(self) -> int:
        """Number of captures given wrong picks."""
        return round(self.wrong_pick_fraction * self.n_captures)


def default_camera() -> Camera:
    """The simulated camera: 640x480, LENSMODEL_OPENCV5, fx = fy = 520, mild barrel distortion.

    About 63 x 50 deg field of view; the same camera as docs/formats/camera.md's example.
    """
    K = np.array([[520.0, 0.0, 319.5], [0.0, 520.0, 239.5], [0.0, 0.0, 1.0]])
    return Camera.from_opencv(K, [-0.15, 0.05, 0.0005, -0.0003, 0.0], 640, 480, source="simulated")


def default_T_cam_laser() -> FloatArray:
    """The simulated rig's true T_cam_laser (4, 4).

    The camera sits 0.12 m above the laser, 5 cm forward and 2 cm to its right, looking
    along the laser's +x (camera z = laser x, camera x = -laser y, camera y = -laser z),
    then turned 2 deg left (yaw), pitched 5 deg down and rolled 1.5 deg, so that no axis
    of the solve is trivially aligned.
    """
    # Columns of R_laser_cam: the camera's axes in the laser frame before the turn.
    R_base = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    # Yaw about laser z, pitch about laser y (positive tilts +x down), roll about the
    # optical axis.
    turn = Rotation.from_euler("ZYX", [2.0, 5.0, 1.5], degrees=True).as_matrix()
    R_laser_cam = turn @ R_base
    T_laser_cam = make_T(R_laser_cam, [0.05, -0.02, 0.12])
    return inv_T(T_laser_cam)


def moved_T_cam_laser(
    T_cam_laser: ArrayLike, rotation_deg: float, translation_mm: float, seed: int = 0
) -> FloatArray:
    """T_cam_laser after the camera has moved on the rig: turned by ``rotation_deg`` about a
    random axis and shifted by ``translation_mm`` in a random direction (both in the camera
    frame, seeded), for drift-check tests and benchmarks."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    shift = rng.normal(size=3)
    shift /= np.linalg.norm(shift)
    T = np.asarray(T_cam_laser, dtype=float)
    dR = Rotation.from_rotvec(np.radians(rotation_deg) * axis).as_matrix()
    return make_T(dR @ T[:3, :3], T[:3, 3] + 0.001 * translation_mm * shift)


@dataclass(frozen=True, eq=False)
class SimCapture:
    """One simulated capture and its ground truth.

    Attributes:
        name: capture name, also the stem of its scan and image files (``cap00``...).
        scan: the simulated scan.
        box_pose: (3,) the box's (x_m, y_m, yaw_rad) in the laser frame (rigcal.targets.box).
        room_pose: (3,) the room's (x_m, y_m, yaw_rad) in the laser frame (rigcal.sim.render).
        true_laser_ends: (2, 2) metres, laser frame z = 0: the true box ends, end 0 at the
            smaller beam angle (picks.py's order).
        true_pixels: (2, 2) pixels: the true ends projected through the true T_cam_laser.
        picked_pixels: (2, 2) pixels: what the simulated user picked (0.1 px resolution),
            same order.
        segment_id: id of the box face's segment among ``extract_lines(scan)`` (default
            line parameters).
        is_wrong_pick: whether the picks were made grossly wrong on purpose.
        wrong_pick_kind: ``""``, ``"moved end 0"``, ``"moved end 1"``, ``"moved both"`` or
            ``"swapped"``.
    """

    name: str
    scan: Scan
    box_pose: FloatArray
    room_pose: FloatArray
    true_laser_ends: FloatArray
    true_pixels: FloatArray
    picked_pixels: FloatArray
    segment_id: int
    is_wrong_pick: bool
    wrong_pick_kind: str = ""

    def __post_init__(self) -> None:
        for name in ("box_pose", "room_pose", "true_laser_ends", "true_pixels", "picked_pixels"):
            a = np.array(getattr(self, name), dtype=float)
            a.setflags(write=False)
            object.__setattr__(self, name, a)


@dataclass(frozen=True, eq=False)
class BoxSession:
    """A simulated session: its spec, camera, true calibration and captures."""

    spec: SessionSpec
    camera: Camera
    T_cam_laser: FloatArray
    captures: tuple[SimCapture, ...]

    def __post_init__(self) -> None:
        T = np.array(self.T_cam_laser, dtype=float)
        T.setflags(write=False)
        object.__setattr__(self, "T_cam_laser", T)

    def scene(self, capture: SimCapture) -> Scene:
        """The scene of a capture, for :func:`rigcal.sim.render.render_image`."""
        return Scene(
            room=self.spec.room,
            room_pose=_pose3(capture.room_pose),
            box=self.spec.box,
            box_pose=_pose3(capture.box_pose),
        )


# --- generation ---------------------------------------------------------------------------
def generate_session(
    spec: SessionSpec, camera: Camera | None = None, T_cam_laser: ArrayLike | None = None
) -> BoxSession:
    """Simulate a box-target session.

    Args:
        spec: what to simulate (seeded).
        camera: the camera; :func:`default_camera` when None.
        T_cam_laser: (4, 4) the true calibration; :func:`default_T_cam_laser` when None.

    Returns:
        The session, deterministic for ``spec`` (including its seed), camera and pose.

    Raises:
        InputError: the box cannot be placed visibly (e.g. a camera that does not look
            along the laser's +x, distances the image cannot hold, or range noise so large
            that the box's face is no clean segment in the scans).
    """
    camera = camera or default_camera()
    T = default_T_cam_laser() if T_cam_laser is None else np.asarray(T_cam_laser, dtype=float)
    rng = np.random.default_rng(spec.seed)
    angles = beam_angles(spec.fov_deg, spec.angle_increment_deg)[2]
    n = spec.n_captures
    # Stratified distances and incidences (each capture in its own slice of the range, in
    # random order) spread the geometry even over a few captures.
    dist_u = (rng.permutation(n) + rng.uniform(size=n)) / n
    inc_u = (rng.permutation(n) + rng.uniform(size=n)) / n
    bear_u = (rng.permutation(n) + rng.uniform(size=n)) / n
    wrong = set(rng.choice(n, size=spec.n_wrong_picks, replace=False).tolist())
    bearing_lo, bearing_hi = _bearing_limits(camera, T)
    static = None
    if spec.noise is not None:
        far = spec.distance_m[1] + float(np.hypot(spec.box.width_m, spec.box.depth_m))
        try:
            static = static_scene(
                rng, spec.room, spec.wall_clearance_m, (bearing_lo, bearing_hi), far, spec.noise.n_clutter
            )
        except ValueError as exc:
            raise InputError(f"cannot simulate: {exc}") from None
    width = max(2, len(str(n - 1)))
    captures = []
    for i in range(n):
        d_lo, d_hi = spec.distance_m
        distance = d_lo + dist_u[i] * (d_hi - d_lo)
        incidence = np.radians(spec.max_incidence_deg) * (2.0 * inc_u[i] - 1.0)
        captures.append(
            _capture(
                spec,
                camera,
                T,
                rng,
                angles,
                f"cap{i:0{width}d}",
                distance,
                incidence,
                bear_u[i],
                (bearing_lo, bearing_hi),
                i in wrong,
                stamp_s=float(i),
                static=static,
            )
        )
    return BoxSession(spec, camera, T, tuple(captures))


def _capture(
    spec: SessionSpec,
    camera: Camera,
    T: FloatArray,
    rng: np.random.Generator,
    angles: FloatArray,
    name: str,
    distance: float,
    incidence: float,
    bearing_u: float,
    bearing_limits: tuple[float, float],
    wrong: bool,
    stamp_s: float,
    static: tuple[tuple[float, float, float], FloatArray] | None = None,
) -> SimCapture:
    """Draw placements until one gives a visible box whose face is a clean scan segment."""
    box = spec.box
    lo, hi = bearing_limits
    u = bearing_u
    for attempt in range(_MAX_ATTEMPTS):
        if attempt >= _MAX_ATTEMPTS // 2:  # give up the stratum: anything in range
            distance = rng.uniform(*spec.distance_m)
            incidence = np.radians(spec.max_incidence_deg) * rng.uniform(-1.0, 1.0)
            u = rng.uniform()
        bearing = lo + u * (hi - lo)
        face_centre = distance * np.array([np.cos(bearing), np.sin(bearing)])
        pose = box.placement_for_face(face_centre, bearing + incidence)
        if not _box_in_image(spec, camera, T, pose):
            # Too wide a bearing for this distance: pull the box towards the image centre.
            u = 0.5 + 0.93 * (u - 0.5)
            continue
        if static is None:
            room_pose = random_room_pose(spec, rng, box.footprint(*pose))
            if room_pose is None:
                continue
            walls = spec.room.wall_segments(room_pose)
        elif spec.room.contains(static[0], box.footprint(*pose), spec.wall_clearance_m):
            room_pose, walls = static
        else:
            continue
        segments = np.concatenate([walls, box.footprint_segments(*pose)])
        if spec.noise is None:
            ranges, hit = cast_scan_hits(segments, angles, spec.range_max_m)
            ranges = noisy_ranges(rng, ranges, spec.range_sigma_m, spec.dropout_fraction, RANGE_DECIMALS)
        else:
            ranges, hit = realistic_ranges(
                rng, segments, angles, spec.range_max_m, spec.noise, RANGE_DECIMALS
            )
        face_beams = np.flatnonzero(hit == len(walls) + FRONT_FACE_SEGMENT)
        scan = Scan.from_uniform(
            spec.angle_min_rad,
            float(np.radians(spec.angle_increment_deg)),
            ranges,
            spec.range_min_m,
            spec.range_max_m,
            stamp_s=stamp_s,
        )
        ends = _order_ends(box.front_ends(*pose))
        found = find_face_segment(
            scan,
            ends,
            face_beams,
            line_params=spec.line_params,
            tolerance_m=max(FACE_TOLERANCE_M, FACE_TOLERANCE_SIGMAS * spec.true_range_sigma_m),
        )
        if found is None:
            # At steep incidence the box's side shows next to its face and the two may not
            # separate cleanly in the scan: turn the box a little towards the scanner.
            incidence *= 0.9
            continue
        seg_id, _ = found
        true_px = camera.project(transform_points(T, ends))
        picked, kind = _picks(spec, camera, rng, true_px, wrong)
        return SimCapture(
            name=name,
            scan=scan,
            box_pose=np.array(pose),
            room_pose=np.array(room_pose),
            true_laser_ends=ends,
            true_pixels=true_px,
            picked_pixels=picked,
            segment_id=seg_id,
            is_wrong_pick=wrong,
            wrong_pick_kind=kind,
        )
    raise InputError(
        f"cannot simulate {name}: no box placement in {_MAX_ATTEMPTS} attempts was both inside the "
        "image and a clean line segment in the scan; check the camera, T_cam_laser, distance_m "
        "and range_sigma_m"
    )


def find_face_segment(
    scan: Scan,
    true_ends: FloatArray,
    face_beams: ArrayLike | None = None,
    line_params: LineParams | None = None,
    tolerance_m: float = FACE_TOLERANCE_M,
) -> tuple[int, Segment] | None:
    """The scan segment on the box face, as a user would pick it, or None.

    The segment with the most returns within ``tolerance_m`` of the true face, of which
    they must be most (80%). When ``face_beams`` is given, the segment must also span the
    face: its first and last returns at most one valid return away from the face's, and
    within ``tolerance_m`` of the face (a return from the box's side only at the corner).
    Finally, the box ends picks.py derives from it must lie within 10 cm of the true ends.
    A face cut in two, or merged with something else, does not qualify.

    Args:
        scan: the scan.
        true_ends: (2, 2) the face's true ends, laser frame, metres.
        face_beams: (K,) indices of the beams whose noise-free ray hits the face.
        line_params: line extraction parameters (default: picks.py's default).
        tolerance_m: how far from the face a return may lie and still count as on it.

    Returns:
        (segment id, segment), or None.
    """
    best: tuple[int, Segment] | None = None
    best_count = 0
    for seg in extract_lines(scan, line_params):
        pts = np.asarray(seg.points, dtype=float)
        on = distance_to_segment(pts, true_ends) < tolerance_m
        if len(pts) >= 3 and on.mean() >= FACE_SHARE and on.sum() > best_count:
            best, best_count = (seg.id, seg), int(on.sum())
    if best is None:
        return None
    seg = best[1]
    indices = np.asarray(seg.indices)
    if face_beams is not None:
        valid = scan.valid
        face = np.asarray(face_beams, dtype=np.int64)
        face = face[valid[face]]
        if len(face) < 2:
            return None
        rank = np.cumsum(valid) - 1  # position of each beam among the valid returns
        if abs(rank[indices[0]] - rank[face[0]]) > 1 or abs(rank[indices[-1]] - rank[face[-1]]) > 1:
            return None
        # A return from the box's side may end the segment only if it is at the corner.
        first_last = np.asarray(seg.points, dtype=float)[[0, -1]]
        if (distance_to_segment(first_last, true_ends) > tolerance_m).any():
            return None
    ends, _ = extended_ends(np.asarray(seg.points, dtype=float), indices, scan)
    if np.linalg.norm(ends - true_ends, axis=1).max() > END_TOLERANCE_M:
        return None
    return best


def _order_ends(ends: FloatArray) -> FloatArray:
    """End 0 is the end at the smaller beam angle (picks.py, docs/conventions.md)."""
    a = np.arctan2(ends[:, 1], ends[:, 0])
    out: FloatArray = ends[np.argsort(a)]
    return out


def distance_to_segment(points: FloatArray, ends: FloatArray) -> FloatArray:
    """(N,) distances from points (N, 2) to the finite segment between ends (2, 2)."""
    d = ends[1] - ends[0]
    s = np.clip((points - ends[0]) @ d / (d @ d), 0.0, 1.0)
    out: FloatArray = np.linalg.norm(points - (ends[0] + s[:, None] * d), axis=1)
    return out


def _bearing_limits(camera: Camera, T_cam_laser: FloatArray) -> tuple[float, float]:
    """Laser-frame azimuths (rad) of the image's left and right edges, at mid-height."""
    T_laser_cam = inv_T(T_cam_laser)
    cy = 0.5 * (camera.height_px - 1)
    b = camera.bearings([[0.0, cy], [camera.width_px - 1.0, cy]]) @ T_laser_cam[:3, :3].T
    az = np.arctan2(b[:, 1], b[:, 0])
    if not np.all(b[:, 0] > 0):
        raise InputError("cannot simulate: the camera does not look along the laser's +x")
    return float(az.min()), float(az.max())


def _box_in_image(spec: SessionSpec, camera: Camera, T: FloatArray, pose: tuple[float, float, float]) -> bool:
    """Every corner of the box projects inside the image with margin, and the camera sees
    the front face from the front."""
    faces = spec.box.faces(*pose)
    corners = np.concatenate([faces[0], faces[1]])  # front and back: all eight corners
    q = camera.project(transform_points(T, corners))
    if not camera.in_image(q, spec.image_margin_px).all():
        return False
    cam_centre = inv_T(T)[:3, 3]
    front = faces[0]
    normal = np.cross(front[1] - front[0], front[3] - front[0])
    normal_out = -np.array([np.cos(pose[2]), np.sin(pose[2]), 0.0])
    normal = normal if normal @ normal_out > 0 else -normal
    return bool(normal @ (cam_centre - front.mean(axis=0)) > 0)


def random_room_pose(
    spec: SessionSpec, rng: np.random.Generator, footprint: FloatArray
) -> tuple[float, float, float] | None:
    """A room pose (laser frame) that holds the laser and the box with clearance, or None
    (:meth:`Room.pose_holding`: a random place and heading of the rig in the room)."""
    return spec.room.pose_holding(rng, footprint, spec.wall_clearance_m)


def _picks(
    spec: SessionSpec, camera: Camera, rng: np.random.Generator, true_px: FloatArray, wrong: bool
) -> tuple[FloatArray, str]:
    """Picked pixels: the truth plus Gaussian noise, or a gross error; at 0.1 px."""
    # Picks stay strictly inside the image (the picking file's readers refuse others).
    hi = np.array([camera.width_px - 1.0, camera.height_px - 1.0])
    picked = np.clip(true_px + rng.normal(0.0, spec.pick_sigma_px, size=(2, 2)), 0.0, hi)
    if not wrong:
        return np.round(picked, PICK_DECIMALS), ""
    k = int(rng.integers(3))
    if k == 2:
        return np.round(picked[::-1], PICK_DECIMALS), "swapped"
    which = [int(rng.integers(2))] if k == 0 else [0, 1]
    for _ in range(50):
        moved = picked.copy()
        for j in which:
            moved[j] = _shifted_inside(camera, rng, picked[j])
        # Two ends picked on one spot would be refused as a picking error, not a wrong pick.
        if np.linalg.norm(moved[0] - moved[1]) > 5.0:
            break
    kind = f"moved end {which[0]}" if k == 0 else "moved both"
    return np.round(moved, PICK_DECIMALS), kind


def _shifted_inside(camera: Camera, rng: np.random.Generator, px: FloatArray) -> FloatArray:
    """px moved by 15-60 px in a random direction, staying inside the image."""
    for _ in range(50):
        r = rng.uniform(*WRONG_PICK_SHIFT_PX)
        a = rng.uniform(0.0, 2.0 * np.pi)
        q = px + r * np.array([np.cos(a), np.sin(a)])
        if camera.in_image(q[None], 1.0)[0]:
            out: FloatArray = q
            return out
    raise ValueError("cannot move a pick inside the image")  # pragma: no cover - image < 120 px


# --- observations ------------------------------------------------------------------------
def session_observations(
    session: BoxSession, line_params: LineParams | None = None, folder: str | Path | None = None
) -> list[BoxObservation]:
    """The solver's input, exactly as :func:`rigcal.calib.box.picks.read_picks` would build it
    from the written session, without writing files (for fast Monte-Carlo benchmarks).

    Args:
        session: the simulated session.
        line_params: line extraction parameters (default: those the picking file implies,
            scaled to the session's range noise, as read_picks uses them).
        folder: where the session is (or would be) written; only used for the
            observations' ``scan_path`` and ``image_path`` (relative paths when None).

    Raises:
        InputError: a capture's segment id does not exist under ``line_params``.
    """
    base = Path(folder).resolve() if folder is not None else None
    out = []
    for i, c in enumerate(session.captures):
        segments = extract_lines(c.scan, line_params or session.spec.line_params)
        if not 0 <= c.segment_id < len(segments):
            raise InputError.at(
                None, f"captures[{i}].laser_side.segment", c.segment_id, f"a segment id below {len(segments)}"
            )
        seg = segments[c.segment_id]
        scan_rel, image_rel = _capture_files(c.name)
        scan_path = base / scan_rel if base else Path(scan_rel)
        image_path = base / image_rel if base else Path(image_rel)
        out.append(side_observation(i, c.name, scan_path, image_path, c.scan, seg.indices, c.picked_pixels))
    return out


# --- writing -----------------------------------------------------------------------------
def write_session(
    session: BoxSession, folder: str | Path, force: bool = False, render_images: bool = True
) -> Path:
    """Write a session folder (docs/formats/session.md).

    Writes ``camera.yaml``, ``scans/<capture>.yaml``, ``images/<capture>.png``,
    ``picks.yaml`` and ``truth.yaml`` into a temporary sibling folder, then renames it into
    place, so a failed or interrupted write leaves nothing half-written.

    Args:
        session: the session.
        folder: the folder to create.
        force: replace an existing folder.
        render_images: render the images; when false each image is a flat grey placeholder
            of the camera's size (fast, and the picking file stays valid).

    Returns:
        The folder.

    Raises:
        OutputError: the folder exists and ``force`` is false, or a write failed.
    """
    from rigcal.scan import write_scan

    with atomic_folder(folder, force) as tmp:
        (tmp / "scans").mkdir()
        (tmp / "images").mkdir()
        camera_file = write_camera(session.camera, tmp)
        for c in session.captures:
            scan_rel, image_rel = _capture_files(c.name)
            write_scan(tmp / scan_rel, c.scan)
            (tmp / image_rel).write_bytes(_png(session, c, render_images))
        (tmp / "picks.yaml").write_text(picks_text(session, camera_file), encoding="utf-8")
        (tmp / "truth.yaml").write_text(truth_text(session), encoding="utf-8")
    return Path(folder)


def _capture_files(name: str) -> tuple[str, str]:
    """Scan and image paths of a capture, relative to the session folder."""
    return f"scans/{name}.yaml", f"images/{name}.png"


def write_camera(camera: Camera, folder: Path) -> str:
    """Write the camera file; returns its name (a rigcal camera file when the lens model is
    OpenCV's, else a mrcal .cameramodel)."""
    from rigcal.camera import camera_to_opencv_yaml

    if camera.lensmodel == "LENSMODEL_PINHOLE" or camera.lensmodel.startswith("LENSMODEL_OPENCV"):
        (folder / "camera.yaml").write_text(camera_to_opencv_yaml(camera), encoding="utf-8")
        return "camera.yaml"
    camera.to_cameramodel().write(str(folder / "camera.cameramodel"))
    return "camera.cameramodel"


def _png(session: BoxSession, capture: SimCapture, render: bool) -> bytes:
    import cv2

    if render:
        from rigcal.sim.render import render_image

        img = render_image(session.camera, session.T_cam_laser, session.scene(capture))
    else:
        img = np.full((session.camera.height_px, session.camera.width_px, 3), 128, dtype=np.uint8)
    ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:  # pragma: no cover - cv2 encodes any 8-bit image
        raise OutputError(f"{capture.name}: cannot encode the image as PNG")
    return bytes(buf.tobytes())


def regenerate_command(spec: SessionSpec, images: bool = True) -> str | None:
    """The ``rigcal simulate box-session`` command that makes this spec, or None when the
    spec uses settings the command does not expose."""
    exposed = ("n_captures", "pick_sigma_px", "range_sigma_m", "wrong_pick_fraction", "seed", "noise")
    default = SessionSpec()
    for name in SessionSpec.__dataclass_fields__:
        if name not in exposed and getattr(spec, name) != getattr(default, name):
            return None
    cmd = f"rigcal simulate box-session -o SESSION --seed {spec.seed}"
    if spec.n_captures != default.n_captures:
        cmd += f" --captures {spec.n_captures}"
    if spec.pick_sigma_px != default.pick_sigma_px:
        cmd += f" --pick-sigma-px {spec.pick_sigma_px:g}"
    if spec.range_sigma_m != default.range_sigma_m:
        cmd += f" --range-sigma-m {spec.range_sigma_m:g}"
    if spec.wrong_pick_fraction != default.wrong_pick_fraction:
        cmd += f" --wrong-picks {spec.wrong_pick_fraction:g}"
    if spec.noise is not None:
        if spec.noise != RealisticNoise():
            return None
        cmd += " --noise realistic"
    if not images:
        cmd += " --no-images"
    return cmd


def picks_text(session: BoxSession, camera_file: str = "camera.yaml") -> str:
    """Text of the session's picking file (docs/formats/session.md)."""
    spec = session.spec
    n_wrong = sum(c.is_wrong_pick for c in session.captures)
    cmd = regenerate_command(spec)
    lines = [
        "# rigcal picking file (docs/formats/session.md)",
        f"# Synthetic box-target session (rigcal.sim.box_session), seed {spec.seed}: "
        f"{len(session.captures)} captures,",
        f"# box face at {spec.distance_m[0]:g}-{spec.distance_m[1]:g} m, "
        f"pick noise {spec.pick_sigma_px:g} px, "
        + (
            f"range noise {spec.range_sigma_m:g} m, dropouts {spec.dropout_fraction:g},"
            if spec.noise is None
            else "realistic scanner and cluttered room (noise in truth.yaml),"
        ),
        f"# {n_wrong} captures with deliberately wrong picks (named in truth.yaml).",
        "# The true T_cam_laser is in truth.yaml:",
        "#   rigcal solve picks.yaml -o rig.yaml --truth truth.yaml",
    ]
    if cmd is not None:
        lines.append(f"# Regenerate with: {cmd}")
    lines += [
        "schema_version: 1",
        f"name: simulated box session, seed {spec.seed}",
        f"camera: {camera_file}",
        "laser:",
        f"  name: {SCANNER_NAME}",
        f"  fov_deg: {spec.fov_deg:g}",
        f"  angle_increment_deg: {spec.angle_increment_deg:g}",
        f"  range_min_m: {spec.range_min_m:g}",
        f"  range_max_m: {spec.range_max_m:g}",
    ]
    if spec.noise is None:
        lines.append(f"  range_sigma_m: {spec.range_sigma_m:g}")
    lines += [
        "captures:",
    ]
    for c in session.captures:
        scan_rel, image_rel = _capture_files(c.name)
        px = ", ".join(f"[{u:.{PICK_DECIMALS}f}, {v:.{PICK_DECIMALS}f}]" for u, v in c.picked_pixels)
        lines += [
            f"  - name: {c.name}",
            f"    scan: {scan_rel}",
            f"    image: {image_rel}",
            f"    laser_side: {{segment: {c.segment_id}}}",
            f"    image_endpoints_px: [{px}]",
        ]
    return "\n".join(lines) + "\n"


def truth_text(session: BoxSession) -> str:
    """Text of the session's truth file, with how it was generated."""
    from rigcal.calib.truth import truth_to_text

    spec = session.spec
    generator: dict[str, Any] = {
        "tool": "rigcal.sim.box_session",
        "seed": spec.seed,
        "captures": len(session.captures),
        "pick_sigma_px": spec.pick_sigma_px,
        "range_sigma_m": spec.range_sigma_m,
        "dropout_fraction": spec.dropout_fraction,
        "wrong_pick_fraction": spec.wrong_pick_fraction,
        "wrong_picks": {c.name: c.wrong_pick_kind for c in session.captures if c.is_wrong_pick},
        "distance_m": [float(x) for x in spec.distance_m],
        "box_m": {"width": spec.box.width_m, "depth": spec.box.depth_m, "height": spec.box.height_m},
    }
    if spec.noise is not None:
        generator["range_sigma_m"] = spec.noise.range_sigma_m
        generator["dropout_fraction"] = spec.noise.dropout_fraction
        generator["noise"] = {"model": "realistic", **spec.noise.as_dict()}
    return truth_to_text(np.array(session.T_cam_laser), generator=generator)


def describe_session(session: BoxSession) -> str:
    """A one-paragraph human summary of the session's geometry and noise."""
    ends = np.array([c.true_laser_ends for c in session.captures])
    centres = ends.mean(axis=1)
    dist = np.linalg.norm(centres, axis=1)
    bearing = np.degrees(np.arctan2(centres[:, 1], centres[:, 0]))
    d = ends[:, 1] - ends[:, 0]
    # Incidence: between the face's normal and the direction back to the laser.
    normal = np.column_stack([d[:, 1], -d[:, 0]]) / np.linalg.norm(d, axis=1)[:, None]
    inc = np.degrees(np.arccos(np.clip(np.abs(np.sum(normal * -centres, axis=1)) / dist, 0.0, 1.0)))
    spec = session.spec
    wrong = [c.name for c in session.captures if c.is_wrong_pick]
    return (
        f"{len(session.captures)} captures of a {spec.box.width_m:g} m box: face at "
        f"{dist.min():.2f}-{dist.max():.2f} m, bearings {bearing.min():+.1f} to {bearing.max():+.1f} deg, "
        f"incidence up to {inc.max():.0f} deg; pick noise {spec.pick_sigma_px:g} px, "
        + (
            f"range noise {1000 * spec.range_sigma_m:g} mm, {100 * spec.dropout_fraction:g}% dropouts; "
            if spec.noise is None
            else f"realistic range noise ({1000 * spec.noise.range_sigma_m:.1f} mm sd, heavy-tailed), "
            f"mixed pixels, clutter; "
        )
        + (f"wrong picks in {', '.join(wrong)}" if wrong else "no wrong picks")
        + f"; seed {spec.seed}."
    )


def _pose3(p: Sequence[float] | FloatArray) -> tuple[float, float, float]:
    return float(p[0]), float(p[1]), float(p[2])
