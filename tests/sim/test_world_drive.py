"""Simulated worlds and drives: world files, the loop's geometry, scans against the truth."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.io.trajectory import read_tum
from rigcal.recordings.sequence import read_sequence
from rigcal.sim.drive import DriveSpec, Motion, laser_stamps, simulate_scans
from rigcal.sim.world import BUILTIN, read_world


@pytest.mark.parametrize(("name", "length"), [("corridor-loop", 60.0), ("cubicle-loop", 35.0)])
def test_builtin_loops_have_the_papers_lengths(name, length):
    assert BUILTIN[name]().path_length_m == pytest.approx(length, rel=0.01)


def test_a_lap_closes_and_turns_once():
    w = BUILTIN["corridor-loop"]()
    m = Motion(w, DriveSpec())
    p = m.poses(np.array([0.0, m.duration_s]))
    assert np.linalg.norm(p[1, :2] - p[0, :2]) < 0.05
    assert p[1, 2] - p[0, 2] == pytest.approx(2 * np.pi, abs=0.05)
    # Walking speed, slower in turns, with stops: the lap takes longer than length / speed.
    assert m.duration_s > w.path_length_m / DriveSpec().speed_mps


def test_two_laps_drive_the_loop_twice_and_revisit_every_place():
    w = BUILTIN["cubicle-loop"]()
    one, two = Motion(w, DriveSpec(stops=0)), Motion(w, DriveSpec(stops=0, laps=2))
    assert two.duration_s == pytest.approx(2 * one.duration_s, rel=1e-3)
    t = np.linspace(0.0, one.duration_s - 0.5, 50)  # the seam moves the last samples by millimetres
    first, second = two.poses(t), two.poses(t + one.duration_s)
    np.testing.assert_allclose(second[:, :2], first[:, :2], atol=0.01)
    np.testing.assert_allclose(second[:, 2] - first[:, 2], 2 * np.pi, atol=0.01)
    np.testing.assert_allclose(first, one.poses(t), atol=1e-9)
    with pytest.raises(InputError, match="laps: got 0; expected a whole number of laps"):
        DriveSpec(laps=0)


def test_noiseless_scans_lie_on_the_worlds_walls():
    w = BUILTIN["cubicle-loop"]()
    spec = DriveSpec(range_sigma_m=0.0, dropout_fraction=0.0)
    m = Motion(w, spec)
    stamps = laser_stamps(m, spec)[::200]
    poses = m.poses(stamps)
    segs = w.scan_segments()
    for scan, (x, y, yaw) in zip(simulate_scans(w, poses, stamps, spec), poses, strict=True):
        pts = scan.points[scan.valid]
        c, s = np.cos(yaw), np.sin(yaw)
        world_pts = pts @ np.array([[c, -s], [s, c]]).T + [x, y]
        d = np.min([_dist_to_segment(world_pts, a, b) for a, b in segs], axis=0)
        assert d.max() < 1e-3  # ranges are kept to 0.1 mm


def _dist_to_segment(p, a, b):
    u = b - a
    t = np.clip((p - a) @ u / (u @ u), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * u), axis=1)


def test_world_file_round_trip_and_errors(tmp_path):
    doc = {
        "schema_version": 1,
        "name": "box room",
        "laser_height_m": 0.3,
        "walls": [{"from": [0, 0], "to": [4, 0], "texture": "bricks"}, {"from": [4, 0], "to": [4, 3]}],
        "obstacles": [{"polygon": [[2.5, 1.5], [3, 1.5], [3, 2]], "height_m": 1.0}],
        "path": [[0.5, 0.5], [3.5, 0.5], [3.5, 2.5]],
    }
    f = tmp_path / "w.yaml"
    f.write_text(yaml.safe_dump(doc))
    w = read_world(f)
    assert len(w.surfaces) == 5
    assert w.laser_height_m == 0.3
    assert len(w.scan_segments()) == 5
    bad = [
        ({"walls": [{"from": [0, 0], "to": [0, 0]}]}, r"walls\[0\]: got .*non-zero length"),
        ({"walls": [{"from": [0, 0], "to": [1, "a"]}]}, r"walls\[0\]\.to: got \[1, 'a'\]"),
        ({"walls": [{"from": [0, 0], "to": [1, 0], "texture": "gold"}]}, r"walls\[0\]\.texture: got 'gold'"),
        ({"path": [[0, 0]]}, r"path: got .*at least 3 points"),
        ({"path": [[0.5, 0.5], [0.5, 0.5], [3.5, 2.5]]}, r"path\[1\]: got .*; expected a point at"),
        ({"path": [[0.5, 0.5], [3.5, 0.5], [0.5, 0.7]]}, r"path\[1\]: got .*less than 150 deg"),
        ({"path": [[0.5, 0.5], [4.5, 0.5], [3.5, 2.5]]}, r"path\[1\]: got .*clear of walls and obstacles"),
        ({"path": [[0.5, 0.5], [3.5, 0.5], [1e300, 2.5]]}, r"path\[2\]: got .*within 100 km"),
        ({"roof": 1}, r"roof: got 1; expected no such key"),
        ({"schema_version": 2}, r"schema_version: got 2"),
    ]
    for change, match in bad:
        f.write_text(yaml.safe_dump(doc | change))
        with pytest.raises(InputError, match=match):
            read_world(f)


def test_cli_writes_a_sequence_with_truth_and_rig(tmp_path, capsys):
    out = tmp_path / "seq"
    args = [
        "simulate",
        "world",
        "--world",
        "cubicle-loop",
        "-o",
        str(out),
        "--laser-rate-hz",
        "5",
        "--no-images",
    ]
    assert main(args) == 0
    seq = read_sequence(out)
    truth = read_tum(out / "groundtruth.tum")
    assert len(seq.scans) == len(truth) > 100
    np.testing.assert_allclose([s.stamp_s for s in seq.scans], truth.stamps_s)
    assert (out / "rig.yaml").is_file()
    assert main(["simulate", "world", "-o", str(out)]) == 5
    assert main(["simulate", "world", "--world", "moon", "-o", str(tmp_path / "x")]) == 2
