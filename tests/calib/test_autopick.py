"""rigcal pick: box ends proposed through a pose and refined to the box's edges, on
rendered sessions with known true pixels; the picking file's schema 2; every error path."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.calib.box.autopick import PickSettings, auto_pick, pick_file_text
from rigcal.calib.box.picks import read_pick_draft, read_picks
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.sim.box_session import SessionSpec, generate_session, write_session
from rigcal.viz.contact_sheet import COLUMNS, TILE_W, SheetEntry, contact_sheet


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A rendered 8-capture session (seed 3) and its simulation (true pixels, true pose)."""
    sim = generate_session(SessionSpec(n_captures=8, seed=3))
    folder = write_session(sim, tmp_path_factory.mktemp("s") / "session")
    return sim, folder


def draft_file(folder: Path, sim, manual: int, exact: bool = True, drop_sides: bool = False) -> Path:
    """A schema-2 picking file: the first ``manual`` captures picked (true pixels when
    ``exact``, else the simulated user's), the others not."""
    doc = yaml.safe_load((folder / "picks.yaml").read_text())
    doc["schema_version"] = 2
    for i, c in enumerate(doc["captures"]):
        if i < manual:
            if exact:
                c["image_endpoints_px"] = sim.captures[i].true_pixels.tolist()
        else:
            del c["image_endpoints_px"]
            if drop_sides:
                del c["laser_side"]
    path = folder / f"draft{manual}{int(exact)}{int(drop_sides)}.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def errors_px(run, sim) -> np.ndarray:
    e = [
        np.linalg.norm(p.image_endpoints_px - c.true_pixels, axis=1)
        for p, c in zip(run.picks, sim.captures, strict=True)
        if p.source == "auto"
    ]
    return np.concatenate(e)


def test_true_pose_finds_the_edges_within_a_pixel(rendered):
    sim, folder = rendered
    run = auto_pick(read_pick_draft(draft_file(folder, sim, 3)), PickSettings(rounds=1), sim.T_cam_laser)
    e = errors_px(run, sim)
    assert run.seeded_from == "rig"
    assert np.mean(e < 1.0) >= 0.9
    assert e.max() < 3.5
    assert run.height_fraction == pytest.approx(0.5, abs=0.03)  # the box is centred on the laser plane


def test_three_manual_picks_suffice(rendered):
    sim, folder = rendered
    run = auto_pick(read_pick_draft(draft_file(folder, sim, 3)))
    assert run.seeded_from == "3 manual picks"
    e = errors_px(run, sim)
    assert np.mean(e < 1.0) >= 0.8
    confident = [p for p in run.picks if p.source == "auto" and not p.review]
    assert confident
    assert run.final is not None
    assert all(0.0 <= p.confidence <= 1.0 for p in run.picks)
    # Manual picks are kept as they were.
    np.testing.assert_allclose(run.picks[0].image_endpoints_px, sim.captures[0].true_pixels)


def test_box_side_found_by_its_width(rendered):
    sim, folder = rendered
    path = draft_file(folder, sim, 3, drop_sides=True)
    with pytest.raises(InputError, match=r"captures\[3\]\.laser_side: missing; give the box width"):
        auto_pick(read_pick_draft(path))
    run = auto_pick(read_pick_draft(path), PickSettings(box_width_m=0.6))
    for p, c in zip(run.picks[3:], sim.captures[3:], strict=True):
        assert p.laser_side == {"segment": c.segment_id}


def test_too_few_manual_picks_without_a_rig(rendered):
    sim, folder = rendered
    with pytest.raises(InputError, match=r"captures: 2 picked by hand; expected at least 3 .*--rig"):
        auto_pick(read_pick_draft(draft_file(folder, sim, 2)))


def test_written_file_round_trips_and_solves(rendered, tmp_path):
    sim, folder = rendered
    run = auto_pick(read_pick_draft(draft_file(folder, sim, 3, exact=False)))
    out = folder / "auto.yaml"
    out.write_text(pick_file_text(run, out))
    again = read_pick_draft(out)
    assert again.schema_version == 2
    assert [c.pick.source for c in again.captures if c.pick] == ["manual"] * 3 + ["auto"] * 5
    for p, c in zip(run.picks, again.captures, strict=True):
        np.testing.assert_allclose(c.image_endpoints_px, p.image_endpoints_px, atol=0.006)
        assert c.pick is not None
        assert c.pick.review == p.review
    assert len(read_picks(out).observations) == 8
    # Written elsewhere, the paths are relative to the new file.
    other = tmp_path / "sub" / "auto.yaml"
    other.parent.mkdir()
    other.write_text(pick_file_text(run, other))
    assert len(read_picks(other).observations) == 8


def test_contact_sheet_has_a_tile_per_capture(rendered):
    sim, folder = rendered
    entries = [
        SheetEntry(c.name, folder / "images" / f"{c.name}.png", c.true_pixels, None, "manual", i == 1, i == 0)
        for i, c in enumerate(sim.captures[:5])
    ]
    sheet = contact_sheet(entries)
    assert sheet.shape[1] == COLUMNS * TILE_W
    assert sheet.shape[0] > 2 * 240  # two rows of tiles
    assert sheet.dtype == np.uint8


def test_cli(rendered, tmp_path, capsys):
    sim, folder = rendered
    path = draft_file(folder, sim, 3)
    out, sheet = tmp_path / "auto.yaml", tmp_path / "sheet.png"
    assert main(["pick", str(path), "-o", str(out), "--sheet", str(sheet)]) == 0
    assert "5 captures picked automatically (pose from 3 manual picks)" in capsys.readouterr().out
    assert cv2.imread(str(sheet)).shape[1] == COLUMNS * TILE_W
    assert main(["pick", str(path), "-o", str(out)]) == 5
    assert main(["pick", str(draft_file(folder, sim, 1)), "-o", str(tmp_path / "x.yaml")]) == 3
    assert not (tmp_path / "x.yaml").exists()
    assert "Examples" in (main(["pick", "--help"]) == 0 and capsys.readouterr().out)


# --- schema 2 of the picking file ------------------------------------------------------------
@pytest.mark.parametrize(
    ("change", "key", "expected"),
    [
        ({"pick": {"source": "guess"}}, "captures[0].pick.source", "'manual' or 'auto'"),
        ({"pick": {"source": "auto", "confidence": 1.5}}, "captures[0].pick.confidence", "from 0 to 1"),
        ({"pick": {"source": "auto", "review": "yes"}}, "captures[0].pick.review", "true or false"),
        ({"pick": {"source": "auto", "colour": 1}}, "captures[0].pick.colour", "no such key"),
        ({"laser_side": None}, "captures[0].laser_side", "{segment: ID}, {segments: [ID, ...]}"),
    ],
)
def test_schema_2_errors(rendered, change, key, expected):
    sim, folder = rendered
    path = draft_file(folder, sim, 3)
    doc = yaml.safe_load(path.read_text())
    doc["captures"][0].update(change)
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=re.escape(f"{path}: {key}: got ") + ".*" + re.escape(expected)):
        read_pick_draft(path)


def test_schema_1_has_no_box_and_needs_every_pick(rendered):
    _sim, folder = rendered
    doc = yaml.safe_load((folder / "picks.yaml").read_text())
    doc["box"] = {"width_m": 0.6}
    path = folder / "v1.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"box: got .*; expected no such key in schema 1"):
        read_pick_draft(path)
    del doc["box"]
    del doc["captures"][1]["image_endpoints_px"]
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"captures\[1\]\.image_endpoints_px: missing"):
        read_pick_draft(path)


def test_box_size_must_be_positive(rendered):
    sim, folder = rendered
    path = draft_file(folder, sim, 3)
    doc = yaml.safe_load(path.read_text())
    doc["box"] = {"width_m": -1}
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match=r"box\.width_m: got -1; expected a finite number > 0"):
        read_pick_draft(path)


def test_a_side_that_is_not_found_leaves_the_capture_unpicked(rendered, tmp_path, capsys):
    sim, folder = rendered
    path = draft_file(folder, sim, 3, drop_sides=True)
    run = auto_pick(read_pick_draft(path), PickSettings(box_width_m=2.0))  # no 2 m segment
    unpicked = [p for p in run.picks if p.image_endpoints_px is None]
    assert len(unpicked) == 5
    assert all(p.review and "no segment of the box's width 2 m" in p.reasons[0] for p in unpicked)
    out = tmp_path / "auto.yaml"
    out.write_text(pick_file_text(run, out))
    assert read_pick_draft(out).captures[3].image_endpoints_px is None
    with pytest.raises(InputError, match=r"captures\[3\]\.laser_side: missing; .*rigcal pick"):
        read_picks(out)
    sheet = tmp_path / "sheet.png"
    argv = ["pick", str(path), "--box-width-m", "2", "-o", str(tmp_path / "a2.yaml"), "--sheet", str(sheet)]
    assert main(argv) == 0
    assert "not picked (pick by hand or remove): cap03" in capsys.readouterr().out
    assert cv2.imread(str(sheet)) is not None


def test_a_rig_that_puts_the_box_behind_the_camera_picks_nothing_and_says_so(rendered, tmp_path, capsys):
    from rigcal.geometry import make_T
    from rigcal.rig import Rig
    from rigcal.rigfile import write_rig

    sim, folder = rendered
    path = draft_file(folder, sim, 0)
    flipped = make_T(np.diag([-1.0, 1.0, -1.0]), np.zeros(3)) @ sim.T_cam_laser  # turned 180 deg about y
    write_rig(tmp_path / "behind.yaml", Rig(T_cam_laser=flipped, camera=sim.camera))
    out, sheet = tmp_path / "auto.yaml", tmp_path / "sheet.png"
    argv = ["pick", str(path), "--rig", str(tmp_path / "behind.yaml"), "-o", str(out), "--sheet", str(sheet)]
    assert main(argv) == 4
    captured = capsys.readouterr()
    assert "picked automatically" not in captured.out
    assert f"Error: {path}: no capture could be picked (8 captures): with the pose from rig" in captured.err
    assert not out.exists()
    assert not sheet.exists()


def test_no_contact_sheet_is_left_when_the_picks_cannot_be_written(rendered, tmp_path, capsys):
    sim, folder = rendered
    path = draft_file(folder, sim, 3)
    (tmp_path / "a-file").write_text("x")
    sheet = tmp_path / "sheet.png"
    argv = ["pick", str(path), "-o", str(tmp_path / "a-file" / "auto.yaml"), "--sheet", str(sheet)]
    assert main(argv) == 5
    assert "a-file is a file; expected a folder to write into" in capsys.readouterr().err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a-file"]
