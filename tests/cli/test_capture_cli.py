"""`rigcal capture`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_recording_is_bad_input(fails, tmp_path):
    fails(["capture", tmp_path / "none.bag", "-o", tmp_path / "session"], 3)


def test_a_bad_threshold_is_a_usage_error(fails, tmp_path):
    argv = ["capture", tmp_path / "none.bag", "-o", tmp_path / "session", "--scan-threshold-m", "-1"]
    assert "--scan-threshold-m" in fails(argv, 2)


def test_a_bad_board_targets_file_stops_before_the_recording_is_read(fails, tmp_path):
    bad = tmp_path / "board.yaml"
    bad.write_text("schema_version: 2\nkind: board\nboard: {corners_x: 8, corners_y: 1, spacing_m: 0.06}\n")
    argv = ["capture", tmp_path / "none.bag", "-o", tmp_path / "session", "--target", bad]
    assert fails(argv, 3) == f"Error: {bad}: board.corners_y: got 1; expected an integer in [2, 1000]"
    bad.write_text("schema_version: 1\nkind: board\nboard: {corners_x: 8, corners_y: 6, spacing_m: 0.06}\n")
    assert fails(argv, 3).startswith(f"Error: {bad}: schema_version: got 1; expected 2 (kind: board needs")
    bad.write_text(
        "schema_version: 2\nkind: board\nboard: {corners_x: 8, corners_y: 6, spacing_m: 0.06}\nx: 1\n"
    )
    assert fails(argv, 3).startswith(f"Error: {bad}: x: got 1; expected no such key")


def test_max_scans_below_one_is_a_usage_error(fails, tmp_path):
    argv = ["capture", tmp_path / "none.bag", "-o", tmp_path / "session", "--max-scans", "0"]
    assert "--max-scans" in fails(argv, 2)
