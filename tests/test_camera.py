"""Camera model: file round trips, projection geometry, the pixel convention and read_camera's errors."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from rigcal.camera import Camera, camera_from_dict, camera_to_opencv_yaml, read_camera
from rigcal.errors import InputError

EXAMPLE_CAMERA = Path(__file__).resolve().parents[1] / "examples" / "box-session" / "camera.yaml"

K = [[520.0, 0.0, 319.5], [0.0, 518.0, 241.25], [0.0, 0.0, 1.0]]
DISTORTIONS = {
    "LENSMODEL_PINHOLE": [],
    "LENSMODEL_OPENCV4": [-0.15, 0.05, 0.0005, -0.0003],
    "LENSMODEL_OPENCV5": [-0.15, 0.05, 0.0005, -0.0003, 0.01],
    "LENSMODEL_OPENCV8": [-0.15, 0.05, 0.0005, -0.0003, 0.01, 0.002, -0.001, 0.0004],
    "LENSMODEL_OPENCV12": [
        -0.15,
        0.05,
        0.0005,
        -0.0003,
        0.01,
        0.002,
        -0.001,
        0.0004,
        1e-4,
        -2e-4,
        3e-5,
        1e-5,
    ],
}


def grid_points() -> np.ndarray:
    """Camera-frame points spread over the field of view, 1 to 5 m away."""
    x, y = np.meshgrid(np.linspace(-0.5, 0.5, 7), np.linspace(-0.4, 0.4, 5))
    rays = np.column_stack([x.ravel(), y.ravel(), np.ones(x.size)])
    return rays * np.linspace(1.0, 5.0, len(rays))[:, None]


@pytest.fixture(params=sorted(DISTORTIONS))
def camera(request) -> Camera:
    return Camera.from_opencv(K, DISTORTIONS[request.param], 640, 480)


@pytest.fixture
def camera_yaml(tmp_path) -> Path:
    path = tmp_path / "camera.yaml"
    path.write_text(EXAMPLE_CAMERA.read_text())
    return path


def write_doc(path: Path, doc: Any) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def edit(path: Path, **changes: Any) -> Path:
    doc = yaml.safe_load(path.read_text())
    doc.update(changes)
    return write_doc(path, doc)


def expect_error(path: Path, key: str, shown: str) -> str:
    """read_camera fails with one line ``FILE: KEY: got SHOWN; ...``; returns the message."""
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: got {shown};")) as exc:
        read_camera(path)
    assert "\n" not in str(exc.value)
    return str(exc.value)


# --- round trips ---------------------------------------------------------------------------------
def test_opencv_yaml_round_trip_gives_identical_projections(camera, tmp_path):
    path = tmp_path / "cam.yaml"
    path.write_text(camera_to_opencv_yaml(camera))
    back = read_camera(path)
    assert back.lensmodel == camera.lensmodel
    assert (back.width_px, back.height_px) == (640, 480)
    np.testing.assert_array_equal(back.intrinsics, camera.intrinsics)
    np.testing.assert_array_equal(back.project(grid_points()), camera.project(grid_points()))


def test_opencv_yaml_round_trip_of_tiny_and_long_coefficients(tmp_path):
    cam = Camera.from_opencv(
        [[500.123456789012, 0, 320.987654321], [0, 501.5, 240.0625], [0, 0, 1]],
        [1e-5, -0.0123456789012345, 2.5e-7, -3e-12, 1e-20],
        640,
        480,
    )
    path = tmp_path / "cam.yaml"
    path.write_text(camera_to_opencv_yaml(cam))
    back = read_camera(path)
    np.testing.assert_allclose(back.intrinsics, cam.intrinsics, rtol=1e-9, atol=0)
    np.testing.assert_allclose(back.project(grid_points()), cam.project(grid_points()), rtol=0, atol=1e-6)


def test_example_camera_file_rewritten_reads_back_identical(tmp_path):
    cam = read_camera(EXAMPLE_CAMERA)
    path = tmp_path / "cam.yaml"
    path.write_text(camera_to_opencv_yaml(cam))
    np.testing.assert_array_equal(read_camera(path).intrinsics, cam.intrinsics)


def test_cameramodel_round_trip_gives_identical_projections(camera, tmp_path):
    path = tmp_path / "cam.cameramodel"
    camera.to_cameramodel().write(str(path))
    back = read_camera(path)
    assert back.lensmodel == camera.lensmodel
    assert (back.width_px, back.height_px) == (640, 480)
    assert back.source == str(path)
    np.testing.assert_array_equal(back.intrinsics, camera.intrinsics)
    np.testing.assert_array_equal(back.project(grid_points()), camera.project(grid_points()))


def test_cameramodel_with_a_non_opencv_lens_model_round_trips(tmp_path):
    cam = Camera("LENSMODEL_STEREOGRAPHIC", np.array([400.0, 401.0, 320.0, 240.0]), 640, 480)
    path = tmp_path / "stereo.cameramodel"
    cam.to_cameramodel().write(str(path))
    back = read_camera(path)
    assert back.lensmodel == "LENSMODEL_STEREOGRAPHIC"
    np.testing.assert_array_equal(back.project(grid_points()), cam.project(grid_points()))
    p = grid_points()
    np.testing.assert_allclose(
        back.bearings(back.project(p)), p / np.linalg.norm(p, axis=1)[:, None], atol=1e-9
    )


def test_cameramodel_ignores_extrinsics(tmp_path):
    cam = Camera.from_opencv(K, DISTORTIONS["LENSMODEL_OPENCV5"], 640, 480)
    path = tmp_path / "cam.cameramodel"
    cam.to_cameramodel(rt_cam_ref=[0.1, -0.2, 0.3, 1.0, 2.0, 3.0]).write(str(path))
    np.testing.assert_array_equal(read_camera(path).project(grid_points()), cam.project(grid_points()))


def test_embedded_dict_round_trip(camera):
    back = camera_from_dict(camera.to_dict(), None, "camera")
    assert back.lensmodel == camera.lensmodel
    np.testing.assert_array_equal(back.intrinsics, camera.intrinsics)
    assert (back.width_px, back.height_px) == (camera.width_px, camera.height_px)


def test_opencv_order_maps_onto_mrcal_intrinsics():
    cam = Camera.from_opencv(K, DISTORTIONS["LENSMODEL_OPENCV5"], 640, 480)
    assert cam.lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_array_equal(
        cam.intrinsics, [520.0, 518.0, 319.5, 241.25, -0.15, 0.05, 0.0005, -0.0003, 0.01]
    )
    np.testing.assert_array_equal(cam.K, K)
    np.testing.assert_array_equal(cam.distortion, DISTORTIONS["LENSMODEL_OPENCV5"])


def test_writer_refuses_a_non_opencv_model():
    cam = Camera("LENSMODEL_STEREOGRAPHIC", np.array([500.0, 500.0, 320.0, 240.0]), 640, 480)
    with pytest.raises(InputError, match="lensmodel: got 'LENSMODEL_STEREOGRAPHIC'"):
        camera_to_opencv_yaml(cam)


# --- geometry ------------------------------------------------------------------------------------
def test_bearings_invert_project(camera):
    p = grid_points()
    b = camera.bearings(camera.project(p))
    np.testing.assert_allclose(np.linalg.norm(b, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(b, p / np.linalg.norm(p, axis=1)[:, None], atol=1e-7)


def test_distortion_moves_off_axis_pixels():
    pinhole = Camera.from_opencv(K, [], 640, 480)
    distorted = Camera.from_opencv(K, DISTORTIONS["LENSMODEL_OPENCV5"], 640, 480)
    p = np.array([[0.0, 0.0, 2.0], [0.4, 0.3, 1.0]])
    q0, q1 = pinhole.project(p), distorted.project(p)
    np.testing.assert_allclose(q0[0], q1[0], atol=1e-9)
    np.testing.assert_allclose(q0[0], [319.5, 241.25])
    assert np.linalg.norm(q0[1] - q1[1]) > 5.0


def test_pinhole_projection_is_eq_1():
    cam = Camera.from_opencv(K, [], 640, 480)
    np.testing.assert_allclose(cam.project([[0.2, -0.1, 2.0]]), [[319.5 + 52.0, 241.25 - 25.9]])


def test_points_at_or_behind_the_camera_project_to_nan(camera):
    p = np.array([[0.1, 0.2, 1.0], [0.1, 0.2, -1.0], [0.1, 0.2, 0.0], [0.0, 0.0, -3.0]])
    q, dq_dp = camera.project_with_gradient(p)
    assert np.isfinite(q[0]).all()
    assert np.isfinite(dq_dp[0]).all()
    assert np.isnan(q[1:]).all()
    assert np.isnan(dq_dp[1:]).all()
    assert not camera.in_image(q[1:]).any()


def test_project_gradient_matches_finite_differences(camera):
    p = np.array([[0.3, -0.2, 2.0]])
    _, J = camera.project_with_gradient(p)
    h = 1e-6
    num = np.column_stack(
        [(camera.project(p + h * e) - camera.project(p - h * e))[0] / (2 * h) for e in np.eye(3)]
    )
    np.testing.assert_allclose(J[0], num, rtol=1e-5, atol=1e-4)


# --- pixel convention ----------------------------------------------------------------------------
def test_in_image_uses_the_pixel_centre_convention():
    cam = Camera.from_opencv(K, [], 640, 480)
    inside = [[-0.5, -0.5], [639.5, 479.5], [0.0, 0.0], [639.5, -0.5], [-0.5, 479.5]]
    outside = [
        [-0.5001, 0.0],
        [0.0, -0.5001],
        [639.5001, 0.0],
        [0.0, 479.5001],
        [640.0, 240.0],
        [np.nan, 1.0],
    ]
    assert cam.in_image(inside).all()
    assert not cam.in_image(outside).any()


def test_in_image_margin_shrinks_the_image_on_every_side():
    cam = Camera.from_opencv(K, [], 640, 480)
    assert cam.in_image([[9.5, 9.5], [629.5, 469.5]], margin_px=10).all()
    assert not cam.in_image([[9.4, 100.0], [100.0, 9.4], [629.6, 100.0], [100.0, 469.6]], margin_px=10).any()


def test_principal_point_projects_to_cx_cy_in_the_pixel_centre_convention():
    cam = read_camera(EXAMPLE_CAMERA)
    np.testing.assert_allclose(cam.project([[0.0, 0.0, 1.0]]), [[319.5, 239.5]])
    np.testing.assert_allclose(cam.bearings([[319.5, 239.5]]), [[0.0, 0.0, 1.0]], atol=1e-12)


# --- read_camera: OpenCV YAML errors -------------------------------------------------------------
def test_example_camera_reads():
    cam = read_camera(EXAMPLE_CAMERA)
    assert cam.lensmodel == "LENSMODEL_OPENCV5"
    assert (cam.width_px, cam.height_px) == (640, 480)
    assert cam.source == str(EXAMPLE_CAMERA)


def test_distortion_and_name_are_optional(camera_yaml):
    doc = yaml.safe_load(camera_yaml.read_text())
    del doc["distortion"]
    doc["name"] = "front"
    assert read_camera(write_doc(camera_yaml, doc)).lensmodel == "LENSMODEL_PINHOLE"


def test_missing_camera_file(tmp_path):
    path = tmp_path / "none.yaml"
    with pytest.raises(InputError, match=re.escape(f"{path}: camera file not found")):
        read_camera(path)


def test_bad_yaml_names_the_line(camera_yaml):
    camera_yaml.write_text("schema_version: 1\nK: [[1, 0, 2],\n  [0, 1\nimage_width_px: 3\n")
    with pytest.raises(InputError, match=rf"{re.escape(str(camera_yaml))}: not valid YAML at line \d+"):
        read_camera(camera_yaml)


def test_camera_file_not_a_mapping(camera_yaml):
    camera_yaml.write_text("[520, 520, 319.5, 239.5]\n")
    expect_error(camera_yaml, "(top level)", "[520, 520, 319.5, 239.5]")


def test_unknown_key(camera_yaml):
    message = expect_error(
        edit(camera_yaml, lensmodel="LENSMODEL_OPENCV5"), "lensmodel", "'LENSMODEL_OPENCV5'"
    )
    assert "no such key" in message


@pytest.mark.parametrize("key", ["schema_version", "image_width_px", "image_height_px", "K"])
def test_missing_key(camera_yaml, key):
    doc = yaml.safe_load(camera_yaml.read_text())
    del doc[key]
    with pytest.raises(InputError, match=re.escape(f"{camera_yaml}: {key}: missing")):
        read_camera(write_doc(camera_yaml, doc))


@pytest.mark.parametrize(("version", "shown"), [(2, "2"), ("1", "'1'"), (True, "True")])
def test_wrong_schema_version(camera_yaml, version, shown):
    expect_error(edit(camera_yaml, schema_version=version), "schema_version", shown)


@pytest.mark.parametrize("key", ["image_width_px", "image_height_px"])
@pytest.mark.parametrize(
    ("value", "shown"), [(0, "0"), (-480, "-480"), (640.0, "640.0"), (True, "True"), ("640", "'640'")]
)
def test_bad_image_size(camera_yaml, key, value, shown):
    message = expect_error(edit(camera_yaml, **{key: value}), key, shown)
    assert "a positive integer" in message


@pytest.mark.parametrize(
    ("K_value", "key", "shown"),
    [
        ([[520, 0, 319.5], [0, 520, 239.5]], "K", "[[520, 0, 319.5], [0, 520, 239.5]]"),
        ([520, 520, 319.5, 239.5], "K", "[520, 520, 319.5, 239.5]"),
        ("identity", "K", "'identity'"),
        ([[520, 0, 319.5], [0, 520], [0, 0, 1]], "K[1]", "[0, 520]"),
        ([[520, 0, 319.5], [0, 520, 239.5], [0, 0, 1, 0]], "K[2]", "[0, 0, 1, 0]"),
        ([[520, 0, "319.5"], [0, 520, 239.5], [0, 0, 1]], "K[0][2]", "'319.5'"),
        ([[520, 0, 319.5], [0, float("nan"), 239.5], [0, 0, 1]], "K[1][1]", "nan"),
        ([[520, 0, 319.5], [0, 520, float("inf")], [0, 0, 1]], "K[1][2]", "inf"),
        ([[True, 0, 319.5], [0, 520, 239.5], [0, 0, 1]], "K[0][0]", "True"),
    ],
)
def test_wrong_matrix_shape_or_entries(camera_yaml, K_value, key, shown):
    expect_error(edit(camera_yaml, K=K_value), key, shown)


@pytest.mark.parametrize(
    "K_value",
    [
        [[520, 1.5, 319.5], [0, 520, 239.5], [0, 0, 1]],
        [[520, 0, 319.5], [0.2, 520, 239.5], [0, 0, 1]],
        [[520, 0, 319.5], [0, 520, 239.5], [0, 0, 2]],
        [[520, 0, 319.5], [0, 520, 239.5], [0.001, 0, 1]],
    ],
)
def test_skewed_or_malformed_matrix(camera_yaml, K_value):
    message = expect_error(edit(camera_yaml, K=K_value), "K", repr(K_value))
    assert "no skew" in message


@pytest.mark.parametrize(
    "K_value",
    [
        [[0, 0, 319.5], [0, 520, 239.5], [0, 0, 1]],
        [[520, 0, 319.5], [0, -520, 239.5], [0, 0, 1]],
        [[-520, 0, 319.5], [0, -520, 239.5], [0, 0, 1]],
    ],
)
def test_non_positive_focal_length(camera_yaml, K_value):
    message = expect_error(edit(camera_yaml, K=K_value), "K", repr(K_value))
    assert "positive focal lengths" in message


@pytest.mark.parametrize(
    ("dist", "shown"),
    [
        ([0.1, 0.2, 0.3], "[0.1, 0.2, 0.3]"),
        ([0.0] * 6, repr([0.0] * 6)),
        ([0.0] * 14, repr([0.0] * 14)),
        ("none", "'none'"),
        (None, "None"),
    ],
)
def test_wrong_number_of_distortion_coefficients(camera_yaml, dist, shown):
    message = expect_error(edit(camera_yaml, distortion=dist), "distortion", shown)
    assert "0, 4, 5, 8 or 12" in message


@pytest.mark.parametrize(("bad", "shown"), [("0.1", "'0.1'"), (float("nan"), "nan"), (False, "False")])
def test_bad_distortion_coefficient(camera_yaml, bad, shown):
    expect_error(edit(camera_yaml, distortion=[-0.15, 0.05, bad, 0.0, 0.0]), "distortion[2]", shown)


def test_from_opencv_rejects_a_wrong_coefficient_count():
    with pytest.raises(InputError, match=re.escape("cam.yaml: distortion: got [0.1, 0.2]")):
        Camera.from_opencv(K, [0.1, 0.2], 640, 480, source="cam.yaml")


# --- read_camera: .cameramodel errors ------------------------------------------------------------
def write_model(path: Path, **fields: Any) -> Path:
    model = {
        "lensmodel": "LENSMODEL_PINHOLE",
        "intrinsics": [500.0, 500.0, 319.5, 239.5],
        "imagersize": [640, 480],
        "extrinsics": [0, 0, 0, 0, 0, 0],
    } | fields
    path.write_text(repr(model))
    return path


def expect_model_error(path: Path, *fragments: str) -> None:
    with pytest.raises(InputError, match=re.escape(f"{path}: not a valid mrcal cameramodel:")) as exc:
        read_camera(path)
    assert "\n" not in str(exc.value)
    for f in fragments:
        assert f in str(exc.value)


def test_hand_written_cameramodel_reads(tmp_path):
    cam = read_camera(write_model(tmp_path / "c.cameramodel"))
    assert cam.lensmodel == "LENSMODEL_PINHOLE"
    np.testing.assert_array_equal(cam.intrinsics, [500.0, 500.0, 319.5, 239.5])


def test_missing_cameramodel(tmp_path):
    path = tmp_path / "none.cameramodel"
    with pytest.raises(InputError, match=re.escape(f"{path}: camera model not found")):
        read_camera(path)


@pytest.mark.parametrize("text", ["this is { not a model", "", "\x00\x01binary"])
def test_corrupt_cameramodel(tmp_path, text):
    path = tmp_path / "c.cameramodel"
    path.write_text(text)
    expect_model_error(path)


def test_cameramodel_with_unknown_lens_model(tmp_path):
    expect_model_error(write_model(tmp_path / "c.cameramodel", lensmodel="LENSMODEL_FOO"), "LENSMODEL_FOO")


def test_cameramodel_with_wrong_intrinsics_count(tmp_path):
    path = write_model(tmp_path / "c.cameramodel", lensmodel="LENSMODEL_OPENCV4")
    expect_model_error(path, "LENSMODEL_OPENCV4")


@pytest.mark.parametrize("size", [[0, 480], [640], "640x480"])
def test_cameramodel_with_bad_image_size(tmp_path, size):
    expect_model_error(write_model(tmp_path / "c.cameramodel", imagersize=size))


def test_cameramodel_without_image_size(tmp_path):
    path = tmp_path / "c.cameramodel"
    path.write_text(repr({"lensmodel": "LENSMODEL_PINHOLE", "intrinsics": [500.0, 500.0, 319.5, 239.5]}))
    expect_model_error(path, "imagersize")


# --- embedded camera block (rig files) -----------------------------------------------------------
def embedded(**changes: Any) -> dict[str, Any]:
    return {
        "lensmodel": "LENSMODEL_PINHOLE",
        "intrinsics": [500.0, 500.0, 319.5, 239.5],
        "imagersize": [640, 480],
    } | changes


@pytest.mark.parametrize(
    ("d", "key", "shown"),
    [
        (embedded(lensmodel="LENSMODEL_FOO"), "camera.lensmodel", "'LENSMODEL_FOO'"),
        (embedded(lensmodel=5), "camera.lensmodel", "5"),
        (embedded(intrinsics=[500.0, 500.0, 319.5]), "camera.intrinsics", "[500.0, 500.0, 319.5]"),
        (embedded(intrinsics=[500.0, 500.0, 319.5, "x"]), "camera.intrinsics[3]", "'x'"),
        (embedded(imagersize=[640, 0]), "camera.imagersize", "[640, 0]"),
        (embedded(imagersize=[640.0, 480]), "camera.imagersize", "[640.0, 480]"),
        (embedded(imagersize=[640]), "camera.imagersize", "[640]"),
        (embedded(distortion=[0.1]), "camera.distortion", "[0.1]"),
        ("pinhole", "camera", "'pinhole'"),
    ],
)
def test_embedded_camera_errors(d, key, shown):
    with pytest.raises(InputError, match=re.escape(f"rig.yaml: {key}: got {shown};")):
        camera_from_dict(d, "rig.yaml", "camera")


def test_embedded_camera_missing_key():
    d = embedded()
    del d["imagersize"]
    with pytest.raises(InputError, match=re.escape("rig.yaml: camera.imagersize: missing")):
        camera_from_dict(d, "rig.yaml", "camera")


def test_cameramodel_with_a_negative_focal_length_is_refused(tmp_path):
    import mrcal

    path = tmp_path / "neg.cameramodel"
    intrinsics = ("LENSMODEL_PINHOLE", np.array([-500.0, 500.0, 320.0, 240.0]))
    mrcal.cameramodel(intrinsics=intrinsics, imagersize=(640, 480)).write(str(path))
    with pytest.raises(
        InputError, match=r"neg\.cameramodel: intrinsics: got \[-500\.0.*positive focal lengths"
    ):
        read_camera(path)
