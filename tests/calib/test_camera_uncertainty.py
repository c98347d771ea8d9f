"""The camera's own uncertainty in a board calibration: a mrcal model's intrinsics
covariance, propagated into T_cam_laser's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.camera import intrinsics_covariance, read_intrinsics_covariance
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.boards import solved_camera_model


@pytest.fixture(scope="module")
def model():
    sim = generate_board_session(BoardSpec(n_captures=2, seed=1))
    return solved_camera_model(sim.camera, n_views=12, seed=5)


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, model):
    """The same board session with its camera as a mrcal model that keeps its
    optimization_inputs, and as the same model without them."""
    sim = generate_board_session(BoardSpec(n_captures=8, seed=4))
    root = tmp_path_factory.mktemp("cam")
    folder = write_board_session(sim, root / "s")
    model.write(str(folder / "camera.cameramodel"))
    bare = type(model)(intrinsics=model.intrinsics(), imagersize=model.imagersize())
    bare.write(str(folder / "bare.cameramodel"))
    out = {}
    for name in ("camera.cameramodel", "bare.cameramodel"):
        doc = yaml.safe_load((folder / "board_session.yaml").read_text())
        doc["camera"] = name
        path = folder / f"session_{Path(name).stem}.yaml"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
        out[name] = path
    return sim, out


def test_intrinsics_covariance_is_mrcals_and_covers_the_solves_error(model):
    from rigcal.sim.box_session import default_camera

    cov = intrinsics_covariance(model)
    n = len(model.intrinsics()[1])
    assert cov.shape == (n, n)
    assert np.allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov)[0] > -1e-12 * np.abs(cov).max()
    sig = np.sqrt(np.diag(cov))
    assert (sig > 0).all()
    # The solved focal lengths and centre are within 4 of their own sigmas of the truth.
    err = model.intrinsics()[1] - default_camera().intrinsics
    assert (np.abs(err[:4]) < 4.0 * sig[:4]).all()
    # A model without optimization_inputs has none.
    bare = type(model)(intrinsics=model.intrinsics(), imagersize=model.imagersize())
    assert intrinsics_covariance(bare) is None


def test_a_mrcal_model_carries_its_uncertainty_into_t(sessions, model):
    _sim, paths = sessions
    cal = calibrate_board(paths["camera.cameramodel"])
    cam = cal.report["uncertainty"]["camera"]
    assert cam["included"] is True
    assert "optimization_inputs" in cam["source"]
    assert np.allclose(cam["intrinsics_sigma"], np.sqrt(np.diag(intrinsics_covariance(model))), rtol=1e-5)
    assert all(0.0 < s <= 1.0 for s in cam["variance_share"])
    base = calibrate_board(paths["bare.cameramodel"])
    assert base.report["uncertainty"]["camera"]["included"] is False
    # The same solve; only the covariance grows, by the camera's share.
    assert np.array_equal(cal.result.T_cam_laser, base.result.T_cam_laser)
    added = cal.result.covariance - base.result.covariance
    assert np.linalg.eigvalsh(added)[0] > -1e-15
    shares = np.diag(added) / np.diag(cal.result.covariance)
    assert np.allclose(cam["variance_share"], shares, atol=1e-4)
    from rigcal.calib.board.calibrate import board_report_table

    assert "optimization_inputs" in board_report_table(cal.report)


def test_given_sigmas_take_precedence_over_the_models(sessions):
    _, paths = sessions
    sig = [0.5] + [0.0] * 8
    cal = calibrate_board(paths["camera.cameramodel"], intrinsics_sigma=sig)
    cam = cal.report["uncertainty"]["camera"]
    assert cam["source"].startswith("--intrinsics-sigma")
    assert cam["intrinsics_sigma"] == sig


def test_files_without_the_uncertainty_say_so_in_one_line(sessions, tmp_path):
    _, paths = sessions
    note = calibrate_board(paths["bare.cameramodel"]).report["uncertainty"]["camera"]["note"]
    assert "keeps no optimization_inputs" in note
    assert "--intrinsics-sigma" in note
    assert "\n" not in note
    cov, why = read_intrinsics_covariance(paths["bare.cameramodel"].parent / "camera.yaml")
    assert cov is None
    assert "OpenCV, ROS or rigcal camera file" in why
