"""`rigcal matches`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_sequence_is_bad_input(fails, tmp_path):
    fails(["matches", tmp_path / "seq", "--image", "0", "-o", tmp_path / "m.png"], 3)


def test_a_picture_of_an_unknown_kind_is_refused(fails, tmp_path):
    fails(["matches", tmp_path / "seq", "--image", "0", "-o", tmp_path / "m.gif"], 3)


def test_a_negative_image_is_a_usage_error(fails, tmp_path):
    assert "--image" in fails(["matches", tmp_path / "seq", "--image", "-1", "-o", tmp_path / "m.png"], 2)
