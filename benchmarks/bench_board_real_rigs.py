"""Board calibration as on real rigs: honest sigma with few poses, order invariance, a unit
mistake, the camera's share.

On sessions from the realistic simulator (``rigcal.sim.noise``: Student-t range noise of
about 20 mm sd, mixed pixels, grazing bias, clutter; a 0.96 x 0.72 m board, hand-held:
every pose captured ``--repeats`` times, with ``--handheld`` 1-3 deg / 2-5 cm apart):

- **coverage**: a session of 2N poses is split in two halves of N poses (N = 5, 8, 10);
  each half is solved on its own (``calibrate_board``, the product's path) and scored by
  its NEES against the truth and its d^2 against the full session's answer, both under
  the half's own covariance; the share of halves inside the chi-square 6-dof 95 % bound
  (12.59) should be at least 90 %;
- **order**: the largest change of T_cam_laser when every capture's returns are permuted
  or rotated (should be 0, and under 1e-9);
- **unit mistake**: one capture's returns in millimetres (and, apart, 140 m away): the
  share of trials in which that capture is set aside, and the error of the answer;
- **camera**: the camera intrinsics' share of T's variance (``--intrinsics-sigma``), and
  the spread of T over cameras drawn from the intrinsics' covariance against the
  propagated sigma;
- **mrcal camera** (``--mrcal-camera``): every session's camera file is a mrcal model solved
  (``mrcal.optimize``) from 15 simulated chessboard views of the true camera, so its
  intrinsics carry a real calibration error (drawn, in effect, from their covariance) while
  the session's corners come from the true camera; its covariance comes from the model's
  optimization_inputs with no ``--intrinsics-sigma``. Coverage then scores the camera's
  uncertainty too, and the camera's share of T's variance is reported;
- **capture order**: the largest change of T when the session's captures are permuted or
  rotated, with and without their returns shuffled (0, and under 1e-9).

    .venv/bin/python benchmarks/bench_board_real_rigs.py                 # 8 seeds
    .venv/bin/python benchmarks/bench_board_real_rigs.py --seeds 3 --sizes 5
    .venv/bin/python benchmarks/bench_board_real_rigs.py --mrcal-camera --seeds 6 --skip order unit camera
"""

from __future__ import annotations

import argparse
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from rigcal.calib.board.calibrate import calibrate_board
from rigcal.calib.board.plane import solve_plane
from rigcal.calib.board.session import board_pose, plane_observation, read_board_session
from rigcal.calib.intrinsics import Board
from rigcal.calib.report import truth_comparison
from rigcal.errors import CalibrationError
from rigcal.geometry import pose_error, tangent_delta
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.boards import solved_camera_model
from rigcal.sim.noise import RealisticNoise

CHI2_6_95 = 12.591587243743977
BOARD = Board(7, 5, 0.12)


HANDHELD = False  # --handheld: repeats 1-3 deg / 2-5 cm apart
MRCAL_CAMERA = False  # --mrcal-camera: the camera file is a mrcal model solved from simulated views


def session(poses: int, seed: int, repeats: int, folder: Path):
    spec = BoardSpec(
        n_captures=poses, seed=seed, noise=RealisticNoise(), repeats=repeats, board=BOARD, handheld=HANDHELD
    )
    sim = generate_board_session(spec)
    path = write_board_session(sim, folder) / "board_session.yaml"
    if MRCAL_CAMERA:
        solved_camera_model(sim.camera, n_views=15, seed=1000 + seed).write(
            str(folder / "camera.cameramodel")
        )
        doc = yaml.safe_load(path.read_text())
        doc["camera"] = "camera.cameramodel"
        path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return sim, path


def subset(path: Path, names: list[str], out: Path) -> Path:
    """The session with only the named captures (the same files)."""
    doc = yaml.safe_load(path.read_text())
    doc["captures"] = [c for c in doc["captures"] if c["name"] in names]
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def d2(T: np.ndarray, cov: np.ndarray, T_ref: np.ndarray) -> float:
    x = tangent_delta(T_ref, T)
    return float(x @ np.linalg.solve(cov, x))


def coverage(n: int, seeds: range, repeats: int) -> dict[str, object]:
    nees, dd, small, share = [], [], [], []
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            sim, path = session(2 * n, seed, repeats, Path(tmp) / "s")
            try:
                full = calibrate_board(path)
            except CalibrationError:
                continue
            names = [c.name for c in sim.captures]
            rng = np.random.default_rng(seed)
            poses = rng.permutation(2 * n)
            for half in (poses[:n], poses[n:]):
                pick = [names[p * repeats + j] for p in sorted(half) for j in range(repeats)]
                try:
                    cal = calibrate_board(subset(path, pick, Path(tmp) / "s" / "half.yaml"))
                except CalibrationError:
                    continue
                res = cal.result
                nees.append(truth_comparison(res.T_cam_laser, res.covariance, sim.T_cam_laser)["nees"])
                dd.append(d2(res.T_cam_laser, res.covariance, full.result.T_cam_laser))
                small.append(any("too small" in w for w in cal.report["warnings"]))
                cam = cal.report["uncertainty"]["camera"]
                share.append(float(np.mean(cam["variance_share"])) if cam["included"] else 0.0)
    a, b = np.array(nees), np.array(dd)
    return {
        "halves": len(a),
        "nees_mean": float(np.mean(a)),
        "nees_in": float(np.mean(a <= CHI2_6_95)),
        "d2_in": float(np.mean(b <= CHI2_6_95)),
        "d2_max": float(np.max(b)),
        "warned_small": float(np.mean(small)),
        "camera_share": float(np.mean(share)),
    }


def order(seeds: range) -> float:
    worst = 0.0
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            _, path = session(8, seed, 1, Path(tmp) / "s")
            obs = read_board_session(path).observations
        base = solve_plane(obs, fit_range_bias=True, uncertainty_checks=False).T_cam_laser
        rng = np.random.default_rng(seed)
        for rotate in (False, True):
            shuffled = [
                replace(
                    o,
                    points_laser=np.roll(o.points_laser, int(rng.integers(len(o.points_laser))), axis=0)
                    if rotate
                    else o.points_laser[rng.permutation(len(o.points_laser))],
                )
                for o in obs
            ]
            T = solve_plane(shuffled, fit_range_bias=True, uncertainty_checks=False).T_cam_laser
            worst = max(worst, float(np.abs(T - base).max()))
    return worst


def capture_order(seeds: range) -> float:
    """The largest change of T_cam_laser (with its uncertainty checks) when the captures are
    listed in another order (permuted, or rotated), with and without every capture's
    returns shuffled too."""
    worst = 0.0
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            _, path = session(8, seed, 1, Path(tmp) / "s")
            obs = list(read_board_session(path).observations)
        base = solve_plane(obs, fit_range_bias=True).T_cam_laser
        rng = np.random.default_rng(seed)
        C = len(obs)
        for rotate, shuffle in ((False, False), (True, False), (False, True)):
            order = np.roll(np.arange(C), int(rng.integers(1, C))) if rotate else rng.permutation(C)
            given = [obs[i] for i in order]
            if shuffle:
                given = [
                    replace(o, points_laser=o.points_laser[rng.permutation(len(o.points_laser))])
                    for o in given
                ]
            T = solve_plane(given, fit_range_bias=True).T_cam_laser
            worst = max(worst, float(np.abs(T - base).max()))
    return worst


def unit_mistake(seeds: range, mistake: str) -> dict[str, float]:
    caught, errs = 0, []
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            sim, path = session(10, seed, 1, Path(tmp) / "s")
            obs = list(read_board_session(path).observations)
        bad = seed % len(obs)
        p = obs[bad].points_laser
        far = p + 140.0 * p / np.linalg.norm(p, axis=1, keepdims=True)
        obs[bad] = replace(obs[bad], points_laser=1000.0 * p if mistake == "mm" else far)
        res = solve_plane(obs, fit_range_bias=True, uncertainty_checks=False)
        caught += bool(res.screened_out is not None and res.screened_out[bad] and res.screened_out.sum() == 1)
        errs.append(pose_error(res.T_cam_laser, sim.T_cam_laser))
    e = np.array(errs)
    return {"caught": caught / len(seeds), "rot_max": float(e[:, 0].max()), "trans_max": float(e[:, 1].max())}


# 1-sigma of the default camera's intrinsics as a careful intrinsics calibration leaves them
# (OPENCV5: fx, fy, cx, cy, k1, k2, p1, p2, k3).
INTRINSICS_SIGMA = [0.8, 0.8, 1.0, 1.0, 0.004, 0.004, 0.0003, 0.0003, 0.0]


def camera_share(seeds: range, draws: int) -> dict[str, float]:
    """The camera's share of T's variance (mean over axes and seeds), and the spread of T
    over sessions whose camera is drawn from the intrinsics' covariance (the same
    corners and returns, each board pose re-solved under the drawn camera) against the
    propagated camera sigma (ratio about 1 when the propagation is right)."""
    shares, ratios = [], []
    for seed in seeds:
        with tempfile.TemporaryDirectory() as tmp:
            _, path = session(10, seed, 1, Path(tmp) / "s")
            cal = calibrate_board(path, intrinsics_sigma=INTRINSICS_SIGMA)
            base = calibrate_board(path)
        shares.append(np.mean(cal.report["uncertainty"]["camera"]["variance_share"]))
        cam, ses = cal.session.camera, cal.session
        cov_cam = cal.result.covariance - base.result.covariance
        rng = np.random.default_rng(seed)

        def solved(camera, ses=ses) -> np.ndarray:
            obs = []
            for i, o in enumerate(ses.observations):
                T_cb, cov, _ = board_pose(camera, ses.board, ses.corners_px[i], ses.corner_sigma_px)
                obs.append(plane_observation(i, o.name, T_cb, cov, o.points_laser))
            return solve_plane(obs, fit_range_bias=True, uncertainty_checks=False).T_cam_laser

        T0 = solved(cam)
        moves = []
        for _ in range(draws):
            drawn = replace(cam, intrinsics=cam.intrinsics + rng.normal(size=9) * np.array(INTRINSICS_SIGMA))
            moves.append(tangent_delta(solved(drawn), T0))
        m = np.array(moves)
        ratios.append(float(np.sqrt(np.mean(m**2, axis=0)).sum() / np.sqrt(np.diag(cov_cam)).sum()))
    return {"share": float(np.mean(shares)), "ratio": float(np.median(ratios))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--sizes", type=int, nargs="+", default=[5, 8, 10])
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--handheld", action="store_true", help="repeats of a hand-held board, not at one pose")
    ap.add_argument(
        "--mrcal-camera", action="store_true", help="camera files as mrcal models solved from views"
    )
    ap.add_argument("--skip", nargs="*", default=[], choices=["coverage", "order", "unit", "camera"])
    ap.add_argument("--draws", type=int, default=8, help="cameras drawn per seed (camera section)")
    args = ap.parse_args()
    global HANDHELD, MRCAL_CAMERA
    HANDHELD = args.handheld
    MRCAL_CAMERA = args.mrcal_camera
    seeds = range(args.seeds)
    if "coverage" not in args.skip:
        print(
            f"{'poses':>6}{'halves':>8}{'NEES_mean':>11}{'NEES_in95':>11}{'d2_in95':>9}{'d2_max':>8}"
            f"{'warned':>8}{'cam_share':>10}{'s/half':>8}"
        )
        for n in args.sizes:
            t0 = time.perf_counter()
            s = coverage(n, seeds, args.repeats)
            dt = (time.perf_counter() - t0) / max(int(s["halves"]), 1)
            print(
                f"{n:>6}{s['halves']:>8}{s['nees_mean']:>11.2f}{s['nees_in']:>11.0%}{s['d2_in']:>9.0%}"
                f"{s['d2_max']:>8.1f}{s['warned_small']:>8.0%}{s['camera_share']:>10.0%}{dt:>8.1f}",
                flush=True,
            )
    if "order" not in args.skip:
        print(f"order: largest |dT| over permuted and rotated returns: {order(seeds):.3g}", flush=True)
        print(f"order: largest |dT| over reordered captures: {capture_order(seeds):.3g}", flush=True)
    if "unit" not in args.skip:
        for mistake in ("mm", "140m"):
            u = unit_mistake(seeds, mistake)
            print(
                f"unit mistake ({mistake}): set aside in {u['caught']:.0%} of {len(seeds)} trials; "
                f"worst error {u['rot_max']:.2f} deg / {1000 * u['trans_max']:.0f} mm",
                flush=True,
            )

    if "camera" not in args.skip:
        c = camera_share(range(min(args.seeds, 3)), args.draws)
        print(
            f"camera (sigmas {INTRINSICS_SIGMA}): share of T's variance {c['share']:.0%} (mean over axes); "
            f"spread over drawn cameras / propagated sigma {c['ratio']:.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
