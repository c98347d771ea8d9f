"""Board poses captured more than once (BoardSpec.repeats), and their verdicts."""

from __future__ import annotations

import numpy as np

from rigcal.calib.board.plane import solve_plane
from rigcal.sim.board_session import BoardSpec, T_cam_board, generate_board_session


def test_repeats_share_the_pose_with_fresh_noise():
    sim = generate_board_session(BoardSpec(n_captures=3, repeats=2, seed=4))
    caps = sim.captures
    assert [c.name for c in caps] == [f"cap{i:02d}" for i in range(6)]
    for a, b in zip(caps[::2], caps[1::2], strict=True):
        np.testing.assert_array_equal(a.T_laser_board, b.T_laser_board)
        assert not np.array_equal(a.corners_px, b.corners_px)
        assert not np.array_equal(a.scan.ranges_m, b.scan.ranges_m)
    assert not np.array_equal(caps[0].T_laser_board, caps[2].T_laser_board)
    np.testing.assert_allclose(T_cam_board(sim, caps[0]), sim.T_cam_laser @ caps[0].T_laser_board)


def test_one_repeat_is_the_session_of_old():
    """repeats=1 draws exactly what the simulator drew before it had repeats."""
    a = generate_board_session(BoardSpec(n_captures=4, seed=9))
    b = generate_board_session(BoardSpec(n_captures=4, seed=9, repeats=1))
    for x, y in zip(a.captures, b.captures, strict=True):
        np.testing.assert_array_equal(x.scan.ranges_m, y.scan.ranges_m)
        np.testing.assert_array_equal(x.corners_px, y.corners_px)


def test_repeated_captures_get_one_verdict_in_a_solve():
    from rigcal.calib.board.session import board_pose, plane_observation
    from rigcal.lines import extract_lines

    sim = generate_board_session(BoardSpec(n_captures=8, repeats=2, seed=3))
    obs = []
    for i, c in enumerate(sim.captures):
        T, cov, _ = board_pose(sim.camera, sim.spec.board, c.corners_px, 0.3)
        seg = next(s for s in extract_lines(c.scan) if s.id == c.segment_id)
        obs.append(plane_observation(i, c.name, T, cov, np.array(seg.points)))
    res = solve_plane(obs, None)
    groups = res.pose_group.reshape(-1, 2)
    assert (groups[:, 0] == groups[:, 1]).all()
    v = res.inlier_captures.reshape(-1, 2)
    assert (v[:, 0] == v[:, 1]).all()


def test_handheld_repeats_are_near_but_not_at_the_pose():
    """BoardSpec.handheld: each repeat after the first is turned 1-3 deg about the board's
    centre and moved 2-5 cm (the centre itself moves by the shift alone)."""
    from rigcal.geometry import inv_T

    spec = BoardSpec(n_captures=4, repeats=3, seed=6, handheld=True)
    sim = generate_board_session(spec)
    b = spec.board
    centre = np.array([0.5 * (b.width_n - 1) * b.spacing_m, 0.5 * (b.height_n - 1) * b.spacing_m, 0.0, 1.0])
    for k in range(4):
        first = sim.captures[3 * k]
        for c in sim.captures[3 * k + 1 : 3 * k + 3]:
            D = inv_T(first.T_laser_board) @ c.T_laser_board
            angle = np.degrees(np.arccos(np.clip((np.trace(D[:3, :3]) - 1) / 2, -1, 1)))
            assert 1.0 - 1e-9 <= angle <= 3.0 + 1e-9
            moved = np.linalg.norm((c.T_laser_board @ centre - first.T_laser_board @ centre)[:3])
            assert 0.02 - 1e-9 <= moved <= 0.05 + 1e-9
