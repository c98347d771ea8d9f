"""Rig exports (ROS tf, URDF, Kalibr, mrcal): round trips, the direction they state, and `rigcal export`."""

from __future__ import annotations

import json
import logging
import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import mrcal
import numpy as np
import pytest
import yaml
import yourdfpy
from kalibr_reader import KalibrCameraChain
from scipy.spatial.transform import Rotation

from rigcal.camera import Camera
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.geometry import inv_T, make_T, random_rotation, rt_from_T, transform_points
from rigcal.io.exports import (
    R_LINK_OPTICAL,
    Frames,
    T_from_ros_args,
    export_rig,
    kalibr_yaml,
    mrcal_cameramodel_text,
    ros_static_transform,
    urdf_robot,
    urdf_xacro,
)
from rigcal.rig import Rig
from rigcal.rigfile import read_rig, write_rig

K = np.array([[520.0, 0.0, 319.5], [0.0, 510.0, 241.25], [0.0, 0.0, 1.0]])
DIST5 = [-0.15, 0.05, 0.0005, -0.0003, 0.0]
DIST8 = [0.1, 0.01, 0.001, 0.002, 0.003, 0.01, 0.02, 0.03]
SEEDS = [0, 1, 2, 3, 4]
# The exports print 9 significant digits.
ATOL = 1e-8

# Camera 10 cm above the laser, optical axis along the laser's x (forward).
R_LASER_CAM_LEVEL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
T_LASER_CAM_LEVEL = make_T(R_LASER_CAM_LEVEL, [0.0, 0.0, 0.1])


def T_from_urdf_origin(xyz: list[float], rpy: list[float]) -> np.ndarray:
    """T_parent_child from a URDF joint origin (fixed-axis roll, pitch, yaw), read as ROS does."""
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
    T[:3, 3] = xyz
    return T


def camera(dist=DIST5) -> Camera:
    return Camera.from_opencv(K, dist, 640, 480)


def random_rig(seed: int, dist=DIST5) -> Rig:
    rng = np.random.default_rng(seed)
    T = make_T(random_rotation(rng), rng.uniform(-0.5, 0.5, 3))
    return Rig(T, camera(dist), np.diag([1e-6] * 3 + [1e-5] * 3))


def level_rig(dist=DIST5) -> Rig:
    return Rig(inv_T(T_LASER_CAM_LEVEL), camera(dist), None)


def line_starting(text: str, prefix: str) -> str:
    lines = [line for line in text.splitlines() if line.startswith(prefix)]
    assert len(lines) == 1, text
    return lines[0]


def ros1_args(text: str) -> list[str]:
    return line_starting(text, "rosrun tf2_ros static_transform_publisher ").split()[3:]


def ros2_options(args: list[str]) -> dict[str, str]:
    assert len(args) % 2 == 0
    return {args[i]: args[i + 1] for i in range(0, len(args), 2)}


def T_from_ros2(opts: dict[str, str]) -> np.ndarray:
    q = [float(opts[k]) for k in ("--qx", "--qy", "--qz", "--qw")]
    return make_T(Rotation.from_quat(q).as_matrix(), [float(opts[k]) for k in ("--x", "--y", "--z")])


def urdf_origin(text: str) -> tuple[np.ndarray, str, str]:
    robot = ET.fromstring(text)
    assert robot.tag == "robot"
    joint = robot.find("joint")
    assert joint is not None
    assert joint.tag == "joint"
    assert joint.get("type") == "fixed"
    origin = joint.find("origin")
    assert origin is not None
    xyz = [float(v) for v in origin.get("xyz", "").split()]
    rpy = [float(v) for v in origin.get("rpy", "").split()]
    parent, child = joint.find("parent"), joint.find("child")
    assert parent is not None
    assert child is not None
    return T_from_urdf_origin(xyz, rpy), parent.get("link", ""), child.get("link", "")


# --- ROS static transform ---------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_ros1_args_parent_laser_give_T_laser_cam(seed):
    rig = random_rig(seed)
    T, parent, child = T_from_ros_args(ros1_args(ros_static_transform(rig, Frames("laser"))))
    assert (parent, child) == ("laser", "camera_optical_frame")
    np.testing.assert_allclose(T, inv_T(rig.T_cam_laser), atol=ATOL)


@pytest.mark.parametrize("seed", SEEDS)
def test_ros1_args_parent_camera_give_T_cam_laser(seed):
    rig = random_rig(seed)
    T, parent, child = T_from_ros_args(ros1_args(ros_static_transform(rig, Frames("camera"))))
    assert (parent, child) == ("camera_optical_frame", "laser")
    np.testing.assert_allclose(T, rig.T_cam_laser, atol=ATOL)


@pytest.mark.parametrize("parent", ["laser", "camera"])
def test_ros1_launch_line_has_the_command_args(parent):
    text = ros_static_transform(random_rig(7), Frames(parent))
    node = ET.fromstring(line_starting(text, '<node pkg="tf2_ros" type='))
    assert node.get("type") == "static_transform_publisher"
    assert node.get("args", "").split() == ros1_args(text)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("parent", ["laser", "camera"])
def test_ros2_line_carries_the_same_numbers(seed, parent):
    rig = random_rig(seed)
    text = ros_static_transform(rig, Frames(parent))
    T1, p1, c1 = T_from_ros_args(ros1_args(text))
    opts = ros2_options(line_starting(text, "ros2 run tf2_ros static_transform_publisher ").split()[4:])
    assert set(opts) == {
        "--x",
        "--y",
        "--z",
        "--qx",
        "--qy",
        "--qz",
        "--qw",
        "--frame-id",
        "--child-frame-id",
    }
    assert (opts["--frame-id"], opts["--child-frame-id"]) == (p1, c1)
    numbers = [opts[k] for k in ("--x", "--y", "--z", "--qx", "--qy", "--qz", "--qw")]
    assert numbers == ros1_args(text)[:7]
    np.testing.assert_allclose(T_from_ros2(opts), T1, atol=1e-12)


def test_ros2_launch_line_has_the_command_args():
    text = ros_static_transform(random_rig(8), Frames("laser"))
    node = ET.fromstring(line_starting(text, '<node pkg="tf2_ros" exec='))
    command = line_starting(text, "ros2 run tf2_ros static_transform_publisher ")
    assert node.get("args", "").split() == command.split()[4:]


@pytest.mark.parametrize("seed", SEEDS)
def test_ros_quaternion_is_unit_with_nonnegative_w(seed):
    q = np.array([float(x) for x in ros1_args(ros_static_transform(random_rig(seed)))[3:7]])
    assert abs(np.linalg.norm(q) - 1.0) < 1e-8
    assert q[3] >= 0


def test_ros_level_camera_is_the_standard_optical_frame_transform():
    # ROS's usual camera_link -> camera_optical_frame rotation is q = (-0.5, 0.5, -0.5, 0.5).
    args = ros1_args(ros_static_transform(level_rig(), Frames("laser")))
    assert [float(a) for a in args[:7]] == pytest.approx([0, 0, 0.1, -0.5, 0.5, -0.5, 0.5], abs=1e-9)


# --- physical direction ---------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_laser_origin_in_camera_frame_is_T_cam_laser_translation(seed):
    rig = random_rig(seed)
    origin_in_cam = transform_points(rig.T_cam_laser, [[0.0, 0.0, 0.0]])[0]
    np.testing.assert_allclose(origin_in_cam, rig.T_cam_laser[:3, 3], atol=1e-15)
    xyz = [float(a) for a in ros1_args(ros_static_transform(rig, Frames("camera")))[:3]]
    np.testing.assert_allclose(xyz, origin_in_cam, atol=ATOL)


@pytest.mark.parametrize("seed", SEEDS)
def test_camera_centre_in_laser_frame_is_ros_translation_for_parent_laser(seed):
    rig = random_rig(seed)
    R, t = rig.T_cam_laser[:3, :3], rig.T_cam_laser[:3, 3]
    centre_in_laser = np.linalg.solve(R, -t)  # the laser point that maps to the camera's origin
    xyz = [float(a) for a in ros1_args(ros_static_transform(rig, Frames("laser")))[:3]]
    np.testing.assert_allclose(xyz, centre_in_laser, atol=ATOL)
    assert not np.allclose(centre_in_laser, t, atol=1e-3)  # the two directions differ here


def test_level_camera_sees_a_point_ahead_of_the_laser_below_the_image_centre():
    rig = level_rig(dist=[])
    T, _, _ = T_from_ros_args(ros1_args(ros_static_transform(rig, Frames("camera"))))
    p_cam = transform_points(T, [[2.0, 0.0, 0.0]])[0]
    np.testing.assert_allclose(p_cam, [0.0, 0.1, 2.0], atol=ATOL)
    u, v = rig.camera.project(p_cam[None])[0]
    assert u == pytest.approx(319.5, abs=1e-6)
    assert v == pytest.approx(241.25 + 510.0 * 0.1 / 2.0, abs=1e-6)


# --- URDF -----------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("parent", ["laser", "camera"])
def test_urdf_origin_round_trips(seed, parent):
    rig = random_rig(seed)
    T, parent_link, child_link = urdf_origin(urdf_robot(rig, Frames(parent)))
    if parent == "laser":
        assert (parent_link, child_link) == ("laser", "camera_optical_frame")
        np.testing.assert_allclose(T, rig.T_laser_cam, atol=ATOL)
    else:
        assert (parent_link, child_link) == ("camera_optical_frame", "laser")
        np.testing.assert_allclose(T, rig.T_cam_laser, atol=ATOL)


@pytest.mark.parametrize("seed", SEEDS)
def test_urdf_and_ros_agree(seed):
    rig = random_rig(seed)
    T_urdf, _, _ = urdf_origin(urdf_robot(rig, Frames("laser")))
    T_ros, _, _ = T_from_ros_args(ros1_args(ros_static_transform(rig, Frames("laser"))))
    np.testing.assert_allclose(T_urdf, T_ros, atol=2 * ATOL)


def test_urdf_level_camera_rpy_is_the_standard_optical_frame_rotation():
    joint = ET.fromstring(urdf_robot(level_rig(), Frames("laser"))).find("joint")
    assert joint is not None
    origin = joint.find("origin")
    assert origin is not None
    rpy = [float(v) for v in origin.get("rpy", "").split()]
    assert rpy == pytest.approx([-np.pi / 2, 0.0, -np.pi / 2], abs=1e-8)
    assert [float(v) for v in origin.get("xyz", "").split()] == pytest.approx([0.0, 0.0, 0.1], abs=1e-12)


def test_urdf_at_gimbal_lock_round_trips_without_warning():
    rig = level_rig()  # parent camera: pitch is -pi/2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        text = urdf_robot(rig, Frames("camera"))
    T, _, _ = urdf_origin(text)
    np.testing.assert_allclose(T, rig.T_cam_laser, atol=ATOL)


# --- the stated direction -------------------------------------------------------------------

DIRECTION_PHRASES = {
    ("ros", "laser"): [
        "parent laser, child camera_optical_frame",
        "maps points in camera_optical_frame into laser",
        "T_laser_cam",
    ],
    ("ros", "camera"): [
        "parent camera_optical_frame, child laser",
        "maps points in laser into camera_optical_frame",
        "T_cam_laser",
    ],
    ("urdf", "laser"): [
        "pose of camera_optical_frame in laser",
        "maps points in camera_optical_frame",
        "T_laser_cam",
    ],
    ("urdf", "camera"): ["pose of laser in camera_optical_frame", "maps points in laser", "T_cam_laser"],
    ("kalibr", "laser"): ["T_cam_imu is T_cam_laser", "maps laser-frame points into the camera"],
    ("xacro", "laser"): ["pose of camera_optical_frame in laser", "T_laser_cam"],
    ("mrcal", "laser"): ["reference frame is the laser", "map laser points into the camera"],
}


@pytest.mark.parametrize(("fmt", "parent"), list(DIRECTION_PHRASES))
def test_every_export_states_its_direction(fmt, parent):
    text = export_rig(random_rig(5), fmt, Frames(parent))
    for phrase in DIRECTION_PHRASES[(fmt, parent)]:
        assert phrase in text


def test_export_rig_rejects_unknown_format_and_parent():
    with pytest.raises(ValueError, match="format"):
        export_rig(random_rig(0), "tf")
    with pytest.raises(ValueError, match="parent"):
        export_rig(random_rig(0), "ros", Frames("imu"))


# --- Kalibr ---------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_kalibr_camchain_passes_kalibrs_reader_and_matches_rig(seed):
    rig = random_rig(seed)
    (cam0,) = KalibrCameraChain(kalibr_yaml(rig, "/cam0/image_raw")).load_all()
    assert cam0["rostopic"] == "/cam0/image_raw"
    np.testing.assert_array_equal(cam0["T_cam_imu"], rig.T_cam_laser)
    assert cam0["intrinsics"] == ("pinhole", [520.0, 510.0, 319.5, 241.25])
    assert cam0["distortion"] == ("radtan", DIST5[:4])
    assert cam0["resolution"] == [640, 480]
    assert cam0["cam_overlaps"] == []


@pytest.mark.parametrize(
    ("dist", "expected"),
    [
        ([], [0.0, 0.0, 0.0, 0.0]),
        ([0.1, -0.02, 0.001, 0.002], [0.1, -0.02, 0.001, 0.002]),
        ([0.1, -0.02, 0.001, 0.002, 0.0, 0.0, 0.0, 0.0], [0.1, -0.02, 0.001, 0.002]),
    ],
    ids=["pinhole", "opencv4", "opencv8-k3-k6-zero"],
)
def test_kalibr_pinhole_opencv4_and_opencv8_with_zero_k3_to_k6(dist, expected):
    (cam0,) = KalibrCameraChain(kalibr_yaml(random_rig(1, dist))).load_all()
    assert cam0["distortion"] == ("radtan", expected)


@pytest.mark.parametrize(
    ("key", "value", "message"),
    [
        ("rostopic", None, "rostopic field not found"),
        ("T_cam_imu", None, "invalid camera baseline"),
        ("cam_overlaps", None, "cam_overlaps not found"),
        ("intrinsics", [1.0, 2.0, 3.0], "invalid intrinsics for pinhole"),
        ("distortion_coeffs", [0.1, 0.2, 0.3, 0.4, 0.5], "requires 4 coefficients"),
        ("distortion_model", "plumb_bob", "Invalid distortion model"),
        ("resolution", [640, 0], "Invalid resolution"),
        ("T_cam_imu", np.diag([1.0, 1.0, 2.0, 1.0]).tolist(), "not a rotation"),
    ],
)
def test_kalibr_reader_port_rejects_what_kalibr_rejects(key, value, message):
    # The port must be able to fail: each broken variant of a good camchain is refused.
    doc = yaml.safe_load(kalibr_yaml(random_rig(3)))
    if value is None:
        del doc["cam0"][key]
    else:
        doc["cam0"][key] = value
    with pytest.raises(RuntimeError, match=message):
        KalibrCameraChain(yaml.safe_dump(doc)).load_all()


def test_kalibr_refuses_opencv8_with_nonzero_k4_naming_file_and_fix():
    rig = random_rig(0, DIST8)
    with pytest.raises(InputError, match=r"^rig8\.yaml: camera\.intrinsics: got \{'k3': 0\.003.*mrcal"):
        kalibr_yaml(rig, source="rig8.yaml")


def test_kalibr_refuses_opencv5_with_k3():
    rig = random_rig(0, [0.1, 0.01, 0.001, 0.002, 0.003])
    with pytest.raises(InputError, match=r"camera\.intrinsics: got \{'k3': 0\.003\}.*LENSMODEL_OPENCV5"):
        kalibr_yaml(rig)


def test_kalibr_refuses_a_fisheye_lens_model():
    cam = Camera(
        "LENSMODEL_CAHVOR", np.array([500.0, 500.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0, 0.0]), 640, 480
    )
    with pytest.raises(InputError, match=r"camera\.lensmodel: got 'LENSMODEL_CAHVOR'.*--format mrcal"):
        kalibr_yaml(Rig(np.eye(4), cam))


def test_kalibr_refuses_a_relative_topic():
    with pytest.raises(InputError, match="--rostopic: got 'image'"):
        kalibr_yaml(random_rig(0), "image")


# --- URDF loaded by a URDF parser (yourdfpy) ---------------------------------------------------


def load_urdf(text: str, tmp_path: Path, caplog) -> yourdfpy.URDF:
    path = tmp_path / "rig.urdf"
    path.write_text(text)
    with caplog.at_level(logging.WARNING), warnings.catch_warnings():
        warnings.simplefilter("error")
        robot = yourdfpy.URDF.load(str(path))
    assert [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING] == []
    return robot


@pytest.mark.parametrize("seed", SEEDS[:3])
@pytest.mark.parametrize("parent", ["laser", "camera"])
@pytest.mark.parametrize("camera_link", [False, True])
def test_urdf_robot_loads_in_yourdfpy_with_the_rig_transform(seed, parent, camera_link, tmp_path, caplog):
    rig = random_rig(seed)
    frames = Frames(parent, camera_link)
    robot = load_urdf(urdf_robot(rig, frames), tmp_path, caplog)
    pf, cf = frames.names()
    assert robot.base_link == pf
    assert set(robot.link_map) == {pf, cf}
    T_laser_cam = rig.T_laser_cam @ (make_T(R_LINK_OPTICAL, [0, 0, 0]).T if camera_link else np.eye(4))
    expected = T_laser_cam if parent == "laser" else inv_T(T_laser_cam)
    np.testing.assert_allclose(robot.get_transform(cf, pf), expected, atol=ATOL)


def test_urdf_frame_names_are_chosen(tmp_path, caplog):
    rig = random_rig(4)
    text = urdf_robot(rig, Frames("laser", parent_frame="base_scan", child_frame="front_cam_optical"))
    robot = load_urdf(text, tmp_path, caplog)
    np.testing.assert_allclose(
        robot.get_transform("front_cam_optical", "base_scan"), rig.T_laser_cam, atol=ATOL
    )


def expand_xacro(text: str, parent: str) -> str:
    """The xacro macro called in a robot that has ``parent``: the macro's body with its
    default parameters substituted (what ``xacro`` does for ``<xacro:rigcal_rig/>``)."""
    ns = {"xacro": "http://www.ros.org/wiki/xacro"}
    macro = ET.fromstring(text).find("xacro:macro", ns)
    assert macro is not None
    assert macro.get("name") == "rigcal_rig"
    params = dict(p.split(":=") for p in macro.get("params", "").split())
    params["parent"] = parent
    body = "".join(ET.tostring(child, encoding="unicode") for child in macro)
    for k, v in params.items():
        body = body.replace("${" + k + "}", v)
    return f'<robot name="r"><link name="{parent}"/>{body}</robot>'


@pytest.mark.parametrize("parent", ["laser", "camera"])
def test_xacro_macro_expands_into_a_loadable_robot(parent, tmp_path, caplog):
    rig = random_rig(6)
    frames = Frames(parent)
    pf, cf = frames.names()
    robot = load_urdf(expand_xacro(urdf_xacro(rig, frames), pf), tmp_path, caplog)
    expected = rig.T_laser_cam if parent == "laser" else rig.T_cam_laser
    np.testing.assert_allclose(robot.get_transform(cf, pf), expected, atol=ATOL)


# --- camera_link and frame names ------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_camera_link_composes_with_the_drivers_optical_transform(seed):
    # laser -> camera_link (ours) then camera_link -> camera_optical_frame (the driver's,
    # q = (-0.5, 0.5, -0.5, 0.5)) must give the calibrated T_laser_cam.
    rig = random_rig(seed)
    T_laser_link, parent, child = T_from_ros_args(
        ros1_args(ros_static_transform(rig, Frames(camera_link=True)))
    )
    assert (parent, child) == ("laser", "camera_link")
    T_link_optical = make_T(Rotation.from_quat([-0.5, 0.5, -0.5, 0.5]).as_matrix(), [0, 0, 0])
    np.testing.assert_allclose(T_laser_link @ T_link_optical, rig.T_laser_cam, atol=ATOL)


def test_level_camera_link_is_a_pure_translation():
    args = ros1_args(ros_static_transform(level_rig(), Frames(camera_link=True)))
    assert [float(a) for a in args[:7]] == pytest.approx([0, 0, 0.1, 0, 0, 0, 1], abs=1e-9)


def test_frame_names_replace_the_defaults_everywhere():
    text = ros_static_transform(random_rig(2), Frames("camera", True, "cam_base", "scanner"))
    _, parent, child = T_from_ros_args(ros1_args(text))
    assert (parent, child) == ("cam_base", "scanner")
    assert "--frame-id cam_base --child-frame-id scanner" in text
    assert "cam_base is the camera's body frame" in text


# --- mrcal ----------------------------------------------------------------------------------


def read_cameramodel(rig: Rig, tmp_path: Path):
    path = tmp_path / "rig.cameramodel"
    path.write_text(mrcal_cameramodel_text(rig))
    return mrcal.cameramodel(str(path))


@pytest.mark.parametrize("seed", SEEDS)
def test_mrcal_extrinsics_are_rt_cam_laser(seed, tmp_path):
    rig = random_rig(seed)
    model = read_cameramodel(rig, tmp_path)
    np.testing.assert_allclose(model.extrinsics_rt_fromref(), rt_from_T(rig.T_cam_laser), atol=1e-8)
    lensmodel, intrinsics = model.intrinsics()
    assert lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_allclose(intrinsics, rig.camera.intrinsics, rtol=1e-9)
    assert list(model.imagersize()) == [640, 480]


@pytest.mark.parametrize("seed", SEEDS)
def test_mrcal_projects_laser_points_like_rigcal(seed, tmp_path):
    rig = random_rig(seed, [-0.15, 0.05, 0.0005, -0.0003, 0.01, 0.002, 0.001, 0.0005])
    model = read_cameramodel(rig, tmp_path)
    rng = np.random.default_rng(100 + seed)
    z = rng.uniform(1.0, 5.0, 20)
    p_cam = np.column_stack([rng.uniform(-0.4, 0.4, (20, 2)) * z[:, None], z])
    p_laser = transform_points(rig.T_laser_cam, p_cam)
    q_mrcal = mrcal.project(
        mrcal.transform_point_rt(model.extrinsics_rt_fromref(), p_laser), *model.intrinsics()
    )
    q_rigcal = rig.camera.project(transform_points(rig.T_cam_laser, p_laser))
    np.testing.assert_allclose(q_mrcal, q_rigcal, atol=1e-5)
    assert np.all(rig.camera.in_image(q_rigcal))


# --- rigcal export --------------------------------------------------------------------------


@pytest.fixture
def rig_file(tmp_path) -> Path:
    return write_rig(tmp_path / "rig.yaml", random_rig(11))


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("fmt", ["ros", "urdf", "kalibr", "mrcal"])
def test_cli_each_format_to_stdout(fmt, rig_file, capsys):
    code, out, _ = run(capsys, "export", str(rig_file), "--format", fmt)
    assert code == 0
    assert out == export_rig(read_rig(rig_file), fmt, Frames("laser"))


def test_cli_ros_default_parent_is_laser(rig_file, capsys):
    code, out, _ = run(capsys, "export", str(rig_file), "--format", "ros")
    assert code == 0
    T, parent, _ = T_from_ros_args(ros1_args(out))
    assert parent == "laser"
    np.testing.assert_allclose(T, read_rig(rig_file).T_laser_cam, atol=ATOL)


def test_cli_urdf_parent_camera(rig_file, capsys):
    code, out, _ = run(capsys, "export", str(rig_file), "--format", "urdf", "--parent", "camera")
    assert code == 0
    T, parent, child = urdf_origin(out)
    assert (parent, child) == ("camera_optical_frame", "laser")
    np.testing.assert_allclose(T, read_rig(rig_file).T_cam_laser, atol=ATOL)


def test_cli_output_file(rig_file, tmp_path, capsys):
    out_path = tmp_path / "sub" / "camchain.yaml"
    code, out, err = run(capsys, "export", str(rig_file), "--format", "kalibr", "-o", str(out_path))
    assert code == 0
    assert out == ""
    assert str(out_path) in err
    assert out_path.read_text() == kalibr_yaml(read_rig(rig_file))


def test_cli_refuses_to_overwrite_without_force(rig_file, tmp_path, capsys):
    out_path = tmp_path / "camera.cameramodel"
    out_path.write_text("keep me")
    code, out, err = run(capsys, "export", str(rig_file), "--format", "mrcal", "-o", str(out_path))
    assert code == 5
    assert "exists" in err
    assert "--force" in err
    assert out == ""
    assert out_path.read_text() == "keep me"
    code, _, _ = run(capsys, "export", str(rig_file), "--format", "mrcal", "-o", str(out_path), "--force")
    assert code == 0
    assert mrcal.cameramodel(str(out_path)).imagersize().tolist() == [640, 480]


@pytest.mark.parametrize(
    "extra",
    [["--format", "tf"], ["--format", "ros", "--parent", "imu"], []],
    ids=["format", "parent", "none"],
)
def test_cli_bad_usage_is_exit_2(extra, rig_file, capsys):
    code, out, _ = run(capsys, "export", str(rig_file), *extra)
    assert code == 2
    assert out == ""


def test_cli_missing_rig_file_is_exit_3(tmp_path, capsys):
    out_path = tmp_path / "tf.txt"
    code, out, err = run(
        capsys, "export", str(tmp_path / "nope.yaml"), "--format", "ros", "-o", str(out_path)
    )
    assert code == 3
    assert "nope.yaml" in err
    assert out == ""
    assert not out_path.exists()


def test_cli_kalibr_of_opencv8_rig_is_exit_3_and_writes_nothing(tmp_path, capsys):
    rig_path = write_rig(tmp_path / "rig8.yaml", random_rig(2, DIST8))
    out_path = tmp_path / "camchain.yaml"
    code, _, err = run(capsys, "export", str(rig_path), "--format", "kalibr", "-o", str(out_path))
    assert code == 3
    assert "LENSMODEL_OPENCV8" in err
    assert not out_path.exists()


def test_cli_help_has_examples(capsys):
    code, out, _ = run(capsys, "export", "--help")
    assert code == 0
    assert "Examples:" in out
    assert "rigcal export rig.yaml --format ros" in out
    assert "--parent" in out


def test_cli_camera_link_and_frame_names(rig_file, capsys):
    code, out, _ = run(
        capsys, "export", str(rig_file), "--format", "ros", "--camera-link", "--parent-frame", "base_scan"
    )
    assert code == 0
    T, parent, child = T_from_ros_args(ros1_args(out))
    assert (parent, child) == ("base_scan", "camera_link")
    np.testing.assert_allclose(
        T @ make_T(R_LINK_OPTICAL, [0, 0, 0]), read_rig(rig_file).T_laser_cam, atol=ATOL
    )


def test_cli_kalibr_rostopic(rig_file, capsys):
    code, out, _ = run(capsys, "export", str(rig_file), "--format", "kalibr", "--rostopic", "/cam/image")
    assert code == 0
    assert KalibrCameraChain(out).camera(0).rostopic() == "/cam/image"


@pytest.mark.parametrize("fmt", ["urdf", "kalibr"])
def test_cli_json_states_the_transform_written(fmt, rig_file, tmp_path, capsys):
    out_path = tmp_path / f"rig.{fmt}"
    code, out, _ = run(capsys, "export", str(rig_file), "--format", fmt, "-o", str(out_path), "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["output"] == str(out_path)
    rig = read_rig(rig_file)
    expected = rig.T_laser_cam if fmt == "urdf" else rig.T_cam_laser
    np.testing.assert_allclose(np.array(doc["T_parent_child"]), expected, atol=1e-12)
    assert doc["parent_frame"] == ("laser" if fmt == "urdf" else "camera_optical_frame")


def test_cli_json_without_output_carries_the_text(rig_file, capsys):
    code, out, _ = run(capsys, "export", str(rig_file), "--format", "ros", "--camera-link", "--json")
    assert code == 0
    doc = json.loads(out)
    assert doc["output"] is None
    assert (doc["parent_frame"], doc["child_frame"]) == ("laser", "camera_link")
    T, parent, child = T_from_ros_args(ros1_args(doc["text"]))
    assert (parent, child) == ("laser", "camera_link")
    np.testing.assert_allclose(np.array(doc["T_parent_child"]), T, atol=ATOL)


def test_cli_kalibr_error_names_the_rig_file(tmp_path, capsys):
    rig_path = write_rig(tmp_path / "rig8.yaml", random_rig(2, DIST8))
    code, _, err = run(capsys, "export", str(rig_path), "--format", "kalibr")
    assert code == 3
    assert err.startswith(f"Error: {rig_path}: camera.intrinsics: got {{'k3'")
    assert "--format mrcal" in err
