"""The Python API (docs/api.md): `import rigcal` alone, the same answers as the CLI, its
errors, and the documented example run as a script."""

from __future__ import annotations

import re
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import rigcal
from rigcal.cli.main import main
from rigcal.errors import InputError, OutputError
from rigcal.sim.box_session import SessionSpec, generate_session, write_session

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sim():
    return generate_session(SessionSpec(n_captures=8, seed=21))


def captures(sim):
    return [rigcal.BoxCapture(c.scan, c.segment_id, c.picked_pixels, c.name) for c in sim.captures]


def test_import_rigcal_exports_the_api_and_loads_it_lazily():
    code = "import sys, rigcal; print('rigcal.api' in sys.modules, callable(rigcal.solve_box))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True"]
    assert set(rigcal.__all__) <= set(dir(rigcal))
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        rigcal.nope  # noqa: B018


def test_solve_box_in_memory_equals_the_picking_file_solve(sim, tmp_path, capsys):
    write_session(sim, tmp_path / "s", render_images=False)
    mem = rigcal.solve_box(captures(sim), sim.camera, range_sigma_m=0.01, T_truth=sim.T_cam_laser)
    from_file = rigcal.solve_box(tmp_path / "s" / "picks.yaml", range_sigma_m=0.01)
    np.testing.assert_allclose(mem.rig.T_cam_laser, from_file.rig.T_cam_laser, atol=1e-12)
    assert main(["solve", str(tmp_path / "s" / "picks.yaml"), "-o", str(tmp_path / "rig.yaml")]) == 0
    capsys.readouterr()
    np.testing.assert_allclose(
        rigcal.read_rig(tmp_path / "rig.yaml").T_cam_laser, mem.rig.T_cam_laser, atol=1e-9
    )
    assert mem.report["truth"]["rotation_error_deg"] < 0.5
    assert mem.rig.covariance is not None


def test_solve_box_bad_captures_name_the_capture_and_value(sim):
    caps = captures(sim)
    with pytest.raises(InputError, match="camera: got None; expected a Camera"):
        rigcal.solve_box(caps)
    bad = [*caps[:2], rigcal.BoxCapture(caps[2].scan, 999, caps[2].image_endpoints_px), *caps[3:]]
    with pytest.raises(InputError, match=r"captures\[2\]\.side: got 999; expected a segment id from 0 to"):
        rigcal.solve_box(bad, sim.camera)
    bad = [rigcal.BoxCapture(caps[0].scan, caps[0].side, [[-5.0, 1.0], [10.0, 10.0]]), *caps[1:]]
    with pytest.raises(InputError, match=r"captures\[0\]\.image_endpoints_px: got \[\[-5\.0"):
        rigcal.solve_box(bad, sim.camera)
    bad = [rigcal.BoxCapture(caps[0].scan, [3], caps[0].image_endpoints_px), *caps[1:]]
    with pytest.raises(InputError, match=r"captures\[0\]\.side: got \[3\]; expected 2 or more valid beam"):
        rigcal.solve_box(bad, sim.camera)


def test_solve_board_in_memory_needs_well_formed_captures():
    cam = generate_session(SessionSpec(n_captures=2, seed=1)).camera
    with pytest.raises(InputError, match=r"captures\[0\]: got"):
        rigcal.solve_board([rigcal.BoardCapture(np.eye(3), np.zeros((5, 2)))], cam)


def test_localize_refuses_an_existing_output_before_working(tmp_path):
    (tmp_path / "out").mkdir()
    with pytest.raises(OutputError, match="exists"):
        rigcal.localize(tmp_path / "nope", ["icp"], output=tmp_path / "out")


def test_the_documented_example_runs(capsys):
    runpy.run_path(str(ROOT / "examples" / "api_example.py"), run_name="__main__")
    out = capsys.readouterr().out
    box = re.search(r"box target: \d+/\d+ captures, .* error ([\d.]+) deg, ([\d.]+) mm", out)
    board = re.search(r"checkerboard: \d+/\d+ captures, .* error ([\d.]+) deg, ([\d.]+) mm", out)
    drive = re.search(r"localize: icp, \d+ poses over [\d.]+ m; ATE ([\d.]+) m", out)
    assert box, out
    assert board, out
    assert drive, out
    assert float(box[1]) < 0.5
    assert float(box[2]) < 30
    assert float(board[1]) < 1.5
    assert float(board[2]) < 40
    assert float(drive[1]) < 0.2


def test_the_api_page_names_every_exported_function():
    page = (ROOT / "docs" / "api.md").read_text()
    for name in (
        "solve_box",
        "solve_board",
        "read_rig",
        "write_rig",
        "localize",
        "BoxCapture",
        "BoardCapture",
    ):
        assert f"rigcal.{name}" in page
    assert "examples/api_example.py" in page


def test_localize_takes_the_tracks_and_iasm_settings(tmp_path):
    seq, out = tmp_path / "drive", tmp_path / "out"
    assert main(["simulate", "world", "-o", str(seq), "--duration-s", "3", "--seed", "1"]) == 0
    runs = rigcal.localize(seq, ["vo"], output=out, tracks={"equalize": "clahe", "n_features": 600})
    assert len(runs["vo"].stamps_s) > 2
    settings = yaml.safe_load((out / "summary.yaml").read_text())["config"]["settings"]
    assert settings["tracks"]["equalize"] == "clahe"
    assert settings["tracks"]["n_features"] == 600
    with pytest.raises(InputError, match=r"tracks equalize: got 'hist'; expected one of none, gain, clahe"):
        rigcal.localize(seq, ["vo"], tracks={"equalize": "hist"})
    with pytest.raises(InputError, match=r"iasm: got 'snap=1'; expected KEY=VALUE with KEY one of"):
        rigcal.localize(seq, ["iasm"], iasm={"snap": 1})
