"""Finding the board in cluttered scans (laser_side: auto), board.size_m, several segments."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml

from rigcal.calib.board.detect import board_shape, line_candidates, plane_cut, static_returns
from rigcal.calib.board.session import read_board_session
from rigcal.calib.intrinsics import Board
from rigcal.errors import InputError
from rigcal.lines import LineParams, extract_lines
from rigcal.scan import Scan
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.noise import RealisticNoise
from rigcal.sim.raycast import cast_scan_hits

BOARD = Board(8, 6, 0.06)


@pytest.fixture(scope="module")
def sim():
    return generate_board_session(BoardSpec(n_captures=10, seed=4, noise=RealisticNoise()))


@pytest.fixture(scope="module")
def written(sim, tmp_path_factory) -> Path:
    return write_board_session(sim, tmp_path_factory.mktemp("clutter") / "session")


@pytest.fixture
def session(written, tmp_path) -> Path:
    folder = tmp_path / "session"
    shutil.copytree(written, folder)
    return folder / "board_session.yaml"


def to_auto(path: Path, count: int = 0) -> Path:
    path.write_text(
        re.sub(r"laser_side: \{segments?: [^}]*\}", "laser_side: auto", path.read_text(), count=count)
    )
    return path


def beams_of(scan: Scan, points: np.ndarray) -> np.ndarray:
    """The beam index of each of a scan's returns given as points."""
    return np.array([int(np.flatnonzero((scan.points == p).all(axis=1))[0]) for p in points])


def edit(path: Path, change) -> Path:
    doc = yaml.safe_load(path.read_text())
    change(doc)
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


# --- auto in clutter ---------------------------------------------------------------------------
def test_auto_finds_every_board_in_a_cluttered_room_and_never_the_background(sim, session):
    found = read_board_session(to_auto(session))
    for o, c in zip(found.observations, sim.captures, strict=True):
        beams = beams_of(c.scan, o.points_laser)
        assert np.isin(beams, c.board_beams).mean() >= 0.95, c.name
        valid_board = c.board_beams[c.scan.valid[c.board_beams]]
        assert np.isin(valid_board, beams).mean() >= 0.7, c.name
        # Never a return whose true ray hits the static scene.
        true_r = c.scan.ranges_m[beams]
        static_r, _ = cast_scan_hits(sim.static_scene, c.scan.angles_rad[beams], 30.0)
        assert not np.any(np.abs(true_r - static_r) < 0.03), c.name


def test_the_static_background_is_recognised(sim):
    scans = [c.scan for c in sim.captures]
    static = static_returns(scans)
    for c, st in zip(sim.captures, static, strict=True):
        board = c.board_beams[c.scan.valid[c.board_beams]]
        assert st[board].mean() < 0.05
        others = np.setdiff1d(np.flatnonzero(c.scan.valid), board)
        assert st[others].mean() > 0.8
    assert not any(s.any() for s in static_returns(scans[:4]))  # too few captures to tell


def test_auto_error_names_file_key_and_what_was_tried(sim, session):
    """A capture whose scan shows only the room (no board): auto does not take a piece of
    the background, it says what it tried."""
    to_auto(session, count=1)
    scan = session.parent / "scans" / "cap00.yaml"
    doc = yaml.safe_load(scan.read_text())
    angles = doc["angle_min_rad"] + doc["angle_increment_rad"] * np.arange(len(doc["ranges_m"]))
    ranges, _ = cast_scan_hits(sim.static_scene, angles, 30.0)
    doc["ranges_m"] = np.round(ranges + np.random.default_rng(0).normal(0, 0.01, len(ranges)), 4).tolist()
    scan.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError) as info:
        read_board_session(session)
    message = str(info.value)
    assert message.startswith(f"{session}: captures[0].laser_side: got 'auto'; expected the board's returns")
    # The shortest cut allowed is the printed pattern's (a sheet size never narrows it).
    assert "cut lengths 0.08-0.82 m allowed" in message
    seen, static = map(int, re.search(r"(\d+) line segments seen, (\d+) of them on static", message).groups())
    assert seen >= 10
    assert static == seen
    assert "\n" not in message


# --- board.size_m ------------------------------------------------------------------------------
def test_board_shape_from_size_and_from_pattern():
    pattern = board_shape(BOARD)
    assert pattern.max_cut_m == pytest.approx(np.hypot(0.54, 0.42))
    big = board_shape(BOARD, (0.8, 0.6))
    assert big.max_cut_m == pytest.approx(1.0)
    # The shortest cut stays the pattern's: a fifth of its smaller side (0.42 m).
    assert big.min_cut_m == pytest.approx(0.084)
    np.testing.assert_allclose(big.pattern_outline, pattern.outline)
    # The sheet is centred on the pattern.
    np.testing.assert_allclose(big.outline.mean(axis=0), [0.21, 0.15])
    np.testing.assert_allclose(np.ptp(big.outline, axis=0), [0.8, 0.6])


def test_a_board_larger_than_its_pattern_needs_size_m():
    """A straight 0.85 m cut is refused by the pattern's lengths and taken with size_m."""
    angles = np.radians(np.arange(-135, 135.01, 0.25))
    cut = np.array([[2.0, -0.425], [2.0, 0.425]])
    ranges, _ = cast_scan_hits(cut[None], angles, 30.0)
    scan = Scan.from_uniform(angles[0], np.radians(0.25), ranges, 0.1, 30.0)
    moving = scan.valid.copy()
    assert line_candidates(scan, moving, board_shape(BOARD), LineParams()) == []
    found = line_candidates(scan, moving, board_shape(BOARD, (0.9, 0.7)), LineParams())
    assert len(found) == 1
    assert len(found[0]) == scan.valid.sum()


def test_plane_cut_of_a_board_across_the_scan_plane():
    T = np.eye(4)
    T[:3, :3] = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])  # board facing -x
    T[:3, 3] = [2.0, 0.3, 0.2]
    cut = plane_cut(T, board_shape(BOARD, (0.8, 0.6)).outline)
    assert cut is not None
    np.testing.assert_allclose(sorted(cut[:, 1]), [0.3 - 0.21 - 0.4, 0.3 - 0.21 + 0.4], atol=1e-12)
    np.testing.assert_allclose(cut[:, 0], 2.0)
    T[:3, 3] = [2.0, 0.3, 5.0]  # far above the scan plane
    assert plane_cut(T, board_shape(BOARD).outline) is None


@pytest.mark.parametrize(
    ("value", "shown"),
    [([0.5, 0.6], "[0.5, 0.6]"), ([0.8], "[0.8]"), ("big", "'big'"), ([0.8, True], "[0.8, True]")],
)
def test_bad_size_m(session, value, shown):
    edit(session, lambda d: d["board"].update(size_m=value))
    with pytest.raises(InputError, match=re.escape(f"{session}: board.size_m: got {shown}; expected [width")):
        read_board_session(session)


def test_size_m_needs_schema_2(session):
    edit(session, lambda d: d.update(schema_version=1))
    with pytest.raises(
        InputError, match=re.escape(f"{session}: board.size_m: got [0.64, 0.52]; expected no size_m")
    ):
        read_board_session(session)


# --- several segments ---------------------------------------------------------------------------
def test_segments_give_the_returns_of_every_piece(sim, session):
    resolved = read_board_session(session)
    c = next(c for c in sim.captures if len(c.segment_ids) > 1)
    i = sim.captures.index(c)
    segments = extract_lines(c.scan, LineParams())
    want = np.concatenate([segments[k].points for k in c.segment_ids])
    np.testing.assert_array_equal(resolved.observations[i].points_laser, want)


@pytest.mark.parametrize(
    ("value", "key", "shown", "expected"),
    [
        ([], "segments", "[]", "a non-empty list of distinct segment ids"),
        ([1, 1], "segments", "[1, 1]", "a non-empty list of distinct segment ids"),
        ([0, 999], "segments[1]", "999", "a segment id from 0 to"),
        ([0, "x"], "segments[1]", "'x'", "a segment id from 0 to"),
    ],
)
def test_bad_segments(session, value, key, shown, expected):
    edit(session, lambda d: d["captures"][0].update(laser_side={"segments": value}))
    with pytest.raises(
        InputError,
        match=re.escape(f"{session}: captures[0].laser_side.{key}: got {shown}; expected {expected}"),
    ):
        read_board_session(session)


def test_segments_need_schema_2(session):
    def change(d):
        d["schema_version"] = 1
        del d["board"]["size_m"]
        d["captures"][0]["laser_side"] = {"segments": [0, 1]}

    edit(session, change)
    with pytest.raises(
        InputError, match=re.escape("captures[0].laser_side.segments: got [0, 1]; expected no segments")
    ):
        read_board_session(session)


def test_unknown_laser_side_form_lists_the_forms(session):
    edit(session, lambda d: d["captures"][0].update(laser_side={"segmnts": [1]}))
    with pytest.raises(
        InputError,
        match=re.escape("expected auto, {segment: ID}, {segments: [ID, ...]}, {points: [[x1, y1],")
        + ".* or {returns_file",
    ):
        read_board_session(session)


# --- the board's returns listed by another toolbox (laser_side: {returns_file: FILE}) ----------
def test_returns_listed_in_a_file_replace_the_scan(session):
    """A MATLAB toolbox's "points on the board" list (x y z per line, comments with %) gives
    the same observation as the segments it was taken from, with no scan needed."""
    given = read_board_session(session)

    def listed(d):
        for i, c in enumerate(d["captures"]):
            pts = given.observations[i].points_laser
            text = "% laser points on the board\n" + "".join(f"{x:.6f}, {y:.6f}, 0\n" for x, y in pts)
            (session.parent / f"target{i:02d}.txt").write_text(text)
            c["laser_side"] = {"returns_file": f"target{i:02d}.txt"}
            del c["scan"]

    listed_session = read_board_session(edit(session, listed))
    for a, b in zip(given.observations, listed_session.observations, strict=True):
        np.testing.assert_allclose(b.points_laser, a.points_laser, atol=1e-6)
    assert any(p.name == "target03.txt" for p in listed_session.files)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("1.0 2.0\n1.1 2.1 0.5\n", "line 2: got z = 0.5; expected 0"),
        ("1.0 2.0\nx 2.1\n", "line 2: got 'x 2.1'; expected x y [z]"),
        ("1.0 nan\n1.1 2.1\n", "line 1: got '1.0 nan'"),
        ("% only a comment\n1.0 2.0\n", "got 1 point(s); expected at least 2"),
        ("", "got an empty file"),
    ],
)
def test_bad_returns_files_name_the_line(session, text, message):
    (session.parent / "t.txt").write_text(text)
    edit(session, lambda d: d["captures"][0].update(laser_side={"returns_file": "t.txt"}))
    with pytest.raises(InputError, match=re.escape(message)):
        read_board_session(session)


def test_a_capture_without_scan_or_returns_file_is_refused(session):
    edit(session, lambda d: d["captures"][2].pop("scan"))
    with pytest.raises(InputError, match=re.escape("captures[2].scan: missing")):
        read_board_session(session)


def test_auto_needs_every_scan(session):
    given = read_board_session(session)

    def change(d):
        (session.parent / "t.txt").write_text(
            "".join(f"{x} {y}\n" for x, y in given.observations[0].points_laser)
        )
        d["captures"][0]["laser_side"] = {"returns_file": "t.txt"}
        del d["captures"][0]["scan"]
        d["captures"][1]["laser_side"] = "auto"

    with pytest.raises(InputError, match=re.escape("captures[0].scan: missing; laser_side auto")):
        read_board_session(edit(session, change))


def test_returns_file_needs_schema_2(session):
    def change(d):
        d["schema_version"] = 1
        d["board"].pop("size_m", None)
        d["captures"][0]["laser_side"] = {"returns_file": "t.txt"}

    with pytest.raises(InputError, match=re.escape("returns_file: got 't.txt'; expected no returns_file")):
        read_board_session(edit(session, change))
