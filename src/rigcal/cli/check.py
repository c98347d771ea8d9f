"""``rigcal check``: has the rig moved since it was calibrated?"""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.io.validate import Real


@click.command("check")
@click.argument("rig", type=click.Path(path_type=Path))
@click.option(
    "--picks",
    required=True,
    type=click.Path(path_type=Path),
    help="Picking file of a new box-target session.",
)
@click.option(
    "--level",
    default=0.01,
    show_default=True,
    type=Real(min=1e-6, max=0.5),
    help="Chance of a false alarm when nothing moved.",
)
@click.option(
    "--min-captures",
    default=5,
    show_default=True,
    type=click.IntRange(min=3),
    help="Captures needed for a fresh solve (fewer: residual test only).",
)
@click.option(
    "--log",
    "log_path",
    type=click.Path(path_type=Path),
    help="Drift log to append to [default: RIG's name with .checks.jsonl beside it].",
)
@click.option("--no-log", is_flag=True, help="Do not append this check to the drift log.")
@click.option(
    "--plot",
    type=click.Path(path_type=Path),
    help="Also draw the drift history (the log) as a chart: .png, .svg or .pdf.",
)
@click.option("--force", is_flag=True, help="Overwrite an existing plot.")
@click.option("--json", "as_json", is_flag=True, help="Print the result as JSON on stdout.")
def check(
    rig: Path,
    picks: Path,
    level: float,
    min_captures: int,
    log_path: Path | None,
    no_log: bool,
    plot: Path | None,
    force: bool,
    as_json: bool,
) -> int:
    """Test a new box-target session against the calibration in RIG.

    The new picks are reprojected with the stored T_cam_laser and their errors tested
    against the noise and the rig's uncertainty (chi-square); with enough captures a fresh
    solve is also compared with the stored pose (Mahalanobis distance over both
    covariances, chi-square with 6 dof). Exit code 0 when the rig is ok, 1 when it has
    drifted, 2 for usage errors, 3 for bad input. Each check is appended to a drift log
    beside the rig.

    \b
    Examples:
      rigcal check rig.yaml --picks today/picks.yaml
      rigcal check rig.yaml --picks today/picks.yaml --json --no-log
      rigcal check rig.yaml --picks today/picks.yaml --plot drift.png --force
      rigcal check rig.yaml --picks today/picks.yaml || echo "recalibrate the rig"
    """
    from rigcal.calib.drift import DriftSettings, check_drift
    from rigcal.calib.driftlog import append_record, default_log_path, drift_record, read_log
    from rigcal.calib.picks import read_picks
    from rigcal.errors import InputError, OutputError
    from rigcal.io.files import check_apart, check_writable
    from rigcal.rigfile import read_rig
    from rigcal.viz.drift_plot import write_drift_plot

    log = log_path or default_log_path(rig)
    check_apart(log, [rig, picks])
    if (plot is not None or not no_log) and log.is_dir():  # an output where a file goes: exit 5
        raise OutputError(f"{log}: is a folder; expected the drift log's file path (--log)")
    if plot is not None:
        from rigcal.viz.charts import check_chart_name

        check_writable(plot, force, [rig, picks, log])
        check_chart_name(plot)
    stored = read_rig(rig)
    if stored.covariance is None:
        raise InputError(
            f"{rig}: uncertainty: missing; a drift check needs the stored calibration's covariance "
            "(re-solve the rig with `rigcal solve`)"
        )
    session = read_picks(picks)
    result = check_drift(stored, session, DriftSettings(level=level, min_captures_for_solve=min_captures))
    record = drift_record(result, picks)
    # The plot (the history and this check) first: a failure there leaves the log as it was.
    history = read_log(log) if (plot is not None or not no_log) and log.exists() else []
    if plot is not None:
        write_drift_plot(plot, [*history, record], force=force)
    if not no_log:
        append_record(log, record)
    if as_json:
        click.echo(json.dumps(record, indent=1))
    else:
        click.echo(_summary(record))
    if not no_log:
        click.echo(f"appended to {log}" + (f"; drew {plot}" if plot else ""), err=True)
    return 1 if result.drifted else 0


def _summary(record: dict[str, object]) -> str:
    r = record["residual"]
    assert isinstance(r, dict)
    lines = [
        f"verdict: {record['verdict']} (false-alarm level {record['level']})",
        f"residual test: {r['used_ends']}/{r['ends']} box ends, RMS {_px(r['rms_px'])} px under the stored "
        f"calibration, chi2 {r['chi2']:.1f} over {r['dof']} dof, p = {r['p_value']:.3g}",
    ]
    pose = record["pose"]
    if isinstance(pose, dict):
        lines.append(
            f"pose test: fresh solve differs by {pose['rotation_deg']:.4f} deg and "
            f"{pose['translation_mm']:.2f} mm; Mahalanobis^2 {pose['mahalanobis2']:.2f} (6 dof), "
            f"p = {pose['p_value']:.3g}"
        )
    reasons = record["reasons"]
    assert isinstance(reasons, list)
    lines += [f"note: {x}" for x in reasons]
    return "\n".join(lines)


def _px(value: object) -> str:
    """A pixel figure of a record, or n/a (null: no box end within the gate)."""
    return f"{value:.2f}" if isinstance(value, (int, float)) else "n/a"
