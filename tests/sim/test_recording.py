"""Simulated recordings of still moments: the chessboard's sheet, the board drawn over a
background, the sequence folder's still moments and stamps."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.calib.intrinsics import Board, detect_corners
from rigcal.camera import Camera
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.recordings.sequence import read_sequence
from rigcal.scan import Scan
from rigcal.sim.boards import chessboard_sheet, render_board
from rigcal.sim.recording import SCAN_PERIOD_S, StillMoment, write_still_recording


def test_the_sheet_holds_the_pattern_centred():
    img, origin = chessboard_sheet(4, 3, 0.1, (0.7, 0.6), 100.0)
    assert img.shape == (60, 70)
    # The pattern: (4 + 1) x (3 + 1) squares of 10 px, centred, the first one black.
    assert origin == pytest.approx((-0.2, -0.2))
    assert (img[:10, :] == 255).all()  # the 10 cm margin above
    assert img[15, 15] == 0
    assert img[15, 25] == 255
    assert ((img[10:50, 10:60] == 0).sum()) == 10 * 100


def test_a_board_over_a_background_is_found_where_it_was_put(tmp_path):
    import cv2

    camera = Camera.from_opencv(np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]]), np.zeros(5), 640, 480)
    texture, origin = chessboard_sheet(8, 6, 0.06, (0.6, 0.5), 500.0)
    T = make_T(rotvec_to_R([0.3, -0.2, 0.05]), [-0.2, -0.15, 1.6])
    background = np.full((480, 640), 90, np.uint8)
    img = render_board(camera, texture, (0.6, 0.5), T, origin, background)
    assert img[5, 5] == 90  # off the board: the background
    cv2.imwrite(str(tmp_path / "b.png"), img)
    det = detect_corners([tmp_path / "b.png"], Board(8, 6, 0.06))
    assert len(det.paths) == 1
    first = det.corners[0, 0, 0, :2]
    truth = camera.project((T @ np.array([0.0, 0.0, 0.0, 1.0]))[None, :3])[0]
    last = camera.project((T @ np.array([0.42, 0.30, 0.0, 1.0]))[None, :3])[0]
    # OpenCV may number the grid from either end.
    assert min(np.linalg.norm(first - truth), np.linalg.norm(first - last)) < 0.5


def test_a_recording_holds_each_moments_scans_and_moves_between(tmp_path):
    camera = Camera.from_opencv(np.array([[100.0, 0, 32], [0, 100, 24], [0, 0, 1]]), np.zeros(5), 64, 48)
    scans = tuple(Scan.from_uniform(-1.0, 0.01, np.full(200, 2.0 + 0.01 * j), 0.1, 30.0) for j in range(6))
    moments = [StillMoment(scans, np.full((48, 64, 3), 100 + 50 * k, np.uint8)) for k in range(2)]
    starts = write_still_recording(tmp_path / "seq", "r", moments, camera, np.eye(4))
    seq = read_sequence(tmp_path / "seq")
    t = np.array([s.stamp_s for s in seq.scans])
    assert np.all(np.diff(t) > 0)
    assert np.all(np.diff(seq.image_stamps_s) > 0)
    still = (t >= starts[1]) & (t < starts[1] + 6 * SCAN_PERIOD_S - 1e-9)
    assert still.sum() == 6
    assert np.allclose(
        [s.ranges_m[0] for s, k in zip(seq.scans, still, strict=True) if k], 2.0 + 0.01 * np.arange(6)
    )
    assert (tmp_path / "seq" / "rig.yaml").is_file()
