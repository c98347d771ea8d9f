"""Picking files: resolving captures into box observations, and every way read_picks rejects a file."""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from rigcal.calib.box.picks import read_picks
from rigcal.errors import InputError
from rigcal.lines import extract_lines
from rigcal.scan import read_scan

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "box-session"


@pytest.fixture
def session(tmp_path) -> Path:
    """A writable copy of the example session; returns its picking file."""
    folder = tmp_path / "session"
    shutil.copytree(EXAMPLE, folder)
    return folder / "picks.yaml"


def load(picks: Path) -> dict[str, Any]:
    return yaml.safe_load(picks.read_text())


def save(picks: Path, doc: Any) -> Path:
    picks.write_text(yaml.safe_dump(doc, sort_keys=False))
    return picks


def edit_capture(picks: Path, i: int, **changes: Any) -> Path:
    doc = load(picks)
    doc["captures"][i].update(changes)
    return save(picks, doc)


def expect_error(picks: Path, key: str, shown: str) -> str:
    """read_picks fails with one line ``FILE: KEY: got SHOWN; ...``; returns the message."""
    with pytest.raises(InputError, match=re.escape(f"{picks}: {key}: got {shown};")) as exc:
        read_picks(picks)
    message = str(exc.value)
    assert "\n" not in message
    return message


# --- a valid file ------------------------------------------------------------------------------
def test_example_session_resolves_every_capture(session):
    s = read_picks(session)
    assert len(s.observations) == 20
    assert [o.name for o in s.observations] == [f"cap{i:02d}" for i in range(20)]
    assert [o.capture for o in s.observations] == list(range(20))
    assert s.camera.width_px == 640
    assert s.camera_path == session.parent / "camera.yaml"
    assert s.laser["angle_increment_deg"] == 0.25
    assert len(s.input_files()) == 2 + 2 * 20


def test_paths_resolve_relative_to_the_picking_file(session, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    o = read_picks(session).observations[3]
    assert o.scan_path == session.parent / "scans" / "cap03.yaml"
    assert o.image_path == session.parent / "images" / "cap03.png"
    assert o.scan_path.is_absolute()


def test_image_pixels_are_the_picked_ones_in_file_order(session):
    o = read_picks(session).observations[0]
    np.testing.assert_array_equal(o.image_endpoints_px, [[613.1, 242.6], [375.1, 235.7]])


def test_laser_end_zero_is_at_the_smaller_beam_angle_just_outside_the_side(session):
    o = read_picks(session).observations[0]
    scan = read_scan(o.scan_path)
    step = o.beam_step_rad
    assert step == pytest.approx(scan.angle_increment_rad, rel=1e-9)
    a = np.arctan2(o.laser_endpoints[:, 1], o.laser_endpoints[:, 0])
    first, last = scan.angles_rad[o.side_beams[0]], scan.angles_rad[o.side_beams[-1]]
    assert a[0] < a[1]
    # Each end sits at or beyond the outermost return of its side, by at most a few beam steps.
    assert first - 3 * step <= a[0] <= first + 1e-9
    assert last - 1e-9 <= a[1] <= last + 3 * step


def test_side_points_are_the_chosen_segment_returns(session):
    o = read_picks(session).observations[0]
    scan = read_scan(o.scan_path)
    seg = extract_lines(scan)[2]
    np.testing.assert_array_equal(o.side_beams, seg.indices)
    np.testing.assert_array_equal(o.side_points, scan.points[o.side_beams])
    assert o.side_points.shape == (len(o.side_beams), 2)
    assert len(o.side_beams) > 20
    assert np.all(np.diff(o.side_beams) > 0)


def test_side_points_lie_on_the_line_through_the_laser_ends(session):
    o = read_picks(session).observations[0]
    u = (o.laser_endpoints[1] - o.laser_endpoints[0]) / np.linalg.norm(
        o.laser_endpoints[1] - o.laser_endpoints[0]
    )
    n = np.array([-u[1], u[0]])
    assert np.abs((o.side_points - o.laser_endpoints[0]) @ n).max() < 0.03


def test_points_form_keeps_the_given_ends_and_finds_the_side_returns(session):
    seg = read_picks(session).observations[0]
    ends = [[round(float(x), 4) for x in p] for p in seg.laser_endpoints]
    edit_capture(session, 0, laser_side={"points": ends})
    o = read_picks(session).observations[0]
    np.testing.assert_array_equal(o.laser_endpoints, ends)
    assert set(o.side_beams) <= set(seg.side_beams) | {seg.side_beams[0] - 1, seg.side_beams[-1] + 1}
    assert len(o.side_beams) >= len(seg.side_beams) - 2
    scan = read_scan(o.scan_path)
    np.testing.assert_array_equal(o.side_points, scan.points[o.side_beams])


def test_points_form_in_reverse_beam_order_still_puts_end_zero_at_the_smaller_angle(session):
    seg = read_picks(session).observations[0]
    ends = [[round(float(x), 4) for x in p] for p in seg.laser_endpoints[::-1]]
    edit_capture(session, 0, laser_side={"points": ends})
    o = read_picks(session).observations[0]
    np.testing.assert_array_equal(o.laser_endpoints, ends[::-1])
    assert o.side_beams[0] < o.side_beams[-1]


def test_points_form_away_from_any_return_is_refused(session):
    edit_capture(session, 0, laser_side={"points": [[0.5, 5.0], [0.5, 5.5]]})
    with pytest.raises(
        InputError, match=r"captures\[0\]\.laser_side\.points: got .*fewer than 2 valid returns"
    ):
        read_picks(session)


def test_image_of_another_size_is_refused(session):
    import cv2

    img = cv2.imread(str(session.parent / "images" / "cap01.png"))
    cv2.imwrite(str(session.parent / "images" / "cap01.png"), cv2.resize(img, (320, 240)))
    with pytest.raises(
        InputError, match=r"captures\[1\]\.image: got 'images/cap01.png'.*640x480, not 320x240"
    ):
        read_picks(session)


def test_unreadable_image_is_refused(session):
    (session.parent / "images" / "cap02.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match=r"captures\[2\]\.image: got 'images/cap02.png'.*OpenCV can read"):
        read_picks(session)


def test_capture_names_default_to_their_index(session):
    doc = load(session)
    for c in doc["captures"]:
        del c["name"]
    save(session, doc)
    assert [o.name for o in read_picks(session).observations][:3] == ["capture00", "capture01", "capture02"]


def test_scan_with_nan_ranges_still_loads(session):
    scan_file = session.parent / "scans" / "cap00.yaml"
    doc = yaml.safe_load(scan_file.read_text())
    doc["ranges_m"][470] = float("nan")
    doc["ranges_m"][0] = float("nan")
    scan_file.write_text(yaml.safe_dump(doc))
    o = read_picks(session).observations[0]
    assert 470 not in o.side_beams
    assert 469 in o.side_beams
    assert np.isfinite(o.side_points).all()
    assert np.isfinite(o.laser_endpoints).all()


def test_laser_block_is_optional(session):
    doc = load(session)
    del doc["laser"]
    assert read_picks(save(session, doc)).laser == {}


# --- the file itself ---------------------------------------------------------------------------
def test_missing_picking_file(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(InputError, match=re.escape(f"{path}: picking file not found")):
        read_picks(path)


def test_malformed_yaml_names_the_line(session):
    session.write_text("schema_version: 1\ncamera: camera.yaml\ncaptures: [\n  {scan: a\n")
    with pytest.raises(
        InputError, match=rf"{re.escape(str(session))}: not valid YAML at line \d+, column \d+"
    ):
        read_picks(session)


def test_malformed_yaml_reports_the_offending_line(session):
    session.write_text("schema_version: 1\ncamera: camera.yaml\n  captures: x\n")
    with pytest.raises(InputError, match="at line 3"):
        read_picks(session)


@pytest.mark.parametrize(("text", "shown"), [("- a\n- b\n", "['a', 'b']"), ("42\n", "42"), ("", "None")])
def test_top_level_not_a_mapping(session, text, shown):
    session.write_text(text)
    expect_error(session, r"(top level)", shown)


def test_unknown_top_level_key(session):
    doc = load(session)
    doc["cameras"] = "camera.yaml"
    message = expect_error(save(session, doc), "cameras", "'camera.yaml'")
    assert "no such key" in message


def test_unknown_key_inside_a_capture(session):
    message = expect_error(edit_capture(session, 4, segment=3), "captures[4].segment", "3")
    assert "no such key" in message


@pytest.mark.parametrize("key", ["schema_version", "camera", "captures"])
def test_missing_top_level_key(session, key):
    doc = load(session)
    del doc[key]
    with pytest.raises(InputError, match=re.escape(f"{session}: {key}: missing")):
        read_picks(save(session, doc))


@pytest.mark.parametrize("key", ["scan", "image", "laser_side", "image_endpoints_px"])
def test_missing_capture_key(session, key):
    doc = load(session)
    del doc["captures"][2][key]
    with pytest.raises(InputError, match=re.escape(f"{session}: captures[2].{key}: missing")):
        read_picks(save(session, doc))


@pytest.mark.parametrize(("version", "shown"), [(3, "3"), ("1", "'1'"), (None, "None"), (True, "True")])
def test_wrong_schema_version(session, version, shown):
    doc = load(session)
    doc["schema_version"] = version
    expect_error(save(session, doc), "schema_version", shown)


# --- files it names ----------------------------------------------------------------------------
def test_camera_file_missing(session):
    (session.parent / "camera.yaml").unlink()
    message = expect_error(session, "camera", "'camera.yaml'")
    assert "an existing file" in message


def test_camera_not_a_path(session):
    doc = load(session)
    doc["camera"] = 7
    expect_error(save(session, doc), "camera", "7")


def test_invalid_camera_file_is_named(session):
    cam = session.parent / "camera.yaml"
    cam.write_text(cam.read_text().replace("image_width_px: 640", "image_width_px: 0"))
    with pytest.raises(InputError, match=re.escape(f"{cam}: image_width_px: got 0;")):
        read_picks(session)


def test_scan_file_missing(session):
    (session.parent / "scans" / "cap05.yaml").unlink()
    expect_error(session, "captures[5].scan", "'scans/cap05.yaml'")


def test_image_file_missing(session):
    (session.parent / "images" / "cap07.png").unlink()
    expect_error(session, "captures[7].image", "'images/cap07.png'")


def test_scan_path_that_is_a_folder(session):
    expect_error(edit_capture(session, 1, scan="scans"), "captures[1].scan", "'scans'")


# --- captures ------------------------------------------------------------------------------------
@pytest.mark.parametrize(("captures", "shown"), [([], "[]"), (None, "None"), ("cap00", "'cap00'")])
def test_captures_not_a_non_empty_list(session, captures, shown):
    doc = load(session)
    doc["captures"] = captures
    expect_error(save(session, doc), "captures", shown)


def test_capture_not_a_mapping(session):
    doc = load(session)
    doc["captures"][3] = "scans/cap03.yaml"
    expect_error(save(session, doc), "captures[3]", "'scans/cap03.yaml'")


@pytest.mark.parametrize(("name", "shown"), [("", "''"), (5, "5")])
def test_capture_name_not_a_non_empty_string(session, name, shown):
    expect_error(edit_capture(session, 2, name=name), "captures[2].name", shown)


def test_duplicate_capture_names(session):
    message = expect_error(edit_capture(session, 6, name="cap02"), "captures[6].name", "'cap02'")
    assert "not used by another capture" in message


@pytest.mark.parametrize(
    ("sid", "shown"), [(999, "999"), (-1, "-1"), (True, "True"), ("2", "'2'"), (2.0, "2.0")]
)
def test_bad_segment_id(session, sid, shown):
    message = expect_error(
        edit_capture(session, 3, laser_side={"segment": sid}), "captures[3].laser_side.segment", shown
    )
    assert "a segment id from 0 to" in message
    assert "cap03.yaml" in message


def test_segment_id_one_past_the_last(session):
    n = len(extract_lines(read_scan(session.parent / "scans" / "cap03.yaml")))
    edit_capture(session, 3, laser_side={"segment": n})
    message = expect_error(session, "captures[3].laser_side.segment", str(n))
    assert f"from 0 to {n - 1}" in message


@pytest.mark.parametrize(
    ("side", "shown"),
    [
        (
            {"segment": 2, "points": [[1.0, 0.0], [1.0, 1.0]]},
            "{'segment': 2, 'points': [[1.0, 0.0], [1.0, 1.0]]}",
        ),
        ({}, "{}"),
        ({"lines": [2]}, "{'lines': [2]}"),
        (2, "2"),
        ([[1.0, 0.0], [1.0, 1.0]], "[[1.0, 0.0], [1.0, 1.0]]"),
    ],
)
def test_laser_side_needs_exactly_one_form(session, side, shown):
    message = expect_error(edit_capture(session, 1, laser_side=side), "captures[1].laser_side", shown)
    assert "{segment: ID}, {segments: [ID, ...]} or {points:" in message


def test_laser_points_too_close(session):
    edit_capture(session, 1, laser_side={"points": [[1.0, 0.5], [1.0, 0.52]]})
    message = expect_error(session, "captures[1].laser_side.points", "[[1.0, 0.5], [1.0, 0.52]]")
    assert "5 cm" in message


@pytest.mark.parametrize(
    ("points", "shown"),
    [
        ([[1.0, 0.5]], "[[1.0, 0.5]]"),
        ([[1.0, 0.5], [1.0, "x"]], "[[1.0, 0.5], [1.0, 'x']]"),
        ([[1.0, 0.5], [1.0, float("nan")]], "[[1.0, 0.5], [1.0, nan]]"),
    ],
)
def test_laser_points_not_two_finite_pairs(session, points, shown):
    edit_capture(session, 1, laser_side={"points": points})
    expect_error(session, "captures[1].laser_side.points", shown)


@pytest.mark.parametrize(
    ("px", "shown"),
    [
        ([[613.1, 242.6]], "[[613.1, 242.6]]"),
        ([[613.1, 242.6], [375.1, 235.7], [1.0, 2.0]], "[[613.1, 242.6], [375.1, 235.7], [1.0, 2.0]]"),
        ([[613.1, 242.6, 1.0], [375.1, 235.7]], "[[613.1, 242.6, 1.0], [375.1, 235.7]]"),
        ([613.1, 242.6], "[613.1, 242.6]"),
        ("613,242", "'613,242'"),
        ([[613.1, float("nan")], [375.1, 235.7]], "[[613.1, nan], [375.1, 235.7]]"),
        ([[613.1, float("inf")], [375.1, 235.7]], "[[613.1, inf], [375.1, 235.7]]"),
        ([[613.1, "242.6"], [375.1, 235.7]], "[[613.1, '242.6'], [375.1, 235.7]]"),
        ([[613.1, True], [375.1, 235.7]], "[[613.1, True], [375.1, 235.7]]"),
    ],
)
def test_image_endpoints_not_two_finite_pairs(session, px, shown):
    edit_capture(session, 8, image_endpoints_px=px)
    message = expect_error(session, "captures[8].image_endpoints_px", shown)
    assert "two pixel pairs" in message


@pytest.mark.parametrize(
    ("j", "pixel"),
    [(0, [640.0, 200.0]), (1, [100.0, -0.6]), (1, [100.0, 479.6]), (0, [-1.0, 100.0])],
)
def test_pick_outside_the_image(session, j, pixel):
    px = [[300.0, 200.0], [400.0, 210.0]]
    px[j] = pixel
    edit_capture(session, 9, image_endpoints_px=px)
    message = expect_error(session, f"captures[9].image_endpoints_px[{j}]", repr(pixel))
    assert "640x480" in message


def test_pick_on_the_image_edge_is_inside(session):
    edit_capture(session, 9, image_endpoints_px=[[-0.5, -0.5], [639.5, 479.5]])
    np.testing.assert_array_equal(
        read_picks(session).observations[9].image_endpoints_px, [[-0.5, -0.5], [639.5, 479.5]]
    )


def test_two_equal_picks(session):
    edit_capture(session, 10, image_endpoints_px=[[300.0, 200.0], [300.0, 200.0]])
    message = expect_error(session, "captures[10].image_endpoints_px", "[[300.0, 200.0], [300.0, 200.0]]")
    assert "two distinct box ends" in message


@pytest.mark.parametrize(("laser", "shown"), [("hokuyo", "'hokuyo'"), ([1, 2], "[1, 2]"), (None, "None")])
def test_laser_block_not_a_mapping(session, laser, shown):
    doc = load(session)
    doc["laser"] = laser
    expect_error(save(session, doc), "laser", shown)


def test_first_bad_capture_is_the_one_reported(session):
    doc = load(session)
    doc["captures"][12]["laser_side"] = {"segment": 50}
    doc["captures"][15]["laser_side"] = {"segment": 60}
    expect_error(save(session, doc), "captures[12].laser_side.segment", "50")


def test_laser_range_noise_sets_the_line_thresholds(session):
    from rigcal.calib.box.picks import line_params_for
    from rigcal.lines import LineParams

    assert line_params_for(session, {}) == LineParams()
    assert line_params_for(session, {"range_sigma_m": 0.02}) == LineParams.for_range_noise(0.02)
    doc = load(session)
    doc["laser"]["range_sigma_m"] = "1 cm"
    save(session, doc)
    expect_error(session, "laser.range_sigma_m", "'1 cm'")


# --- a box side split into pieces: laser_side {segments: [...]} (schema 2) ---------------------
def split_side(session: Path) -> tuple[list[int], np.ndarray]:
    """Push four returns in the middle of cap00's box side 20 cm back (a gap in the side, as
    a sticker or a handle makes), so line extraction splits it; returns the ids of the two
    pieces and the side's beams before the split."""
    from rigcal.scan import Scan, write_scan

    scan_path = session.parent / "scans" / "cap00.yaml"
    scan = read_scan(scan_path)
    beams = np.array(extract_lines(scan)[2].indices)
    mid = beams[len(beams) // 2 - 2 : len(beams) // 2 + 2]
    ranges = scan.ranges_m.copy()
    ranges[mid] += 0.2
    step = scan.angle_increment_rad
    assert step is not None
    write_scan(
        scan_path,
        Scan.from_uniform(scan.angles_rad[0], step, ranges, scan.range_min_m, scan.range_max_m),
        force=True,
    )
    # The pushed-back returns make a piece of their own, off the side: not one of the side's.
    pieces = [
        s.id
        for s in extract_lines(read_scan(scan_path))
        if np.isin(s.indices, beams).all() and not np.isin(s.indices, mid).any()
    ]
    assert len(pieces) == 2
    return pieces, beams


def test_segments_join_a_split_box_side(session):
    whole = read_picks(session).observations[0]
    pieces, beams = split_side(session)
    doc = load(session)
    doc["schema_version"] = 2
    doc["captures"][0]["laser_side"] = {"segments": pieces[::-1]}
    o = read_picks(save(session, doc)).observations[0]
    assert set(o.side_beams) <= set(beams)
    assert len(o.side_beams) >= 0.85 * len(beams)
    assert np.all(np.diff(o.side_beams) > 0)
    np.testing.assert_allclose(o.laser_endpoints, whole.laser_endpoints, atol=0.01)


@pytest.mark.parametrize(
    ("version", "segments", "key", "shown"),
    [
        (1, [2], "captures[0].laser_side.segments", "[2]"),
        (2, [], "captures[0].laser_side.segments", "[]"),
        (2, [2, 2], "captures[0].laser_side.segments", "[2, 2]"),
        (2, 3, "captures[0].laser_side.segments", "3"),
        (2, [2, 99], "captures[0].laser_side.segments[1]", "99"),
    ],
)
def test_bad_segments_are_named(session, version, segments, key, shown):
    doc = load(session)
    doc["schema_version"] = version
    doc["captures"][0]["laser_side"] = {"segments": segments}
    expect_error(save(session, doc), key, shown)
