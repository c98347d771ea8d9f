"""Feature tracks: SIFT keypoints followed by Lucas-Kanade with a forward-backward check."""

from __future__ import annotations

import numpy as np

from rigcal.geometry import rotvec_to_R
from rigcal.localize.tracks import FrameTracks, Tracker, TrackParams, common, track_sequence
from rigcal.sim.box_session import default_camera

CAM = default_camera()
DEPTH = 3.0


def _truth(px: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Where pixels of the first view of the wall z = DEPTH land in the second camera."""
    b = CAM.bearings(px)
    P = b * (DEPTH / b[:, 2:3])
    return CAM.project(P @ R.T + t)


def test_tracks_follow_the_true_image_motion_to_a_fifth_of_a_pixel(texture, wall_image):
    motions = [(rotvec_to_R([0.0, 0.01 * k, 0.0]), np.array([0.04 * k, 0.0, 0.08 * k])) for k in range(4)]
    images = [wall_image(R, t, DEPTH, texture) for R, t in motions]
    tracks = track_sequence(len(images), lambda i: images[i], CAM)
    assert len(tracks[0].ids) > 500
    for (R, t), tr in zip(motions[1:], tracks[1:], strict=True):
        ia, ib = common(tracks[0], tr)
        assert len(ia) > 0.8 * len(tracks[0].ids)
        err = np.linalg.norm(tr.pixels[ib] - _truth(tracks[0].pixels[ia], R, t), axis=1)
        assert np.median(err) < 0.2
        assert np.percentile(err, 95) < 0.6
        # Bearings are the camera model's, pixel for pixel.
        assert np.allclose(tr.bearings, CAM.bearings(tr.pixels))


def test_a_changed_region_loses_its_tracks_and_new_ones_start(texture, wall_image):
    a = wall_image(np.eye(3), np.zeros(3), DEPTH, texture)
    b = wall_image(np.eye(3), np.array([0.02, 0.0, 0.0]), DEPTH, texture)
    # Something else (a person walking past) covers the left half of the second image.
    b[:, : CAM.width_px // 2] = np.flipud(b[:, CAM.width_px // 2 :][:, : CAM.width_px // 2])
    tracker = Tracker(CAM, TrackParams(redetect_below=10_000))  # detect again every frame
    first = tracker.step(a)
    second = tracker.step(b)
    ia, ib = common(first, second)
    kept = second.pixels[ib]
    # Survivors are on the unchanged right half (a few pixels of slack at the border).
    assert kept[:, 0].min() > CAM.width_px // 2 - 8
    assert len(ia) > 0.3 * len(first.ids)
    new = ~np.isin(second.ids, first.ids)
    assert new.sum() > 50
    assert second.ids[new].min() > first.ids.max()
    assert tracker.detections == 2


def test_no_detection_while_enough_tracks_live(texture, wall_image):
    images = [wall_image(np.eye(3), np.array([0.01 * k, 0.0, 0.0]), DEPTH, texture) for k in range(5)]
    tracker = Tracker(CAM)
    for im in images:
        tracker.step(im)
    assert tracker.detections == 1


def test_a_blank_frame_ends_every_track():
    blank = np.full((CAM.height_px, CAM.width_px), 128, np.uint8)
    tracker = Tracker(CAM)
    tr = tracker.step(blank)
    assert len(tr.ids) == 0
    assert tr.bearings.shape == (0, 3)


def test_common_pairs_tracks_by_id():
    a = FrameTracks(np.array([1, 4, 7, 9]), np.zeros((4, 2)), np.zeros((4, 3)))
    b = FrameTracks(np.array([4, 9, 12]), np.zeros((3, 2)), np.zeros((3, 3)))
    ia, ib = common(a, b)
    assert a.ids[ia].tolist() == [4, 9]
    assert b.ids[ib].tolist() == [4, 9]
