"""Feature tracks: SIFT keypoints followed by Lucas-Kanade with a forward-backward check."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry import rotvec_to_R
from rigcal.localize.tracks import FrameTracks, Tracker, TrackParams, common, equalized, track_sequence
from rigcal.sim.box_session import default_camera

CAM = default_camera()
DEPTH = 3.0


def _truth(px: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Where pixels of the first view of the wall z = DEPTH land in the second camera."""
    b = CAM.bearings(px)
    P = b * (DEPTH / b[:, 2:3])
    return CAM.project(P @ R.T + t)


@pytest.mark.parametrize("detector", ["sift", "shi-tomasi"])
def test_tracks_follow_the_true_image_motion_to_a_fifth_of_a_pixel(texture, wall_image, detector):
    motions = [(rotvec_to_R([0.0, 0.01 * k, 0.0]), np.array([0.04 * k, 0.0, 0.08 * k])) for k in range(4)]
    images = [wall_image(R, t, DEPTH, texture) for R, t in motions]
    tracks = track_sequence(images, CAM, TrackParams(detector=detector))
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
    a = FrameTracks(np.array([1, 4, 7, 9]), np.zeros((4, 2)), _no_bearings)
    b = FrameTracks(np.array([4, 9, 12]), np.zeros((3, 2)), _no_bearings)
    ia, ib = common(a, b)
    assert a.ids[ia].tolist() == [4, 9]
    assert b.ids[ib].tolist() == [4, 9]


def _periodic_frames(period: int, shifts: list[int]) -> list[np.ndarray]:
    """A texture repeating every ``period`` pixels across, moved right by each shift
    (pixels, from the first frame)."""
    import cv2

    rng = np.random.default_rng(5)
    tile = cv2.GaussianBlur(rng.uniform(0, 255, (CAM.height_px, period)).astype(np.float32), (0, 0), 2.0)
    wall = np.tile(tile, (1, CAM.width_px // period + 2))
    return [np.clip(np.roll(wall, s, axis=1)[:, : CAM.width_px], 0, 255).astype(np.uint8) for s in shifts]


def test_prediction_follows_motion_past_a_repeating_patterns_half_period():
    # The image motion grows by 8 px per frame to 40 px, past half the 64 px period: from
    # a standing start Lucas-Kanade takes the nearer copy of the pattern (24 px back);
    # started where each track's last displacement takes it, it follows the true motion.
    steps = [0, 8, 16, 24, 32, 40]
    shifts = np.cumsum(steps).tolist()
    frames = _periodic_frames(64, shifts)
    right = {}
    for predict in (True, False):
        tracker = Tracker(CAM, TrackParams(predict=predict))
        tracks = [tracker.step(f) for f in frames]
        ia, ib = common(tracks[-2], tracks[-1])
        moved = tracks[-1].pixels[ib, 0] - tracks[-2].pixels[ia, 0]
        right[predict] = np.mean(np.abs(moved - steps[-1]) < 0.5) * len(ia) / len(tracks[0].ids)
    assert right[True] > 0.8
    assert right[False] < 0.2


def test_a_new_track_starts_from_its_neighbours_displacement():
    # The first frame's left half is blank, so the tracks found there in the second frame
    # are new when the motion jumps from 20 to 40 px, past half the 64 px period: they
    # start from their neighbours' 20 px (a standing start takes the copy 24 px back).
    frames = _periodic_frames(64, [0, 20, 60])
    frames[0][:, : CAM.width_px // 2] = 128
    tracker = Tracker(CAM, TrackParams(redetect_below=10_000, redetect_fraction=2.0))  # SIFT every frame
    tracks = [tracker.step(f) for f in frames]
    ia, ib = common(tracks[1], tracks[2])
    born = ~np.isin(tracks[1].ids[ia], tracks[0].ids)
    moved = tracks[2].pixels[ib, 0] - tracks[1].pixels[ia, 0]
    assert born.sum() > 100
    assert np.mean(np.abs(moved[born] - 40) < 0.5) > 0.9


def test_an_unknown_detector_is_refused():
    with pytest.raises(ValueError, match=r"detector must be one of \('sift', 'shi-tomasi'\), not 'orb'"):
        TrackParams(detector="orb")


def _no_bearings(px):
    raise AssertionError("bearings are not needed to pair tracks")


def test_bearings_are_unprojected_once_when_first_asked_for():
    calls = []

    def unproject(px):
        calls.append(len(px))
        return np.column_stack([px, np.ones(len(px))]) / np.sqrt((px**2).sum(axis=1) + 1)[:, None]

    f = FrameTracks(np.arange(3), np.array([[0.0, 0.0], [1.0, 0.0], [0.0, -1.0]]), unproject)
    assert calls == []
    np.testing.assert_allclose(f.bearings[1], [np.sqrt(0.5), 0.0, np.sqrt(0.5)])
    assert f.bearings is f.bearings
    assert calls == [3]


def _with_gain(image: np.ndarray, gain: float) -> np.ndarray:
    """The frame an exposure gain records (a camera's automatic exposure between frames)."""
    return np.clip(np.round(image.astype(float) * gain), 0, 255).astype(np.uint8)


def test_clahe_takes_an_exposure_gain_out_of_the_frame(texture, wall_image):
    a = (wall_image(np.eye(3), np.zeros(3), DEPTH, texture).astype(float) * 0.7).astype(np.uint8)
    b = _with_gain(a, 1.3)
    raw = np.abs(b.astype(float) - a).mean()
    p = TrackParams(equalize="clahe")
    eq = np.abs(equalized(b, p).astype(float) - equalized(a, p)).mean()
    assert raw > 20.0
    assert eq < 0.1 * raw
    assert equalized(a, TrackParams(equalize="none")) is a  # as do "none" and "gain"
    assert equalized(a, TrackParams(equalize="gain")) is a


def test_tracks_hold_through_exposure_jumps_with_clahe(texture, wall_image):
    """A 20 % gain step each frame while the camera moves: the patch check drops the
    raw frames' tracks; equalized, the tracks stay and follow the true motion."""
    motions = [(rotvec_to_R([0.0, 0.01 * k, 0.0]), np.array([0.04 * k, 0.0, 0.08 * k])) for k in range(4)]
    gains = [0.7, 0.84, 0.7, 0.84]
    images = [
        _with_gain(wall_image(R, t, DEPTH, texture), g) for (R, t), g in zip(motions, gains, strict=True)
    ]
    kept = {}
    for equalize in ("none", "clahe"):
        p = TrackParams(equalize=equalize)
        tracks = track_sequence([equalized(im, p) for im in images], CAM, p)
        ia, ib = common(tracks[0], tracks[-1])
        kept[equalize] = len(ia) / len(tracks[0].ids)
        if equalize == "clahe":
            R, t = motions[-1]
            err = np.linalg.norm(tracks[-1].pixels[ib] - _truth(tracks[0].pixels[ia], R, t), axis=1)
            assert np.median(err) < 0.2
    assert kept["clahe"] > 0.8
    assert kept["clahe"] > kept["none"] + 0.2


def test_a_bad_equalizer_or_clip_is_refused():
    with pytest.raises(ValueError, match=r"equalize must be one of \(.none., .gain., .clahe.\), not .hist."):
        TrackParams(equalize="hist")
    with pytest.raises(ValueError, match=r"clahe_clip in \(0, 100\], not 0"):
        TrackParams(clahe_clip=0.0)


def test_gain_between_two_frames_is_measured_on_the_points_they_share(texture, wall_image):
    from rigcal.localize.tracks import gain_between

    a = _with_gain(wall_image(np.eye(3), np.zeros(3), DEPTH, texture), 0.7)
    R, t = rotvec_to_R([0.0, 0.01, 0.0]), np.array([0.04, 0.0, 0.08])
    moved = wall_image(R, t, DEPTH, texture)
    px = np.stack(np.meshgrid(np.arange(40, 600, 40.0), np.arange(40, 440, 40.0)), -1).reshape(-1, 2)
    for g in (0.8, 1.25):
        b = _with_gain(moved, 0.7 * g)
        # (The move, 8 cm towards a wall 3 m off, changes each point's 4x4 pixel mean a
        # little: about 1 % of gain.)
        assert gain_between(a, px, b, _truth(px, R, t)) == pytest.approx(g, rel=0.02)
        assert gain_between(a, px, _with_gain(a, g), px) == pytest.approx(g, rel=0.002)
    # Within 2 % of 1, or too few points: no gain.
    assert gain_between(a, px, _with_gain(a, 1.018), px) == 1.0
    assert gain_between(a, px[:10], _with_gain(moved, 0.7 * 1.25), _truth(px[:10], R, t)) == 1.0


def test_tracks_hold_through_exposure_jumps_with_the_gain_divided_out(texture, wall_image):
    motions = [(rotvec_to_R([0.0, 0.01 * k, 0.0]), np.array([0.04 * k, 0.0, 0.08 * k])) for k in range(4)]
    views = [wall_image(R, t, DEPTH, texture) for R, t in motions]
    jumps = [_with_gain(v, g) for v, g in zip(views, [0.7, 0.84, 0.7, 0.84], strict=True)]
    steady = [_with_gain(v, 0.7) for v in views]
    gain = TrackParams(equalize="gain")
    tracks = track_sequence(jumps, CAM, gain)
    ia, ib = common(tracks[0], tracks[-1])
    assert len(ia) > 0.8 * len(tracks[0].ids)
    err = np.linalg.norm(tracks[-1].pixels[ib] - _truth(tracks[0].pixels[ia], *motions[-1]), axis=1)
    assert np.median(err) < 0.2
    # A fixed exposure: the same tracks as without the setting, to the bit.
    for a, b in zip(
        track_sequence(steady, CAM, gain),
        track_sequence(steady, CAM, TrackParams(equalize="none")),
        strict=True,
    ):
        assert np.array_equal(a.ids, b.ids)
        assert np.array_equal(a.pixels, b.pixels)
