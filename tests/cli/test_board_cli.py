"""`rigcal simulate board-session` and `rigcal solve` on board sessions through the command line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.rigfile import read_rig


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("cli") / "board"
    assert main(["simulate", "board-session", "-o", str(folder), "--seed", "4", "--captures", "8"]) == 0
    return folder


@pytest.fixture
def copy(session_dir, tmp_path) -> Path:
    """A writable copy of the simulated session; returns its board session file."""
    folder = tmp_path / "board"
    shutil.copytree(session_dir, folder)
    return folder / "board_session.yaml"


def edit(path: Path, change) -> Path:
    doc = yaml.safe_load(path.read_text())
    change(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def test_simulate_writes_a_board_session(session_dir):
    assert {p.name for p in session_dir.iterdir()} - {".rigcal-output"} == {
        "camera.yaml",
        "scans",
        "board_session.yaml",
        "truth.yaml",
    }
    doc = yaml.safe_load((session_dir / "board_session.yaml").read_text())
    assert doc["method"] == "board"
    assert [c["name"] for c in doc["captures"]] == [f"cap{i:02d}" for i in range(8)]
    assert yaml.safe_load((session_dir / "truth.yaml").read_text())["generator"]["seed"] == 4


def test_solve_board_session_writes_rig_and_report(session_dir, tmp_path, capsys):
    rig, rep = tmp_path / "rig.yaml", tmp_path / "report"
    code, out, err = run(
        capsys,
        "solve",
        session_dir / "board_session.yaml",
        "-o",
        rig,
        "--truth",
        session_dir / "truth.yaml",
        "--report",
        rep,
    )
    assert code == 0, err
    assert "point-to-plane error" in out
    assert "error against truth" in out
    assert "captures 8/8 used" in out
    r = read_rig(rig)
    assert r.covariance is not None
    assert r.covariance.shape == (6, 6)
    assert "board" in r.provenance["method"]
    assert {p.name for p in rep.iterdir()} == {
        ".rigcal-output",
        "report.yaml",
        "report.json",
        "report.txt",
        "residuals.png",
        "residuals.svg",
    }
    assert (rep / "report.txt").read_text() == out
    doc = json.loads((rep / "report.json").read_text())
    assert doc["summary"]["captures"] == 8
    assert yaml.safe_load((rep / "report.yaml").read_text()) == doc


def test_solve_board_session_json(session_dir, tmp_path, capsys):
    code, out, _ = run(
        capsys, "solve", session_dir / "board_session.yaml", "-o", tmp_path / "r.yaml", "--json"
    )
    assert code == 0
    doc = json.loads(out)
    assert doc["summary"]["method"] == "board"
    assert len(doc["per_capture"]) == 8
    assert doc["rig_file"].endswith("r.yaml")
    assert "truth" not in doc


def test_range_sigma_option_overrides_the_sessions(session_dir, tmp_path, capsys):
    rig = tmp_path / "r.yaml"
    args = ["solve", session_dir / "board_session.yaml", "-o", rig, "--range-sigma-m", "0.02"]
    code, _, _ = run(capsys, *args, "--noise", "assumed")
    assert code == 0
    noise = read_rig(rig).provenance["noise"]
    assert noise["mode"] == "assumed"
    assert noise["range_sigma_m"] == 0.02
    # With the default (auto) the data's estimate is used and 0.02 is reported as assumed.
    code, _, _ = run(capsys, *args, "--force")
    assert code == 0
    u = read_rig(rig).uncertainty["noise"]["range_sigma_m"]
    assert u["assumed"] == 0.02
    assert u["used"] == u["estimated"] == pytest.approx(0.01, rel=0.15)


def test_loss_option_reaches_the_board_method(session_dir, tmp_path, capsys):
    """--loss linear is plain least squares for the board method too: a different answer
    from the default Cauchy loss, and recorded in the rig's provenance."""
    answers = {}
    for loss in ("cauchy", "linear"):
        rig = tmp_path / f"{loss}.yaml"
        code, _, err = run(capsys, "solve", session_dir / "board_session.yaml", "-o", rig, "--loss", loss)
        assert code == 0, err
        r = read_rig(rig)
        assert r.provenance["refine"] == {"loss": loss, "loss_scale": 3.0}
        answers[loss] = r.T_cam_laser
    assert not np.array_equal(answers["cauchy"], answers["linear"])
    assert np.abs(answers["cauchy"] - answers["linear"]).max() < 0.05


def test_solve_help_says_the_loss_is_for_both_methods(capsys):
    code, out, _ = run(capsys, "solve", "--help")
    assert code == 0
    assert "both methods" in " ".join(out.split())


def test_intrinsics_sigma_gives_the_cameras_share(session_dir, tmp_path, capsys):
    rig = tmp_path / "r.yaml"
    args = ["solve", session_dir / "board_session.yaml", "-o", rig, "--json"]
    code, out, err = run(capsys, *args, "--intrinsics-sigma", "0.5,0.5,0.5,0.5,0,0,0,0,0")
    assert code == 0, err
    camera = json.loads(out)["uncertainty"]["camera"]
    assert camera["included"] is True
    assert camera["intrinsics_sigma"] == [0.5, 0.5, 0.5, 0.5, 0, 0, 0, 0, 0]
    code, out, _ = run(capsys, *args[:-1], "--force")
    assert code == 0
    assert "camera intrinsics' uncertainty: not included" in out


@pytest.mark.parametrize(
    ("value", "code", "shown"),
    [("a,b", 2, "expected comma-separated numbers"), ("1,2", 3, "expected 9 non-negative numbers")],
)
def test_bad_intrinsics_sigma_is_refused_and_nothing_written(
    session_dir, tmp_path, capsys, value, code, shown
):
    rig = tmp_path / "r.yaml"
    got, _, err = run(
        capsys, "solve", session_dir / "board_session.yaml", "-o", rig, "--intrinsics-sigma", value
    )
    assert got == code
    assert shown in err
    assert not rig.exists()


def test_four_captures_exit_4(copy, tmp_path, capsys):
    edit(copy, lambda d: d.update(captures=d["captures"][:4]))
    rig = tmp_path / "rig.yaml"
    code, out, err = run(capsys, "solve", copy, "-o", rig)
    assert code == 4
    assert "at least 5" in err
    assert out == ""
    assert not rig.exists()


def test_boards_that_never_tilt_are_refused_before_auto_looks_for_returns(copy, tmp_path, capsys):
    """With laser_side auto the boards' normals (what the images alone show) are checked
    first: the real cause, not "give the board's segment ids"."""

    def same_corners_auto(d):
        for c in d["captures"]:
            c["corners_px"] = d["captures"][0]["corners_px"]
            c["laser_side"] = "auto"

    edit(copy, same_corners_auto)
    code, _, err = run(capsys, "solve", copy, "-o", tmp_path / "rig.yaml")
    assert code == 4
    assert "normals' spread" in err
    assert "segment ids" not in err


def test_parallel_boards_exit_4_and_name_the_captures(copy, tmp_path, capsys):
    def same_corners(d):
        for c in d["captures"]:
            c["corners_px"] = d["captures"][0]["corners_px"]

    edit(copy, same_corners)
    rig = tmp_path / "rig.yaml"
    code, _, err = run(capsys, "solve", copy, "-o", rig)
    assert code == 4
    assert "parallel" in err
    for i in range(8):
        assert f"cap{i:02d}" in err
    assert not rig.exists()


def test_bad_file_exits_3_and_writes_nothing(copy, tmp_path, capsys):
    edit(copy, lambda d: d["captures"][2].update(laser_side={"segment": 999}))
    rig, rep = tmp_path / "rig.yaml", tmp_path / "report"
    code, out, err = run(capsys, "solve", copy, "-o", rig, "--report", rep)
    assert code == 3
    assert err.count("\n") == 1
    assert "captures[2].laser_side.segment" in err
    assert "999" in err
    assert out == ""
    assert not rig.exists()
    assert not rep.exists()


def test_simulate_refuses_an_existing_folder_without_force(tmp_path, capsys):
    folder = tmp_path / "board"
    folder.mkdir()
    (folder / "keep.txt").write_text("keep me")
    args = ["simulate", "board-session", "-o", folder, "--captures", "5"]
    code, _, err = run(capsys, *args)
    assert code == 5
    assert "--force" in err
    assert [p.name for p in folder.iterdir()] == ["keep.txt"]
    code, _, err = run(capsys, *args, "--force")
    assert code == 5
    assert "not written by rigcal" in err
    (folder / "keep.txt").unlink()
    code, _, _ = run(capsys, *args, "--force")
    assert code == 0
    assert (folder / "board_session.yaml").is_file()
    assert not (folder / "keep.txt").exists()
