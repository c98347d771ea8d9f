"""Rig files: write/read round trip, the stated direction, validation of every field, overwrite refusal."""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from rigcal.camera import Camera
from rigcal.errors import InputError, OutputError
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.rig import COVARIANCE_PARAMETERS, Rig
from rigcal.rigfile import provenance, read_rig, write_rig

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "box-session"

ROTVEC = np.array([1.2005, -1.1931, 1.2093])
TRANSLATION = np.array([0.0102, 0.1187, -0.0496])


def covariance() -> np.ndarray:
    """A full-rank 6x6 covariance of the usual size (rad^2 and m^2), with correlations."""
    A = np.random.default_rng(3).normal(size=(6, 6))
    D = np.diag(np.sqrt([1e-7] * 3 + [1e-5] * 3))
    return D @ (A @ A.T / 6 + np.eye(6)) @ D


@pytest.fixture
def rig(tmp_path) -> Rig:
    inputs = tmp_path / "input.txt"
    inputs.write_text("picks")
    camera = Camera.from_opencv(
        [[520.0, 0, 319.5], [0, 520.0, 239.5], [0, 0, 1]], [-0.15, 0.05, 0.0005, -0.0003, 0.0], 640, 480
    )
    return Rig(
        T_cam_laser=make_T(rotvec_to_R(ROTVEC), TRANSLATION),
        camera=camera,
        covariance=covariance(),
        laser={
            "name": "hokuyo-utm30lx-sim",
            "angle_increment_deg": np.float64(0.25),
            "beams": np.int64(1081),
        },
        residuals={"captures": 20, "rms_px": np.float64(1.02), "used": np.bool_(True)},
        provenance=provenance("rigcal solve picks.yaml -o rig.yaml", [inputs], {"ransac": {"seed": 0}}),
    )


@pytest.fixture
def rig_path(tmp_path, rig) -> Path:
    return write_rig(tmp_path / "rig.yaml", rig)


def load(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())


def save(path: Path, doc: Any) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def expect_error(path: Path, key: str, shown: str | None = None) -> str:
    """read_rig fails with one line naming the file, the key and (when given) the value."""
    pattern = f"{path}: {key}: " + (f"got {shown};" if shown is not None else "")
    with pytest.raises(InputError, match=re.escape(pattern)) as exc:
        read_rig(path)
    assert "\n" not in str(exc.value)
    return str(exc.value)


# --- round trip ----------------------------------------------------------------------------------
def test_round_trip_keeps_the_transform(rig, rig_path):
    back = read_rig(rig_path)
    np.testing.assert_allclose(back.T_cam_laser, rig.T_cam_laser, rtol=0, atol=1e-11)
    np.testing.assert_allclose(back.T_laser_cam @ back.T_cam_laser, np.eye(4), atol=1e-12)


def test_round_trip_keeps_covariance_and_sigmas(rig, rig_path):
    back = read_rig(rig_path)
    assert back.covariance is not None
    np.testing.assert_allclose(back.covariance, rig.covariance, rtol=1e-6, atol=0)
    for got, want in zip(back.sigmas(), rig.sigmas(), strict=True):
        np.testing.assert_allclose(got, want, rtol=1e-6)
    u = load(rig_path)["uncertainty"]
    np.testing.assert_allclose(u["sigma_rotation_deg"], rig.sigmas()[0], atol=1e-6)
    np.testing.assert_allclose(u["sigma_translation_mm"], rig.sigmas()[1], atol=1e-4)
    assert u["parameters"] == COVARIANCE_PARAMETERS


def test_round_trip_keeps_the_camera(rig, rig_path):
    back = read_rig(rig_path).camera
    assert back.lensmodel == rig.camera.lensmodel
    np.testing.assert_array_equal(back.intrinsics, rig.camera.intrinsics)
    assert (back.width_px, back.height_px) == (640, 480)
    p = np.array([[0.3, -0.2, 2.0], [-1.0, 0.5, 4.0]])
    np.testing.assert_array_equal(back.project(p), rig.camera.project(p))


def test_round_trip_keeps_laser_residuals_and_provenance_as_plain_values(rig, rig_path):
    back = read_rig(rig_path)
    assert back.laser == {"name": "hokuyo-utm30lx-sim", "angle_increment_deg": 0.25, "beams": 1081}
    assert back.residuals == {"captures": 20, "rms_px": 1.02, "used": True}
    assert back.provenance == rig.provenance
    assert back.provenance["inputs"][0]["sha256"] == rig.provenance["inputs"][0]["sha256"]
    assert len(back.provenance["inputs"][0]["sha256"]) == 64
    assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", back.provenance["created_utc"])
    assert back.provenance["ransac"] == {"seed": 0}


def test_rig_without_uncertainty_round_trips(tmp_path, rig):
    bare = Rig(rig.T_cam_laser, rig.camera)
    path = write_rig(tmp_path / "bare.yaml", bare)
    assert "uncertainty" not in load(path)
    back = read_rig(path)
    assert back.covariance is None
    assert back.sigmas() is None
    assert back.laser == back.residuals == back.provenance == {}


def test_singular_covariance_round_trips(tmp_path, rig):
    J = np.random.default_rng(7).normal(size=(6, 5)) * 1e-3
    J[:, 0] *= 10.0
    cov = J @ J.T
    cov = (cov + cov.T) / 2
    path = write_rig(tmp_path / "singular.yaml", Rig(rig.T_cam_laser, rig.camera, cov))
    np.testing.assert_allclose(read_rig(path).covariance, cov, rtol=1e-6, atol=1e-18)


def test_solved_example_rig_round_trips(tmp_path):
    from rigcal.calib.box.session import calibrate

    cal = calibrate(EXAMPLE / "picks.yaml")
    back = read_rig(write_rig(tmp_path / "rig.yaml", cal.rig))
    np.testing.assert_allclose(back.T_cam_laser, cal.rig.T_cam_laser, atol=1e-11)
    np.testing.assert_allclose(back.covariance, cal.rig.covariance, rtol=1e-6)
    assert back.residuals == cal.rig.residuals
    assert len(back.provenance["inputs"]) == 42


# --- the direction on disk -----------------------------------------------------------------------
def test_file_states_laser_to_cam(rig_path):
    text = rig_path.read_text()
    assert "maps: laser -> cam" in text
    assert text.startswith("# rigcal rig file, schema 2")
    assert "p_cam = R p_laser + t" in text
    assert load(rig_path)["T_cam_laser"]["maps"] == "laser -> cam"


def test_file_block_maps_laser_points_into_the_camera_frame(rig, rig_path):
    block = load(rig_path)["T_cam_laser"]
    R = Rotation.from_rotvec(block["rotation_vector_rad"]).as_matrix()
    p_laser = np.array([2.0, -0.5, 0.0])
    p_cam = rig.T_cam_laser @ np.append(p_laser, 1.0)
    np.testing.assert_allclose(R @ p_laser + block["translation_m"], p_cam[:3], atol=1e-10)
    np.testing.assert_allclose(block["translation_m"], TRANSLATION, atol=1e-12)
    np.testing.assert_allclose(block["rotation_vector_rad"], ROTVEC, atol=1e-12)


# --- validation ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("where", "key"),
    [
        ((), "notes"),
        (("T_cam_laser",), "quaternion_xyzw"),
        (("uncertainty",), "sigma_rotation_rad"),
        (("camera",), "distortion"),
    ],
)
def test_unknown_keys_are_rejected_at_each_level(rig_path, where, key):
    doc = load(rig_path)
    target = doc
    for w in where:
        target = target[w]
    target[key] = [1.0]
    message = expect_error(save(rig_path, doc), ".".join((*where, key)), "[1.0]")
    assert "no such key" in message


@pytest.mark.parametrize(
    "keypath",
    [
        "schema_version",
        "T_cam_laser",
        "camera",
        "T_cam_laser.maps",
        "T_cam_laser.rotation_vector_rad",
        "T_cam_laser.translation_m",
        "uncertainty.parameters",
        "uncertainty.covariance",
        "camera.lensmodel",
        "camera.intrinsics",
    ],
)
def test_missing_required_key(rig_path, keypath):
    doc = load(rig_path)
    *parents, key = keypath.split(".")
    target = doc
    for p in parents:
        target = target[p]
    del target[key]
    with pytest.raises(InputError, match=re.escape(f"{rig_path}: {keypath}: missing")):
        read_rig(save(rig_path, doc))


@pytest.mark.parametrize(
    ("version", "shown"), [(4, "4"), (0, "0"), ("1", "'1'"), (True, "True"), (None, "None")]
)
def test_wrong_schema_version(rig_path, version, shown):
    doc = load(rig_path)
    doc["schema_version"] = version
    message = expect_error(save(rig_path, doc), "schema_version", shown)
    assert re.search(r"expected 1, 2", message)
    if version == 4:  # newer than this rigcal reads: named as such
        assert "a file of a newer rigcal: upgrade rigcal to read it" in message


@pytest.mark.parametrize("maps", ["cam -> laser", "laser->cam", "laser -> camera", None])
def test_maps_other_than_laser_to_cam_is_rejected(rig_path, maps):
    doc = load(rig_path)
    doc["T_cam_laser"]["maps"] = maps
    message = expect_error(save(rig_path, doc), "T_cam_laser.maps", repr(maps))
    assert "'laser -> cam'" in message


def test_rotation_vector_longer_than_pi_is_rejected(rig_path):
    doc = load(rig_path)
    doc["T_cam_laser"]["rotation_vector_rad"] = [0.0, 3.2, 0.0]
    message = expect_error(save(rig_path, doc), "T_cam_laser.rotation_vector_rad", "[0.0, 3.2, 0.0]")
    assert "at most pi" in message


def test_rotation_of_exactly_pi_is_accepted(rig_path):
    doc = load(rig_path)
    doc["T_cam_laser"]["rotation_vector_rad"] = [0.0, 0.0, float(np.pi)]
    T = read_rig(save(rig_path, doc)).T_cam_laser
    np.testing.assert_allclose(T[:3, :3], np.diag([-1.0, -1.0, 1.0]), atol=1e-12)


@pytest.mark.parametrize(
    ("key", "value", "where", "shown"),
    [
        ("rotation_vector_rad", [0.1, 0.2], "T_cam_laser.rotation_vector_rad", "[0.1, 0.2]"),
        ("rotation_vector_rad", [0.1, "0.2", 0.3], "T_cam_laser.rotation_vector_rad[1]", "'0.2'"),
        ("rotation_vector_rad", [0.1, 0.2, float("nan")], "T_cam_laser.rotation_vector_rad[2]", "nan"),
        ("translation_m", [0.1, 0.2, 0.3, 0.4], "T_cam_laser.translation_m", "[0.1, 0.2, 0.3, 0.4]"),
        ("translation_m", [0.1, True, 0.3], "T_cam_laser.translation_m[1]", "True"),
        ("translation_m", [0.1, 0.2, float("inf")], "T_cam_laser.translation_m[2]", "inf"),
    ],
)
def test_bad_transform_vectors(rig_path, key, value, where, shown):
    doc = load(rig_path)
    doc["T_cam_laser"][key] = value
    expect_error(save(rig_path, doc), where, shown)


def test_transform_block_not_a_mapping(rig_path):
    doc = load(rig_path)
    doc["T_cam_laser"] = [1.2, -1.2, 1.2, 0.0, 0.1, 0.0]
    expect_error(save(rig_path, doc), "T_cam_laser", "[1.2, -1.2, 1.2, 0.0, 0.1, 0.0]")


def set_covariance(path: Path, cov: Any) -> Path:
    doc = load(path)
    doc["uncertainty"]["covariance"] = cov
    for key in ("sigma_rotation_deg", "sigma_translation_mm"):  # they would disagree with cov
        doc["uncertainty"].pop(key, None)
    return save(path, doc)


def test_covariance_not_symmetric_is_rejected(rig_path, rig):
    cov = rig.covariance.copy()
    cov[0, 4] += 1e-7
    message = expect_error(set_covariance(rig_path, cov.tolist()), "uncertainty.covariance")
    assert "symmetric positive semi-definite" in message


@pytest.mark.parametrize("scale", [1e-6, 1e-18])
def test_covariance_not_positive_semi_definite_is_rejected(rig_path, scale):
    cov = np.diag([1.0, 1.0, 1.0, 1.0, 1.0, -0.5]) * scale
    message = expect_error(set_covariance(rig_path, cov.tolist()), "uncertainty.covariance")
    assert "symmetric positive semi-definite" in message


def test_covariance_indefinite_off_diagonal_is_rejected(rig_path):
    cov = np.eye(6) * 1e-6
    cov[1, 4] = cov[4, 1] = 2e-6
    expect_error(set_covariance(rig_path, cov.tolist()), "uncertainty.covariance")


def test_zero_covariance_is_accepted(rig_path):
    np.testing.assert_array_equal(read_rig(set_covariance(rig_path, np.zeros((6, 6)).tolist())).covariance, 0)


@pytest.mark.parametrize(
    ("cov", "where", "shown"),
    [
        (np.eye(5).tolist(), "uncertainty.covariance", None),
        ([[0.0] * 6] * 5 + [[0.0] * 5], "uncertainty.covariance[5]", "[0.0, 0.0, 0.0, 0.0, 0.0]"),
        (np.eye(6).ravel().tolist(), "uncertainty.covariance", None),
        ("diag", "uncertainty.covariance", "'diag'"),
        (
            [[0.0] * 6] * 3 + [[0.0, float("nan"), 0, 0, 0, 0]] + [[0.0] * 6] * 2,
            "uncertainty.covariance[3][1]",
            "nan",
        ),
    ],
)
def test_covariance_of_wrong_shape_or_entries_is_rejected(rig_path, cov, where, shown):
    message = expect_error(set_covariance(rig_path, cov), where, shown)
    if shown is None:
        assert "6 rows of 6 numbers" in message


def test_covariance_parameters_text_must_match(rig_path):
    doc = load(rig_path)
    doc["uncertainty"]["parameters"] = "[dt_x, dt_y, dt_z, dtheta_x, dtheta_y, dtheta_z]"
    expect_error(
        save(rig_path, doc), "uncertainty.parameters", "'[dt_x, dt_y, dt_z, dtheta_x, dtheta_y, dtheta_z]'"
    )


@pytest.mark.parametrize("key", ["sigma_rotation_deg", "sigma_translation_mm"])
def test_sigmas_of_wrong_length_are_rejected(rig_path, key):
    doc = load(rig_path)
    doc["uncertainty"][key] = [1.0, 2.0]
    expect_error(save(rig_path, doc), f"uncertainty.{key}", "[1.0, 2.0]")


def test_uncertainty_not_a_mapping(rig_path):
    doc = load(rig_path)
    doc["uncertainty"] = [0.1, 0.2]
    expect_error(save(rig_path, doc), "uncertainty", "[0.1, 0.2]")


@pytest.mark.parametrize("key", ["laser", "residuals", "provenance"])
def test_free_form_sections_must_be_mappings(rig_path, key):
    doc = load(rig_path)
    doc[key] = "hokuyo"
    expect_error(save(rig_path, doc), key, "'hokuyo'")


def test_camera_block_errors_name_the_rig_file(rig_path):
    doc = load(rig_path)
    doc["camera"]["lensmodel"] = "LENSMODEL_FISHEYE"
    expect_error(save(rig_path, doc), "camera.lensmodel", "'LENSMODEL_FISHEYE'")


def test_missing_rig_file(tmp_path):
    with pytest.raises(InputError, match=re.escape(f"{tmp_path / 'none.yaml'}: rig file not found")):
        read_rig(tmp_path / "none.yaml")


def test_rig_file_that_is_not_yaml(rig_path):
    rig_path.write_text("schema_version: 1\nT_cam_laser: {maps: laser -> cam\n")
    with pytest.raises(InputError, match=rf"{re.escape(str(rig_path))}: not valid YAML at line \d+"):
        read_rig(rig_path)


# --- writing -------------------------------------------------------------------------------------
def test_refuses_to_overwrite_without_force(rig_path, rig):
    before = rig_path.read_bytes()
    other = Rig(np.eye(4), rig.camera)
    with pytest.raises(OutputError, match=re.escape(f"{rig_path}: exists")):
        write_rig(rig_path, other)
    assert rig_path.read_bytes() == before
    assert sorted(p.name for p in rig_path.parent.iterdir()) == ["input.txt", "rig.yaml"]


def test_force_overwrites(rig_path, rig):
    write_rig(rig_path, Rig(np.eye(4), rig.camera), force=True)
    np.testing.assert_array_equal(read_rig(rig_path).T_cam_laser, np.eye(4))


def test_writes_into_a_new_folder(tmp_path, rig):
    path = write_rig(tmp_path / "out" / "deeper" / "rig.yaml", rig)
    assert read_rig(path).camera.width_px == 640


def test_refuses_a_folder_as_output(tmp_path, rig):
    with pytest.raises(OutputError, match="folder"):
        write_rig(tmp_path, rig, force=True)


# --- golden file ---------------------------------------------------------------------------------
GOLDEN = """\
# rigcal rig file, schema 1 (docs/formats/rig.md).
# T_cam_laser maps laser-frame points into the camera frame: p_cam = R p_laser + t,
# R given as a rotation vector (axis * angle, rad), t in metres.
schema_version: 1
T_cam_laser:
  maps: laser -> cam
  rotation_vector_rad: [1.2005, -1.1931, 1.2093]
  translation_m: [0.0102, 0.1187, -0.0496]
uncertainty:
  parameters: '[dtheta_x, dtheta_y, dtheta_z] rad, [dt_x, dt_y, dt_z] m, in the camera frame:
    R_true = Exp(dtheta) R, t_true = t + dt'
  covariance:
  - [1.0e-06, 0, 0, 0, 0, 0]
  - [0, 4.0e-06, 0, 0, 0, 0]
  - [0, 0, 1.0e-06, 0, 0, 2.0e-07]
  - [0, 0, 0, 4.0e-06, 0, 0]
  - [0, 0, 0, 0, 1.0e-06, 0]
  - [0, 0, 2.0e-07, 0, 0, 9.0e-06]
  sigma_rotation_deg: [0.0573, 0.1146, 0.0573]
  sigma_translation_mm: [2.0, 1.0, 3.0]
camera:
  lensmodel: LENSMODEL_OPENCV5
  intrinsics: [520.0, 520.0, 319.5, 239.5, -0.15, 0.05, 0.0005, -0.0003, 0.0]
  imagersize: [640, 480]
laser: {name: hokuyo-utm30lx-sim, angle_increment_deg: 0.25}
residuals: {captures: 20, captures_used: 20, box_ends: 40, inlier_ends: 39, rms_px: 1.02}
provenance:
  rigcal_version: 0.1.0
  created_utc: '2026-11-22T21:00:00Z'
  command: rigcal solve examples/box-session/picks.yaml -o out/rig.yaml
  inputs: [{path: picks.yaml, sha256: 0000000000000000000000000000000000000000000000000000000000000000}]
  method: box-target (Algorithm 1)
  ransac: {threshold_px: 6.0, confidence: 0.999, seed: 0}
"""


def test_hand_written_rig_file_reads_as_documented(tmp_path):
    path = tmp_path / "golden.yaml"
    path.write_text(GOLDEN)
    rig = read_rig(path)
    R = Rotation.from_rotvec([1.2005, -1.1931, 1.2093]).as_matrix()
    np.testing.assert_allclose(rig.T_cam_laser[:3, :3], R, atol=1e-12)
    np.testing.assert_allclose(rig.T_cam_laser[:3, 3], [0.0102, 0.1187, -0.0496])
    np.testing.assert_array_equal(rig.T_cam_laser[3], [0, 0, 0, 1])
    assert rig.covariance[2, 5] == rig.covariance[5, 2] == 2e-7
    rot_deg, trans_mm = rig.sigmas()
    np.testing.assert_allclose(rot_deg, np.degrees([1e-3, 2e-3, 1e-3]))
    np.testing.assert_allclose(trans_mm, [2.0, 1.0, 3.0])
    assert rig.camera.lensmodel == "LENSMODEL_OPENCV5"
    np.testing.assert_array_equal(
        rig.camera.intrinsics, [520.0, 520.0, 319.5, 239.5, -0.15, 0.05, 0.0005, -0.0003, 0.0]
    )
    assert (rig.camera.width_px, rig.camera.height_px) == (640, 480)
    assert rig.laser == {"name": "hokuyo-utm30lx-sim", "angle_increment_deg": 0.25}
    assert rig.residuals["inlier_ends"] == 39
    assert rig.provenance["ransac"]["seed"] == 0
    assert rig.provenance["created_utc"] == "2026-11-22T21:00:00Z"


def test_hand_written_rig_file_rewrites_to_the_same_values(tmp_path):
    path = tmp_path / "golden.yaml"
    path.write_text(GOLDEN)
    rig = read_rig(path)
    again = read_rig(write_rig(tmp_path / "again.yaml", rig))
    np.testing.assert_allclose(again.T_cam_laser, rig.T_cam_laser, atol=1e-12)
    np.testing.assert_array_equal(again.covariance, rig.covariance)
    assert load(tmp_path / "again.yaml")["T_cam_laser"] == load(path)["T_cam_laser"]
    assert again.provenance == rig.provenance


# --- schema 2: the covariance's checks ------------------------------------------------------------
def checks() -> dict[str, Any]:
    return {
        "noise": {"range_sigma_m": {"assumed": 0.01, "estimated": 0.0142, "used": 0.0142}},
        "model_covariance": covariance().tolist(),
        "spread": {
            "method": "leave-one-capture-out (jackknife)",
            "scale": 1.3,
            "covariance": covariance().tolist(),
        },
        "sensitivity": [{"setting": "range_sigma_m", "factor": 2.0, "sigmas": 0.4}],
    }


def test_schema_2_round_trips_the_uncertainty_checks(tmp_path, rig):
    from dataclasses import replace

    path = write_rig(tmp_path / "r2.yaml", replace(rig, uncertainty=checks()))
    back = read_rig(path)
    assert load(path)["schema_version"] == 2
    assert back.uncertainty["noise"] == checks()["noise"]
    assert back.uncertainty["spread"]["scale"] == 1.3
    np.testing.assert_allclose(back.uncertainty["model_covariance"], covariance(), rtol=1e-6)
    assert back.uncertainty["sensitivity"][0]["setting"] == "range_sigma_m"


def test_schema_1_files_are_read_without_the_checks(rig_path):
    doc = load(rig_path)
    doc["schema_version"] = 1
    rig = read_rig(save(rig_path, doc))
    assert rig.uncertainty == {}
    assert rig.covariance is not None


def test_schema_1_files_may_not_carry_schema_2_keys(rig_path):
    doc = load(rig_path)
    doc["schema_version"] = 1
    doc["uncertainty"]["spread"] = checks()["spread"]
    expect_error(save(rig_path, doc), "uncertainty.spread")


@pytest.mark.parametrize(
    ("key", "value", "where"),
    [
        ("noise", [1, 2], "uncertainty.noise"),
        (
            "noise",
            {"range_sigma_m": {"assumed": 0.01, "used": 0.01}},
            "uncertainty.noise.range_sigma_m.estimated",
        ),
        (
            "noise",
            {"range_sigma_m": {"assumed": -1, "estimated": None, "used": 0.01}},
            "uncertainty.noise.range_sigma_m.assumed",
        ),
        (
            "noise",
            {"range_sigma_m": {"assumed": 0.01, "estimated": ".nan", "used": 0.01}},
            "uncertainty.noise.range_sigma_m.estimated",
        ),
        ("model_covariance", [[1.0, 2.0]], "uncertainty.model_covariance"),
        ("spread", {"scale": 1.0}, "uncertainty.spread"),
        ("spread", {"scale": True, "covariance": covariance().tolist()}, "uncertainty.spread.scale"),
        ("sensitivity", {"a": 1}, "uncertainty.sensitivity"),
    ],
)
def test_bad_uncertainty_checks_are_named(rig_path, key, value, where):
    doc = load(rig_path)
    doc["uncertainty"][key] = value
    expect_error(save(rig_path, doc), where)
