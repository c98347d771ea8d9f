"""`rigcal solve`, `rigcal lines` and `rigcal project` through the command line."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.rigfile import read_rig
from rigcal.sim.box_session import SessionSpec, generate_session, write_session


@pytest.fixture(scope="module")
def session_dir(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("sess") / "session"
    write_session(generate_session(SessionSpec(n_captures=8, seed=21)), folder)
    return folder


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(list(args))
    out, err = capsys.readouterr()
    return code, out, err


def test_solve_writes_rig_and_report(session_dir, tmp_path, capsys):
    rig = tmp_path / "rig.yaml"
    rep = tmp_path / "report"
    code, out, _ = run(
        capsys,
        "solve",
        str(session_dir / "picks.yaml"),
        "-o",
        str(rig),
        "--report",
        str(rep),
        "--truth",
        str(session_dir / "truth.yaml"),
    )
    assert code == 0
    assert "reprojection error" in out
    assert "error against truth" in out
    r = read_rig(rig)
    assert r.covariance is not None
    assert r.provenance["inputs"]
    assert {p.name for p in rep.iterdir()} >= {
        "report.yaml",
        "report.json",
        "report.txt",
        "overlay_cap00.png",
        "residuals.png",
        "residuals.svg",
    }
    assert yaml.safe_load((rep / "report.yaml").read_text().split("\n", 1)[1])["summary"]["captures"] == 8


def test_solve_json(session_dir, tmp_path, capsys):
    code, out, _ = run(
        capsys, "solve", str(session_dir / "picks.yaml"), "-o", str(tmp_path / "r.yaml"), "--json"
    )
    assert code == 0
    doc = json.loads(out)
    assert doc["summary"]["box_ends"] == 16
    assert doc["rig_file"].endswith("r.yaml")
    r = read_rig(tmp_path / "r.yaml")
    np.testing.assert_allclose(np.array(doc["rig"]["T_cam_laser"]), r.T_cam_laser, atol=1e-9)
    assert r.covariance is not None
    np.testing.assert_allclose(np.array(doc["rig"]["covariance"]), r.covariance, rtol=1e-5)
    assert len(doc["rig"]["sigma_translation_mm"]) == 3
    # The noise model and the covariance's checks, as in the report.
    assert set(doc["noise"]) == {"range_sigma_m", "pick_sigma_px"}
    assert doc["noise"]["pick_sigma_px"]["used"] == doc["noise"]["pick_sigma_px"]["estimated"]
    assert {"sensitivity", "model_sigma_rotation_deg"} <= set(doc["uncertainty"])
    assert r.uncertainty["noise"] == doc["noise"]


@pytest.mark.parametrize(("given", "expected"), [(None, 0.004), ("0.02", 0.02)])
def test_solve_range_noise_is_the_picking_files_unless_given(given, expected, session_dir, tmp_path, capsys):
    # The box method takes laser.range_sigma_m from the picking file, as the board method does.
    picks = yaml.safe_load((session_dir / "picks.yaml").read_text())
    picks["laser"]["range_sigma_m"] = 0.004
    picks["camera"] = str(session_dir / picks["camera"])
    for c in picks["captures"]:
        c["scan"], c["image"] = str(session_dir / c["scan"]), str(session_dir / c["image"])
    (tmp_path / "picks.yaml").write_text(yaml.safe_dump(picks))
    extra = ["--range-sigma-m", given] if given else []
    code, _, _ = run(capsys, "solve", str(tmp_path / "picks.yaml"), "-o", str(tmp_path / "r.yaml"), *extra)
    assert code == 0
    assert read_rig(tmp_path / "r.yaml").provenance["noise"]["range_sigma_m"] == expected


def test_solve_refuses_to_overwrite(session_dir, tmp_path, capsys):
    rig = tmp_path / "rig.yaml"
    rig.write_text("keep me")
    code, _, err = run(capsys, "solve", str(session_dir / "picks.yaml"), "-o", str(rig))
    assert code == 5
    assert "exists" in err
    assert "--force" in err
    assert rig.read_text() == "keep me"
    code, _, _ = run(capsys, "solve", str(session_dir / "picks.yaml"), "-o", str(rig), "--force")
    assert code == 0
    assert read_rig(rig).camera.width_px > 0


def test_solve_bad_input_writes_nothing(session_dir, tmp_path, capsys):
    bad = tmp_path / "sess"
    shutil.copytree(session_dir, bad)
    picks = yaml.safe_load((bad / "picks.yaml").read_text())
    picks["captures"][2]["laser_side"] = {"segment": 999}
    (bad / "picks.yaml").write_text(yaml.safe_dump(picks))
    rig = tmp_path / "rig.yaml"
    code, out, err = run(
        capsys, "solve", str(bad / "picks.yaml"), "-o", str(rig), "--report", str(tmp_path / "rep")
    )
    assert code == 3
    assert err.count("\n") == 1
    assert "captures[2].laser_side.segment" in err
    assert "999" in err
    assert not rig.exists()
    assert not (tmp_path / "rep").exists()
    assert out == ""


def test_solve_missing_file_and_usage(tmp_path, capsys):
    code, _, err = run(capsys, "solve", str(tmp_path / "nope.yaml"), "-o", str(tmp_path / "r.yaml"))
    assert code == 3
    assert "nope.yaml" in err
    code, _, _ = run(capsys, "solve", str(tmp_path / "nope.yaml"))
    assert code == 2
    code, _, _ = run(capsys, "solve", "x", "-o", "y", "--threshold-px", "-1")
    assert code == 2


def test_solve_too_few_captures_exit_4(session_dir, tmp_path, capsys):
    picks = yaml.safe_load((session_dir / "picks.yaml").read_text())
    picks["captures"] = picks["captures"][:2]
    p = session_dir / "two.yaml"
    p.write_text(yaml.safe_dump(picks))
    try:
        code, _, err = run(capsys, "solve", str(p), "-o", str(tmp_path / "r.yaml"))
    finally:
        p.unlink()
    assert code == 4
    assert "at least 3" in err
    assert not (tmp_path / "r.yaml").exists()


def test_lines_table_json_and_png(session_dir, tmp_path, capsys):
    scan = session_dir / "scans" / "cap00.yaml"
    code, out, err = run(capsys, "lines", str(scan))
    assert code == 0
    assert "segments" in err
    code, out, _ = run(capsys, "lines", str(scan), "--json", "--png", str(tmp_path / "l.png"))
    assert code == 0
    segs = json.loads(out)
    assert segs
    assert segs[0]["id"] == 0
    assert (tmp_path / "l.png").stat().st_size > 1000
    code, _, _ = run(capsys, "lines", str(scan), "--png", str(tmp_path / "l.png"))
    assert code == 5


def test_project_overlay(session_dir, tmp_path, capsys):
    rig = tmp_path / "rig.yaml"
    assert run(capsys, "solve", str(session_dir / "picks.yaml"), "-o", str(rig))[0] == 0
    png = tmp_path / "o.png"
    args = [str(rig), str(session_dir / "scans" / "cap00.yaml"), str(session_dir / "images" / "cap00.png")]
    code, out, err = run(capsys, "project", *args, "-o", str(png), "--json")
    assert code == 0
    assert json.loads(out)["beams_in_image"] > 10
    assert png.exists()
    code, _, err = run(
        capsys, "project", str(tmp_path / "none.yaml"), *args[1:], "-o", str(tmp_path / "p.png")
    )
    assert code == 3
    assert "none.yaml" in err


def test_help_has_examples(capsys):
    for cmd in ("solve", "lines", "project"):
        code, out, _ = run(capsys, cmd, "--help")
        assert code == 0
        assert "Examples:" in out


def _edit(picks: dict, case: str, folder: Path) -> dict:
    """Break a copied session's picking file (or its files) in one way."""
    caps = picks["captures"]
    if case == "unknown key":
        caps[1]["colour"] = "red"
    elif case == "wrong type":
        caps[1]["image_endpoints_px"] = "left and right"
    elif case == "pick outside image":
        caps[3]["image_endpoints_px"][0] = [700.0, 100.0]
    elif case == "scan all NaN":
        scan = folder / caps[0]["scan"]
        doc = yaml.safe_load(scan.read_text())
        doc["ranges_m"] = [float("nan")] * len(doc["ranges_m"])
        scan.write_text(yaml.safe_dump(doc))
    elif case == "laser points off the scan":
        for c in caps:
            c["laser_side"] = {"points": [[2.0, -0.3], [2.0, 0.3]]}
    elif case == "no consensus":
        rng = __import__("numpy").random.default_rng(0)
        for c in caps:
            c["image_endpoints_px"] = rng.uniform([0, 0], [639, 479], (2, 2)).round(1).tolist()
    return picks


@pytest.mark.parametrize(
    ("case", "code", "needle"),
    [
        ("unknown key", 3, "captures[1].colour"),
        ("wrong type", 3, "captures[1].image_endpoints_px"),
        ("pick outside image", 3, "captures[3].image_endpoints_px[0]"),
        ("scan all NaN", 3, "captures[0].laser_side.segment"),
        ("laser points off the scan", 3, "captures[0].laser_side.points"),
        ("no consensus", 4, "RANSAC found no consensus"),
    ],
)
def test_each_bad_session_gives_one_line_and_writes_nothing(
    session_dir, tmp_path, capsys, case, code, needle
):
    bad = tmp_path / "sess"
    shutil.copytree(session_dir, bad)
    picks = _edit(yaml.safe_load((bad / "picks.yaml").read_text()), case, bad)
    (bad / "picks.yaml").write_text(yaml.safe_dump(picks))
    rig, rep = tmp_path / "rig.yaml", tmp_path / "report"
    got, out, err = run(capsys, "solve", str(bad / "picks.yaml"), "-o", str(rig), "--report", str(rep))
    assert got == code, err
    assert needle in err
    assert err.startswith("Error: ")
    assert err.count("\n") == 1
    assert out == ""
    assert not rig.exists()
    assert not rep.exists()


def test_malformed_yaml_names_the_line(session_dir, tmp_path, capsys):
    bad = tmp_path / "sess"
    shutil.copytree(session_dir, bad)
    (bad / "picks.yaml").write_text("schema_version: 1\ncaptures: [\n")
    got, _, err = run(capsys, "solve", str(bad / "picks.yaml"), "-o", str(tmp_path / "r.yaml"))
    assert got == 3
    assert "not valid YAML at line" in err


def test_existing_report_folder_needs_force(session_dir, tmp_path, capsys):
    rep = tmp_path / "report"
    rep.mkdir()
    (rep / "keep.txt").write_text("mine")
    got, _, err = run(
        capsys, "solve", str(session_dir / "picks.yaml"), "-o", str(tmp_path / "r.yaml"), "--report", str(rep)
    )
    assert got == 5
    assert "--force" in err
    assert (rep / "keep.txt").read_text() == "mine"
    assert not (tmp_path / "r.yaml").exists()
