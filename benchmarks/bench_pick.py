"""Pick assist (rigcal pick): automatic box ends against the truth, and the calibration
they give.

Rendered box-target sessions (``rigcal simulate box-session``: 20 captures, 1 cm range
noise, the simulated user's picks with 1 px noise). For each session the automatic picks
are started four ways: from the simulated user's picks of the first 3 or 5 captures
(``rigcal pick``'s usual use), from a rough rig (the truth turned 0.5 deg about a random
axis and moved 20 mm) and from the true rig. Figures over the automatically picked
captures: the fraction of box ends within 1 px of the true pixel (the true box end
projected), the fraction of captures with both ends within 1 px, the median error, the
fraction marked for review, the within-1 px fraction of those not marked and how many
captures not marked have an end over 2 px off. Then the
calibration error (rotation deg, translation mm; median over sessions) of ``rigcal solve``
on the automatic picks against the same solve on the simulated user's picks of every
capture and on the exact true pixels.

    .venv/bin/python benchmarks/bench_pick.py [--sessions 10]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from rigcal.calib.box.autopick import PickSettings, auto_pick, pick_file_text
from rigcal.calib.box.picks import read_pick_draft, read_picks
from rigcal.calib.box.solve import CalibProblem, solve
from rigcal.sim.box_session import SessionSpec, generate_session, moved_T_cam_laser, write_session


def pose_error(T, T_true) -> tuple[float, float]:
    dR = T[:3, :3] @ T_true[:3, :3].T
    return float(np.degrees(Rotation.from_matrix(dR).magnitude())), 1000.0 * float(
        np.linalg.norm(T[:3, 3] - T_true[:3, 3])
    )


def solve_file(path: Path, T_true) -> tuple[float, float]:
    s = read_picks(path)
    return pose_error(solve(CalibProblem(s.camera, s.observations)).T_cam_laser, T_true)


def draft(folder: Path, manual: int, pixels=None) -> Path:
    doc = yaml.safe_load((folder / "picks.yaml").read_text())
    doc["schema_version"] = 2
    for i, c in enumerate(doc["captures"]):
        if pixels is not None:
            c["image_endpoints_px"] = pixels[i].tolist()
        elif i >= manual:
            del c["image_endpoints_px"]
    path = folder / (f"draft{manual}.yaml" if pixels is None else "exact.yaml")
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sessions", type=int, default=10)
    args = ap.parse_args()
    variants = ("3 manual picks", "5 manual picks", "rough rig (0.5 deg, 20 mm)", "true rig")
    ends: dict[str, list[np.ndarray]] = {v: [] for v in variants}
    review: dict[str, list[np.ndarray]] = {v: [] for v in variants}
    calib: dict[str, list[tuple[float, float]]] = {v: [] for v in (*variants, "user's picks", "exact pixels")}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.sessions):
            sim = generate_session(SessionSpec(n_captures=20, seed=seed))
            folder = write_session(sim, Path(tmp) / f"s{seed}")
            truth = np.array([c.true_pixels for c in sim.captures])
            T_true = np.array(sim.T_cam_laser)
            calib["user's picks"].append(solve_file(folder / "picks.yaml", T_true))
            calib["exact pixels"].append(solve_file(draft(folder, 0, truth), T_true))
            rough = moved_T_cam_laser(T_true, 0.5, 20.0, seed=seed)
            for v, manual, T in zip(variants, (3, 5, 0, 0), (None, None, rough, T_true), strict=True):
                d = read_pick_draft(draft(folder, manual))
                run = auto_pick(d, PickSettings(), T)
                auto = [p for p in run.picks if p.source == "auto" and p.image_endpoints_px is not None]
                e = np.array([np.linalg.norm(p.image_endpoints_px - truth[p.index], axis=1) for p in auto])
                ends[v].append(e)
                review[v].append(np.array([p.review for p in auto]))
                out = folder / f"auto{manual}{T is not None}.yaml"
                out.write_text(pick_file_text(run, out))
                calib[v].append(solve_file(out, T_true))
            print(f"session {seed} done", flush=True)
    print(f"\n## Pick assist, {args.sessions} rendered sessions of 20 captures\n")
    print("| start | ends within 1 px | captures within 1 px | median error (px) | marked for review | "
          "within 1 px, not marked | over 2 px, not marked |\n|---|---|---|---|---|---|---|")  # fmt: skip
    for v in variants:
        e = np.concatenate(ends[v])
        r = np.concatenate(review[v])
        both = e.max(axis=1) < 1.0
        print(
            f"| {v} | {np.mean(e < 1.0):.1%} | {np.mean(both):.1%} | {np.median(e):.2f} | {np.mean(r):.1%} | "
            f"{np.mean(e[~r] < 1.0):.1%} | {int(np.sum(e[~r].max(axis=1) > 2.0))} of {int(np.sum(~r))} |"
        )
    print("\n| picks solved | rotation error (deg), median | translation error (mm), median | "
          "rotation, worst | translation, worst |\n|---|---|---|---|---|")  # fmt: skip
    for v, errs in calib.items():
        a = np.array(errs)
        label = v if v in ("user's picks", "exact pixels") else f"automatic, from {v}"
        print(
            f"| {label} | {np.median(a[:, 0]):.3f} | {np.median(a[:, 1]):.2f} | {a[:, 0].max():.3f} | "
            f"{a[:, 1].max():.2f} |"
        )


if __name__ == "__main__":
    main()
