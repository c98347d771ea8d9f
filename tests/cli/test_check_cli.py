"""`rigcal check` through the command line: verdict as exit code, summary, JSON, log, plot."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.calib.box.session import calibrate
from rigcal.cli.main import main
from rigcal.drift.log import read_log
from rigcal.rigfile import write_rig
from rigcal.sim.box_session import (
    SessionSpec,
    default_T_cam_laser,
    generate_session,
    moved_T_cam_laser,
    write_session,
)
from rigcal.viz.charts import DRIFTED, OK


def simulated(folder: Path, n_captures: int, seed: int, rotation_deg: float = 0.0) -> Path:
    """A written session (placeholder images) of the true rig, its camera turned by rotation_deg;
    returns its picking file."""
    T = moved_T_cam_laser(default_T_cam_laser(), rotation_deg, 0.0, seed=seed)
    spec = SessionSpec(n_captures=n_captures, seed=seed)
    write_session(generate_session(spec, T_cam_laser=T), folder, render_images=False)
    return folder / "picks.yaml"


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> dict[str, Path]:
    """The stored rig file (solved from 20 captures) and new sessions' picking files."""
    base = tmp_path_factory.mktemp("check")
    rig = base / "stored" / "rig.yaml"
    rig.parent.mkdir()
    write_rig(rig, calibrate(simulated(base / "calib", 20, seed=1)).rig)
    return {
        "rig": rig,
        "same": simulated(base / "same", 6, seed=11),
        "turned": simulated(base / "turned", 6, seed=12, rotation_deg=0.5),
        "far": simulated(base / "far", 3, seed=13, rotation_deg=1.5),
    }


@pytest.fixture
def rig(data, tmp_path) -> Path:
    """A fresh copy of the stored rig, so each test starts without a drift log."""
    return Path(shutil.copy(data["rig"], tmp_path / "rig.yaml"))


def run(capsys, *args: str | Path) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


def test_unmoved_rig_exits_0_with_a_summary(rig, data, capsys):
    code, out, err = run(capsys, "check", rig, "--picks", data["same"])
    assert code == 0
    lines = out.splitlines()
    assert lines[0] == "verdict: ok (false-alarm level 0.01)"
    assert lines[1].startswith("residual test: 12/12 box ends, RMS ")
    assert "over 24 dof" in lines[1]
    assert lines[2].startswith("pose test: fresh solve differs by ")
    assert "(6 dof)" in lines[2]
    assert not any(line.startswith("note:") for line in lines)
    assert "appended to" in err


def test_turned_camera_exits_1_with_the_reason(rig, data, capsys):
    code, out, _ = run(capsys, "check", rig, "--picks", data["turned"])
    assert code == 1
    assert out.startswith("verdict: drifted (false-alarm level 0.01)\n")
    assert "note: a fresh solve differs by" in out


def test_level_option_is_recorded(rig, data, capsys):
    code, out, _ = run(capsys, "check", rig, "--picks", data["same"], "--level", "0.05", "--no-log")
    assert code == 0
    assert out.startswith("verdict: ok (false-alarm level 0.05)\n")


def test_min_captures_option_skips_the_pose_test(rig, data, capsys):
    code, out, _ = run(capsys, "check", rig, "--picks", data["same"], "--min-captures", "7", "--no-log")
    assert code == 0
    assert "pose test:" not in out
    assert "only the residual test was run" in out


def test_json_output_parses_and_has_the_verdict(rig, data, capsys):
    code, out, _ = run(capsys, "check", rig, "--picks", data["turned"], "--json", "--no-log")
    assert code == 1
    doc = json.loads(out)
    assert doc["verdict"] == "drifted"
    assert doc["level"] == 0.01
    assert doc["input"] == str(data["turned"].resolve())
    assert doc["kind"] == "box"
    assert doc["pose"]["p_value"] < 0.005
    assert doc["residual"]["ends"] == 12


def test_far_moved_rig_gives_strict_json_and_a_summary(rig, data, capsys):
    """Every box end beyond the gate: all are tested (the rig moved, they are not wrong
    picks), the p-value is tiny, and the record stays valid JSON."""

    def refuse(constant: str) -> None:
        raise ValueError(f"not JSON: {constant}")

    code, out, _ = run(capsys, "check", rig, "--picks", data["far"], "--json")
    assert code == 1
    doc = json.loads(out, parse_constant=refuse)
    assert doc["residual"]["used_ends"] == doc["residual"]["ends"] == 6
    assert doc["residual"]["p_value"] < 1e-6
    line = rig.with_name("rig.checks.jsonl").read_text().splitlines()[0]
    assert json.loads(line, parse_constant=refuse)["verdict"] == "drifted"
    code, out, _ = run(capsys, "check", rig, "--picks", data["far"], "--no-log")
    assert code == 1
    assert "6/6 box ends, RMS" in out


def test_each_check_appends_one_line_to_the_log_beside_the_rig(rig, data, capsys):
    log = rig.with_name("rig.checks.jsonl")
    assert run(capsys, "check", rig, "--picks", data["same"])[0] == 0
    assert run(capsys, "check", rig, "--picks", data["turned"])[0] == 1
    lines = log.read_text().splitlines()
    assert len(lines) == 2
    assert [json.loads(line)["verdict"] for line in lines] == ["ok", "drifted"]
    assert [r["verdict"] for r in read_log(log)] == ["ok", "drifted"]
    assert read_log(log)[1]["input"] == str(data["turned"].resolve())


def test_no_log_leaves_the_log_alone(rig, data, capsys):
    log = rig.with_name("rig.checks.jsonl")
    code, _, err = run(capsys, "check", rig, "--picks", data["same"], "--no-log")
    assert code == 0
    assert not log.exists()
    assert "appended" not in err
    log.write_text("untouched\n")
    assert run(capsys, "check", rig, "--picks", data["same"], "--no-log")[0] == 0
    assert log.read_text() == "untouched\n"


def test_log_option_writes_there(rig, data, tmp_path, capsys):
    log = tmp_path / "logs" / "lab.jsonl"
    code, _, err = run(capsys, "check", rig, "--picks", data["same"], "--log", log)
    assert code == 0
    assert str(log) in err
    assert len(read_log(log)) == 1
    assert not rig.with_name("rig.checks.jsonl").exists()


def test_plot_writes_a_png_of_the_history(rig, data, tmp_path, capsys):
    png = tmp_path / "drift.png"
    assert run(capsys, "check", rig, "--picks", data["same"])[0] == 0
    code, _, err = run(capsys, "check", rig, "--picks", data["turned"], "--plot", png)
    assert code == 1
    assert f"drew {png}" in err
    img = cv2.imread(str(png))
    assert img is not None
    assert img.shape == (750, 900, 3)


def test_plot_refuses_an_existing_file_without_force(rig, data, tmp_path, capsys):
    png = tmp_path / "drift.png"
    png.write_bytes(b"keep me")
    log = rig.with_name("rig.checks.jsonl")
    code, out, err = run(capsys, "check", rig, "--picks", data["same"], "--plot", png)
    assert code == 5
    assert "exists" in err
    assert "--force" in err
    assert out == ""
    assert png.read_bytes() == b"keep me"
    assert not log.exists()
    code, _, _ = run(capsys, "check", rig, "--picks", data["same"], "--plot", png, "--force")
    assert code == 0
    assert cv2.imread(str(png)).shape == (750, 900, 3)
    assert len(read_log(log)) == 1


def count_colour(png: Path, colour: str) -> int:
    """Pixels of exactly this "#rrggbb" colour (the inside of the check's markers)."""
    img = cv2.imread(str(png))
    bgr = [int(colour[i : i + 2], 16) for i in (5, 3, 1)]
    return int((img == np.array(bgr, dtype=np.uint8)).all(axis=2).sum())


def test_plot_shows_ok_and_drifted_checks(rig, data, tmp_path, capsys):
    png = tmp_path / "drift.png"
    assert run(capsys, "check", rig, "--picks", data["same"])[0] == 0
    assert run(capsys, "check", rig, "--picks", data["turned"], "--plot", png)[0] == 1
    assert count_colour(png, OK) > 0
    assert count_colour(png, DRIFTED) > 0


def test_plot_without_logging_shows_the_history_and_this_check(rig, data, tmp_path, capsys):
    log = rig.with_name("rig.checks.jsonl")
    assert run(capsys, "check", rig, "--picks", data["same"])[0] == 0
    before = log.read_text()
    png = tmp_path / "drift.png"
    assert run(capsys, "check", rig, "--picks", data["turned"], "--no-log", "--plot", png)[0] == 1
    assert log.read_text() == before
    assert count_colour(png, OK) > 0  # the logged check
    assert count_colour(png, DRIFTED) > 0  # this one


@pytest.mark.parametrize("which", ["rig", "picks"])
def test_missing_file_is_exit_3_naming_it(rig, data, tmp_path, capsys, which):
    missing = tmp_path / "nope.yaml"
    args = [missing, "--picks", data["same"]] if which == "rig" else [rig, "--picks", missing]
    code, out, err = run(capsys, "check", *args)
    assert code == 3
    assert out == ""
    assert err.count("\n") == 1
    assert err.startswith("Error: ")
    assert "nope.yaml" in err
    assert not rig.with_name("rig.checks.jsonl").exists()


def test_rig_without_uncertainty_is_exit_3(rig, data, capsys):
    doc = yaml.safe_load(rig.read_text())
    del doc["uncertainty"]
    rig.write_text(yaml.safe_dump(doc))
    code, out, err = run(capsys, "check", rig, "--picks", data["same"])
    assert code == 3
    assert out == ""
    assert err.count("\n") == 1
    assert "uncertainty" in err
    assert not rig.with_name("rig.checks.jsonl").exists()


@pytest.mark.parametrize("level", ["0", "0.9", "-0.01", "often"])
def test_bad_level_is_exit_2(rig, data, capsys, level):
    code, _out, err = run(capsys, "check", rig, "--picks", data["same"], "--level", level)
    assert code == 2
    assert "--level" in err
    assert not rig.with_name("rig.checks.jsonl").exists()


def test_missing_picks_option_is_exit_2(rig, capsys):
    code, _, err = run(capsys, "check", rig)
    assert code == 2
    assert "--picks" in err


def test_help_has_examples(capsys):
    code, out, _ = run(capsys, "check", "--help")
    assert code == 0
    assert "Examples:" in out
    assert "rigcal check rig.yaml --picks today/picks.yaml" in out
    for option in ("--picks", "--level", "--log", "--no-log", "--plot", "--force", "--json"):
        assert option in out


@pytest.fixture(scope="module")
def board(tmp_path_factory) -> dict[str, Path]:
    """A rig solved from one simulated board session (whatever its method, a rig) and a
    new board session of the same rig: 20 captures each, as a careful lab records them (a
    10-capture session's rig is uncertain by about 0.6 deg, too much to find a 0.5 deg turn)."""
    base = tmp_path_factory.mktemp("board-check")
    for name, seed in (("calib", 4), ("today", 5)):
        assert main(["simulate", "board-session", "-o", str(base / name), "--seed", str(seed)]) == 0
    rig = base / "rig.yaml"
    assert main(["solve", str(base / "calib" / "board_session.yaml"), "-o", str(rig)]) == 0
    return {"rig": rig, "session": base / "today" / "board_session.yaml"}


def test_board_session_checks_a_rig(board, tmp_path, capsys):
    rig = Path(shutil.copy(board["rig"], tmp_path / "rig.yaml"))
    code, out, err = run(capsys, "check", rig, "--session", board["session"])
    assert code == 0, out + err
    assert out.startswith("verdict: ok (board check, false-alarm level 0.01)\n")
    assert "board captures, RMS" in out
    rec = read_log(tmp_path / "rig.checks.jsonl")[-1]
    assert rec["kind"] == "board"
    assert rec["input"] == str(board["session"].resolve())


def test_board_session_finds_a_turned_camera(board, tmp_path, capsys):
    from rigcal.geometry import make_T, rotvec_to_R
    from rigcal.rigfile import read_rig

    stored = read_rig(board["rig"])
    turned = make_T(rotvec_to_R([0.0, np.radians(0.5), 0.0]), [0.0, 0.0, 0.0]) @ stored.T_cam_laser
    rig = tmp_path / "turned.yaml"
    import dataclasses

    write_rig(rig, dataclasses.replace(stored, T_cam_laser=turned))
    code, out, _ = run(capsys, "check", rig, "--session", board["session"], "--no-log")
    assert code == 1
    assert "a fresh solve differs by" in out


def test_board_session_given_as_picks_says_to_use_session(board, capsys):
    code, _, err = run(capsys, "check", board["rig"], "--picks", board["session"], "--no-log")
    assert code == 3
    assert "method: got 'board'; expected a box picking file for --picks" in err
    assert f"--session {board['session']}" in err
    assert err.count("\n") == 1


def test_box_picks_given_as_session_are_checked_as_box(rig, data, capsys):
    code, out, _ = run(capsys, "check", rig, "--session", data["same"], "--no-log")
    assert code == 0
    assert out.startswith("verdict: ok (false-alarm level 0.01)\n")
