"""A simulated drive around a world's loop: smooth motion, laser scans and ground truth.

Motion: the rig follows the world's closed path at walking speed with its corners rounded
(a circular arc of ``turn_radius_m`` at each waypoint), slows down into turns, and stops
for a few seconds at random places; the heading follows the path's tangent. Poses are
the laser's (x, y, yaw) in the world frame, as a function of time.

Sensors: the laser at its own rate (default 40 Hz, Hokuyo UTM-30LX-like: 270 deg, 0.25
deg steps, 1 cm noise, 30 m, 1 % dropouts), ray-cast against the world's surfaces cut by
its scan plane. Camera frames, when the renderer draws them, come at their own rate with
an optional clock offset; the ground truth is given at every sensor stamp.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.scan import Scan
from rigcal.sim.raycast import beam_angles, cast_scan, noisy_ranges
from rigcal.sim.world import World

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class DriveSpec:
    """How to drive and what the laser is like."""

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


class Motion:
    """The rig's pose as a function of time along a world's loop (one lap)."""

    def __init__(self, world: World, spec: DriveSpec) -> None:
        pts, speeds = _rounded_path(world.path, spec.turn_radius_m, spec.speed_mps, spec.turn_speed_mps)
        seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        dt = seg / (0.5 * (speeds[:-1] + speeds[1:]))
        t = np.concatenate([[0.0], np.cumsum(dt)])
        rng = np.random.default_rng(spec.seed)
        # Stops: hold the pose for stop_s at random points of the lap (not at the start).
        for at in np.sort(rng.uniform(0.1, 0.9, spec.stops)) * t[-1]:
            k = int(np.searchsorted(t, at))
            t = np.concatenate([t[:k], [t[k - 1] + 1e-6], t[k:] + spec.stop_s])
            pts = np.insert(pts, k, pts[k - 1], axis=0)
        self.t = t
        self.xy = pts
        d = np.diff(np.vstack([pts, pts[1:2]]), axis=0)
        yaw = np.arctan2(d[:, 1], d[:, 0])
        # A standing rig keeps its last heading.
        moving = np.linalg.norm(d, axis=1) > 1e-9
        for k in range(1, len(yaw)):
            if not moving[k]:
                yaw[k] = yaw[k - 1]
        self.yaw = np.unwrap(yaw)
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


def laser_stamps(motion: Motion, spec: DriveSpec) -> FloatArray:
    """Scan stamps over the lap at the laser's rate."""
    out: FloatArray = np.arange(0.0, motion.duration_s, 1.0 / spec.laser_rate_hz)
    return out


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


def write_drive(world: World, spec: DriveSpec, folder: str, force: bool = False) -> dict[str, float]:
    """Simulate one lap of ``world`` and write it as a sequence folder with the rig file
    and the laser's ground truth (TUM). Camera images are not rendered yet: the image
    stream is empty.

    Returns:
        Figures of the drive: lap length (m) and duration (s), scans.
    """
    from rigcal.geometry import make_T, rotvec_to_R
    from rigcal.io.sequence import write_sequence
    from rigcal.io.trajectory import Trajectory, tum_text
    from rigcal.rig import Rig
    from rigcal.rigfile import rig_to_text
    from rigcal.sim.box_session import default_camera, default_T_cam_laser

    motion = Motion(world, spec)
    stamps = laser_stamps(motion, spec)
    poses = motion.poses(stamps)
    scans = simulate_scans(world, poses, stamps, spec)
    T = np.array([make_T(rotvec_to_R([0.0, 0.0, yaw]), [x, y, world.laser_height_m]) for x, y, yaw in poses])
    truth = tum_text(Trajectory(T, stamps))
    rig = rig_to_text(Rig(default_T_cam_laser(), default_camera(), laser={"name": "simulated 2D scanner"}))
    write_sequence(
        folder,
        world.name,
        scans,
        [],
        None,
        {"simulator": "rigcal.sim.drive", "world": world.name, "seed": spec.seed},
        force=force,
        groundtruth_tum=truth,
        rig_yaml=rig,
    )
    return {"length_m": world.path_length_m, "duration_s": motion.duration_s, "scans": float(len(scans))}
