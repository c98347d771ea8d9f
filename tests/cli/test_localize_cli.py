"""`rigcal localize`: its error paths and exit codes (the runs: tests/localize)."""

from __future__ import annotations


def test_a_missing_sequence_is_bad_input(fails, tmp_path):
    fails(["localize", tmp_path / "seq", "-o", tmp_path / "out"], 3)


def test_an_unknown_method_is_a_usage_error(fails, tmp_path):
    assert "--method" in fails(
        ["localize", tmp_path / "seq", "--method", "icp,slam", "-o", tmp_path / "out"], 2
    )


def test_an_unknown_setting_is_a_usage_error(fails, tmp_path):
    assert "--iasm" in fails(["localize", tmp_path / "seq", "--iasm", "nope=1", "-o", tmp_path / "out"], 2)
