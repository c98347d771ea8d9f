"""`rigcal intrinsics`: its error paths and exit codes."""

from __future__ import annotations

import pytest


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


@pytest.mark.parametrize(
    ("option", "value"),
    [("--board", "9"), ("--board", "1x6"), ("--charuco", "8x"), ("--imagersize", "640x1")],
)
def test_a_bad_size_is_a_usage_error_naming_its_option(fails, tmp_path, option, value):
    board = [] if option in ("--board", "--charuco") else ["--board", "9x6"]
    argv = ["intrinsics", "--corners", tmp_path / "c.vnl", *board, option, value]
    argv += ["--square-m", "0.03", "-o", tmp_path / "c.cameramodel"]
    line = fails(argv, 2)
    assert option in line
    assert f"'{value}': expected WxH with whole numbers from 2 to 99999" in line
