"""`rigcal export`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_rig_is_bad_input(fails, tmp_path):
    assert "rig.yaml" in fails(["export", tmp_path / "rig.yaml", "--format", "ros"], 3)


def test_an_unknown_format_is_a_usage_error(fails, tmp_path):
    assert "--format" in fails(["export", tmp_path / "rig.yaml", "--format", "vrml"], 2)
