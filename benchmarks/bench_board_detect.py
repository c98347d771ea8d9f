"""Finding the board in cluttered rooms (`laser_side: auto`): how often, and how fast.

Realistic simulated board sessions (``rigcal simulate board-session --noise realistic``:
Student-t range noise of 19.8 mm sd, mixed pixels at depth edges, grazing bias, dropouts,
a still rig in a room with static boxes, cabinets and poles, a board sheet 5 cm larger
than its pattern on every side), 28 captures of about 1000 beams each (a Hokuyo-like
270-degree scanner), several seeds and two amounts of clutter, and a 360-degree scanner
(the room all round, the seam behind it). Every capture's ``laser_side`` is set to
``auto`` and the session read with :func:`rigcal.calib.board.session.read_board_session`.

A capture is **correct** when at least 95 % of the chosen returns are returns whose true
ray hits the board and they hold at least half of the board's valid returns. A chosen
return is **background** when its range is within 3 cm of the static scene's at its beam
(a piece of wall or furniture). For reference, in the same run: the earlier detection
(line segments up to the printed pattern's diagonal, consensus over them, no background
test, no re-picking), and the time to read the same session with the segments given
(PnP and scans, no detection) as the unit of time.

    .venv/bin/python benchmarks/bench_board_detect.py
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.calib.board.detect import board_shape
from rigcal.calib.board.plane import choose_candidates
from rigcal.calib.board.session import read_board_session
from rigcal.errors import CalibrationError, InputError
from rigcal.lines import LineParams, extract_lines
from rigcal.sim.board_session import BoardSpec, SimBoardSession, generate_board_session, write_board_session
from rigcal.sim.noise import RealisticNoise
from rigcal.sim.raycast import cast_scan

ON_BOARD_SHARE = 0.95
COVERED_SHARE = 0.5
BACKGROUND_M = 0.03


def score(sim: SimBoardSession, points: list[np.ndarray]) -> tuple[int, int, int]:
    """(correct captures, captures with a background return, background returns)."""
    correct = with_bg = n_bg = 0
    for c, p in zip(sim.captures, points, strict=True):
        pts = c.scan.points
        beams = np.array([int(np.flatnonzero((pts == q).all(axis=1))[0]) for q in p], dtype=int)
        board = c.board_beams[c.scan.valid[c.board_beams]]
        on = np.isin(beams, board)
        if len(beams) and on.mean() >= ON_BOARD_SHARE and np.isin(board, beams).mean() >= COVERED_SHARE:
            correct += 1
        static = cast_scan(sim.static_scene, c.scan.angles_rad[beams], 30.0)
        bg = np.abs(c.scan.ranges_m[beams] - static) < BACKGROUND_M
        n_bg += int(bg.sum())
        with_bg += int(bg.any())
    return correct, with_bg, n_bg


def earlier_detection(
    sim: SimBoardSession, planes: list[tuple[np.ndarray, float]]
) -> list[np.ndarray] | None:
    """The detection before this one: segments no longer than the pattern's diagonal with a
    square's margin, the consensus picks one per capture; None when it gives up."""
    b = sim.spec.board
    shape = board_shape(b)
    cands = []
    for c in sim.captures:
        segs = [
            np.array(g.points)
            for g in extract_lines(c.scan, LineParams())
            if 0.2 * (b.width_n + 1) * b.spacing_m <= g.length_m <= shape.max_cut_m
        ]
        if not segs:
            return None
        cands.append(segs)
    try:
        chosen = choose_candidates(planes, cands)
    except CalibrationError:
        return None
    return [cands[i][k] for i, k in enumerate(chosen)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--captures", type=int, default=28)
    args = ap.parse_args()
    print(f"## Board detection in clutter: {args.seeds} seeds x {args.captures} captures per row\n")
    print(
        "| scanner | clutter objects | captures | auto correct | with background | background returns | "
        "auto s per session (median) | x reading with segments given | earlier detection correct |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for fov, step, n_clutter in ((270.0, 0.25, 10), (270.0, 0.25, 20), (360.0, 0.36, 20)):
            total = correct = with_bg = n_bg = old_correct = 0
            t_auto, t_given = [], []
            for seed in range(args.seeds):
                noise = RealisticNoise(n_clutter=n_clutter)
                spec = BoardSpec(
                    n_captures=args.captures, seed=seed, noise=noise, fov_deg=fov, angle_increment_deg=step
                )
                sim = generate_board_session(spec)
                folder = write_board_session(sim, Path(tmp) / f"s{fov:g}_{n_clutter}_{seed}")
                given = folder / "board_session.yaml"
                auto = folder / "auto.yaml"
                auto.write_text(
                    re.sub(r"laser_side: \{segments?: [^}]*\}", "laser_side: auto", given.read_text())
                )
                t0 = time.perf_counter()
                ref = read_board_session(given)
                t1 = time.perf_counter()
                try:
                    found = read_board_session(auto)
                    points = [o.points_laser for o in found.observations]
                except (InputError, CalibrationError):
                    points = [np.zeros((0, 2)) for _ in sim.captures]
                t2 = time.perf_counter()
                t_given.append(t1 - t0)
                t_auto.append(t2 - t1)
                k, w, n = score(sim, points)
                correct, with_bg, n_bg, total = correct + k, with_bg + w, n_bg + n, total + len(sim.captures)
                planes = [(o.normal_cam, o.distance_m) for o in ref.observations]
                old = earlier_detection(sim, planes)
                if old is not None:
                    old_correct += score(sim, old)[0]
            print(
                f"| {fov:g} deg, {len(sim.captures[0].scan.ranges_m)} beams | {n_clutter} | {total} | "
                f"{correct} ({100 * correct / total:.1f} %) | {with_bg} | {n_bg} | "
                f"{np.median(t_auto):.2f} | {np.median(np.array(t_auto) / np.array(t_given)):.1f} | "
                f"{old_correct} ({100 * old_correct / total:.1f} %) |"
            )


if __name__ == "__main__":
    main()
