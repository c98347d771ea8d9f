"""``rigcal solve``: box-target extrinsic calibration from a picking file."""

from __future__ import annotations

import math
import shlex
import sys
from pathlib import Path
from typing import Any

import click

from rigcal.calib.options import LOSS, NOISE, PICK_SIGMA_PX, RANGE_SIGMA_M, SEED, THRESHOLD_PX
from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.types import option_type


@click.command("solve")
@click.argument("picks", type=click.Path(path_type=Path))
@output_option("Rig file to write.")
@click.option(
    "--report", "report_dir", type=click.Path(path_type=Path), help="Folder for the residual report."
)
@click.option(
    "--truth", type=click.Path(path_type=Path), help="Truth file: also report the error against it."
)
@click.option("--seed", default=0, show_default=True, type=option_type(SEED), help="RANSAC random seed.")
@click.option(
    "--threshold-px",
    default=6.0,
    show_default=True,
    type=option_type(THRESHOLD_PX),
    help="RANSAC inlier threshold.",
)
@click.option(
    "--pick-sigma-px",
    default=1.0,
    show_default=True,
    type=option_type(PICK_SIGMA_PX),
    help="Pick noise (1 sigma).",
)
@click.option(
    "--range-sigma-m",
    type=option_type(RANGE_SIGMA_M),
    help="Range noise (1 sigma) [default: the picking file's laser.range_sigma_m, else 0.01].",
)
@click.option(
    "--noise",
    "noise_mode",
    default="auto",
    show_default=True,
    type=option_type(NOISE),
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
    type=option_type(LOSS),
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
    "--level-prior",
    "level_prior",
    multiple=True,
    nargs=3,
    type=(click.Choice(["roll_deg", "pitch_deg", "camera_height_m"]), float, float),
    metavar="NAME VALUE SIGMA",
    help="Board method, boards that never tilt: the reduced solve (yaw and the camera's "
    "position in the scan plane) for a level scanner, with NAME's measured VALUE and 1-sigma "
    "as a prior; give all three: roll_deg, pitch_deg (the scanner's tilt from level) and "
    "camera_height_m (the camera centre's height above the scan plane). Over the session's level:.",
)
@click.option(
    "--paper-endpoints",
    is_flag=True,
    help="Use only the first/last laser returns of the box side, unweighted (the paper's method).",
)
@force_option("Overwrite an existing rig file / report folder.")
@json_option("Print the summary as JSON on stdout.")
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
    level_prior: tuple[tuple[str, float, float], ...],
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
      rigcal solve wall/board_session.yaml -o rig.yaml --level-prior roll_deg 0 0.5 \\
        --level-prior pitch_deg 0 0.5 --level-prior camera_height_m 0.12 0.005
      rigcal solve v/marker_session.yaml -o rig.yaml --report v-report/
    """
    from rigcal.jobs import as_json as json_text
    from rigcal.jobs import solve_files

    done = solve_files(
        picks,
        output,
        command="rigcal " + shlex.join(sys.argv[1:]) if sys.argv else "rigcal solve",
        report_dir=report_dir,
        truth=truth,
        seed=seed,
        threshold_px=threshold_px,
        pick_sigma_px=pick_sigma_px,
        range_sigma_m=range_sigma_m,
        noise=noise_mode,
        range_bias=range_bias,
        loss=loss,
        intrinsics_sigma=_sigma_list(intrinsics_sigma) if intrinsics_sigma is not None else None,
        skip_unseen_boards=skip_unseen_boards,
        paper_endpoints=paper_endpoints,
        level=_level_priors(level_prior) if level_prior else None,
        force=force,
    )
    if as_json:
        click.echo(json_text(done.doc))
    else:
        click.echo(done.table, nl=False)
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


def _level_priors(given: tuple[tuple[str, float, float], ...]) -> Any:
    """--level-prior's triples as :class:`rigcal.calib.board.level.LevelPriors` (all three names,
    once each, finite values, sigmas > 0)."""
    from rigcal.calib.board.level import LevelPriors
    from rigcal.errors import InputError

    names = ("roll_deg", "pitch_deg", "camera_height_m")
    out: dict[str, tuple[float, float]] = {}
    for name, value, sigma in given:
        if name in out:
            raise InputError(f"--level-prior: {name} given twice; expected each of {', '.join(names)} once")
        if not (math.isfinite(value) and math.isfinite(sigma) and sigma > 0):
            raise InputError(
                f"--level-prior: {name}: got value {value:g}, sigma {sigma:g}; expected a finite value "
                "and a 1-sigma > 0"
            )
        out[name] = (value, sigma)
    missing = [n for n in names if n not in out]
    if missing:
        raise InputError(
            f"--level-prior: {', '.join(missing)} missing; the reduced solve needs all three priors "
            "(roll_deg, pitch_deg, camera_height_m), each as NAME VALUE SIGMA"
        )
    return LevelPriors(out["roll_deg"], out["pitch_deg"], out["camera_height_m"])
