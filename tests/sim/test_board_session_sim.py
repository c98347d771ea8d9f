"""Synthetic board sessions: determinism, true geometry, the written folder and its read-back."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.calib.board.session import board_points, read_board_session
from rigcal.calib.truth import read_truth
from rigcal.camera import read_camera
from rigcal.errors import OutputError
from rigcal.geometry import transform_points
from rigcal.lines import LineParams, extract_lines
from rigcal.scan import read_scan
from rigcal.sim.board_session import BoardSpec, T_cam_board, generate_board_session, write_board_session
from rigcal.sim.box_session import default_T_cam_laser

SPEC = BoardSpec(n_captures=8, seed=11)


@pytest.fixture(scope="module")
def sim():
    return generate_board_session(SPEC)


@pytest.fixture(scope="module")
def written(sim, tmp_path_factory):
    folder = tmp_path_factory.mktemp("w") / "board"
    write_board_session(sim, folder)
    return folder


def segment_points(sim, capture) -> np.ndarray:
    """(M, 3) the returns of the capture's board segment, laser frame."""
    seg = extract_lines(capture.scan, LineParams.for_range_noise(sim.spec.range_sigma_m))[capture.segment_id]
    return np.column_stack([seg.points, np.zeros(len(seg.points))])


# --- determinism ---------------------------------------------------------------------------------
def test_same_seed_gives_the_same_session(sim):
    again = generate_board_session(SPEC)
    assert len(again.captures) == len(sim.captures) == SPEC.n_captures
    for a, b in zip(sim.captures, again.captures, strict=True):
        assert a.name == b.name
        assert a.segment_id == b.segment_id
        np.testing.assert_array_equal(a.corners_px, b.corners_px)
        np.testing.assert_array_equal(a.scan.ranges_m, b.scan.ranges_m)
        np.testing.assert_array_equal(a.T_laser_board, b.T_laser_board)


def test_another_seed_gives_another_session(sim):
    other = generate_board_session(BoardSpec(n_captures=2, seed=12))
    for a, b in zip(sim.captures, other.captures, strict=False):
        assert not np.array_equal(a.corners_px, b.corners_px)
        assert not np.array_equal(a.scan.ranges_m, b.scan.ranges_m)


# --- geometry ------------------------------------------------------------------------------------
def test_board_segment_returns_lie_on_the_true_board_plane(sim):
    sigma = sim.spec.range_sigma_m
    off = []
    for c in sim.captures:
        pts = transform_points(sim.T_cam_laser, segment_points(sim, c))
        T = T_cam_board(sim, c)
        off.append((pts - T[:3, 3]) @ T[:3, 2])
    off = np.concatenate(off)
    # A return is off the plane by its range error times the cosine of its incidence: never
    # more than 5 sigma for a few hundred returns (p ~ 6e-7 each), and an RMS under sigma.
    assert np.abs(off).max() < 5 * sigma
    assert np.sqrt(np.mean(off**2)) < sigma


def test_board_segment_returns_lie_within_the_board(sim):
    b = sim.spec.board
    w, h, m = (b.width_n - 1) * b.spacing_m, (b.height_n - 1) * b.spacing_m, sim.spec.sheet_margin_m
    for c in sim.captures:
        xy = transform_points(np.linalg.inv(c.T_laser_board), segment_points(sim, c))[:, :2]
        # The board's outline is the corner grid plus its margin; 5 cm for range noise along
        # grazing beams.
        assert np.all(xy[:, 0] > -m - 0.05)
        assert np.all(xy[:, 0] < w + m + 0.05)
        assert np.all(xy[:, 1] > -m - 0.05)
        assert np.all(xy[:, 1] < h + m + 0.05)


def test_corners_are_the_true_projection_inside_the_image(sim):
    np.testing.assert_array_equal(sim.T_cam_laser, default_T_cam_laser())
    for c in sim.captures:
        true_px = sim.camera.project(transform_points(T_cam_board(sim, c), board_points(sim.spec.board)))
        assert sim.camera.in_image(true_px, 15.0).all()
        assert sim.camera.in_image(c.corners_px).all()
        # Pixel noise: within 5 sigma plus the 0.005 px of rounding to 0.01 px.
        assert np.abs(c.corners_px - true_px).max() < 5 * sim.spec.corner_sigma_px + 0.005
        np.testing.assert_array_equal(c.corners_px, np.round(c.corners_px, 2))


def test_t_cam_board_is_the_laser_pose_composed(sim):
    c = sim.captures[3]
    np.testing.assert_allclose(T_cam_board(sim, c), sim.T_cam_laser @ c.T_laser_board, atol=1e-15)


# --- writing -------------------------------------------------------------------------------------
def test_written_folder_holds_the_session(written):
    assert {p.name for p in written.iterdir()} == {
        ".rigcal-output",
        "camera.yaml",
        "scans",
        "board_session.yaml",
        "truth.yaml",
    }
    assert sorted(p.name for p in (written / "scans").iterdir()) == [f"cap{i:02d}.yaml" for i in range(8)]


def test_written_session_reads_back_the_same(sim, written):
    doc = yaml.safe_load((written / "board_session.yaml").read_text())
    assert doc["method"] == "board"
    assert doc["board"] == {"corners_x": 8, "corners_y": 6, "spacing_m": 0.06, "corner_sigma_px": 0.3}
    for entry, c in zip(doc["captures"], sim.captures, strict=True):
        assert entry["name"] == c.name
        assert entry["laser_side"] == {"segment": c.segment_id}
        np.testing.assert_allclose(entry["corners_px"], c.corners_px, atol=1e-9)
        np.testing.assert_array_equal(read_scan(written / entry["scan"]).ranges_m, c.scan.ranges_m)
    np.testing.assert_allclose(read_truth(written / "truth.yaml"), sim.T_cam_laser, atol=1e-11)
    cam = read_camera(written / "camera.yaml")
    np.testing.assert_allclose(cam.intrinsics, sim.camera.intrinsics)


def test_written_session_resolves_to_the_true_board_poses(sim, written):
    s = read_board_session(written / "board_session.yaml", corner_sigma_px=SPEC.corner_sigma_px)
    assert [o.name for o in s.observations] == [c.name for c in sim.captures]
    for T, c in zip(s.T_cam_board, sim.captures, strict=True):
        px = sim.camera.project(transform_points(T, board_points(SPEC.board)))
        # The board poses reproject onto the written corners to within their noise.
        assert np.sqrt(np.mean(np.sum((px - c.corners_px) ** 2, axis=1))) < 2 * SPEC.corner_sigma_px
        T_true = T_cam_board(sim, c)
        # Normals within 2 deg (0.3 px of corner noise on a board up to 3 m away).
        assert np.degrees(np.arccos(min(1.0, float(T[:3, 2] @ T_true[:3, 2])))) < 2.0


def test_write_refuses_an_existing_folder_without_force(sim, tmp_path):
    folder = tmp_path / "board"
    folder.mkdir()
    (folder / "keep.txt").write_text("keep me")
    with pytest.raises(OutputError, match="exists"):
        write_board_session(sim, folder)
    assert [p.name for p in folder.iterdir()] == ["keep.txt"]
    with pytest.raises(OutputError, match="not written by rigcal"):
        write_board_session(sim, folder, force=True)
    (folder / "keep.txt").unlink()
    write_board_session(sim, folder, force=True)
    assert (folder / "board_session.yaml").is_file()
