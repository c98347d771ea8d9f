"""Bags as real cameras and scanners fill them: colour with alpha, Bayer mosaics, packed
YUV, 12-bit data in 16-bit words, ranges at range_max, scans over a full turn, images
before the first scan. Each is converted by a documented rule (docs/formats/sequence.md,
"From bags") and counted, or refused in one line naming the bag, topic, message and field."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from test_bag import bag_with

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence

RNG = np.random.default_rng(7)
BGRA = RNG.integers(0, 256, (4, 6, 4), dtype=np.uint8)


def _stored(tmp_path, fields, k=1):
    """Import a bag whose second image has ``fields``; the stored frame k, unchanged."""
    bag = bag_with(tmp_path / "b2", 2, image=fields)
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    seq = read_sequence(tmp_path / "seq")
    return cv2.imread(str(tmp_path / "seq" / "images" / seq.image_files[k]), cv2.IMREAD_UNCHANGED), seq


@pytest.mark.parametrize(
    ("encoding", "want"),
    [("bgra8", BGRA[:, :, :3]), ("8UC4", BGRA[:, :, :3]), ("rgba8", BGRA[:, :, 2::-1])],
)
def test_alpha_is_dropped_and_colour_stored_as_bgr(tmp_path, encoding, want):
    got, _ = _stored(tmp_path, {"encoding": encoding, "step": 24, "data": BGRA.ravel()})
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize(
    ("encoding", "red_at"),
    [("bayer_rggb8", (0, 0)), ("bayer_bggr8", (1, 1)), ("bayer_gbrg8", (1, 0)), ("bayer_grbg8", (0, 1))],
)
def test_a_bayer_mosaic_of_a_red_scene_is_stored_red(tmp_path, encoding, red_at):
    """ROS names the pattern from the first row, OpenCV from the second: a mix-up would
    turn red into blue. A red scene's mosaic (200 on its red sites, 0 elsewhere)."""
    mosaic = np.zeros((4, 6), np.uint8)
    mosaic[red_at[0] :: 2, red_at[1] :: 2] = 200
    got, _ = _stored(tmp_path, {"encoding": encoding, "step": 6, "data": mosaic.ravel()})
    assert got.shape == (4, 6, 3)
    b, g, r = (got[1:3, 1:5, c].astype(int) for c in range(3))
    assert (r > 150).all()
    assert (b < 30).all()
    assert (g < 30).all()


def test_packed_yuv_is_converted_and_an_odd_width_refused(tmp_path):
    uyvy = RNG.integers(0, 256, (4, 6, 2), dtype=np.uint8)
    got, _ = _stored(tmp_path, {"encoding": "yuv422", "step": 12, "data": uyvy.ravel()})
    np.testing.assert_array_equal(got, cv2.cvtColor(uyvy, cv2.COLOR_YUV2BGR_UYVY))
    bag = bag_with(tmp_path / "odd", 2, image={"encoding": "yuv422_yuy2", "width": 5, "step": 10})
    with pytest.raises(
        InputError, match=r"^.*odd: /cam/image message 1: width: got 5; expected an even number"
    ):
        import_bag(bag, tmp_path / "s2", "/scan", "/cam/image")
    assert not (tmp_path / "s2").exists()


@pytest.mark.parametrize("width", [6, 12])
def test_a_one_row_bayer_image_is_refused(tmp_path, width):
    fields = {
        "encoding": "bayer_rggb8",
        "height": 1,
        "width": width,
        "step": width,
        "data": np.zeros(width, np.uint8),
    }
    bag = bag_with(tmp_path / "b", 2, image=fields)
    with pytest.raises(
        InputError, match=rf"message 1: height x width: got '1x{width}'; expected at least 2x2"
    ):
        import_bag(bag, tmp_path / "s", "/scan", "/cam/image")


def test_twelve_bit_data_in_sixteen_bits_are_shifted_alike_in_every_frame(tmp_path):
    """A 12-bit camera's mono16 (levels up to 4095): OpenCV's top byte would read it as 0-15,
    nearly black. Every frame is shifted by the topic's 4 spare bits, a dark frame too, so
    that a level means the same brightness in every frame."""
    bright = (np.arange(24, dtype=np.uint16).reshape(4, 6) * 178).clip(0, 4095)  # up to 4094
    bright.flat[0] = 4095
    dark = bright // 4  # the second frame, a quarter as bright
    from rosbags.rosbag2 import Writer
    from test_bag import TS2, _msgs

    scan, image, _, _ = _msgs(TS2)
    with Writer(tmp_path / "m16", version=8) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=TS2)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=TS2)
        for k, img in enumerate((bright, dark)):
            w.write(
                cs, 10**9 * (10 + k), TS2.serialize_cdr(scan(1.0 + 0.1 * k, k), "sensor_msgs/msg/LaserScan")
            )
            m = image(1.0 + 0.1 * k, k)
            m.encoding, m.step, m.data = "mono16", 12, img.astype("<u2").view(np.uint8).ravel()
            w.write(ci, 10**9 * (10 + k) + 1, TS2.serialize_cdr(m, "sensor_msgs/msg/Image"))
    s = import_bag(tmp_path / "m16", tmp_path / "seq", None, None)
    assert s.depth == {"frames": 2, "max_level": 4095, "shift_bits": 4}
    seq = read_sequence(tmp_path / "seq")
    got = [cv2.imread(str(tmp_path / "seq" / "images" / f), cv2.IMREAD_UNCHANGED) for f in seq.image_files]
    assert all(g.dtype == np.uint8 for g in got)
    np.testing.assert_array_equal(got[0], bright >> 4)
    np.testing.assert_array_equal(got[1], dark >> 4)  # the same shift, not stretched on its own
    assert seq.source["images_16_bit"] == {"frames": 2, "max_level": 4095, "shift_bits": 4}


def test_sixteen_bit_bayer_is_demosaiced_then_shifted(tmp_path):
    mosaic = np.zeros((4, 6), np.uint16)
    mosaic[0::2, 0::2] = 1000  # a red scene, 10 bits
    got, seq = _stored(
        tmp_path, {"encoding": "bayer_rggb16", "step": 12, "data": mosaic.view(np.uint8).ravel()}
    )
    assert got.dtype == np.uint8
    assert seq.source["images_16_bit"]["shift_bits"] == 2
    assert (got[1:3, 1:5, 2] > 200).all()


def test_a_sixteen_bit_png_compressed_image_is_shifted_as_a_raw_one(tmp_path):
    img = (np.arange(24, dtype=np.uint16).reshape(4, 6) * 40).astype(np.uint16)  # up to 920: 10 bits
    data = np.frombuffer(cv2.imencode(".png", img)[1].tobytes(), np.uint8)
    got, seq = _stored(tmp_path, {"format": "png", "data": data})
    np.testing.assert_array_equal(got, img >> 2)
    assert seq.source["images_16_bit"] == {"frames": 1, "max_level": 920, "shift_bits": 2}


def test_jpeg_compressed_images_are_kept_as_they_are(tmp_path):
    data = cv2.imencode(".jpg", BGRA[:, :, :3])[1].tobytes()
    bag = bag_with(tmp_path / "b2", 2, image={"format": "jpeg", "data": np.frombuffer(data, np.uint8)})
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    seq = read_sequence(tmp_path / "seq")
    assert (tmp_path / "seq" / "images" / seq.image_files[1]).read_bytes() == data


def test_ranges_at_range_max_are_no_return(tmp_path):
    r = np.array([2.0] * 5 + [30.0] * 6, np.float32)  # a driver writing range_max for no return
    bag = bag_with(tmp_path / "b2", 2, scan={"ranges": r})
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert s.scan_counts["returns_at_range_max"] == 12
    scan = read_sequence(tmp_path / "seq").scans[0]
    assert scan.valid.tolist() == [True] * 5 + [False] * 6
    assert np.isinf(scan.ranges_m[5:]).all()
    assert read_sequence(tmp_path / "seq").source["returns_at_range_max"] == 12


def test_a_scan_over_a_full_turn_keeps_one_turn(tmp_path):
    step = np.radians(1.0)
    n = 451  # -180 deg to 270 deg: 90 deg measured twice
    bag = bag_with(
        tmp_path / "b2",
        2,
        scan={"angle_min": -np.pi, "angle_max": -np.pi + (n - 1) * step, "angle_increment": step,
              "ranges": np.full(n, 3.0, np.float32)},
    )  # fmt: skip
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert s.scan_counts["beams_past_one_turn"] == 2 * 90
    scan = read_sequence(tmp_path / "seq").scans[0]
    assert len(scan.ranges_m) == 361
    assert scan.angles_rad[-1] == pytest.approx(np.pi, abs=1e-5)


def test_inf_nan_and_zero_ranges_and_intensities_of_any_length(tmp_path):
    r = np.array([np.inf, np.nan, 0.0, -np.inf] + [2.0] * 7, np.float32)
    bag = bag_with(tmp_path / "b2", 2, scan={"ranges": r, "intensities": np.ones(3, np.float32)})
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    scan = read_sequence(tmp_path / "seq").scans[0]
    assert scan.valid.tolist() == [False] * 4 + [True] * 7


def test_the_command_says_what_it_converted(tmp_path, capsys):
    r = np.array([2.0] * 10 + [30.0], np.float32)
    bag = bag_with(tmp_path / "b2", 2, scan={"ranges": r})  # images at 1 s and 2 s, scans 1.0-1.1 s
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "s")]) == 0
    out = capsys.readouterr().out
    assert "2 ranges at range_max (no return)" in out
    assert (
        "0 images before the first scan and 1 after the last (kept; check and localize's image methods "
        "leave them out)" in out
    )
    # The bag's camera, not asked for, is said to be left (no silent sequence without it).
    assert (
        "CameraInfo topic(s) ['/cam/info'] not read: no camera.yaml (--camera-info-topic TOPIC writes it)"
        in out
    )
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "c"), "--camera-info-topic", "/cam/info"]) == 0
    assert "CameraInfo" not in capsys.readouterr().out
    assert main(["-q", "import-bag", str(bag), "-o", str(tmp_path / "j"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["returns_at_range_max"] == 2
    assert doc["images_outside_scans"] == {"before": 0, "after": 1}


def test_messages_a_driver_left_unstamped_take_their_record_time(tmp_path, capsys):
    """A camera driver that never fills header.stamp: every image would share stamp 0 and
    all but one be dropped as repeated; each takes the time the recorder got it instead."""
    from rosbags.rosbag2 import Writer
    from test_bag import TS2, _msgs

    scan, image, _, _ = _msgs(TS2)
    with Writer(tmp_path / "b2", version=8) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=TS2)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=TS2)
        for k in range(5):
            w.write(
                cs,
                10**9 * 100 + 10**8 * k,
                TS2.serialize_cdr(scan(100.0 + 0.1 * k, k), "sensor_msgs/msg/LaserScan"),
            )
            w.write(
                ci,
                10**9 * 100 + 10**8 * k + 5 * 10**6,
                TS2.serialize_cdr(image(0.0, k), "sensor_msgs/msg/Image"),
            )
    assert main(["import-bag", str(tmp_path / "b2"), "-o", str(tmp_path / "s")]) == 0
    assert (
        "5 /cam/image messages with header.stamp 0 (stamped with their record time)"
        in capsys.readouterr().out
    )
    seq = read_sequence(tmp_path / "s")
    np.testing.assert_allclose(seq.image_stamps_s, 100.005 + 0.1 * np.arange(5), atol=1e-9)
    assert seq.source["unstamped_record_time"] == {"/cam/image": 5}
    argv = ["import-bag", str(tmp_path / "b2"), "--stamps", "strict", "-o", str(tmp_path / "t")]
    assert main(argv) == 3
    err = capsys.readouterr().err
    assert "/cam/image message 0: header.stamp: got 0.0; expected a stamp set by the driver" in err
    assert not (tmp_path / "t").exists()
