"""Capture's board route end to end: a simulated recording of a board's still moments ->
``rigcal capture --target BOARD.yaml`` -> ``rigcal solve``, against the simulated truth.

Per seed: a board session simulated with ``BoardSpec(repeats=K)`` (K scans of each board
pose, independent range noise each: one still moment), its poses spread as a careful lab
places them, rendered as a recording (``rigcal.sim.recording``: the board's sheet over a
still background, scans at 10 Hz, images at about 7.7 Hz, moves between moments) and
written as a sequence folder. Then the library calls ``rigcal capture`` makes
(still moments, the board in each image and scan, the board session) and the board solve,
once keeping every scan of each moment and once only the scan paired with the image
(``--max-scans 1``). Printed: the still moments found, the share of them with the board
found, and per scans-per-moment setting the median rotation and translation errors, the
median NEES (6 dof: 5.35 expected) and the median range noise the solve estimated.

    .venv/bin/python benchmarks/bench_capture_board.py                  # clean and realistic, 3 seeds
    .venv/bin/python benchmarks/bench_capture_board.py --noise realistic --seeds 5 --poses 10
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.capture import write_board_capture_session
from rigcal.calib.capture import find_still_periods
from rigcal.calib.report import truth_comparison
from rigcal.errors import CalibrationError
from rigcal.recordings.sequence import read_sequence
from rigcal.sim.board_session import BoardSpec, generate_board_session
from rigcal.sim.noise import RealisticNoise
from rigcal.sim.recording import board_moments, write_still_recording
from rigcal.targets.board import BoardTarget


def trial(noise: str, seed: int, poses: int, scans: int, work: Path) -> dict[str, object]:
    spec = BoardSpec(
        n_captures=poses,
        repeats=scans,
        seed=seed,
        spread=True,
        noise=RealisticNoise() if noise == "realistic" else None,
    )
    sim = generate_board_session(spec)
    folder = work / f"{noise}-{seed}"
    write_still_recording(
        folder / "seq", "board drive", board_moments(sim, seed), sim.camera, sim.T_cam_laser, seed
    )
    b = spec.board
    target = BoardTarget("board", b.width_n, b.height_n, b.spacing_m, spec.size_m)
    seq = read_sequence(folder / "seq")
    still = find_still_periods(seq)
    out: dict[str, object] = {"moments": len(still)}
    for label, max_scans in (("all", None), ("one", 1)):
        session = folder / f"s-{label}"
        try:
            found = write_board_capture_session(
                seq, still, session, folder / "seq" / "camera.yaml", target, max_scans=max_scans
            )
        except CalibrationError as exc:
            out[label] = None
            print(f"  {noise} seed {seed} {label}: {exc}")
            continue
        out["found"] = len(found.found)
        out[f"scans-{label}"] = float(np.mean(found.scans))
        cal = calibrate_board(session / "board_session.yaml")
        t = truth_comparison(cal.result.T_cam_laser, cal.result.covariance, sim.T_cam_laser)
        out[label] = (
            t["rotation_error_deg"],
            t["translation_error_mm"],
            t["nees"],
            1000.0 * cal.report["noise"]["range_sigma_m"]["estimated"],
        )
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", choices=("clean", "realistic", "both"), default="both")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--poses", type=int, default=20)
    ap.add_argument("--scans", type=int, default=10, help="scans of each still moment (10 Hz)")
    args = ap.parse_args()
    models = ("clean", "realistic") if args.noise == "both" else (args.noise,)
    t0 = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-capture-board-") as tmp:
        for noise in models:
            runs = [trial(noise, seed, args.poses, args.scans, Path(tmp)) for seed in range(args.seeds)]
            moments = sum(int(r["moments"]) for r in runs)  # type: ignore[call-overload]
            found = sum(int(r.get("found", 0)) for r in runs)  # type: ignore[call-overload]
            scans = np.mean([r["scans-all"] for r in runs if "scans-all" in r])
            for label in ("one", "all"):
                ok = [r[label] for r in runs if r.get(label) is not None]
                m = np.median(np.array(ok), axis=0) if ok else [np.nan] * 4
                kept = "1" if label == "one" else f"{scans:.1f}"
                rows.append(
                    f"| {noise} | {args.poses} | {moments}/{args.seeds * args.poses} | "
                    f"{100.0 * found / max(moments, 1):.1f} % | {kept} | {m[0]:.3f} | {m[1]:.2f} | "
                    f"{m[2]:.2f} | {m[3]:.2f} | {len(ok)}/{args.seeds} |"
                )
    print(
        "| noise | poses | still moments found | board found | scans a capture | rotation error "
        "(deg, median) | translation error (mm, median) | NEES (median) | range sigma estimated "
        "(mm, median) | solved |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
