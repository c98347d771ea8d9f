"""`rigcal project`: its error paths and exit codes."""

from __future__ import annotations


def test_missing_inputs_are_bad_input(fails, tmp_path):
    line = fails(
        ["project", tmp_path / "rig.yaml", tmp_path / "s.yaml", tmp_path / "i.png", "-o", tmp_path / "o.png"],
        3,
    )
    assert "rig.yaml" in line


def test_the_output_is_required(fails, tmp_path):
    assert "-o" in fails(["project", tmp_path / "rig.yaml", tmp_path / "s.yaml", tmp_path / "i.png"], 2)
