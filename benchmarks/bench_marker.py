"""The marker target against the board method: accuracy, NEES, spread, captures found, corner bias.

Per seed, one simulated marker session of as many views as ``--views`` asks at most
(``rigcal.sim.marker_session``: images rendered from the printed faces, the realistic
camera's blur, noise and exposure when the noise is realistic; ``--scans`` scans per still
moment, independent range noise each) is solved with no hand input (``calibrate_marker``:
the target's pose read from both faces' corners at once, each moment's scans averaged per
beam, the V found in the scans, the plane method on both faces) on its first n views for
each n of ``--views``. With ``--steps``, the largest n is solved twice more to show what
each step buys: with one scan a still moment (each capture's first scan only, the same
views) and with one pose per face (each face posed from its own corners, not the target
from both). Beside it, the board method (``calibrate_board``) on a board session of the
same seed, views and noise model (the lab's large board of bench_realistic_calib.py;
its corners are given, its returns found by ``laser_side`` segment ids).

``--sessions DIR`` keeps each simulated session (and its targets' true poses) in DIR and
reuses it on a later run, so that rows added later are on the very same views.

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
    .venv/bin/python benchmarks/bench_marker.py --seeds 12 --views 5 10 20 --steps --no-board
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
from rigcal.calib.truth import read_truth
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


def simulated(
    seed: int, noise_name: str, noise: RealisticNoise | None, n: int, scans: int, cache: Path
) -> Path:
    """The session folder of one seed (simulated and written on first use, then reused);
    beside it ``true_poses.npz``, each capture's true T_laser_target (for the corner bias)."""
    folder = cache / f"{noise_name}_{seed}_{n}x{scans}"
    if not (folder / "marker_session.yaml").is_file():
        spec = MarkerSpec(n_captures=n, seed=seed, noise=noise, scans_per_capture=scans)
        sim = generate_marker_session(spec)
        write_marker_session(sim, folder, force=True)
        np.savez(folder / "true_poses.npz", *[c.T_laser_target for c in sim.captures])
    return folder


def marker_runs(
    folder: Path, views: list[int], bias: list, steps: bool, plain: bool = True
) -> dict[str, dict]:
    """Per row name (``N``, ``N one scan``, ``N per face``) the solve's figures (``plain``:
    the ``N`` rows)."""
    _corner_bias(folder, bias)
    T_truth = read_truth(folder / "truth.yaml")
    doc = yaml.safe_load((folder / "marker_session.yaml").read_text())
    runs: list[tuple[str, list, bool]] = [(str(n), doc["captures"][:n], True) for n in views] if plain else []
    if steps:
        n = max(views)
        first = [
            {k: v for k, v in c.items() if k != "scans"} | {"scan": c["scans"][0]}
            for c in doc["captures"][:n]
        ]
        runs += [(f"{n} one scan", first, True), (f"{n} per face", doc["captures"][:n], False)]
    out = {}
    for name, captures, joint in runs:
        path = folder / f"bench_{name.replace(' ', '_')}.yaml"
        path.write_text(yaml.safe_dump(dict(doc, captures=captures)))
        try:
            cal = calibrate_marker(path, joint=joint)
        except CalibrationError as exc:
            # A session that stops counts as none found (the reason says which step stopped it).
            out[name] = {"failed": str(exc)[:300], "found": 0.0}
            continue
        r = cal.result
        row = _scores(r.T_cam_laser, r.covariance, T_truth)
        row["found"] = len(cal.session.found) / len(captures)
        row["spread"] = r.spread.scale if r.spread is not None else np.nan
        row["scale"] = cal.report["marker"]["scale"]["ratio"]
        row["dropped"] = [n for n, _ in cal.session.dropped]
        out[name] = row
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


def _corner_bias(folder: Path, bias: list) -> None:
    """Outward corner errors (px) of ChArUco corners and of raw ArUco marker corners (none
    without the targets' true poses)."""
    import cv2

    from rigcal.calib.marker.detect import detect_target
    from rigcal.camera import read_camera
    from rigcal.targets.marker import charuco_board, read_targets

    if not (folder / "true_poses.npz").is_file():
        return
    t = read_targets(folder / "targets.yaml")
    camera = read_camera(folder / "camera.yaml")
    T_cam_laser = read_truth(folder / "truth.yaml")
    poses = np.load(folder / "true_poses.npz")
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, t.dictionary))
    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(d, params)
    for i in range(len(poses.files)):
        image = cv2.imread(str(folder / "images" / f"cap{i:02d}.png"))
        T_laser_target = poses[f"arr_{i}"]
        view = detect_target(image, camera, t)
        grey = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        corners, ids, _ = det.detectMarkers(grey)
        ids = [] if ids is None else ids.ravel().tolist()
        for k in range(2):
            T = T_cam_laser @ T_laser_face(t, T_laser_target, k)
            f = view.faces[k]
            if f is not None:
                true = camera.project(transform_points(T, t.faces[k].corner_points[f.corner_ids]))
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
                true = camera.project(transform_points(T, np.asarray(obj[j]).reshape(4, 3) + off))
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
    dropped = sum(len(r.get("dropped", [])) for r in rows)
    return (
        f"runs {len(ok)}/{len(rows)}  median {np.median(rot):.3f} deg / {np.median(tr):.2f} mm  "
        f"(p90 {np.percentile(rot, 90):.3f} deg / {np.percentile(tr, 90):.2f} mm)  "
        f"mean NEES {nees.mean():.2f} (95 % band {6 - half:.1f}-{6 + half:.1f}), "
        f"{100 * np.mean(nees < CHI2_6_95):.0f} % under the 95 % point  "
        f"spread scale median {np.nanmedian([r['spread'] for r in ok]):.2f}  "
        f"captures found {100 * found:.1f} % ({dropped} set aside)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--first-seed", type=int, default=100)
    ap.add_argument("--noise", choices=["clean", "realistic", "both"], default="both")
    ap.add_argument("--no-board", action="store_true")
    ap.add_argument("--no-marker", action="store_true", help="the board method only")
    ap.add_argument("--scans", type=int, default=10, help="scans per still moment (marker sessions)")
    ap.add_argument("--views", type=int, nargs="+", default=[10, 20], help="the session's first n views")
    ap.add_argument("--steps", action="store_true", help="also one scan a moment and one pose per face")
    ap.add_argument("--only-steps", action="store_true", help="the --steps rows only")
    ap.add_argument("--sessions", type=Path, help="keep and reuse the simulated marker sessions here")
    args = ap.parse_args()
    views = sorted(args.views)
    models = {"clean": None, "realistic": RealisticNoise()}
    chosen = list(models) if args.noise == "both" else [args.noise]
    with tempfile.TemporaryDirectory() as tmp:
        cache = args.sessions or Path(tmp)
        cache.mkdir(parents=True, exist_ok=True)
        for name in chosen:
            noise = models[name]
            marker: dict[str, list] = {}
            board: dict[int, list] = {n: [] for n in views}
            bias: list = []
            t0 = time.time()
            for seed in range(args.first_seed, args.first_seed + args.seeds):
                if not args.no_marker:
                    folder = simulated(seed, name, noise, max(views), args.scans, cache)
                    for row_name, row in marker_runs(
                        folder, views, bias, args.steps or args.only_steps, not args.only_steps
                    ).items():
                        marker.setdefault(row_name, []).append(row)
                        print(f"  {name} marker seed {seed} views {row_name}: {row}", flush=True)
                if not args.no_board:
                    for n, row in board_runs(seed, noise, views).items():
                        board[n].append(row)
                        print(f"  {name} board seed {seed} views {n}: {row}", flush=True)
            scans = "" if args.no_marker else f", {args.scans} scans a still moment (marker; the board: 1)"
            print(f"== {name} noise{scans} ({time.time() - t0:.0f} s)")
            for row_name, rows in marker.items():
                print(f"marker, {row_name} views: {summarise(rows)}")
            if not args.no_board:
                for n in views:
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
