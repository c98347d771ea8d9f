"""Speed of the simulated camera: frames per second of the world renderer, and the time to
generate a whole drive against the drive's own duration.

1. ``render_world`` on 200 poses spread over a lap of the 60 m corridor loop, 640x480, the
   default camera (textures generated once beforehand, not timed): frames per second, and
   the same with the sensor effects and the PNG encoding of ``rigcal simulate world``.
2. ``write_drive``: one lap of the corridor loop at a 10 Hz camera and a 40 Hz laser, written
   to a temporary folder: the lap's duration over the generation time (textures, scans,
   images, files): seconds of data per second of work, as every "x real time" in rigcal
   (above 1: faster than real time).

    .venv/bin/python benchmarks/bench_simulate.py
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.geometry import inv_T
from rigcal.sim.box_session import default_camera, default_T_cam_laser
from rigcal.sim.drive import DriveSpec, Motion, encode_png, laser_poses_T, write_drive
from rigcal.sim.textures import world_textures
from rigcal.sim.world import BUILTIN
from rigcal.sim.world_render import CameraEffects, apply_effects, render_world


def main() -> None:
    world = BUILTIN["corridor-loop"]()
    spec = DriveSpec(seed=1)
    cam = default_camera()
    t0 = time.perf_counter()
    tex = world_textures(world, spec.seed)
    tex_s = time.perf_counter() - t0
    motion = Motion(world, spec)
    poses = laser_poses_T(world, motion.poses(np.linspace(0.0, motion.duration_s, 200, endpoint=False)))
    T_laser_cam = inv_T(default_T_cam_laser())
    render_world(world, cam, poses[0] @ T_laser_cam, tex)  # builds the ray fan
    rng = np.random.default_rng(0)
    render, full = [], []
    for T in poses:
        t0 = time.perf_counter()
        frame = render_world(world, cam, T @ T_laser_cam, tex)
        t1 = time.perf_counter()
        encode_png(apply_effects(frame.image, CameraEffects(), rng))
        t2 = time.perf_counter()
        render.append(t1 - t0)
        full.append(t2 - t0)
    print(f"textures of the corridor loop: {tex_s:.2f} s")
    print("| step, 640x480, corridor loop | ms per frame (median) | frames per second |")
    print("|---|---|---|")
    for label, ts in (("render_world", render), ("render + noise + PNG", full)):
        ms = 1000.0 * float(np.median(ts))
        print(f"| {label} | {ms:.1f} | {1000.0 / ms:.1f} |")

    with tempfile.TemporaryDirectory() as tmp:
        figures = write_drive(world, DriveSpec(seed=1), str(Path(tmp) / "seq"))
        size_mb = sum(p.stat().st_size for p in (Path(tmp) / "seq").rglob("*") if p.is_file()) / 1e6
    ratio = figures["duration_s"] / figures["generation_s"]
    print()
    print("| drive | duration (s) | scans | images | generation (s) | x real time | folder (MB) |")
    print("|---|---|---|---|---|---|---|")
    print(
        f"| corridor loop, 40 Hz laser, 10 Hz camera | {figures['duration_s']:.1f} | {int(figures['scans'])} "
        f"| {int(figures['images'])} | {figures['generation_s']:.1f} | {ratio:.2f} | {size_mb:.0f} |"
    )


if __name__ == "__main__":
    main()
