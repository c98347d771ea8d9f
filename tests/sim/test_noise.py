"""The realistic scanner and room model (rigcal.sim.noise) and the simulators' realistic mode."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

from rigcal.arrays import MAD_TO_SIGMA
from rigcal.calib.board.session import read_board_session
from rigcal.calib.box.picks import read_picks
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.box_session import SessionSpec, generate_session, write_session
from rigcal.sim.noise import RealisticNoise, realistic_ranges
from rigcal.sim.raycast import cast_scan

WALL = np.array([[[3.0, -20.0], [3.0, 20.0]]])  # a wall 3 m ahead, across the beams


def _beams(n: int = 4000) -> np.ndarray:
    return np.linspace(-0.05, 0.05, n)


def test_range_noise_scatters_14_to_20_mm_with_heavy_tails():
    rng = np.random.default_rng(0)
    a = _beams()
    noise = RealisticNoise(dropout_fraction=0.0, incidence_bias_m=0.0)
    r, hit = realistic_ranges(rng, WALL, a, 30.0, noise)
    err = r - cast_scan(WALL, a, 30.0)
    robust = MAD_TO_SIGMA * np.median(np.abs(err - np.median(err)))
    assert 0.014 <= robust <= 0.020
    assert 0.014 <= noise.range_sigma_m <= 0.020
    # A Gaussian puts 0.006 % beyond 4 sigma; Student-t with 4 dof about 1 %.
    assert np.mean(np.abs(err) > 4 * robust) > 0.003
    assert (hit == 0).all()


def test_grazing_beams_read_long():
    rng = np.random.default_rng(1)
    wall = np.array([[[0.5, -1.0], [6.0, 4.5]]])  # seen at 45-80 deg incidence
    a = np.linspace(0.2, 0.55, 3000)
    noise = RealisticNoise(range_scale_m=0.0, dropout_fraction=0.0, mixed_pixel_fraction=0.0)
    r, _ = realistic_ranges(rng, wall, a, 30.0, noise)
    true = cast_scan(wall, a, 30.0)
    ok = r > 0
    assert np.all(r[ok] - true[ok] >= -1e-4)
    assert np.mean(r[ok] - true[ok]) > 0.003


def test_mixed_pixels_land_between_the_two_depths():
    scene = np.array([[[2.0, -0.3], [2.0, 0.3]], [[5.0, -5.0], [5.0, 5.0]]])
    a = np.linspace(-0.4, 0.4, 801)
    true = cast_scan(scene, a, 30.0)
    jumps = np.flatnonzero(np.abs(np.diff(true)) > 0.1)
    between = []
    for seed in range(20):
        noise = RealisticNoise(range_scale_m=0.0, dropout_fraction=0.0, incidence_bias_m=0.0)
        r, _ = realistic_ranges(np.random.default_rng(seed), scene, a, 30.0, noise)
        for j in jumps:
            lo, hi = sorted(true[j : j + 2])
            between += [x for x in r[j : j + 2] if lo + 0.05 < x < hi - 0.05]
    assert 8 <= len(between) <= 32  # about half of 40 edge pairs
    clean = RealisticNoise(
        range_scale_m=0.0, dropout_fraction=0.0, incidence_bias_m=0.0, mixed_pixel_fraction=0
    )
    r, _ = realistic_ranges(np.random.default_rng(0), scene, a, 30.0, clean)
    assert not np.any((r > 2.1) & (r < 4.9))


@pytest.mark.parametrize(
    ("field", "value"), [("range_dof", 2.0), ("mixed_pixel_fraction", 1.5), ("n_clutter", -1)]
)
def test_bad_parameters(field, value):
    with pytest.raises(ValueError, match=f"RealisticNoise: {field}"):
        RealisticNoise(**{field: value})


@pytest.fixture(scope="module")
def board_sim():
    return generate_board_session(BoardSpec(n_captures=8, seed=2, noise=RealisticNoise()))


def test_realistic_board_session_keeps_the_room_still(board_sim):
    """The background (walls and clutter) is the same in every capture: away from the
    boards, the beams hit the same static segment in every scan."""
    assert len(board_sim.static_scene) > 4 + 4 * 5  # walls and clutter
    hits = []
    for c in board_sim.captures:
        from rigcal.sim.raycast import cast_scan_hits

        hits.append(cast_scan_hits(board_sim.static_scene, c.scan.angles_rad, 30.0)[1])
    assert all((h == hits[0]).all() for h in hits)


def test_realistic_board_session_file_hides_the_noise(board_sim, tmp_path):
    folder = write_board_session(board_sim, tmp_path / "s")
    doc = yaml.safe_load((folder / "board_session.yaml").read_text())
    assert "range_sigma_m" not in doc["laser"]
    W, H = doc["board"]["size_m"]
    assert W > 9 * 0.06  # larger than the printed pattern
    assert H > 7 * 0.06
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    assert truth["generator"]["noise"]["model"] == "realistic"
    assert truth["generator"]["range_sigma_m"] == pytest.approx(RealisticNoise().range_sigma_m)
    session = read_board_session(folder / "board_session.yaml")
    # The listed segments hold the board's returns.
    for o, c in zip(session.observations, board_sim.captures, strict=True):
        pts = c.scan.points[c.board_beams]
        on = (o.points_laser[:, None, :] == pts[None]).all(axis=2).any(axis=1)
        assert on.mean() >= 0.8
    assert any(len(c.segment_ids) > 1 for c in board_sim.captures)  # a cut split into pieces


def test_realistic_box_session_reads_and_hides_the_noise(tmp_path):
    sim = generate_session(SessionSpec(n_captures=6, seed=3, noise=RealisticNoise()))
    folder = write_session(sim, tmp_path / "box", render_images=False)
    text = (folder / "picks.yaml").read_text()
    assert "range_sigma_m" not in yaml.safe_load(text)["laser"]
    assert "--noise realistic" in text
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    assert truth["generator"]["noise"]["n_clutter"] == RealisticNoise().n_clutter
    session = read_picks(folder / "picks.yaml")
    assert len(session.observations) == 6
    # The still rig: every capture has the same room pose.
    assert all(np.array_equal(c.room_pose, sim.captures[0].room_pose) for c in sim.captures)


def test_clean_mode_is_unchanged():
    """The default model draws as before (the figures in docs/benchmarks.md hold)."""
    a = generate_board_session(BoardSpec(n_captures=2, seed=11))
    b = generate_board_session(BoardSpec(n_captures=2, seed=11, noise=None))
    assert all(
        np.array_equal(x.scan.ranges_m, y.scan.ranges_m) for x, y in zip(a.captures, b.captures, strict=True)
    )
    assert len(a.static_scene) == 0
