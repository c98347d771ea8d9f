"""False alarms of the targetless check on unmoved rigs, and whether its statistic is
calibrated: many short simulated drives, one check each, no perturbation.

Each drive is simulated with its own seed (``rigcal simulate world``; the world by the
seed: even the corridor, odd the cubicles; realistic camera:
exposure walk, blur, noise; a smaller camera than the benchmark's
laps so that many drives fit the time: 320 x 240 at 5 Hz) and checked once against the
true rig: the drives share no noise, so the checks are independent trials. Printed: the
false alarms with their Clopper-Pearson 95 % interval, and the calibration of the test
under no change: its p-values against the uniform distribution (Kolmogorov-Smirnov,
quantiles) and Hotelling's statistic, scaled to F(k, n - k), against its mean. Rows are
appended to ``--out`` (JSON lines) as they come, so a run stopped early keeps its checks
and ``--report`` prints them.

    .venv/bin/python benchmarks/bench_targetless_rates.py --seeds 100-139 --out /tmp/rates.jsonl
    .venv/bin/python benchmarks/bench_targetless_rates.py --report --out /tmp/rates.jsonl

The same drives checked again (``--keep``, then ``--recheck``) with the edge term off and the
stored T turned, and the correction's gain on the turned axis against the unmoved rigs' rows:

    .venv/bin/python benchmarks/bench_targetless_rates.py --recheck /tmp/rates.jsonl --no-edges \
        --out /tmp/still.jsonl
    .venv/bin/python benchmarks/bench_targetless_rates.py --recheck /tmp/rates.jsonl --no-edges \
        --perturb rz:0.3 --out /tmp/rz.jsonl --gain /tmp/still.jsonl
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

from bench_targetless import REALISTIC, WORLDS, clopper_pearson

TAIL = (0.005, 0.01, 0.02, 0.05, 0.1)
"""The levels at which each group's p-values are counted against a uniform tail."""

CAMERA = {
    "K": [[260.0, 0.0, 159.5], [0.0, 260.0, 119.5], [0.0, 0.0, 1.0]],
    "dist": [-0.15, 0.05, 0.0005, -0.0003, 0.0],
}


def small_rig(cache: Path) -> Path:
    """The simulated rig with a 320 x 240 camera (the simulated camera at half size)."""
    from rigcal.camera import Camera
    from rigcal.rig import Rig
    from rigcal.rigfile import write_rig
    from rigcal.sim.box_session import default_T_cam_laser

    path = cache / "rig-320.yaml"
    if not path.exists():
        cam = Camera.from_opencv(np.array(CAMERA["K"]), CAMERA["dist"], 320, 240, source="simulated")
        write_rig(path, Rig(default_T_cam_laser(), cam, laser={"name": "simulated 2D scanner"}))
    return path


def simulate(cache: Path, rig: Path, world: str, seed: int, duration_s: float) -> Path | None:
    from rigcal.cli.main import main

    out = cache / f"{world}-320-s{seed}-{duration_s:g}s"
    if not (out / "sequence.yaml").exists():
        args = ["simulate", "world", "--world", world, "-o", str(out), "--seed", str(seed), "--rig", str(rig)]
        args += [*REALISTIC, "--duration-s", f"{duration_s:g}", "--camera-rate-hz", "5", "--force"]
        try:
            code = main(args)
        except Exception as exc:  # a seed the simulator cannot render is skipped, and said
            print(f"seed {seed}: simulate failed ({exc!r}); skipped", file=sys.stderr)
            return None
        if code != 0:
            return None
    return out


def check(folder: Path, rig: Path, edges: bool = True, perturb: tuple[int, float] | None = None) -> dict:  # type: ignore[type-arg]
    """One check of the drive ``folder`` against the rig file ``rig``: with the edge term
    or without it (``edges``: the photometric term alone, as on a drive that shows no
    edge clearly), the stored T_cam_laser moved by ``perturb`` (axis, rad or m: T_true
    Exp(p), so the right correction is -p) or not."""
    from bench_targetless import perturbed
    from rigcal.drift.targetless import TargetlessSettings, check_targetless
    from rigcal.localize.streams import open_streams

    streams = open_streams(folder, rig_file=rig)
    assert streams.rig is not None
    stored = streams.rig if perturb is None else perturbed(streams.rig, *perturb)
    c = time.process_time()
    res = check_targetless(stored, streams, TargetlessSettings(edges=edges))
    rec = res.record
    error = None
    if perturb is not None and res.verdict != "cannot_tell":
        axis, size = perturb
        x = float(res.correction[axis]) + size
        error = math.degrees(x) if axis < 3 else 1000.0 * x  # the correction's error, deg or mm
    keys = ("t2", "dof", "effective_blocks", "effective_clusters", "blocks", "corners", "edges")
    keys += ("edge_corners", "corner_directions")
    return {
        "verdict": res.verdict,
        "p_value": rec.get("p_value"),
        **{k: rec.get(k) for k in keys},
        "observed": rec.get("observed_axes"),
        "correction_deg": rec.get("correction_rotation_deg"),
        "correction_mm": rec.get("correction_translation_mm"),
        "sigma_deg": rec.get("sigma_rotation_deg"),
        "sigma_mm": rec.get("sigma_translation_mm"),
        "solve": {k: rec.get(k) for k in ("steps", "steps_refused", "last_step_units")},
        "reasons": res.reasons if res.verdict == "cannot_tell" else [],
        # The test's pieces (resolution units), so that the report can say what the
        # statistic would give with another floor.
        "details": {
            "groups": [
                {k: np.asarray(v).tolist() for k, v in g.items()} for g in res.details.get("groups", [])
            ]
        },
        "tests": rec.get("tests"),
        "edge_bands": rec.get("edge_bands"),
        "odometry_errors": rec.get("odometry_errors"),
        "perturb": None if perturb is None else [AXES_NAMES[perturb[0]], perturb[1]],
        "correction_error": error,
        "cpu_s": round(time.process_time() - c, 2),
    }


AXES_NAMES = ("rx", "ry", "rz", "tx", "ty", "tz")


def perturbation(text: str | None) -> tuple[int, float] | None:
    """``AXIS:SIZE`` (deg for rx/ry/rz, mm for tx/ty/tz) as (axis, rad or m)."""
    if not text:
        return None
    name, _, size = text.partition(":")
    axis = AXES_NAMES.index(name)
    return axis, math.radians(float(size)) if axis < 3 else float(size) / 1000.0


def detection(rows: list[dict]) -> None:  # type: ignore[type-arg]
    """Of perturbed checks: how often the perturbed axis is observed, detected when
    observed (with the Clopper-Pearson interval), and the correction's error there."""
    rows = [r for r in rows if r.get("perturb")]
    if not rows:
        return
    axis, size = rows[0]["perturb"]
    shown = f"{math.degrees(size):g} deg" if axis.startswith("r") else f"{1000.0 * size:g} mm"
    seen = [r for r in rows if axis in (r.get("observed") or [])]
    hit = sum(r["verdict"] == "drifted" for r in seen)
    lo, hi = clopper_pearson(hit, len(seen)) if seen else (math.nan, math.nan)
    err = np.abs([r["correction_error"] for r in seen if r["correction_error"] is not None])
    print(
        f"perturbed {axis} by {shown}: observed in {len(seen)}/{len(rows)}; detected "
        f"{hit}/{len(seen)} (Clopper-Pearson 95 %: {100 * lo:.1f}-{100 * hi:.1f} %); correction error "
        + (f"median {np.median(err):.4f}, max {err.max():.4f}" if len(err) else "-")
    )


def gain(rows: list[dict], unmoved: list[dict]) -> None:  # type: ignore[type-arg]
    """The correction's gain along the perturbed axis: per drive, (the unmoved rig's
    correction less the perturbed one's) over the perturbation, on the drives both
    judged with the axis observed; printed with its spread, and the turned rig's error
    less the unmoved one's (an overshoot is negative for a positive perturbation)."""
    rows = [r for r in rows if r.get("perturb") and r["verdict"] != "cannot_tell"]
    if not rows:
        return
    name, size = rows[0]["perturb"]
    axis = AXES_NAMES.index(name)
    seen = [r for r in unmoved if r["verdict"] != "cannot_tell" and name in (r.get("observed") or [])]
    base = {r["seed"]: r for r in seen}
    pairs = [(base[r["seed"]], r) for r in rows if r["seed"] in base and name in (r.get("observed") or [])]
    if not pairs:
        print(f"gain: no drive judged with {name} observed both unmoved and perturbed")
        return

    def value(r: dict) -> float:  # type: ignore[type-arg]
        x = (r["correction_deg"] + r["correction_mm"])[axis]
        return math.radians(x) if axis < 3 else x / 1000.0

    g = np.array([(value(u) - value(p)) / size for u, p in pairs])
    d = (1.0 - g) * size
    d = np.degrees(d) if axis < 3 else 1000.0 * d
    unit = "deg" if axis < 3 else "mm"
    sd = g.std(ddof=1) if len(g) > 1 else math.nan
    print(
        f"gain on {name} over {len(g)} drives: mean {g.mean():.3f} (sd {sd:.3f}, "
        f"standard error {sd / math.sqrt(len(g)):.3f}), median {np.median(g):.3f}, "
        f"range {g.min():.3f} to {g.max():.3f}; "
        f"turned error less unmoved: mean {d.mean():+.4f} {unit} ({d.min():+.4f} to {d.max():+.4f})"
    )


def read_rows(path: Path) -> list[dict]:  # type: ignore[type-arg]
    """The checks already in ``path`` (JSON lines; none if it does not exist)."""
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def seeds_of(text: str) -> list[int]:
    a, _, b = text.partition("-")
    return list(range(int(a), int(b or a) + 1))


def refloored(rows: list[dict], scales: list[float]) -> None:  # type: ignore[type-arg]
    """The p-values the same checks give with the known part of each test's covariance
    (the floor) scaled by each of ``scales`` (0: no floor), the estimate and its data
    covariance unchanged (the observed directions as chosen with the settings' floor)."""
    from scipy.stats import kstest

    from rigcal.drift.statistic import hotelling

    rows = [r for r in rows if r.get("details", {}).get("groups")]
    print("floor scaled by | alarms at 1 % | KS D | p quantiles 0.1 / 0.5 / 0.9")
    for a in scales:
        p = []
        for r in rows:
            groups = [{k: np.asarray(v) for k, v in g.items()} for g in r["details"]["groups"]]
            ps = [
                hotelling(g["z"], g["C_data"], a * g["C_known"], float(g["n_data"]), 0.01).p for g in groups
            ]
            p.append(min(1.0, len(ps) * min(ps)))
        q = np.quantile(p, [0.1, 0.5, 0.9])
        ks = kstest(p, "uniform").statistic
        n1 = sum(x < 0.01 for x in p)
        print(f"{a:g} | {n1}/{len(p)} | {ks:.3f} | {q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f}")


def alarms(rows: list[dict], what: str) -> None:  # type: ignore[type-arg]
    """The false alarms among the judged checks with their Clopper-Pearson interval, and
    the "cannot tell" count."""
    judged = [r for r in rows if r["verdict"] != "cannot_tell"]
    fa = sum(r["verdict"] == "drifted" for r in judged)
    lo, hi = clopper_pearson(fa, len(judged))
    print(
        f"{what}: {len(rows)} checks, {len(rows) - len(judged)} cannot tell; false alarms at 1 %: "
        f"{fa}/{len(judged)} (Clopper-Pearson 95 %: {100 * lo:.1f}-{100 * hi:.1f} %)"
    )


def report(rows: list[dict], floor_scale: list[float] | None = None) -> None:  # type: ignore[type-arg]
    from scipy.stats import f as f_dist
    from scipy.stats import kstest

    judged = [r for r in rows if r["verdict"] != "cannot_tell"]
    alarms(rows, "all")
    for world in sorted({r["world"] for r in rows}):
        alarms([r for r in rows if r["world"] == world], world)
    for r in rows:
        if r["verdict"] == "drifted":
            print(f"  alarm: {r['world']} seed {r['seed']}: p {r['p_value']:.3g}, tests {r.get('tests')}")
        if r["verdict"] == "cannot_tell":
            why = "; ".join(r["reasons"])
            print(f"  cannot tell: {r['world']} seed {r['seed']} ({r.get('solve')}): {why}")
    if not judged:
        return
    axes = ["rx", "ry", "rz", "tx", "ty"]
    tested = {a: sum(a in (r.get("observed") or []) for r in judged) for a in axes}
    print(f"axes tested (of {len(judged)} judged): " + ", ".join(f"{a} {n}" for a, n in tested.items()))
    for world in sorted({r["world"] for r in judged}):
        w = [r for r in judged if r["world"] == world]
        counts = ", ".join(f"{a} {sum(a in (r.get('observed') or []) for r in w)}" for a in axes)
        corners = np.median([r.get("corners") or 0 for r in w])
        print(f"  {world} ({len(w)}): {counts}; median corners {corners:g}")
    # Each group's own p-values (the combined one is their Bonferroni minimum).
    for name in sorted({t["directions"] for r in judged for t in r.get("tests") or []}):
        tg = [t for r in judged for t in r.get("tests") or [] if t["directions"] == name]
        pg = np.array([t["p_value"] for t in tg])
        ksg = kstest(pg, "uniform")
        q = np.quantile(pg, [0.1, 0.5, 0.9])
        print(
            f"group {name!r}: {len(pg)} tests, KS D = {ksg.statistic:.3f} (p = {ksg.pvalue:.3g}); "
            f"quantiles 0.1 / 0.5 / 0.9: {q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f}; "
            f"p < 0.01: {int((pg < 0.01).sum())}"
        )
        # The lower tail against a uniform one's: a heavy tail shows as more than expected.
        tail = ", ".join(f"< {a:g}: {int((pg < a).sum())} ({a * len(pg):.1f})" for a in TAIL)
        qn = np.quantile([t["effective_clusters"] for t in tg], [0.05, 0.5])
        print(f"  p-values {tail} (expected); effective clusters 5 % / 50 %: {qn[0]:.1f} / {qn[1]:.1f}")
    p = np.array([r["p_value"] for r in judged])
    ks = kstest(p, "uniform")
    qs = [0.1, 0.25, 0.5, 0.75, 0.9]
    print(f"p-values against uniform: KS D = {ks.statistic:.3f}, p = {ks.pvalue:.3g}; quantiles", end=" ")
    print(", ".join(f"{q:g}: {float(np.quantile(p, q)):.3f}" for q in qs))
    print(f"p < 0.05: {int((p < 0.05).sum())}/{len(p)}, p < 0.1: {int((p < 0.1).sum())}/{len(p)}")
    # T^2 scaled to F(k, n - k), whose mean is (n - k) / (n - k - 2).
    F, mean_F = [], []
    for r in judged:
        k, n = r["dof"], r["effective_blocks"]
        F.append(r["t2"] * (n - k) / (k * (n - 1)))
        mean_F.append(f_dist.mean(k, n - k) if n - k > 2 else math.nan)
    dofs = sorted({r["dof"] for r in judged})
    print(f"F statistic: mean {np.mean(F):.3f} against its expected {np.nanmean(mean_F):.3f}; dof {dofs}")
    if floor_scale is not None:
        refloored(judged, floor_scale)
    cpu = [r["cpu_s"] for r in rows]
    print(f"check CPU s: median {np.median(cpu):.2f}, max {max(cpu):.2f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache", type=Path, default=Path("/tmp/rigcal-bench-targetless"))
    ap.add_argument("--seeds", default="100-109", help="a range of seeds, a-b")
    ap.add_argument("--duration-s", type=float, default=24.0)
    ap.add_argument("--worlds", default=",".join(WORLDS))
    ap.add_argument("--out", type=Path, required=True, help="JSON lines, appended")
    ap.add_argument("--report", action="store_true", help="only print the report of --out")
    ap.add_argument(
        "--floor-scale",
        help="also the p-values with the floor's covariance scaled by these, comma-separated (e.g. 0,0.25,1)",
    )
    ap.add_argument(
        "--keep", action="store_true", help="keep the simulated drives (else removed after their check)"
    )
    ap.add_argument(
        "--recheck",
        type=Path,
        help="check again the drives of this run's rows (kept in --cache by --keep; no simulation)",
    )
    ap.add_argument("--compare", type=Path, help="also list the verdicts that differ from this run's")
    ap.add_argument(
        "--gain",
        type=Path,
        help="the unmoved rigs' rows of the same drives: print the correction's gain on the perturbed axis",
    )
    ap.add_argument(
        "--no-edges",
        action="store_true",
        help="the photometric term alone (the edge term off), as without edges",
    )
    ap.add_argument(
        "--perturb", help="AXIS:SIZE, the stored T_cam_laser moved (deg for rx/ry/rz, mm for tx/ty/tz)"
    )
    args = ap.parse_args()
    perturb = perturbation(args.perturb)
    if args.recheck:
        rig = small_rig(args.cache)
        done = {r["seed"] for r in read_rows(args.out)}
        for old in read_rows(args.recheck):
            folder = args.cache / f"{old['world']}-320-s{old['seed']}-{old['duration_s']:g}s"
            if old["seed"] in done or not (folder / "sequence.yaml").exists():
                continue
            row = {k: old[k] for k in ("world", "seed", "duration_s")} | check(
                folder, rig, not args.no_edges, perturb
            )
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), file=sys.stderr, flush=True)
    elif not args.report:
        args.cache.mkdir(parents=True, exist_ok=True)
        rig = small_rig(args.cache)
        worlds = args.worlds.split(",")
        done = {r["seed"] for r in read_rows(args.out)}  # a stopped run resumes where it stopped
        for seed in seeds_of(args.seeds):
            if seed in done:
                continue
            world = worlds[seed % len(worlds)]
            folder = simulate(args.cache, rig, world, seed, args.duration_s)
            if folder is None:
                continue
            row = {"world": world, "seed": seed, "duration_s": args.duration_s} | check(
                folder, rig, not args.no_edges, perturb
            )
            with args.out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(json.dumps(row), file=sys.stderr, flush=True)
            if not args.keep:
                import shutil

                shutil.rmtree(folder)
    rows = read_rows(args.out)
    if args.compare:
        before = {r["seed"]: r for r in read_rows(args.compare)}
        rows_b = [before[r["seed"]] for r in rows if r["seed"] in before]
        print(f"--- {args.compare} on the same {len(rows_b)} drives:")
        report(rows_b)
        for r in rows:
            b = before.get(r["seed"])
            if b is not None and b["verdict"] != r["verdict"]:
                print(f"  changed: {r['world']} seed {r['seed']}: {b['verdict']} -> {r['verdict']}")
        print(f"--- {args.out}:")
    if any(r.get("perturb") for r in rows):
        detection(rows)  # a moved rig: its alarms are detections
        if args.gain:
            gain(rows, read_rows(args.gain))
    else:
        report(rows, [float(x) for x in args.floor_scale.split(",")] if args.floor_scale else None)


if __name__ == "__main__":
    main()
