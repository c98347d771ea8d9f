"""`rigcal capture`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_recording_is_bad_input(fails, tmp_path):
    fails(["capture", tmp_path / "none.bag", "-o", tmp_path / "session"], 3)


def test_a_bad_threshold_is_a_usage_error(fails, tmp_path):
    argv = ["capture", tmp_path / "none.bag", "-o", tmp_path / "session", "--scan-threshold-m", "-1"]
    assert "--scan-threshold-m" in fails(argv, 2)
