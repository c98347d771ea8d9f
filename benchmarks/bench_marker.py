"""The marker target against the board method: accuracy, NEES, spread, captures found, corner bias.

Per seed, one simulated marker session of 20 views (``rigcal.sim.marker_session``: images
rendered from the printed faces, the realistic camera's blur, noise and exposure when the
noise is realistic; ``--scans`` scans per still moment, independent range noise each) is
solved with no hand input (``calibrate_marker``: the target's pose read from both faces'
corners at once, each moment's scans averaged per beam, the V found in the scans, the
plane method on both faces) on all 20 views and on the first 10. Beside it, the board
method (``calibrate_board``) on a board session of the
same seed, views and noise model (the lab's large board of bench_realistic_calib.py;
its corners are given, its returns found by ``laser_side`` segment ids).

Printed per configuration: median rotation / translation error against the truth, the
mean NEES under the reported covariance (with the 95 % band of a mean of that many
chi-square 6-dof values), the share of solves whose NEES is under the 95 % point, the
median spread scale (leave-one-out spread over the model's 1-sigma, about 1 when the
covariance is honest), and the share of captures the target was found in.

Corner bias: per detected face, the ChArUco corners against their true projections, and
the raw ArUco marker corners (OpenCV's detector with sub-pixel refinement, no ChArUco)
against the markers' true corners; the bias is the mean error along the outward
direction (from the pattern's / the marker's centre), in pixels: negative means inside.

    .venv/bin/python benchmarks/bench_marker.py --seeds 6
    .venv/bin/python benchmarks/bench_marker.py --seeds 6 --scans 1 --no-board   # one scan a moment
    .venv/bin/python benchmarks/bench_marker.py --seeds 2 --noise clean   # quicker
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.intrinsics import Board
from rigcal.calib.marker.calibrate import calibrate_marker
from rigcal.calib.report import truth_comparison
from rigcal.errors import CalibrationError
from rigcal.geometry import transform_points
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.marker_session import MarkerSpec, T_laser_face, generate_marker_session, write_marker_session
from rigcal.sim.noise import RealisticNoise

CHI2_6_95 = 12.591587243743977
BOARD = Board(7, 5, 0.12)


def _scores(T, cov, T_truth) -> dict[str, float]:
    t = truth_comparison(T, cov, T_truth)
    return {"rot": t["rotation_error_deg"], "trans": t["translation_error_mm"], "nees": t["nees"]}


def marker_runs(
    seed: int, noise: RealisticNoise | None, views: list[int], bias: list, scans: int
) -> dict[int, dict]:
    spec = MarkerSpec(n_captures=max(views), seed=seed, noise=noise, scans_per_capture=scans)
    sim = generate_marker_session(spec)
    _corner_bias(sim, bias)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = write_marker_session(sim, Path(tmp) / "s")
        doc = yaml.safe_load((folder / "marker_session.yaml").read_text())
        for n in views:
            d = dict(doc, captures=doc["captures"][:n])
            path = folder / f"marker_{n}.yaml"
            path.write_text(yaml.safe_dump(d))
            try:
                cal = calibrate_marker(path)
            except CalibrationError as exc:
                out[n] = {"failed": str(exc)[:120], "found": np.nan}
                continue
            r = cal.result
            row = _scores(r.T_cam_laser, r.covariance, sim.T_cam_laser)
            row["found"] = len(cal.session.found) / n
            row["spread"] = r.spread.scale if r.spread is not None else np.nan
            row["scale"] = cal.report["marker"]["scale"]["ratio"]
            out[n] = row
    return out


def board_runs(seed: int, noise: RealisticNoise | None, views: list[int]) -> dict[int, dict]:
    out = {}
    for n in views:
        spec = BoardSpec(n_captures=n, seed=seed, noise=noise, board=BOARD)
        sim = generate_board_session(spec)
        with tempfile.TemporaryDirectory() as tmp:
            folder = write_board_session(sim, Path(tmp) / "s")
            try:
                cal = calibrate_board(folder / "board_session.yaml")
            except CalibrationError as exc:
                out[n] = {"failed": str(exc)[:120]}
                continue
        r = cal.result
        row = _scores(r.T_cam_laser, r.covariance, sim.T_cam_laser)
        row["spread"] = r.spread.scale if r.spread is not None else np.nan
        row["found"] = 1.0
        out[n] = row
    return out


def _corner_bias(sim, bias: list) -> None:
    """Outward corner errors (px) of ChArUco corners and of raw ArUco marker corners."""
    import cv2

    from rigcal.calib.marker.detect import detect_target
    from rigcal.targets.marker import charuco_board

    t = sim.spec.target
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, t.dictionary))
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(d, params)
    for c in sim.captures:
        view = detect_target(c.image, sim.camera, t)
        grey = cv2.cvtColor(c.image, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = det.detectMarkers(grey)
        ids = [] if ids is None else ids.ravel().tolist()
        for k in range(2):
            T = sim.T_cam_laser @ T_laser_face(t, c.T_laser_target, k)
            f = view.faces[k]
            if f is not None:
                true = sim.camera.project(transform_points(T, t.faces[k].corner_points[f.corner_ids]))
                centre = true.mean(axis=0)
                out = (true - centre) / np.linalg.norm(true - centre, axis=1, keepdims=True)
                bias.append(("charuco", float(np.mean(np.sum((f.corners_px - true) * out, axis=1)))))
            board = charuco_board(t, k)
            obj = board.getObjPoints()
            off = np.array([*t.faces[k].offset_m, 0.0])
            for j, mid in enumerate(board.getIds().ravel().tolist()):
                if mid not in ids:
                    continue
                seen = corners[ids.index(mid)].reshape(4, 2)
                true = sim.camera.project(transform_points(T, np.asarray(obj[j]).reshape(4, 3) + off))
                centre = true.mean(axis=0)
                out = (true - centre) / np.linalg.norm(true - centre, axis=1, keepdims=True)
                bias.append(("aruco", float(np.mean(np.sum((seen - true) * out, axis=1)))))


def summarise(rows: list[dict]) -> str:
    ok = [r for r in rows if "failed" not in r]
    if not ok:
        return f"all {len(rows)} failed"
    rot = np.array([r["rot"] for r in ok])
    tr = np.array([r["trans"] for r in ok])
    nees = np.array([r["nees"] for r in ok])
    half = 1.96 * np.sqrt(12.0 / len(ok))
    found = np.nanmean([r.get("found", np.nan) for r in rows])
    return (
        f"runs {len(ok)}/{len(rows)}  median {np.median(rot):.3f} deg / {np.median(tr):.2f} mm  "
        f"(p90 {np.percentile(rot, 90):.3f} deg / {np.percentile(tr, 90):.2f} mm)  "
        f"mean NEES {nees.mean():.2f} (95 % band {6 - half:.1f}-{6 + half:.1f}), "
        f"{100 * np.mean(nees < CHI2_6_95):.0f} % under the 95 % point  "
        f"spread scale median {np.nanmedian([r['spread'] for r in ok]):.2f}  "
        f"captures found {100 * found:.1f} %"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--noise", choices=["clean", "realistic", "both"], default="both")
    ap.add_argument("--no-board", action="store_true")
    ap.add_argument("--no-marker", action="store_true", help="the board method only")
    ap.add_argument("--scans", type=int, default=10, help="scans per still moment (marker sessions)")
    args = ap.parse_args()
    views = [10, 20]
    models = {"clean": None, "realistic": RealisticNoise()}
    chosen = list(models) if args.noise == "both" else [args.noise]
    for name in chosen:
        noise = models[name]
        marker: dict[int, list] = {n: [] for n in views}
        board: dict[int, list] = {n: [] for n in views}
        bias: list = []
        t0 = time.time()
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            for n, row in (
                {} if args.no_marker else marker_runs(seed, noise, views, bias, args.scans)
            ).items():
                marker[n].append(row)
                print(f"  {name} marker seed {seed} views {n}: {row}", flush=True)
            if not args.no_board:
                for n, row in board_runs(seed, noise, views).items():
                    board[n].append(row)
                    print(f"  {name} board seed {seed} views {n}: {row}", flush=True)
        scans = "" if args.no_marker else f", {args.scans} scans a still moment (marker; the board: 1)"
        print(f"== {name} noise{scans} ({time.time() - t0:.0f} s)")
        for n in views:
            if not args.no_marker:
                print(f"marker, {n} views: {summarise(marker[n])}")
            if not args.no_board:
                print(f"board,  {n} views: {summarise(board[n])}")
        for kind in ("charuco", "aruco"):
            b = np.array([v for k, v in bias if k == kind])
            if len(b):
                print(
                    f"corner bias {kind}: mean outward {b.mean():+.3f} px "
                    f"(+- {b.std() / np.sqrt(len(b)):.3f}), "
                    f"{len(b)} {'faces' if kind == 'charuco' else 'markers'}"
                )
        print(flush=True)


if __name__ == "__main__":
    main()
