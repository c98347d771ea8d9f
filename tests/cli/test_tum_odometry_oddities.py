"""TUM odometry files as other tools write them: quaternions off unit length (too few
decimals, or not normalised at all), 2D columns, w first. One line naming the file, the
line, the value and what was expected (exit 3), nothing written."""

from __future__ import annotations

import pytest

from rigcal.cli.main import main

LASER = "".join(f"{1.0 + 0.1 * k:.1f} -0.5 0.25 0.5 3 5 2.0 2.0 2.0 2.0 2.0\n" for k in range(10))

CASES = [
    (
        "0.9 0 0 0 0 0 0 2\n2.5 1 0 0 0 0 0 2\n",
        "odom.tum: line 1: qx qy qz qw: got [0.0, 0.0, 0.0, 2.0] (norm 2); expected a unit quaternion "
        "(norm within 0.001 of 1, as printed to 3 decimals)",
    ),
    (
        "0.9 0 0 0 0 0 0.38 0.92\n2.5 1 0 0 0 0 0.38 0.92\n",
        "(norm 0.995389) (printed with too few decimals?); expected a unit quaternion",
    ),
    ("0.9 0 0 0 0 0 0 0\n", "line 1: qx qy qz qw: got [0.0, 0.0, 0.0, 0.0] (norm 0)"),
    (
        "0.9 0 0 0\n2.5 1 0 0.1\n",
        "odom.tum: line 1: got 4 fields; expected 8 (timestamp tx ty tz qx qy qz qw): a 2D 'timestamp x y "
        "yaw' file? write each pose as 'timestamp x y 0 0 0 sin(yaw/2) cos(yaw/2)'",
    ),
    ("0.9 0 0\n2.5 1 0\n", "line 1: got 3 fields; expected 8 (timestamp tx ty tz qx qy qz qw): a 2D"),
    (
        "0.9 0 0 0 1 0 0 0\n2.5 1 0 0 1 0 0 0\n",
        "odom.tum: pose 0: got 'tilted 180.0 deg'; expected planar odometry (z axis up; TUM's "
        "quaternions are qx qy qz qw, w last)",
    ),
]


@pytest.mark.parametrize(("text", "want"), CASES)
def test_tum_odometry_of_other_tools_is_one_line(tmp_path, fails, text, want):
    (tmp_path / "laser.txt").write_text(LASER)
    (tmp_path / "odom.tum").write_text(text)
    argv = ["import-laser", tmp_path / "laser.txt", "--odometry", tmp_path / "odom.tum", "-o", tmp_path / "s"]
    assert want in fails(argv, 3)


def test_a_quaternion_printed_to_three_decimals_is_read(tmp_path):
    (tmp_path / "laser.txt").write_text(LASER)
    (tmp_path / "odom.tum").write_text("0.9 0 0 0 0 0 0.383 0.924\n2.5 1 0 0 0 0 0.383 0.924\n")
    argv = ["import-laser", str(tmp_path / "laser.txt"), "--odometry", str(tmp_path / "odom.tum")]
    assert main([*argv, "-o", str(tmp_path / "s")]) == 0
