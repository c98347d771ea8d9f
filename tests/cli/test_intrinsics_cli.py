"""`rigcal intrinsics`: its error paths and exit codes."""

from __future__ import annotations


def test_no_board_is_a_usage_error(fails, tmp_path):
    fails(["intrinsics", tmp_path / "a.png", "--square-m", "0.03", "-o", tmp_path / "c.cameramodel"], 2)


def test_a_bad_square_size_is_a_usage_error(fails, tmp_path):
    argv = [
        "intrinsics",
        tmp_path / "a.png",
        "--board",
        "9x6",
        "--square-m",
        "0",
        "-o",
        tmp_path / "c.cameramodel",
    ]
    assert "--square-m" in fails(argv, 2)


def test_missing_images_are_bad_input(fails, tmp_path):
    argv = [
        "intrinsics",
        tmp_path / "a.png",
        "--board",
        "9x6",
        "--square-m",
        "0.03",
        "-o",
        tmp_path / "c.cameramodel",
    ]
    fails(argv, 3)
