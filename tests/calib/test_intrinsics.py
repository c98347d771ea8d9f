"""Camera intrinsics from chessboard images: real OpenCV sample images against OpenCV's published result."""

from __future__ import annotations

from pathlib import Path

import cv2
import mvtbdata
import numpy as np
import pytest

from rigcal.calib.intrinsics import (
    Board,
    detect_corners,
    read_corners_vnl,
    solve_intrinsics,
    write_corners_vnl,
)
from rigcal.cli.main import main
from rigcal.errors import CalibrationError, InputError

DATA = Path(mvtbdata.__file__).parent
IMAGES = sorted((DATA / "images" / "calibration").glob("left*.jpg"))
BOARD = Board(9, 6, 0.025)


@pytest.fixture(scope="module")
def detections():
    return detect_corners(IMAGES, BOARD)


@pytest.fixture(scope="module")
def published():
    """OpenCV's own calibration of these images (shipped beside them)."""
    fs = cv2.FileStorage(str(DATA / "data" / "left_intrinsics.yml"), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    rms = fs.getNode("avg_reprojection_error").real()
    fs.release()
    return K, rms


def test_the_sample_set_is_there():
    assert len(IMAGES) == 14


def test_board_found_in_every_image_as_a_regular_grid(detections):
    assert len(detections.paths) == 14
    assert detections.missing == ()
    assert detections.imagersize == (640, 480)
    c = detections.corners
    assert c.shape == (14, 6, 9, 3)
    # Rows hold 9 corners and columns 6 (not transposed): neighbours along a row and along a
    # column are about one square apart, never a whole row apart.
    along_rows = np.linalg.norm(np.diff(c[..., :2], axis=2), axis=-1)
    along_cols = np.linalg.norm(np.diff(c[..., :2], axis=1), axis=-1)
    for img in range(14):
        step = np.median(along_rows[img])
        assert 0.5 < np.median(along_cols[img]) / step < 2.0
        assert along_rows[img].max() < 2.5 * step


def test_solve_matches_opencvs_published_intrinsics(detections, published):
    K, published_rms = published
    res = solve_intrinsics(detections, BOARD, "LENSMODEL_OPENCV5")
    lens, intr = res.model.intrinsics()
    assert lens == "LENSMODEL_OPENCV5"
    # OpenCV's solve fixed fx = fy and used 13 of the 14 images: agree to 1 % in focal length
    # and 3 px in the principal point.
    assert intr[0] == pytest.approx(K[0, 0], rel=0.01)
    assert intr[1] == pytest.approx(K[1, 1], rel=0.01)
    assert abs(intr[2] - K[0, 2]) < 3.0
    assert abs(intr[3] - K[1, 2]) < 3.0
    # The sub-pixel detector fits at least as well as OpenCV's published 0.39 px.
    assert res.rms_px < published_rms
    assert res.worst_px < 2.0
    assert res.images_used == 14
    assert set(res.per_image_rms_px) == {p.name for p in IMAGES}
    # mrcal's uncertainty is smallest in the middle, where the boards were.
    assert res.uncertainty_px["centre"] < 0.5
    assert res.uncertainty_px["centre"] < res.uncertainty_px["top_left_corner"]


def test_corners_file_round_trip_gives_the_same_solve(detections, tmp_path):
    path = tmp_path / "corners.vnl"
    path.write_text(write_corners_vnl(detections))
    again = read_corners_vnl(path, BOARD, (640, 480))
    np.testing.assert_allclose(again.corners[..., :2], detections.corners[..., :2], atol=1e-4)
    np.testing.assert_array_equal(again.corners[..., 2], detections.corners[..., 2])
    a = solve_intrinsics(detections, BOARD, "LENSMODEL_OPENCV5").model.intrinsics()[1]
    b = solve_intrinsics(again, BOARD, "LENSMODEL_OPENCV5").model.intrinsics()[1]
    # The file keeps corners to 1e-4 px, which moves the solve by far less than its uncertainty.
    np.testing.assert_allclose(a, b, rtol=1e-3)


def test_solving_leaves_the_detections_unmarked(detections):
    before = detections.corners.copy()
    solve_intrinsics(detections, BOARD, "LENSMODEL_OPENCV5")
    np.testing.assert_array_equal(detections.corners, before)


def test_board_not_found_is_listed_not_fatal(tmp_path):
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 200, np.uint8))
    det = detect_corners([*IMAGES[:3], blank], BOARD)
    assert det.missing == (str(blank),)
    assert len(det.paths) == 3


def test_too_few_boards_names_the_images_without_one(tmp_path):
    blank = tmp_path / "blank.png"
    cv2.imwrite(str(blank), np.full((480, 640), 200, np.uint8))
    det = detect_corners([IMAGES[0], blank], BOARD)
    with pytest.raises(CalibrationError, match=r"found in 1 image.*at least 3.*not found in: blank\.png"):
        solve_intrinsics(det, BOARD)


def test_images_of_different_sizes_are_refused(tmp_path):
    small = tmp_path / "small.png"
    cv2.imwrite(str(small), np.full((240, 320), 200, np.uint8))
    with pytest.raises(InputError, match=r"small\.png: image is 320x240; expected 640x480"):
        detect_corners([IMAGES[0], small], BOARD)


def test_missing_image_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"nope\.png: image not found"):
        detect_corners([tmp_path / "nope.png"], BOARD)


def test_unknown_lens_model_is_refused(detections):
    with pytest.raises(InputError, match=r"lensmodel: got 'LENSMODEL_NOPE'"):
        solve_intrinsics(detections, BOARD, "LENSMODEL_NOPE")


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("a.png 1 2 0 9\n", r"line 2: got 5 fields"),
        ("a.png x 2 0\n", r"line 2: got 'a.png x 2 0'"),
        ("a.png 1 2 0\n", r"a.png: got 1 corners; expected 54"),
    ],
)
def test_bad_corners_files(tmp_path, text, match):
    path = tmp_path / "c.vnl"
    path.write_text("# filename x y level\n" + text)
    with pytest.raises(InputError, match=match):
        read_corners_vnl(path, BOARD, (640, 480))


def test_corners_file_marks_missing_boards_and_ignored_corners(tmp_path):
    rows = [f"a.png {i}.0 {j}.0 {'-' if (i, j) == (0, 0) else 1}" for j in range(6) for i in range(9)]
    path = tmp_path / "c.vnl"
    path.write_text("\n".join(["# filename x y level", *rows, "b.png - - -"]) + "\n")
    det = read_corners_vnl(path, BOARD, (640, 480))
    assert det.paths == ("a.png",)
    assert det.missing == ("b.png",)
    assert det.corners[0, 0, 0, 2] == -1.0
    assert det.corners[0, 0, 1, 2] == 0.5


def test_cli_writes_a_cameramodel_that_rigcal_reads(tmp_path, capsys):
    from rigcal.camera import read_camera

    out = tmp_path / "cam.cameramodel"
    corners = tmp_path / "corners.vnl"
    argv = ["intrinsics", *map(str, IMAGES[:8]), "--board", "9x6", "--square-m", "0.025"]
    code = main([*argv, "--lensmodel", "LENSMODEL_OPENCV5", "-o", str(out), "--save-corners", str(corners)])
    assert code == 0
    printed = capsys.readouterr().out
    assert "LENSMODEL_OPENCV5: fx" in printed
    assert "projection uncertainty" in printed
    cam = read_camera(out)
    assert cam.lensmodel == "LENSMODEL_OPENCV5"
    assert (cam.width_px, cam.height_px) == (640, 480)
    assert corners.read_text().startswith("# filename x y level")
    # Refuses to overwrite; the corners file alone is then solved again from --corners.
    assert main([*argv, "-o", str(out)]) == 5
    capsys.readouterr()
    again = tmp_path / "again.cameramodel"
    argv2 = ["intrinsics", "--corners", str(corners), "--imagersize", "640x480", "--board", "9x6"]
    assert main([*argv2, "--square-m", "0.025", "-o", str(again), "--json"]) == 0
    assert '"images_used": 8' in capsys.readouterr().out


@pytest.mark.parametrize(
    ("args", "code"),
    [
        (["--board", "9by6", "--square-m", "0.025"], 2),
        (["--board", "9x6", "--square-m", "0"], 2),
        (["--board", "9x6", "--square-m", "0.025", "--corners", "nope.vnl", "--imagersize", "640x480"], 3),
        (["--board", "9x6", "--square-m", "0.025"], 2),  # no images and no --corners
    ],
)
def test_cli_usage_and_input_errors(tmp_path, capsys, args, code):
    assert main(["intrinsics", *args, "-o", str(tmp_path / "c.cameramodel")]) == code
    assert not (tmp_path / "c.cameramodel").exists()


# --- ChArUco, on images rendered through a known camera ------------------------------------
TRUE_CAMERA = ((600.0, 605.0, 330.0, 235.0), (-0.2, 0.08, 0.001, -0.0005, 0.0))


def charuco_board():
    from rigcal.calib.intrinsics import CharucoBoard

    return CharucoBoard(8, 6, 0.04, 0.03)


@pytest.fixture(scope="module")
def charuco_images(tmp_path_factory):
    """12 views of a ChArUco board (0.32 x 0.24 m) at 0.45-0.8 m, tilted up to ~35 deg,
    rendered through TRUE_CAMERA with 2 grey levels of noise."""
    from rigcal.camera import Camera
    from rigcal.geometry import make_T, rotvec_to_R
    from rigcal.sim.boards import render_board

    (fx, fy, cx, cy), dist = TRUE_CAMERA
    cam = Camera.from_opencv([[fx, 0, cx], [0, fy, cy], [0, 0, 1]], dist, 640, 480)
    texture = charuco_board().opencv().generateImage((1600, 1200), marginSize=0)
    rng = np.random.default_rng(0)
    folder = tmp_path_factory.mktemp("charuco")
    paths = []
    for k in range(12):
        rv = rng.uniform(-0.6, 0.6, 3)
        rv[2] = rng.uniform(-0.3, 0.3)
        R = rotvec_to_R(rv)
        centre = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), rng.uniform(0.45, 0.8)])
        img = render_board(cam, texture, (0.32, 0.24), make_T(R, centre - R @ np.array([0.16, 0.12, 0.0])))
        img = np.clip(img + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
        paths.append(folder / f"view{k:02d}.png")
        cv2.imwrite(str(paths[-1]), img)
    return cam, paths


def test_charuco_solve_projects_like_the_true_camera(charuco_images):
    import mrcal

    from rigcal.calib.intrinsics import detect_charuco

    cam, paths = charuco_images
    board = charuco_board()
    det = detect_charuco(paths, board)
    assert len(det.paths) == 12
    assert ((det.corners[..., 2] > 0).sum(axis=(1, 2)) >= 25).all()
    res = solve_intrinsics(det, board.grid, "LENSMODEL_OPENCV5")
    assert res.rms_px < 0.5
    # Intrinsics trade off against each other (cx against the tangential terms); what must
    # agree is where the camera projects. mrcal's projection difference, with the implied
    # rotation between the two camera frames fitted, over the middle of the image the
    # boards covered.
    truth = mrcal.cameramodel(intrinsics=(cam.lensmodel, np.array(cam.intrinsics)), imagersize=(640, 480))
    diff = mrcal.projection_diff((truth, res.model), gridn_width=16, use_uncertainties=False, distance=0.6)[0]
    assert np.median(diff[3:-3, 4:-4]) < 0.1
    assert diff[3:-3, 4:-4].max() < 0.3
    assert res.model.intrinsics()[1][0] == pytest.approx(600.0, rel=0.005)


def test_charuco_cli_and_bad_options(charuco_images, tmp_path, capsys):
    _, paths = charuco_images
    out = tmp_path / "c.cameramodel"
    base = ["intrinsics", *map(str, paths), "--square-m", "0.04", "-o", str(out)]
    assert main([*base, "--charuco", "8x6", "--marker-m", "0.03", "--lensmodel", "LENSMODEL_OPENCV5"]) == 0
    assert "images used 12" in capsys.readouterr().out
    for bad in (
        ["--charuco", "8x6"],  # no --marker-m
        ["--charuco", "8x6", "--board", "9x6", "--marker-m", "0.03"],  # both boards
        ["--charuco", "8x6", "--marker-m", "0.05"],  # marker larger than a square
    ):
        assert main([*base, "--force", *bad]) == 2
    assert (
        main([*base, "--force", "--charuco", "8x6", "--marker-m", "0.03", "--dictionary", "DICT_NOPE"]) == 3
    )
    assert "dictionary" in capsys.readouterr().err


# --- honesty: both RMS figures, degenerate sets, another board size -----------------------------
def test_rms_over_all_corners_and_over_inliers(detections):
    res = solve_intrinsics(detections, BOARD, "LENSMODEL_OPENCV5")
    assert res.rms_all_px >= res.rms_px
    assert res.worst_all_px >= res.worst_px
    if res.outliers == 0:
        assert res.rms_all_px == pytest.approx(res.rms_px, abs=1e-4)
    # A well-spread set of 14 real images raises no degeneracy warning.
    assert res.warnings == ()


def test_repeated_views_and_one_tilt_are_warned(detections):
    from rigcal.calib.intrinsics import Detections

    # The same three images four times over: one set of views, few tilts.
    idx = [0, 1, 2] * 4
    det = Detections(
        tuple(f"copy{i}_{detections.paths[j].split('/')[-1]}" for i, j in enumerate(idx)),
        detections.corners[idx],
        (),
        detections.imagersize,
    )
    res = solve_intrinsics(det, BOARD, "LENSMODEL_OPENCV5")
    assert any("nearly the same view" in w for w in res.warnings)


def test_other_board_size_is_suggested(tmp_path, capsys):
    from rigcal.calib.intrinsics import other_board_sizes

    wrong = Board(8, 6, 0.025)
    found = other_board_sizes(IMAGES[:1], wrong)
    assert found == {IMAGES[0].name: (9, 6)}
    argv = ["intrinsics", *map(str, IMAGES[:2]), "--board", "8x6", "--square-m", "0.025"]
    assert main([*argv, "-o", str(tmp_path / "c.cameramodel")]) == 4
    err = capsys.readouterr().err
    assert "a 9x6 chessboard is detected in left01.jpg" in err
    assert not (tmp_path / "c.cameramodel").exists()
