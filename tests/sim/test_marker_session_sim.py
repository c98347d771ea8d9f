"""The marker session simulator: textures from the printed pages, faces where the truth
puts them, the V in the scan, determinism, tilted views."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.board.detect import plane_cut
from rigcal.geometry import transform_points
from rigcal.sim.marker_session import (
    TEXELS_PER_M,
    MarkerSpec,
    T_laser_face,
    _texture,
    generate_marker_session,
)
from rigcal.targets.marker import default_target, face_image


@pytest.fixture(scope="module")
def sim():
    return generate_marker_session(MarkerSpec(n_captures=3, seed=7))


def test_texture_is_the_printed_face():
    t = default_target()
    tex = _texture(t, 1)
    assert np.array_equal(tex.levels[0][:, :, 0], face_image(t, 1, TEXELS_PER_M))


def test_faces_are_rendered_where_the_truth_puts_them(sim):
    import cv2

    t = sim.spec.target
    for c in sim.captures:
        grey = cv2.cvtColor(c.image, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = cv2.aruco.ArucoDetector(
            cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
        ).detectMarkers(grey)
        assert ids is not None
        assert set(ids.ravel()) <= t.all_ids
        assert len(ids) >= 10
        for k in range(2):
            T = sim.T_cam_laser @ T_laser_face(t, c.T_laser_target, k)
            # Every marker found on face k lies inside the face's projected outline.
            outline = sim.camera.project(transform_points(T, np.column_stack([t.outline(k), np.zeros(4)])))
            for m, i in zip(corners, ids.ravel(), strict=True):
                if i in t.faces[k].ids:
                    centre = m.reshape(4, 2).mean(axis=0)
                    assert (
                        cv2.pointPolygonTest(outline.astype(np.float32), tuple(map(float, centre)), False) > 0
                    )


def test_the_scan_sees_the_v_on_the_faces(sim):
    t = sim.spec.target
    for c in sim.captures:
        for k in range(2):
            beams = c.face_beams[k]
            assert len(beams) >= 8
            cut = plane_cut(T_laser_face(t, c.T_laser_target, k), t.outline(k))
            p = c.scan.points[beams[c.scan.valid[beams]]]
            d = cut[1] - cut[0]
            n = np.array([-d[1], d[0]]) / np.linalg.norm(d)
            # 1 cm Gaussian range noise: within 5 sigma of the face's cut.
            assert np.abs((p - cut[0]) @ n).max() < 0.05


def test_views_are_tilted_unless_upright(sim):
    up = [abs(c.T_laser_target[2, 1]) for c in sim.captures]  # the edge's direction's z part
    assert min(up) < 0.999
    upright = generate_marker_session(MarkerSpec(n_captures=1, seed=7, upright=True))
    assert abs(upright.captures[0].T_laser_target[2, 1]) == pytest.approx(1.0)


def test_same_seed_same_session(sim):
    again = generate_marker_session(MarkerSpec(n_captures=1, seed=7))
    assert np.array_equal(again.captures[0].scan.ranges_m, sim.captures[0].scan.ranges_m)
    assert np.array_equal(again.captures[0].image, sim.captures[0].image)
