"""Bags: the odometry's orientations and stamps as drivers write them. A quaternion that is
zero (no orientation filled in), NaN or off unit length beyond what tf2 accepts would give
a wrong heading (the yaw of a quaternion of norm 1/sqrt(2) about z is half its angle): it
is refused naming the bag, topic, message and field (exit 3, nothing written); one within
tf2's tolerance is normalised. An odometry or IMU message stamped 0 (a driver that does
not stamp) takes its record time, as scans and images do, and is counted. An IMU whose
angular_velocity_covariance[0] is -1 (sensor_msgs/Imu: the rate is not given) is no
gyroscope: the bag's only IMU is then left out, said on the summary line; one asked for
with --imu-topic is refused."""

from __future__ import annotations

import numpy as np
import pytest
from rosbags.rosbag2 import Writer as Writer2
from test_bag import TS2, _msgs

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence

T = TS2.types
VEC = T["geometry_msgs/msg/Vector3"]
QUAT = T["geometry_msgs/msg/Quaternion"]
RECORD_S = 100.0  # the recorder's clock at the first message; messages every 0.5 s after it


def _q(yaw: float, scale: float = 1.0):
    return (0.0, 0.0, scale * np.sin(yaw / 2), scale * np.cos(yaw / 2))


def _hdr(t: float, frame: str):
    time = T["builtin_interfaces/msg/Time"](sec=int(t), nanosec=round((t - int(t)) * 1e9))
    return T["std_msgs/msg/Header"](stamp=time, frame_id=frame)


def _bag(path, quats, stamped=True, via_tf=False, mount=(0.0, 0.0, 0.0, 1.0), imu_stamped=None, rate=0.0):
    """Three scans and images stamped at the record time; four odometry poses (x = 0.5 k,
    orientation ``quats[k]``), on /odom or as /tf's odom -> base_link, stamped at their
    record time or 0; /tf_static base_link -> laser with rotation ``mount`` and an unrelated
    camera link whose rotation is zero; with ``imu_stamped`` (True or False) an IMU topic."""
    scan, image, _, _ = _msgs(TS2)
    ser = TS2.serialize_cdr
    record = [RECORD_S + 0.5 * k for k in range(4)]

    def odom(k):
        pose = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=0.5 * k, y=0.0, z=0.0), orientation=QUAT(*quats[k])
        )
        return T["nav_msgs/msg/Odometry"](
            header=_hdr(record[k] if stamped else 0.0, "odom"), child_frame_id="base_link",
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=VEC(x=0.0, y=0.0, z=0.0),
                                                   angular=VEC(x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36),
            ),
        )  # fmt: skip

    def transform(parent, child, t, q, x=0.0):
        tf = T["geometry_msgs/msg/Transform"](translation=VEC(x=x, y=0.0, z=0.0), rotation=QUAT(*q))
        return T["geometry_msgs/msg/TransformStamped"](
            header=_hdr(t, parent), child_frame_id=child, transform=tf
        )

    def tf(k):
        t = record[k] if stamped else 0.0
        return T["tf2_msgs/msg/TFMessage"](
            transforms=[
                transform("map", "odom", t, _q(0.3)),
                transform("odom", "base_link", t, quats[k], 0.5 * k),
            ]
        )

    def imu(t):
        return T["sensor_msgs/msg/Imu"](
            header=_hdr(t, "laser"),
            orientation=QUAT(0.0, 0.0, 0.0, 1.0), orientation_covariance=np.zeros(9),
            angular_velocity=VEC(x=0.0, y=0.0, z=0.1), angular_velocity_covariance=np.r_[rate, np.zeros(8)],
            linear_acceleration=VEC(x=0.0, y=0.0, z=-9.8), linear_acceleration_covariance=np.zeros(9),
        )  # fmt: skip

    static = T["tf2_msgs/msg/TFMessage"](
        transforms=[
            transform("base_link", "laser", 0.0, mount, 0.3),
            transform("base_link", "camera", 0.0, (0.0, 0.0, 0.0, 0.0)),
        ]
    )
    with Writer2(path, version=8) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=TS2)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=TS2)
        kind = "tf2_msgs/msg/TFMessage" if via_tf else "nav_msgs/msg/Odometry"
        co = w.add_connection("/tf" if via_tf else "/odom", kind, typestore=TS2)
        ct = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=TS2)
        cm = (
            w.add_connection("/imu", "sensor_msgs/msg/Imu", typestore=TS2)
            if imu_stamped is not None
            else None
        )
        w.write(ct, int(1e9 * (RECORD_S - 1)), ser(static, "tf2_msgs/msg/TFMessage"))
        for k in range(4):
            ns = round(1e9 * record[k])
            if k < 3:
                w.write(cs, ns, ser(scan(record[k] + 0.25, k), "sensor_msgs/msg/LaserScan"))
                w.write(ci, ns + 1, ser(image(record[k] + 0.25, k), "sensor_msgs/msg/Image"))
            w.write(co, ns + 2, ser(tf(k) if via_tf else odom(k), kind))
        for j in range(30) if cm is not None else ():
            t = RECORD_S + 0.05 * j
            w.write(cm, round(1e9 * t) + 3, ser(imu(t if imu_stamped else 0.0), "sensor_msgs/msg/Imu"))
    return path


def _import(bag, out, **kw):
    topic = "/tf" if kw.pop("via_tf", False) else "/odom"
    return import_bag(bag, out, "/scan", "/cam/image", odometry_topic=topic, imu_topic="none", **kw)


UNIT = [_q(0.1 * k) for k in range(4)]


@pytest.mark.parametrize("via_tf", [False, True])
@pytest.mark.parametrize("scale", [0.999, 1.004])  # squared norms within tf2's 0.01 of 1
def test_a_nearly_unit_quaternion_is_normalised(tmp_path, via_tf, scale):
    bag = _bag(tmp_path / "b", [_q(0.1 * k, scale) for k in range(4)], via_tf=via_tf)
    _import(bag, tmp_path / "seq", via_tf=via_tf)
    od = read_sequence(tmp_path / "seq").odometry
    assert od is not None
    np.testing.assert_allclose(od.poses[:, 2], [0.0, 0.1, 0.2, 0.3], atol=1e-9)
    np.testing.assert_allclose(od.T_base_laser, [0.3, 0.0, 0.0], atol=1e-9)


@pytest.mark.parametrize("via_tf", [False, True])
@pytest.mark.parametrize(
    ("quat", "shown"),
    [
        (_q(0.2, 1 / np.sqrt(2)), r"\[0.0, 0.0, 0.070\d*, 0.703\d*\] \(norm 0.707107\)"),  # read as 0.1 rad
        ((0.0, 0.0, 0.0, 0.0), r"\[0.0, 0.0, 0.0, 0.0\] \(norm 0\)"),
        ((0.0, 0.0, float("nan"), 1.0), r"\[0.0, 0.0, nan, 1.0\] \(norm nan\)"),
    ],
)
def test_an_odometry_quaternion_off_unit_length_is_refused(tmp_path, capsys, via_tf, quat, shown):
    bag = _bag(tmp_path / "b", [*UNIT[:2], quat, UNIT[3]], via_tf=via_tf)
    key = r"transforms\[1\]\.transform\.rotation" if via_tf else r"pose\.pose\.orientation"
    topic = "/tf" if via_tf else "/odom"
    with pytest.raises(
        InputError, match=rf"b: {topic} message 2: {key}: got '{shown}'; expected a unit quaternion"
    ):
        _import(bag, tmp_path / "seq", via_tf=via_tf)
    argv = ["import-bag", str(bag), "--imu-topic", "none"]  # the bag's only scan and image topics
    assert main([*argv, "--odometry-topic", topic, "-o", str(tmp_path / "out")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert [line for line in err if line.startswith("Error: ")] == err[-1:]
    assert err[-1].endswith("as tf2 takes them)")
    assert not (tmp_path / "out").exists()


def test_the_mounting_from_a_tf_static_rotation_off_unit_length_is_refused(tmp_path):
    # The unrelated base_link -> camera link's zero rotation is never read; the laser's is.
    bag = _bag(tmp_path / "b", UNIT, mount=(0.0, 0.0, 0.0, 0.5))
    with pytest.raises(
        InputError,
        match=r"b: /tf_static message 0: transforms\[0\]\.transform\.rotation: got '\[0.0, 0.0, 0.0, 0.5\] "
        r"\(norm 0.5\)'; expected a unit quaternion",
    ):
        _import(bag, tmp_path / "seq")
    assert not (tmp_path / "seq").exists()


@pytest.mark.parametrize("via_tf", [False, True])
def test_odometry_stamped_0_takes_its_record_time(tmp_path, via_tf):
    bag = _bag(tmp_path / "b", UNIT, stamped=False, via_tf=via_tf)
    s = _import(bag, tmp_path / "seq", via_tf=via_tf)
    topic = "/tf" if via_tf else "/odom"
    assert s.unstamped == {topic: 4}
    assert f"4 {topic} messages with header.stamp 0" in " ".join(s.notes())
    seq = read_sequence(tmp_path / "seq")
    assert seq.odometry is not None
    np.testing.assert_allclose(seq.odometry.stamps_s, RECORD_S + 0.5 * np.arange(4) + 2e-9, atol=1e-6)
    assert seq.source["unstamped_record_time"] == {topic: 4}
    key = r"transforms\[1\]\.header\.stamp" if via_tf else r"header\.stamp"
    with pytest.raises(InputError, match=rf"b: {topic} message 0: {key}: got 0.0; expected a stamp set by"):
        _import(bag, tmp_path / "strict", via_tf=via_tf, stamps="strict")


def test_imu_messages_stamped_0_take_their_record_time(tmp_path):
    bag = _bag(tmp_path / "b", UNIT, imu_stamped=False)
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", imu_topic="/imu")
    assert s.unstamped == {"/imu": 30}
    gyro = read_sequence(tmp_path / "seq").gyro
    assert gyro is not None
    np.testing.assert_allclose(gyro.stamps_s, RECORD_S + 0.05 * np.arange(30), atol=1e-6)
    with pytest.raises(InputError, match=r"b: /imu message 0: header\.stamp: got 0.0; expected a stamp set"):
        import_bag(bag, tmp_path / "strict", "/scan", "/cam/image", imu_topic="/imu", stamps="strict")


def test_an_imu_without_its_angular_velocity_is_no_gyro(tmp_path, capsys):
    bag = _bag(tmp_path / "b", UNIT, imu_stamped=True, rate=-1.0)
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")  # the bag's only IMU
    assert s.gyro == 0
    assert "IMU topic /imu not read: its angular_velocity_covariance[0] is -1" in " ".join(s.notes())
    seq = read_sequence(tmp_path / "seq")
    assert seq.gyro is None
    assert "imu_topic" not in seq.source
    with pytest.raises(
        InputError,
        match=r"b: /imu message 0: angular_velocity_covariance\[0\]: got -1.0; expected an IMU that measures",
    ):
        import_bag(bag, tmp_path / "asked", "/scan", "/cam/image", imu_topic="/imu")
    assert not (tmp_path / "asked").exists()
    argv = ["-q", "import-bag", str(bag), "--imu-topic", "/imu", "-o", str(tmp_path / "cli")]
    assert main(argv) == 3
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith("--imu-topic none reads no IMU)")


@pytest.mark.parametrize("via_tf", [False, True])
def test_an_odometry_tilted_off_the_floor_is_refused(tmp_path, via_tf):
    # Rolled 180 deg (z down, as NED): its heading would read mirrored. 0.1 rad of roll is read.
    roll = (np.sin(0.05), 0.0, 0.0, np.cos(0.05))
    bag = _bag(tmp_path / "ok", [*UNIT[:2], roll, UNIT[3]], via_tf=via_tf)
    _import(bag, tmp_path / "seq", via_tf=via_tf)
    bag = _bag(tmp_path / "b", [*UNIT[:2], (1.0, 0.0, 0.0, 0.0), UNIT[3]], via_tf=via_tf)
    key = r"transforms\[1\]\.transform\.rotation" if via_tf else r"pose\.pose\.orientation"
    with pytest.raises(
        InputError,
        match=rf"b: /(tf|odom) message 2: {key}: got 'tilted 180.0 deg'; expected planar odometry "
        r"\(z axis up; frames with z down, as NED, are not the ROS odometry's ENU\)",
    ):
        _import(bag, tmp_path / "bad", via_tf=via_tf)
