"""`rigcal simulate board-session`: a good session by default (the first solve is
healthy), a weak one on request."""

from __future__ import annotations

import json

import numpy as np
import yaml

from rigcal.cli.main import main
from rigcal.sim.board_session import BoardSpec, generate_board_session


def test_default_is_a_good_session_that_solves_without_warnings(tmp_path, capsys):
    out = tmp_path / "board"
    assert main(["simulate", "board-session", "-o", str(out)]) == 0
    assert "20 board captures (good session)" in capsys.readouterr().err
    gen = yaml.safe_load((out / "truth.yaml").read_text())["generator"]
    assert gen["captures"] == 20
    assert gen["poses"] == "spread"
    argv = ["solve", str(out / "board_session.yaml"), "-o", str(tmp_path / "rig.yaml"), "--json"]
    assert main([*argv, "--truth", str(out / "truth.yaml")]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["warnings"] == []


def test_weak_session_is_the_hurried_one(tmp_path, capsys):
    out = tmp_path / "weak"
    assert main(["simulate", "board-session", "-o", str(out), "--session", "weak", "--seed", "1"]) == 0
    gen = yaml.safe_load((out / "truth.yaml").read_text())["generator"]
    assert gen["captures"] == 12
    assert gen["poses"] == "random"
    argv = ["solve", str(out / "board_session.yaml"), "-o", str(tmp_path / "rig.yaml"), "--json"]
    assert main(argv) == 0
    assert any(w.startswith("large uncertainty") for w in json.loads(capsys.readouterr().out)["warnings"])
    assert main(["simulate", "board-session", "-o", str(tmp_path / "x"), "--session", "fine"]) == 2


def test_spread_poses_take_one_stratum_of_distance_each():
    spec = BoardSpec(n_captures=10, spread=True, seed=5)
    s = generate_board_session(spec)
    b = spec.board
    mid = np.array([0.5 * (b.width_n - 1) * b.spacing_m, 0.5 * (b.height_n - 1) * b.spacing_m, 0.0, 1.0])
    dist = [float(np.hypot(*(c.T_laser_board @ mid)[:2])) for c in s.captures]
    lo, hi = spec.distance_m
    strata = np.floor((np.array(dist) - lo) / (hi - lo) * 10).astype(int)
    # The board's centre is the drawn distance (up to its 8 cm height jitter, which moves it
    # by less than a millimetre); each tenth of the range is used once.
    assert sorted(strata.tolist()) == list(range(10))
    # Random poses (the library's default, as before) need not cover them.
    assert not BoardSpec().spread
