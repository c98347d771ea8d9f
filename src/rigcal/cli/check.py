"""``rigcal check``: has the rig moved since it was calibrated?"""

from __future__ import annotations

import os
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, wheel_odometry_option
from rigcal.cli.types import option_type
from rigcal.jobs import LEVEL, MIN_CAPTURES


@click.command("check")
@click.argument("rig", type=click.Path(path_type=Path))
@click.option(
    "--picks",
    type=click.Path(path_type=Path),
    help="Picking file of a new box-target session.",
)
@click.option(
    "--session",
    type=click.Path(path_type=Path),
    help="A new session file: a board session (method: board) or a box picking file.",
)
@click.option(
    "--sequence",
    type=click.Path(path_type=Path),
    help="A drive (sequence folder with images): the targetless check.",
)
@click.option(
    "--trajectory",
    type=click.Path(path_type=Path),
    help="With --sequence: the laser's poses over the drive (a TUM file, e.g. a `rigcal localize` "
    "run's METHOD/trajectory.tum) instead of the check's own laser odometry.",
)
@wheel_odometry_option(
    "With --sequence: use: the check's laser odometry starts each step from the drive's wheel "
    "odometry (when it has one); ignore: from the previous motion, without reading odometry.tum."
)
@click.option(
    "--level",
    default=0.01,
    show_default=True,
    type=option_type(LEVEL),
    help="Chance of a false alarm when nothing moved.",
)
@click.option(
    "--min-captures",
    default=5,
    show_default=True,
    type=option_type(MIN_CAPTURES),
    help="Captures needed for a fresh solve of a box session (fewer: residual test only).",
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
@force_option("Overwrite an existing plot.")
@json_option("Print the result as JSON on stdout.")
def check(
    rig: Path,
    picks: Path | None,
    session: Path | None,
    sequence: Path | None,
    trajectory: Path | None,
    wheel_odometry: str,
    level: float,
    min_captures: int,
    log_path: Path | None,
    no_log: bool,
    plot: Path | None,
    force: bool,
    as_json: bool,
) -> int:
    """Test the calibration in RIG against a new box session, a board session or a drive.

    With --picks (or --session of a box picking file) the new picks are reprojected with
    the stored T_cam_laser and their errors tested against the noise and the rig's
    uncertainty (chi-square); with enough captures a fresh solve is also compared with
    the stored pose (Mahalanobis distance over both covariances, chi-square with 6 dof).
    With --session of a board session, the board returns' distances from their planes
    and a fresh board solve are tested alike, whatever method solved RIG.

    With --sequence, no target: the drive's laser returns are projected into the frames
    that see them and T_cam_laser is corrected to make them photometrically consistent
    (IASM's projection, paper Section III); the correction is tested on the directions the
    drive observes, and those it does not are named with why. The laser's motion comes
    from the check's own laser odometry, or with --trajectory from a TUM file of the
    laser's poses covering the drive's images to within 0.05 s (a `rigcal localize` run's; its stamps must
    increase, with no gap over 0.5 s). The check's own odometry starts each ICP step from
    the drive's wheel odometry (odometry.tum) unless --wheel-odometry ignore.

    Exit code 0 when the rig is ok, 1 when it has drifted, 6 when the drive cannot tell
    (too short, no camera-laser overlap, no motion that observes the rig), 2 for usage
    errors, 3 for bad input. Each check is appended to a drift log beside the rig.

    \b
    Examples:
      rigcal check rig.yaml --picks today/picks.yaml
      rigcal check rig.yaml --session today/board_session.yaml --json --no-log
      rigcal check rig.yaml --sequence drives/2026-11-26/ --plot drift.png --force
      rigcal check rig.yaml --sequence drives/today/ --trajectory runs/today/kf/trajectory.tum
      rigcal check rig.yaml --sequence drives/today/ --wheel-odometry ignore --no-log
      rigcal check rig.yaml --sequence drives/today/ || echo "recalibrate, or drive more"
    """
    from rigcal.cli.progress import Progress
    from rigcal.jobs import as_json as json_text
    from rigcal.jobs import check_rig

    given = [p for p in (picks, session, sequence) if p]
    if len(given) != 1:
        raise click.UsageError("give one of --picks, --session or --sequence")
    if sequence is not None:
        # The targetless check keeps both cores busy with threads of its own; OpenBLAS's
        # threads, spinning while they wait beside them, cost about a CPU second of the
        # check's ten and gain nothing on its small products (the results are the same).
        # Read when numpy loads OpenBLAS, which no import above has done.
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    if trajectory is not None and sequence is None:
        raise click.UsageError("--trajectory goes with --sequence (a drive's laser poses)")
    if wheel_odometry != "use" and sequence is None:
        raise click.UsageError("--wheel-odometry goes with --sequence (a drive's wheel odometry)")
    with Progress("frame") as bars:
        done = check_rig(
            rig,
            picks=picks,
            session=session,
            sequence=sequence,
            trajectory=trajectory,
            wheel_odometry=wheel_odometry == "use",
            level=level,
            min_captures=min_captures,
            log=log_path,
            no_log=no_log,
            plot=plot,
            force=force,
            progress=bars,
        )
    click.echo(json_text(done.record) if as_json else _summary(done.record))
    if done.log is not None:
        click.echo(f"appended to {done.log}" + (f"; drew {plot}" if plot else ""), err=True)
    return done.exit_code


def _summary(record: dict[str, object]) -> str:
    kind = record.get("kind", "box")
    what = "" if kind == "box" else f"{kind} check, "
    lines = [f"verdict: {record['verdict']} ({what}false-alarm level {record['level']})"]
    r = record["residual"]
    if isinstance(r, dict) and "ends" in r:
        lines.append(
            f"residual test: {r['used_ends']}/{r['ends']} box ends, RMS {_px(r['rms_px'])} px under the "
            f"stored calibration, chi2 {r['chi2']:.1f} over {r['dof']} dof, p = {r['p_value']:.3g}"
        )
    elif isinstance(r, dict):
        lines.append(
            f"residual test: {r['used_captures']}/{r['captures']} board captures, RMS {_px(r['rms_mm'])} mm "
            f"off their planes under the stored calibration, chi2 {r['chi2']:.1f} over {r['dof']} dof, "
            f"p = {r['p_value']:.3g}"
        )
    pose = record["pose"]
    if isinstance(pose, dict):
        lines.append(
            f"pose test: fresh solve differs by {pose['rotation_deg']:.4f} deg and "
            f"{pose['translation_mm']:.2f} mm; Mahalanobis^2 {pose['mahalanobis2']:.2f} (6 dof), "
            f"p = {pose['p_value']:.3g}"
        )
    t = record.get("targetless")
    if isinstance(t, dict) and "t2" in t:
        lines.append(
            f"drive: {t['duration_s']:.1f} s, {t['travel_m']:.1f} m, {t['patches']} patches in {t['blocks']} "
            f"blocks; observed: {', '.join(t['observed_axes']) or 'none'}"
        )
        lines.append(
            f"correction (laser frame): rotation {_vec(t['correction_rotation_deg'])} deg "
            f"(1 sigma {_vec(t['sigma_rotation_deg'])}), "
            f"translation {_vec(t['correction_translation_mm'])} mm "
            f"(1 sigma {_vec(t['sigma_translation_mm'])})"
        )
        lines.append(f"test: T^2 {t['t2']:.2f} over {t['dof']} directions, p = {t['p_value']:.3g}")
    reasons = record["reasons"]
    assert isinstance(reasons, list)
    lines += [f"note: {x}" for x in reasons]
    return "\n".join(lines)


def _vec(v: object) -> str:
    assert isinstance(v, list)
    return "[" + ", ".join(f"{x:.3f}" if isinstance(x, (int, float)) else "n/a" for x in v) + "]"


def _px(value: object) -> str:
    """A pixel figure of a record, or n/a (null: no box end within the gate)."""
    return f"{value:.2f}" if isinstance(value, (int, float)) else "n/a"
