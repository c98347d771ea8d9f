"""Line extraction: how often one surface comes out as more than one segment, and speed.

Scans of a Hokuyo-like scanner (270 deg, 0.25 deg steps, 1081 beams) with Gaussian range
noise are ray-cast against (a) one wall at 6-8 m and (b) a 0.6 m box face at 2.5 m in
front of a wall at 5 m. A surface "splits" when it yields other than exactly one segment.
Speed: time per scan of ``extract_lines`` (its compiled kernel) on the 10 mm wall scans,
against the time numpy takes to compute the scan's points (``Scan`` construction) and
against the Python region growing (``extract_lines(..., kernel=False)``, the kernel's
reference) on the same scans in the same run, as ratios; the two give the same segments
(checked here on every scan timed). The same comparison on the first 400 scans of the
simulated cubicle loop (a Hokuyo at 40 Hz, the scans ``bench_icp.py`` times the laser
odometry on), best of three
passes.

    .venv/bin/python benchmarks/bench_lines.py
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench_icp import hokuyo_loop_scans
from rigcal.lines import LineParams, extract_lines
from rigcal.scan import Scan
from rigcal.sim.drive import DriveSpec
from rigcal.sim.raycast import cast_scan

ANGLES = np.radians(np.arange(-135.0, 135.001, 0.25))
STEP = float(np.radians(0.25))


def noisy(segments: list, rng: np.random.Generator, sigma: float) -> Scan:
    r = cast_scan(segments, ANGLES, 30.0)
    r = np.where(np.isfinite(r), r + rng.normal(0.0, sigma, len(r)), 0.0)
    return Scan.from_uniform(ANGLES[0], STEP, r, 0.1, 30.0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scans", type=int, default=500)
    args = ap.parse_args()
    print(f"## Line extraction, {args.scans} scans per row\n")
    print("| range noise | thresholds | wall at 6-8 m split | box face at 2.5 m split |\n|---|---|---|---|")
    t_extract = t_scan = t_reference = 0.0
    for sigma, scaled in ((0.005, False), (0.01, False), (0.02, False), (0.02, True), (0.03, True)):
        params = LineParams.for_range_noise(sigma) if scaled else LineParams()
        wall_splits = face_splits = 0
        for seed in range(args.scans):
            rng = np.random.default_rng(seed)
            d = rng.uniform(6.0, 8.0)
            t0 = time.perf_counter()
            scan = noisy([[[d, -6.0], [d, 6.0]]], rng, sigma)
            t1 = time.perf_counter()
            segs = extract_lines(scan, params)
            t2 = time.perf_counter()
            if sigma == 0.01:
                t_scan += t1 - t0
                t_extract += t2 - t1
                t3 = time.perf_counter()
                ref = extract_lines(scan, params, kernel=False)
                t_reference += time.perf_counter() - t3
                if [s.indices.tolist() for s in ref] != [s.indices.tolist() for s in segs]:
                    raise AssertionError(f"compiled and reference segments differ (seed {seed})")
            wall_splits += len(segs) != 1
            scan = noisy([[[2.5, -0.3], [2.5, 0.3]], [[5.0, -6.0], [5.0, 6.0]]], rng, sigma)
            face = [s for s in extract_lines(scan, params) if abs(s.centroid[0] - 2.5) < 0.1]
            face_splits += len(face) != 1
        kind = "scaled to the noise" if scaled else "defaults (for 10 mm)"
        print(f"| {1000 * sigma:g} mm | {kind} | {wall_splits}/{args.scans} | {face_splits}/{args.scans} |")
    n = args.scans
    print(
        f"\nextract_lines: {1000 * t_extract / n:.2f} ms per 1081-beam scan "
        f"({t_extract / t_scan:.1f}x the time to ray-cast and build the scan, same run); "
        f"Python reference: {1000 * t_reference / n:.2f} ms "
        f"({t_reference / t_extract:.1f}x the compiled kernel, same scans)"
    )

    loop_timing()


def loop_timing() -> None:
    """Compiled against reference extraction on the cubicle loop's scans (best of 3)."""
    scans = hokuyo_loop_scans(DriveSpec(laser_rate_hz=40.0, seed=1))
    ms, beams = {}, {}
    for kernel in (True, False):
        passes = []
        for _ in range(3):
            t0 = time.perf_counter()
            segs = [extract_lines(s, kernel=kernel) for s in scans]
            passes.append(1000.0 * (time.perf_counter() - t0) / len(scans))
        ms[kernel] = min(passes)
        beams[kernel] = [[g.indices.tolist() for g in scan_segs] for scan_segs in segs]
    if beams[True] != beams[False]:
        raise AssertionError("compiled and reference segments differ on the cubicle loop")
    per_scan = np.mean([len(b) for b in beams[True]])
    print(
        f"cubicle loop, {len(scans)} scans ({per_scan:.0f} segments a scan): compiled {ms[True]:.3f} ms, "
        f"Python reference {ms[False]:.2f} ms per scan ({ms[False] / ms[True]:.1f}x, same segments)"
    )


if __name__ == "__main__":
    main()
