"""Synthetic box-target sessions: geometry, picking-file round trip, determinism, writing."""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np
import pytest

from rigcal.calib.box.picks import read_picks
from rigcal.calib.truth import read_truth
from rigcal.camera import read_camera
from rigcal.errors import OutputError
from rigcal.geometry import transform_points
from rigcal.lines import extract_lines
from rigcal.scan import read_scan
from rigcal.sim import box_session
from rigcal.sim.box_session import (
    SessionSpec,
    default_camera,
    default_T_cam_laser,
    generate_session,
    session_observations,
    write_session,
)
from rigcal.sim.render import render_image
from rigcal.targets.box import BoxTarget


@pytest.fixture(scope="module")
def session():
    return generate_session(SessionSpec(n_captures=6, seed=3))


@pytest.fixture(scope="module")
def written(session, tmp_path_factory):
    folder = tmp_path_factory.mktemp("w") / "session"
    write_session(session, folder, render_images=False)
    return folder


def is_box_colour(bgr: np.ndarray) -> bool:
    b, g, r = (float(x) for x in bgr)
    return r > 40 and r > 1.6 * g and r > 3.0 * b


def incidence_deg(ends: np.ndarray) -> float:
    d = ends[1] - ends[0]
    normal = np.array([d[1], -d[0]]) / np.linalg.norm(d)
    centre = ends.mean(axis=0)
    return float(np.degrees(np.arccos(abs(normal @ centre) / np.linalg.norm(centre))))


# --- geometry -----------------------------------------------------------------------------
def test_true_ends_project_onto_the_true_pixels(session):
    T = default_T_cam_laser()
    np.testing.assert_array_equal(session.T_cam_laser, T)
    for c in session.captures:
        ends3 = np.column_stack([c.true_laser_ends, np.zeros(2)])
        q = session.camera.project(np.ascontiguousarray(ends3 @ T[:3, :3].T + T[:3, 3]))
        np.testing.assert_allclose(c.true_pixels, q, atol=1e-9)
        assert session.camera.in_image(c.picked_pixels, 5.0).all()
        # Not a wrong pick: within 5 sigma, at 0.1 px resolution.
        assert np.abs(c.picked_pixels - c.true_pixels).max() < 5 * session.spec.pick_sigma_px
        np.testing.assert_array_equal(c.picked_pixels, np.round(c.picked_pixels, 1))


def test_true_ends_are_the_box_face_ends(session):
    box = session.spec.box
    for c in session.captures:
        ends = box.front_ends(*c.box_pose)
        # Same two points, possibly in the other order.
        same = np.allclose(ends, c.true_laser_ends) or np.allclose(ends[::-1], c.true_laser_ends)
        assert same
        assert np.linalg.norm(c.true_laser_ends[1] - c.true_laser_ends[0]) == pytest.approx(box.width_m)
        assert incidence_deg(c.true_laser_ends) <= session.spec.max_incidence_deg + 1e-6


def test_end_order_follows_beam_angle(session):
    # End 0 is at the smaller beam angle, and the chosen segment starts there (picks.py).
    for c in session.captures:
        a = np.arctan2(c.true_laser_ends[:, 1], c.true_laser_ends[:, 0])
        assert a[0] < a[1]
        seg = extract_lines(c.scan)[c.segment_id]
        first, last = c.scan.angles_rad[seg.indices[0]], c.scan.angles_rad[seg.indices[-1]]
        step = np.radians(session.spec.angle_increment_deg)
        assert abs(first - a[0]) < 2.5 * step
        assert abs(last - a[1]) < 2.5 * step


def test_face_returns_lie_on_the_true_face_within_noise(session):
    sigma = session.spec.range_sigma_m
    residuals = []
    for c in session.captures:
        seg = extract_lines(c.scan)[c.segment_id]
        e0, e1 = c.true_laser_ends
        n = np.array([-(e1 - e0)[1], (e1 - e0)[0]]) / np.linalg.norm(e1 - e0)
        residuals.append((np.asarray(seg.points) - e0) @ n)
    r = np.concatenate(residuals)
    # Returns are noisy along the beam; across the face that is sigma * cos(incidence).
    assert 0.4 * sigma < np.std(r) < 1.2 * sigma
    assert abs(np.mean(r)) < 0.3 * sigma


def test_noiseless_face_returns_are_exact():
    spec = SessionSpec(n_captures=3, pick_sigma_px=0.0, range_sigma_m=0.0, dropout_fraction=0.0, seed=4)
    sess = generate_session(spec)
    for c, o in zip(sess.captures, session_observations(sess), strict=True):
        np.testing.assert_array_equal(c.picked_pixels, np.round(c.true_pixels, 1))
        e0, e1 = c.true_laser_ends
        n = np.array([-(e1 - e0)[1], (e1 - e0)[0]]) / np.linalg.norm(e1 - e0)
        off = np.abs((o.side_points - e0) @ n)
        # Ranges are kept to 0.1 mm; line extraction may add a return from the box's side at
        # the corner, as the first or last.
        assert (off[1:-1] < 2e-4).all()
        assert (off[[0, -1]] < 0.02).all()
        # Without noise the derived ends are within a beam gap of the true ends.
        gap = np.linalg.norm(e0) * np.radians(spec.angle_increment_deg) / np.cos(np.radians(50))
        assert np.linalg.norm(o.laser_endpoints - c.true_laser_ends, axis=1).max() < 1.5 * gap


def test_chosen_segment_ends_are_near_the_true_ends(session):
    for c, o in zip(session.captures, session_observations(session), strict=True):
        assert o.name == c.name
        err = np.linalg.norm(o.laser_endpoints - c.true_laser_ends, axis=1)
        assert err.max() < 0.05
        np.testing.assert_array_equal(o.image_endpoints_px, c.picked_pixels)


def test_scan_matches_the_spec(session):
    spec = session.spec
    for c in session.captures:
        assert len(c.scan.angles_rad) == 1081
        assert c.scan.angles_rad[0] == pytest.approx(np.radians(-135.0))
        assert c.scan.angles_rad[-1] == pytest.approx(np.radians(135.0))
        assert c.scan.range_max_m == spec.range_max_m
        # Closed room: only dropouts are invalid (1%).
        assert 0.95 < c.scan.valid.mean() <= 1.0


def test_placements_spread_over_distance_and_bearing():
    sess = generate_session(SessionSpec(n_captures=10, seed=5))
    centres = np.array([c.true_laser_ends.mean(axis=0) for c in sess.captures])
    dist = np.linalg.norm(centres, axis=1)
    lo, hi = sess.spec.distance_m
    assert dist.min() < lo + 0.2 * (hi - lo)
    assert dist.max() > hi - 0.2 * (hi - lo)
    bearing = np.degrees(np.arctan2(centres[:, 1], centres[:, 0]))
    assert bearing.max() - bearing.min() > 20.0
    inc = [incidence_deg(c.true_laser_ends) for c in sess.captures]
    assert max(inc) > 25.0
    # Every corner of the box inside the image with margin.
    for c in sess.captures:
        corners = sess.spec.box.faces(*c.box_pose).reshape(-1, 3)
        q = sess.camera.project(transform_points(sess.T_cam_laser, corners))
        assert sess.camera.in_image(q, sess.spec.image_margin_px).all()


def test_wrong_picks_are_gross_and_recorded():
    sess = generate_session(SessionSpec(n_captures=8, wrong_pick_fraction=0.5, seed=6))
    wrong = [c for c in sess.captures if c.is_wrong_pick]
    assert len(wrong) == 4
    for c in sess.captures:
        err = np.linalg.norm(c.picked_pixels - c.true_pixels, axis=1)
        if not c.is_wrong_pick:
            assert c.wrong_pick_kind == ""
            assert err.max() < 5.0
        elif c.wrong_pick_kind == "swapped":
            np.testing.assert_allclose(c.picked_pixels[::-1], c.true_pixels, atol=5.0)
        else:
            assert err.max() > 10.0
        assert sess.camera.in_image(c.picked_pixels).all()


def test_other_box_and_camera():
    K = np.array([[400.0, 0, 399.5], [0, 400.0, 299.5], [0, 0, 1]])
    from rigcal.camera import Camera

    cam = Camera.from_opencv(K, [], 800, 600)
    spec = SessionSpec(n_captures=3, seed=7, box=BoxTarget(width_m=0.8, depth_m=0.1, height_m=0.05))
    sess = generate_session(spec, camera=cam)
    assert sess.camera is cam
    for c in sess.captures:
        assert np.linalg.norm(c.true_laser_ends[1] - c.true_laser_ends[0]) == pytest.approx(0.8)


def test_bad_spec_is_refused():
    with pytest.raises(ValueError, match="wrong_pick_fraction"):
        SessionSpec(wrong_pick_fraction=1.5)
    with pytest.raises(ValueError, match="distance_m"):
        SessionSpec(distance_m=(3.0, 2.0))


# --- rendering a capture ----------------------------------------------------------------
def test_rendered_capture_shows_the_box_at_the_picked_ends(session):
    c = session.captures[0]
    img = render_image(session.camera, session.T_cam_laser, session.scene(c))
    e0, e1 = c.true_laser_ends
    along = (e1 - e0) / np.linalg.norm(e1 - e0)
    for j, inward in ((0, along), (1, -along)):
        u, v = np.round(c.true_pixels[j]).astype(int)
        assert any(is_box_colour(p) for p in img[v - 1 : v + 2, u - 1 : u + 2].reshape(-1, 3))
        q = session.camera.project(
            transform_points(session.T_cam_laser, [c.true_laser_ends[j] + 0.02 * inward])
        )
        ui, vi = np.round(q[0]).astype(int)
        assert is_box_colour(img[vi, ui])
    # Well above the box: not box-coloured.
    corners = session.spec.box.faces(*c.box_pose).reshape(-1, 3)
    q = session.camera.project(transform_points(session.T_cam_laser, corners))
    u_mid, v_top = int(q[:, 0].mean()), int(q[:, 1].min())
    assert v_top > 40
    assert not is_box_colour(img[v_top - 30, u_mid])


# --- files --------------------------------------------------------------------------------
def test_written_session_reads_back_identically(session, written):
    files = sorted(p.relative_to(written).as_posix() for p in written.rglob("*") if p.is_file())
    names = [c.name for c in session.captures]
    assert files == sorted(
        [".rigcal-output", "camera.yaml", "picks.yaml", "truth.yaml"]
        + [f"scans/{n}.yaml" for n in names]
        + [f"images/{n}.png" for n in names]
    )
    picks = read_picks(written / "picks.yaml")
    expected = session_observations(session, folder=written)
    assert len(picks.observations) == len(expected)
    for a, b in zip(picks.observations, expected, strict=True):
        assert (a.capture, a.name, a.scan_path, a.image_path, a.beam_step_rad) == (
            b.capture,
            b.name,
            b.scan_path,
            b.image_path,
            b.beam_step_rad,
        )
        for field in ("laser_endpoints", "side_points", "side_beams", "image_endpoints_px"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    np.testing.assert_allclose(read_truth(written / "truth.yaml"), session.T_cam_laser, atol=1e-11)
    cam = read_camera(written / "camera.yaml")
    np.testing.assert_allclose(cam.intrinsics, default_camera().intrinsics)
    scan = read_scan(written / "scans" / f"{names[0]}.yaml")
    np.testing.assert_array_equal(scan.ranges_m, session.captures[0].scan.ranges_m)


def test_picking_file_text(session, written):
    text = (written / "picks.yaml").read_text()
    assert text.startswith("# rigcal picking file")
    assert "Regenerate with: rigcal simulate box-session -o SESSION --seed 3 --captures 6" in text
    c = session.captures[1]
    assert f"laser_side: {{segment: {c.segment_id}}}" in text
    (u0, v0), (u1, v1) = c.picked_pixels
    assert f"image_endpoints_px: [[{u0:.1f}, {v0:.1f}], [{u1:.1f}, {v1:.1f}]]" in text


def test_same_seed_same_bytes_other_seed_differs(tmp_path):
    spec = SessionSpec(n_captures=3, seed=11, wrong_pick_fraction=0.4)
    a = write_session(generate_session(spec), tmp_path / "a", render_images=False)
    b = write_session(generate_session(spec), tmp_path / "b", render_images=False)
    c = write_session(generate_session(replace(spec, seed=12)), tmp_path / "c", render_images=False)
    for rel in ("picks.yaml", "truth.yaml", "camera.yaml", "scans/cap00.yaml", "scans/cap02.yaml"):
        assert (a / rel).read_bytes() == (b / rel).read_bytes(), rel
    assert (a / "picks.yaml").read_bytes() != (c / "picks.yaml").read_bytes()
    assert (a / "scans/cap00.yaml").read_bytes() != (c / "scans/cap00.yaml").read_bytes()
    assert "wrong_picks" in (a / "truth.yaml").read_text()


def test_refuses_existing_folder_unless_forced(session, tmp_path):
    folder = tmp_path / "s"
    folder.mkdir()
    (folder / "keep.txt").write_text("mine")
    with pytest.raises(OutputError, match="exists"):
        write_session(session, folder, render_images=False)
    assert os.listdir(tmp_path) == ["s"]
    assert (folder / "keep.txt").read_text() == "mine"
    with pytest.raises(OutputError, match="not written by rigcal"):
        write_session(session, folder, force=True, render_images=False)
    assert (folder / "keep.txt").read_text() == "mine"
    (folder / "keep.txt").unlink()
    write_session(session, folder, render_images=False, force=True)  # empty: nothing to lose
    (folder / "extra.txt").write_text("written after")
    write_session(session, folder, force=True, render_images=False)  # rigcal's: replaced whole
    assert not (folder / "extra.txt").exists()
    assert (folder / "picks.yaml").is_file()
    assert os.listdir(tmp_path) == ["s"]  # no temporary or old folder left behind
    (tmp_path / "f").write_text("a file")
    with pytest.raises(OutputError, match="not a folder"):
        write_session(session, tmp_path / "f", force=True, render_images=False)


def test_failed_write_leaves_nothing(session, tmp_path, monkeypatch):
    def broken(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(box_session, "_png", broken)
    with pytest.raises(OutputError, match="No space left"):
        write_session(session, tmp_path / "s")
    assert os.listdir(tmp_path) == []


def test_rendered_images_are_written(tmp_path):
    import cv2

    sess = generate_session(SessionSpec(n_captures=1, seed=8))
    folder = write_session(sess, tmp_path / "s")
    img = cv2.imread(str(folder / "images" / "cap00.png"))
    assert img.shape == (480, 640, 3)
    np.testing.assert_array_equal(
        img, render_image(sess.camera, sess.T_cam_laser, sess.scene(sess.captures[0]))
    )
