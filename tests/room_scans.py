"""The scans of a small room, for command-line tests on sequence folders."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigcal.scan import Scan


def room_scan(x_m: float, t_s: float) -> Scan:
    """A 6 m x 4 m room seen from (x_m, 0), 181 beams over 180 deg."""
    a = np.radians(np.arange(181) - 90.0)
    c, s = np.cos(a), np.sin(a)
    with np.errstate(divide="ignore"):
        to_x = np.where(c > 1e-9, (3.0 - x_m) / c, np.inf)
        to_y = np.where(np.abs(s) > 1e-9, 2.0 / np.abs(s), np.inf)
    return Scan.from_uniform(-np.pi / 2, np.radians(1.0), np.minimum(to_x, to_y), 0.05, 30.0, stamp_s=t_s)


def room_drive(base: Path, odometry: bool = False) -> Path:
    """Four seconds through the room at 0.5 m/s: scans at 10 Hz, 64x48 textured images at
    5 Hz, the rig inside (and beside it, ``base/rig.yaml``), with ``odometry`` the wheel
    odometry at 20 Hz. Returns the sequence folder ``base/seq``."""
    import cv2

    from rigcal.camera import Camera
    from rigcal.io.wheel_odometry import checked
    from rigcal.recordings.sequence import ImageFrame, write_sequence
    from rigcal.rig import Rig
    from rigcal.rigfile import write_rig
    from rigcal.sim.box_session import default_T_cam_laser

    w, h = 64, 48
    cam = Camera.from_opencv(np.array([[50.0, 0, 31.5], [0, 50.0, 23.5], [0, 0, 1]]), [0.0] * 5, w, h)
    write_rig(base / "rig.yaml", Rig(default_T_cam_laser(), cam, laser={"name": "test"}))
    rng = np.random.default_rng(3)
    scans = [room_scan(0.05 * k, 0.1 * k) for k in range(40)]
    frames = []
    for k in range(20):
        img = cv2.GaussianBlur(rng.integers(0, 255, (h, w), dtype=np.uint8), (3, 3), 0)
        frames.append(ImageFrame(0.2 * k + 0.01, f"{k:06d}.png", cv2.imencode(".png", img)[1].tobytes()))
    wheels = None
    if odometry:
        t = np.arange(0.0, 4.0, 0.05)
        wheels = checked(t, np.column_stack([0.5 * t, 0 * t, 0 * t]), (0.0, 0.0, 0.0), "test")
    rig_yaml = (base / "rig.yaml").read_text()
    return write_sequence(
        base / "seq", "room", scans, frames, None, {"test": True}, rig_yaml=rig_yaml, odometry=wheels
    )


def carmen_drive(t0: float, x0: float, odom_x0: float, odom_yaw: float) -> list[tuple[float, str]]:
    """A CARMEN log's lines (stamp, line) for 2 s at 0.5 m/s along x from ``x0`` in the
    room: ODOM lines at 20 Hz (the base's odometry from ``odom_x0`` along ``odom_yaw``),
    FLASER lines at 10 Hz (laser pose = truth)."""
    out = []
    for k in range(40):
        t, x = t0 + 0.05 * k, x0 + 0.025 * k
        ox = odom_x0 + 0.025 * k
        xy = f"{ox * np.cos(odom_yaw):.4f} {ox * np.sin(odom_yaw):.4f}"
        out.append((t, f"ODOM {xy} {odom_yaw} 0.5 0 0 {t:.6f} h {t:.6f}"))
        if k % 2 == 0:
            r = " ".join(f"{v:.3f}" for v in room_scan(x, 0.0).ranges_m)
            ts = t + 0.001
            out.append((ts, f"FLASER 181 {r} {x:.4f} 0 0 {x:.4f} 0 0 {ts:.6f} h {ts:.6f}"))
    return out
