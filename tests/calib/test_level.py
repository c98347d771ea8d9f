"""Boards that never tilt: the images-first check, the reduced solve for a level scanner
(yaw and the horizontal translations; roll, pitch and height from priors), its session
key, command-line option and rig file."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.level import (
    LevelFrame,
    LevelPriors,
    board_vertical,
    level_errors,
    solve_level,
)
from rigcal.calib.board.plane import check_normals
from rigcal.calib.board.session import read_board_session
from rigcal.calib.intrinsics import Board
from rigcal.cli.main import main
from rigcal.errors import CalibrationError, InputError
from rigcal.geometry import make_T
from rigcal.rigfile import read_rig
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session

CHI2_3_999 = 16.27  # chi-square, 3 dof, 99.9 %
CHI2_6_999 = 22.46


def camera_height(T: np.ndarray) -> float:
    """The camera centre's height above the scan plane (its z in the laser frame)."""
    return float((-T[:3, :3].T @ T[:3, 3])[2])


@pytest.fixture(scope="module")
def wall(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, np.ndarray]:
    """A session of 5 upright boards (leaning at most 2 deg, never rolled) turned in front
    of a level scanner, and its true T_cam_laser."""
    spec = BoardSpec(n_captures=5, seed=4, max_tilt_deg=2.0, max_roll_deg=0.0, board=Board(7, 5, 0.12))
    sim = generate_board_session(spec)
    folder = write_board_session(sim, tmp_path_factory.mktemp("wall") / "s")
    return folder / "board_session.yaml", sim.T_cam_laser


def priors_for(T: np.ndarray, height_off_m: float = 0.0) -> LevelPriors:
    return LevelPriors((0.0, 0.5), (0.0, 0.5), (camera_height(T) + height_off_m, 0.005))


def test_images_first_names_the_missing_tilt(wall: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    path, _ = wall
    # A wrong segment id is not what is reported: the images alone show the boards never tilt.
    text = re.sub(r"laser_side: \{segment: \d+\}", "laser_side: {segment: 9999}", path.read_text(), count=1)
    broken = path.parent / "broken_ids.yaml"
    broken.write_text(text)
    with pytest.raises(CalibrationError) as exc:
        read_board_session(broken)
    msg = str(exc.value)
    assert "never tilt: every board normal is within" in msg
    assert re.search(r"normals' spread 0\.0\d\d < 0\.05", msg)
    assert "tilted forward and back by 20-40 deg" in msg
    assert "--level-prior" in msg
    assert "segment" not in msg


def test_boards_facing_one_way_are_told_to_turn() -> None:
    from rigcal.calib.board.plane import PlaneObservation

    n = np.array([0.0, 0.0, 1.0])
    obs = [PlaneObservation(i, f"c{i}", n, 2.0, np.zeros((2, 2))) for i in range(5)]
    with pytest.raises(
        CalibrationError, match=r"all face one way \(their planes are parallel: every normal within 0\.0 deg"
    ):
        check_normals(obs)


def test_reduced_solve_recovers_the_observed_parameters(wall: tuple[Path, np.ndarray]) -> None:
    path, T = wall
    session = read_board_session(path, level=priors_for(T))
    result, sol = solve_level(session.observations, session.level, fit_range_bias=False)  # type: ignore[arg-type]
    assert sol.frame.sign == 1
    e = level_errors(sol, T)
    assert e["d2_observed"] < CHI2_3_999
    assert e["d2_all"] < CHI2_6_999
    assert abs(e["yaw_error_deg"]) < 1.0
    assert e["horizontal_error_mm"] < 30.0
    est = sol.estimates()
    # The prior-bound parameters stay at their priors, with about their sigmas.
    assert abs(est["camera_height_m"][0] - camera_height(T)) < 0.002
    assert est["camera_height_m"][1] == pytest.approx(0.005, rel=0.05)
    assert np.degrees(est["roll_rad"][1]) >= 0.5
    assert np.degrees(est["pitch_rad"][1]) >= 0.5
    # The data fix the observed ones far better than the priors fix theirs.
    assert np.degrees(est["yaw_rad"][1]) < 0.5
    assert result.inlier_captures.all()


def test_the_height_prior_moves_only_the_height(wall: tuple[Path, np.ndarray]) -> None:
    path, T = wall
    session = read_board_session(path, level=priors_for(T))
    _, a = solve_level(session.observations, priors_for(T))
    _, b = solve_level(session.observations, priors_for(T, 0.05))
    ea, eb = a.estimates(), b.estimates()
    assert eb["camera_height_m"][0] - ea["camera_height_m"][0] == pytest.approx(0.05, abs=0.002)
    assert abs(np.degrees(eb["yaw_rad"][0] - ea["yaw_rad"][0])) < 0.05
    assert abs(eb["camera_x_m"][0] - ea["camera_x_m"][0]) < 0.002


def test_an_upside_down_scanner_is_found(wall: tuple[Path, np.ndarray]) -> None:
    """The laser's z down: the same boards, the returns mirrored (y -> -y), T turned by pi
    about the laser's x."""
    path, T = wall
    session = read_board_session(path, level=priors_for(T))
    flip = make_T(np.diag([1.0, -1.0, -1.0]), np.zeros(3))
    T_down = T @ flip
    mirrored = [replace(o, points_laser=o.points_laser * np.array([1.0, -1.0])) for o in session.observations]
    _, sol = solve_level(mirrored, LevelPriors((0.0, 0.5), (0.0, 0.5), (camera_height(T_down), 0.005)))
    assert sol.frame.sign == -1
    e = level_errors(sol, T_down)
    assert e["d2_all"] < CHI2_6_999
    assert abs(e["yaw_error_deg"]) < 1.0


def test_level_frame_round_trip() -> None:
    rng = np.random.default_rng(0)
    up = rng.normal(size=3)
    frame = LevelFrame.from_up(up / np.linalg.norm(up), -1)
    x = np.array([0.7, 0.02, -0.03, 0.1, -0.2, 0.15])
    assert np.allclose(frame.parameters(frame.pose(x)), x, atol=1e-12)


def test_vertical_from_upright_normals() -> None:
    yaw = np.radians([-40, -15, 0, 20, 45])
    up = np.array([0.0, -1.0, 0.0])  # the camera's -y
    normals = np.column_stack([np.sin(yaw), np.zeros(5), np.cos(yaw)])
    v = board_vertical(normals)
    assert np.allclose(v.up_cam, up)
    assert v.max_tilt_deg < 1e-6
    assert v.spread < 1e-9


def test_boards_facing_one_way_cannot_give_a_level_solve(wall: tuple[Path, np.ndarray]) -> None:
    path, T = wall
    session = read_board_session(path, level=priors_for(T))
    same = [replace(o, normal_cam=session.observations[0].normal_cam) for o in session.observations]
    with pytest.raises(CalibrationError, match=r"all face nearly one way .* turned about the vertical"):
        solve_level(same, priors_for(T))
    with pytest.raises(CalibrationError, match="the level solve needs at least 3"):
        solve_level(session.observations[:2], priors_for(T))


def test_report_and_rig_say_what_is_prior_bound(wall: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    path, T = wall
    cal = calibrate_board(path, level=priors_for(T))
    red = cal.report["reduced"]
    assert set(red["solved"]) == {"yaw_deg", "camera_x_mm", "camera_y_mm"}
    assert set(red["prior_bound"]) == {"roll_deg", "pitch_deg", "camera_height_mm"}
    assert red["prior_bound"]["camera_height_mm"]["prior_sigma"] == pytest.approx(5.0)
    assert cal.report["warnings"][0].startswith("reduced solve (level scanner, upright boards)")
    assert not any(w.startswith("large uncertainty") for w in cal.report["warnings"])
    from rigcal.rigfile import rig_to_text, write_rig

    out = write_rig(tmp_path / "rig.yaml", cal.rig)
    assert rig_to_text(cal.rig).startswith("# rigcal rig file, schema 3")
    back = read_rig(out)
    assert back.uncertainty["reduced"]["prior_bound"]["roll_deg"]["prior"] == 0.0
    # The covariance carries the height prior: about 5 mm along the vertical.
    up = red["level_frame"]["up_cam"]
    assert float(np.sqrt(up @ back.covariance[3:, 3:] @ up)) == pytest.approx(0.005, rel=0.2)
    # A schema 2 file cannot hold the section.
    doc = yaml.safe_load(out.read_text())
    doc["schema_version"] = 2
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"uncertainty.reduced: got .*; expected no such key"):
        read_rig(bad)
    doc["schema_version"] = 3
    doc["uncertainty"]["reduced"]["solved"] = {"yaw_deg": 1.0}
    bad.write_text(yaml.safe_dump(doc))
    with pytest.raises(
        InputError, match=r"uncertainty.reduced.solved: got .*; expected a mapping of parameter"
    ):
        read_rig(bad)


def _with_level(path: Path, level: str, version: int = 3) -> Path:
    text = re.sub(r"schema_version: \d", f"schema_version: {version}", path.read_text())
    out = path.parent / f"level_{abs(hash(level))}_{version}.yaml"
    out.write_text(text + level)
    return out


def test_session_level_key(wall: tuple[Path, np.ndarray]) -> None:
    path, T = wall
    h = camera_height(T)
    good = _with_level(
        path, f"level: {{roll_deg: [0, 0.5], pitch_deg: [0.0, 0.5], camera_height_m: [{h}, 0.005]}}\n"
    )
    assert read_board_session(good).level == LevelPriors((0.0, 0.5), (0.0, 0.5), (h, 0.005))
    cases = [
        (
            _with_level(
                path, "level: {roll_deg: [0, 0.5], pitch_deg: [0, 0.5], camera_height_m: [0.1, 0.0]}\n"
            ),
            r"level.camera_height_m: got \[0.1, 0.0\]; expected \[measured value, 1-sigma > 0\] in m",
        ),
        (
            _with_level(path, "level: {roll_deg: 0, pitch_deg: [0, 0.5], camera_height_m: [0.1, 0.01]}\n"),
            r"level.roll_deg: got 0; expected \[measured value, 1-sigma > 0\] in deg",
        ),
        (
            _with_level(path, "level: {roll_deg: [0, 0.5], camera_height_m: [0.1, 0.01]}\n"),
            r"level.pitch_deg: missing",
        ),
        (
            _with_level(
                path, "level: {roll_deg: [0, 0.5], pitch_deg: [0, 0.5], camera_height_m: [0.1, 0.01]}\n", 2
            ),
            r"level: got .*; expected no level in schema_version 1 or 2 \(level needs 3\)",
        ),
    ]
    for file, message in cases:
        with pytest.raises(InputError, match=message):
            read_board_session(file)


def test_auto_returns_are_refused_with_the_level_solve(wall: tuple[Path, np.ndarray]) -> None:
    path, T = wall
    text = re.sub(r"laser_side: \{segment: \d+\}", "laser_side: auto", path.read_text())
    auto = path.parent / "auto.yaml"
    auto.write_text(text)
    with pytest.raises(
        InputError, match=r"captures\[0\].laser_side: got 'auto'; expected the board's segment ids"
    ):
        read_board_session(auto, level=priors_for(T))
    # Without priors, auto on boards that never tilt says so from the images first.
    with pytest.raises(CalibrationError, match="never tilt"):
        read_board_session(auto)


def test_cli_level_prior(
    wall: tuple[Path, np.ndarray], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    path, T = wall
    h = f"{camera_height(T):.4f}"
    base = ["solve", str(path), "-o", str(tmp_path / "rig.yaml"), "--force"]
    prior = ["--level-prior", "pitch_deg", "0", "0.5", "--level-prior", "camera_height_m", h, "0.005"]

    def run(*extra: str) -> tuple[int, str]:
        code = main([*base, *extra])
        out = capsys.readouterr()
        return code, out.out + out.err

    code, out = run("--level-prior", "roll_deg", "0", "0.5", *prior)
    assert code == 0, out
    assert "prior-bound (not measured)" in out
    assert read_rig(tmp_path / "rig.yaml").uncertainty["reduced"]["level_frame"]["laser_z"] == "up"
    code, out = run("--level-prior", "roll_deg", "0", "0.5")
    assert code == 3
    assert "--level-prior: pitch_deg, camera_height_m missing; the reduced solve needs all three" in out
    code, out = run("--level-prior", "roll_deg", "0", "0.5", "--level-prior", "roll_deg", "0", "1")
    assert code == 3
    assert "roll_deg given twice" in out
    code, out = run("--level-prior", "roll_deg", "0", "0", *prior)
    assert code == 3
    assert "roll_deg: got value 0, sigma 0; expected a finite value and a 1-sigma > 0" in out
    code, out = run()
    assert code == 4
    assert "never tilt" in out


def test_pcd_scans_give_the_same_board_returns(wall: tuple[Path, np.ndarray], tmp_path: Path) -> None:
    """The session's scans as clockwise binary PCD files (no return: 0 0 0): the same
    segment ids pick the same returns, to float32 precision."""
    from rigcal.scan import read_scan

    path, T = wall
    folder = path.parent
    for scan_file in sorted((folder / "scans").glob("*.yaml")):
        scan = read_scan(scan_file)
        xyz = np.zeros((len(scan.ranges_m), 3), dtype="<f4")
        xyz[scan.valid, :2] = scan.points[scan.valid]
        head = (
            "VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\n"
            f"WIDTH {len(xyz)}\nHEIGHT 1\nPOINTS {len(xyz)}\nDATA binary\n"
        )
        scan_file.with_suffix(".pcd").write_bytes(head.encode() + xyz[::-1].tobytes())
    pcd = folder / "pcd_session.yaml"
    pcd.write_text(re.sub(r"(scan: scans/\S+)\.yaml", r"\1.pcd", path.read_text()))
    a = read_board_session(path, level=priors_for(T))
    b = read_board_session(pcd, level=priors_for(T))
    for x, y in zip(a.observations, b.observations, strict=True):
        assert len(x.points_laser) == len(y.points_laser)
        assert np.allclose(np.sort(x.points_laser, axis=0), np.sort(y.points_laser, axis=0), atol=1e-6)


def test_api_solve_board_takes_level_priors(wall: tuple[Path, np.ndarray]) -> None:
    import rigcal

    path, T = wall
    sol = rigcal.solve_board(path, level=priors_for(T), T_truth=T)
    assert sol.rig.uncertainty["reduced"]["model"] == "level scanner, upright boards"
    assert sol.report["truth"]["nees"] < CHI2_6_999
    with pytest.raises(
        InputError, match=r"rigcal.solve_board: level: got 'flat'; expected a rigcal.calib.board.level"
    ):
        rigcal.solve_board(path, level="flat")  # type: ignore[arg-type]
