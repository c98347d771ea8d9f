"""The output folder of ``rigcal localize`` (docs/localization.md): each
method's trajectory, the run's summary and the charts. The localization
(:func:`rigcal.localize.pipeline.run`) returns its results; this output layer writes them.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import yaml

from rigcal.io.files import atomic_folder
from rigcal.io.trajectory import kitti_text, planar_trajectory, tum_text
from rigcal.localize.pipeline import MethodRun, Run, planar_at, summary
from rigcal.viz.charts import figure_bytes
from rigcal.viz.paths_plot import errors_figure, graph_figure, paths_figure


def write_run(r: Run, sequence: Path, output: str | Path, force: bool = False, kitti: bool = False) -> Path:
    """Write the output folder of a localization run: ``METHOD/trajectory.tum`` (and
    ``.kitti`` with ``kitti``, ``steps.csv`` where the method keeps one) per method,
    ``summary.yaml``/``.json`` and, with ground truth, ``paths.png``/``.svg`` (as the
    paper's Fig. 8) and ``errors.png``/``.svg``; all in one rename.

    Raises:
        OutputError: ``output`` exists and ``force`` is False, or cannot be written.
    """
    doc = summary(r, sequence)
    with atomic_folder(output, force, inputs=[sequence]) as tmp:
        for m in r.methods:
            # The estimate is anchored at the truth's first pose, so it runs at the truth's
            # height (the laser's, e.g. 0.4 m above the floor); 0 without truth.
            z = 0.0
            if r.truth is not None and r.truth.stamps_s is not None:
                z = float(np.interp(m.stamps_s[0], r.truth.stamps_s, r.truth.poses[:, 2, 3]))
            traj = planar_trajectory(m.stamps_s, m.poses, z)
            (tmp / m.method).mkdir()
            (tmp / m.method / "trajectory.tum").write_text(tum_text(traj), encoding="utf-8")
            if m.steps_csv is not None:
                (tmp / m.method / "steps.csv").write_text(m.steps_csv, encoding="utf-8")
            if m.closures is not None:
                _write_closures(tmp / m.method, m)
            if kitti:
                (tmp / m.method / "trajectory.kitti").write_text(kitti_text(traj), encoding="utf-8")
        (tmp / "summary.yaml").write_text(yaml.safe_dump(doc, sort_keys=False), encoding="utf-8")
        (tmp / "summary.json").write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
        if r.truth is not None:
            gt = planar_at(r.truth, r.truth.stamps_s)  # type: ignore[arg-type]
            poses = {m.method: m.poses for m in r.methods}
            truth_at = {m.method: planar_at(r.truth, m.stamps_s) for m in r.methods}
            stamps = {m.method: m.stamps_s for m in r.methods}
            for fmt in (".png", ".svg"):
                (tmp / f"paths{fmt}").write_bytes(figure_bytes(paths_figure(gt, poses), fmt))
                (tmp / f"errors{fmt}").write_bytes(figure_bytes(errors_figure(truth_at, poses, stamps), fmt))
    return Path(output)


def _write_closures(folder: Path, m: MethodRun) -> None:
    """METHOD+lc/closures.csv (every closure proposed, and what became of it) and
    graph.png/.svg (the optimised path and its closures)."""
    assert m.closures is not None
    rows = ["i,j,stamp_i_s,stamp_j_s,status,source,inliers,rms_m,sigma_x_m,sigma_y_m,sigma_yaw_rad,why_not"]
    accepted: list[tuple[int, int, str]] = []
    rejected: list[tuple[int, int, str]] = []
    for c in m.closures.closures:
        status = "accepted" if c.T_j_i is not None and not c.kernel_rejected else "rejected"
        (accepted if status == "accepted" else rejected).append((c.i, c.j, c.source))
        # The closure edge's 1-sigma (its fit's covariance; empty where it was not fitted).
        sig = "" if c.covariance is None else ",".join(f"{v:.3g}" for v in np.sqrt(np.diag(c.covariance)))
        rows.append(
            f"{c.i},{c.j},{float(m.stamps_s[c.i])!r},{float(m.stamps_s[c.j])!r},{status},{c.source},"
            f"{c.inliers:.3f},{c.rms_m:.4f},{sig or ',,'},{c.why_not}"
        )
    (folder / "closures.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    for fmt in (".png", ".svg"):
        (folder / f"graph{fmt}").write_bytes(figure_bytes(graph_figure(m.poses, accepted, rejected), fmt))
