"""IASM and H-IASM steps on rendered views of a simulated wall (paper Sections III and V)."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from rigcal.calib.lines import extract_lines
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.localize.iasm import (
    Frame,
    IasmParams,
    camera_motion,
    hiasm_step,
    homography_predictions,
    iasm_step,
    joint_polish,
    keyframe_reference,
    laser_metric_wanted,
    make_frame,
    match_returns,
    snap_to_lines,
    window_search,
)
from rigcal.localize.icp import line_normals, pose_of, se2
from rigcal.localize.image_matching import new_keyframe
from rigcal.scan import Scan
from rigcal.sim.box_session import default_camera
from rigcal.sim.drive import side_T_cam_laser
from rigcal.sim.raycast import beam_angles, cast_scan
from rigcal.sim.textures import world_textures
from rigcal.sim.world import Surface, World
from rigcal.sim.world_render import render_world

CAM = default_camera()
T_CAM_LASER = side_T_cam_laser()  # looking to the laser's left (+y)


def _world(left: str) -> World:
    """A 3 m wide corridor along x: the wall on the left has texture ``left``."""
    p = np.array
    walls = (
        Surface(p([-12.0, 1.5]), p([12.0, 1.5]), 2.5, left),
        Surface(p([12.0, -1.5]), p([-12.0, -1.5]), 2.5, "posters"),
        Surface(p([12.0, 1.5]), p([12.0, -1.5]), 2.5, "bricks"),
        Surface(p([-12.0, -1.5]), p([-12.0, 1.5]), 2.5, "doors"),
    )
    return World("test-corridor", walls, p([[-10.0, 0.0], [10.0, 0.0], [0.0, 0.5]]), 0.4)


def _frame(world, tex, pose, params):
    x, y, yaw = pose
    T_world_laser = make_T(rotvec_to_R([0.0, 0.0, yaw]), [x, y, world.laser_height_m])
    img = render_world(world, CAM, T_world_laser @ np.linalg.inv(T_CAM_LASER), tex).image
    gray = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
    a0, step, ang = beam_angles(270.0, 0.25)
    c, s = np.cos(yaw), np.sin(yaw)
    segs = (world.scan_segments() - [x, y]) @ np.array([[c, s], [-s, c]]).T
    scan = Scan.from_uniform(a0, step, cast_scan(segs, ang, 30.0), 0.1, 30.0, 0.0)
    return make_frame(gray, scan, CAM, T_CAM_LASER, params)


def _posters_pair(motion, params):
    """Frames at the origin and at ``motion`` in a corridor with posters on its left wall."""
    world = _world("posters")
    tex = world_textures(world, 0)
    return _frame(world, tex, (0.0, 0.0, 0.0), params), _frame(world, tex, tuple(motion), params)


def _correct(m, motion):
    c, s = np.cos(motion[2]), np.sin(motion[2])
    moved = m.b @ np.array([[c, -s], [s, c]]).T + motion[:2]
    return np.linalg.norm(m.a - moved, axis=1) < 0.03


@pytest.fixture(scope="module")
def repeating():
    world = _world("repeating")
    return world, world_textures(world, 0)


def test_repeating_pattern_fools_iasm_but_not_hiasm(repeating):
    """Fig. 5: a 0.3 m step along a wall with a 0.5 m period. IASM's search around each
    return's own pixel holds the wrong period's copy, not the true match; H-IASM's window
    around the homography's prediction holds only the true match."""
    world, tex = repeating
    params = IasmParams()
    motion = np.array([0.3, 0.0, 0.0])
    f1 = _frame(world, tex, (0.0, 0.0, 0.0), params)
    f2 = _frame(world, tex, tuple(motion), params)
    rng = np.random.default_rng(0)
    _, m_iasm = iasm_step(f1, f2, CAM, T_CAM_LASER, params, rng)
    R, t = camera_motion(motion, T_CAM_LASER)
    res, m_h = hiasm_step(
        f1, f2, R, t / np.linalg.norm(t), float(np.linalg.norm(t)), CAM, T_CAM_LASER, params, rng
    )
    assert len(m_iasm.a) > 20
    assert _correct(m_iasm, motion).mean() < 0.3
    assert len(m_h.a) > 20
    assert _correct(m_h, motion).mean() > 0.9
    assert res is not None
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.01
    assert abs(res.motion[2]) < np.radians(0.1)


def test_a_scale_carried_from_a_faster_step_misplaces_hiasms_windows():
    """The rig slows from 0.4 m to 0.1 m between images: with the previous step's scale
    (the paper's, carried over) the windows sit 0.3 m ahead of the true matches; with the
    step's own (the laser odometry's, ``IasmParams.odometry_scale``) they hold them."""
    params = IasmParams()
    motion = np.array([0.1, 0.0, 0.0])
    f1, f2 = _posters_pair(motion, params)
    R, t = camera_motion(motion, T_CAM_LASER)
    t_unit = t / np.linalg.norm(t)
    carried = float(np.linalg.norm(camera_motion(np.array([0.4, 0.0, 0.0]), T_CAM_LASER)[1]))
    found = {}
    for name, scale in (("carried", carried), ("own", float(np.linalg.norm(t)))):
        res, m = hiasm_step(f1, f2, R, t_unit, scale, CAM, T_CAM_LASER, params, np.random.default_rng(0))
        right = res is not None and np.linalg.norm(res.motion[:2] - motion[:2]) < 0.01
        found[name] = (_correct(m, motion).mean() if len(m.a) else 0.0, right)
    assert found["carried"][0] < 0.2
    assert not found["carried"][1]
    assert found["own"][0] > 0.9
    assert found["own"][1]


def test_dense_window_search_also_takes_the_right_period(repeating):
    """Fig. 5 with H-IASM's dense window search: the matches are the true ones."""
    world, tex = repeating
    params = IasmParams(dense_window=True)
    motion = np.array([0.3, 0.0, 0.0])
    f1 = _frame(world, tex, (0.0, 0.0, 0.0), params)
    f2 = _frame(world, tex, tuple(motion), params)
    R, t = camera_motion(motion, T_CAM_LASER)
    res, m = hiasm_step(
        f1, f2, R, t / np.linalg.norm(t), float(np.linalg.norm(t)), CAM, T_CAM_LASER, params,
        np.random.default_rng(0),
    )  # fmt: skip
    assert len(m.a) > 20
    assert _correct(m, motion).mean() > 0.9
    assert res is not None
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.01


def _true_pixels(f1, motion):
    """Where the true motion puts each return of f1 in the next image (NaN: not visible)."""
    c, s = np.cos(motion[2]), np.sin(motion[2])
    b = (f1.points - motion[:2]) @ np.array([[c, -s], [s, c]])
    P = np.column_stack([b, np.zeros(len(b))]) @ T_CAM_LASER[:3, :3].T + T_CAM_LASER[:3, 3]
    out = np.full((len(b), 2), np.nan)
    out[f1.visible] = CAM.project(P[f1.visible])
    return out, b


def test_dense_window_search_places_matches_between_the_returns():
    """On noise-free views of a textured wall, a step that puts no return of scan t+1 where
    a return of scan t was: the dense search finds each point on the wall to well under a
    millimetre; the best of scan t+1's returns (with the parabola) is a beam spacing's
    fraction off."""
    params = IasmParams()
    motion = np.array([0.1037, 0.0, 0.0])
    f1, f2 = _posters_pair(motion, params)
    pred, true_b = _true_pixels(f1, motion)
    dense = window_search(f1, f2, pred, CAM, T_CAM_LASER, params)
    beams = match_returns(f1, f2, pred, params.window_px, params.window_px)
    err_dense = np.linalg.norm(dense.b - true_b[dense.i1], axis=1)
    err_beams = np.linalg.norm(beams.b - true_b[beams.i1], axis=1)
    assert len(dense.i1) > 100
    assert np.median(err_dense) < 0.5e-3
    assert np.median(err_dense) < 0.5 * np.median(err_beams)
    # each match lies on scan t+1's wall (y = 1.5 m in the frame after a step along x)
    left = np.abs(dense.b[:, 1] - 1.5) < 0.05
    assert left.mean() > 0.9
    assert np.abs(dense.b[left, 1] - 1.5).max() < 1e-6


def test_dense_window_search_without_predictions_or_lines_finds_nothing():
    world = _world("posters")
    tex = world_textures(world, 0)
    params = IasmParams()
    f1 = _frame(world, tex, (0.0, 0.0, 0.0), params)
    f2 = _frame(world, tex, (0.1, 0.0, 0.0), params)
    none = np.full((len(f1.points), 2), np.nan)
    assert len(window_search(f1, f2, none, CAM, T_CAM_LASER, params).i1) == 0
    far = np.full((len(f1.points), 2), -500.0)  # every prediction far outside the image
    assert len(window_search(f1, f2, far, CAM, T_CAM_LASER, params).i1) == 0


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


def test_frames_are_moved_to_the_image_time_and_snapped_when_asked():
    world = _world("posters")
    tex = world_textures(world, 0)
    f_raw = _frame(world, tex, (0.0, 0.0, 0.0), IasmParams())
    T = np.array([[1.0, 0.0, 0.02], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    a0, step, ang = beam_angles(270.0, 0.25)
    segs = world.scan_segments()
    scan = Scan.from_uniform(a0, step, cast_scan(segs, ang, 30.0) + 0.004, 0.1, 30.0, 0.0)
    moved = make_frame(f_raw.gray, scan, CAM, T_CAM_LASER, IasmParams(), None, T)
    assert np.allclose(moved.points, scan.points[scan.valid] + [0.02, 0.0])
    snapped = make_frame(f_raw.gray, scan, CAM, T_CAM_LASER, IasmParams(snap_max_m=0.03), None, T)
    on = snapped.line_of >= 0
    assert np.abs(snapped.centres[on] - moved.centres[on]).max() < 1e-4
    assert not np.allclose(snapped.points, moved.points)


def test_iasm_recovers_a_small_step_on_texture():
    world = _world("bricks")
    tex = world_textures(world, 0)
    params = IasmParams()
    motion = np.array([0.08, 0.01, np.radians(2.0)])
    f1 = _frame(world, tex, (0.0, 0.0, 0.0), params)
    f2 = _frame(world, tex, tuple(motion), params)
    res, _ = iasm_step(f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0))
    assert res is not None
    assert res.inliers > 30
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.005
    assert abs(res.motion[2] - motion[2]) < np.radians(0.05)


def test_homography_prediction_is_the_returns_next_pixel(repeating):
    """Eq. (10): each return of a line lands where the true motion projects it."""
    world, tex = repeating
    params = IasmParams()
    motion = np.array([0.2, 0.05, np.radians(3.0)])
    f1 = _frame(world, tex, (0.0, 0.0, 0.0), params)
    R, t = camera_motion(motion, T_CAM_LASER)
    pred = homography_predictions(
        f1, R, t / np.linalg.norm(t), float(np.linalg.norm(t)), CAM, T_CAM_LASER[:3, :3]
    )
    ok = np.isfinite(pred[:, 0])
    assert ok.sum() > 50
    P2 = f1.cam[ok] @ R.T + t
    assert np.allclose(pred[ok], CAM.project(P2), atol=0.3)


def test_flat_walls_give_no_correspondences_and_the_step_fails():
    world = _world("plain")
    world = World(
        world.name, tuple(Surface(s.a, s.b, s.height_m, "plain") for s in world.surfaces), world.path, 0.4
    )
    tex = world_textures(world, 0)
    params = IasmParams()
    f1 = _frame(world, tex, (0.0, 0.0, 0.0), params)
    f2 = _frame(world, tex, (0.1, 0.0, 0.0), params)
    res, m = iasm_step(f1, f2, CAM, T_CAM_LASER, params, np.random.default_rng(0))
    assert res is None
    assert len(m.a) < params.min_correspondences


def test_metric_choice_from_the_angle_histogram():
    """Section III-C: one direction of lines (a corridor) -> image metric; a corner -> laser."""
    a0, step, ang = beam_angles(270.0, 0.25)
    corridor = np.array([[[-10, 1.5], [10, 1.5]], [[-10, -1.5], [10, -1.5]]], dtype=float)
    room = np.array(
        [[[3, -3], [3, 3]], [[3, 3], [-3, 3]], [[-3, 3], [-3, -3]], [[-3, -3], [3, -3]]], dtype=float
    )
    for segs, laser in ((corridor, False), (room, True)):
        scan = Scan.from_uniform(a0, step, cast_scan(segs, ang, 8.0), 0.1, 8.0, 0.0)
        assert laser_metric_wanted(extract_lines(scan), IasmParams()) is laser


def test_joint_polish_takes_the_walls_where_they_constrain_and_the_matches_where_not():
    # A featureless corridor: the walls fix the cross-corridor offset and the heading, not
    # the motion along it. Correspondences 1 cm off (biased) along and across: the polish
    # keeps the walls' answer across and takes the correspondences' along the corridor.
    u = np.linspace(-8, 8, 800)
    walls = np.vstack(
        [np.column_stack([u, np.full_like(u, -1.0)]), np.column_stack([u, np.full_like(u, 1.0)])]
    )
    truth = np.array([0.08, 0.02, 0.0])
    scan2 = walls - truth[:2]  # the same walls seen after the motion
    b = np.array([[2.0, 1.0], [-3.0, -1.0], [5.0, 1.0], [-6.0, -1.0]])
    a = b + truth[:2] + [0.01, 0.01]  # the correspondences' bias
    x = joint_polish(
        np.zeros(3), a, b, walls, scan2, IasmParams(), line_normals(walls, np.repeat([0, 1], 800))
    )
    assert x[0] == pytest.approx(0.09, abs=1e-3)  # along: the correspondences'
    assert x[1] == pytest.approx(0.02, abs=1e-4)  # across: the walls'
    assert x[2] == pytest.approx(0.0, abs=1e-5)


def _room_walls(n: int = 400) -> tuple[np.ndarray, np.ndarray]:
    """Returns on the four walls of a 10 x 4 m room (beam order per wall) and their labels."""
    u = np.linspace(0.0, 1.0, n)[:, None]
    corners = np.array([[-5.0, -2.0], [5.0, -2.0], [5.0, 2.0], [-5.0, 2.0], [-5.0, -2.0]])
    pts = [a + u * (b - a) for a, b in itertools.pairwise(corners)]
    return np.vstack(pts), np.repeat(np.arange(4), n)


def _moved(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """Points seen from ``pose`` (x, y, yaw) in their frame."""
    T = np.linalg.inv(se2(pose))
    out: np.ndarray = points @ T[:2, :2].T + T[:2, 2]
    return out


def test_keyframe_reference_aligns_scan_t1_with_an_older_scan():
    # The keyframe's scan, scan t 1.5 m on, scan t+1 a step further: the keyframe's
    # returns, put in scan t's frame, give the step as scan t's own would.
    walls, labels = _room_walls()
    T_key_t = np.array([1.5, 0.2, 0.1])
    step = np.array([0.1, 0.01, 0.02])
    n = len(walls)
    key = Frame(
        np.zeros((1, 1), np.uint8),
        walls,
        np.zeros((n, 3)),
        np.zeros((n, 2)),
        np.zeros(n, bool),
        np.zeros((n, 1), np.float32),
        [],
        labels,
        line_normals(walls, labels),
        np.zeros((n, 2)),
    )
    ref = keyframe_reference(key, se2(T_key_t))
    np.testing.assert_allclose(ref.points, _moved(walls, T_key_t), atol=1e-12)
    np.testing.assert_allclose(
        np.abs(np.einsum("ij,ij->i", ref.normals, line_normals(ref.points, labels))), 1.0
    )
    scan2 = _moved(walls, pose_of(se2(T_key_t) @ se2(step)))
    none = np.zeros((0, 2))
    x = joint_polish(
        step + np.array([0.02, -0.01, 0.01]), none, none, ref.points, scan2, IasmParams(), ref.normals
    )
    np.testing.assert_allclose(x, step, atol=1e-6)


def test_fallback_keeps_the_odometry_where_the_walls_leave_the_motion_open():
    # Along a featureless corridor the walls fix the offset across and the heading, not
    # the motion along: aligned with the keyframe, the fallback takes the walls' answer
    # across and the odometry's along.
    u = np.linspace(-8, 8, 800)
    walls = np.vstack(
        [np.column_stack([u, np.full_like(u, -1.0)]), np.column_stack([u, np.full_like(u, 1.0)])]
    )
    truth = np.array([0.1, 0.02, 0.0])
    odometry = np.array([0.12, 0.035, 0.002])
    none = np.zeros((0, 2))
    normals = line_normals(walls, np.repeat([0, 1], 800))
    x = joint_polish(odometry, none, none, walls, walls - truth[:2], IasmParams(), normals, odometry)
    assert x[0] == pytest.approx(0.12, abs=1e-3)  # along: the odometry's
    assert x[1] == pytest.approx(0.02, abs=1e-4)  # across: the walls'
    assert x[2] == pytest.approx(0.0, abs=1e-4)
    # Nothing in common with the keyframe: the odometry's motion, wherever it starts.
    far = walls + np.array([50.0, 0.0])
    x = joint_polish(np.zeros(3), none, none, walls, far, IasmParams(), normals, odometry)
    np.testing.assert_allclose(x, odometry, atol=1e-9)


def test_a_new_keyframe_past_its_distance_or_turn():
    p = IasmParams(keyframe_m=2.0, keyframe_deg=20.0)
    assert not new_keyframe(se2([1.9, 0.5, np.radians(19.0)]), p)
    assert new_keyframe(se2([1.9, 0.7, 0.0]), p)
    assert new_keyframe(se2([0.0, 0.0, np.radians(-21.0)]), p)
    assert new_keyframe(se2([0.0, 0.0, 0.0]), IasmParams(keyframe_m=0.0))


def test_joint_polish_leaves_out_returns_paired_across_a_corner():
    # Returns of scan t+1 on a surface scan t did not see, 8 cm behind one of its walls
    # near a corner: paired with that wall's line they pull the scan off and round; left
    # out (laser_reject_m) they do not.
    walls, labels = _room_walls()
    step = np.array([0.1, 0.0, 0.0])
    scan2 = _moved(walls, step)
    stray = _moved(np.column_stack([np.full(15, 5.08), np.linspace(-1.9, -1.5, 15)]), step)
    none = np.zeros((0, 2))
    normals = line_normals(walls, labels)
    data = np.vstack([scan2, stray])
    kept = joint_polish(step, none, none, walls, data, IasmParams(laser_reject_m=0.0), normals)
    left_out = joint_polish(step, none, none, walls, data, IasmParams(), normals)
    assert np.abs(kept[0] - step[0]) > 5e-4
    assert np.abs(np.degrees(kept[2] - step[2])) > 5e-3
    np.testing.assert_allclose(left_out, step, atol=1e-9)
