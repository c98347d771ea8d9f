"""`rigcal import-carmen`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_log_is_bad_input(fails, tmp_path):
    assert "none.log" in fails(["import-carmen", tmp_path / "none.log", "-o", tmp_path / "seq"], 3)


def test_a_bad_range_is_a_usage_error(fails, tmp_path):
    argv = ["import-carmen", tmp_path / "a.log", "-o", tmp_path / "seq", "--flaser-range-max-m", "0"]
    assert "--flaser-range-max-m" in fails(argv, 2)


def test_a_bad_laser_offset_is_bad_input(fails, tmp_path):
    (tmp_path / "a.log").write_text("")
    assert "--laser-offset" in fails(
        ["import-carmen", tmp_path / "a.log", "-o", tmp_path / "seq", "--laser-offset", "1,2"], 3
    )
