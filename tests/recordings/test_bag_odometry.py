"""Bags: a nav_msgs/Odometry topic as the wheel odometry, /tf_static's mounting, --stamps strict."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import Writer as Writer2
from test_bag import TS1, TS2, _msgs, write_bag

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence


def _odometry_bag(
    path,
    ros,
    odom_stamps,
    child="base_link",
    static=(("base_link", "laser"),),
    nan=False,
    via_tf=False,
    covariance=None,
):
    ts = TS2 if ros == 2 else TS1
    T = ts.types
    scan, image, _, _ = _msgs(ts)
    covariance = np.zeros(36) if covariance is None else covariance
    header = T["std_msgs/msg/Header"]
    time = T["builtin_interfaces/msg/Time"]

    def hdr(t, frame):
        kw = {"stamp": time(sec=int(t), nanosec=round((t - int(t)) * 1e9)), "frame_id": frame}
        if "seq" in header.__dataclass_fields__:
            kw["seq"] = 0
        return header(**kw)

    def quat(yaw):
        return T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=np.sin(yaw / 2), w=np.cos(yaw / 2))

    def odom(t, k):
        x = float("nan") if nan and k == 1 else 0.5 * k
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=x, y=0.0, z=0.0), orientation=quat(0.1 * k)
        )
        twist = T["geometry_msgs/msg/Twist"](
            linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
        )
        return T["nav_msgs/msg/Odometry"](
            header=hdr(t, "odom"), child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=covariance),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=covariance),
        )  # fmt: skip

    def tf_static():
        shift = T["geometry_msgs/msg/Vector3"](x=0.3, y=0.0, z=0.2)
        tf = T["geometry_msgs/msg/Transform"](translation=shift, rotation=quat(0.0))
        stamped = T["geometry_msgs/msg/TransformStamped"]
        tfs = [stamped(header=hdr(0.0, a), child_frame_id=b, transform=tf) for a, b in static]
        return T["tf2_msgs/msg/TFMessage"](transforms=tfs)

    def tf(t, k):
        """/tf: map -> odom (not the odometry) and odom -> child, the odometry's pose."""
        x = float("nan") if nan and k == 1 else 0.5 * k
        stamped = T["geometry_msgs/msg/TransformStamped"]
        move = T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0)
        fix = T["geometry_msgs/msg/Vector3"](x=1.0, y=2.0, z=0.0)
        return T["tf2_msgs/msg/TFMessage"](
            transforms=[
                stamped(header=hdr(t, "map"), child_frame_id="odom",
                        transform=T["geometry_msgs/msg/Transform"](translation=fix, rotation=quat(0.5))),
                stamped(header=hdr(t, "odom"), child_frame_id=child,
                        transform=T["geometry_msgs/msg/Transform"](translation=move, rotation=quat(0.1 * k))),
            ]
        )  # fmt: skip

    writer = Writer2(path, version=8) if ros == 2 else Writer1(path)
    ser = ts.serialize_cdr if ros == 2 else ts.serialize_ros1
    with writer as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        odom_type = "tf2_msgs/msg/TFMessage" if via_tf else "nav_msgs/msg/Odometry"
        co = w.add_connection("/tf" if via_tf else "/odom", odom_type, typestore=ts)
        if ros == 2:  # (the ROS 1 type store has no tf2_msgs)
            ct = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
            w.write(ct, int(1e9 * 9), ser(tf_static(), "tf2_msgs/msg/TFMessage"))
        for k, t in enumerate([1.0, 1.5, 2.0]):
            w.write(cs, int(1e9 * (10 + k)), ser(scan(t, k), "sensor_msgs/msg/LaserScan"))
            w.write(ci, int(1e9 * (10 + k)) + 1, ser(image(t, k), "sensor_msgs/msg/Image"))
        for k, t in enumerate(odom_stamps):
            w.write(co, int(1e9 * (10 + k)) + 2, ser(tf(t, k) if via_tf else odom(t, k), odom_type))
    return path


@pytest.mark.parametrize("ros", [1, 2])
def test_odometry_topic_with_the_mounting_from_tf_static(tmp_path, ros):
    bag = _odometry_bag(tmp_path / ("b.bag" if ros == 1 else "b2"), ros, [0.9, 1.4, 1.9, 2.4])
    mount = np.array([0.3, 0.0, 0.0]) if ros == 1 else None  # ROS 2: from /tf_static
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", odometry_topic="/odom", laser_offset=mount)
    assert s.odometry == 4
    od = read_sequence(tmp_path / "seq").odometry
    assert od is not None
    np.testing.assert_allclose(od.stamps_s, [0.9, 1.4, 1.9, 2.4])
    np.testing.assert_allclose(od.poses[:, 0], [0.0, 0.5, 1.0, 1.5])
    np.testing.assert_allclose(od.poses[:, 2], [0.0, 0.1, 0.2, 0.3], atol=1e-9)
    np.testing.assert_allclose(od.T_base_laser, [0.3, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (
            {"child": "base_footprint"},
            r"/odom: child_frame_id: got 'base_footprint'; expected the scans' frame",
        ),
        ({"static": ()}, r"expected the scans' frame 'laser' or a frame linked to it"),
        ({"nan": True}, r"b2: /odom: odometry pose 1: got \[1.4, nan, 0.0, 0.09"),
        (
            {"odom_stamps": [5.0, 6.0]},
            r"/odom: odometry stamps: got '5.0 to 6.0'; expected a span overlapping",
        ),
    ],
)
def test_bad_odometry_topics_are_one_line_naming_the_topic(tmp_path, kwargs, match):
    stamps = kwargs.pop("odom_stamps", [0.9, 1.4, 1.9, 2.4])
    bag = _odometry_bag(tmp_path / "b2", 2, stamps, **kwargs)
    with pytest.raises(InputError, match=match):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", odometry_topic="/odom")
    assert not (tmp_path / "seq").exists()


def test_the_laser_offset_option_and_a_wrong_topic_type(tmp_path, capsys):
    bag = _odometry_bag(tmp_path / "b2", 2, [0.9, 1.4, 1.9, 2.4], static=())
    args = ["import-bag", str(bag), "--scan-topic", "/scan", "--image-topic", "/cam/image"]
    assert (
        main([*args, "--odometry-topic", "/odom", "--laser-offset", "0.1,0,0", "-o", str(tmp_path / "s")])
        == 0
    )
    od = read_sequence(tmp_path / "s").odometry
    np.testing.assert_allclose(od.T_base_laser, [0.1, 0.0, 0.0])
    assert main([*args, "--odometry-topic", "/scan", "-o", str(tmp_path / "t")]) == 3
    assert (
        "/scan: got 'sensor_msgs/msg/LaserScan'; expected a topic of type nav_msgs/msg/Odometry"
        in capsys.readouterr().err
    )


def test_strict_stamps_refuse_what_repair_sorts(tmp_path):
    bag = write_bag(tmp_path / "b2", 2, [1.05, 1.0, 1.1], [1.0, 2.0])
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    with pytest.raises(
        InputError, match=r"b2: /scan message 1 header.stamp: got 1.0; expected a stamp after"
    ):
        import_bag(bag, tmp_path / "s2", "/scan", "/cam/image", stamps="strict")


def test_tf_odom_to_base_link_as_the_odometry(tmp_path):
    """A bag without nav_msgs/Odometry: /tf's odom -> base_link transforms are the wheel
    odometry (the other transforms on /tf left alone), the mounting from /tf_static."""
    bag = _odometry_bag(tmp_path / "b2", 2, [0.9, 1.4, 1.9, 2.4], via_tf=True)
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", odometry_topic="/tf")
    assert s.odometry == 4
    od = read_sequence(tmp_path / "seq").odometry
    assert od is not None
    np.testing.assert_allclose(od.stamps_s, [0.9, 1.4, 1.9, 2.4])
    np.testing.assert_allclose(od.poses[:, 0], [0.0, 0.5, 1.0, 1.5])
    np.testing.assert_allclose(od.poses[:, 2], [0.0, 0.1, 0.2, 0.3], atol=1e-9)
    np.testing.assert_allclose(od.T_base_laser, [0.3, 0.0, 0.0], atol=1e-9)


def test_tf_odometry_errors_name_the_topic_and_the_frames(tmp_path, capsys):
    bag = _odometry_bag(tmp_path / "b2", 2, [0.9, 1.4, 1.9, 2.4], via_tf=True)
    with pytest.raises(
        InputError,
        match=r"b2: /tf: transforms: got \[\('map', 'odom'\), \('odom', 'base_link'\)\]; "
        r"expected transforms odom -> base_footprint",
    ):
        import_bag(
            bag, tmp_path / "seq", "/scan", "/cam/image", odometry_topic="/tf",
            odometry_frames=("odom", "base_footprint"),
        )  # fmt: skip
    assert not (tmp_path / "seq").exists()
    nan_bag = _odometry_bag(tmp_path / "n2", 2, [0.9, 1.4, 1.9, 2.4], via_tf=True, nan=True)
    with pytest.raises(InputError, match=r"n2: /tf: odometry pose 1: got \[1.4, nan"):
        import_bag(nan_bag, tmp_path / "seq", "/scan", "/cam/image", odometry_topic="/tf")
    args = [
        "import-bag",
        str(bag),
        "--scan-topic",
        "/scan",
        "--image-topic",
        "/cam/image",
        "--odometry-topic",
        "/tf",
    ]
    assert main([*args, "--odometry-frames", "odom", "-o", str(tmp_path / "t")]) == 3
    assert "--odometry-frames: got 'odom'; expected PARENT,CHILD" in capsys.readouterr().err
    assert main([*args, "--odometry-frames", "/odom,base_link", "-o", str(tmp_path / "u")]) == 0
    assert read_sequence(tmp_path / "u").odometry is not None
