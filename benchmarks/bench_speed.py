"""Speed of the box-target calibration: P3P in a batch against OpenCV, and whole solves.

1. P3P: the same random triples (points in front of a camera, uniformly random poses)
   solved by ``rigcal.calib.box.p3p.p3p`` (the compiled kernel) and ``p3p_numpy`` (its
   numpy reference, vectorised over the batch) in one batch, and by ``cv2.solveP3P``
   called once per triple from Python, as RANSAC would call it. Both give every real
   solution; the figures are solutions per second and the ratio between the two, measured
   in the same process (best of several repeats, so that a busy machine affects both).
   rigcal's P3P gives the depths along the bearings (the paper's step 5); with Horn's
   method for each solution (step 6) both sides end with full poses: Horn's method as
   ``horn_batch`` (numpy, batched ``eigh``, the reference) and compiled in ``p3p_poses``
   (the RANSAC's path), whose poses are checked against the reference's before timing.
   The kernels' compile time (first call in a fresh process) is measured apart
   (``jit_cost.py``); the kernels are called once before timing.
2. End-to-end: a simulated 40-capture session written to disk (placeholder images), then
   ``rigcal solve``'s library path on it: reading the picking file and every scan, camera
   and image, line extraction, RANSAC, refinement and the report, with and without the
   overlay images. Reading alone is timed separately.

    .venv/bin/python benchmarks/bench_speed.py
"""

from __future__ import annotations

import argparse
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from rigcal.calib.box.horn import horn_batch
from rigcal.calib.box.p3p import p3p, p3p_numpy, p3p_poses
from rigcal.calib.box.picks import read_picks
from rigcal.calib.box.session import calibrate
from rigcal.geometry import random_rotation
from rigcal.sim.box_session import SessionSpec, generate_session, write_session
from rigcal.viz.report_dir import write_box_report


def random_triples(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3, 3) bearings and (n, 3, 3) world points of random poses."""
    X = rng.uniform(-2.0, 2.0, (n, 3, 3))
    R = np.array([random_rotation(rng) for _ in range(n)])
    t = rng.uniform(-1.0, 1.0, (n, 3)) + np.array([0.0, 0.0, 6.0])
    Xc = np.einsum("kij,knj->kni", R, X) + t[:, None]
    return Xc / np.linalg.norm(Xc, axis=2, keepdims=True), X


def best_of(repeats: int, fn: Callable[[], int]) -> tuple[float, int]:
    times = []
    count = 0
    for _ in range(repeats):
        t0 = time.perf_counter()
        count = fn()
        times.append(time.perf_counter() - t0)
    return min(times), count


def bench_p3p(n: int, repeats: int) -> None:
    rng = np.random.default_rng(0)
    y, X = random_triples(rng, n)
    image = y[:, :, :2] / y[:, :, 2:]

    def ours_depths() -> int:
        return len(p3p(y, X).triple)

    def numpy_depths() -> int:
        return len(p3p_numpy(y, X).triple)

    def ours() -> int:
        sol = p3p(y, X)
        cam = sol.depths[:, :, None] * y[sol.triple]
        _, _, ok = horn_batch(cam, X[sol.triple])
        return int(ok.sum())

    def ours_compiled() -> int:
        return int(p3p_poses(y, X).ok.sum())

    def opencv() -> int:
        count = 0
        K = np.eye(3)
        for k in range(n):
            count += cv2.solveP3P(X[k], image[k], K, None, cv2.SOLVEPNP_P3P)[0]
        return count

    poses = p3p_poses(y, X)  # compile (or load from numba's cache) before timing
    sol = p3p(y, X)
    R_ref, t_ref, ok_ref = horn_batch(sol.depths[:, :, None] * y[sol.triple], X[sol.triple])
    same = bool((poses.ok == ok_ref).all())
    pose_diff = max(
        float(np.abs(poses.R - R_ref).max(initial=0.0)), float(np.abs(poses.t - t_ref).max(initial=0.0))
    )
    t_depths, s_depths = best_of(repeats, ours_depths)
    t_numpy, s_numpy = best_of(repeats, numpy_depths)
    t_ours, s_ours = best_of(repeats, ours)
    t_compiled, s_compiled = best_of(repeats, ours_compiled)
    t_cv, s_cv = best_of(repeats, opencv)
    print(f"## P3P, {n} random triples (best of {repeats})\n")
    print("| solver | solutions | solutions/s | us/triple | ratio |\n|---|---|---|---|---|")
    print(f"| cv2.solveP3P per triple | {s_cv} | {s_cv / t_cv:,.0f} | {1e6 * t_cv / n:.2f} | 1.0 |")
    for label, t, s in (
        ("rigcal p3p (depths), compiled kernel", t_depths, s_depths),
        ("rigcal p3p_numpy (depths), numpy reference, one batch", t_numpy, s_numpy),
        ("rigcal p3p + Horn (poses), compiled P3P, batched Horn", t_ours, s_ours),
        ("rigcal p3p_poses (poses), compiled P3P + compiled Horn", t_compiled, s_compiled),
    ):
        print(f"| {label} | {s} | {s / t:,.0f} | {1e6 * t / n:.2f} | {(s / t) / (s_cv / t_cv):.1f} |")
    print(
        f"\nCompiled against batched Horn: the same {'flags' if same else 'FLAGS DIFFER'}, "
        f"poses within {pose_diff:.1e}."
    )


def bench_solve(captures: int, repeats: int) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "session"
        write_session(generate_session(SessionSpec(n_captures=captures, seed=7)), folder, render_images=False)
        picks = folder / "picks.yaml"
        t_read, _ = best_of(repeats, lambda: len(read_picks(picks).observations))
        t_solve, _ = best_of(repeats, lambda: len(calibrate(picks).result.inliers))

        def with_report() -> int:
            cal = calibrate(picks)
            write_box_report(Path(tmp) / "report", cal, force=True)
            return 0

        t_report, _ = best_of(repeats, with_report)
    print(f"\n## End-to-end solve, {captures} captures (best of {repeats})\n")
    print("| stage | seconds |\n|---|---|")
    print(f"| read picking file, scans, camera, images; extract lines | {t_read:.3f} |")
    print(f"| read + RANSAC + refinement + report data | {t_solve:.3f} |")
    print(f"| the same + report folder with {captures} overlay PNGs | {t_report:.3f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--triples", type=int, default=5000)
    ap.add_argument("--captures", type=int, default=40)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    bench_p3p(args.triples, args.repeats)
    from jit_cost import KERNELS, compile_table

    print("\n### First call of the kernel in a fresh process\n")
    print(compile_table({k: v for k, v in KERNELS.items() if k.startswith("P3P")}))
    bench_solve(args.captures, args.repeats)


if __name__ == "__main__":
    main()
