"""ROS 1 and ROS 2 bags, written here with rosbags, into sequence folders."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_typestore

from rigcal.camera import read_camera
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence

TS2 = get_typestore(Stores.ROS2_HUMBLE)
TS1 = get_typestore(Stores.ROS1_NOETIC)


def _msgs(ts):
    T = ts.types
    time = T["builtin_interfaces/msg/Time"]
    header = T["std_msgs/msg/Header"]

    def hdr(t: float, frame: str):
        sec = int(t)
        kw = {"stamp": time(sec=sec, nanosec=round((t - sec) * 1e9)), "frame_id": frame}
        if "seq" in header.__dataclass_fields__:
            kw["seq"] = 0
        return header(**kw)

    def scan(t: float, k: int):
        r = np.full(11, 2.0 + 0.01 * k, dtype=np.float32)
        r[3] = np.nan
        return T["sensor_msgs/msg/LaserScan"](
            header=hdr(t, "laser"), angle_min=-0.5, angle_max=0.5, angle_increment=0.1, time_increment=0.0,
            scan_time=0.025, range_min=0.1, range_max=30.0, ranges=r, intensities=np.zeros(0, np.float32),
        )  # fmt: skip

    def image(t: float, k: int):
        img = np.full((4, 6, 3), 10 * k, np.uint8)
        img[0, 0] = [255, 0, 0]  # rgb: red in the corner
        return T["sensor_msgs/msg/Image"](
            header=hdr(t, "cam"), height=4, width=6, encoding="rgb8", is_bigendian=0, step=18,
            data=img.ravel(),
        )  # fmt: skip

    def compressed(t: float, k: int):
        _, buf = cv2.imencode(".png", np.full((4, 6), 20 * k, np.uint8))
        return T["sensor_msgs/msg/CompressedImage"](header=hdr(t, "cam"), format="png", data=buf.ravel())

    def info(t: float):
        fields = T["sensor_msgs/msg/CameraInfo"].__dataclass_fields__
        upper = "K" in fields  # ROS 1 names the matrices K, D, R, P
        roi = T["sensor_msgs/msg/RegionOfInterest"](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
        )
        mats = {
            "d": np.array([-0.1, 0.01, 0.0, 0.0, 0.0]),
            "k": np.array([500.0, 0, 320, 0, 500, 240, 0, 0, 1]),
            "r": np.eye(3).ravel(),
            "p": np.array([500.0, 0, 320, 0, 0, 500, 240, 0, 0, 0, 1, 0]),
        }
        kw = {(key.upper() if upper else key): v for key, v in mats.items()}
        return T["sensor_msgs/msg/CameraInfo"](
            header=hdr(t, "cam"), height=4, width=6, distortion_model="plumb_bob",
            binning_x=0, binning_y=0, roi=roi, **kw,
        )  # fmt: skip

    return scan, image, compressed, info


def write_bag(path: Path, ros: int, scan_stamps, image_stamps, compressed=False, info=True) -> Path:
    ts = TS2 if ros == 2 else TS1
    scan, image, comp, cinfo = _msgs(ts)
    img_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    writer = Writer2(path, version=8) if ros == 2 else Writer1(path)
    with writer as w:
        kw = {"typestore": ts}
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", **kw)
        ci = w.add_connection("/cam/image", img_type, **kw)
        cc = w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", **kw) if info else None
        ser = ts.serialize_cdr if ros == 2 else ts.serialize_ros1
        for k, t in enumerate(scan_stamps):
            w.write(cs, int(1e9 * (10 + k)), ser(scan(t, k), "sensor_msgs/msg/LaserScan"))
        for k, t in enumerate(image_stamps):
            msg = comp(t, k) if compressed else image(t, k)
            w.write(ci, int(1e9 * (10 + k)) + 1, ser(msg, img_type))
        if cc is not None:
            w.write(cc, int(1e9 * 10) + 2, ser(cinfo(1.0), "sensor_msgs/msg/CameraInfo"))
    return path


@pytest.mark.parametrize("ros", [1, 2])
def test_bag_to_sequence_round_trip(tmp_path, ros):
    bag = write_bag(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, [1.0, 1.025, 1.05], [1.0, 1.1])
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", "/cam/info")
    assert (s.scans, s.images, s.camera) == (3, 2, True)
    seq = read_sequence(tmp_path / "seq")
    assert [sc.stamp_s for sc in seq.scans] == pytest.approx([1.0, 1.025, 1.05])
    assert len(seq.scans[0].ranges_m) == 11
    assert np.isnan(seq.scans[0].ranges_m[3])
    assert not seq.scans[0].valid[3]
    assert seq.scans[2].ranges_m[0] == pytest.approx(2.02, abs=1e-6)
    np.testing.assert_allclose(seq.scans[0].angles_rad[[0, -1]], [-0.5, 0.5], atol=1e-6)
    np.testing.assert_allclose(seq.image_stamps_s, [1.0, 1.1])
    img = cv2.imread(str(tmp_path / "seq" / "images" / seq.image_files[0]))
    assert img.shape == (4, 6, 3)
    assert img[0, 0].tolist() == [0, 0, 255]  # rgb8 red stored as BGR red
    cam = read_camera(tmp_path / "seq" / "camera.yaml")
    assert cam.intrinsics[:5].tolist() == [500.0, 500.0, 320.0, 240.0, -0.1]


def test_compressed_images_are_kept_as_they_are(tmp_path):
    bag = write_bag(tmp_path / "b2", 2, [1.0], [1.0, 2.0], compressed=True, info=False)
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert not s.camera
    seq = read_sequence(tmp_path / "seq")
    assert seq.image_files[0].endswith(".png")
    assert cv2.imread(str(tmp_path / "seq" / "images" / seq.image_files[1]), cv2.IMREAD_GRAYSCALE)[0, 0] == 20


def test_out_of_order_and_repeated_stamps_are_sorted_counted_and_dropped(tmp_path):
    bag = write_bag(tmp_path / "b2", 2, [1.05, 1.0, 1.0, 1.1], [2.0, 1.0])
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert s.reordered == {"scans": 1, "images": 1}
    assert s.duplicates == {"scans": 1, "images": 0}
    seq = read_sequence(tmp_path / "seq")
    assert [sc.stamp_s for sc in seq.scans] == pytest.approx([1.0, 1.05, 1.1])
    np.testing.assert_allclose(seq.image_stamps_s, [1.0, 2.0])


def test_missing_topic_lists_the_bags_topics(tmp_path):
    bag = write_bag(tmp_path / "b2", 2, [1.0], [1.0])
    with pytest.raises(InputError, match=r"--scan-topic: got '/laser'; expected one of the bag's topics \["):
        import_bag(bag, tmp_path / "seq", "/laser", "/cam/image")
    assert not (tmp_path / "seq").exists()


def test_wrong_topic_type_and_empty_topic(tmp_path):
    bag = write_bag(tmp_path / "b2", 2, [1.0], [])
    with pytest.raises(
        InputError,
        match=r"/scan: got 'sensor_msgs/msg/LaserScan'; expected a topic of type sensor_msgs/msg/Image",
    ):
        import_bag(bag, tmp_path / "seq", "/scan", "/scan")
    with pytest.raises(InputError, match=r"/cam/image: got 'no messages'"):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert not (tmp_path / "seq").exists()


def test_not_a_bag(tmp_path):
    (tmp_path / "x.bag").write_text("hello")
    with pytest.raises(InputError, match=r"x\.bag: not a readable ROS 1 or ROS 2 bag"):
        import_bag(tmp_path / "x.bag", tmp_path / "seq", "/scan", "/cam/image")
    with pytest.raises(InputError, match=r"nope\.bag: bag not found"):
        import_bag(tmp_path / "nope.bag", tmp_path / "seq", "/scan", "/cam/image")


def test_cli(tmp_path, capsys):
    bag = write_bag(tmp_path / "b.bag", 1, [1.0, 1.05], [1.0])
    argv = [
        "import-bag",
        str(bag),
        "--scan-topic",
        "/scan",
        "--image-topic",
        "/cam/image",
        "-o",
        str(tmp_path / "s"),
    ]
    assert main(argv) == 0
    assert "2 scans, 1 images" in capsys.readouterr().out
    assert main(argv) == 5
    assert main([*argv, "--force", "--camera-info-topic", "/cam/info"]) == 0
    assert main([*argv[:-2], "-o", str(tmp_path / "t"), "--scan-topic", "/nope"]) == 3
    assert "Examples" in (main(["import-bag", "--help"]) == 0 and capsys.readouterr().out)

    assert main(["-q", *argv[:-2], "-o", str(tmp_path / "j"), "--json"]) == 0
    out, err = capsys.readouterr()
    doc = json.loads(out)
    assert (doc["scans"], doc["images"], doc["camera_yaml"]) == (2, 1, False)
    assert doc["output"] == str(tmp_path / "j")
    assert err == ""  # -q: no progress lines
    assert main(["-v", *argv[:-2], "-o", str(tmp_path / "v")]) == 0
    err = capsys.readouterr().err
    assert "INFO: rigcal.recordings.bag: " in err
    assert "2 scans, 1 images read from 3 messages" in err
    assert "reading: 3/3 in " in err  # stderr is not a terminal: one line when a stage ends


def test_a_negative_angle_increment_gives_the_same_points_in_increasing_order():
    from types import SimpleNamespace

    from rigcal.recordings.bag import _scan

    ranges = [1.0, 2.0, 3.0, 4.0]
    up = _scan(
        SimpleNamespace(
            angle_min=-0.3, angle_max=0.3, angle_increment=0.2, ranges=ranges, range_min=0.1, range_max=9.0
        ),
        1.0,
        "bag: /scan",
    )
    down = _scan(
        SimpleNamespace(
            angle_min=0.3,
            angle_max=-0.3,
            angle_increment=-0.2,
            ranges=ranges[::-1],
            range_min=0.1,
            range_max=9.0,
        ),
        1.0,
        "bag: /scan",
    )
    np.testing.assert_allclose(down.angles_rad, up.angles_rad, atol=1e-15)
    np.testing.assert_allclose(down.points, up.points, atol=1e-15)


# --- message bodies a broken driver can write ------------------------------------------------
def bag_with(
    path: Path, ros: int, image: dict | None = None, scan: dict | None = None, info: dict | None = None
):
    """A bag with two scans, two images and a CameraInfo; the second image's, every scan's
    and the CameraInfo's fields overridden. ``image`` with ``format`` makes CompressedImages."""
    ts = TS2 if ros == 2 else TS1
    mk_scan, mk_image, mk_comp, mk_info = _msgs(ts)
    compressed = image is not None and "format" in image
    img_type = "sensor_msgs/msg/CompressedImage" if compressed else "sensor_msgs/msg/Image"
    ser = ts.serialize_cdr if ros == 2 else ts.serialize_ros1
    writer = Writer2(path, version=8) if ros == 2 else Writer1(path)
    with writer as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        ci = w.add_connection("/cam/image", img_type, typestore=ts)
        cc = w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=ts)
        for k in range(2):
            msg = mk_scan(1.0 + 0.1 * k, k)
            for key, v in (scan or {}).items():
                setattr(msg, key, v)
            w.write(cs, int(1e9 * (10 + k)), ser(msg, "sensor_msgs/msg/LaserScan"))
        for k in range(2):
            msg = mk_comp(1.0 + k, k) if compressed else mk_image(1.0 + k, k)
            for key, v in (image or {}).items() if k == 1 else ():
                setattr(msg, key, v)
            w.write(ci, int(1e9 * (10 + k)) + 1, ser(msg, img_type))
        msg = mk_info(1.0)
        for key, v in (info or {}).items():
            setattr(msg, key.upper() if ros == 1 and len(key) == 1 else key, v)
        w.write(cc, int(1e9 * 10) + 2, ser(msg, "sensor_msgs/msg/CameraInfo"))
    return path


def _u8(n: int) -> np.ndarray:
    return np.full(n, 7, np.uint8)


BAD_IMAGES = [
    ("short-data", {"data": _u8(71)}, r"data: got '71 bytes'; expected height \* step = 4 \* 18 = 72 bytes"),
    ("long-data", {"data": _u8(90)}, r"data: got '90 bytes'; expected height \* step = 4 \* 18 = 72"),
    ("height-0", {"height": 0, "data": _u8(0)}, r"height: got 0; expected a positive number of pixels"),
    ("width-0", {"width": 0, "step": 0, "data": _u8(0)}, r"width: got 0; expected a positive"),
    (
        "step-below-width",
        {"step": 12, "data": _u8(48)},
        r"step: got 12; expected at least width \* 3 = 18 bytes",
    ),
    (
        "mono16-odd-step",
        {"encoding": "mono16", "step": 13, "data": _u8(52)},
        r"step: got 13; expected at least width \* 2 = 12 bytes, a multiple of 2 \(mono16\)",
    ),
    (
        "mono16-odd-bytes",
        {"encoding": "mono16", "step": 12, "data": _u8(47)},
        r"data: got '47 bytes'; expected height \* step = 4 \* 12 = 48 bytes",
    ),
    (
        "unknown-encoding",
        {"encoding": "32FC1"},
        r"encoding: got '32FC1'; expected mono8/8UC1, mono16/16UC1, bgr8, rgb8, 8UC3, bgra8, rgba8, 8UC4, "
        r"bayer_rggb8, bayer_bggr8, bayer_gbrg8, bayer_grbg8 \(or 16\), yuv422 \(uyvy\) or yuv422_yuy2",
    ),
    (
        "compressed-broken-png",
        {"format": "png", "data": np.frombuffer(b"\x89PNG\r\n\x1a\nbroken", np.uint8)},
        r"data: got '14 bytes of PNG'; expected an image that decodes",
    ),
    (
        "compressed-not-an-image",
        {"format": "jpeg", "data": _u8(40)},
        r"data: got b'\\x07.*; expected PNG or JPEG bytes \(format says 'jpeg'\)",
    ),
]


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize(("name", "fields", "message"), BAD_IMAGES, ids=[c[0] for c in BAD_IMAGES])
def test_bad_image_bodies_are_refused_naming_bag_topic_and_message(tmp_path, ros, name, fields, message):
    bag = bag_with(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, image=fields)
    with pytest.raises(InputError, match=rf"^{bag}: /cam/image message 1: {message}"):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert not (tmp_path / "seq").exists()


@pytest.mark.parametrize("ros", [1, 2])
def test_padded_rows_and_big_endian_mono16_are_read_as_the_pixels(tmp_path, ros):
    img16 = np.arange(24, dtype=np.uint16).reshape(4, 6) * 1000
    padded = np.zeros((4, 16), np.uint8)  # 12 bytes of pixels + 4 of padding per row
    padded[:, :12] = img16.astype(">u2").view(np.uint8).reshape(4, 12)
    fields = {"encoding": "mono16", "is_bigendian": 1, "step": 16, "data": padded.ravel()}
    bag = bag_with(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, image=fields)
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    seq = read_sequence(tmp_path / "seq")
    got = cv2.imread(str(tmp_path / "seq" / "images" / seq.image_files[1]), cv2.IMREAD_UNCHANGED)
    # stored as 8 bits: levels up to 23000 use 15 bits, so every frame is shifted right by 7
    np.testing.assert_array_equal(got, (img16 >> 7).astype(np.uint8))
    assert seq.source["images_16_bit"] == {"frames": 1, "max_level": 23000, "shift_bits": 7}


BEAMS = [  # 11 ranges from -0.5 in steps of 0.1: angle_max 0.5 exactly, 0.4 / 0.6 one beam off
    (0.5, None),
    (0.4, None),
    (0.6, None),
    (
        0.3,
        r"ranges: got '11 ranges'; expected 9 \(\+-1\) = round\(\(angle_max - angle_min\) / angle_incr",
    ),
    (0.8, r"ranges: got '11 ranges'; expected 14 \(\+-1\)"),
    (float("nan"), r"angle_max: got nan"),
    (7.0, r"angle_max: got 7.0"),
]


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize(("angle_max", "message"), BEAMS)
def test_the_beam_count_must_match_the_angles_within_one(tmp_path, ros, angle_max, message):
    bag = bag_with(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, scan={"angle_max": angle_max})
    if message is None:
        assert import_bag(bag, tmp_path / "seq", "/scan", "/cam/image").scans == 2
        return
    with pytest.raises(InputError, match=rf"^{bag}: /scan message 0: {message}"):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")


BAD_INFOS = [
    ({"k": np.zeros(9)}, r"K: got \[\[0.0, 0.0, 0.0\], .*; expected \[\[fx, 0, cx\], \[0, fy, cy\]"),
    ({"k": np.array([0.0, 0, 320, 0, 500, 240, 0, 0, 1])}, r"K: .*; expected positive focal lengths fx, fy"),
    ({"k": np.array([500.0, 1, 320, 0, 500, 240, 0, 0, 1])}, r"K: .*expected .*\(no skew\)"),
    ({"k": np.array([500.0, 0, np.nan, 0, 500, 240, 0, 0, 1])}, r"K: got .*; expected finite numbers"),
    ({"width": 0}, r"width: got 0; expected a positive image size"),
    ({"height": 0}, r"height: got 0; expected a positive image size"),
    ({"distortion_model": "equidistant", "d": np.zeros(4)}, r"distortion_model: got 'equidistant'"),
    ({"d": np.zeros(3)}, r"D: got \[0.0, 0.0, 0.0\]; expected 5 finite coefficients for plumb_bob"),
    ({"d": np.array([0.1, np.inf, 0, 0, 0])}, r"D: got .*; expected 5 finite coefficients"),
]


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize(("fields", "message"), BAD_INFOS)
def test_a_camera_info_that_is_no_camera_is_refused_before_writing(tmp_path, ros, fields, message):
    bag = bag_with(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, info=fields)
    with pytest.raises(InputError, match=rf"^{bag}: /cam/info message 0: {message}"):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", "/cam/info")
    assert not (tmp_path / "seq").exists()
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")  # without the camera: fine


def test_a_camera_without_distortion_is_a_pinhole(tmp_path):
    bag = bag_with(tmp_path / "b2", 2, info={"d": np.zeros(0), "distortion_model": ""})
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", "/cam/info")
    assert read_camera(tmp_path / "seq" / "camera.yaml").lensmodel == "LENSMODEL_PINHOLE"


def test_a_message_too_short_for_its_type_is_named(tmp_path):
    ts = TS1
    with Writer1(tmp_path / "b.bag") as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        w.write(cs, 1, b"\x00\x01")
        w.write(ci, 2, b"")
    with pytest.raises(
        InputError, match=r"b\.bag: /scan message 0: cannot decode a sensor_msgs/msg/LaserScan"
    ):
        import_bag(tmp_path / "b.bag", tmp_path / "seq", "/scan", "/cam/image")


def test_libpng_says_nothing_of_its_own(tmp_path, capfd):
    png = bytearray(cv2.imencode(".png", np.arange(400, dtype=np.uint8).reshape(20, 20))[1].tobytes())
    png[60] ^= 0xFF  # a CRC error in IDAT: libpng would print "libpng error: IDAT: CRC error"
    bag = bag_with(tmp_path / "b2", 2, image={"format": "png", "data": np.frombuffer(bytes(png), np.uint8)})
    argv = [
        "-q",
        "import-bag",
        str(bag),
        "--scan-topic",
        "/scan",
        "--image-topic",
        "/cam/image",
        "-o",
        str(tmp_path / "s"),
    ]
    assert main(argv) == 3
    err = capfd.readouterr().err
    assert [x for x in err.splitlines() if x.strip()] == [
        f"Error: {bag}: /cam/image message 1: data: got '{len(png)} bytes of PNG'; expected an image that "
        "decodes (damaged data)"
    ]


@pytest.mark.parametrize("ros", [1, 2])
def test_images_of_two_sizes_or_a_camera_of_another_size_are_refused(tmp_path, ros):
    bag = bag_with(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, image={"height": 3, "data": _u8(54)})
    with pytest.raises(
        InputError, match=rf"^{bag}: /cam/image message 1: size: got '6x3'; expected 6x4 like "
    ):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    bag = bag_with(tmp_path / ("c.bag" if ros == 1 else "c2"), ros, info={"width": 640, "height": 480})
    with pytest.raises(
        InputError,
        match=rf"^{bag}: /cam/info message 0: width x height: got '640x480'; expected the images' size 6x4",
    ):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", "/cam/info")
    assert not (tmp_path / "seq").exists()
