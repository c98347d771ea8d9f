"""A simulated drive around a world's loop: smooth motion, laser scans and ground truth.

Motion: the rig follows the world's closed path at walking speed with its corners rounded
(a circular arc of ``turn_radius_m`` at each waypoint), slows down into turns, and stops
for a few seconds at random places; the heading follows the path's tangent. Poses are
the laser's (x, y, yaw) in the world frame, as a function of time.

Sensors: the laser at its own rate (default 40 Hz, Hokuyo UTM-30LX-like: 270 deg, 0.25
deg steps, 1 cm noise, 30 m, 1 % dropouts), ray-cast against the world's surfaces cut by
its scan plane. The camera at its own rate (default 10 Hz), not synchronised with the
laser (its first frame comes at a seeded random phase within its period), rendered by
:mod:`rigcal.sim.world_render` at the true pose with noise, optional blur and exposure
changes; its stamps carry an optional clock offset. The ground truth is the laser's true
pose at every sensor stamp, in true (laser) time.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.scan import Scan
from rigcal.sim.raycast import beam_angles, cast_scan, noisy_ranges
from rigcal.sim.world import World

if TYPE_CHECKING:
    from rigcal.recordings.sequence import ImageFrame
    from rigcal.rig import Rig


@dataclass(frozen=True)
class DriveSpec:
    """How to drive and what the laser and the camera are like.

    Camera: ``camera_rate_hz`` frames per second; ``camera_clock_offset_s`` is added to the
    written image stamps (camera clock = true time + offset); ``image_noise_sigma`` (grey
    levels), ``image_blur_sigma_px`` and ``exposure_walk`` (the log-gain's random-walk step
    per frame) as in :class:`rigcal.sim.world_render.CameraEffects`; ``images`` False
    writes no images; ``image_format`` is how they are stored (:data:`IMAGE_FORMATS`).
    ``start_still_s``: seconds the rig stands still at the start before it moves (as real
    drives begin, where IMU drivers calibrate); every sensor covers them, and the motion
    after them is the drive's without them, later by that much (0: none).
    ``duration_s`` drives only the lap's first seconds of motion (None: the lap), after the
    standstill.
    ``wheel_odometry`` also writes the base's wheel odometry (:func:`wheel_odometry`);
    ``gyro`` a MEMS gyroscope's yaw rate (:func:`gyro_rates`).
    ``laps``: how many times the loop is driven, one lap after the other (the stops fall
    anywhere in the drive); a second lap revisits every place of the first, as loop
    closure's place recognition is measured on.
    """

    speed_mps: float = 1.0
    turn_speed_mps: float = 0.5
    turn_radius_m: float = 0.8
    stops: int = 2
    stop_s: float = 2.0
    laser_rate_hz: float = 40.0
    fov_deg: float = 270.0
    angle_increment_deg: float = 0.25
    range_sigma_m: float = 0.01
    range_max_m: float = 30.0
    dropout_fraction: float = 0.01
    seed: int = 0
    camera_rate_hz: float = 10.0
    camera_clock_offset_s: float = 0.0
    image_noise_sigma: float = 2.0
    image_blur_sigma_px: float = 0.0
    exposure_walk: float = 0.0
    images: bool = True
    duration_s: float | None = None
    image_format: str = "png"
    wheel_odometry: bool = False
    laps: int = 1
    gyro: bool = False
    start_still_s: float = 0.0

    def __post_init__(self) -> None:
        checks = [
            ("laser_rate_hz", self.laser_rate_hz, self.laser_rate_hz > 0, "a rate above 0 Hz"),
            ("range_max_m", self.range_max_m, 0.5 <= self.range_max_m <= 100, "0.5 to 100 m"),
            ("camera_rate_hz", self.camera_rate_hz, self.camera_rate_hz > 0, "a rate above 0 Hz"),
            (
                "camera_clock_offset_s",
                self.camera_clock_offset_s,
                abs(self.camera_clock_offset_s) < 1e6,
                "a finite offset, seconds",
            ),
            (
                "image_noise_sigma",
                self.image_noise_sigma,
                0 <= self.image_noise_sigma <= 100,
                "0 to 100 grey levels",
            ),
            (
                "image_blur_sigma_px",
                self.image_blur_sigma_px,
                0 <= self.image_blur_sigma_px <= 50,
                "0 to 50 pixels",
            ),
            ("exposure_walk", self.exposure_walk, 0 <= self.exposure_walk <= 1, "0 to 1"),
            (
                "duration_s",
                self.duration_s,
                self.duration_s is None or self.duration_s > 0,
                "a duration above 0 s",
            ),
            (
                "start_still_s",
                self.start_still_s,
                0 <= self.start_still_s <= 3600,
                "0 to 3600 s of standstill",
            ),
        ]
        for key, value, ok, expected in checks:
            if not ok or (value is not None and not np.isfinite(value)):
                raise InputError.at(None, key, value, expected)
        if not (isinstance(self.laps, int) and 1 <= self.laps <= 100):
            raise InputError.at(None, "laps", self.laps, "a whole number of laps, 1 to 100")
        if self.image_format not in IMAGE_FORMATS:
            raise InputError.at(None, "image_format", self.image_format, f"one of {list(IMAGE_FORMATS)}")


IMAGE_FORMATS = {
    "png": "lossless colour PNG (fast settings)",
    "png-grey": "lossless grey PNG of the levels rigcal reads (OpenCV's grey weights, as "
    "cv2.imread's): localize and matches give the same results as with png, in about a third "
    "of the space; other tools see grey images",
    "jpg": "colour JPEG, quality 95: about a fifth of png's space, lossy (grey levels off by "
    "about 1.5 RMS, so results differ slightly)",
}
"""How ``rigcal simulate world`` stores images (``--image-format``)."""


class Motion:
    """The rig's pose as a function of time along a world's loop (``spec.laps`` laps)."""

    def __init__(self, world: World, spec: DriveSpec) -> None:
        pts, speeds = _rounded_path(world.path, spec.turn_radius_m, spec.speed_mps, spec.turn_speed_mps)
        # The path is closed (its last sample is its first): laps follow on.
        pts = np.vstack([np.tile(pts[:-1], (spec.laps, 1)), pts[-1:]])
        speeds = np.r_[np.tile(speeds[:-1], spec.laps), speeds[-1:]]
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        dt = seg / (0.5 * (speeds[:-1] + speeds[1:]))
        t = np.concatenate([[0.0], np.cumsum(dt)])
        rng = np.random.default_rng(spec.seed)
        # Stops: hold the pose for stop_s at random points of the drive (not at the start).
        for at in np.sort(rng.uniform(0.1, 0.9, spec.stops)) * t[-1]:
            k = int(np.searchsorted(t, at))
            t = np.concatenate([t[:k], [t[k - 1] + 1e-6], t[k:] + spec.stop_s])
            pts = np.insert(pts, k, pts[k - 1], axis=0)
        d = np.diff(np.vstack([pts, pts[1:2]]), axis=0)
        yaw = np.arctan2(d[:, 1], d[:, 0])
        # A standing rig keeps its last heading.
        moving = np.linalg.norm(d, axis=1) > 1e-9
        for k in range(1, len(yaw)):
            if not moving[k]:
                yaw[k] = yaw[k - 1]
        yaw = np.unwrap(yaw)
        if spec.start_still_s > 0:
            # The standstill at the start: the first pose held, the motion after it later.
            t = np.r_[0.0, t + spec.start_still_s]
            pts = np.vstack([pts[:1], pts])
            yaw = np.r_[yaw[:1], yaw]
        self.t = t
        self.xy = pts
        self.yaw = yaw
        self.duration_s = float(t[-1])

    def poses(self, stamps: FloatArray) -> FloatArray:
        """(N, 3) laser poses (x, y, yaw) at the stamps (clipped to the lap)."""
        s = np.clip(stamps, 0.0, self.duration_s)
        return np.column_stack(
            [
                np.interp(s, self.t, self.xy[:, 0]),
                np.interp(s, self.t, self.xy[:, 1]),
                np.interp(s, self.t, self.yaw),
            ]
        )


def _rounded_path(
    waypoints: FloatArray, radius: float, v_straight: float, v_turn: float
) -> tuple[FloatArray, FloatArray]:
    """A closed path through the waypoints with each corner replaced by a circular arc,
    sampled every 2 cm, and the speed at each sample."""
    P = np.asarray(waypoints, dtype=float)
    n = len(P)
    pts: list[FloatArray] = []
    speeds: list[FloatArray] = []
    for i in range(n):
        prev, cur, nxt = P[i - 1], P[i], P[(i + 1) % n]
        u_in = (cur - prev) / np.linalg.norm(cur - prev)
        u_out = (nxt - cur) / np.linalg.norm(nxt - cur)
        r = min(radius, 0.45 * np.linalg.norm(cur - prev), 0.45 * np.linalg.norm(nxt - cur))
        a = cur - r * u_in  # arc start
        b = cur + r * u_out  # arc end
        # Straight part from the previous arc's end to this arc's start.
        start = pts[-1][-1] if pts else None
        if start is not None:
            m = max(int(np.linalg.norm(a - start) / 0.02), 1)
            s = np.linspace(0.0, 1.0, m, endpoint=False)[:, None]
            pts.append(start + s * (a - start))
            speeds.append(np.full(m, v_straight))
        # Quadratic Bezier arc (close to circular for right angles) from a to b via cur.
        m = max(int(2.0 * r / 0.02), 2)
        s = np.linspace(0.0, 1.0, m)[:, None]
        arc = (1 - s) ** 2 * a + 2 * (1 - s) * s * cur + s**2 * b
        pts.append(arc)
        speeds.append(np.full(m, v_turn))
    # Close the loop back to the first arc's start.
    first = pts[0][0]
    last = pts[-1][-1]
    m = max(int(np.linalg.norm(first - last) / 0.02), 1)
    s = np.linspace(0.0, 1.0, m + 1)[1:, None]
    pts.append(last + s * (first - last))
    speeds.append(np.full(m, v_straight))
    return np.vstack(pts), np.concatenate(speeds)


def drive_duration(motion: Motion, spec: DriveSpec) -> float:
    """How long the drive lasts: the lap, or the standstill and ``spec.duration_s`` of
    motion when that is shorter."""
    if spec.duration_s is None:
        return motion.duration_s
    return min(spec.start_still_s + spec.duration_s, motion.duration_s)


def laser_stamps(motion: Motion, spec: DriveSpec) -> FloatArray:
    """Scan stamps over the drive at the laser's rate (the laser's clock is true time)."""
    out: FloatArray = np.arange(0.0, drive_duration(motion, spec), 1.0 / spec.laser_rate_hz)
    return out


def camera_stamps(motion: Motion, spec: DriveSpec) -> FloatArray:
    """True times of the camera frames: the camera's rate, starting at a seeded random
    phase within its period (camera and laser are not synchronised). Without the clock
    offset."""
    period = 1.0 / spec.camera_rate_hz
    phase = float(np.random.default_rng([spec.seed, 2]).uniform(0.0, period))
    out: FloatArray = np.arange(phase, drive_duration(motion, spec), period)
    return out


def side_T_cam_laser() -> FloatArray:
    """A side-looking rig's T_cam_laser (4, 4): the camera looks to the laser's left (+y),
    10 cm above the laser and 5 cm to its left, pitched 10 deg down."""
    from rigcal.geometry import inv_T, make_T, rotvec_to_R

    R_base = np.array(
        [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]]
    )  # columns: camera axes in the laser frame
    pitch = rotvec_to_R([np.radians(-10.0), 0.0, 0.0])  # about laser x: tilts +y down
    return inv_T(make_T(pitch @ R_base, [0.0, 0.05, 0.10]))


def laser_poses_T(world: World, poses: FloatArray) -> FloatArray:
    """(N, 4, 4) T_world_laser from (N, 3) laser poses (x, y, yaw) at the laser's height."""
    from rigcal.geometry import make_T, rotvec_to_R

    h = world.laser_height_m
    return np.array([make_T(rotvec_to_R([0.0, 0.0, yaw]), [x, y, h]) for x, y, yaw in poses]).reshape(
        -1, 4, 4
    )


def simulate_scans(world: World, poses: FloatArray, stamps: FloatArray, spec: DriveSpec) -> list[Scan]:
    """One noisy scan per pose (x, y, yaw of the laser in the world)."""
    rng = np.random.default_rng(spec.seed + 1)
    angle_min, step, angles = beam_angles(spec.fov_deg, spec.angle_increment_deg)
    segs = world.scan_segments()
    scans = []
    for (x, y, yaw), t in zip(poses, stamps, strict=True):
        c, s = np.cos(yaw), np.sin(yaw)
        R = np.array([[c, s], [-s, c]])  # world -> laser rotation (R_laser_world)
        local = (segs - np.array([x, y])) @ R.T
        r = cast_scan(local, angles, spec.range_max_m)
        r = noisy_ranges(rng, r, spec.range_sigma_m, spec.dropout_fraction)
        scans.append(Scan.from_uniform(angle_min, step, r, 0.1, spec.range_max_m, float(t)))
    return scans


# Simulated wheel odometry: its rate, the laser's pose on the base (x, y, yaw), and its
# errors: a wheel-radius scale error (fraction of the distance), a heading drift per metre
# (a wheel-base error: deg/m, as the right wheel's radius off by 0.1 %), and white noise
# per step on the distance (fraction) and on the heading (rad per sqrt(step)).
WHEEL_RATE_HZ = 50.0
WHEEL_T_BASE_LASER = (0.20, 0.0, 0.0)
WHEEL_SCALE_ERROR = 0.02
WHEEL_DRIFT_DEG_PER_M = 0.5
WHEEL_NOISE = (0.01, 0.002)


def wheel_odometry(motion: Motion, spec: DriveSpec) -> tuple[FloatArray, FloatArray]:
    """Stamps (M,) and poses (M, 3) of the base's wheel odometry over the drive: the true
    base motion (the laser's, moved by :data:`WHEEL_T_BASE_LASER`) between consecutive
    stamps, its distance scaled by (1 + scale error + noise) and its heading drifting with
    the distance driven, chained from the true start."""
    from rigcal.geometry import pose_of, se2

    rng = np.random.default_rng([spec.seed, 7])
    t: FloatArray = np.arange(0.0, drive_duration(motion, spec), 1.0 / WHEEL_RATE_HZ)
    T_laser_base = np.linalg.inv(se2(np.array(WHEEL_T_BASE_LASER)))
    base = [se2(p) @ T_laser_base for p in motion.poses(t)]
    T = base[0]
    out = [pose_of(T)]
    drift = np.radians(WHEEL_DRIFT_DEG_PER_M)
    for a, b in itertools.pairwise(base):
        dx, dy, dth = pose_of(np.linalg.inv(a) @ b)
        dist = float(np.hypot(dx, dy))
        scale = 1.0 + WHEEL_SCALE_ERROR + WHEEL_NOISE[0] * rng.standard_normal()
        dth_noisy = dth + drift * dist + WHEEL_NOISE[1] * rng.standard_normal()
        T = T @ se2(np.array([dx * scale, dy * scale, dth_noisy]))
        out.append(pose_of(T))
    return t, np.array(out)


# Simulated gyroscope (a MEMS IMU's z axis, mounted level: its rate is the laser's yaw
# rate): its rate, and its errors in the standard model of a rate gyro (IEEE Std 952-1997,
# Annex C; Groves, Principles of GNSS, Inertial, and Multisensor Integrated Navigation
# Systems, 2013, Section 4.4): white rate noise of GYRO_NOISE_DEG_S_RT_HZ (the angle random
# walk, deg/s/sqrt(Hz)), a constant bias drawn once per drive (1-sigma GYRO_BIAS_DEG_S,
# what is left of a turn-on bias a driver does not calibrate away), and a bias random walk
# (GYRO_BIAS_WALK_DEG_S_RT_S, deg/s/sqrt(s): the slow drift of the bias in a run).
GYRO_RATE_HZ = 200.0
GYRO_NOISE_DEG_S_RT_HZ = 0.005
GYRO_BIAS_DEG_S = 0.05
GYRO_BIAS_WALK_DEG_S_RT_S = 0.0005


def gyro_rates(motion: Motion, spec: DriveSpec) -> tuple[FloatArray, FloatArray]:
    """Stamps (M,) and yaw rates (M,) rad/s of the gyroscope over the drive: the true yaw
    rate averaged over the period ending at each sample's stamp (:mod:`rigcal.io.gyro`),
    plus the bias (constant and random walk) and white noise of
    :data:`GYRO_NOISE_DEG_S_RT_HZ` (a sample's 1-sigma is the density times sqrt(rate)).
    Its random stream is its own (seeded by the drive's
    seed and 11): a drive's other streams are the same with or without it."""
    t, (bias, walk, noise) = _gyro_stamps(motion, spec), _gyro_errors(motion, spec)
    dt = 1.0 / GYRO_RATE_HZ
    ends = np.r_[t[0] - dt, t]
    true = np.diff(np.interp(np.clip(ends, 0.0, motion.duration_s), motion.t, motion.yaw)) / dt
    return t, true + bias + walk + noise


def gyro_bias(motion: Motion, spec: DriveSpec) -> tuple[FloatArray, FloatArray]:
    """Stamps (M,) and the bias (M,) rad/s (constant and random walk) of
    :func:`gyro_rates`'s samples: what a filter's bias estimate is checked against."""
    bias, walk, _ = _gyro_errors(motion, spec)
    out: FloatArray = bias + walk
    return _gyro_stamps(motion, spec), out


def _gyro_stamps(motion: Motion, spec: DriveSpec) -> FloatArray:
    out: FloatArray = np.arange(0.0, drive_duration(motion, spec), 1.0 / GYRO_RATE_HZ)
    return out


def _gyro_errors(motion: Motion, spec: DriveSpec) -> tuple[float, FloatArray, FloatArray]:
    """The gyro's constant bias, bias random walk and white noise at its samples (rad/s)."""
    rng = np.random.default_rng([spec.seed, 11])
    n, dt = len(_gyro_stamps(motion, spec)), 1.0 / GYRO_RATE_HZ
    bias = float(np.radians(GYRO_BIAS_DEG_S) * rng.standard_normal())
    walk = np.cumsum(np.radians(GYRO_BIAS_WALK_DEG_S_RT_S) * np.sqrt(dt) * rng.standard_normal(n))
    noise = np.radians(GYRO_NOISE_DEG_S_RT_HZ) * np.sqrt(GYRO_RATE_HZ) * rng.standard_normal(n)
    return bias, walk, noise


def write_drive(
    world: World,
    spec: DriveSpec,
    folder: str,
    force: bool = False,
    rig: Rig | None = None,
    progress: Callable[[int], None] | None = None,
) -> dict[str, float]:
    """Simulate a drive of ``world`` and write it as a sequence folder: scans, camera
    images (PNG), the rig file and the laser's ground truth (TUM) at every sensor stamp.

    Args:
        world: the world.
        spec: motion, laser and camera settings.
        folder: the sequence folder to create.
        force: replace an existing folder.
        rig: T_cam_laser and the camera; the simulated default rig
            (:func:`rigcal.sim.box_session.default_T_cam_laser`, forward-looking) when None.
        progress: called with 1 after each rendered image.

    Returns:
        Figures of the drive: lap length (m), drive duration (s), scans, images, and the
        generation time (s, wall clock).
    """
    from rigcal.io.trajectory import Trajectory, tum_text
    from rigcal.recordings.sequence import write_sequence
    from rigcal.rigfile import rig_to_text

    start = time.perf_counter()
    rig = rig or default_rig()
    motion = Motion(world, spec)
    stamps = laser_stamps(motion, spec)
    scans = simulate_scans(world, motion.poses(stamps), stamps, spec)
    cam_t = camera_stamps(motion, spec) if spec.images else np.zeros(0)
    truth_t = np.unique(np.concatenate([stamps, cam_t]))
    truth = tum_text(Trajectory(laser_poses_T(world, motion.poses(truth_t)), truth_t))
    source = {
        "simulator": "rigcal.sim.drive",
        "world": world.name,
        "seed": spec.seed,
        "laser_rate_hz": spec.laser_rate_hz,
        "range_max_m": spec.range_max_m,
        "camera_rate_hz": spec.camera_rate_hz if spec.images else None,
        "camera_clock_offset_s": spec.camera_clock_offset_s,
        "image_noise_sigma": spec.image_noise_sigma,
        "image_blur_sigma_px": spec.image_blur_sigma_px,
        "exposure_walk": spec.exposure_walk,
    }
    if spec.laps != 1:
        source["laps"] = spec.laps
    if spec.start_still_s > 0:
        source["start_still_s"] = spec.start_still_s
    if spec.images and spec.image_format != "png":
        source["image_format"] = spec.image_format
    odometry = None
    if spec.wheel_odometry:
        from rigcal.io.wheel_odometry import checked

        wheel_t, wheel_poses = wheel_odometry(motion, spec)
        odometry = checked(wheel_t, wheel_poses, WHEEL_T_BASE_LASER, "simulated wheel odometry")
        source["wheel_odometry"] = {
            "rate_hz": WHEEL_RATE_HZ,
            "scale_error": WHEEL_SCALE_ERROR,
            "drift_deg_per_m": WHEEL_DRIFT_DEG_PER_M,
            "noise_distance_fraction_heading_rad": list(WHEEL_NOISE),
        }
    gyro = None
    if spec.gyro:
        from rigcal.io.gyro import checked as checked_gyro

        gyro = checked_gyro(*gyro_rates(motion, spec), "simulated gyroscope")
        source["gyro"] = {
            "rate_hz": GYRO_RATE_HZ,
            "noise_deg_s_rt_hz": GYRO_NOISE_DEG_S_RT_HZ,
            "bias_deg_s": GYRO_BIAS_DEG_S,
            "bias_walk_deg_s_rt_s": GYRO_BIAS_WALK_DEG_S_RT_S,
        }
    write_sequence(
        folder,
        world.name,
        scans,
        _images(world, spec, motion, cam_t, rig, progress),
        None,
        source,
        force=force,
        groundtruth_tum=truth,
        rig_yaml=rig_to_text(rig),
        odometry=odometry,
        gyro=gyro,
    )
    return {
        "length_m": world.path_length_m,
        "duration_s": drive_duration(motion, spec),
        "scans": float(len(scans)),
        "images": float(len(cam_t)),
        "generation_s": time.perf_counter() - start,
    }


def _images(
    world: World,
    spec: DriveSpec,
    motion: Motion,
    stamps: FloatArray,
    rig: Rig,
    progress: Callable[[int], None] | None,
) -> Iterator[ImageFrame]:
    """The camera's frames, rendered at the true poses; PNG encoding runs in a second thread
    while the next frame renders."""
    if not len(stamps):
        return
    from rigcal.geometry import inv_T
    from rigcal.recordings.sequence import ImageFrame
    from rigcal.sim.textures import world_textures
    from rigcal.sim.world_render import CameraEffects, apply_effects, render_world

    tex = world_textures(world, spec.seed)
    effects = CameraEffects(spec.image_noise_sigma, spec.image_blur_sigma_px, spec.exposure_walk)
    rng = np.random.default_rng([spec.seed, 3])
    log_gain = np.clip(np.cumsum(rng.normal(0.0, spec.exposure_walk, len(stamps))), -0.7, 0.7)
    T_laser_cam = inv_T(rig.T_cam_laser)
    T_world_laser = laser_poses_T(world, motion.poses(stamps))
    pending: Future[bytes] | None = None
    stamp, name = 0.0, ""
    with ThreadPoolExecutor(max_workers=1) as pool:
        for k, t in enumerate(stamps):
            frame = render_world(world, rig.camera, T_world_laser[k] @ T_laser_cam, tex)
            image = apply_effects(frame.image, effects, rng, float(np.exp(log_gain[k])))
            if pending is not None:
                yield ImageFrame(stamp, name, pending.result())
            pending = pool.submit(encode_image, image, spec.image_format)
            stamp, name = float(t + spec.camera_clock_offset_s), f"{k:06d}{image_suffix(spec.image_format)}"
            if progress is not None:
                progress(1)
        if pending is not None:
            yield ImageFrame(stamp, name, pending.result())


def encode_png(image: NDArray[np.uint8]) -> bytes:
    """Lossless PNG, fast settings (low compression, Huffman only)."""
    return encode_image(image, "png")


def image_suffix(image_format: str) -> str:
    """The file name suffix of an image format of :data:`IMAGE_FORMATS`."""
    return ".jpg" if image_format == "jpg" else ".png"


def encode_image(image: NDArray[np.uint8], image_format: str) -> bytes:
    """A rendered BGR image encoded in one of :data:`IMAGE_FORMATS`."""
    import cv2

    if image_format == "jpg":
        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])
    else:
        if image_format == "png-grey":
            from rigcal.io.images import rgb_to_grey

            image = rgb_to_grey(np.ascontiguousarray(image[..., ::-1]))  # the levels read_grey gives
        params = [
            cv2.IMWRITE_PNG_COMPRESSION,
            1,
            cv2.IMWRITE_PNG_STRATEGY,
            cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY,
        ]
        ok, buf = cv2.imencode(".png", image, params)
    if not ok:  # pragma: no cover - cv2 encodes any uint8 image
        raise RuntimeError(f"{image_format} encoding failed")
    out: bytes = buf.tobytes()
    return out


def first_image_bytes(world: World, spec: DriveSpec, rig: Rig | None = None) -> int:
    """The size of the drive's first image as it will be written (rendered and encoded
    now, one frame's work), to estimate a sequence's size before writing it."""
    motion = Motion(world, spec)
    stamps = camera_stamps(motion, spec)[:1]
    return sum(len(f.data) for f in _images(world, spec, motion, stamps, rig or default_rig(), None))


def default_rig() -> Rig:
    """The simulated forward-looking rig (:func:`rigcal.sim.box_session.default_T_cam_laser`)."""
    from rigcal.rig import Rig
    from rigcal.sim.box_session import default_camera, default_T_cam_laser

    return Rig(default_T_cam_laser(), default_camera(), laser={"name": "simulated 2D scanner"})
