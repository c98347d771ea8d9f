"""ROS 1 and ROS 2 bags into sequence folders, with the rosbags package (no ROS install).

Reads ``sensor_msgs/LaserScan`` (scans), ``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage`` (images) and, when given, ``sensor_msgs/CameraInfo``
(the camera). Stamps are the messages' header stamps. Messages out of time order are
sorted, exact duplicates of a stamp are dropped; both are counted in the summary so that
nothing is silently changed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from rigcal.errors import InputError
from rigcal.io.gyro import Gyro
from rigcal.io.gyro import checked as checked_gyro
from rigcal.io.images import eight_bit_pngs
from rigcal.io.stamps import outside_scans
from rigcal.io.validate import real
from rigcal.io.wheel_odometry import WheelOdometry, check_level, checked
from rigcal.recordings.sequence import ImageFrame, write_sequence
from rigcal.scan import Scan

log = logging.getLogger(__name__)

SCAN_TYPES = ("sensor_msgs/msg/LaserScan",)
TF_TYPES = ("tf2_msgs/msg/TFMessage",)
# The odometry: nav_msgs/Odometry, or tf's transform between two frames (odom -> base_link).
ODOMETRY_TYPES = ("nav_msgs/msg/Odometry", *TF_TYPES)
ODOMETRY_FRAMES = ("odom", "base_link")
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
IMU_TYPES = ("sensor_msgs/msg/Imu",)
# ``--imu-topic``: no IMU read, even where the bag has one.
NO_IMU = "none"


@dataclass
class ImportSummary:
    """What an import did."""

    scans: int = 0
    images: int = 0
    camera: bool = False
    reordered: dict[str, int] = field(default_factory=dict)
    duplicates: dict[str, int] = field(default_factory=dict)
    odometry: int = 0
    gyro: int = 0  # the IMU's samples kept as gyro.csv
    imu_topics: list[str] = field(default_factory=list)  # several IMU topics, none chosen
    imu_no_rate: str = ""  # the bag's only IMU topic, not read: its angular velocity not given
    # What the import converted by a documented rule (docs/formats/sequence.md#from-bags):
    scan_counts: dict[str, int] = field(default_factory=dict)  # returns at range_max, beams past a turn, ...
    outside: dict[str, int] = field(default_factory=dict)  # images before the first scan, after the last
    depth: dict[str, int] = field(default_factory=dict)  # 16-bit images: frames, max_level, shift_bits
    unstamped: dict[str, int] = field(default_factory=dict)  # topic -> messages stamped 0 (record time used)
    unread_info: list[str] = field(default_factory=list)  # CameraInfo topics the bag has, none asked for

    def record(self) -> dict[str, Any]:
        """The conversions made, for the sequence's ``source`` (none: nothing)."""
        out: dict[str, Any] = {k: v for k, v in self.scan_counts.items() if v}
        if any(self.outside.values()):
            out["images_outside_scans"] = dict(self.outside)
        if self.depth:
            out["images_16_bit"] = dict(self.depth)
        if self.unstamped:
            out["unstamped_record_time"] = dict(self.unstamped)
        return out

    def notes(self) -> list[str]:
        """One phrase per conversion made, for the command's summary line."""
        out = []
        if self.scan_counts.get("returns_at_range_max"):
            out.append(f"{self.scan_counts['returns_at_range_max']} ranges at range_max (no return)")
        if self.scan_counts.get("range_max_inf"):
            out.append(f"{self.scan_counts['range_max_inf']} scans with range_max inf (no limit)")
        if self.scan_counts.get("beams_past_one_turn"):
            out.append(f"{self.scan_counts['beams_past_one_turn']} beams past one full turn (dropped)")
        if any(self.outside.values()):
            out.append(
                f"{self.outside['before']} images before the first scan and {self.outside['after']} "
                "after the last (kept; check and localize's image methods leave them out)"
            )
        if self.imu_topics:
            out.append(f"IMU topics {self.imu_topics}, none read (--imu-topic T keeps one as the gyro)")
        if self.imu_no_rate:
            out.append(
                f"IMU topic {self.imu_no_rate} not read: its angular_velocity_covariance[0] is -1 "
                "(no angular velocity given)"
            )
        for topic, n in self.unstamped.items():
            out.append(f"{n} {topic} messages with header.stamp 0 (stamped with their record time)")
        if self.depth:
            d = self.depth
            out.append(
                f"{d['frames']} 16-bit images stored as 8 bits (levels up to {d['max_level']}: "
                f"shifted right by {d['shift_bits']} bits)"
            )
        if self.unread_info:
            out.append(
                f"CameraInfo topic(s) {self.unread_info} not read: no camera.yaml "
                "(--camera-info-topic TOPIC writes it)"
            )
        return out


ROS2_METADATA = "metadata.yaml"
ROS2_STORAGE = (".db3", ".mcap")  # sqlite3 and MCAP storage


def bag_files(paths: Sequence[Path]) -> list[Path]:
    """The files of a bag as given: a ROS 1 ``.bag``, a ROS 2 bag's folder (with its
    ``metadata.yaml``), its ``metadata.yaml``, one of its ``.db3`` or ``.mcap`` files, or
    a folder of such files copied without their ``metadata.yaml`` (each a part of the
    bag: rosbags reads them alone), in name order.

    Raises:
        InputError: a path that does not exist, or a folder with neither a metadata.yaml
            nor a .db3 or .mcap file.
    """
    out: list[Path] = []
    for b in paths:
        if b.name == ROS2_METADATA and b.is_file():
            b = b.parent
        if not b.exists():
            raise InputError(f"{b}: bag not found")
        if b.is_dir() and not (b / ROS2_METADATA).is_file():
            found = sorted(f for f in b.iterdir() if f.suffix in ROS2_STORAGE and f.is_file())
            if not found:
                raise InputError(
                    f"{b}: got a folder without {ROS2_METADATA} or a .db3 or .mcap file; expected a ROS 2 "
                    "bag's folder (its metadata.yaml and storage files) or a ROS 1 .bag file"
                )
            out += found
            continue
        out.append(b)
    return out


def import_bag(
    bag: str | Path,
    output: str | Path,
    scan_topic: str | None,
    image_topic: str | None,
    camera_info_topic: str | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
    stamps: str = "repair",
    odometry_topic: str | None = None,
    laser_offset: NDArray[np.float64] | None = None,
    odometry_frames: tuple[str, str] = ODOMETRY_FRAMES,
    more: Sequence[str | Path] = (),
    imu_topic: str | None = None,
) -> ImportSummary:
    """Write a sequence folder from a bag. ``progress`` is called with (messages read,
    messages on the wanted topics). ``stamps="strict"`` refuses messages out of time order
    and repeated stamps instead of sorting and dropping them. ``odometry_topic``: a
    nav_msgs/Odometry topic kept as the wheel odometry, or a tf topic (tf2_msgs/TFMessage,
    as /tf) whose transforms ``odometry_frames`` (parent, child: odom -> base_link by
    default) are; the laser's mounting from ``laser_offset`` or else the bag's /tf_static
    (:func:`bag_odometry`). ``scan_topic`` and ``image_topic`` None: the bag's only topic
    of that type. ``more``: the further files of a bag recorded in parts (``rosbag record
    --split``), read with ``bag`` as one bag, their messages in time order. ``imu_topic``: a
    sensor_msgs/Imu topic whose angular velocity, rotated into the scans' frame, is kept as
    the gyroscope (:func:`bag_gyro`); None: the bag's only one, if it has one;
    :data:`NO_IMU`: none.

    Raises:
        InputError: unreadable bag, a missing topic (the bag's topics are listed), a topic
            of the wrong type, an empty topic, an image encoding that cannot be stored,
            stamps out of order (strict), or odometry or an IMU that cannot be used.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = Path(bag)
    if bag.name == ROS2_METADATA and bag.is_file():  # a ROS 2 bag named by its metadata file
        bag = bag.parent
    parts = bag_files([bag, *(Path(b) for b in more)])
    if len(set(parts)) < len(parts):
        raise InputError.at(bag, "BAG", [str(b) for b in parts], "each part of a bag given once")
    more = parts[1:]
    try:
        reader = AnyReader(parts, default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own errors for unreadable bags
        raise InputError(f"{bag}: not a readable ROS 1 or ROS 2 bag: {str(exc).strip()[:120]}") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        scan_topic = scan_topic or _only_topic(bag, topics, "--scan-topic", SCAN_TYPES)
        image_topic = image_topic or _only_topic(bag, topics, "--image-topic", IMAGE_TYPES)
        if odometry_topic == TF_STATIC:  # fixed transforms (the mounting), no motion
            raise InputError.at(
                bag,
                "--odometry-topic",
                odometry_topic,
                f"the odometry over time: a nav_msgs/Odometry topic or /tf (its odom -> base_link); "
                f"{TF_STATIC} holds fixed transforms, read for the laser's mounting",
            )
        imus = sorted(t for t, kind in topics.items() if kind in IMU_TYPES)
        summary = ImportSummary()
        if imu_topic is None and len(imus) > 1:
            summary.imu_topics = imus
        imu_chosen = imu_topic is None  # the bag's only IMU, not asked for
        imu_topic = (imus[0] if len(imus) == 1 else None) if imu_topic is None else imu_topic
        imu_topic = None if imu_topic == NO_IMU else imu_topic
        wanted = {"scan": (scan_topic, SCAN_TYPES), "image": (image_topic, IMAGE_TYPES)}
        if camera_info_topic is not None:
            wanted["camera_info"] = (camera_info_topic, INFO_TYPES)
        if odometry_topic is not None:
            wanted["odometry"] = (odometry_topic, ODOMETRY_TYPES)
        if imu_topic is not None:
            wanted["imu"] = (imu_topic, IMU_TYPES)
        if (odometry_topic is not None or imu_topic is not None) and topics.get(TF_STATIC) in TF_TYPES:
            wanted["tf_static"] = (TF_STATIC, TF_TYPES)
        for what, (topic, types) in wanted.items():
            if topic not in topics:
                raise InputError.at(
                    bag,
                    f"--{what.replace('_', '-')}-topic",
                    topic,
                    f"one of the bag's topics {sorted(topics)}",
                )
            if topics[topic] not in types:
                raise InputError.at(bag, topic, topics[topic], f"a topic of type {' or '.join(types)}")
        if camera_info_topic is None:  # said on the summary line: a camera the bag has, not kept
            summary.unread_info = sorted(t for t, kind in topics.items() if kind in INFO_TYPES)
        scans: list[tuple[float, Scan]] = []
        images: list[tuple[float, bytes, str]] = []
        info: Any = None
        camera_yaml: str | None = None
        first_image: tuple[tuple[int, int], str] | None = None  # (width, height), where
        info_where = ""
        wheel = _WheelMessages(odometry_frames)
        conns = [c for c in reader.connections if c.topic in {t for t, _ in wanted.values()}]
        total = sum(int(c.msgcount) for c in conns)
        # A message is named by the file it is in (a part of a bag recorded in parts) and
        # its index on its topic there.
        seen: dict[tuple[str, str], int] = {}
        for k, (con, recorded_ns, raw) in enumerate(reader.messages(connections=conns)):
            part = str(getattr(con.owner, "path", bag)) if more else str(bag)
            n = seen.get((part, con.topic), 0)
            seen[(part, con.topic)] = n + 1
            where = f"{part}: {con.topic} message {n}"
            msg = _deserialize(reader, raw, con.msgtype, where)
            stamped = _Stamper(con.topic, where, recorded_ns, stamps == "strict", summary.unstamped)
            if con.topic in (odometry_topic, TF_STATIC):  # TFMessage has no header
                wheel.add(con.topic, msg, where, stamped)
                if progress is not None:
                    progress(k + 1, total)
                continue
            stamp = stamped(msg.header.stamp)
            if con.topic == imu_topic:
                if float(msg.angular_velocity_covariance[0]) == -1.0 and not wheel.imu_no_rate:
                    wheel.imu_no_rate = where  # sensor_msgs/Imu: -1 marks the rate as not given
                w = msg.angular_velocity
                wheel.imu.append((stamp, float(w.x), float(w.y), float(w.z)))
                wheel.imu_frames.add(str(msg.header.frame_id).lstrip("/"))
                if progress is not None:
                    progress(k + 1, total)
                continue
            if con.topic == scan_topic:
                wheel.scan_frame = wheel.scan_frame or str(msg.header.frame_id)
                scans.append((stamp, _scan(msg, stamp, where, summary.scan_counts)))
            elif con.topic == image_topic:
                data, ext, size = _image_bytes(msg, con.msgtype, where)
                first_image = first_image or (size, where)
                if size != first_image[0]:
                    raise InputError.at(
                        where, "size", _wxh(size), f"{_wxh(first_image[0])} like {first_image[1]}"
                    )
                images.append((stamp, data, ext))
            elif info is None:
                info = msg
                camera_yaml = _camera_yaml(msg, where)
                info_where = where
            if progress is not None:
                progress(k + 1, total)
        if (
            info is not None
            and first_image is not None
            and (int(info.width), int(info.height)) != first_image[0]
        ):
            raise InputError.at(
                info_where,
                "width x height",
                _wxh((int(info.width), int(info.height))),
                f"the images' size {_wxh(first_image[0])} ({first_image[1]}): a camera of other images",
            )
    finally:
        reader.close()
    log.info("%s: %d scans, %d images read from %d messages", bag, len(scans), len(images), total)
    for what, items, topic in (("scans", scans, scan_topic), ("images", images, image_topic)):
        if not items:
            raise InputError.at(bag, topic, "no messages", f"a topic with {what}")
    scans_sorted, summary.reordered["scans"], summary.duplicates["scans"] = _ordered(scans)
    images_sorted, summary.reordered["images"], summary.duplicates["images"] = _ordered(images)
    if stamps == "strict":
        _strict_order(bag, [(scan_topic, scans), (image_topic, images)])
    odometry = None
    scan_t = np.array([t for t, _ in scans_sorted])
    if odometry_topic is not None:
        odometry = bag_odometry(wheel, f"{bag}: {odometry_topic}", laser_offset, scan_t)
        summary.odometry = len(odometry.stamps_s)
    gyro = None
    if imu_topic is not None and wheel.imu_no_rate and imu_chosen:
        summary.imu_no_rate, imu_topic = imu_topic, None  # said on the summary line, no gyro
    elif imu_topic is not None and wheel.imu_no_rate:
        raise InputError.at(
            wheel.imu_no_rate,
            "angular_velocity_covariance[0]",
            -1.0,
            "an IMU that measures its angular velocity (-1 marks it as not given; "
            "--imu-topic none reads no IMU)",
        )
    elif imu_topic is not None:
        gyro = bag_gyro(wheel, f"{bag}: {imu_topic}", scan_t)
        summary.gyro = len(gyro.stamps_s)
    summary.outside = outside_scans(np.array([t for t, _, _ in images_sorted]), scan_t)
    datas, summary.depth = eight_bit_pngs([data for _, data, _ in images_sorted])
    images_sorted = [  # a converted frame is an 8-bit PNG
        (t, data, ext if data is was else "png")
        for (t, was, ext), data in zip(images_sorted, datas, strict=True)
    ]
    frames = [ImageFrame(stamp, f"{i:06d}.{ext}", data) for i, (stamp, data, ext) in enumerate(images_sorted)]
    write_sequence(
        output,
        bag.name,
        [s for _, s in scans_sorted],
        frames,
        camera_yaml,
        {
            "bag": str(bag.resolve()),
            **({"bag_parts": [str(b.resolve()) for b in parts]} if more else {}),
            "scan_topic": scan_topic,
            "image_topic": image_topic,
            "camera_info_topic": camera_info_topic,
            **({"odometry_topic": odometry_topic} if odometry_topic is not None else {}),
            **({"imu_topic": imu_topic} if imu_topic is not None else {}),
            **summary.record(),
        },
        force=force,
        odometry=odometry,
        gyro=gyro,
    )
    summary.scans, summary.images, summary.camera = len(scans_sorted), len(frames), camera_yaml is not None
    return summary


TF_STATIC = "/tf_static"


def _only_topic(bag: Path, topics: dict[str, str], option: str, types: tuple[str, ...]) -> str:
    """The bag's one topic of ``types``, for an option not given; else an error listing them."""
    found = sorted(t for t, kind in topics.items() if kind in types)
    if len(found) == 1:
        return found[0]
    what = " or ".join(x.rsplit("/", 1)[-1] for x in types)
    has = f"the bag's {what} topics {found}" if found else f"a {what} topic (the bag has {sorted(topics)})"
    raise InputError.at(bag, option, "not given", f"one of {has}" if found else has)


class _Stamper:
    """A message's header stamp in seconds; a stamp of 0 (a driver that leaves
    ``header.stamp`` unset) is the time the recorder got the message, counted per topic in
    ``counts``, or refused with ``strict`` (``--stamps strict``)."""

    def __init__(self, topic: str, where: str, recorded_ns: int, strict: bool, counts: dict[str, int]):
        self.topic, self.where, self.recorded_ns = topic, where, recorded_ns
        self.strict, self.counts = strict, counts

    def __call__(self, stamp: Any, key: str = "header.stamp") -> float:
        t = float(stamp.sec) + 1e-9 * float(stamp.nanosec)
        if t != 0.0:
            return t
        if self.strict:
            raise InputError.at(
                self.where, key, 0.0, "a stamp set by the driver (--stamps repair uses the record time)"
            )
        self.counts[self.topic] = self.counts.get(self.topic, 0) + 1
        return 1e-9 * float(self.recorded_ns)


class _WheelMessages:
    """The odometry topic's poses and /tf_static's transforms, gathered as the bag is read."""

    def __init__(self, tf_frames: tuple[str, str] = ODOMETRY_FRAMES) -> None:
        self.poses: list[tuple[float, float, float, float]] = []  # stamp, x, y, yaw
        self.frames: set[tuple[str, str]] = set()  # (frame_id, child_frame_id)
        self.tf_frames = tf_frames  # the odometry's transform on a tf topic (parent, child)
        self.tf_seen: set[tuple[str, str]] = set()  # every transform a tf topic carried
        self.via_tf = False
        self.static: dict[tuple[str, str], NDArray[np.float64]] = {}  # (parent, child) -> x y yaw
        self.static_R: dict[tuple[str, str], NDArray[np.float64]] = {}  # (parent, child) -> R_parent_child
        self.static_bad: dict[tuple[str, str], str] = {}  # (parent, child) -> why its rotation is refused
        self.scan_frame = ""
        self.imu: list[tuple[float, float, float, float]] = []  # stamp, angular velocity x y z (rad/s)
        self.imu_frames: set[str] = set()
        self.imu_no_rate = ""  # the first IMU message marking its angular velocity as not given

    def add(self, topic: str, msg: Any, where: str, stamped: Callable[..., float]) -> None:
        """One message of the odometry topic or of /tf_static; ``where`` names it, ``stamped``
        turns a header stamp into seconds (:class:`_Stamper`)."""
        if topic == TF_STATIC:
            for j, tf in enumerate(msg.transforms):
                t = tf.transform.translation
                key = (str(tf.header.frame_id).lstrip("/"), str(tf.child_frame_id).lstrip("/"))
                try:
                    R = _rotation(tf.transform.rotation, where, f"transforms[{j}].transform.rotation")
                except InputError as exc:  # a transform nothing may need: refused where it is used
                    self.static_bad[key] = str(exc)
                    continue
                self.static[key] = np.array([float(t.x), float(t.y), _yaw(R)])
                self.static_R[key] = R
            return
        if hasattr(msg, "transforms"):  # a tf topic: the odometry is one of its transforms
            self.via_tf = True
            for j, tf in enumerate(msg.transforms):
                key = (str(tf.header.frame_id).lstrip("/"), str(tf.child_frame_id).lstrip("/"))
                self.tf_seen.add(key)
                if key != self.tf_frames:
                    continue
                t = tf.transform.translation
                yaw = _planar_yaw(tf.transform.rotation, where, f"transforms[{j}].transform.rotation")
                stamp = stamped(tf.header.stamp, f"transforms[{j}].header.stamp")
                self.poses.append((stamp, float(t.x), float(t.y), yaw))
                self.frames.add(key)
            return
        p = msg.pose.pose
        yaw = _planar_yaw(p.orientation, where, "pose.pose.orientation")
        self.poses.append((stamped(msg.header.stamp), float(p.position.x), float(p.position.y), yaw))
        self.frames.add((str(msg.header.frame_id).lstrip("/"), str(msg.child_frame_id).lstrip("/")))


# A quaternion whose squared norm is off 1 by more than this is refused, as tf2 refuses
# one (its setTransform: "Ignoring transform ... because of an invalid quaternion"); within
# it (float32 rounding, a driver's integration) it is normalised.
QUATERNION_NORM2_TOLERANCE = 0.01


def _rotation(q: Any, where: str, key: str) -> NDArray[np.float64]:
    """R (3, 3) of a geometry_msgs/Quaternion (x y z w), normalised.

    Raises:
        InputError: a quaternion not finite, zero (a driver that fills no orientation) or
            off unit length by more than tf2 accepts (:data:`QUATERNION_NORM2_TOLERANCE`),
            whose heading would otherwise be read wrong (the yaw of a quaternion of norm
            1/sqrt(2) about z is half its angle).
    """
    quat = np.array([float(q.x), float(q.y), float(q.z), float(q.w)])
    norm2 = float(quat @ quat) if np.isfinite(quat).all() else np.nan
    if not abs(norm2 - 1.0) <= QUATERNION_NORM2_TOLERANCE:
        raise InputError.at(
            where,
            key,
            f"{quat.tolist()} (norm {np.sqrt(norm2):.6g})",
            f"a unit quaternion x y z w (squared norm within {QUATERNION_NORM2_TOLERANCE:g} of 1, as tf2 "
            "takes them)",
        )
    return np.asarray(Rotation.from_quat(quat / np.sqrt(norm2)).as_matrix())


def _planar_yaw(q: Any, where: str, key: str) -> float:
    """The heading of an odometry orientation, refused when not a unit quaternion
    (:func:`_rotation`) or tilted off the floor (z down: a heading read mirrored)."""
    R = _rotation(q, where, key)
    check_level(R[None], where, key, "frames with z down, as NED, are not the ROS odometry's ENU")
    return _yaw(R)


def _yaw(R: NDArray[np.float64]) -> float:
    """The heading of a rotation (about z)."""
    return float(np.arctan2(R[1, 0], R[0, 0]))


def bag_odometry(
    wheel: _WheelMessages,
    where: str,
    laser_offset: NDArray[np.float64] | None,
    scan_stamps_s: NDArray[np.float64],
) -> WheelOdometry:
    """The odometry topic's poses (T_odom_base: header.frame_id -> child_frame_id) as the
    wheel odometry. The laser's mounting: ``laser_offset`` when given; else 0 when the
    scans' frame is the odometry's child frame; else the /tf_static transform from the
    child frame to the scans' frame.

    Raises:
        InputError: messages that switch frames, no transform between the odometry's child
            frame and the scans' frame (unknown frames), and the checks of
            :func:`rigcal.io.wheel_odometry.checked` (stamps, NaN, no overlap).
    """
    if wheel.via_tf and not wheel.poses:
        parent, child = wheel.tf_frames
        raise InputError.at(
            where,
            "transforms",
            sorted(wheel.tf_seen),
            f"transforms {parent} -> {child} (--odometry-frames PARENT,CHILD)",
        )
    if len(wheel.frames) > 1:
        raise InputError.at(
            where, "frame_id -> child_frame_id", sorted(wheel.frames), "one pair of frames for the topic"
        )
    child = next(iter(wheel.frames))[1] if wheel.frames else ""
    if laser_offset is not None:
        mount = laser_offset
    elif child == wheel.scan_frame.lstrip("/"):
        mount = np.zeros(3)
    elif (child, wheel.scan_frame.lstrip("/")) in wheel.static:
        mount = wheel.static[(child, wheel.scan_frame.lstrip("/"))]
    elif (child, wheel.scan_frame.lstrip("/")) in wheel.static_bad:
        raise InputError(wheel.static_bad[(child, wheel.scan_frame.lstrip("/"))])
    else:
        raise InputError.at(
            where,
            "child_frame_id",
            child,
            f"the scans' frame {wheel.scan_frame!r} or a frame linked to it by a {TF_STATIC} transform "
            f"(known: {sorted(wheel.static)}); or give --laser-offset",
        )
    a = np.array(wheel.poses, dtype=float).reshape(-1, 4)
    order = np.argsort(a[:, 0], kind="stable")
    return checked(a[order, 0], a[order, 1:], mount, where, scan_stamps_s)


def bag_gyro(wheel: _WheelMessages, where: str, scan_stamps_s: NDArray[np.float64]) -> Gyro:
    """The IMU topic's angular velocities (its ``header.frame_id``'s axes) rotated into the
    scans' frame, their z component (the yaw rate about the laser's z axis), as the
    gyroscope: R_laser_imu from the scans' and the IMU's frames, the same frame or linked by
    a chain of /tf_static transforms (:func:`_static_rotation`).

    Raises:
        InputError: messages that switch frames, an IMU frame not linked to the scans',
            and the checks of :func:`rigcal.io.gyro.checked` (stamps, NaN, no overlap).
    """
    if len(wheel.imu_frames) > 1:
        raise InputError.at(where, "header.frame_id", sorted(wheel.imu_frames), "one frame for the topic")
    frame = next(iter(wheel.imu_frames), "")
    R = _static_rotation(wheel.static_R, wheel.scan_frame.lstrip("/"), frame)
    if R is None:
        raise InputError.at(
            where,
            "header.frame_id",
            frame,
            f"the scans' frame {wheel.scan_frame!r} or a frame linked to it by {TF_STATIC} transforms "
            f"(known: {sorted(wheel.static_R)}"
            + (
                f"; refused, their rotation not a unit quaternion: {sorted(wheel.static_bad)}"
                if wheel.static_bad
                else ""
            )
            + ")",
        )
    a = np.array(wheel.imu, dtype=float).reshape(-1, 4)
    order = np.argsort(a[:, 0], kind="stable")
    rates = (a[order, 1:] @ R.T)[:, 2]  # (R_laser_imu w_imu)_z
    return checked_gyro(a[order, 0], rates, where, scan_stamps_s)


def _static_rotation(
    static: dict[tuple[str, str], NDArray[np.float64]], target: str, source: str
) -> NDArray[np.float64] | None:
    """R_target_source through the /tf_static transforms (R_parent_child each, taken
    either way), or None when no chain links the two frames (breadth first)."""
    rotations: dict[str, NDArray[np.float64]] = {target: np.eye(3)}  # frame -> R_target_frame
    todo = [target]
    while todo:
        frame = todo.pop(0)
        for (parent, child), R in static.items():
            for a, b, R_ab in ((parent, child, R), (child, parent, R.T)):
                if a == frame and b not in rotations:
                    rotations[b] = rotations[a] @ R_ab
                    todo.append(b)
    return rotations.get(source)


def _strict_order(bag: Path, streams: list[tuple[str, list[Any]]]) -> None:
    """--stamps strict: the first message whose header stamp is not after the previous
    one's (in the bag's order) is an error."""
    for topic, items in streams:
        t = np.array([it[0] for it in items])
        bad = np.flatnonzero(np.diff(t) <= 0)
        if len(bad):
            k = int(bad[0]) + 1
            raise InputError.at(
                bag,
                f"{topic} message {k} header.stamp",
                float(t[k]),
                f"a stamp after the previous {t[k - 1]!r}",
            )


def _ordered(items: list[Any]) -> tuple[list[Any], int, int]:
    """Sorted by stamp; (items, how many were out of order, how many duplicate stamps dropped)."""
    stamps = np.array([it[0] for it in items])
    reordered = int((np.diff(stamps) < 0).sum()) if len(stamps) > 1 else 0
    order = np.argsort(stamps, kind="stable")
    out: list[Any] = []
    dup = 0
    for i in order:
        if out and items[i][0] == out[-1][0]:
            dup += 1
            continue
        out.append(items[i])
    return out, reordered, dup


def _deserialize(reader: Any, raw: bytes, msgtype: str, where: str) -> Any:
    """One message, or InputError naming it when its bytes do not make one of its type."""
    try:
        return reader.deserialize(raw, msgtype)
    except Exception as exc:  # rosbags raises struct/index/value errors on short bodies
        raise InputError(
            f"{where}: cannot decode a {msgtype} ({type(exc).__name__}: {str(exc).strip()[:80]})"
        ) from None


# A LaserScan's range_max of +inf says the driver sets no limit (ROS 2's
# pointcloud_to_laserscan by default: a double's maximum, inf as the message's float32):
# read as the largest range a float32 holds, so that every finite return is one.
NO_RANGE_LIMIT_M = float(np.finfo(np.float32).max)
# A real scanner's beam count is round((angle_max - angle_min) / angle_increment) + 1, but
# drivers differ by one (urg_node and sick_scan drop or add the end beam), so a count
# within one of it is accepted (docs/formats/sequence.md).
BEAM_COUNT_SLACK = 1


def _scan(msg: Any, stamp: float, where: str, counts: dict[str, int] | None = None) -> Scan:
    """A LaserScan message as a scan; its geometry checked (finite, angles within 2 pi,
    0 <= range_min < range_max, as many ranges as angle_min .. angle_max in steps of
    angle_increment give, within :data:`BEAM_COUNT_SLACK`), -inf ranges ("too close", REP
    117) as 0 (no return) and other negative ranges refused. A negative
    ``angle_increment`` (a scanner sweeping clockwise, angle_max < angle_min) gives the
    same beams in reverse order, so that the angles increase (docs/formats/scan.md). A range
    equal to ``range_max`` is no return (inf); a ``range_max`` of +inf is no limit
    (:data:`NO_RANGE_LIMIT_M`); beams past one full turn are dropped; ``counts``
    (``returns_at_range_max``, ``range_max_inf``, ``beams_past_one_turn``) adds them up."""
    two_pi = 2 * np.pi
    a0 = real(float(msg.angle_min), where, "angle_min", lo=-two_pi, hi=two_pi)
    a1 = real(float(msg.angle_max), where, "angle_max", lo=-two_pi, hi=two_pi)
    r = np.asarray(msg.ranges, dtype=float)
    r = np.where(r == -np.inf, 0.0, r)
    if len(r) == 0:
        raise InputError.at(where, "ranges", [], "at least one range")
    step = real(float(msg.angle_increment), where, "angle_increment", lo=-two_pi, hi=two_pi)
    if len(r) > 1 and step == 0:
        raise InputError.at(where, "angle_increment", step, "a non-zero step (rad)")
    if step != 0:
        n = round((a1 - a0) / step) + 1
        if abs(len(r) - n) > BEAM_COUNT_SLACK:
            raise InputError.at(
                where,
                "ranges",
                f"{len(r)} ranges",
                f"{n} (+-{BEAM_COUNT_SLACK}) = round((angle_max - angle_min) / angle_increment) + 1 "
                f"with angle_min {a0:g}, angle_max {a1:g}, angle_increment {step:g} rad",
            )
    lo = real(float(msg.range_min), where, "range_min", nonneg=True)
    unlimited = float(msg.range_max) == np.inf  # no limit: the largest range a LaserScan holds
    hi = NO_RANGE_LIMIT_M if unlimited else real(float(msg.range_max), where, "range_max", positive=True)
    if lo >= hi:
        raise InputError.at(where, "range_min", lo, f"less than range_max = {hi:g}")
    with np.errstate(invalid="ignore"):
        negative = np.flatnonzero(r < 0)
    if len(negative):
        k = int(negative[0])
        raise InputError.at(where, f"ranges[{k}]", float(r[k]), "a range >= 0 (NaN, inf, -inf: no return)")
    if step < 0:
        a0, step, r = a0 + step * (len(r) - 1), -step, r[::-1]
    # A range of exactly range_max is the driver's value for no return (or a return it
    # clipped), never a surface measured with noise: no return.
    at_max = r == hi
    if at_max.any():
        r = np.where(at_max, np.inf, r)
    # Beams more than half a step past one full turn from the first measure directions
    # already measured (a scan spanning over 360 deg): dropped, the first turn kept.
    turn = int(np.floor(2 * np.pi / step + 0.5)) + 1 if step > 0 else len(r)
    if counts is not None:
        counts["returns_at_range_max"] = counts.get("returns_at_range_max", 0) + int(at_max.sum())
        counts["range_max_inf"] = counts.get("range_max_inf", 0) + int(unlimited)
        counts["beams_past_one_turn"] = counts.get("beams_past_one_turn", 0) + max(0, len(r) - turn)
    return Scan.from_uniform(a0, step, r[:turn], lo, hi, stamp)


# Raw encodings stored as they are (sensor_msgs/image_encodings.h): bytes per channel, channels.
RAW_ENCODINGS = {
    "mono8": (1, 1), "8uc1": (1, 1), "mono16": (2, 1), "16uc1": (2, 1),
    "bgr8": (1, 3), "rgb8": (1, 3), "8uc3": (1, 3),
}  # fmt: skip
# Raw encodings real cameras also send, converted to BGR as cv_bridge converts them: bytes
# per channel, channels in the message, OpenCV's conversion. Alpha is dropped; a Bayer
# mosaic is demosaiced (ROS names the pattern's first row, OpenCV its second: ROS rggb is
# OpenCV's BG); packed YUV 4:2:2 (two bytes a pixel) is converted.
CONVERTED_ENCODINGS = {
    "bgra8": (1, 4, "COLOR_BGRA2BGR"), "8uc4": (1, 4, "COLOR_BGRA2BGR"), "rgba8": (1, 4, "COLOR_RGBA2BGR"),
    "bayer_rggb8": (1, 1, "COLOR_BayerBG2BGR"), "bayer_bggr8": (1, 1, "COLOR_BayerRG2BGR"),
    "bayer_gbrg8": (1, 1, "COLOR_BayerGR2BGR"), "bayer_grbg8": (1, 1, "COLOR_BayerGB2BGR"),
    "bayer_rggb16": (2, 1, "COLOR_BayerBG2BGR"), "bayer_bggr16": (2, 1, "COLOR_BayerRG2BGR"),
    "bayer_gbrg16": (2, 1, "COLOR_BayerGR2BGR"), "bayer_grbg16": (2, 1, "COLOR_BayerGB2BGR"),
    "yuv422": (1, 2, "COLOR_YUV2BGR_UYVY"), "uyvy": (1, 2, "COLOR_YUV2BGR_UYVY"),
    "yuv422_yuy2": (1, 2, "COLOR_YUV2BGR_YUY2"), "yuyv": (1, 2, "COLOR_YUV2BGR_YUY2"),
}  # fmt: skip
ENCODINGS_READ = (
    "mono8/8UC1, mono16/16UC1, bgr8, rgb8, 8UC3, bgra8, rgba8, 8UC4, bayer_rggb8, bayer_bggr8, "
    "bayer_gbrg8, bayer_grbg8 (or 16), yuv422 (uyvy) or yuv422_yuy2 (yuyv)"
)
# The largest image side accepted (as camera files: docs/formats/camera.md).
MAX_IMAGE_SIDE_PX = 10**6


def _wxh(size: tuple[int, int]) -> str:
    return f"{size[0]}x{size[1]}"


def _image_bytes(msg: Any, msgtype: str, where: str) -> tuple[bytes, str, tuple[int, int]]:
    """Encoded image bytes, their extension and the image's (width, height): compressed
    images as they are (once they decode), raw images as lossless PNG.

    A raw image must hold exactly ``height * step`` bytes with ``step >= width * bytes per
    pixel`` (whole pixels for 16-bit encodings) and both sides positive; big-endian 16-bit
    data are swapped to the machine's order."""
    import cv2

    from rigcal.io.images import decode

    if msgtype.endswith("CompressedImage"):
        data = bytes(msg.data)
        if data.startswith(b"\x89PNG\r\n\x1a\n"):
            ext = "png"
        elif data.startswith(b"\xff\xd8\xff"):
            ext = "jpg"
        else:
            raise InputError.at(
                where, "data", data[:8], f"PNG or JPEG bytes (format says {str(msg.format)[:40]!r})"
            )
        img = decode(data, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError.at(
                where, "data", f"{len(data)} bytes of {ext.upper()}", "an image that decodes (damaged data)"
            )
        return data, ext, (int(img.shape[1]), int(img.shape[0]))
    enc = str(msg.encoding).lower()
    if enc not in RAW_ENCODINGS and enc not in CONVERTED_ENCODINGS:
        raise InputError.at(where, "encoding", str(msg.encoding)[:40], ENCODINGS_READ)
    size, channels = RAW_ENCODINGS[enc] if enc in RAW_ENCODINGS else CONVERTED_ENCODINGS[enc][:2]
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    for key, v in (("height", h), ("width", w)):
        if not 0 < v <= MAX_IMAGE_SIDE_PX:
            raise InputError.at(where, key, v, f"a positive number of pixels (at most {MAX_IMAGE_SIDE_PX})")
    if channels == 2 and w % 2:  # 4:2:2 shares one colour between two pixels of a row
        raise InputError.at(where, "width", w, f"an even number of pixels ({enc}: two pixels share a colour)")
    if step < w * size * channels or step % size:
        raise InputError.at(
            where,
            "step",
            step,
            f"at least width * {size * channels} = {w * size * channels} bytes"
            + (f", a multiple of {size} ({enc})" if size > 1 else f" ({enc})"),
        )
    raw = bytes(msg.data)
    if len(raw) != h * step:
        raise InputError.at(
            where, "data", f"{len(raw)} bytes", f"height * step = {h} * {step} = {h * step} bytes"
        )
    dtype = np.dtype(np.uint16 if size == 2 else np.uint8)
    if size == 2:
        dtype = dtype.newbyteorder(">" if int(msg.is_bigendian) else "<")
    rows = np.frombuffer(raw, dtype=dtype).reshape(h, step // size)[:, : w * channels]
    img = rows.reshape(h, w, channels) if channels > 1 else rows
    if enc == "rgb8":
        img = img[:, :, ::-1]
    if enc in CONVERTED_ENCODINGS:
        if enc.startswith("bayer") and min(h, w) < 2:  # a mosaic's 2x2 cell
            raise InputError.at(where, "height x width", f"{h}x{w}", f"at least 2x2 pixels ({enc})")
        code = getattr(cv2, CONVERTED_ENCODINGS[enc][2])
        img = cv2.cvtColor(np.ascontiguousarray(img, dtype=img.dtype.newbyteorder("=")), code)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img, dtype=img.dtype.newbyteorder("=")))
    if not ok:  # pragma: no cover - cv2 encodes any 8/16-bit image
        raise InputError(f"{where}: cannot encode an image as PNG")
    return bytes(buf.tobytes()), "png", (w, h)


def _camera_yaml(info: Any, where: str) -> str:
    """A rigcal camera file from a CameraInfo message, checked as a ROS camera_info file is
    (docs/formats/camera.md: a positive size, a finite K with fx, fy > 0 and no skew,
    plumb_bob with 5 or rational_polynomial with 8 coefficients, or none), so that what is
    written can be read back."""
    from rigcal.camera import Camera, camera_to_opencv_yaml
    from rigcal.camera_formats import ROS_DISTORTION_MODELS, check_pinhole_K

    # ROS 2 names the fields k, d; ROS 1 names them K, D.
    K = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=float).reshape(3, 3)
    d = np.asarray(info.d if hasattr(info, "d") else info.D, dtype=float)
    w, h = int(info.width), int(info.height)
    for key, v in (("width", w), ("height", h)):
        if not 0 < v <= MAX_IMAGE_SIDE_PX:
            raise InputError.at(
                where, key, v, f"a positive image size in pixels (at most {MAX_IMAGE_SIDE_PX})"
            )
    if not np.all(np.isfinite(K)):
        raise InputError.at(where, "K", K.ravel().tolist(), "finite numbers")
    check_pinhole_K(K, where, "K")
    model = str(info.distortion_model)
    if len(d):
        if model not in ROS_DISTORTION_MODELS:
            raise InputError.at(
                where, "distortion_model", model[:40], f"one of {sorted(ROS_DISTORTION_MODELS)}"
            )
        if len(d) not in ROS_DISTORTION_MODELS[model] or not np.all(np.isfinite(d)):
            n = ROS_DISTORTION_MODELS[model][0]
            raise InputError.at(where, "D", d.tolist(), f"{n} finite coefficients for {model}")
    return camera_to_opencv_yaml(Camera.from_opencv(K, d.tolist(), w, h))
