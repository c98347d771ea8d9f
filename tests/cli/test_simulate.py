"""`rigcal simulate box-session` through the command line."""

from __future__ import annotations

import pytest
import yaml
from click.testing import CliRunner

from rigcal.calib.box.picks import read_picks
from rigcal.calib.truth import read_truth
from rigcal.cli.main import cli, main
from rigcal.sim.box_session import default_T_cam_laser


def test_writes_a_session(tmp_path):
    out = tmp_path / "sess"
    res = CliRunner().invoke(
        cli,
        ["simulate", "box-session", "-o", str(out), "--captures", "4", "--seed", "2", "--no-images"],
    )
    assert res.exit_code == 0, res.output
    assert res.stdout == ""  # results are files; the summary goes to stderr
    assert "4 captures" in res.stderr
    assert "rigcal solve" in res.stderr
    session = read_picks(out / "picks.yaml")
    assert [o.name for o in session.observations] == ["cap00", "cap01", "cap02", "cap03"]
    assert read_truth(out / "truth.yaml") == pytest.approx(default_T_cam_laser(), abs=1e-11)
    assert "--seed 2 --captures 4" in (out / "picks.yaml").read_text()


def test_noise_and_wrong_picks_reach_the_truth_file(tmp_path):
    out = tmp_path / "sess"
    args = ["simulate", "box-session", "-o", str(out), "--captures", "4", "--no-images"]
    args += ["--pick-sigma-px", "2.5", "--range-sigma-m", "0.02", "--wrong-picks", "0.5"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    gen = yaml.safe_load((out / "truth.yaml").read_text())["generator"]
    assert gen["pick_sigma_px"] == 2.5
    assert gen["range_sigma_m"] == 0.02
    assert len(gen["wrong_picks"]) == 2
    assert "wrong picks in" in res.stderr


@pytest.mark.parametrize(
    "bad",
    [
        ["--captures", "0"],
        ["--captures", "many"],
        ["--wrong-picks", "1.5"],
        ["--pick-sigma-px", "-1"],
        ["--range-sigma-m", "-0.01"],
        ["--seed", "-3"],
    ],
)
def test_bad_option_values_are_usage_errors(tmp_path, bad):
    res = CliRunner().invoke(cli, ["simulate", "box-session", "-o", str(tmp_path / "s"), *bad])
    assert res.exit_code == 2
    assert not (tmp_path / "s").exists()


def test_output_is_required():
    assert CliRunner().invoke(cli, ["simulate", "box-session"]).exit_code == 2


def test_existing_folder_needs_force(tmp_path, capsys):
    out = tmp_path / "sess"
    out.mkdir()
    (out / "mine.txt").write_text("keep")
    args = ["simulate", "box-session", "-o", str(out), "--captures", "3", "--no-images"]
    assert main(args) == 5
    err = capsys.readouterr().err
    assert err.startswith("Error: ")
    assert "exists" in err
    assert "--force" in err
    assert (out / "mine.txt").read_text() == "keep"
    assert main([*args, "--force"]) == 5
    assert "not written by rigcal" in capsys.readouterr().err
    (out / "mine.txt").unlink()
    assert main([*args, "--force"]) == 0
    assert main([*args, "--force"]) == 0
    assert (out / "picks.yaml").is_file()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sess"]


def test_help_has_examples():
    for args in (["simulate", "--help"], ["simulate", "box-session", "--help"]):
        res = CliRunner().invoke(cli, args)
        assert res.exit_code == 0
        assert "Examples:" in res.output
    res = CliRunner().invoke(cli, ["simulate", "box-session", "--help"])
    assert "rigcal simulate box-session -o examples/box-session --seed 1" in res.output


@pytest.mark.parametrize(
    ("command", "session_file", "extra"),
    [
        ("box-session", "picks.yaml", ["--captures", "5", "--no-images"]),
        ("board-session", "board_session.yaml", ["--captures", "6"]),
    ],
)
def test_noise_realistic(tmp_path, command, session_file, extra):
    out = tmp_path / "s"
    res = CliRunner().invoke(cli, ["simulate", command, "-o", str(out), "--noise", "realistic", *extra])
    assert res.exit_code == 0, res.output
    doc = yaml.safe_load((out / session_file).read_text())
    assert "range_sigma_m" not in doc["laser"]  # a user does not know the true noise
    assert yaml.safe_load((out / "truth.yaml").read_text())["generator"]["noise"]["model"] == "realistic"
    bad = CliRunner().invoke(cli, ["simulate", command, "-o", str(tmp_path / "t"), "--noise", "rough"])
    assert bad.exit_code == 2


@pytest.mark.parametrize(
    ("command", "entry"),
    [
        (["box-session", "--captures", "3", "--no-images"], "picks.yaml"),
        (["board-session", "--captures", "3"], "board_session.yaml"),
        (["world", "--world", "cubicle-loop", "--no-images", "--duration-s", "2"], "sequence.yaml"),
    ],
)
def test_json_names_what_was_written_and_the_true_transform(command, entry, tmp_path, capsys):
    import json

    import numpy as np

    out = tmp_path / "s"
    assert main(["simulate", *command, "-o", str(out), "--seed", "3", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["entry"] == str(out / entry)
    assert (out / entry).is_file()
    T = np.array(doc["T_cam_laser_true"])
    np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    if command[0] == "world":
        assert doc["x_real_time"] == pytest.approx(doc["duration_s"] / doc["wall_s"], rel=1e-9)


def test_calib_session_is_kept_as_a_hidden_alias(tmp_path):
    out = tmp_path / "s"
    args = ["simulate", "calib-session", "-o", str(out), "--captures", "3", "--no-images"]
    res = CliRunner().invoke(cli, args)
    assert res.exit_code == 0, res.output
    assert (out / "picks.yaml").is_file()
    listing = CliRunner().invoke(cli, ["simulate", "--help"]).output
    assert "box-session" in listing
    assert "calib-session" not in listing
