"""``rigcal solve``: box-target extrinsic calibration from a picking file."""

from __future__ import annotations

import json
import shlex
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import click

from rigcal.calib.options import LOSS, NOISE, PICK_SIGMA_PX, RANGE_SIGMA_M, SEED, THRESHOLD_PX


@click.command("solve")
@click.argument("picks", type=click.Path(path_type=Path))
@click.option(
    "-o",
    "--output",
    "output",
    required=True,
    type=click.Path(path_type=Path),
    metavar="FILE",
    help="Rig file to write.",
)
@click.option(
    "--report", "report_dir", type=click.Path(path_type=Path), help="Folder for the residual report."
)
@click.option(
    "--truth", type=click.Path(path_type=Path), help="Truth file: also report the error against it."
)
@click.option("--seed", default=0, show_default=True, type=SEED, help="RANSAC random seed.")
@click.option(
    "--threshold-px",
    default=6.0,
    show_default=True,
    type=THRESHOLD_PX,
    help="RANSAC inlier threshold.",
)
@click.option(
    "--pick-sigma-px",
    default=1.0,
    show_default=True,
    type=PICK_SIGMA_PX,
    help="Pick noise (1 sigma).",
)
@click.option(
    "--range-sigma-m",
    type=RANGE_SIGMA_M,
    help="Range noise (1 sigma) [default: the picking file's laser.range_sigma_m, else 0.01].",
)
@click.option(
    "--noise",
    "noise_mode",
    default="auto",
    show_default=True,
    type=NOISE,
    help="auto: estimate the range and pick/corner noise from the session and use them (the "
    "assumed values are reported beside them); assumed: use --range-sigma-m, --pick-sigma-px "
    "and the session file's values.",
)
@click.option(
    "--range-bias/--no-range-bias",
    default=True,
    show_default=True,
    help="Board method: estimate the scanner's range bias by incidence (slanted boards read "
    "long) with the pose; its uncertainty enters the covariance.",
)
@click.option(
    "--loss",
    default="cauchy",
    show_default=True,
    type=LOSS,
    help="Robust loss of the refinement, both methods (the board method bends it at 3 sigmas of "
    "the whitened errors); linear: plain least squares, outliers still rejected by the gate.",
)
@click.option(
    "--intrinsics-sigma",
    "intrinsics_sigma",
    metavar="S1,S2,...",
    help="Board method: 1-sigma of each camera intrinsic, comma-separated in the lens model's "
    "order (fx,fy,cx,cy, then distortion); propagated into T's covariance and reported as the "
    "camera's share. Without it, a mrcal .cameramodel that keeps its optimization_inputs gives "
    "its own intrinsics covariance; other camera files are taken as exact and the report says so.",
)
@click.option(
    "--skip-unseen-boards",
    is_flag=True,
    help="Board method: leave out the captures whose image shows no board, with a warning each "
    "(without it they stop the solve, all named in one error).",
)
@click.option(
    "--paper-endpoints",
    is_flag=True,
    help="Use only the first/last laser returns of the box side, unweighted (the paper's method).",
)
@click.option("--force", is_flag=True, help="Overwrite an existing rig file / report folder.")
@click.option("--json", "as_json", is_flag=True, help="Print the summary as JSON on stdout.")
def solve(
    picks: Path,
    output: Path,
    report_dir: Path | None,
    truth: Path | None,
    seed: int,
    threshold_px: float,
    pick_sigma_px: float,
    range_sigma_m: float | None,
    noise_mode: str,
    range_bias: bool,
    loss: str,
    intrinsics_sigma: str | None,
    skip_unseen_boards: bool,
    paper_endpoints: bool,
    force: bool,
    as_json: bool,
) -> None:
    """Solve T_cam_laser from a box-target picking file, a board session or a marker session.

    For a box-target picking file, runs the paper's Algorithm 1: line extraction, RANSAC
    over P3P + Horn hypotheses, Levenberg-Marquardt refinement with covariance. For a board
    session (method: board) runs the plane method (docs/formats/board-session.md); for a
    marker session (method: marker) it reads the V marker target in every image and finds
    it in every scan, then runs the plane method on both faces
    (docs/formats/marker-session.md). Writes
    the rig file, and with --report a folder with report.yaml/json/txt (and, for the box
    method, one overlay PNG per capture). Prints the residual table (or JSON) on stdout.

    \b
    Examples:
      rigcal solve examples/box-session/picks.yaml -o rig.yaml
      rigcal solve session/picks.yaml -o rig.yaml --report report/ --force
      rigcal solve session/picks.yaml -o rig.yaml --truth session/truth.yaml --json
      rigcal solve board/board_session.yaml -o rig.yaml --report board-report/
      rigcal solve v/marker_session.yaml -o rig.yaml --report v-report/
    """
    from rigcal.calib.options import box_settings
    from rigcal.calib.report import report_table
    from rigcal.calib.session import calibrate, write_report_dir
    from rigcal.io.files import check_apart, check_folder_writable, check_writable
    from rigcal.rigfile import write_rig

    # Refuse before working: nothing is written unless everything can be.
    inputs = [picks, *([truth] if truth else [])]
    check_writable(output, force, inputs)
    if report_dir is not None:
        # The rig may go inside the report folder (it is written after it), not onto it.
        check_folder_writable(report_dir, force, inputs)
        check_apart(output, [report_dir])
    settings = box_settings(
        threshold_px=threshold_px,
        seed=seed,
        pick_sigma_px=pick_sigma_px,
        loss=loss,
        paper_endpoints=paper_endpoints,
        noise=noise_mode,
    )
    command = "rigcal " + shlex.join(sys.argv[1:]) if sys.argv else "rigcal solve"
    from rigcal.calib.board_session import is_board_session
    from rigcal.calib.marker_session import is_marker_session
    from rigcal.io.files import load_yaml

    sigmas = _sigma_list(intrinsics_sigma) if intrinsics_sigma is not None else None
    data = load_yaml(picks, "picking file")
    if is_board_session(data) or is_marker_session(data):
        _solve_board(
            picks,
            output,
            report_dir,
            truth,
            seed,
            range_sigma_m,
            noise_mode,
            range_bias,
            loss,
            sigmas,
            skip_unseen_boards,
            command,
            force,
            as_json,
            marker=is_marker_session(data),
        )
        return
    if sigmas is not None:
        from rigcal.errors import InputError

        raise InputError(
            f"--intrinsics-sigma: got {intrinsics_sigma!r}; the box method does not take the "
            "camera's uncertainty yet (only board sessions, method: board)"
        )
    # One rule for both methods: --range-sigma-m, else the file's laser.range_sigma_m.
    cal = calibrate(picks, settings, truth, command=command, range_sigma_m=range_sigma_m)
    _check_apart_from(output, report_dir, cal.session.input_files())
    if report_dir is not None:
        write_report_dir(report_dir, cal, force=force)
    write_rig(output, cal.rig, force=force)
    if as_json:
        doc = {k: cal.report[k] for k in ("summary", "noise", "uncertainty", "rejected", "warnings")}
        doc["rig_file"] = str(output)
        doc["rig"] = cal.rig.to_json()
        if "truth" in cal.report:
            doc["truth"] = cal.report["truth"]
        click.echo(json.dumps(doc, indent=1))
    else:
        click.echo(report_table(cal.report), nl=False)
        click.echo(f"wrote {output}" + (f" and {report_dir}/" if report_dir else ""), err=True)


def _sigma_list(text: str) -> list[float]:
    """--intrinsics-sigma's comma-separated numbers."""
    try:
        return [float(x) for x in text.split(",")]
    except ValueError:
        raise click.BadParameter(
            f"got {text!r}; expected comma-separated numbers such as 1.5,1.5,2,2,0.01",
            param_hint="--intrinsics-sigma",
        ) from None


def _check_apart_from(output: Path, report_dir: Path | None, files: Iterable[Path]) -> None:
    """The outputs against every file the session read (its scans, images, camera, lists)."""
    from rigcal.io.files import check_apart

    files = list(files)
    check_apart(output, files)
    if report_dir is not None:
        check_apart(report_dir, files)


def _solve_board(
    session: Path,
    output: Path,
    report_dir: Path | None,
    truth: Path | None,
    seed: int,
    range_sigma_m: float | None,
    noise_mode: str,
    range_bias: bool,
    loss: str,
    intrinsics_sigma: list[float] | None,
    skip_unseen_boards: bool,
    command: str,
    force: bool,
    as_json: bool,
    marker: bool = False,
) -> None:
    """A board session (``method: board``) or a marker session (``method: marker``): the
    plane method, then the same outputs."""
    import yaml

    from rigcal.calib.board_calibrate import board_report_table, calibrate_board
    from rigcal.calib.marker_calibrate import calibrate_marker, marker_report_table
    from rigcal.io.files import atomic_folder
    from rigcal.rigfile import write_rig
    from rigcal.viz.charts import figure_bytes
    from rigcal.viz.residual_plot import board_residuals_figure

    table = marker_report_table if marker else board_report_table
    kind = "marker" if marker else "board"
    if marker and intrinsics_sigma is not None:
        from rigcal.errors import InputError

        raise InputError(
            f"--intrinsics-sigma: got {','.join(f'{x:g}' for x in intrinsics_sigma)!r}; the marker "
            "method does not take the camera's uncertainty yet (only board sessions, method: board)"
        )
    if marker:
        cal: Any = calibrate_marker(
            session, range_sigma_m, truth, command, seed, noise_mode, range_bias, loss=loss
        )
    else:
        cal = calibrate_board(
            session,
            range_sigma_m,
            truth,
            command,
            seed,
            noise_mode,
            range_bias,
            loss=loss,
            intrinsics_sigma=intrinsics_sigma,
            skip_unseen_boards=skip_unseen_boards,
        )
    _check_apart_from(output, report_dir, cal.session.files)
    if report_dir is not None:
        with atomic_folder(report_dir, force) as tmp:
            (tmp / "report.yaml").write_text(
                f"# rigcal solve report, {kind} method (docs/formats/report.md)\n"
                + yaml.safe_dump(cal.report, sort_keys=False, default_flow_style=None, width=110)
            )
            (tmp / "report.json").write_text(json.dumps(cal.report, indent=1) + "\n")
            (tmp / "report.txt").write_text(table(cal.report))
            fig = board_residuals_figure(cal.report, cal.result.residuals_m)
            for fmt in (".png", ".svg"):
                (tmp / f"residuals{fmt}").write_bytes(figure_bytes(fig, fmt))
    write_rig(output, cal.rig, force=force)
    if as_json:
        doc = dict(cal.report)
        doc["rig_file"] = str(output)
        doc["rig"] = cal.rig.to_json()
        click.echo(json.dumps(doc, indent=1))
    else:
        click.echo(table(cal.report), nl=False)
        click.echo(f"wrote {output}" + (f" and {report_dir}/" if report_dir else ""), err=True)
