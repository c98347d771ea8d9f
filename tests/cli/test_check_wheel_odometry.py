"""`rigcal check --sequence` on a drive whose wheel odometry (odometry.tum) is broken: the
check starts its laser odometry from the wheels, so a broken file is one line naming the
file, the line and the value (exit 3), and `--wheel-odometry ignore` checks the drive
without reading it, as `rigcal localize` does."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from rigcal.batch.manifest import read_manifest
from rigcal.cli.main import main
from rigcal.errors import InputError
from room_scans import room_drive


@pytest.fixture
def drive(tmp_path) -> Path:
    """Four seconds of a room at 0.5 m/s with its wheel odometry; the rig beside it."""
    seq = room_drive(tmp_path, odometry=True)
    lines = (seq / "odometry.tum").read_text().splitlines(keepends=True)
    lines[5] = "0.2 0.1 0.0 0.0 0.0 0.0 0.0 x\n"  # one value a hand edit spoiled
    (seq / "odometry.tum").write_text("".join(lines))
    return seq


def test_a_broken_odometry_file_names_file_line_and_value_and_the_way_around(drive, fails):
    rig = drive.parent / "rig.yaml"
    line = fails(["check", rig, "--sequence", drive, "--no-log"], 3)
    assert line == (
        f"Error: {drive / 'odometry.tum'}: line 6: got '0.2 0.1 0.0 0.0 0.0 0.0 0.0 x'; expected 8 numbers "
        "(--wheel-odometry ignore runs without it)"
    )


def test_ignored_wheel_odometry_is_not_read(drive, capsys):
    rig = drive.parent / "rig.yaml"
    code = main(["check", str(rig), "--sequence", str(drive), "--no-log", "--wheel-odometry", "ignore"])
    assert code in (0, 1, 6)  # a verdict (this short drive: cannot tell), not an error
    assert "Error" not in capsys.readouterr().err


def test_wheel_odometry_without_a_drive_is_a_usage_error(drive, capsys):
    rig = drive.parent / "rig.yaml"
    assert main(["check", str(rig), "--picks", str(rig), "--wheel-odometry", "ignore"]) == 2
    assert "--wheel-odometry goes with --sequence" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("item", "match"),
    [
        ({"sequence": "seq", "wheel_odometry": "off"}, r"items\[0\].wheel_odometry: got 'off'; expected one"),
        ({"picks": "p.yaml", "wheel_odometry": "ignore"}, r"wheel_odometry: got 'ignore'; expected an item"),
    ],
)
def test_a_fleet_files_wheel_odometry_is_checked_before_any_item_runs(tmp_path, item, match):
    manifest = tmp_path / "fleet.yaml"
    doc = {"schema_version": 1, "command": "check", "items": [{"rig": "rig.yaml", **item}]}
    manifest.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=match):
        read_manifest(manifest)


def test_a_fleet_item_ignoring_the_wheels_runs_as_the_command(drive, tmp_path):
    manifest = tmp_path / "fleet.yaml"
    item = {"rig": "rig.yaml", "sequence": "seq", "wheel_odometry": "ignore", "no_log": True}
    manifest.write_text(yaml.safe_dump({"schema_version": 1, "command": "check", "items": [item]}))
    (only,) = read_manifest(manifest)
    assert only.argv(tmp_path / "out")[-4:-1] == ["--wheel-odometry", "ignore", "--no-log"]
