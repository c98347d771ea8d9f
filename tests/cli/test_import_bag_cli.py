"""`rigcal import-bag`: its error paths and exit codes."""

from __future__ import annotations


def test_a_missing_bag_is_bad_input(fails, tmp_path):
    argv = ["import-bag", tmp_path / "none.bag", "--scan-topic", "/scan", "--image-topic", "/img"]
    assert "none.bag" in fails([*argv, "-o", tmp_path / "seq"], 3)


def test_without_topics_a_missing_bag_is_still_named(fails, tmp_path):
    # --scan-topic and --image-topic default to the bag's only topics of their types.
    assert "none.bag: bag not found" in fails(
        ["import-bag", tmp_path / "none.bag", "-o", tmp_path / "seq"], 3
    )
