"""IASM steps on rendered views of a simulated corridor (paper Section III)."""

from __future__ import annotations

import numpy as np
from corridor_views import CAM, T_CAM_LASER, corridor, view

from rigcal.lines import extract_lines
from rigcal.localize.iasm import (
    IasmParams,
    iasm_step,
    image_scores,
    laser_metric_wanted,
    make_frame,
    snap_to_lines,
)
from rigcal.scan import Scan
from rigcal.sim.raycast import beam_angles, cast_scan
from rigcal.sim.textures import world_textures
from rigcal.sim.world import Surface, World


def test_snapping_moves_returns_along_their_beams_onto_their_line():
    """A wall y = 1.5 m seen at a slant with 1 cm range noise: the snapped returns lie on
    the fitted line, each on its own beam; the ends of the line, a return on no line and
    a return too far off stay where they are."""
    rng = np.random.default_rng(3)
    th = np.radians(np.arange(30.0, 80.0, 0.25))
    r = 1.5 / np.sin(th) + rng.normal(0.0, 0.01, len(th))
    r[100] += 0.2  # far off the wall
    pts = np.column_stack([r * np.cos(th), r * np.sin(th)])
    labels = np.zeros(len(pts), dtype=np.int64)
    labels[50] = -1
    out = snap_to_lines(pts, labels, 0.05)
    moved = np.flatnonzero(np.linalg.norm(out - pts, axis=1) > 0)
    assert set(moved).isdisjoint({0, 1, len(pts) - 2, len(pts) - 1, 50, 100})
    assert len(moved) > 0.95 * (len(pts) - 6)
    assert np.abs(out[moved, 1] - 1.5).max() < 0.01  # on the fitted line (within its error)
    assert np.abs(out[moved, 1] - 1.5).std() < 1e-3
    # along its own beam: the same bearing
    assert np.allclose(np.arctan2(out[moved, 1], out[moved, 0]), th[moved])
    # along the wall, the snapped points scatter far less than the raw returns
    along_raw = pts[moved, 0] - 1.5 / np.tan(th[moved])
    along_snap = out[moved, 0] - 1.5 / np.tan(th[moved])
    assert along_snap.std() < 0.2 * along_raw.std()
    assert np.array_equal(snap_to_lines(pts, -np.ones(len(pts), dtype=np.int64), 0.05), pts)


def test_frames_are_moved_to_the_image_time_and_snapped_unless_told_not_to():
    world = corridor("posters")
    tex = world_textures(world, 0)
    f_raw = view(world, tex, (0.0, 0.0, 0.0), IasmParams())
    T = np.array([[1.0, 0.0, 0.02], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    a0, step, ang = beam_angles(270.0, 0.25)
    segs = world.scan_segments()
    scan = Scan.from_uniform(a0, step, cast_scan(segs, ang, 30.0) + 0.004, 0.1, 30.0, 0.0)
    moved = make_frame(f_raw.gray, scan, CAM, T_CAM_LASER, IasmParams(snap_max_m=0.0), None, T)
    assert np.allclose(moved.points, scan.points[scan.valid] + [0.02, 0.0])
    snapped = make_frame(f_raw.gray, scan, CAM, T_CAM_LASER, IasmParams(), None, T)  # 0.03 m
    on = snapped.line_of >= 0
    assert np.abs(snapped.centres[on] - moved.centres[on]).max() < 1e-4
    assert not np.allclose(snapped.points, moved.points)


def test_iasm_recovers_a_small_step_on_texture():
    world = corridor("bricks")
    tex = world_textures(world, 0)
    params = IasmParams()
    motion = np.array([0.08, 0.01, np.radians(2.0)])
    f1 = view(world, tex, (0.0, 0.0, 0.0), params)
    f2 = view(world, tex, tuple(motion), params)
    res, _ = iasm_step(f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0))
    assert res is not None
    assert res.inliers > 30
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.005
    assert abs(res.motion[2] - motion[2]) < np.radians(0.05)


def test_flat_walls_give_no_correspondences_and_the_step_fails():
    world = corridor("plain")
    world = World(
        world.name, tuple(Surface(s.a, s.b, s.height_m, "plain") for s in world.surfaces), world.path, 0.4
    )
    tex = world_textures(world, 0)
    params = IasmParams()
    f1 = view(world, tex, (0.0, 0.0, 0.0), params)
    f2 = view(world, tex, (0.1, 0.0, 0.0), params)
    res, m = iasm_step(f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0))
    assert res is None
    assert len(m.a) < params.min_correspondences


def test_metric_choice_from_the_angle_histogram():
    """Section III-C: one direction of lines (a corridor) -> image metric; a corner -> laser."""
    a0, step, ang = beam_angles(270.0, 0.25)
    hallway = np.array([[[-10, 1.5], [10, 1.5]], [[-10, -1.5], [10, -1.5]]], dtype=float)
    room = np.array(
        [[[3, -3], [3, 3]], [[3, 3], [-3, 3]], [[-3, 3], [-3, -3]], [[-3, -3], [3, -3]]], dtype=float
    )
    for segs, laser in ((hallway, False), (room, True)):
        scan = Scan.from_uniform(a0, step, cast_scan(segs, ang, 8.0), 0.1, 8.0, 0.0)
        assert laser_metric_wanted(extract_lines(scan), IasmParams()) is laser


def test_out_of_range_corridor_ends_select_the_image_metric_and_it_scores_the_truth_best():
    """Section III-C on a textured corridor whose ends are beyond an 8 m laser: the walls
    leave the motion along the corridor open, and the image metric decides it."""
    world = corridor("bricks")
    tex = world_textures(world, 0)
    params = IasmParams()
    motion = np.array([0.12, 0.0, 0.0])
    f1 = view(world, tex, (0.0, 0.0, 0.0), params, range_max_m=8.0)
    f2 = view(world, tex, tuple(motion), params, range_max_m=8.0)
    assert not laser_metric_wanted(f1.lines, params)
    along = np.array([motion + np.array([dx, 0.0, 0.0]) for dx in (-0.1, -0.03, 0.0, 0.03, 0.1)])
    scores = image_scores(along, f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0))
    assert scores.shape == (5,)
    assert int(np.argmax(scores)) == 2
    # A hypothesis that moves the returns out of the image scores worst.
    away = image_scores(
        np.array([[0.0, 0.0, np.pi]]), f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0)
    )
    assert away[0] == -np.inf
    res, _ = iasm_step(f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0))
    assert res is not None
    assert res.metric == "image"
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.005
