"""Streams of a sequence: pairing the laser to image times, images, and their errors."""

from __future__ import annotations

import sys

import cv2
import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.localize.streams import open_streams
from rigcal.localize.time_pairing import nearest_index, pose_at
from rigcal.recordings.sequence import ImageFrame, write_sequence
from rigcal.rig import Rig
from rigcal.rigfile import rig_to_text
from rigcal.scan import Scan
from rigcal.sim.box_session import default_camera, default_T_cam_laser
from rigcal.sim.raycast import beam_angles, cast_scan
from rigcal.sim.render import Room

ROOM = Room((8.0, 6.0))


def _scan(pose, t):
    x, y, yaw = pose
    _, _, ang = beam_angles(270.0, 0.5)
    # The room seen from the pose: the room's pose in the laser frame.
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.array([[c, -s], [s, c]])
    o = -R.T @ [x, y]
    r = cast_scan(ROOM.wall_segments((o[0], o[1], -yaw)), ang, 30.0)
    return Scan.from_uniform(float(ang[0]), float(ang[1] - ang[0]), r, 0.1, 30.0, t)


def _truth(t):
    return np.array([-2.0 + 0.8 * t, -0.5 + 0.1 * t, 0.2 * t])


@pytest.fixture
def seq(tmp_path):
    cam = default_camera()
    scans = [_scan(_truth(t), t) for t in np.arange(0.0, 2.0, 0.05)]
    img = np.random.default_rng(0).integers(0, 255, (cam.height_px, cam.width_px), dtype=np.uint8)
    png = cv2.imencode(".png", img)[1].tobytes()
    images = [ImageFrame(float(t), f"{k:06d}.png", png) for k, t in enumerate(np.arange(0.013, 2.0, 0.1))]
    rig = rig_to_text(Rig(default_T_cam_laser(), cam))
    return write_sequence(tmp_path / "seq", "t", scans, images, None, {}, rig_yaml=rig)


def test_nearest_index_and_pose_interpolation():
    s = np.array([0.0, 1.0, 2.0])
    assert [nearest_index(s, t) for t in (-1.0, 0.4, 0.6, 1.49, 1.51, 5.0)] == [0, 0, 1, 1, 2, 2]
    p = np.array([[0, 0, 3.0], [1, 2, -3.0]])  # yaw crosses +-pi: interpolated the short way
    q = pose_at(np.array([0.0, 1.0]), p, 0.5)
    assert q[:2] == pytest.approx([0.5, 1.0])
    assert abs(np.cos(q[2]) + 1.0) < 1e-2


def test_laser_points_at_an_image_are_the_scan_moved_to_its_time(seq):
    st = open_streams(seq)
    i = 7
    t = float(st.image_stamps_s[i])
    pts = st.laser_points_at_image(i)
    # Points put in the room by the true pose at the image's time lie on the room's walls.
    off_wall = _off_wall(pts, _truth(t))
    assert np.median(off_wall) < 0.002
    # Without the motion compensation, the nearest scan (13 ms away) is a centimetre off.
    k = nearest_index(st.scan_stamps_s, t)
    raw = st.scans[k].points[st.scans[k].valid]
    assert np.median(_off_wall(raw, _truth(t))) > 3 * np.median(off_wall)


def _off_wall(pts, pose):
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    w = pts @ np.array([[c, -s], [s, c]]).T + [x, y]
    return np.minimum(np.abs(4.0 - np.abs(w[:, 0])), np.abs(3.0 - np.abs(w[:, 1])))


def test_images_are_read_and_checked(seq, tmp_path):
    st = open_streams(seq)
    assert st.image(3).shape == (480, 640)
    st.require_images("vo")
    (seq / "images" / "000004.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"000004\.png: not a readable image"):
        st.image(4)


def test_a_method_needing_the_rig_says_so(seq):
    (seq / "rig.yaml").unlink()
    with pytest.raises(InputError, match=r"rig: got 'rig\.yaml'; expected a file"):
        open_streams(seq)
    text = (seq / "sequence.yaml").read_text().replace("rig: rig.yaml\n", "")
    (seq / "sequence.yaml").write_text(text)
    with pytest.raises(InputError, match="needs the calibration"):
        open_streams(seq).require_rig("vo")


def test_images_of_the_wrong_size_are_refused(seq, tmp_path):
    small = cv2.imencode(".png", np.zeros((240, 320), np.uint8))[1].tobytes()
    (seq / "images" / "000000.png").write_bytes(small)
    with pytest.raises(InputError, match=r"000000\.png: image size: got '320x240'; expected 640x480"):
        open_streams(seq).require_images("vo")


def test_scan_stamps_out_of_order_or_repeated_are_refused(tmp_path):
    cam = default_camera()
    rig = rig_to_text(Rig(default_T_cam_laser(), cam))
    for stamps, bad in (
        ([0.0, 0.1, 0.1], "stamps_s\\[2\\]: got 0.1"),
        ([0.0, 0.2, 0.1], "stamps_s\\[2\\]: got 0.1"),
    ):
        scans = [_scan(_truth(t), t) for t in stamps]
        folder = write_sequence(
            tmp_path / f"s{len(list(tmp_path.iterdir()))}", "t", scans, [], None, {}, rig_yaml=rig
        )
        with pytest.raises(InputError, match=bad):
            open_streams(folder)


def test_laser_odometry_on_a_second_thread_equals_the_direct_one(seq):
    direct = open_streams(seq).laser_odometry()
    st = open_streams(seq)
    st.start_laser_odometry()
    st.start_laser_odometry()  # a second call starts nothing more
    tracks = st.feature_tracks()  # the image stage, meanwhile
    assert len(tracks) == st.n_images
    assert np.array_equal(st.laser_odometry().poses, direct.poses)
    assert "icp_s" in st.timings_s
    assert "tracks_s" in st.timings_s


def test_a_failed_run_stops_the_background_laser_odometry(seq):
    from rigcal.localize.pipeline import run

    bad = seq / "images" / "000003.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"000003\.png: not a readable image"):
        run(seq, ["vo"], progress=None)
    # The laser odometry thread was told to stop (or had finished): none is left running.
    import threading

    for t in threading.enumerate():
        if t.name.startswith("laser-odometry"):
            t.join(timeout=10)
            assert not t.is_alive()


def test_the_image_cache_keeps_what_its_byte_budget_allows(seq, monkeypatch):
    import rigcal.localize.image_cache as image_cache_module

    st = open_streams(seq)
    one = st.image(0).nbytes
    monkeypatch.setattr(image_cache_module, "_IMAGE_CACHE_BYTES", 2 * one)
    for i in range(1, 5):
        st.image(i)
    assert st._image_cache.indices() == [3, 4]  # the least recently used went first
    assert st.timings_s["read_images_s"] > 0


def _distinct_images(seq):
    """Give each image of the sequence its own content (image k is filled with k)."""
    for k, name in enumerate(sorted((seq / "images").iterdir())):
        name.write_bytes(cv2.imencode(".png", np.full((480, 640), k, np.uint8))[1].tobytes())


def test_images_in_order_are_each_frame_decoded_ahead_once(seq, monkeypatch):
    _distinct_images(seq)
    st = open_streams(seq)
    st.image(2)  # already kept: not decoded again
    decoded = []
    real = st._decode
    monkeypatch.setattr(st, "_decode", lambda i: decoded.append(i) or real(i))
    frames = list(st.images_in_order(ahead=3))
    assert [int(f[0, 0]) for f in frames] == list(range(st.n_images))
    assert sorted(decoded) == [i for i in range(st.n_images) if i != 2]
    assert all(st.image(i) is frames[i] for i in range(st.n_images))  # kept for a second pass


def test_a_broken_image_ahead_stops_the_ordered_reading_with_its_name(seq):
    _distinct_images(seq)
    (seq / "images" / "000005.png").write_bytes(b"not a png")
    st = open_streams(seq)
    frames = st.images_in_order(ahead=4)
    assert [int(next(frames)[0, 0]) for _ in range(5)] == [0, 1, 2, 3, 4]
    with pytest.raises(InputError, match=r"000005\.png: not a readable image"):
        next(frames)


def test_computed_ahead_keeps_the_order_and_raises_where_the_item_would_be():
    from rigcal.localize.prefetch import computed_ahead

    started = []

    def square(i):
        started.append(i)
        if i == 6:
            raise ValueError("item 6")
        return i * i

    items = computed_ahead(square, 10, ahead=3)
    assert [next(items) for _ in range(6)] == [(i, i * i) for i in range(6)]
    with pytest.raises(ValueError, match="item 6"):
        next(items)
    assert max(started) <= 8  # never more than `ahead` items beyond the one asked for


def test_ahead_starts_its_first_items_at_once_and_stops_when_closed():
    import threading

    from rigcal.localize.prefetch import Ahead

    started: list[int] = []
    three = threading.Event()

    def item(i):
        started.append(i)
        if len(started) == 3:
            three.set()
        return i

    with Ahead(item, 100, ahead=3) as work:
        assert three.wait(10.0)  # under way before any item is asked for
        assert sorted(started) == [0, 1, 2]
        assert [next(iter(work))] == [(0, 0)]
    assert len(started) <= 4  # closed: the rest never started


def test_images_ahead_are_the_frames_in_order(seq):
    st = open_streams(seq)
    with st.images_ahead([3, 1, 2], ahead=2) as frames:
        got = list(frames)
    for i, g in zip([3, 1, 2], got, strict=True):
        np.testing.assert_array_equal(g, open_streams(seq).image(i))


def test_feature_tracks_read_the_frames_in_order_ahead(seq):
    from rigcal.localize.tracks import track_sequence

    st = open_streams(seq)
    assert st.rig is not None
    direct = track_sequence([st.image(i) for i in range(st.n_images)], st.rig.camera)
    ahead = open_streams(seq).feature_tracks()
    assert len(ahead) == len(direct)
    for a, b in zip(ahead, direct, strict=True):
        assert np.array_equal(a.ids, b.ids)
        assert np.array_equal(a.pixels, b.pixels)


def test_the_lines_of_the_scans_at_the_images_are_kept_and_others_not(seq):
    s = open_streams(seq)
    at_images = {s.scan_at_image(i) for i in range(s.n_images)}
    k_img = min(at_images)
    k_other = next(k for k in range(len(s.scans)) if k not in at_images)
    assert s.lines(k_img) is s.lines(k_img)  # extracted once, shared
    first = s.lines(k_other)
    again = s.lines(k_other)
    assert first is not again  # not kept
    assert [g.indices.tolist() for g in first] == [g.indices.tolist() for g in again]


def test_every_reader_of_the_frames_sees_them_equalized_when_asked(seq):
    from rigcal.io.images import read_grey
    from rigcal.localize.tracks import TrackParams, equalized

    st = open_streams(seq)
    st.track_params = TrackParams(equalize="clahe")
    raw = read_grey(seq / "images" / "000002.png")
    assert raw is not None
    want = equalized(raw, st.track_params)
    assert not np.array_equal(want, raw)
    assert np.array_equal(st.image(2), want)  # visual odometry's and IASM's patches
    ordered = list(st.images_in_order())  # the feature tracks
    assert np.array_equal(ordered[2], want)
    assert np.array_equal(open_streams(seq).image(2), raw)  # the default leaves them be


def test_early_frames_are_the_frames_read_grey_reads_and_stop_at_one_they_cannot_take(tmp_path):
    from rigcal.io.images import read_grey
    from rigcal.localize.image_cache import EarlyFrames, ImageCache

    rng = np.random.default_rng(3)
    paths = []
    for k in range(4):
        rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
        if k == 2:
            rgb = rgb[:-1]  # another size: the reader's own decoding reports it
        path = tmp_path / f"{k}.png"
        assert cv2.imwrite(str(path), rgb)
        paths.append((k, path))
    early = EarlyFrames(paths, (48, 64), ImageCache())
    early._thread.join(30.0)  # it ends by itself at frame 2
    early.stop()
    assert early.cache.indices() == [0, 1]
    for i in (0, 1):
        np.testing.assert_array_equal(early.cache.get(i), read_grey(paths[i][1]))
        np.testing.assert_array_equal(early.cache.get(i), cv2.imread(str(paths[i][1]), cv2.IMREAD_GRAYSCALE))


def test_early_frames_convert_with_the_kernel_only_once_another_thread_loaded_it(monkeypatch):
    """The early frames' thread never makes a kernel's first call (numba's set-up, which
    the command's main thread makes at its own first kernel): numpy's conversion until
    then, the same levels."""
    import types

    from rigcal.io.png import rgb_to_grey_reference
    from rigcal.localize import image_cache

    def converted(rgb):  # type: ignore[no-untyped-def]
        return rgb[..., 0]

    fake = types.SimpleNamespace(_rgb_to_grey=types.SimpleNamespace(signatures=[]), rgb_to_grey=converted)
    monkeypatch.setitem(sys.modules, "rigcal.io.images", fake)
    assert image_cache._to_grey() is rgb_to_grey_reference
    fake._rgb_to_grey.signatures = ["(uint8[:, :, ::1], uint8[:, ::1])"]
    assert image_cache._to_grey() is converted
    monkeypatch.setitem(sys.modules, "rigcal.io.images", types.SimpleNamespace())  # still importing
    assert image_cache._to_grey() is rgb_to_grey_reference
