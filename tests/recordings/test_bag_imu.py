"""Bags: a sensor_msgs/Imu topic as the gyroscope, rotated into the scans' frame by /tf_static."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rosbags.rosbag2 import Writer as Writer2
from test_bag import TS2, _msgs

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence


def _imu_bag(path, imu_stamps, rates=None, frame="imu_link", topics=("/imu",), static=True):
    """Scans (frame laser) at 1.0, 1.5, 2.0 s, an image each; IMU messages on ``topics`` at
    ``imu_stamps`` in ``frame``; /tf_static: base_link -> laser (turned 90 deg about z) and
    base_link -> imu_link (upside down: 180 deg about x), so the laser's yaw rate is minus
    the IMU's z rate."""
    ts = TS2
    T = ts.types
    scan, image, _, _ = _msgs(ts)
    time = T["builtin_interfaces/msg/Time"]
    vec = T["geometry_msgs/msg/Vector3"]
    q = T["geometry_msgs/msg/Quaternion"]

    def hdr(t, f):
        return T["std_msgs/msg/Header"](stamp=time(sec=int(t), nanosec=round((t - int(t)) * 1e9)), frame_id=f)

    def imu(t, w):
        return T["sensor_msgs/msg/Imu"](
            header=hdr(t, frame),
            orientation=q(x=0.0, y=0.0, z=0.0, w=1.0), orientation_covariance=np.zeros(9),
            angular_velocity=vec(x=0.3, y=-0.2, z=w), angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vec(x=0.0, y=0.0, z=-9.8), linear_acceleration_covariance=np.zeros(9),
        )  # fmt: skip

    def tf_static():
        st = T["geometry_msgs/msg/TransformStamped"]
        tr = T["geometry_msgs/msg/Transform"]
        yaw90 = q(x=0.0, y=0.0, z=np.sin(np.pi / 4), w=np.cos(np.pi / 4))
        flip = q(x=1.0, y=0.0, z=0.0, w=0.0)
        return T["tf2_msgs/msg/TFMessage"](
            transforms=[
                st(header=hdr(0.0, "base_link"), child_frame_id="laser",
                   transform=tr(translation=vec(x=0.2, y=0.0, z=0.3), rotation=yaw90)),
                st(header=hdr(0.0, "base_link"), child_frame_id="imu_link",
                   transform=tr(translation=vec(x=0.0, y=0.1, z=0.1), rotation=flip)),
            ]
        )  # fmt: skip

    rates = np.linspace(0.0, 0.5, len(imu_stamps)) if rates is None else rates
    with Writer2(path, version=8) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=ts)
        cimus = [w.add_connection(t, "sensor_msgs/msg/Imu", typestore=ts) for t in topics]
        if static:
            ct = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=ts)
            w.write(ct, int(1e9 * 9), ts.serialize_cdr(tf_static(), "tf2_msgs/msg/TFMessage"))
        for k, t in enumerate([1.0, 1.5, 2.0]):
            w.write(cs, int(1e9 * (10 + k)), ts.serialize_cdr(scan(t, k), "sensor_msgs/msg/LaserScan"))
            w.write(ci, int(1e9 * (10 + k)) + 1, ts.serialize_cdr(image(t, k), "sensor_msgs/msg/Image"))
        for c in cimus:
            for k, (t, r) in enumerate(zip(imu_stamps, rates, strict=True)):
                w.write(c, int(1e9 * 10) + k, ts.serialize_cdr(imu(t, float(r)), "sensor_msgs/msg/Imu"))
    return path


def test_the_only_imu_topic_is_the_gyro_rotated_into_the_scans_frame(tmp_path):
    stamps = np.arange(0.9, 2.1, 0.01)
    rates = 0.2 * np.sin(stamps)
    bag = _imu_bag(tmp_path / "b", stamps, rates)
    s = import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert s.gyro == len(stamps)
    seq = read_sequence(tmp_path / "seq")
    assert seq.source["imu_topic"] == "/imu"
    assert seq.gyro is not None
    np.testing.assert_allclose(seq.gyro.stamps_s, stamps, atol=1e-9)
    # Upside down: the laser turns the other way; the x and y rates have no part in its yaw.
    np.testing.assert_allclose(seq.gyro.rates_rad_s, -rates, atol=1e-12)
    # --imu-topic none: no gyro, as before.
    s = import_bag(bag, tmp_path / "none", "/scan", "/cam/image", imu_topic="none")
    assert s.gyro == 0
    assert not read_sequence(tmp_path / "none").has_gyro


def test_an_imu_in_the_scans_frame_needs_no_transform(tmp_path):
    stamps = np.arange(0.9, 2.1, 0.01)
    bag = _imu_bag(tmp_path / "b", stamps, frame="laser", static=False)
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", imu_topic="/imu")
    gyro = read_sequence(tmp_path / "seq").gyro
    assert gyro is not None
    np.testing.assert_allclose(gyro.rates_rad_s, np.linspace(0.0, 0.5, len(stamps)), atol=1e-12)


def test_several_imu_topics_and_none_chosen_keep_none_and_say_so(tmp_path, capsys):
    stamps = np.arange(0.9, 2.1, 0.01)
    bag = _imu_bag(tmp_path / "b", stamps, topics=("/imu", "/imu2"))
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "seq")]) == 0
    out = capsys.readouterr().out
    assert "IMU topics ['/imu', '/imu2'], none read (--imu-topic T keeps one as the gyro)" in out
    assert not read_sequence(tmp_path / "seq").has_gyro
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "s2"), "--imu-topic", "/imu2", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["gyro_samples"] == len(stamps)


@pytest.mark.parametrize(
    ("stamps", "rates", "frame", "message"),
    [
        ([0.9, 1.0, 1.0, 1.1], None, "imu_link", r"b: /imu: gyro stamp 2: got 1.0; expected a stamp after"),
        ([0.9, 1.0, 1.1], [0.0, float("nan"), 0.0], "imu_link", r"b: /imu: gyro sample 1: got \[1.0, nan\]"),
        (
            [5.0, 5.1, 5.2],
            None,
            "imu_link",
            r"b: /imu: gyro stamps: got '5.0 to 5.2'; expected a span overlapping",
        ),
        (
            [0.9, 1.0, 1.1],
            None,
            "imu_other",
            r"b: /imu: header.frame_id: got 'imu_other'; expected the scans' frame 'laser' or a frame linked",
        ),
    ],
)
def test_bad_imu_messages_are_one_line_errors_and_nothing_is_written(
    tmp_path, capsys, stamps, rates, frame, message
):
    """Repeated stamps, a NaN rate, a span missing the scans', a frame /tf_static does not
    link to the scans': one line naming the bag and topic (exit 3), no folder."""
    bag = _imu_bag(tmp_path / "b", np.array(stamps), None if rates is None else np.array(rates), frame=frame)
    with pytest.raises(InputError, match=message):
        import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert not (tmp_path / "seq").exists()
    assert main(["import-bag", str(bag), "-o", str(tmp_path / "seq")]) == 3
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[-1].startswith(f"Error: {bag}: /imu: ")
    assert not (tmp_path / "seq").exists()
