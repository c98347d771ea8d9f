"""Auto's returns on a hand-held board (``laser_side: auto``): how many returns off the
board it takes, how much of the board it keeps, and the answer with and without
``board.size_m``.

Sessions from the realistic simulator (``rigcal.sim.noise``: Student-t range noise of about
20 mm sd, mixed pixels, grazing bias, a still room with clutter) with a person holding the
board (``BoardSpec.holder``): at each end of the board's cut the scan goes on for
0.1-0.3 m along the board's line but 50-100 mm off it, touching the board's ends, as the
hands, arms and body of whoever holds it do. Every capture's returns are found by auto,
once with the sheet's size given (``board.size_m``) and once without; per capture the
returns taken are compared with the board's own (the simulator knows which beams hit it):

- **off-board returns**: returns taken that are not the board's, and how far the farthest
  lies from the board's true line;
- **board kept**: the share of the board's returns taken;
- **answer**: T_cam_laser's error against the truth for both, and how far apart they are.

    .venv/bin/python benchmarks/bench_board_auto_returns.py --seeds 4
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.session import read_board_session
from rigcal.calib.intrinsics import Board
from rigcal.errors import CalibrationError
from rigcal.geometry import pose_error
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.noise import RealisticNoise

BOARD = Board(7, 5, 0.12)


def _auto(path: Path, size: bool) -> Path:
    doc = yaml.safe_load(path.read_text())
    for c in doc["captures"]:
        c["laser_side"] = "auto"
    if not size:
        doc["board"].pop("size_m", None)
    out = path.with_name(f"auto_{'size' if size else 'nosize'}.yaml")
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def _line_distance(p: np.ndarray, cut: np.ndarray) -> np.ndarray:
    u = (cut[1] - cut[0]) / np.linalg.norm(cut[1] - cut[0])
    return np.abs((p - cut[0]) @ np.array([-u[1], u[0]]))


def run(seeds: range, poses: int) -> dict[str, dict[str, list[float]]]:
    from rigcal.calib.board.detect import plane_cut

    stats: dict[str, dict[str, list[float]]] = {}
    for seed in seeds:
        spec = BoardSpec(n_captures=poses, seed=seed, noise=RealisticNoise(), board=BOARD, holder=True)
        sim = generate_board_session(spec)
        b = spec.board
        w, h = (b.width_n - 1) * b.spacing_m, (b.height_n - 1) * b.spacing_m
        m = spec.sheet_margin_m
        outline = np.array([[-m, -m], [w + m, -m], [w + m, h + m], [-m, h + m]])
        with tempfile.TemporaryDirectory() as tmp:
            path = write_board_session(sim, Path(tmp) / "s") / "board_session.yaml"
            for size in (True, False):
                key = "with size_m" if size else "without size_m"
                st = stats.setdefault(key, {k: [] for k in ("extra", "off_mm", "kept", "rot", "trans", "T")})
                f = _auto(path, size)
                try:
                    ses = read_board_session(f)
                except Exception as exc:
                    print(f"seed {seed} {key}: {str(exc)[:160]}")
                    continue
                for c, o in zip(sim.captures, ses.observations, strict=True):
                    board = c.scan.points[c.board_beams[c.scan.valid[c.board_beams]]]
                    have = {tuple(p) for p in board}
                    took = np.asarray(o.points_laser)
                    extra = np.array([tuple(p) not in have for p in took], dtype=bool)
                    cut = plane_cut(c.T_laser_board, outline)
                    st["extra"].append(float(extra.sum()))
                    st["off_mm"].append(
                        1000 * float(_line_distance(took[extra], cut).max()) if extra.any() else 0.0
                    )
                    st["kept"].append(float((~extra).sum()) / max(len(board), 1))
                try:
                    cal = calibrate_board(f)
                except CalibrationError as exc:
                    print(f"seed {seed} {key}: {exc}")
                    continue
                e = pose_error(cal.result.T_cam_laser, sim.T_cam_laser)
                st["rot"].append(float(e[0]))
                st["trans"].append(1000 * float(e[1]))
                st["T"].append(cal.result.T_cam_laser)  # type: ignore[arg-type]
    return stats


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--poses", type=int, default=10)
    args = ap.parse_args()
    stats = run(range(args.seeds), args.poses)
    print(
        f"{'':<16}{'captures':>9}{'w/ extra':>9}{'extra/cap':>10}{'off>=50mm':>10}{'kept_med':>9}"
        f"{'kept_min':>9}{'kept<0.8':>9}{'rot_deg':>9}{'trans_mm':>9}"
    )
    for key, st in stats.items():
        ex, off, kept = np.array(st["extra"]), np.array(st["off_mm"]), np.array(st["kept"])
        print(
            f"{key:<16}{len(ex):>9}{int((ex > 0).sum()):>9}{ex.mean():>10.2f}{int((off >= 50).sum()):>10}"
            f"{np.median(kept):>9.2f}{kept.min():>9.2f}{int((kept < 0.8).sum()):>9}"
            f"{np.median(st['rot']) if st['rot'] else np.nan:>9.3f}"
            f"{np.median(st['trans']) if st['trans'] else np.nan:>9.1f}"
        )
    a, b = stats.get("with size_m", {}).get("T", []), stats.get("without size_m", {}).get("T", [])
    if a and len(a) == len(b):
        moves = [pose_error(x, y) for x, y in zip(a, b, strict=True)]
        worst = np.max(np.array(moves), axis=0)
        print(f"with vs without size_m: largest move {worst[0]:.3f} deg / {1000 * worst[1]:.1f} mm")


if __name__ == "__main__":
    main()
