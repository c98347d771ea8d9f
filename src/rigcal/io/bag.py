"""ROS 1 and ROS 2 bags into sequence folders, with the rosbags package (no ROS install).

Reads ``sensor_msgs/LaserScan`` (scans), ``sensor_msgs/Image`` or
``sensor_msgs/CompressedImage`` (images) and, when given, ``sensor_msgs/CameraInfo``
(the camera). Stamps are the messages' header stamps. Messages out of time order are
sorted, exact duplicates of a stamp are dropped; both are counted in the summary so that
nothing is silently changed.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.errors import InputError
from rigcal.io.sequence import ImageFrame, write_sequence
from rigcal.io.validate import real
from rigcal.scan import Scan

log = logging.getLogger(__name__)

SCAN_TYPES = ("sensor_msgs/msg/LaserScan",)
IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)


@dataclass
class ImportSummary:
    """What an import did."""

    scans: int = 0
    images: int = 0
    camera: bool = False
    reordered: dict[str, int] = field(default_factory=dict)
    duplicates: dict[str, int] = field(default_factory=dict)


def import_bag(
    bag: str | Path,
    output: str | Path,
    scan_topic: str,
    image_topic: str,
    camera_info_topic: str | None = None,
    force: bool = False,
    progress: Callable[[int, int], None] | None = None,
) -> ImportSummary:
    """Write a sequence folder from a bag. ``progress`` is called with (messages read,
    messages on the wanted topics).

    Raises:
        InputError: unreadable bag, a missing topic (the bag's topics are listed), a topic
            of the wrong type, an empty topic, or an image encoding that cannot be stored.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = Path(bag)
    if not bag.exists():
        raise InputError(f"{bag}: bag not found")
    try:
        reader = AnyReader([bag], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.open()
    except Exception as exc:  # rosbags raises its own errors for unreadable bags
        raise InputError(f"{bag}: not a readable ROS 1 or ROS 2 bag: {str(exc).strip()[:120]}") from None
    try:
        topics = {c.topic: c.msgtype for c in reader.connections}
        wanted = {"scan": (scan_topic, SCAN_TYPES), "image": (image_topic, IMAGE_TYPES)}
        if camera_info_topic is not None:
            wanted["camera_info"] = (camera_info_topic, INFO_TYPES)
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
        scans: list[tuple[float, Scan]] = []
        images: list[tuple[float, bytes, str]] = []
        info: Any = None
        conns = [c for c in reader.connections if c.topic in {t for t, _ in wanted.values()}]
        total = sum(int(c.msgcount) for c in conns)
        for k, (con, _, raw) in enumerate(reader.messages(connections=conns)):
            msg: Any = reader.deserialize(raw, con.msgtype)
            stamp = float(msg.header.stamp.sec) + 1e-9 * float(msg.header.stamp.nanosec)
            if con.topic == scan_topic:
                scans.append((stamp, _scan(msg, stamp, f"{bag}: {scan_topic} at {stamp:.9f} s")))
            elif con.topic == image_topic:
                data, ext = _image_bytes(msg, con.msgtype, bag, image_topic)
                images.append((stamp, data, ext))
            elif info is None:
                info = msg
            if progress is not None:
                progress(k + 1, total)
    finally:
        reader.close()
    log.info("%s: %d scans, %d images read from %d messages", bag, len(scans), len(images), total)
    summary = ImportSummary()
    for what, items, topic in (("scans", scans, scan_topic), ("images", images, image_topic)):
        if not items:
            raise InputError.at(bag, topic, "no messages", f"a topic with {what}")
    scans_sorted, summary.reordered["scans"], summary.duplicates["scans"] = _ordered(scans)
    images_sorted, summary.reordered["images"], summary.duplicates["images"] = _ordered(images)
    frames = [ImageFrame(stamp, f"{i:06d}.{ext}", data) for i, (stamp, data, ext) in enumerate(images_sorted)]
    camera_yaml = _camera_yaml(info) if info is not None else None
    write_sequence(
        output,
        bag.name,
        [s for _, s in scans_sorted],
        frames,
        camera_yaml,
        {
            "bag": str(bag.resolve()),
            "scan_topic": scan_topic,
            "image_topic": image_topic,
            "camera_info_topic": camera_info_topic,
        },
        force=force,
    )
    summary.scans, summary.images, summary.camera = len(scans_sorted), len(frames), camera_yaml is not None
    return summary


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


def _scan(msg: Any, stamp: float, where: str) -> Scan:
    """A LaserScan message as a scan; its geometry checked (finite, angles within 2 pi,
    0 <= range_min < range_max), -inf ranges ("too close", REP 117) as 0 (no return) and
    other negative ranges refused. A negative ``angle_increment`` (a scanner sweeping
    clockwise, angle_max < angle_min) gives the same beams in reverse order, so that the
    angles increase (docs/formats/scan.md)."""
    two_pi = 2 * np.pi
    a0 = real(float(msg.angle_min), where, "angle_min", lo=-two_pi, hi=two_pi)
    r = np.asarray(msg.ranges, dtype=float)
    r = np.where(r == -np.inf, 0.0, r)
    if len(r) == 0:
        raise InputError.at(where, "ranges", [], "at least one range")
    step = real(float(msg.angle_increment), where, "angle_increment", lo=-two_pi, hi=two_pi)
    if len(r) > 1 and step == 0:
        raise InputError.at(where, "angle_increment", step, "a non-zero step (rad)")
    lo = real(float(msg.range_min), where, "range_min", nonneg=True)
    hi = real(float(msg.range_max), where, "range_max", positive=True)
    if lo >= hi:
        raise InputError.at(where, "range_min", lo, f"less than range_max = {hi:g}")
    with np.errstate(invalid="ignore"):
        negative = np.flatnonzero(r < 0)
    if len(negative):
        k = int(negative[0])
        raise InputError.at(where, f"ranges[{k}]", float(r[k]), "a range >= 0 (NaN, inf, -inf: no return)")
    if step < 0:
        a0, step, r = a0 + step * (len(r) - 1), -step, r[::-1]
    return Scan.from_uniform(a0, step, r, lo, hi, stamp)


def _image_bytes(msg: Any, msgtype: str, bag: Path, topic: str) -> tuple[bytes, str]:
    """Encoded image bytes and their extension: compressed images as they are, raw images
    as lossless PNG."""
    import cv2

    if msgtype.endswith("CompressedImage"):
        fmt = str(msg.format).lower()
        ext = "png" if "png" in fmt else "jpg"
        return bytes(msg.data), ext
    enc = str(msg.encoding).lower()
    h, w = int(msg.height), int(msg.width)
    data = np.frombuffer(bytes(msg.data), dtype=np.uint16 if enc in ("mono16", "16uc1") else np.uint8)
    if enc in ("mono8", "8uc1", "mono16", "16uc1"):
        img = data.reshape(h, -1)[:, :w]
    elif enc in ("bgr8", "rgb8", "8uc3"):
        img = data.reshape(h, -1)[:, : 3 * w].reshape(h, w, 3)
        if enc == "rgb8":
            img = img[:, :, ::-1]
    else:
        raise InputError.at(bag, f"{topic}.encoding", enc, "mono8, mono16, bgr8 or rgb8")
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:  # pragma: no cover - cv2 encodes any 8/16-bit image
        raise InputError(f"{bag}: {topic}: cannot encode an image as PNG")
    return bytes(buf.tobytes()), "png"


def _camera_yaml(info: Any) -> str:
    """A rigcal camera file from a CameraInfo message (plumb_bob / rational_polynomial)."""
    from rigcal.camera import Camera, camera_to_opencv_yaml

    # ROS 2 names the fields k, d; ROS 1 names them K, D.
    K = np.asarray(info.k if hasattr(info, "k") else info.K, dtype=float).reshape(3, 3)
    d = [float(x) for x in np.asarray(info.d if hasattr(info, "d") else info.D, dtype=float)]
    if len(d) not in (0, 4, 5, 8, 12):
        raise InputError.at(None, "camera_info.d", d, "0, 4, 5, 8 or 12 distortion coefficients")
    return camera_to_opencv_yaml(Camera.from_opencv(K, d, int(info.width), int(info.height)))
