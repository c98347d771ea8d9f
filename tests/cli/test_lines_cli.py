"""`rigcal lines`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_scan_is_bad_input(fails, tmp_path):
    assert "none.yaml" in fails(["lines", tmp_path / "none.yaml"], 3)


def test_a_bad_range_noise_is_a_usage_error(fails, tmp_path):
    assert "--range-sigma-m" in fails(["lines", tmp_path / "s.yaml", "--range-sigma-m", "nan"], 2)


def test_an_unknown_option_is_a_usage_error(fails, tmp_path):
    fails(["lines", tmp_path / "s.yaml", "--bogus"], 2)
