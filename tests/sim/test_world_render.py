"""Camera images of simulated worlds: geometry against the laser and the planes, occlusion,
textures, sensor effects."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from rigcal.camera import Camera
from rigcal.geometry import inv_T, make_T, transform_points
from rigcal.sim.box_session import default_camera, default_T_cam_laser
from rigcal.sim.drive import (
    DriveSpec,
    Motion,
    laser_poses_T,
    laser_stamps,
    side_T_cam_laser,
    simulate_scans,
)
from rigcal.sim.textures import _GENERATORS, REPEAT_PERIOD_M, TEXELS_PER_M, world_textures
from rigcal.sim.world import BUILTIN, TEXTURES, Surface, World
from rigcal.sim.world_render import (
    SURFACE_CEILING,
    SURFACE_FLOOR,
    CameraEffects,
    apply_effects,
    render_world,
)


@pytest.fixture(scope="module")
def cubicles():
    w = BUILTIN["cubicle-loop"]()
    return w, world_textures(w, seed=0)


def _point_segment(p, a, b):
    u = b - a
    s = np.clip((p - a) @ u / (u @ u), 0.0, 1.0)
    return np.linalg.norm(p - (a + s[:, None] * u), axis=1)


@pytest.mark.parametrize("T_cam_laser", [default_T_cam_laser(), side_T_cam_laser()], ids=["forward", "side"])
def test_laser_points_land_on_their_wall_at_their_depth(cubicles, T_cam_laser):
    w, tex = cubicles
    cam = default_camera()
    spec = DriveSpec(range_sigma_m=0.0, dropout_fraction=0.0)
    m = Motion(w, spec)
    stamps = laser_stamps(m, spec)[100::400][:4]
    poses = m.poses(stamps)
    checked = 0
    for scan, T_wl in zip(simulate_scans(w, poses, stamps, spec), laser_poses_T(w, poses), strict=True):
        frame = render_world(w, cam, T_wl @ inv_T(T_cam_laser), tex)
        p_laser = np.column_stack([scan.points[scan.valid], np.zeros(int(scan.valid.sum()))])
        p_cam = transform_points(T_cam_laser, p_laser)
        q = cam.project(p_cam)
        inside = cam.in_image(q, margin_px=2.0)
        px = np.rint(q[inside]).astype(int)
        p_world = transform_points(T_wl, p_laser[inside])[:, :2]
        wall = np.argmin([_point_segment(p_world, s.a, s.b) for s in w.surfaces], axis=0)
        labels = frame.surface[px[:, 1], px[:, 0]]
        # Away from the image of a surface's edge, the pixel shows the wall the laser hit.
        nb = np.stack([frame.surface[px[:, 1] + dv, px[:, 0] + du] for dv in (-2, 0, 2) for du in (-2, 0, 2)])
        clear = (nb == labels).all(axis=0)
        # The camera sits beside the laser: a few points the laser sees past an obstacle's
        # end are hidden from the camera by it (nearer than the point).
        depth = frame.depth_m[px[:, 1], px[:, 0]]
        z = p_cam[inside, 2]
        hidden = depth < 0.98 * z - 0.01
        assert hidden.mean() < 0.05
        clear &= ~hidden
        assert clear.sum() > 20
        np.testing.assert_array_equal(labels[clear], wall[clear])
        # z-depth within what moving (by at most half a pixel) to the nearest pixel centre
        # can change: the depth's variation to the neighbouring pixels.
        dnb = np.stack(
            [frame.depth_m[px[:, 1] + dv, px[:, 0] + du] for dv in (-1, 0, 1) for du in (-1, 0, 1)]
        )
        tol = np.abs(dnb - depth).max(axis=0) + 1e-3
        assert (np.abs(depth - z)[clear] <= tol[clear]).all()
        checked += int(clear.sum())
    assert checked > 200


def test_a_pixels_ray_meets_its_plane_at_the_rendered_depth(cubicles):
    w, tex = cubicles
    cam = default_camera()
    m = Motion(w, DriveSpec())
    T_wc = laser_poses_T(w, m.poses(np.array([7.3])))[0] @ inv_T(default_T_cam_laser())
    frame = render_world(w, cam, T_wc, tex)
    rng = np.random.default_rng(4)
    u = rng.integers(0, cam.width_px, 3000)
    v = rng.integers(0, cam.height_px, 3000)
    bear = cam.bearings(np.column_stack([u, v]).astype(float))
    depth = frame.depth_m[v, u].astype(float)
    p_world = transform_points(T_wc, bear * (depth / bear[:, 2])[:, None])
    lab = frame.surface[v, u]
    assert {SURFACE_FLOOR, SURFACE_CEILING} <= set(lab.tolist())
    assert (lab >= 0).sum() > 500
    np.testing.assert_allclose(p_world[lab == SURFACE_FLOOR, 2], 0.0, atol=1e-4)
    np.testing.assert_allclose(p_world[lab == SURFACE_CEILING, 2], tex.ceiling_height_m, atol=1e-4)
    for j in np.unique(lab[lab >= 0]):
        s = w.surfaces[j]
        p = p_world[lab == j]
        n = np.array([-(s.b - s.a)[1], (s.b - s.a)[0]]) / np.linalg.norm(s.b - s.a)
        np.testing.assert_allclose((p[:, :2] - s.a) @ n, 0.0, atol=2e-4)
        assert (p[:, 2] > -1e-4).all()
        assert (p[:, 2] < s.height_m + 1e-4).all()
        assert (_point_segment(p[:, :2], s.a, s.b) < 2e-4).all()


def test_a_low_partition_hides_the_wall_below_its_top_only():
    wall = Surface(np.array([4.0, -3.0]), np.array([4.0, 3.0]), 2.5, "posters")
    part = Surface(np.array([2.5, -1.0]), np.array([2.5, 1.0]), 1.0, "noise")
    w = World("test", (wall, part), np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]]), 0.4)
    cam = Camera.from_opencv(np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]]), [], 160, 120)
    R = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # looking along world +x
    frame = render_world(w, cam, make_T(R, [0.0, 0.0, 1.2]), world_textures(w, seed=0))
    col = frame.surface[:, 80]
    # Top to bottom: ceiling, the wall seen above the partition, the partition, the floor.
    runs = [int(col[0])] + [int(b) for a, b in itertools.pairwise(col) if a != b]
    assert runs == [SURFACE_CEILING, 0, 1, SURFACE_FLOOR]
    bear = cam.bearings(np.array([[80.0, v] for v in range(120)]))
    for lab, x in ((0, 4.0), (1, 2.5)):
        rows = np.flatnonzero(col == lab)
        np.testing.assert_allclose(frame.depth_m[rows, 80], x, rtol=1e-5)
        z = 1.2 - bear[rows, 1] / bear[rows, 2] * x  # camera y is down
        assert (z >= 0).all()
        assert (z <= w.surfaces[lab].height_m).all()
    # Where the partition ends, the wall is seen down to the floor.
    assert (frame.surface[:, 20] != 1).all()
    assert 0 in frame.surface[:, 20]


def test_textures_are_deterministic_and_cover_every_name():
    assert set(_GENERATORS) == set(TEXTURES)
    w = BUILTIN["calibration-room"]()
    a, b = world_textures(w, seed=3), world_textures(w, seed=3)
    for x, y in zip(a.walls.levels + a.floor.levels, b.walls.levels + b.floor.levels, strict=True):
        assert np.array_equal(x, y)
    assert not np.array_equal(world_textures(w, seed=4).walls.levels[0], a.walls.levels[0])


def _generate(name, seed=1, length_m=4.0, height_m=2.5):
    ppm = TEXELS_PER_M
    return _GENERATORS[name](np.random.default_rng(seed), int(height_m * ppm), int(length_m * ppm), ppm)


@pytest.mark.parametrize("name", sorted(TEXTURES))
def test_every_texture_fills_walls_of_any_length(name):
    """Whatever falls near a wall's end (a notice board wider than what is left) is cut at
    the end, for every seed: the wall's texture has the wall's size."""
    for seed in range(40):
        for length_m in (0.6, 1.3, 2.9):
            img = _generate(name, seed=seed, length_m=length_m)
            assert img.shape[:2] == (int(2.5 * TEXELS_PER_M), int(length_m * TEXELS_PER_M))


def test_repeating_is_exactly_periodic_and_plain_is_texture_poor():
    rep = _generate("repeating")
    p = int(REPEAT_PERIOD_M * TEXELS_PER_M)
    assert np.array_equal(rep[:, p:], rep[:, :-p])
    assert not np.array_equal(rep[:, p // 2 :], rep[:, : -(p // 2)])

    def detail(img):  # mean gradient magnitude above the skirting board
        g = cv2.cvtColor(img[: int(2.2 * TEXELS_PER_M)], cv2.COLOR_BGR2GRAY).astype(float)
        return np.abs(np.diff(g, axis=1)).mean() + np.abs(np.diff(g, axis=0)).mean()

    plain = detail(_generate("plain"))
    assert plain < 0.5
    for name in ("posters", "bricks", "doors", "noise", "signs"):
        assert detail(_generate(name)) > 4 * plain, name


def test_textured_corridor_frames_have_hundreds_of_sift_features():
    w = BUILTIN["corridor-loop"]()
    tex = world_textures(w, seed=0)
    m = Motion(w, DriveSpec())
    # In the stretch with doors on both walls (y = 4.75), looking along the corridor.
    stamps = np.arange(0.0, m.duration_s, 0.25)
    poses = m.poses(stamps)
    k = int(np.argmin(np.hypot(poses[:, 0] - 3.0, poses[:, 1] - 4.75)))
    T_wc = laser_poses_T(w, poses[k : k + 1])[0] @ inv_T(default_T_cam_laser())
    img = apply_effects(
        render_world(w, default_camera(), T_wc, tex).image, CameraEffects(), np.random.default_rng(0)
    )
    keypoints = cv2.SIFT_create().detect(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    assert len(keypoints) > 200


def test_camera_effects_noise_gain_blur():
    flat = np.full((200, 300, 3), 100, dtype=np.uint8)
    eff = CameraEffects(noise_sigma=2.0)
    a = apply_effects(flat, eff, np.random.default_rng(1))
    assert np.array_equal(a, apply_effects(flat, eff, np.random.default_rng(1)))
    assert np.std(a.astype(float)) == pytest.approx(2.0, rel=0.05)
    assert np.mean(a.astype(float)) == pytest.approx(100.0, abs=0.05)
    g = apply_effects(flat, CameraEffects(noise_sigma=0.0), np.random.default_rng(1), gain=1.5)
    assert (g == 150).all()
    step = np.zeros((50, 50, 3), dtype=np.uint8)
    step[:, 25:] = 200
    blurred = apply_effects(step, CameraEffects(noise_sigma=0.0, blur_sigma_px=2.0), np.random.default_rng(1))
    assert 0 < blurred[0, 24, 0] < 200
    assert blurred[0, 0, 0] == 0
