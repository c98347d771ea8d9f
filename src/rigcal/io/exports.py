"""A rig in the formats other tools read: ROS tf, URDF, Kalibr-style YAML, mrcal.

Every export says which way its transform goes, in the text itself. The frames are
rigcal's (docs/conventions.md): the camera frame is an optical frame (x right, y down,
z forward; ROS calls it e.g. ``camera_optical_frame``) and the laser frame is ROS's
(REP 103: x forward, y left, z up). A ROS transform from a parent to a child frame is the
child's pose in the parent: it maps child-frame points into the parent frame, so parent
``laser`` and child ``camera`` is T_laser_cam, and parent ``camera`` is T_cam_laser.

All functions are pure (text in, text out); :func:`export_rig` picks one by name.
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from rigcal.errors import InputError
from rigcal.geometry import rt_from_T
from rigcal.rig import Rig

FloatArray = NDArray[np.float64]

FORMATS = ("ros", "urdf", "kalibr", "mrcal")

# Kalibr's pinhole-radtan camera has OpenCV's first four coefficients (k1, k2, p1, p2).
_KALIBR_LENSMODELS = ("LENSMODEL_PINHOLE", "LENSMODEL_OPENCV4", "LENSMODEL_OPENCV5")


def transform_between(rig: Rig, parent: str) -> tuple[FloatArray, str, str]:
    """(T_parent_child, parent name, child name) for parent "laser" or "camera"."""
    if parent == "laser":
        return rig.T_laser_cam, "laser", "camera"
    if parent == "camera":
        return np.asarray(rig.T_cam_laser, dtype=float), "camera", "laser"
    raise ValueError(f"parent must be 'laser' or 'camera', not {parent!r}")


def _xyz_quat(T: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Translation (3,) and quaternion (x, y, z, w) (ROS order) of a transform."""
    q = Rotation.from_matrix(T[:3, :3]).as_quat()  # scipy: scalar last, as ROS
    if q[3] < 0:
        q = -q
    return T[:3, 3], q


def _short(frame: str) -> str:
    return "cam" if frame == "camera" else frame


def _f(x: float) -> str:
    return f"{float(x):.9g}"


def ros_static_transform(
    rig: Rig, parent: str = "laser", parent_frame: str | None = None, child_frame: str | None = None
) -> str:
    """ROS 1 and ROS 2 ``static_transform_publisher`` commands and launch-file lines."""
    T, p, c = transform_between(rig, parent)
    pf = parent_frame or ("laser" if p == "laser" else "camera_optical_frame")
    cf = child_frame or ("camera_optical_frame" if c == "camera" else "laser")
    xyz, q = _xyz_quat(T)
    args1 = " ".join(_f(v) for v in (*xyz, *q)) + f" {pf} {cf}"
    args2 = (
        f"--x {_f(xyz[0])} --y {_f(xyz[1])} --z {_f(xyz[2])} --qx {_f(q[0])} --qy {_f(q[1])} "
        f"--qz {_f(q[2])} --qw {_f(q[3])} --frame-id {pf} --child-frame-id {cf}"
    )
    return "\n".join(
        [
            f"# rigcal rig as a ROS static transform: parent {pf}, child {cf}.",
            f"# It is the pose of {cf} in {pf}: it maps points in {cf} into {pf}",
            f"# (T_{_short(p)}_{_short(c)} in rigcal's notation). Quaternion in ROS order (x, y, z, w).",
            f"# {cf} is an optical frame (x right, y down, z forward)"
            if c == "camera"
            else f"# {pf} is an optical frame (x right, y down, z forward)",
            "",
            "# ROS 1:",
            f"rosrun tf2_ros static_transform_publisher {args1}",
            f'<node pkg="tf2_ros" type="static_transform_publisher" name="{pf}_to_{cf}" args="{args1}"/>',
            "",
            "# ROS 2:",
            f"ros2 run tf2_ros static_transform_publisher {args2}",
            f'<node pkg="tf2_ros" exec="static_transform_publisher" name="{pf}_to_{cf}" args="{args2}"/>',
            "",
        ]
    )


def urdf_joint(
    rig: Rig, parent: str = "laser", parent_link: str | None = None, child_link: str | None = None
) -> str:
    """A fixed URDF joint placing the child link in the parent link."""
    T, p, c = transform_between(rig, parent)
    pl = parent_link or ("laser" if p == "laser" else "camera_optical_frame")
    cl = child_link or ("camera_optical_frame" if c == "camera" else "laser")
    # URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z: R = Rz Ry Rx.
    # At pitch +-pi/2 (e.g. parent camera, optical axis along the laser's x) scipy warns of
    # gimbal lock; the angles it returns still give the same rotation, so the warning is noise.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Gimbal lock detected", category=UserWarning)
        rpy = Rotation.from_matrix(T[:3, :3]).as_euler("xyz")
    xyz = T[:3, 3]
    return "\n".join(
        [
            f"<!-- rigcal rig as a URDF joint: the pose of {cl} in {pl} (maps points in {cl}",
            f"     into {pl}; T_{_short(p)}_{_short(c)} in rigcal's notation).",
            "     rpy: fixed-axis roll, pitch, yaw (rad). -->",
            f'<joint name="{pl}_to_{cl}" type="fixed">',
            f'  <parent link="{pl}"/>',
            f'  <child link="{cl}"/>',
            f'  <origin xyz="{" ".join(_f(v) for v in xyz)}" rpy="{" ".join(_f(v) for v in rpy)}"/>',
            "</joint>",
            "",
        ]
    )


def kalibr_yaml(rig: Rig) -> str:
    """A Kalibr-style camera chain entry with the laser in place of the IMU.

    Raises:
        InputError: the lens model has no Kalibr equivalent (only pinhole with up to the
            four radtan coefficients k1, k2, p1, p2 can be written).
    """
    cam = rig.camera
    intr = np.asarray(cam.intrinsics, dtype=float)
    if cam.lensmodel not in _KALIBR_LENSMODELS or (cam.lensmodel == "LENSMODEL_OPENCV5" and intr[8] != 0.0):
        raise InputError(
            f"camera: lens model {cam.lensmodel}"
            + (f" with k3 = {intr[8]:g}" if cam.lensmodel == "LENSMODEL_OPENCV5" else "")
            + " has no Kalibr equivalent; expected pinhole with at most k1, k2, p1, p2 (radtan)"
        )
    dist = [float(x) for x in intr[4:8]] if len(intr) > 4 else [0.0, 0.0, 0.0, 0.0]
    T = np.asarray(rig.T_cam_laser, dtype=float)
    doc: dict[str, Any] = {
        "cam0": {
            "T_cam_laser": [[float(x) for x in row] for row in T],
            "camera_model": "pinhole",
            "intrinsics": [float(x) for x in intr[:4]],
            "distortion_model": "radtan",
            "distortion_coeffs": dist,
            "resolution": [int(cam.width_px), int(cam.height_px)],
        }
    }
    head = (
        "# rigcal rig, Kalibr camchain style. T_cam_laser (4x4, row-major) maps laser-frame points\n"
        "# into the camera frame, as Kalibr's T_cam_imu maps IMU-frame points. intrinsics: fu, fv, pu, pv.\n"
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


def export_rig(rig: Rig, fmt: str, parent: str = "laser") -> str:
    """The rig as text in format ``fmt`` (one of :data:`FORMATS`)."""
    if fmt == "ros":
        return ros_static_transform(rig, parent)
    if fmt == "urdf":
        return urdf_joint(rig, parent)
    if fmt == "kalibr":
        return kalibr_yaml(rig)
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


def T_from_urdf_origin(xyz: list[float], rpy: list[float]) -> FloatArray:
    """T_parent_child from a URDF joint origin."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    T[:3, 3] = xyz
    return T
