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
from rigcal.io.bag import import_bag
from rigcal.io.sequence import read_sequence

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
            header=hdr(t, "cam"), height=480, width=640, distortion_model="plumb_bob",
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
    assert "INFO: rigcal.io.bag: " in err
    assert "2 scans, 1 images read from 3 messages" in err
    assert "reading: 3/3 in " in err  # stderr is not a terminal: one line when a stage ends


def test_a_negative_angle_increment_gives_the_same_points_in_increasing_order():
    from types import SimpleNamespace

    from rigcal.io.bag import _scan

    ranges = [1.0, 2.0, 3.0, 4.0]
    up = _scan(
        SimpleNamespace(angle_min=-0.3, angle_increment=0.2, ranges=ranges, range_min=0.1, range_max=9.0),
        1.0,
        "bag: /scan",
    )
    down = _scan(
        SimpleNamespace(
            angle_min=0.3, angle_increment=-0.2, ranges=ranges[::-1], range_min=0.1, range_max=9.0
        ),
        1.0,
        "bag: /scan",
    )
    np.testing.assert_allclose(down.angles_rad, up.angles_rad, atol=1e-15)
    np.testing.assert_allclose(down.points, up.points, atol=1e-15)
