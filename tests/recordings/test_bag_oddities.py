"""Bags as real robots record them: two laser topics, a scan whose beam count and step
change, compressed images of other encodings, odometry asked of /tf_static, a scan frame
with a leading slash. One line naming the bag, the topic or option, the value and what
was expected (exit 3), or the data read as they are."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from rosbags.rosbag2 import Writer as Writer2
from test_bag import TS2, _msgs, bag_with
from test_bag_odometry import _odometry_bag

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence

SCAN, IMAGE = "sensor_msgs/msg/LaserScan", "sensor_msgs/msg/Image"


def _bag(path, lasers=("/scan",), change_beams=False, scan_frame="laser"):
    scan, image, _, _ = _msgs(TS2)
    ser = TS2.serialize_cdr
    with Writer2(path, version=8) as w:
        cs = [w.add_connection(t, SCAN, typestore=TS2) for t in lasers]
        ci = w.add_connection("/cam/image", IMAGE, typestore=TS2)
        for k in range(6):
            m = scan(1.0 + 0.1 * k, k)
            m.header.frame_id = scan_frame
            if change_beams and k % 2:  # another mode of the scanner: twice the beams
                m.ranges, m.angle_increment = np.full(21, 2.0, np.float32), 0.05
            for c in cs:
                w.write(c, int(1e9 * (10 + k)), ser(m, SCAN))
            w.write(ci, int(1e9 * (10 + k)) + 1, ser(image(1.0 + 0.1 * k, k), IMAGE))
    return path


def test_two_laser_topics_and_none_chosen_names_them(tmp_path, capsys):
    bag = _bag(tmp_path / "two", lasers=("/front/scan", "/rear/scan"))
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "s")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"Error: {bag}: --scan-topic: got 'not given'; expected one of the bag's LaserScan topics "
        "['/front/scan', '/rear/scan']"
    ]
    assert not (tmp_path / "s").exists()
    # One of each: the bag's own topics are read without naming them.
    assert main(["import-bag", str(_bag(tmp_path / "one")), "-o", str(tmp_path / "t")]) == 0
    assert read_sequence(tmp_path / "t").source["scan_topic"] == "/scan"


def test_a_scan_whose_beam_count_and_step_change_keeps_each_scans_own(tmp_path):
    bag = _bag(tmp_path / "b", change_beams=True)
    import_bag(bag, tmp_path / "s", None, None)
    scans = read_sequence(tmp_path / "s").scans
    assert [len(s.ranges_m) for s in scans] == [11, 21] * 3
    np.testing.assert_allclose([s.angle_increment_rad for s in scans], [0.1, 0.05] * 3, rtol=1e-6)
    np.testing.assert_allclose([s.angles_rad[-1] for s in scans], 0.5, rtol=1e-6)


@pytest.mark.parametrize(
    ("fmt", "data"),
    [
        ("tiff", cv2.imencode(".tiff", np.zeros((4, 6), np.uint8))[1].ravel()),
        ("bmp", cv2.imencode(".bmp", np.zeros((4, 6), np.uint8))[1].ravel()),
        (
            "16UC1; compressedDepth png",
            np.r_[np.zeros(12, np.uint8), cv2.imencode(".png", np.zeros((4, 6)))[1]],
        ),
    ],
)
def test_compressed_images_of_another_encoding_name_the_message(tmp_path, fmt, data):
    bag = bag_with(tmp_path / "c", 2, image={"format": fmt, "data": data})
    with pytest.raises(
        InputError,
        match=rf"c: /cam/image message 1: data: got .*; expected PNG or JPEG bytes \(format says '{fmt}'\)",
    ):
        import_bag(bag, tmp_path / "s", "/scan", "/cam/image")
    assert not (tmp_path / "s").exists()


def test_odometry_asked_of_tf_static_says_what_it_holds(tmp_path):
    bag = _odometry_bag(
        tmp_path / "b2",
        2,
        [0.9, 1.4, 1.9, 2.4],
        static=(("odom", "base_link"), ("base_link", "laser")),
        via_tf=True,
    )
    with pytest.raises(
        InputError,
        match=r"b2: --odometry-topic: got '/tf_static'; expected the odometry over time: a nav_msgs/Odometry "
        r"topic or /tf \(its odom -> base_link\); /tf_static holds fixed transforms",
    ):
        import_bag(bag, tmp_path / "s", "/scan", "/cam/image", odometry_topic="/tf_static")
    # /tf's odom -> base_link is the odometry, /tf_static's base_link -> laser the mounting.
    import_bag(bag, tmp_path / "s", "/scan", "/cam/image", odometry_topic="/tf")
    od = read_sequence(tmp_path / "s").odometry
    assert od is not None
    np.testing.assert_allclose(od.T_base_laser, [0.3, 0.0, 0.0], atol=1e-9)


def test_tf_missing_for_a_scan_frame_on_another_frame_asks_for_the_mounting(tmp_path):
    bag = _odometry_bag(tmp_path / "b2", 2, [0.9, 1.4, 1.9, 2.4], static=())
    with pytest.raises(
        InputError,
        match=r"/odom: child_frame_id: got 'base_link'; expected the scans' frame 'laser' .*--laser-offset",
    ):
        import_bag(bag, tmp_path / "s", "/scan", "/cam/image", odometry_topic="/odom")
    assert not (tmp_path / "s").exists()


def test_frames_named_with_a_leading_slash_are_the_same_frames(tmp_path):
    """ROS 1 bags often name frames '/base_link': the odometry's child and /tf_static's
    frames match the scans' whichever spelling each uses."""
    bag = _odometry_bag(
        tmp_path / "b2", 2, [0.9, 1.4, 1.9, 2.4], child="/base_link", static=(("/base_link", "laser"),)
    )
    import_bag(bag, tmp_path / "s", "/scan", "/cam/image", odometry_topic="/odom")
    od = read_sequence(tmp_path / "s").odometry
    assert od is not None
    np.testing.assert_allclose(od.T_base_laser, [0.3, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("ros", [1, 2])
def test_a_bag_recorded_in_parts_is_read_as_one(tmp_path, capsys, ros):
    """rosbag record --split writes a drive as several files: given together they are one
    bag, their messages in time order; a part given twice or missing is one line."""
    from test_bag import write_bag

    a = write_bag(
        tmp_path / ("a.bag" if ros == 1 else "a"), ros, [1.0 + 0.1 * k for k in range(10)], [1.05, 1.45]
    )
    b = write_bag(
        tmp_path / ("b.bag" if ros == 1 else "b"), ros, [2.0 + 0.1 * k for k in range(10)], [2.05, 2.45]
    )
    assert main(["-q", "import-bag", str(b), str(a), "-o", str(tmp_path / "s"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert (doc["scans"], doc["images"]) == (20, 4)
    seq = read_sequence(tmp_path / "s")
    stamps = [s.stamp_s for s in seq.scans]
    np.testing.assert_allclose(stamps, sorted(stamps))
    np.testing.assert_allclose([stamps[0], stamps[-1]], [1.0, 2.9])
    assert seq.source["bag_parts"] == [str(b.resolve()), str(a.resolve())]
    assert main(["import-bag", str(a), str(a), "-o", str(tmp_path / "t")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"Error: {a}: BAG: got ")
    assert err[-1].endswith("expected each part of a bag given once")
    assert main(["import-bag", str(a), str(tmp_path / "c.bag"), "-o", str(tmp_path / "t")]) == 3
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"Error: {tmp_path / 'c.bag'}: bag not found"
    assert not (tmp_path / "t").exists()


@pytest.mark.parametrize("ros", [1, 2])
def test_a_bad_message_in_a_later_part_is_named_by_its_own_file(tmp_path, capsys, ros):
    """A bag recorded in parts: a broken scan in the second file is named by that file and
    its index there, not by the first file."""
    import dataclasses

    from rosbags.rosbag1 import Writer as Writer1
    from test_bag import TS1, write_bag

    ts = TS2 if ros == 2 else TS1
    a = write_bag(tmp_path / ("a.bag" if ros == 1 else "a"), ros, [1.0 + 0.1 * k for k in range(5)], [1.05])
    b = tmp_path / ("b.bag" if ros == 1 else "b")
    scan, image, _, _ = _msgs(ts)
    ser = ts.serialize_cdr if ros == 2 else ts.serialize_ros1
    with Writer2(b, version=8) if ros == 2 else Writer1(b) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        for k in range(3):
            msg = scan(2.0 + 0.1 * k, k)
            if k == 2:
                msg = dataclasses.replace(msg, angle_increment=0.0)
            w.write(cs, int(1e9 * (20 + k)), ser(msg, "sensor_msgs/msg/LaserScan"))
        w.write(ci, int(1e9 * 20) + 1, ser(image(2.05, 0), "sensor_msgs/msg/Image"))
    assert main(["import-bag", str(a), str(b), "-o", str(tmp_path / "s")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith(f"Error: {b}: /scan message 2: ")
    assert not (tmp_path / "s").exists()
