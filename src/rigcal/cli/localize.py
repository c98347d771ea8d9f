"""``rigcal localize`` and ``rigcal evaluate``: trajectories from sequences, and their errors."""

from __future__ import annotations

import json
from pathlib import Path

import click


@click.command("localize")
@click.argument("sequence", type=click.Path(path_type=Path))
@click.option(
    "--method",
    default="icp",
    show_default=True,
    help="icp (point-to-line) or icp-p2p (point-to-point, Eq. 4).",
)
@click.option(
    "-o", "--output", required=True, type=click.Path(path_type=Path, file_okay=False), help="Output folder."
)
@click.option("--kitti", is_flag=True, help="Also write the trajectory in KITTI form.")
@click.option("--force", is_flag=True, help="Replace an existing output folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON.")
def localize(sequence: Path, method: str, output: Path, kitti: bool, force: bool, as_json: bool) -> None:
    """Estimate the laser's trajectory through SEQUENCE (a sequence folder).

    Writes trajectory.tum (and trajectory.kitti), summary.yaml/json with the configuration,
    timings and, when the sequence has ground truth, the paper's Table 1 figures.

    \b
    Examples:
      rigcal simulate world --world corridor-loop -o corridor/
      rigcal localize corridor/ --method icp -o out/icp
    """
    from rigcal.errors import OutputError
    from rigcal.localize.pipeline import run

    if output.exists() and not force:
        raise OutputError(f"{output}: exists; pass --force to replace it")
    r = run(sequence, method, output, force=force, kitti=kitti)
    if as_json:
        click.echo(json.dumps({"metrics": r.metrics, "timings_s": r.timings_s}, indent=1))
    elif r.metrics is not None:
        click.echo(_table(method, r.metrics))
    click.echo(
        f"wrote {output}/: {len(r.stamps_s)} poses; {r.degenerate_steps} degenerate steps; "
        f"{1000 * r.timings_s['estimate_s'] / len(r.stamps_s):.1f} ms per scan",
        err=True,
    )


@click.command("evaluate")
@click.argument("trajectory", type=click.Path(path_type=Path))
@click.option("--gt", required=True, type=click.Path(path_type=Path), help="Ground truth (TUM).")
@click.option("--json", "as_json", is_flag=True, help="Print the figures as JSON.")
def evaluate_cmd(trajectory: Path, gt: Path, as_json: bool) -> None:
    """Score a TUM TRAJECTORY against ground truth the way the paper's Table 1 does, plus
    ATE (SE(2)-aligned) and RPE over 1 m and 10 m as evo computes them.

    \b
    Examples:
      rigcal evaluate out/icp/trajectory.tum --gt corridor/groundtruth.tum
    """
    from rigcal.io.trajectory import read_tum
    from rigcal.localize.metrics import evaluate
    from rigcal.localize.pipeline import planar_at

    est = read_tum(trajectory)
    truth = read_tum(gt)
    assert est.stamps_s is not None
    m = evaluate(planar_at(est, est.stamps_s), planar_at(truth, est.stamps_s))
    click.echo(json.dumps(m, indent=1) if as_json else _table(trajectory.name, m))


def _table(label: str, m: dict[str, object]) -> str:
    head = (
        "| method | loop closure (m) | loop closure (%) | avg position error (m) | ATE RMSE (m) "
        "| RPE 1 m | RPE 10 m |"
    )
    keys = ("loop_closure_error_m", "loop_closure_error_percent", "average_position_error_m", "ate_rmse_m")
    row = " | ".join(str(m[k]) for k in (*keys, "rpe_1m_rmse_m", "rpe_10m_rmse_m"))
    return f"{head}\n|---|---|---|---|---|---|---|\n| {label} | {row} |"
