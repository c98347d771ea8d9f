"""rigcal capture from a sequence folder (a simulated recording of still moments) to
rigcal solve: the board route (a targets file of kind board) and the marker route; board
sessions with a still moment's scans (schema 4); and their errors."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.session import read_board_session
from rigcal.calib.report import truth_comparison
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.rigfile import read_rig
from rigcal.scan import Scan
from rigcal.sim.board_session import BoardSpec, generate_board_session
from rigcal.sim.recording import StillMoment, board_moments, marker_moments, write_still_recording
from rigcal.targets.board import BoardTarget, board_target_text, read_target

POSES = 7
SCANS = 8  # a moment's scans: 0.8 s still at 10 Hz


@pytest.fixture(scope="module")
def board_sim():
    return generate_board_session(BoardSpec(n_captures=POSES, repeats=SCANS, seed=3, spread=True))


@pytest.fixture(scope="module")
def board_rec(tmp_path_factory, board_sim) -> tuple[Path, Path]:
    """A recording of the board's still moments, one more where the board is out of sight
    (the background's picture; the scans of the first pose), and its targets file."""
    s = board_sim
    root = tmp_path_factory.mktemp("boardrec")
    moments = board_moments(s)
    empty = np.full_like(moments[0].image, 128)
    moments.insert(3, StillMoment(moments[0].scans, empty))
    write_still_recording(root / "seq", "board drive", moments, s.camera, s.T_cam_laser)
    b = s.spec.board
    target = BoardTarget("lab board", b.width_n, b.height_n, b.spacing_m, s.spec.size_m)
    (root / "board.yaml").write_text(board_target_text(target))
    return root / "seq", root / "board.yaml"


@pytest.fixture(scope="module")
def board_captured(tmp_path_factory, board_rec) -> tuple[Path, str]:
    seq, target = board_rec
    out = tmp_path_factory.mktemp("boardcap") / "s"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["capture", str(seq), "--target", str(target), "-o", str(out), "--json"]) == 0
    return out, buf.getvalue()


def test_board_target_round_trip(tmp_path):
    t = BoardTarget("b", 8, 6, 0.06, (0.6, 0.5), 0.4)
    (tmp_path / "b.yaml").write_text(board_target_text(t))
    assert read_target(tmp_path / "b.yaml") == BoardTarget(
        "b", 8, 6, 0.06, (0.6, 0.5), 0.4, tmp_path / "b.yaml"
    )


def test_the_board_route_from_a_sequence_folder_to_the_rig(board_sim, board_captured, board_rec, tmp_path):
    out, printed = board_captured
    rows = json.loads(printed)["captures"]
    assert len(rows) == POSES + 1
    # The moment whose image shows no board is listed with the reason; the others go on.
    assert rows[3]["board"] == "set aside: board: no 8x6 chessboard found in the image"
    assert all(r["board"] == "board 48 corners" for k, r in enumerate(rows) if k != 3)
    doc = yaml.safe_load((out / "board_session.yaml").read_text())
    assert doc["schema_version"] == 4
    assert doc["board"] == {
        "corners_x": 8,
        "corners_y": 6,
        "spacing_m": 0.06,
        "size_m": list(board_sim.spec.size_m),
    }
    assert [c["name"] for c in doc["captures"]] == [f"cap{k:02d}" for k in range(POSES + 1) if k != 3]
    assert all(c["laser_side"] == "auto" and 4 <= len(c["scans"]) <= SCANS for c in doc["captures"])
    assert "# set aside: cap03 (board: no 8x6 chessboard" in (out / "board_session.yaml").read_text()
    assert (out / "targets.yaml").read_text() == board_rec[1].read_text()
    # rigcal solve takes it as it is.
    rig = tmp_path / "rig.yaml"
    assert (
        main(["solve", str(out / "board_session.yaml"), "-o", str(rig), "--report", str(tmp_path / "r")]) == 0
    )
    t = truth_comparison(read_rig(rig).T_cam_laser, np.eye(6), board_sim.T_cam_laser)
    # Bounds from the noise: 1 cm range noise averaged over ~6 scans, 7 boards.
    assert t["rotation_error_deg"] < 0.5
    assert t["translation_error_mm"] < 10.0
    report = yaml.safe_load((tmp_path / "r" / "report.yaml").read_text())
    assert [c["scans"] for c in report["per_capture"]] == [len(c["scans"]) for c in doc["captures"]]


def test_one_scan_a_moment_against_all(board_rec, board_captured, board_sim, tmp_path):
    """--max-scans 1 keeps the scan paired with the image; the mean of a moment's scans
    shows less range noise in the solve's own estimate."""
    seq, target = board_rec
    assert (
        main(["capture", str(seq), "--target", str(target), "-o", str(tmp_path / "one"), "--max-scans", "1"])
        == 0
    )
    doc = yaml.safe_load((tmp_path / "one" / "board_session.yaml").read_text())
    assert all(c["scan"] == f"scans/{c['name']}.yaml" and "scans" not in c for c in doc["captures"])
    one = calibrate_board(tmp_path / "one" / "board_session.yaml")
    every = calibrate_board(board_captured[0] / "board_session.yaml")
    sigma = [c.report["noise"]["range_sigma_m"]["estimated"] for c in (one, every)]
    assert sigma[1] < 0.7 * sigma[0]


def test_a_board_target_file_is_refused_by_a_marker_session_and_the_reverse(board_rec, tmp_path):
    from rigcal.targets.marker import read_targets

    with pytest.raises(InputError, match=r"board\.yaml: kind: got 'board'; expected marker"):
        read_targets(board_rec[1])


def _fails(argv: list, code: int, capsys, out: Path) -> str:
    """Run rigcal; it must end in ``code`` with one Error: line and ``out`` not written."""
    assert main([str(a) for a in argv]) == code
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("Error: ")
    assert "Traceback" not in "\n".join(err)
    assert not out.exists()
    return err[-1]


def test_capture_errors_from_a_sequence_folder(board_rec, tmp_path, capsys):
    seq, target = board_rec
    out = tmp_path / "s"
    base = ["capture", seq, "-o", out]
    # A recording with no still moment.
    err = _fails([*base, "--target", target, "--still-frames", "500"], 3, capsys, out)
    assert err.startswith(
        f"Error: {seq}: still periods: got none; expected moments where the scans and images"
    )
    # A board never seen: the targets file says 9x6 inner corners.
    wrong = tmp_path / "wrong.yaml"
    text = target.read_text().replace("corners_x: 8", "corners_x: 9")
    wrong.write_text("".join(line for line in text.splitlines(True) if "size_m" not in line))
    err = _fails([*base, "--target", wrong], 3, capsys, out)
    assert err.startswith(
        f"Error: {wrong}: board: got '9x6 inner corners'; expected the chessboard the recording shows: "
        f"none of the {POSES + 1} still moments of {seq} shows it"
    )


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (
            lambda t: t.replace("corners_x: 8", "corners_x: 1"),
            r"board\.corners_x: got 1; expected an integer in \[2, 1000\]",
        ),
        (
            lambda t: t.replace("spacing_m: 0.06", "spacing_m: -0.06"),
            r"board\.spacing_m: got -0\.06; expected",
        ),
        (
            lambda t: t.replace("size_m: [", "size_m: [0.1, 0.1] #["),
            r"board\.size_m: got \[0\.1, 0\.1\]; expected \[width, height\] of the board's sheet "
            r"in metres, at least the printed pattern's \[0\.54, 0\.42\]",
        ),
        (
            lambda t: t.replace("schema_version: 2", "schema_version: 1"),
            r"schema_version: got 1; expected 2 \(kind: board needs schema version 2\)",
        ),
        (
            lambda t: t.replace("kind: board", "kind: plank"),
            r"kind: got 'plank'; expected marker \(the V of two ChArUco faces\) or board \(a chessboard\)",
        ),
        (lambda t: t + "colour: red\n", r"bad\.yaml: colour: got 'red'; expected no such key"),
        (lambda t: t.replace("board:", "boards:"), r"board"),
    ],
)
def test_bad_board_targets_files(board_rec, tmp_path, edit, match, capsys):
    seq, target = board_rec
    bad = tmp_path / "bad.yaml"
    bad.write_text(edit(target.read_text()))
    with pytest.raises(InputError, match=match):
        read_target(bad)
    # The command stops before reading the recording: exit 3, one line, nothing written.
    assert main(["capture", str(seq), "--target", str(bad), "-o", str(tmp_path / "s")]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith(f"Error: {bad}: ")
    assert not (tmp_path / "s").exists()


def test_the_board_found_in_too_few_moments_is_a_calibration_failure(board_sim, tmp_path, capsys):
    """Four moments show the board: the board method needs five (exit 4, nothing written)."""
    s = board_sim
    moments = board_moments(s)[:4]
    write_still_recording(tmp_path / "seq", "short", moments, s.camera, s.T_cam_laser)
    b = s.spec.board
    (tmp_path / "b.yaml").write_text(board_target_text(BoardTarget("b", b.width_n, b.height_n, b.spacing_m)))
    assert (
        main(
            [
                "capture",
                str(tmp_path / "seq"),
                "--target",
                str(tmp_path / "b.yaml"),
                "-o",
                str(tmp_path / "s"),
            ]
        )
        == 4
    )
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(
        f"Error: {tmp_path / 'seq'}: the board was found in 4 of 4 still moments; the board method needs 5"
    )
    assert not (tmp_path / "s").exists()


def test_a_moment_whose_scans_miss_the_board_is_set_aside(board_sim, tmp_path, capsys):
    """The board is seen in the image but the scans are of the room alone (the board above
    the scan plane): that moment is set aside with what the scan search tried."""
    s = board_sim
    moments = board_moments(s)
    room = tuple(_without(sc, s) for sc in moments[2].scans)
    moments[2] = StillMoment(room, moments[2].image)
    write_still_recording(tmp_path / "seq", "board drive", moments, s.camera, s.T_cam_laser)
    b = s.spec.board
    (tmp_path / "b.yaml").write_text(
        board_target_text(BoardTarget("b", b.width_n, b.height_n, b.spacing_m, s.spec.size_m))
    )
    out = tmp_path / "s"
    assert main(["capture", str(tmp_path / "seq"), "--target", str(tmp_path / "b.yaml"), "-o", str(out)]) == 0
    table = capsys.readouterr().out
    assert "cap02" in table
    assert "set aside: the board in the scan: " in table
    doc = yaml.safe_load((out / "board_session.yaml").read_text())
    assert "cap02" not in [c["name"] for c in doc["captures"]]
    assert main(["solve", str(out / "board_session.yaml"), "-o", str(tmp_path / "rig.yaml")]) == 0


def _without(scan: Scan, s) -> Scan:
    """The scan with the board's returns replaced by a far wall's (no board in it)."""
    from dataclasses import replace

    r = scan.ranges_m.copy()
    r[np.isfinite(r) & (r < s.spec.distance_m[1] + 0.3)] = np.nan
    return replace(scan, ranges_m=r)


def test_the_marker_route_from_a_sequence_folder_to_the_rig(tmp_path, capsys):
    from rigcal.sim.marker_session import MarkerSpec, generate_marker_session
    from rigcal.targets.marker import targets_text

    sim = generate_marker_session(MarkerSpec(n_captures=7, scans_per_capture=SCANS, seed=5))
    write_still_recording(tmp_path / "seq", "v drive", marker_moments(sim), sim.camera, sim.T_cam_laser)
    (tmp_path / "targets.yaml").write_text(targets_text(sim.spec.target))
    out = tmp_path / "v"
    assert (
        main(["capture", str(tmp_path / "seq"), "--target", str(tmp_path / "targets.yaml"), "-o", str(out)])
        == 0
    )
    assert capsys.readouterr().out.count("markers left ") == 7
    doc = yaml.safe_load((out / "marker_session.yaml").read_text())
    assert all(4 <= len(c["scans"]) <= SCANS for c in doc["captures"])
    # The camera came from the sequence folder (no --camera).
    assert (out / "camera.yaml").read_text() == (tmp_path / "seq" / "camera.yaml").read_text()
    assert main(["solve", str(out / "marker_session.yaml"), "-o", str(tmp_path / "rig.yaml")]) == 0
    t = truth_comparison(read_rig(tmp_path / "rig.yaml").T_cam_laser, np.eye(6), sim.T_cam_laser)
    assert t["rotation_error_deg"] < 1.5
    assert t["translation_error_mm"] < 30.0


# --- board sessions with a still moment's scans (schema 4) ----------------------------------


def _copy(out: Path, tmp_path: Path) -> Path:
    shutil.copytree(out, tmp_path / "s")
    return tmp_path / "s" / "board_session.yaml"


def test_a_board_capture_reads_the_mean_of_its_scans(board_captured, tmp_path):
    from rigcal.scan import mean_scan, read_scan

    path = _copy(board_captured[0], tmp_path)
    doc = yaml.safe_load(path.read_text())
    session = read_board_session(path)
    first = doc["captures"][0]
    assert session.scans_per_capture[first["name"]] == len(first["scans"])
    assert len(session.files) >= 2 + sum(len(c["scans"]) for c in doc["captures"])
    # The returns found lie on the mean scan's points.
    mean = mean_scan([read_scan(path.parent / f) for f in first["scans"]])
    pts = session.observations[0].points_laser
    d = np.min(np.linalg.norm(mean.points[mean.valid][:, None] - pts[None], axis=2), axis=0)
    assert d.max() < 1e-9


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d.update(schema_version=3), r"captures\[0\]\.scans: got .*; expected no such key"),
        (
            lambda d: d["captures"][0].update(scan="scans/cap00_00.yaml"),
            r"captures\[0\]: got \[.*\]; expected one of scan \(a file\) or scans",
        ),
        (
            lambda d: d["captures"][0].update(scans=[]),
            r"captures\[0\]\.scans: got \[\]; expected a non-empty list of scan files",
        ),
        (lambda d: d["captures"][0].update(scans=["scans/none.yaml"]), r"captures\[0\]\.scans\[0\]"),
    ],
)
def test_board_session_scans_errors(board_captured, tmp_path, edit, match):
    path = _copy(board_captured[0], tmp_path)
    d = yaml.safe_load(path.read_text())
    edit(d)
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=match):
        read_board_session(path)


def test_scans_of_another_scanner_in_one_capture_are_refused(board_captured, tmp_path):
    from rigcal.scan import read_scan, write_scan

    path = _copy(board_captured[0], tmp_path)
    d = yaml.safe_load(path.read_text())
    f = path.parent / d["captures"][0]["scans"][1]
    sc = read_scan(f)
    write_scan(
        f, Scan(sc.angles_rad[:-1], sc.ranges_m[:-1], sc.range_min_m, sc.range_max_m, sc.stamp_s), force=True
    )
    with pytest.raises(
        InputError, match=r"captures\[0\]\.scans\[1\]: got .*; expected a scan with the beams of"
    ):
        read_board_session(path)


def test_a_scan_change_counts_beams_that_change_together():
    """Noise and mixed pixels move beams one by one; what moves, moves neighbours together."""
    from rigcal.calib.capture import scan_change

    rng = np.random.default_rng(0)
    flat = np.full(1000, 2.0)
    a = Scan.from_uniform(-1.0, 0.002, flat, 0.1, 30.0)
    # Heavy-tailed noise (Student t, 4 dof, 1.4 cm scale) moves ~8 % of the beams by 5 cm.
    noisy = [
        Scan.from_uniform(-1.0, 0.002, flat + 0.014 * rng.standard_t(4, 1000), 0.1, 30.0) for _ in range(2)
    ]
    raw = np.mean(np.abs(noisy[0].ranges_m - noisy[1].ranges_m) > 0.05)
    assert raw > 0.05
    assert scan_change(noisy[0], noisy[1], 0.05) < 0.01
    # A board 30 beams wide moved by 20 cm: 3 % of the beams, every one counted.
    moved = flat.copy()
    moved[400:430] += 0.2
    assert scan_change(a, Scan.from_uniform(-1.0, 0.002, moved, 0.1, 30.0), 0.05) == pytest.approx(0.03)
