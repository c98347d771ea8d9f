"""Board sessions: board pose by PnP, reading a session, the plane-method pipeline, every rejected file."""

from __future__ import annotations

import re
import shutil
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest
import yaml

from rigcal.calib.board.calibrate import board_report, board_report_table, calibrate_board
from rigcal.calib.board.plane import PlaneObservation, solve_plane
from rigcal.calib.board.session import board_points, board_pose, read_board_session
from rigcal.calib.intrinsics import Board
from rigcal.errors import InputError
from rigcal.geometry import R_to_rotvec, make_T, rotvec_to_R, transform_points
from rigcal.lines import LineParams, extract_lines
from rigcal.sim.board_session import BoardSpec, T_cam_board, generate_board_session, write_board_session
from rigcal.sim.box_session import default_camera

BOARD = Board(8, 6, 0.06)


def pose_error(T_est: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """[d, e] in board_pose's tangent space: R_true = Exp(d) R_est, t_true = t_est + e."""
    d = R_to_rotvec(T_true[:3, :3] @ T_est[:3, :3].T)
    return np.concatenate([d, T_true[:3, 3] - T_est[:3, 3]])


def true_plane(T: np.ndarray) -> tuple[np.ndarray, float]:
    """The board plane n . p = d (d > 0) of a board pose in the camera frame."""
    n = T[:3, 2]
    d = float(n @ T[:3, 3])
    return (n, d) if d > 0 else (-n, -d)


def render_board(T: np.ndarray, size: tuple[int, int] = (640, 480)) -> np.ndarray:
    """A grey image of BOARD at pose T through the default camera, 2x supersampled: its
    (width_n + 1) x (height_n + 1) dark and light squares on a light background."""
    cam = default_camera()
    sp = BOARD.spacing_m
    outline = np.array(
        [[-1, -1, 0], [BOARD.width_n, -1, 0], [BOARD.width_n, BOARD.height_n, 0], [-1, BOARD.height_n, 0]]
    )
    box = cam.project(transform_points(T, sp * outline))
    (u0, v0), (u1, v1) = np.floor(box.min(axis=0)).astype(int) - 2, np.ceil(box.max(axis=0)).astype(int) + 2
    u, v = np.meshgrid(np.arange(2 * u0, 2 * u1) / 2 - 0.25, np.arange(2 * v0, 2 * v1) / 2 - 0.25)
    b = cam.bearings(np.column_stack([u.ravel(), v.ravel()]))
    n, t = T[:3, 2], T[:3, 3]
    q = (b * ((n @ t) / (b @ n))[:, None] - t) @ T[:3, :3]
    i, j = np.floor(q[:, 0] / sp), np.floor(q[:, 1] / sp)
    on = (i >= -1) & (i <= BOARD.width_n - 1) & (j >= -1) & (j <= BOARD.height_n - 1)
    patch = np.where(on & ((i + j) % 2 == 0), 30.0, 220.0).reshape(u.shape)
    img = np.full(size[::-1], 220, np.uint8)
    img[v0:v1, u0:u1] = cv2.resize(patch, (u1 - u0, v1 - v0), interpolation=cv2.INTER_AREA).astype(np.uint8)
    return img


@pytest.fixture(scope="module")
def sim():
    # Low corner noise, so that every board plane is known to well under the tolerances of
    # test_each_plane_matches_the_true_board_plane.
    return generate_board_session(BoardSpec(n_captures=6, seed=7, corner_sigma_px=0.1))


@pytest.fixture(scope="module")
def written(sim, tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("board") / "session"
    write_board_session(sim, folder)
    return folder


@pytest.fixture(scope="module")
def resolved(written):
    return read_board_session(written / "board_session.yaml", corner_sigma_px=0.1)


@pytest.fixture
def session(written, tmp_path) -> Path:
    """A writable copy of the written session; returns its board session file."""
    folder = tmp_path / "session"
    shutil.copytree(written, folder)
    return folder / "board_session.yaml"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    sim = generate_board_session(BoardSpec(n_captures=20, seed=3))
    folder = tmp_path_factory.mktemp("board20") / "session"
    write_board_session(sim, folder)
    return sim, calibrate_board(folder / "board_session.yaml", truth_path=folder / "truth.yaml")


def load(path: Path) -> dict[str, Any]:
    return yaml.safe_load(path.read_text())


def save(path: Path, doc: Any) -> Path:
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def edit(path: Path, change) -> Path:
    doc = load(path)
    change(doc)
    return save(path, doc)


def edit_capture(path: Path, i: int, **changes: Any) -> Path:
    doc = load(path)
    doc["captures"][i].update(changes)
    return save(path, doc)


def expect_error(path: Path, key: str, shown: str) -> str:
    """read_board_session fails with one line ``FILE: KEY: got SHOWN; ...``; returns the message."""
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: got {shown};")) as exc:
        read_board_session(path)
    message = str(exc.value)
    assert "\n" not in message
    return message


# --- board_pose ----------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("rotvec", "t"),
    [
        ([0.3, -0.4, 0.1], [-0.15, -0.1, 1.5]),
        ([-0.5, 0.2, -0.3], [-0.3, -0.15, 1.0]),
        ([0.1, 0.6, 3.0], [0.1, 0.05, 2.5]),
    ],
)
def test_board_pose_recovers_a_known_pose_from_exact_corners(rotvec, t):
    cam = default_camera()
    T = make_T(rotvec_to_R(rotvec), t)
    px = cam.project(transform_points(T, board_points(BOARD)))
    assert cam.in_image(px, 20.0).all()
    T_est, _, rms = board_pose(cam, BOARD, px, 0.5)
    err = pose_error(T_est, T)
    # Translation to 1e-6 m as asked. Rotation to 1e-5 deg rather than 1e-6: OpenCV's
    # iterative PnP stops at a relative step of FLT_EPSILON, which leaves up to ~3e-6 deg
    # (1e-6 px of reprojection error) on random poses; a wrong lens model or corner order
    # would be off by whole degrees.
    assert np.degrees(np.linalg.norm(err[:3])) < 1e-5
    assert np.linalg.norm(err[3:]) < 1e-6
    assert rms < 1e-5


def test_board_pose_covariance_scales_with_the_corner_noise():
    cam = default_camera()
    T = make_T(rotvec_to_R([0.3, -0.4, 0.1]), [-0.15, -0.1, 1.5])
    px = cam.project(transform_points(T, board_points(BOARD)))
    _, cov_big, _ = board_pose(cam, BOARD, px, 0.5)
    _, cov_small, _ = board_pose(cam, BOARD, px, 0.1)
    np.testing.assert_allclose(cov_small, (0.1 / 0.5) ** 2 * cov_big, rtol=1e-9, atol=1e-20)
    assert np.all(np.diag(cov_small) < np.diag(cov_big))
    assert np.all(np.linalg.eigvalsh(cov_small) > 0)


def test_board_pose_covariance_matches_the_scatter_of_noisy_poses():
    cam = default_camera()
    T = make_T(rotvec_to_R([0.3, -0.4, 0.1]), [-0.15, -0.1, 1.5])
    px = cam.project(transform_points(T, board_points(BOARD)))
    rng = np.random.default_rng(1)
    sigma = 0.5
    nees = []
    for _ in range(40):
        T_est, cov, _ = board_pose(cam, BOARD, px + rng.normal(0.0, sigma, px.shape), sigma)
        x = pose_error(T_est, T)
        nees.append(x @ np.linalg.solve(cov, x))
    # With an honest covariance the NEES of the 6-dof error is chi-square(6): mean 6, and the
    # mean of 40 draws has a standard deviation of sqrt(12 / 40) = 0.55. 3..10 leaves room for
    # PnP's nonlinearity and for its fit on undistorted rather than pixel coordinates, and
    # still fails a covariance whose sigmas are off by a factor of 2 (mean 1.5 or 24).
    assert 3.0 < np.mean(nees) < 10.0


# --- a valid file --------------------------------------------------------------------------------
def test_one_plane_observation_per_capture_with_names_and_files(sim, written, resolved):
    C = len(sim.captures)
    assert len(resolved.observations) == C
    assert all(isinstance(o, PlaneObservation) for o in resolved.observations)
    assert [o.name for o in resolved.observations] == [c.name for c in sim.captures]
    assert [o.capture for o in resolved.observations] == list(range(C))
    assert resolved.board == BOARD
    assert resolved.laser["range_sigma_m"] == sim.spec.range_sigma_m
    assert resolved.T_cam_board.shape == (C, 4, 4)
    assert resolved.corner_rms_px.shape == (C,)
    files = [p.resolve() for p in resolved.files]
    expected = [written / "board_session.yaml", written / "camera.yaml"]
    expected += [written / "scans" / f"{c.name}.yaml" for c in sim.captures]
    assert files == [p.resolve() for p in expected]


def test_each_plane_matches_the_true_board_plane(sim, resolved):
    for o, c in zip(resolved.observations, sim.captures, strict=True):
        n, d = true_plane(T_cam_board(sim, c))
        assert np.linalg.norm(o.normal_cam) == pytest.approx(1.0, abs=1e-12)
        assert o.distance_m > 0
        # At 0.1 px corner noise a board up to 3 m away has its normal to ~0.1 deg and the
        # plane's distance from the camera to ~2 mm (1 sigma, from its PnP covariance).
        assert np.degrees(np.arccos(min(1.0, float(n @ o.normal_cam)))) < 0.5
        assert abs(o.distance_m - d) < 0.005
        # The board's origin lies on the plane.
        assert o.normal_cam @ o.board_origin_cam == pytest.approx(o.distance_m, abs=1e-12)


@pytest.mark.parametrize("order", ["mirrored rows", "rotated 180 deg"])
def test_plane_does_not_depend_on_the_corner_order(session, resolved, order):
    grid = np.array(load(session)["captures"][0]["corners_px"]).reshape(BOARD.height_n, BOARD.width_n, 2)
    # Mirrored rows make the board's z axis point at the camera (a board seen from behind):
    # its plane must still come out with distance > 0 and the same normal.
    grid = grid[:, ::-1] if order == "mirrored rows" else grid[::-1, ::-1]
    edit_capture(session, 0, corners_px=grid.reshape(-1, 2).tolist())
    o = read_board_session(session, corner_sigma_px=0.1).observations[0]
    ref = resolved.observations[0]
    assert o.distance_m == pytest.approx(ref.distance_m, abs=1e-6)
    np.testing.assert_allclose(o.normal_cam, ref.normal_cam, atol=1e-6)


def test_an_image_of_the_board_gives_its_plane(session):
    T = make_T(rotvec_to_R([0.3, -0.4, 0.1]), [-0.15, -0.1, 1.5])
    cv2.imwrite(str(session.parent / "board.png"), render_board(T))
    edit(session, lambda d: d["captures"][2].pop("corners_px"))
    edit_capture(session, 2, image="board.png")
    s = read_board_session(session)
    o = s.observations[2]
    n, d = true_plane(T)
    # Corners found to ~0.1 px in a rendered image; OpenCV may number the grid from either
    # end (the pose then turned 180 deg about the board's normal), which leaves the plane.
    assert np.degrees(np.arccos(min(1.0, float(n @ o.normal_cam)))) < 0.3
    assert abs(o.distance_m - d) < 0.003
    assert s.corner_rms_px[2] < 0.3
    assert (session.parent / "board.png").resolve() in [p.resolve() for p in s.files]


def test_board_poses_and_their_corner_rms_follow_the_corner_noise(sim, resolved):
    # Each corner is off by 0.1 px per axis (1 sigma) and rounded to 0.01 px: the RMS of the
    # 2-D residuals after fitting 6 pose parameters to 48 corners is about 0.13 px.
    assert np.all(resolved.corner_rms_px > 0.05)
    assert np.all(resolved.corner_rms_px < 0.3)
    for T, o, c in zip(resolved.T_cam_board, resolved.observations, sim.captures, strict=True):
        x = pose_error(T, T_cam_board(sim, c))
        # Within 5 sigma of its own covariance (chi-square(6) beyond 36: p < 1e-5).
        assert x @ np.linalg.solve(o.board_pose_cov, x) < 36.0


def test_laser_returns_are_the_chosen_segments_points(sim, resolved):
    params = LineParams.for_range_noise(sim.spec.range_sigma_m)
    for o, c in zip(resolved.observations, sim.captures, strict=True):
        seg = extract_lines(c.scan, params)[c.segment_id]
        np.testing.assert_allclose(o.points_laser, seg.points, atol=1e-9)


def test_points_form_picks_the_board_returns(sim, session):
    before = read_board_session(session).observations[0].points_laser
    ends = [[round(float(x), 4) for x in p] for p in before[[0, -1]]]
    edit_capture(session, 0, laser_side={"points": ends})
    after = read_board_session(session).observations[0].points_laser
    # The same returns, give or take one at each end (within 3 cm of the line between the
    # ends, and up to 2 cm beyond them).
    assert len(before) - 2 <= len(after) <= len(before) + 2
    shared = (np.abs(after[:, None, :] - before[None, :, :]).sum(axis=2) < 1e-9).any(axis=1)
    assert shared.sum() >= len(before) - 2


# --- the whole pipeline --------------------------------------------------------------------------
def test_calibrate_board_recovers_the_truth_within_four_sigma(calibrated):
    sim, cal = calibrated
    x = pose_error(cal.result.T_cam_laser, sim.T_cam_laser)
    sigma = np.sqrt(np.diag(cal.result.covariance))
    # Every component of the tangent-space error within 4 sigma (p ~ 6e-5 each if honest).
    assert np.all(np.abs(x) < 4.0 * sigma), (x, sigma)
    truth = cal.report["truth"]
    assert truth["nees"] == pytest.approx(x @ np.linalg.solve(cal.result.covariance, x), rel=1e-3)
    assert truth["translation_error_mm"] == pytest.approx(1000 * np.linalg.norm(x[3:]), abs=1e-3)


def test_calibrate_board_residuals_match_the_range_noise(calibrated):
    _, cal = calibrated
    s = cal.report["summary"]
    assert s["method"] == "board"
    assert s["captures"] == s["captures_used"] == 20
    # A 1 cm range error moves a return off the plane by 1 cm times the cosine of the beam's
    # incidence, plus the plane's own error of a few mm: the RMS is somewhat under 1 cm.
    assert 5.0 < s["rms_mm"] < 15.0
    # The whitened residuals are about unit variance when the noise model is right.
    assert 0.8 < s["residual_scale"] < 1.25
    assert s["returns"] == sum(len(o.points_laser) for o in cal.session.observations)
    assert cal.report["warnings"] == []


def test_calibrate_board_rig_carries_the_solve(calibrated):
    _, cal = calibrated
    np.testing.assert_array_equal(cal.rig.T_cam_laser, cal.result.T_cam_laser)
    np.testing.assert_array_equal(cal.rig.covariance, cal.result.covariance)
    assert cal.rig.camera.width_px == 640
    assert "board" in cal.rig.provenance["method"]
    # Noise estimated from the session: the simulator's 1 cm range and 0.3 px corner noise.
    noise = cal.rig.provenance["noise"]
    assert noise["mode"] == "auto"
    assert noise["range_sigma_m"] == pytest.approx(0.01, rel=0.1)
    assert noise["corner_sigma_px"] == pytest.approx(0.3, rel=0.1)
    assert cal.rig.uncertainty["noise"]["range_sigma_m"]["assumed"] == 0.01
    assert len(cal.rig.provenance["inputs"]) == 2 + 20


def test_board_report_table_lists_every_capture_and_the_truth(calibrated):
    _, cal = calibrated
    text = board_report_table(cal.report)
    for c in cal.report["per_capture"]:
        assert c["capture"] in text
    assert "point-to-plane error" in text
    assert "error against truth" in text
    assert "rejected" not in text


def test_a_capture_with_wrong_returns_is_rejected_and_reported(calibrated):
    sim, cal = calibrated
    obs = list(cal.session.observations)
    # Capture 5's returns moved 30 cm away from the scanner: 3 cm RMS is RANSAC's threshold.
    obs[5] = replace(
        obs[5],
        points_laser=obs[5].points_laser * (1.0 + 0.3 / np.linalg.norm(obs[5].points_laser, axis=1))[:, None],
    )
    result = solve_plane(obs, range_sigma_m=0.01)
    assert result.inlier_captures.tolist() == [i != 5 for i in range(20)]
    report = board_report(replace(cal.session, observations=tuple(obs)), result, sim.T_cam_laser)
    assert report["summary"]["captures_used"] == 19
    assert report["per_capture"][5]["inlier"] is False
    assert report["per_capture"][5]["rms_mm"] > 100
    assert any(w.startswith("capture cap05: rejected") for w in report["warnings"])
    assert any(
        line.startswith("cap05") and line.endswith("rejected")
        for line in board_report_table(report).splitlines()
    )
    # The rejected capture does not spoil the rest: still within 4 sigma of the truth.
    x = pose_error(result.T_cam_laser, sim.T_cam_laser)
    assert np.all(np.abs(x) < 4.0 * np.sqrt(np.diag(result.covariance)))


# --- rejected files ------------------------------------------------------------------------------
def test_schema_version_other_than_1_to_4(session):
    edit(session, lambda d: d.update(schema_version=5))
    assert "expected 1, 2, 3 or 4" in expect_error(session, "schema_version", "5")


def test_unknown_top_level_key(session):
    edit(session, lambda d: d.update(colour="red"))
    assert "no such key" in expect_error(session, "colour", "'red'")


def test_unknown_capture_key(session):
    edit_capture(session, 1, picture="x.png")
    expect_error(session, "captures[1].picture", "'x.png'")


@pytest.mark.parametrize("key", ["camera", "board", "captures"])
def test_missing_top_level_key(session, key):
    edit(session, lambda d: d.pop(key))
    with pytest.raises(InputError, match=re.escape(f"{session}: {key}: missing; this key is required")):
        read_board_session(session)


def test_missing_capture_key(session):
    edit(session, lambda d: d["captures"][2].pop("laser_side"))
    with pytest.raises(InputError, match=re.escape(f"{session}: captures[2].laser_side: missing")):
        read_board_session(session)


@pytest.mark.parametrize(
    ("change", "key", "shown"),
    [
        ({"corners_x": 1}, "board.corners_x", "1"),
        ({"corners_y": "6"}, "board.corners_y", "'6'"),
        ({"corners_x": True}, "board.corners_x", "True"),
        ({"spacing_m": -0.06}, "board.spacing_m", "-0.06"),
        ({"spacing_m": "6 cm"}, "board.spacing_m", "'6 cm'"),
    ],
)
def test_bad_board(session, change, key, shown):
    edit(session, lambda d: d["board"].update(change))
    expect_error(session, key, shown)


def test_board_without_spacing(session):
    edit(session, lambda d: d["board"].pop("spacing_m"))
    with pytest.raises(InputError, match=re.escape(f"{session}: board.spacing_m: missing")):
        read_board_session(session)


def test_board_not_a_mapping(session):
    edit(session, lambda d: d.update(board="8x6"))
    expect_error(session, "board", "'8x6'")


def test_missing_scan_file(session):
    edit_capture(session, 1, scan="scans/nope.yaml")
    assert "nope.yaml" in expect_error(session, "captures[1].scan", "'scans/nope.yaml'")


def test_corners_px_with_the_wrong_count(session):
    corners = load(session)["captures"][0]["corners_px"]
    edit_capture(session, 0, corners_px=corners[:-1])
    assert "48 [u, v] pairs" in expect_error(session, "captures[0].corners_px", "'47 corners'")


def test_corners_px_not_a_list(session):
    edit_capture(session, 0, corners_px="auto")
    expect_error(session, "captures[0].corners_px", "'auto'")


@pytest.mark.parametrize("bad", [["a", 200.0], [300.0], [300.0, float("nan")], [True, 200.0]])
def test_corner_that_is_not_a_pair_of_numbers(session, bad):
    corners = load(session)["captures"][3]["corners_px"]
    corners[5] = bad
    edit_capture(session, 3, corners_px=corners)
    expect_error(session, "captures[3].corners_px[5]", repr(bad))


def test_corner_outside_the_image(session):
    corners = load(session)["captures"][2]["corners_px"]
    corners[7] = [700.0, 100.0]
    edit_capture(session, 2, corners_px=corners)
    assert "inside the image" in expect_error(session, "captures[2].corners_px[7]", "[700.0, 100.0]")


def test_both_corners_px_and_image(session):
    edit_capture(session, 0, image="board.png")
    message = expect_error(session, "captures[0]", "['corners_px', 'image', 'laser_side', 'name', 'scan']")
    assert "exactly one of corners_px" in message


def test_neither_corners_px_nor_image(session):
    edit(session, lambda d: d["captures"][0].pop("corners_px"))
    expect_error(session, "captures[0]", "['laser_side', 'name', 'scan']")


def test_laser_side_segment_out_of_range(session):
    edit_capture(session, 1, laser_side={"segment": 99})
    assert "a segment id from 0 to" in expect_error(session, "captures[1].laser_side.segment", "99")


@pytest.mark.parametrize("side", [{"segment": 1, "points": [[1, 0], [2, 0]]}, {"beams": [1, 2]}, 3])
def test_laser_side_of_the_wrong_form(session, side):
    edit_capture(session, 1, laser_side=side)
    expect_error(session, "captures[1].laser_side", repr(side))


def test_laser_side_points_with_no_returns_near(session):
    # Behind the scanner, outside its 270 deg field of view: no return can lie there.
    edit_capture(session, 0, laser_side={"points": [[-1.0, -0.1], [-1.0, 0.1]]})
    message = expect_error(session, "captures[0].laser_side.points", "[[-1.0, -0.1], [-1.0, 0.1]]")
    assert "no returns near" in message


@pytest.mark.filterwarnings("error")
def test_laser_side_points_that_coincide(session):
    # Two equal points used to divide by their zero distance (a RuntimeWarning) before
    # failing with a misleading "no returns near".
    edit_capture(session, 0, laser_side={"points": [[1.0, 0.2], [1.0, 0.2]]})
    message = expect_error(session, "captures[0].laser_side.points", "[[1.0, 0.2], [1.0, 0.2]]")
    assert "at least 5 cm apart" in message


def test_duplicate_capture_names(session):
    edit_capture(session, 4, name="cap01")
    expect_error(session, "captures[4].name", "'cap01'")


def test_image_that_shows_no_board(session):
    cv2.imwrite(str(session.parent / "blank.png"), np.full((480, 640), 200, np.uint8))
    edit(session, lambda d: d["captures"][1].pop("corners_px"))
    edit_capture(session, 1, image="blank.png")
    assert "8x6 board" in expect_error(session, "captures[1].image", "'blank.png'")


def test_every_image_without_a_board_is_named_in_one_error(session):
    for k in (1, 4):  # one file each: a file named by two captures is refused on its own
        cv2.imwrite(str(session.parent / f"blank{k}.png"), np.full((480, 640), 200, np.uint8))
        edit(session, lambda d, k=k: d["captures"][k].pop("corners_px"))
        edit_capture(session, k, image=f"blank{k}.png")
    message = expect_error(session, "captures[1].image, captures[4].image", "'blank1.png', 'blank4.png'")
    assert "2 of 6 captures show none" in message
    assert "--skip-unseen-boards" in message
    s = read_board_session(session, skip_unseen_boards=True)
    assert [o.name for o in s.observations] == ["cap00", "cap02", "cap03", "cap05"]
    assert [o.capture for o in s.observations] == [0, 2, 3, 5]
    assert len(s.skipped) == 2
    assert s.skipped[0].startswith("cap01 (blank1.png): no 8x6 board found")


def test_skipped_captures_are_warned_about_in_the_report(session):
    cv2.imwrite(str(session.parent / "blank.png"), np.full((480, 640), 200, np.uint8))
    edit(session, lambda d: d["captures"][2].pop("corners_px"))
    edit_capture(session, 2, image="blank.png")
    with pytest.raises(InputError, match=r"captures\[2\]\.image: got 'blank.png'"):
        calibrate_board(session)
    cal = calibrate_board(session, skip_unseen_boards=True)
    assert cal.report["summary"]["captures"] == 5
    assert (
        "capture cap02 (blank.png): no 8x6 board found (left out: --skip-unseen-boards)"
        in cal.report["warnings"]
    )


def test_missing_image_file(session):
    edit(session, lambda d: d["captures"][1].pop("corners_px"))
    edit_capture(session, 1, image="nope.png")
    expect_error(session, "captures[1].image", "'nope.png'")


def test_auto_laser_side_finds_every_boards_segment(tmp_path):
    """`laser_side: auto` picks, in every capture, the segment the simulator put on the board."""
    import re

    from rigcal.lines import LineParams, extract_lines
    from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session

    sim = generate_board_session(BoardSpec(n_captures=10, seed=5))
    folder = write_board_session(sim, tmp_path / "auto")
    f = folder / "board_session.yaml"
    f.write_text(re.sub(r"laser_side: \{segment: \d+\}", "laser_side: auto", f.read_text()))
    session = read_board_session(f)
    params = LineParams.for_range_noise(sim.spec.range_sigma_m)
    for o, c in zip(session.observations, sim.captures, strict=True):
        true_points = np.array(extract_lines(c.scan, params)[c.segment_id].points)
        on_board = (o.points_laser[:, None, :] == true_points[None]).all(axis=2).any(axis=1)
        assert on_board.mean() >= 0.95
        assert on_board.sum() >= 0.9 * len(true_points)


def test_auto_laser_side_without_a_board_sized_segment_is_refused(tmp_path):
    import re

    from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session

    sim = generate_board_session(BoardSpec(n_captures=6, seed=6))
    folder = write_board_session(sim, tmp_path / "s")
    f = folder / "board_session.yaml"
    f.write_text(re.sub(r"laser_side: \{segment: \d+\}", "laser_side: auto", f.read_text(), count=1))
    scan = folder / "scans" / "cap00.yaml"
    doc = yaml.safe_load(scan.read_text())
    doc["ranges_m"] = [0.0] * len(doc["ranges_m"])
    scan.write_text(yaml.safe_dump(doc))
    with pytest.raises(
        InputError,
        match=r"captures\[0\]\.laser_side: got 'auto'; expected the board's returns: cut lengths .* allowed",
    ):
        read_board_session(f)


def test_corners_from_a_corners_vnl_file_give_the_same_planes(tmp_path):
    """A session whose captures name images listed in a mrcal corners.vnl file reads its
    corners from there, exactly as if they were listed inline."""
    sim = generate_board_session(BoardSpec(n_captures=6, seed=8))
    folder = write_board_session(sim, tmp_path / "s")
    f = folder / "board_session.yaml"
    doc = yaml.safe_load(f.read_text())
    rows = ["# filename x y level"]
    for c in doc["captures"]:
        rows += [f"{c['name']}.png {u} {v} 0" for u, v in c.pop("corners_px")]
        c["image"] = f"images/{c['name']}.png"
    (folder / "corners.vnl").write_text("\n".join(rows) + "\n")
    doc["corners_vnl"] = "corners.vnl"
    inline = read_board_session(f)
    f2 = folder / "vnl_session.yaml"
    f2.write_text(yaml.safe_dump(doc))
    from_vnl = read_board_session(f2)
    for a, b in zip(inline.observations, from_vnl.observations, strict=True):
        np.testing.assert_allclose(a.normal_cam, b.normal_cam, atol=1e-9)
        assert a.distance_m == pytest.approx(b.distance_m, abs=1e-9)
    doc["captures"][2]["image"] = "images/other.png"
    f2.write_text(yaml.safe_dump(doc))
    with pytest.raises(
        InputError, match=r"captures\[2\]\.image: got 'images/other.png'; expected an image listed"
    ):
        read_board_session(f2)
