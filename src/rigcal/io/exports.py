"""A rig in the formats other tools read: ROS tf, URDF (and xacro), Kalibr camchain, mrcal.

Every export says which way its transform goes, in the text itself. The frames are
rigcal's (docs/conventions.md): the camera frame is an optical frame (x right, y down,
z forward; ROS calls it e.g. ``camera_optical_frame``) and the laser frame is ROS's
(REP 103: x forward, y left, z up). A ROS transform from a parent to a child frame is the
child's pose in the parent: it maps child-frame points into the parent frame, so parent
``laser`` and child ``camera`` is T_laser_cam, and parent ``camera`` is T_cam_laser.

With :class:`Frames` ``camera_link`` the camera end is instead the camera's body frame
(REP 103 axes), the frame a camera driver hangs its optical frame from.

All functions are pure (text in, text out); :func:`export_rig` picks one by name.

Names reach other languages here: frame names become XML attributes and comments (URDF,
xacro, launch files) and shell words (``rosrun``, ``ros2 run``). They are checked against
the ROS name rules (:func:`ros_name`) and, as a second fence, escaped for each language
(:func:`_attr`, :func:`_comment`, ``shlex.quote``).
"""

from __future__ import annotations

import re
import shlex
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.geometry import inv_T, make_T, rt_from_T

if TYPE_CHECKING:  # the rig is only named here; exports take one built elsewhere
    from rigcal.rig import Rig


FORMATS = ("ros", "urdf", "xacro", "kalibr", "mrcal")

# The camera's body frame (REP 103: x forward, y left, z up) from its optical frame
# (x right, y down, z forward): R_link_optical, the rotation a camera driver publishes
# from ``camera_link`` to ``camera_optical_frame`` (q = (-0.5, 0.5, -0.5, 0.5)).
R_LINK_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


# A ROS name (wiki.ros.org/Names, design.ros2.org "Topic and Service name mapping"): tokens
# of a letter then letters, digits and '_', joined by '/'. tf2 frame ids take no leading
# '/' (ROS 2 refuses them); topics are absolute ('/' first) here. No '__' (reserved in ROS
# 2), no trailing '_' or '/'.
_TOKENS = r"[A-Za-z][A-Za-z0-9_]*(?:/[A-Za-z][A-Za-z0-9_]*)*"
_FRAME_RE = re.compile(_TOKENS)
_TOPIC_RE = re.compile("/" + _TOKENS)
MAX_ROS_NAME = 200
FRAME_NAME_RULE = (
    "a ROS frame name: a letter, then letters, digits and '_' (tokens joined by '/'; "
    "no leading '/', no '__', no trailing '_')"
)
TOPIC_NAME_RULE = "a ROS topic name: '/', then tokens of a letter, letters, digits and '_' joined by '/'"


def ros_name(name: object, key: str, topic: bool = False) -> str:
    """``name`` if it is a ROS frame name (or, with ``topic``, an absolute topic name).

    Raises:
        InputError: ``KEY: got NAME; expected a ROS frame name ...``.
    """
    pattern, rule = (_TOPIC_RE, TOPIC_NAME_RULE) if topic else (_FRAME_RE, FRAME_NAME_RULE)
    if (
        not isinstance(name, str)
        or len(name) > MAX_ROS_NAME
        or not pattern.fullmatch(name)
        or "__" in name
        or name.endswith("_")
    ):
        raise InputError.at(None, key, name, rule)
    return name


def _attr(value: str) -> str:
    """``value`` escaped for a double-quoted XML attribute."""
    return value.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;").replace('"', "&quot;")


def _comment(text: str) -> str:
    """``text`` safe inside an XML comment (which may not hold ``--`` nor end in ``-``)."""
    while "--" in text:
        text = text.replace("--", "- -")
    return text + " " if text.endswith("-") else text


@dataclass(frozen=True)
class Frames:
    """Which frames an export joins, and their names.

    Attributes:
        parent: "laser" or "camera": which sensor is the transform's parent.
        camera_link: attach to the camera's body frame (``camera_link``, REP 103 axes)
            instead of its optical frame, so that the camera driver's own
            ``camera_link -> camera_optical_frame`` transform stays the only parent of the
            optical frame.
        parent_frame, child_frame: names to use instead of the defaults (``laser``,
            ``camera_optical_frame`` or ``camera_link``).
    """

    parent: str = "laser"
    camera_link: bool = False
    parent_frame: str | None = None
    child_frame: str | None = None

    def __post_init__(self) -> None:
        """Frame names are checked here, before they reach any export."""
        for key, name in (("parent_frame", self.parent_frame), ("child_frame", self.child_frame)):
            if name is not None:
                ros_name(name, key)
        pf, cf = self.names()
        if pf == cf:
            raise InputError.at(None, "child_frame", cf, "a name other than the parent frame's")

    def camera_name(self) -> str:
        return "camera_link" if self.camera_link else "camera_optical_frame"

    def names(self) -> tuple[str, str]:
        """(parent frame name, child frame name)."""
        p, c = ("laser", self.camera_name()) if self.parent == "laser" else (self.camera_name(), "laser")
        return self.parent_frame or p, self.child_frame or c


def transform_between(rig: Rig, parent: str, camera_link: bool = False) -> tuple[FloatArray, str, str]:
    """(T_parent_child, parent sensor, child sensor) for parent "laser" or "camera".

    With ``camera_link`` the camera end is the camera's body frame:
    T_laser_link = T_laser_cam @ T_optical_link.
    """
    if parent not in ("laser", "camera"):
        raise ValueError(f"parent must be 'laser' or 'camera', not {parent!r}")
    T_laser_cam = np.asarray(rig.T_laser_cam, dtype=float)
    if camera_link:
        T_laser_cam = T_laser_cam @ make_T(R_LINK_OPTICAL.T, np.zeros(3))
    if parent == "laser":
        return T_laser_cam, "laser", "camera"
    return inv_T(T_laser_cam), "camera", "laser"


def _xyz_quat(T: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Translation (3,) and quaternion (x, y, z, w) (ROS order) of a transform."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # scipy: scalar last, as ROS
    if q[3] < 0:
        q = -q
    return T[:3, 3], q


def _short(frame: str, camera_link: bool) -> str:
    return ("link" if camera_link else "cam") if frame == "camera" else frame


def _f(x: float) -> str:
    return f"{float(x):.9g}"


def _direction(rig: Rig, frames: Frames) -> tuple[FloatArray, str, str, list[str]]:
    """(T_parent_child, parent name, child name, comment lines stating the direction)."""
    T, p, c = transform_between(rig, frames.parent, frames.camera_link)
    pf, cf = frames.names()
    cam = cf if c == "camera" else pf
    axes = (
        f"{cam} is the camera's body frame (x forward, y left, z up; REP 103); its optical "
        "frame (x right, y down, z forward) is camera_link rotated by q = (-0.5, 0.5, -0.5, 0.5)"
        if frames.camera_link
        else f"{cam} is an optical frame (x right, y down, z forward)"
    )
    lines = [
        f"the pose of {cf} in {pf}: it maps points in {cf} into {pf}",
        f"(T_{_short(p, frames.camera_link)}_{_short(c, frames.camera_link)} in rigcal's notation).",
        axes,
    ]
    return T, pf, cf, lines


def ros_static_transform(rig: Rig, frames: Frames | None = None) -> str:
    """ROS 1 and ROS 2 ``static_transform_publisher`` commands and launch-file lines."""
    T, pf, cf, what = _direction(rig, frames or Frames())
    xyz, q = _xyz_quat(T)
    words1 = [*(_f(v) for v in (*xyz, *q)), pf, cf]
    words2 = [
        *("--x", _f(xyz[0]), "--y", _f(xyz[1]), "--z", _f(xyz[2])),
        *("--qx", _f(q[0]), "--qy", _f(q[1]), "--qz", _f(q[2]), "--qw", _f(q[3])),
        *("--frame-id", pf, "--child-frame-id", cf),
    ]
    node = _attr(f"{pf}_to_{cf}".replace("/", "_"))  # a node name has no '/'
    return "\n".join(
        [
            f"# rigcal rig as a ROS static transform: parent {pf}, child {cf}.",
            f"# It is {what[0]}",
            f"# {what[1]} Quaternion in ROS order (x, y, z, w).",
            f"# {what[2]}.",
            "",
            "# ROS 1:",
            f"rosrun tf2_ros static_transform_publisher {shlex.join(words1)}",
            f'<node pkg="tf2_ros" type="static_transform_publisher" name="{node}" '
            f'args="{_attr(shlex.join(words1))}"/>',
            "",
            "# ROS 2:",
            f"ros2 run tf2_ros static_transform_publisher {shlex.join(words2)}",
            f'<node pkg="tf2_ros" exec="static_transform_publisher" name="{node}" '
            f'args="{_attr(shlex.join(words2))}"/>',
            "",
        ]
    )


def _origin(T: FloatArray) -> str:
    # URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z: R = Rz Ry Rx.
    # At pitch +-pi/2 (e.g. parent camera, optical axis along the laser's x) scipy warns of
    # gimbal lock; the angles it returns still give the same rotation, so the warning is noise.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected", category=UserWarning)
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    return f'<origin xyz="{" ".join(_f(v) for v in T[:3, 3])}" rpy="{" ".join(_f(v) for v in rpy)}"/>'


def _xml_head(title: str, what: list[str], usage: tuple[str, ...] = ()) -> list[str]:
    return [
        '<?xml version="1.0"?>',
        "<!-- " + _comment(f"rigcal rig as {title} places {what[0]}"),
        _comment(f"     {what[1]}"),
        _comment(f"     {what[2]}."),
        *(_comment(u) for u in usage),
        "     rpy: fixed-axis roll, pitch, yaw (rad). -->",
    ]


def _joint(parent: str, child: str, T: FloatArray, indent: str) -> list[str]:
    return [
        f'{indent}<joint name="{_attr(parent)}_to_{_attr(child)}" type="fixed">',
        f'{indent}  <parent link="{_attr(parent)}"/>',
        f'{indent}  <child link="{_attr(child)}"/>',
        f"{indent}  {_origin(T)}",
        f"{indent}</joint>",
    ]


def urdf_robot(rig: Rig, frames: Frames | None = None, robot_name: str = "rigcal_rig") -> str:
    """A loadable URDF ``<robot>``: both sensor links and the fixed joint between them."""
    T, pf, cf, what = _direction(rig, frames or Frames())
    return "\n".join(
        [
            *_xml_head(f"a URDF robot: the joint {pf}_to_{cf}", what),
            f'<robot name="{_attr(robot_name)}">',
            f'  <link name="{_attr(pf)}"/>',
            f'  <link name="{_attr(cf)}"/>',
            *_joint(pf, cf, T, "  "),
            "</robot>",
            "",
        ]
    )


def urdf_xacro(rig: Rig, frames: Frames | None = None) -> str:
    """A xacro file with one macro, ``rigcal_rig``, to include in a robot description.

    The macro adds the child link and the fixed joint; the parent link (by default the
    parent frame's name, ``parent:=...`` to attach elsewhere) is the including robot's.
    """
    T, pf, cf, what = _direction(rig, frames or Frames())
    usage = (
        '     Use: <xacro:include filename="rig.xacro"/> <xacro:rigcal_rig/>',
        f"     (parent:=LINK if your robot calls {pf} otherwise).",
    )
    return "\n".join(
        [
            *_xml_head("a xacro macro: the joint", what, usage),
            '<robot xmlns:xacro="http://www.ros.org/wiki/xacro">',
            f'  <xacro:macro name="rigcal_rig" params="parent:={_attr(pf)} child:={_attr(cf)}">',
            '    <link name="${child}"/>',
            *_joint("${parent}", "${child}", T, "    "),
            "  </xacro:macro>",
            "</robot>",
            "",
        ]
    )


# Kalibr's pinhole camera with its radtan distortion has OpenCV's first four coefficients
# (k1, k2, p1, p2); OpenCV's k3..k6 must be zero for the same lens to be written.
_KALIBR_LENSMODELS = ("LENSMODEL_PINHOLE", "LENSMODEL_OPENCV4", "LENSMODEL_OPENCV5", "LENSMODEL_OPENCV8")


def kalibr_yaml(rig: Rig, rostopic: str = "/camera/image_raw", source: str | Path | None = None) -> str:
    """A Kalibr camchain (``camchain-imucam.yaml``) with the laser in the IMU's place.

    Kalibr reads the extrinsics of a camera-IMU chain from ``T_cam_imu`` (it maps IMU-frame
    points into the camera frame); here the "IMU" frame is the laser, so it holds
    T_cam_laser. ``source`` names the rig file in error messages.

    Raises:
        InputError: the lens model has no Kalibr equivalent (pinhole with radtan
            distortion holds k1, k2, p1, p2 only; OpenCV's k3..k6 must be 0).
    """
    cam = rig.camera
    intr = np.asarray(cam.intrinsics, dtype=float)
    extra = intr[8:]
    if cam.lensmodel not in _KALIBR_LENSMODELS:
        raise InputError.at(
            source,
            "camera.lensmodel",
            cam.lensmodel,
            "a pinhole lens model Kalibr can hold (LENSMODEL_PINHOLE, or LENSMODEL_OPENCV4/5/8 "
            "with k3..k6 = 0); "
            "use --format mrcal for this lens",
        )
    if np.any(extra != 0.0):
        names = ("k3", "k4", "k5", "k6")
        raise InputError.at(
            source,
            "camera.intrinsics",
            {n: float(v) for n, v in zip(names, extra, strict=False) if v != 0.0},
            f"k3..k6 = 0 for Kalibr's radtan distortion (k1, k2, p1, p2; {cam.lensmodel}); "
            "recalibrate with LENSMODEL_OPENCV4 or use --format mrcal",
        )
    ros_name(rostopic, "--rostopic", topic=True)
    dist = [float(x) for x in intr[4:8]] if len(intr) > 4 else [0.0, 0.0, 0.0, 0.0]
    T = np.asarray(rig.T_cam_laser, dtype=float)
    doc: dict[str, Any] = {
        "cam0": {
            "T_cam_imu": [[float(x) for x in row] for row in T],
            "cam_overlaps": [],
            "camera_model": "pinhole",
            "distortion_coeffs": dist,
            "distortion_model": "radtan",
            "intrinsics": [float(x) for x in intr[:4]],
            "resolution": [int(cam.width_px), int(cam.height_px)],
            "rostopic": rostopic,
        }
    }
    head = (
        "# rigcal rig as a Kalibr camchain (camchain-imucam.yaml), the laser in the IMU's place:\n"
        "# T_cam_imu is T_cam_laser (4x4, row-major); it maps laser-frame points into the camera\n"
        "# (optical) frame, as Kalibr's T_cam_imu maps IMU-frame points. intrinsics: fu, fv, pu, pv.\n"
    )
    return head + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110)


def mrcal_cameramodel_text(rig: Rig) -> str:
    """A mrcal ``.cameramodel`` whose reference frame is the laser: its extrinsics
    ``rt_cam_ref`` are rt_cam_laser (mrcal's ``extrinsics_rt_fromref``)."""
    import io

    import mrcal

    model = mrcal.cameramodel(
        intrinsics=(rig.camera.lensmodel, np.asarray(rig.camera.intrinsics, dtype=float)),
        imagersize=np.array([rig.camera.width_px, rig.camera.height_px]),
        extrinsics_rt_fromref=rt_from_T(rig.T_cam_laser),
    )
    buf = io.StringIO()
    model.write(
        buf,
        note="rigcal rig: the reference frame is the laser; extrinsics map laser points into the camera",
    )
    return buf.getvalue()


def export_rig(
    rig: Rig,
    fmt: str,
    frames: Frames | None = None,
    rostopic: str = "/camera/image_raw",
    source: str | Path | None = None,
) -> str:
    """The rig as text in format ``fmt`` (one of :data:`FORMATS`); ``frames`` applies to
    ros, urdf and xacro, ``rostopic`` to kalibr; ``source`` names the rig file in errors."""
    if fmt == "ros":
        return ros_static_transform(rig, frames)
    if fmt == "urdf":
        return urdf_robot(rig, frames)
    if fmt == "xacro":
        return urdf_xacro(rig, frames)
    if fmt == "kalibr":
        return kalibr_yaml(rig, rostopic, source)
    if fmt == "mrcal":
        return mrcal_cameramodel_text(rig)
    raise ValueError(f"format must be one of {FORMATS}, not {fmt!r}")


def T_from_ros_args(args: list[str]) -> tuple[FloatArray, str, str]:
    """Parse ROS 1 ``static_transform_publisher`` arguments ``x y z qx qy qz qw parent child``
    back into (T_parent_child, parent, child) (for round trips and users' own files)."""
    if len(args) != 9:
        raise ValueError("expected x y z qx qy qz qw parent child")
    v = np.array([float(a) for a in args[:7]])
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(v[3:7]).as_matrix()
    T[:3, 3] = v[:3]
    return T, args[7], args[8]
