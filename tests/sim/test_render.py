"""Ray-cast rendering: surfaces land where the camera model projects them."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry import transform_points
from rigcal.sim.box_session import default_camera, default_T_cam_laser
from rigcal.sim.render import (
    BOX_BGR,
    LABEL_BOX,
    LABEL_CEILING,
    LABEL_FLOOR,
    LABEL_STAND,
    LABEL_WALLS,
    Room,
    Scene,
    pixel_bearings,
    render_scene,
)
from rigcal.targets.box import BoxTarget


def is_box_colour(bgr: np.ndarray) -> bool:
    """The box's orange, at any brightness (faces and outlines share its hue)."""
    b, g, r = (float(x) for x in bgr)
    return r > 40 and r > 1.6 * g and r > 3.0 * b


@pytest.fixture(scope="module")
def rendered():
    camera = default_camera()
    T = default_T_cam_laser()
    box = BoxTarget()
    # Room axes along the laser's, walls at laser x = 7, -5 and y = 3, -6; the box off to
    # the left where the lens distortion is strong.
    scene = Scene(Room(), room_pose=(1.0, -1.5, 0.0), box=box, box_pose=(1.8, 0.45, 0.35))
    image, labels = render_scene(camera, T, scene)
    return camera, T, scene, image, labels


def pixel_of(camera, T, point_laser) -> tuple[int, int]:
    q = camera.project(transform_points(T, [point_laser]))[0]
    assert camera.in_image(q[None])[0]
    return round(q[0]), round(q[1])


def test_image_shape_and_box_colour(rendered):
    camera, _, _, image, labels = rendered
    assert image.shape == (camera.height_px, camera.width_px, 3)
    assert image.dtype == np.uint8
    front = labels == LABEL_BOX
    assert front.sum() > 500
    assert all(is_box_colour(p) for p in image[front])
    assert is_box_colour(np.array(BOX_BGR))
    # Nothing but the box is box-coloured.
    box_any = (labels >= LABEL_BOX) & (labels < LABEL_BOX + 6)
    assert not any(is_box_colour(p) for p in image[~box_any])


@pytest.mark.parametrize(
    ("point", "label"),
    [
        ((1.8, -0.6, -0.4), LABEL_FLOOR),  # floor, right of the box
        ((7.0, -0.5, 1.0), LABEL_WALLS[0]),  # wall ahead, room x = +6
        ((6.0, 3.0, 0.3), LABEL_WALLS[2]),  # left wall, room y = +4.5
        ((6.5, 0.0, 2.2), LABEL_CEILING),
        ((1.8 - 0.075 * np.cos(0.35), 0.45 - 0.075 * np.sin(0.35), 0.0), LABEL_BOX),  # front face centre
        ((1.8, 0.45, -0.25), LABEL_STAND),
    ],
)
def test_surfaces_appear_where_the_camera_projects_them(rendered, point, label):
    camera, T, _, _, labels = rendered
    u, v = pixel_of(camera, T, point)
    assert labels[v, u] == label


def test_box_ends_are_on_the_box_edge(rendered):
    camera, T, scene, image, labels = rendered
    ends = scene.box.front_ends(*scene.box_pose)
    direction = (ends[1] - ends[0]) / np.linalg.norm(ends[1] - ends[0])
    for j, inward in ((0, direction), (1, -direction)):
        u, v = pixel_of(camera, T, ends[j])
        patch = labels[v - 1 : v + 2, u - 1 : u + 2]
        assert (patch == LABEL_BOX).any()
        # 2 cm inside the end, on the front face at laser height: box colour.
        ui, vi = pixel_of(camera, T, ends[j] + 0.02 * inward)
        assert is_box_colour(image[vi, ui])
        # 25 cm beyond the end: off the box.
        uo, vo = pixel_of(camera, T, ends[j] - 0.25 * inward)
        assert not is_box_colour(image[vo, uo])


def test_box_occludes_the_wall_behind(rendered):
    camera, T, _, _, labels = rendered
    # A point three times as far from the camera as the box's centre, on the same ray.
    cam_centre = np.linalg.inv(T)[:3, 3]
    u, v = pixel_of(camera, T, cam_centre + 3.0 * (np.array([1.8, 0.45, 0.0]) - cam_centre))
    assert LABEL_BOX <= labels[v, u] < LABEL_BOX + 6


def test_bearing_grid_is_cached_and_unit():
    camera = default_camera()
    b = pixel_bearings(camera)
    assert pixel_bearings(camera) is b
    assert b.shape == (camera.width_px * camera.height_px, 3)
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-5)
    assert not b.flags.writeable


def test_box_silhouette_matches_the_projected_corners(rendered):
    # The lens distortion moves the box's left end by about 5 px here: a renderer that
    # ignored it would be off by that much.
    camera, T, scene, _, labels = rendered
    corners = scene.box.faces(*scene.box_pose).reshape(-1, 3)
    q = camera.project(transform_points(T, corners))
    v, u = np.nonzero((labels >= LABEL_BOX) & (labels < LABEL_BOX + 6))
    np.testing.assert_allclose([u.min(), v.min()], q.min(axis=0), atol=1.5)
    np.testing.assert_allclose([u.max(), v.max()], q.max(axis=0), atol=1.5)
