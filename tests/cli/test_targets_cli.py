"""`rigcal targets new|print`: their error paths and exit codes."""

from __future__ import annotations

from rigcal.cli.main import main


def test_an_existing_targets_file_is_kept_without_force(fails, tmp_path):
    out = tmp_path / "targets.yaml"
    out.write_text("mine\n")
    fails(["targets", "new", "-o", out], 5)
    assert out.read_text() == "mine\n"
    assert main(["targets", "new", "-o", str(out), "--force"]) == 0
    assert out.read_text() != "mine\n"


def test_the_output_is_required(fails):
    assert "-o" in fails(["targets", "new"], 2)


def test_print_of_a_missing_targets_file_is_bad_input(fails, tmp_path):
    fails(["targets", "print", tmp_path / "none.yaml", "-o", tmp_path / "pages"], 3)
