"""`rigcal import-bag`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_bag_is_bad_input(fails, tmp_path):
    argv = ["import-bag", tmp_path / "none.bag", "--scan-topic", "/scan", "--image-topic", "/img"]
    assert "none.bag" in fails([*argv, "-o", tmp_path / "seq"], 3)


def test_the_scan_topic_is_required(fails, tmp_path):
    assert "--scan-topic" in fails(["import-bag", tmp_path / "none.bag", "-o", tmp_path / "seq"], 2)
