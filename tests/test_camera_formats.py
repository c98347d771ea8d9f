"""Cameras from ROS camera_info YAML and OpenCV FileStorage files, read through `read_camera`."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.camera import Camera, read_camera
from rigcal.camera_formats import camera_to_ros_camera_info, is_opencv_storage
from rigcal.errors import InputError

EXAMPLE_CAMERA = Path(__file__).resolve().parents[1] / "examples" / "box-session" / "camera.yaml"

K = np.array([[612.5, 0.0, 321.75], [0.0, 608.25, 238.5], [0.0, 0.0, 1.0]])
DIST5 = [-0.21, 0.07, 0.0011, -0.0007, -0.012]
DIST8 = [0.35, -0.12, 0.0009, 0.0004, 0.021, 0.71, -0.05, 0.043]

# As ROS camera_calibration writes it (ost.yaml), distortion in plumb_bob.
GOLDEN_ROS = """\
image_width: 752
image_height: 480
camera_name: narrow_stereo
camera_matrix:
  rows: 3
  cols: 3
  data: [461.6, 0, 368.2, 0, 460.3, 248.1, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.2917, 0.0855, 0.00019, 0.0000276, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [361.5, 0, 372.9, 0, 0, 418.4, 250.8, 0, 0, 0, 1, 0]
"""

# As OpenCV 4's calibration sample writes it (%YAML:1.0 header).
GOLDEN_OPENCV = """\
%YAML:1.0
---
calibration_time: "Mon 03 Jun 2024 10:00:00 CEST"
image_width: 1280
image_height: 720
flags: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 9.1e+02, 0., 6.395e+02, 0., 9.05e+02, 3.595e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -1.2e-01, 4.0e-02, 1.0e-04, -2.0e-04, 0. ]
avg_reprojection_error: 0.21
"""


def ros_doc() -> dict:
    return yaml.safe_load(GOLDEN_ROS)


def write_yaml(path: Path, doc: dict) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def write_storage(path: Path, entries: dict) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in entries.items():
        fs.write(key, value)
    fs.release()
    return path


def storage_entries(**replace) -> dict:
    entries = {
        "image_width": 640,
        "image_height": 480,
        "camera_matrix": K,
        "distortion_coefficients": np.array([DIST5]),
    }
    entries.update(replace)
    return {k: v for k, v in entries.items() if v is not None}


def error_of(path: Path) -> str:
    with pytest.raises(InputError) as info:
        read_camera(path)
    message = str(info.value)
    assert message.startswith(str(path))
    return message


# --- ROS camera_info: round trips ----------------------------------------------------------


@pytest.mark.parametrize(
    ("dist", "model", "lensmodel"),
    [(DIST5, "plumb_bob", "LENSMODEL_OPENCV5"), (DIST8, "rational_polynomial", "LENSMODEL_OPENCV8")],
)
def test_ros_camera_info_round_trip(dist, model, lensmodel, tmp_path):
    cam = Camera.from_opencv(K, dist, 640, 480)
    path = tmp_path / "camera_info.yaml"
    path.write_text(camera_to_ros_camera_info(cam, "front"))
    back = read_camera(path)
    assert back.lensmodel == lensmodel
    np.testing.assert_array_equal(back.intrinsics, cam.intrinsics)
    assert (back.width_px, back.height_px) == (640, 480)
    doc = yaml.safe_load(path.read_text())
    assert doc["distortion_model"] == model
    assert doc["camera_name"] == "front"


def test_ros_camera_info_pinhole_is_padded_to_five_zeros(tmp_path):
    cam = Camera.from_opencv(K, [], 640, 480)
    path = tmp_path / "camera_info.yaml"
    path.write_text(camera_to_ros_camera_info(cam))
    doc = yaml.safe_load(path.read_text())
    assert doc["distortion_model"] == "plumb_bob"
    assert doc["distortion_coefficients"] == {"rows": 1, "cols": 5, "data": [0.0] * 5}
    back = read_camera(path)
    assert back.lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_array_equal(back.intrinsics, [*cam.intrinsics, 0.0, 0.0, 0.0, 0.0, 0.0])


def test_ros_camera_info_projection_matrix_is_K_with_zero_column(tmp_path):
    doc = yaml.safe_load(camera_to_ros_camera_info(Camera.from_opencv(K, DIST5, 640, 480)))
    P = np.array(doc["projection_matrix"]["data"]).reshape(3, 4)
    np.testing.assert_array_equal(P, np.column_stack([K, np.zeros(3)]))
    np.testing.assert_array_equal(doc["rectification_matrix"]["data"], np.eye(3).ravel())


def test_ros_camera_info_writer_refuses_other_lens_models():
    cam = Camera("LENSMODEL_OPENCV12", np.r_[K[0, 0], K[1, 1], K[0, 2], K[1, 2], np.zeros(12)], 640, 480)
    with pytest.raises(InputError, match="LENSMODEL_OPENCV12"):
        camera_to_ros_camera_info(cam)


def test_ros_golden_camera_info_reads_as_expected(tmp_path):
    path = tmp_path / "ost.yaml"
    path.write_text(GOLDEN_ROS)
    cam = read_camera(path)
    assert cam.lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_array_equal(
        cam.intrinsics, [461.6, 460.3, 368.2, 248.1, -0.2917, 0.0855, 0.00019, 0.0000276, 0.0]
    )
    assert (cam.width_px, cam.height_px) == (752, 480)
    assert cam.source == str(path)


# --- ROS camera_info: errors ---------------------------------------------------------------


def test_ros_equidistant_model_is_refused(tmp_path):
    doc = ros_doc()
    doc["distortion_model"] = "equidistant"
    doc["distortion_coefficients"] = {"rows": 1, "cols": 4, "data": [0.1, 0.01, 0.001, 0.0001]}
    message = error_of(write_yaml(tmp_path / "fisheye.yaml", doc))
    assert "distortion_model" in message
    assert "'equidistant'" in message
    assert "plumb_bob" in message


def test_ros_wrong_camera_matrix_shape(tmp_path):
    doc = ros_doc()
    doc["camera_matrix"] = {"rows": 3, "cols": 4, "data": doc["projection_matrix"]["data"]}
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "camera_matrix" in message
    assert "3x3 matrix" in message


def test_ros_camera_matrix_data_length_must_match(tmp_path):
    doc = ros_doc()
    doc["camera_matrix"]["data"] = doc["camera_matrix"]["data"][:8]
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "camera_matrix" in message


@pytest.mark.parametrize(("model", "count"), [("plumb_bob", 4), ("plumb_bob", 8), ("rational_polynomial", 5)])
def test_ros_wrong_number_of_coefficients(model, count, tmp_path):
    doc = ros_doc()
    doc["distortion_model"] = model
    doc["distortion_coefficients"] = {"rows": 1, "cols": count, "data": [0.01] * count}
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "distortion_coefficients" in message
    assert f"{5 if model == 'plumb_bob' else 8} coefficients" in message


def test_ros_missing_image_width(tmp_path):
    doc = ros_doc()
    del doc["image_width"]
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "image_width: missing" in message


@pytest.mark.parametrize("width", [0, -640, 640.5, "640", True])
def test_ros_bad_image_width(width, tmp_path):
    doc = ros_doc()
    doc["image_width"] = width
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "image_width" in message
    assert "positive integer" in message


def test_ros_skewed_camera_matrix(tmp_path):
    doc = ros_doc()
    doc["camera_matrix"]["data"][1] = 0.5
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "camera_matrix" in message
    assert "no skew" in message


def test_ros_non_finite_camera_matrix(tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text(GOLDEN_ROS.replace("461.6, 0, 368.2", "461.6, 0, .nan"))
    assert "camera_matrix" in error_of(path)


def test_ros_unknown_key(tmp_path):
    doc = ros_doc()
    doc["binning_x"] = 2
    message = error_of(write_yaml(tmp_path / "cam.yaml", doc))
    assert "binning_x" in message
    assert "no such key" in message


# --- OpenCV FileStorage --------------------------------------------------------------------


@pytest.mark.parametrize("suffix", [".xml", ".yaml", ".yml"])
@pytest.mark.parametrize(
    ("k_key", "d_key"), [("camera_matrix", "distortion_coefficients"), ("cameraMatrix", "distCoeffs")]
)
def test_opencv_storage_round_trip(suffix, k_key, d_key, tmp_path):
    entries = {"image_width": 640, "image_height": 480, k_key: K, d_key: np.array([DIST8])}
    path = write_storage(tmp_path / f"calib{suffix}", entries)
    assert is_opencv_storage(path)
    cam = read_camera(path)
    assert cam.lensmodel == "LENSMODEL_OPENCV8"
    np.testing.assert_array_equal(cam.intrinsics, [612.5, 608.25, 321.75, 238.5, *DIST8])
    assert (cam.width_px, cam.height_px) == (640, 480)


@pytest.mark.parametrize("suffix", [".xml", ".yaml"])
@pytest.mark.parametrize(
    ("w_key", "h_key", "k_key"),
    [("image_Width", "image_Height", "Camera_Matrix"), ("IMAGE_WIDTH", "Image_height", "CAMERA_MATRIX")],
)
def test_opencv_storage_keys_match_in_any_case(suffix, w_key, h_key, k_key, tmp_path):
    entries = {w_key: 800, h_key: 600, k_key: K, "Distortion_Coefficients": np.array([DIST5])}
    cam = read_camera(write_storage(tmp_path / f"old{suffix}", entries))
    assert (cam.width_px, cam.height_px) == (800, 600)
    np.testing.assert_array_equal(cam.intrinsics, [612.5, 608.25, 321.75, 238.5, *DIST5])


@pytest.mark.parametrize("suffix", [".xml", ".yaml"])
def test_opencv_storage_one_dimensional_arrays(suffix, tmp_path):
    entries = storage_entries(distortion_coefficients=np.array(DIST5))
    cam = read_camera(write_storage(tmp_path / f"calib{suffix}", entries))
    np.testing.assert_array_equal(cam.intrinsics[4:], DIST5)


def test_opencv_golden_yaml_1_0_reads_as_expected(tmp_path):
    path = tmp_path / "out_camera_data.yml"
    path.write_text(GOLDEN_OPENCV)
    cam = read_camera(path)
    assert cam.lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_array_equal(cam.intrinsics, [910.0, 905.0, 639.5, 359.5, -0.12, 0.04, 1e-4, -2e-4, 0.0])
    assert (cam.width_px, cam.height_px) == (1280, 720)


@pytest.mark.parametrize("suffix", [".xml", ".yaml"])
@pytest.mark.parametrize("dist", [np.array([DIST5]), np.array(DIST5)], ids=["2d", "1d"])
def test_opencv_storage_missing_camera_matrix(suffix, dist, tmp_path):
    path = write_storage(
        tmp_path / f"calib{suffix}", storage_entries(camera_matrix=None, distortion_coefficients=dist)
    )
    message = error_of(path)
    assert "camera_matrix: missing" in message
    assert "cameraMatrix" in message


@pytest.mark.parametrize("suffix", [".xml", ".yaml"])
def test_opencv_storage_missing_image_size(suffix, tmp_path):
    path = write_storage(tmp_path / f"calib{suffix}", storage_entries(image_height=None))
    message = error_of(path)
    assert "image_height: missing" in message
    assert "imageHeight" in message


@pytest.mark.parametrize("suffix", [".xml", ".yaml"])
def test_opencv_storage_3x4_camera_matrix(suffix, tmp_path):
    path = write_storage(
        tmp_path / f"calib{suffix}", storage_entries(camera_matrix=np.column_stack([K, np.zeros(3)]))
    )
    message = error_of(path)
    assert "camera_matrix" in message
    assert "3x3 matrix" in message


def test_opencv_storage_skewed_camera_matrix(tmp_path):
    skewed = K.copy()
    skewed[0, 1] = 1.5
    message = error_of(write_storage(tmp_path / "calib.xml", storage_entries(camera_matrix=skewed)))
    assert "camera_matrix" in message
    assert "no skew" in message


def test_opencv_storage_wrong_number_of_coefficients(tmp_path):
    path = write_storage(
        tmp_path / "calib.xml", storage_entries(distortion_coefficients=np.array([[0.1, 0.01, 0.001]]))
    )
    message = error_of(path)
    assert "distortion_coefficients" in message
    assert "0, 4, 5, 8 or 12" in message


def test_opencv_storage_non_integer_image_width(tmp_path):
    message = error_of(write_storage(tmp_path / "calib.xml", storage_entries(image_width=640.5)))
    assert "image_width" in message
    assert "positive integer" in message


@pytest.mark.parametrize(
    ("name", "text"),
    [
        ("calib.xml", '<?xml version="1.0"?>\n<opencv_storage>\n<camera_matrix type_id="opencv-matrix">\n'),
        ("calib.yml", "%YAML:1.0\n---\ncamera_matrix: !!opencv-matrix\n  rows: [\n"),
    ],
    ids=["xml", "yaml"],
)
def test_malformed_filestorage_is_an_input_error(name, text, tmp_path):
    path = tmp_path / name
    path.write_text(text)
    assert "not a readable OpenCV FileStorage file" in error_of(path)


# --- dispatch ------------------------------------------------------------------------------


def test_rigcal_camera_yaml_is_not_taken_for_filestorage():
    assert not is_opencv_storage(EXAMPLE_CAMERA)
    cam = read_camera(EXAMPLE_CAMERA)
    assert cam.lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_array_equal(
        cam.intrinsics, [520.0, 520.0, 319.5, 239.5, -0.15, 0.05, 0.0005, -0.0003, 0.0]
    )


def test_rigcal_camera_yaml_with_yaml_directive_goes_to_rigcal_reader(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_text("%YAML 1.1\n---\n" + EXAMPLE_CAMERA.read_text())
    assert not is_opencv_storage(path)
    cam, expected = read_camera(path), read_camera(EXAMPLE_CAMERA)
    assert cam.lensmodel == expected.lensmodel
    np.testing.assert_array_equal(cam.intrinsics, expected.intrinsics)
    assert (cam.width_px, cam.height_px) == (expected.width_px, expected.height_px)


def test_rigcal_camera_yaml_errors_come_from_rigcal_reader(tmp_path):
    path = tmp_path / "camera.yaml"
    path.write_text(EXAMPLE_CAMERA.read_text().replace("image_width_px", "width_px"))
    message = error_of(path)
    assert "width_px" in message
    assert "no such key" in message


def test_missing_camera_file(tmp_path):
    for name in ("nope.yaml", "nope.xml"):
        with pytest.raises(InputError, match="not found"):
            read_camera(tmp_path / name)
