"""One capture off by a unit mistake (returns in millimetres) or far away is set aside
before the board solve, named in the report, and does not steer the answer."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.plane import capture_line, gross_outliers, solve_plane
from rigcal.calib.board.session import read_board_session
from rigcal.geometry import pose_error
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.noise import RealisticNoise


def millimetres(p: np.ndarray) -> np.ndarray:
    return 1000.0 * p


def far_away(p: np.ndarray) -> np.ndarray:
    return p + 140.0 * p / np.linalg.norm(p, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    sim = generate_board_session(BoardSpec(n_captures=9, seed=21, noise=RealisticNoise()))
    folder = write_board_session(sim, tmp_path_factory.mktemp("gross") / "s")
    return sim, read_board_session(folder / "board_session.yaml")


def test_a_clean_session_sets_nothing_aside(session):
    _, s = session
    screen = gross_outliers(s.observations, [capture_line(o.points_laser) for o in s.observations])
    assert not screen.gross.any()
    assert np.isfinite(screen.limit_m)
    assert np.nanmax(screen.rms_m) < 0.2 * screen.limit_m


@pytest.mark.parametrize("mistake", [millimetres, far_away])
@pytest.mark.parametrize("bad", [0, 4])
def test_a_unit_mistake_is_set_aside_and_the_answer_is_the_others(session, mistake, bad):
    _, s = session
    obs = list(s.observations)
    clean = solve_plane(obs, uncertainty_checks=False, fit_range_bias=True)
    obs[bad] = replace(obs[bad], points_laser=mistake(obs[bad].points_laser))
    res = solve_plane(obs, uncertainty_checks=False, fit_range_bias=True)
    assert res.screened_out is not None
    assert np.flatnonzero(res.screened_out).tolist() == [bad]
    assert not res.inlier_captures[bad]
    # The rest is solved as without the bad capture: near the clean answer, in its sigma.
    others = solve_plane(obs[:bad] + obs[bad + 1 :], uncertainty_checks=False, fit_range_bias=True)
    assert np.abs(res.T_cam_laser - others.T_cam_laser).max() < 1e-6
    rot_deg, trans_m = pose_error(res.T_cam_laser, clean.T_cam_laser)
    sig = np.sqrt(np.diag(clean.covariance))
    assert rot_deg < 5 * np.degrees(np.linalg.norm(sig[:3]))
    assert trans_m < 5 * np.linalg.norm(sig[3:])


def test_report_names_a_capture_in_millimetres(session, tmp_path: Path):
    sim, s = session
    folder = write_board_session(sim, tmp_path / "s")
    f = folder / "board_session.yaml"
    doc = yaml.safe_load(f.read_text())
    doc["schema_version"] = 2
    for i, (c, o) in enumerate(zip(doc["captures"], s.observations, strict=True)):
        p = millimetres(o.points_laser) if i == 2 else o.points_laser
        (folder / f"returns{i}.txt").write_text("".join(f"{float(x)!r} {float(y)!r}\n" for x, y in p))
        c["laser_side"] = {"returns_file": f"returns{i}.txt"}
    f.write_text(yaml.safe_dump(doc, sort_keys=False))
    cal = calibrate_board(f)
    first = cal.report["warnings"][0]
    assert first.startswith("capture cap02: set aside before the solve:")
    assert "millimetres read as metres?" in first
    assert cal.report["summary"]["captures_screened_out"] == 1
    per = {c["capture"]: c for c in cal.report["per_capture"]}
    assert per["cap02"]["screened_out"]
    assert not per["cap02"]["inlier"]
    assert sum(c["screened_out"] for c in per.values()) == 1
    assert not any(w.startswith("capture cap02: rejected") for w in cal.report["warnings"])
