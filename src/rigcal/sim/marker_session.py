"""Synthetic marker sessions: the V marker target seen by camera and scanner, T_cam_laser known.

Per capture the target (:mod:`rigcal.targets.marker`) stands in front of the rig with its
common edge crossing the scan plane, turned, tilted and rolled at random (so that its
faces' normals point up and down as well as sideways: views of an upright V leave the
laser's height, roll and pitch unobserved). The image is ray-cast: the room
(:func:`rigcal.sim.render.render_scene`, with no box) and the target's two faces, textured
with the very images ``rigcal targets print`` prints (:func:`rigcal.targets.marker.face_image`),
mip-mapped, shaded by incidence, then recorded by the camera (exposure gain, blur, image
noise: :func:`rigcal.sim.world_render.apply_effects`). The scans are ray-cast against the
faces' cuts and the room, as the board simulator's: ``scans_per_capture`` of them per
capture, with independent range noise, as a still moment of a bag holds (a 40 Hz scanner
held still for a quarter of a second gives 10); what the scanner repeats from scan to
scan at one pose (the grazing bias, the room) repeats in the simulation too.

With ``MarkerSpec(noise=RealisticNoise())`` (``--noise realistic``) the scanner and room
are :mod:`rigcal.sim.noise`'s (heavy-tailed range noise, mixed pixels, grazing bias,
dropouts, a still rig in a room with static clutter) and the camera blurs, is noisier and
changes its exposure between captures. The session folder holds ``camera.yaml``,
``targets.yaml``, ``scans/``, ``images/``, ``marker_session.yaml`` and ``truth.yaml``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.calib.board.detect import plane_cut
from rigcal.calib.marker.session import MARKER_SESSION_SCHEMA_VERSION
from rigcal.camera import Camera
from rigcal.errors import InputError, OutputError
from rigcal.geometry import inv_T, make_T, rotvec_to_R, transform_points
from rigcal.io.files import atomic_folder
from rigcal.scan import Scan, write_scan
from rigcal.sim.board_session import session_head_lines
from rigcal.sim.box_session import default_camera, default_T_cam_laser, write_camera
from rigcal.sim.noise import RealisticNoise, realistic_ranges, static_scene
from rigcal.sim.raycast import beam_angles, cast_scan_hits, noisy_ranges
from rigcal.sim.render import Room, Scene, pixel_bearings, ray_rectangle, render_scene
from rigcal.sim.textures import MipImage, mips, sample
from rigcal.sim.world_render import CameraEffects, apply_effects
from rigcal.targets.marker import MarkerTarget, default_target, face_image, targets_text

_MAX_ATTEMPTS = 500
# The target stands within this bearing of the laser's +x (radians).
_BEARING = 0.3
# Texels per metre of the faces' textures (0.5 mm: the default target's squares and
# offsets are whole texels).
TEXELS_PER_M = 2000.0
# A face seen more obliquely than this (cosine between its normal and the view) is not
# placed: its markers would not be read.
_MIN_VIEW_COS = 0.5
# A face's cut by the scan plane is at least this long.
_MIN_CUT_M = 0.12


@dataclass(frozen=True)
class MarkerSpec:
    """What to simulate.

    Attributes:
        n_captures: captures in the session.
        range_sigma_m: 1-sigma Gaussian range noise (clean model).
        dropout_fraction: fraction of returns lost (clean model).
        distance_m: (min, max) distance of the target's edge from the laser.
        max_turn_deg: turn about the vertical, up to this either way.
        max_tilt_deg: tilt about the target's horizontal axis (its top towards or away
            from the rig), up to this either way.
        max_roll_deg: roll about the line of sight (the edge leaning), up to this.
        upright: no tilt and no roll (every face vertical): the weak geometry.
        seed: seed of the generator.
        noise: None for the clean scanner and room, or the realistic ones.
        image_noise_sigma, blur_sigma_px, exposure_sigma: the camera's additive noise
            (grey levels), blur and log-gain spread between captures; None: 1 / 0 / 0 for
            the clean model, 3 / 0.8 / 0.25 for the realistic one.
        target: the marker target.
        scans_per_capture: scans of each still moment, independent range noise each.
    """

    n_captures: int = 20
    range_sigma_m: float = 0.01
    dropout_fraction: float = 0.01
    distance_m: tuple[float, float] = (1.0, 2.2)
    max_turn_deg: float = 30.0
    max_tilt_deg: float = 30.0
    max_roll_deg: float = 30.0
    upright: bool = False
    seed: int = 0
    fov_deg: float = 270.0
    angle_increment_deg: float = 0.25
    range_min_m: float = 0.1
    range_max_m: float = 30.0
    wall_clearance_m: float = 0.5
    room: Room = field(default_factory=Room)
    noise: RealisticNoise | None = None
    image_noise_sigma: float | None = None
    blur_sigma_px: float | None = None
    exposure_sigma: float | None = None
    target: MarkerTarget = field(default_factory=default_target)
    scans_per_capture: int = 10

    def __post_init__(self) -> None:
        if self.scans_per_capture < 1:
            raise ValueError("MarkerSpec: scans_per_capture must be >= 1")

    @property
    def effects(self) -> tuple[CameraEffects, float]:
        """The camera's effects and its log-gain spread."""
        real = self.noise is not None
        noise = self.image_noise_sigma if self.image_noise_sigma is not None else (3.0 if real else 1.0)
        blur = self.blur_sigma_px if self.blur_sigma_px is not None else (0.8 if real else 0.0)
        gain = self.exposure_sigma if self.exposure_sigma is not None else (0.25 if real else 0.0)
        return CameraEffects(noise, blur), gain


@dataclass(frozen=True, eq=False)
class MarkerCapture:
    """One simulated capture: the target's pose, its still moment's scans (``scan`` the
    first), the image and the beams whose true ray hits each face."""

    name: str
    T_laser_target: FloatArray
    scan: Scan
    image: NDArray[np.uint8]
    face_beams: tuple[NDArray[np.int64], NDArray[np.int64]]
    scans: tuple[Scan, ...] = ()


@dataclass(frozen=True, eq=False)
class SimMarkerSession:
    """A simulated marker session."""

    spec: MarkerSpec
    camera: Camera
    T_cam_laser: FloatArray
    captures: tuple[MarkerCapture, ...]


def generate_marker_session(
    spec: MarkerSpec, camera: Camera | None = None, T_cam_laser: ArrayLike | None = None
) -> SimMarkerSession:
    """Simulate a marker session (deterministic for the spec's seed).

    Raises:
        InputError: no visible placement of the target crossing the scan plane was found.
    """
    camera = camera or default_camera()
    T = default_T_cam_laser() if T_cam_laser is None else np.asarray(T_cam_laser, dtype=float)
    rng = np.random.default_rng(spec.seed)
    static = None
    if spec.noise is not None:
        try:
            static = static_scene(
                rng,
                spec.room,
                spec.wall_clearance_m,
                (-_BEARING, _BEARING),
                spec.distance_m[1] + 0.5,
                spec.noise.n_clutter,
            )
        except ValueError as exc:
            raise InputError(f"cannot simulate: {exc}") from None
    textures = tuple(_texture(spec.target, k) for k in range(2))
    captures = [
        _capture(spec, camera, T, rng, f"cap{i:02d}", static, textures) for i in range(spec.n_captures)
    ]
    return SimMarkerSession(spec, camera, T, tuple(captures))


def _texture(target: MarkerTarget, k: int) -> MipImage:
    img = face_image(target, k, TEXELS_PER_M)
    return mips(np.repeat(img[:, :, None], 3, axis=2), TEXELS_PER_M)


def T_laser_face(target: MarkerTarget, T_laser_target: FloatArray, k: int) -> FloatArray:
    """Face k's frame in the laser frame."""
    out: FloatArray = T_laser_target @ target.T_target_face(k)
    return out


def _capture(
    spec: MarkerSpec,
    camera: Camera,
    T: FloatArray,
    rng: np.random.Generator,
    name: str,
    static: tuple[tuple[float, float, float], FloatArray] | None,
    textures: tuple[MipImage, ...],
) -> MarkerCapture:
    target = spec.target
    cam_in_laser = inv_T(T)[:3, 3]
    for _ in range(_MAX_ATTEMPTS):
        dist = rng.uniform(*spec.distance_m)
        bearing = rng.uniform(-_BEARING, _BEARING)
        radial = np.array([np.cos(bearing), np.sin(bearing), 0.0])
        y0 = np.array([0.0, 0.0, -1.0])
        R_base = np.column_stack([np.cross(y0, radial), y0, radial])
        tilt_deg = 0.0 if spec.upright else rng.uniform(-1, 1) * spec.max_tilt_deg
        roll_deg = 0.0 if spec.upright else rng.uniform(-1, 1) * spec.max_roll_deg
        turn = rotvec_to_R([0.0, 0.0, np.radians(rng.uniform(-1, 1) * spec.max_turn_deg)])
        tilt = rotvec_to_R(np.radians(tilt_deg) * R_base[:, 0])
        roll = rotvec_to_R(np.radians(roll_deg) * radial)
        R = roll @ tilt @ turn @ R_base
        # The edge crosses the scan plane at dist * radial, between 35 and 65 % of its length.
        frac = rng.uniform(0.35, 0.65)
        T_laser_target = make_T(R, dist * radial - frac * target.edge_m * R[:, 1])
        cuts = []
        ok = True
        for k in range(2):
            T_lf = T_laser_face(target, T_laser_target, k)
            cut = plane_cut(T_lf, target.outline(k))
            centre = transform_points(
                T_lf, np.array([[0.5 * target.faces[k].width_m, 0.5 * target.edge_m, 0.0]])
            )[0]
            view = centre - cam_in_laser
            facing = float(T_lf[:3, 2] @ view) / float(np.linalg.norm(view))
            px = camera.project(transform_points(T @ T_lf, target.faces[k].corner_points))
            if (
                cut is None
                or np.linalg.norm(cut[1] - cut[0]) < _MIN_CUT_M
                or facing < _MIN_VIEW_COS
                or not camera.in_image(px, 12.0).all()
            ):
                ok = False
                break
            cuts.append(cut)
        if not ok:
            continue
        if static is None:
            room_pose = spec.room.pose_holding(rng, np.vstack(cuts), spec.wall_clearance_m)
            if room_pose is None:
                continue
            scene = spec.room.wall_segments(room_pose)
        elif spec.room.contains(static[0], np.vstack(cuts), spec.wall_clearance_m):
            room_pose, scene = static[0], static[1]
        else:
            continue
        segments = np.concatenate([scene, np.array(cuts)])
        scan, beams = _scan(spec, rng, segments, len(scene))
        if min(len(b) for b in beams) < 8:
            continue
        more = [_scan(spec, rng, segments, len(scene))[0] for _ in range(spec.scans_per_capture - 1)]
        image = render_capture(spec, camera, T, T_laser_target, room_pose, textures, rng)
        return MarkerCapture(name, T_laser_target, scan, image, beams, (scan, *more))
    raise InputError(f"cannot simulate {name}: no target placement was visible and crossed the scan plane")


def _scan(
    spec: MarkerSpec, rng: np.random.Generator, segments: FloatArray, n_scene: int
) -> tuple[Scan, tuple[NDArray[np.int64], NDArray[np.int64]]]:
    angle_min, step, angles = beam_angles(spec.fov_deg, spec.angle_increment_deg)
    if spec.noise is None:
        ranges, hit = cast_scan_hits(segments, angles, spec.range_max_m)
        ranges = noisy_ranges(rng, ranges, spec.range_sigma_m, spec.dropout_fraction)
    else:
        ranges, hit = realistic_ranges(rng, segments, angles, spec.range_max_m, spec.noise)
    scan = Scan.from_uniform(angle_min, step, ranges, spec.range_min_m, spec.range_max_m)
    beams = (np.flatnonzero(hit == n_scene), np.flatnonzero(hit == n_scene + 1))
    return scan, beams


def render_capture(
    spec: MarkerSpec,
    camera: Camera,
    T_cam_laser: FloatArray,
    T_laser_target: FloatArray,
    room_pose: tuple[float, float, float],
    textures: tuple[MipImage, ...],
    rng: np.random.Generator,
) -> NDArray[np.uint8]:
    """The image of one capture: the room, the target's textured faces, the camera's effects."""
    base, _ = render_scene(camera, T_cam_laser, Scene(spec.room, room_pose, box=None))
    img = base.reshape(-1, 3).astype(np.float32)
    T_laser_cam = inv_T(T_cam_laser)
    o = T_laser_cam[:3, 3].astype(np.float32)
    D = pixel_bearings(camera) @ T_laser_cam[:3, :3].T.astype(np.float32)
    # The angle one pixel spans at the image's centre (for the mip level).
    c = pixel_bearings(camera)[
        (camera.height_px // 2) * camera.width_px + camera.width_px // 2 + np.array([0, 1])
    ]
    pixel_rad = np.float32(np.linalg.norm(c[1] - c[0]))
    t_best = np.full(len(D), np.inf, dtype=np.float32)
    for k in range(2):
        T_lf = T_laser_face(spec.target, T_laser_target, k)
        outline = np.column_stack([spec.target.outline(k), np.zeros(4)])
        t, _ = ray_rectangle(o, D, transform_points(T_lf, outline))
        hit = np.flatnonzero(t < t_best)
        if not len(hit):
            continue
        t_best[hit] = t[hit]
        p = o + t[hit, None] * D[hit]
        q = (p - T_lf[:3, 3].astype(np.float32)) @ T_lf[:3, :3].astype(np.float32)
        cos_v = np.abs(D[hit] @ T_lf[:3, 2].astype(np.float32))
        foot = (t[hit] * pixel_rad / np.maximum(cos_v, np.float32(0.2))).astype(np.float32)
        ppm = np.float32(TEXELS_PER_M)
        tex = sample(textures[k], q[:, 0] * ppm - 0.5, q[:, 1] * ppm - 0.5, foot, clamp=True)
        # Matte paper lit from near the rig: brighter head-on.
        img[hit] = tex * (np.float32(0.55) + np.float32(0.4) * cos_v)[:, None]
    effects, gain_sigma = spec.effects
    gain = float(np.exp(np.clip(rng.normal(0.0, gain_sigma), -0.7, 0.7))) if gain_sigma > 0 else 1.0
    return apply_effects(img.reshape(camera.height_px, camera.width_px, 3), effects, rng, gain)


def marker_session_text(session: SimMarkerSession, camera_file: str = "camera.yaml") -> str:
    """Text of the session's marker session file (docs/formats/marker-session.md)."""
    spec = session.spec
    lines = session_head_lines(
        "marker",
        spec.seed,
        f"range noise {spec.range_sigma_m:g} m."
        if spec.noise is None
        else "realistic scanner, camera and cluttered room (the true noise is in truth.yaml).",
        MARKER_SESSION_SCHEMA_VERSION,
        camera_file,
        ["targets: targets.yaml"],
        spec.angle_increment_deg,
        spec.range_sigma_m if spec.noise is None else None,
    )
    for c in session.captures:
        if len(c.scans) > 1:
            files = ", ".join(f"scans/{c.name}_{j:02d}.yaml" for j in range(len(c.scans)))
            lines += [f"  - {{name: {c.name}, image: images/{c.name}.png, scans: [{files}]}}"]
        else:
            lines += [f"  - {{name: {c.name}, scan: scans/{c.name}.yaml, image: images/{c.name}.png}}"]
    return "\n".join(lines) + "\n"


def write_marker_session(session: SimMarkerSession, folder: str | Path, force: bool = False) -> Path:
    """Write the session folder atomically (refuses an existing folder unless ``force``)."""
    import cv2

    from rigcal.calib.truth import truth_to_text

    spec = session.spec
    with atomic_folder(folder, force) as tmp:
        (tmp / "scans").mkdir()
        (tmp / "images").mkdir()
        camera_file = write_camera(session.camera, tmp)
        (tmp / "targets.yaml").write_text(targets_text(spec.target), encoding="utf-8")
        for c in session.captures:
            if len(c.scans) > 1:
                for j, sc in enumerate(c.scans):
                    write_scan(tmp / "scans" / f"{c.name}_{j:02d}.yaml", sc)
            else:
                write_scan(tmp / "scans" / f"{c.name}.yaml", c.scan)
            ok, buf = cv2.imencode(".png", c.image, [cv2.IMWRITE_PNG_COMPRESSION, 3])
            if not ok:  # pragma: no cover - cv2 encodes any 8-bit image
                raise OutputError(f"{c.name}: cannot encode the image as PNG")
            (tmp / "images" / f"{c.name}.png").write_bytes(buf.tobytes())
        (tmp / "marker_session.yaml").write_text(marker_session_text(session, camera_file), encoding="utf-8")
        effects, gain = spec.effects
        generator = {
            "tool": "rigcal.sim.marker_session",
            "seed": spec.seed,
            "captures": len(session.captures),
            "range_sigma_m": spec.noise.range_sigma_m if spec.noise else spec.range_sigma_m,
            "upright": spec.upright,
            "scans_per_capture": spec.scans_per_capture,
            "camera_effects": {
                "noise_sigma": effects.noise_sigma,
                "blur_sigma_px": effects.blur_sigma_px,
                "log_gain_sigma": gain,
            },
        }
        if spec.noise:
            generator["noise"] = {"model": "realistic", **spec.noise.as_dict()}
        (tmp / "truth.yaml").write_text(
            truth_to_text(np.array(session.T_cam_laser), generator), encoding="utf-8"
        )
    return Path(folder)
