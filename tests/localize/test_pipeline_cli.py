"""`rigcal localize` and `rigcal evaluate` on a simulated sequence."""

from __future__ import annotations

import json

import pytest
import yaml

from rigcal.cli.main import main
from rigcal.io.trajectory import read_tum


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "cubicle"
    assert (
        main(["simulate", "world", "--world", "cubicle-loop", "-o", str(out), "--laser-rate-hz", "10"]) == 0
    )
    return out


def test_localize_writes_trajectory_summary_and_table(sequence, tmp_path, capsys):
    out = tmp_path / "icp"
    assert main(["localize", str(sequence), "--method", "icp", "-o", str(out), "--kitti"]) == 0
    table = capsys.readouterr().out
    assert "| icp |" in table
    traj = read_tum(out / "icp" / "trajectory.tum")
    summary = yaml.safe_load((out / "summary.yaml").read_text())
    assert len(traj) == summary["methods"]["icp"]["poses"]
    assert (out / "icp" / "trajectory.kitti").read_text().count("\n") == len(traj)
    assert summary["config"]["methods"] == ["icp"]
    assert (out / "paths.png").stat().st_size > 1000
    m = summary["methods"]["icp"]["metrics"]
    # A clean simulated office: point-to-line ICP closes the 35 m loop within a metre.
    assert m["loop_closure_error_m"] < 1.0
    assert m["path_length_m"] == pytest.approx(35.0, rel=0.05)
    assert json.loads((out / "summary.json").read_text())["methods"]["icp"]["metrics"] == m


def test_evaluate_agrees_with_the_summary(sequence, tmp_path, capsys):
    out = tmp_path / "p2p"
    assert main(["localize", str(sequence), "--method", "icp-p2p", "-o", str(out)]) == 0
    capsys.readouterr()
    assert (
        main(
            [
                "evaluate",
                str(out / "icp-p2p" / "trajectory.tum"),
                "--gt",
                str(sequence / "groundtruth.tum"),
                "--json",
            ]
        )
        == 0
    )
    m = json.loads(capsys.readouterr().out)
    summary = yaml.safe_load((out / "summary.yaml").read_text())["methods"]["icp-p2p"]["metrics"]
    assert m["loop_closure_error_m"] == pytest.approx(summary["loop_closure_error_m"], abs=1e-3)
    assert m["ate_rmse_m"] == pytest.approx(summary["ate_rmse_m"], abs=1e-3)


def test_bad_method_and_existing_output(sequence, tmp_path, capsys):
    assert main(["localize", str(sequence), "--method", "sift", "-o", str(tmp_path / "x")]) == 3
    assert "--method: got 'sift'" in capsys.readouterr().err
    assert main(["localize", str(sequence), "--method", "icp,icp", "-o", str(tmp_path / "x")]) == 3
    assert not (tmp_path / "x").exists()
    (tmp_path / "y").mkdir()
    assert main(["localize", str(sequence), "-o", str(tmp_path / "y")]) == 5
    assert main(["localize", str(tmp_path / "nope"), "-o", str(tmp_path / "z")]) == 3
