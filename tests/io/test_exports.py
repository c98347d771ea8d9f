"""Rig exports (ROS tf, URDF, Kalibr, mrcal): round trips, the direction they state, and `rigcal export`."""

from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import mrcal
import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rigcal.camera import Camera
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.geometry import inv_T, make_T, random_rotation, rt_from_T, transform_points
from rigcal.io.exports import (
    T_from_ros_args,
    T_from_urdf_origin,
    export_rig,
    kalibr_yaml,
    mrcal_cameramodel_text,
    ros_static_transform,
    urdf_joint,
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
    joint = ET.fromstring(text)
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
    T, parent, child = T_from_ros_args(ros1_args(ros_static_transform(rig, "laser")))
    assert (parent, child) == ("laser", "camera_optical_frame")
    np.testing.assert_allclose(T, inv_T(rig.T_cam_laser), atol=ATOL)


@pytest.mark.parametrize("seed", SEEDS)
def test_ros1_args_parent_camera_give_T_cam_laser(seed):
    rig = random_rig(seed)
    T, parent, child = T_from_ros_args(ros1_args(ros_static_transform(rig, "camera")))
    assert (parent, child) == ("camera_optical_frame", "laser")
    np.testing.assert_allclose(T, rig.T_cam_laser, atol=ATOL)


@pytest.mark.parametrize("parent", ["laser", "camera"])
def test_ros1_launch_line_has_the_command_args(parent):
    text = ros_static_transform(random_rig(7), parent)
    node = ET.fromstring(line_starting(text, '<node pkg="tf2_ros" type='))
    assert node.get("type") == "static_transform_publisher"
    assert node.get("args", "").split() == ros1_args(text)


@pytest.mark.parametrize("seed", SEEDS)
@pytest.mark.parametrize("parent", ["laser", "camera"])
def test_ros2_line_carries_the_same_numbers(seed, parent):
    rig = random_rig(seed)
    text = ros_static_transform(rig, parent)
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
    text = ros_static_transform(random_rig(8), "laser")
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
    args = ros1_args(ros_static_transform(level_rig(), "laser"))
    assert [float(a) for a in args[:7]] == pytest.approx([0, 0, 0.1, -0.5, 0.5, -0.5, 0.5], abs=1e-9)


# --- physical direction ---------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_laser_origin_in_camera_frame_is_T_cam_laser_translation(seed):
    rig = random_rig(seed)
    origin_in_cam = transform_points(rig.T_cam_laser, [[0.0, 0.0, 0.0]])[0]
    np.testing.assert_allclose(origin_in_cam, rig.T_cam_laser[:3, 3], atol=1e-15)
    xyz = [float(a) for a in ros1_args(ros_static_transform(rig, "camera"))[:3]]
    np.testing.assert_allclose(xyz, origin_in_cam, atol=ATOL)


@pytest.mark.parametrize("seed", SEEDS)
def test_camera_centre_in_laser_frame_is_ros_translation_for_parent_laser(seed):
    rig = random_rig(seed)
    R, t = rig.T_cam_laser[:3, :3], rig.T_cam_laser[:3, 3]
    centre_in_laser = np.linalg.solve(R, -t)  # the laser point that maps to the camera's origin
    xyz = [float(a) for a in ros1_args(ros_static_transform(rig, "laser"))[:3]]
    np.testing.assert_allclose(xyz, centre_in_laser, atol=ATOL)
    assert not np.allclose(centre_in_laser, t, atol=1e-3)  # the two directions differ here


def test_level_camera_sees_a_point_ahead_of_the_laser_below_the_image_centre():
    rig = level_rig(dist=[])
    T, _, _ = T_from_ros_args(ros1_args(ros_static_transform(rig, "camera")))
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
    T, parent_link, child_link = urdf_origin(urdf_joint(rig, parent))
    if parent == "laser":
        assert (parent_link, child_link) == ("laser", "camera_optical_frame")
        np.testing.assert_allclose(T, rig.T_laser_cam, atol=ATOL)
    else:
        assert (parent_link, child_link) == ("camera_optical_frame", "laser")
        np.testing.assert_allclose(T, rig.T_cam_laser, atol=ATOL)


@pytest.mark.parametrize("seed", SEEDS)
def test_urdf_and_ros_agree(seed):
    rig = random_rig(seed)
    T_urdf, _, _ = urdf_origin(urdf_joint(rig, "laser"))
    T_ros, _, _ = T_from_ros_args(ros1_args(ros_static_transform(rig, "laser")))
    np.testing.assert_allclose(T_urdf, T_ros, atol=2 * ATOL)


def test_urdf_level_camera_rpy_is_the_standard_optical_frame_rotation():
    joint = ET.fromstring(urdf_joint(level_rig(), "laser"))
    origin = joint.find("origin")
    assert origin is not None
    rpy = [float(v) for v in origin.get("rpy", "").split()]
    assert rpy == pytest.approx([-np.pi / 2, 0.0, -np.pi / 2], abs=1e-8)
    assert [float(v) for v in origin.get("xyz", "").split()] == pytest.approx([0.0, 0.0, 0.1], abs=1e-12)


def test_urdf_at_gimbal_lock_round_trips_without_warning():
    rig = level_rig()  # parent camera: pitch is -pi/2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        text = urdf_joint(rig, "camera")
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
    ("kalibr", "laser"): ["T_cam_laser (4x4, row-major) maps laser-frame points", "into the camera frame"],
    ("mrcal", "laser"): ["reference frame is the laser", "map laser points into the camera"],
}


@pytest.mark.parametrize(("fmt", "parent"), list(DIRECTION_PHRASES))
def test_every_export_states_its_direction(fmt, parent):
    text = export_rig(random_rig(5), fmt, parent)
    for phrase in DIRECTION_PHRASES[(fmt, parent)]:
        assert phrase in text


def test_export_rig_rejects_unknown_format_and_parent():
    with pytest.raises(ValueError, match="format"):
        export_rig(random_rig(0), "tf")
    with pytest.raises(ValueError, match="parent"):
        export_rig(random_rig(0), "ros", "imu")


# --- Kalibr ---------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", SEEDS)
def test_kalibr_yaml_matches_rig(seed):
    rig = random_rig(seed)
    cam0 = yaml.safe_load(kalibr_yaml(rig))["cam0"]
    np.testing.assert_array_equal(np.array(cam0["T_cam_laser"]), rig.T_cam_laser)
    assert cam0["camera_model"] == "pinhole"
    assert cam0["intrinsics"] == [520.0, 510.0, 319.5, 241.25]
    assert cam0["distortion_model"] == "radtan"
    assert cam0["distortion_coeffs"] == DIST5[:4]
    assert cam0["resolution"] == [640, 480]


@pytest.mark.parametrize(
    ("dist", "expected"),
    [([], [0.0, 0.0, 0.0, 0.0]), ([0.1, -0.02, 0.001, 0.002], [0.1, -0.02, 0.001, 0.002])],
)
def test_kalibr_pinhole_and_opencv4(dist, expected):
    cam0 = yaml.safe_load(kalibr_yaml(random_rig(1, dist)))["cam0"]
    assert cam0["distortion_coeffs"] == expected


def test_kalibr_refuses_opencv8():
    rig = random_rig(0, DIST8)
    with pytest.raises(InputError, match="LENSMODEL_OPENCV8"):
        kalibr_yaml(rig)


def test_kalibr_refuses_opencv5_with_k3():
    rig = random_rig(0, [0.1, 0.01, 0.001, 0.002, 0.003])
    with pytest.raises(InputError, match=r"LENSMODEL_OPENCV5 with k3 = 0\.003"):
        kalibr_yaml(rig)


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
    assert out == export_rig(read_rig(rig_file), fmt, "laser")


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
