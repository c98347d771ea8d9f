"""Rendered views of a simulated 3 m wide corridor, with the scans seen from them: the
scenes of the IASM and H-IASM tests."""

from __future__ import annotations

import cv2
import numpy as np

from rigcal.geometry import make_T, rotvec_to_R
from rigcal.localize.iasm import make_frame
from rigcal.scan import Scan
from rigcal.sim.box_session import default_camera
from rigcal.sim.drive import side_T_cam_laser
from rigcal.sim.raycast import beam_angles, cast_scan
from rigcal.sim.textures import world_textures
from rigcal.sim.world import Surface, World
from rigcal.sim.world_render import render_world

CAM = default_camera()
T_CAM_LASER = side_T_cam_laser()  # looking to the laser's left (+y)


def corridor(left: str) -> World:
    """A 3 m wide corridor along x: the wall on the left has texture ``left``."""
    p = np.array
    walls = (
        Surface(p([-12.0, 1.5]), p([12.0, 1.5]), 2.5, left),
        Surface(p([12.0, -1.5]), p([-12.0, -1.5]), 2.5, "posters"),
        Surface(p([12.0, 1.5]), p([12.0, -1.5]), 2.5, "bricks"),
        Surface(p([-12.0, -1.5]), p([-12.0, 1.5]), 2.5, "doors"),
    )
    return World("test-corridor", walls, p([[-10.0, 0.0], [10.0, 0.0], [0.0, 0.5]]), 0.4)


def view(world, tex, pose, params, range_max_m=30.0):
    """The frame (image and scan) of the laser at ``pose`` (x, y, yaw) in ``world``, its
    returns out to ``range_max_m``."""
    x, y, yaw = pose
    T_world_laser = make_T(rotvec_to_R([0.0, 0.0, yaw]), [x, y, world.laser_height_m])
    img = render_world(world, CAM, T_world_laser @ np.linalg.inv(T_CAM_LASER), tex).image
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    a0, step, ang = beam_angles(270.0, 0.25)
    c, s = np.cos(yaw), np.sin(yaw)
    segs = (world.scan_segments() - [x, y]) @ np.array([[c, s], [-s, c]]).T
    scan = Scan.from_uniform(a0, step, cast_scan(segs, ang, range_max_m), 0.1, range_max_m, 0.0)
    return make_frame(gray, scan, CAM, T_CAM_LASER, params)


def posters_pair(motion, params):
    """Frames at the origin and at ``motion`` in a corridor with posters on its left wall."""
    world = corridor("posters")
    tex = world_textures(world, 0)
    return view(world, tex, (0.0, 0.0, 0.0), params), view(world, tex, tuple(motion), params)


def correct(m, motion):
    """Which matches ``motion`` maps onto each other within 3 cm."""
    c, s = np.cos(motion[2]), np.sin(motion[2])
    moved = m.b @ np.array([[c, -s], [s, c]]).T + motion[:2]
    return np.linalg.norm(m.a - moved, axis=1) < 0.03
