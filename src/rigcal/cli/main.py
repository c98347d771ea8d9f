"""The ``rigcal`` command: a click group and the one error boundary.

Each command lives in its own thin module (parse -> call one library function -> write ->
summary) and imports the heavy libraries inside its body, so ``rigcal --help`` is instant.
A :class:`~rigcal.errors.RigcalError` becomes one ``Error: ...`` line on stderr and the
exit code of its class (docs/cli.md); anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import os
import sys

import click

from rigcal import __version__
from rigcal.cli import batch as batch_cmd
from rigcal.cli import capture as capture_cmd
from rigcal.cli import check as check_cmd
from rigcal.cli import export as export_cmd
from rigcal.cli import import_bag as import_bag_cmd
from rigcal.cli import import_carmen as import_carmen_cmd
from rigcal.cli import import_laser as import_laser_cmd
from rigcal.cli import intrinsics as intrinsics_cmd
from rigcal.cli import lines as lines_cmd
from rigcal.cli import localize as localize_cmd
from rigcal.cli import pick as pick_cmd
from rigcal.cli import project as project_cmd
from rigcal.cli import simulate as simulate_cmd
from rigcal.cli import solve as solve_cmd
from rigcal.cli import targets as targets_cmd
from rigcal.cli import warm_up as warm_up_cmd
from rigcal.errors import RigcalError


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="rigcal")
@click.option("-v", "--verbose", count=True, help="More log output on stderr (-v info, -vv debug).")
@click.option("-q", "--quiet", is_flag=True, help="No progress bars or log output below errors.")
@click.pass_context
def cli(ctx: click.Context, verbose: int, quiet: bool) -> None:
    """Laser-camera extrinsic calibration and image-augmented laser scan matching.

    \b
    Examples:
      rigcal lines session/scans/cap00.yaml --png lines.png
      rigcal solve session/picks.yaml -o rig.yaml --report report/
      rigcal project rig.yaml session/scans/cap00.yaml session/images/cap00.png -o overlay.png
      rigcal check rig.yaml --picks today/picks.yaml
      rigcal export rig.yaml --format ros
      rigcal intrinsics calib/*.jpg --board 9x6 --square-m 0.025 -o camera.cameramodel
      rigcal simulate box-session -o session/ --seed 1
      rigcal targets print targets.yaml -o print/
      rigcal -q localize corridor/ --method icp -o out/ --json
      rigcal batch fleet.yaml -o nightly/ --ray auto
      rigcal warm-up
    """
    from rigcal.cli.progress import configure

    ctx.obj = {"verbose": verbose, "quiet": quiet}
    configure(verbose, quiet)


cli.add_command(solve_cmd.solve)
cli.add_command(lines_cmd.lines)
cli.add_command(project_cmd.project)
cli.add_command(simulate_cmd.simulate)
cli.add_command(check_cmd.check)
cli.add_command(export_cmd.export)
cli.add_command(intrinsics_cmd.intrinsics)
cli.add_command(import_bag_cmd.import_bag)
cli.add_command(import_carmen_cmd.import_carmen)
cli.add_command(localize_cmd.localize)
cli.add_command(localize_cmd.evaluate_cmd, name="evaluate")
cli.add_command(localize_cmd.matches)
cli.add_command(batch_cmd.batch)
cli.add_command(pick_cmd.pick)
cli.add_command(capture_cmd.capture)
cli.add_command(import_laser_cmd.import_laser)
cli.add_command(warm_up_cmd.warm_up)
cli.add_command(targets_cmd.targets)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the console script; returns the process exit code."""
    # OpenCV's own log lines (e.g. about a broken PNG) would come before rigcal's one error
    # line; it reads this when first imported, which the commands do in their bodies.
    os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")
    args = sys.argv[1:] if argv is None else argv
    for a in args:  # no file system accepts a NUL byte; say so before any command runs
        if "\0" in str(a):
            click.echo(f"Error: {str(a)!r}: an argument with a NUL byte; expected none", err=True)
            return 2
    try:
        rv = cli.main(args=args, prog_name="rigcal", standalone_mode=False)
    except RigcalError as exc:
        click.echo(f"Error: {exc}", err=True)
        return exc.exit_code
    except click.UsageError as exc:  # one line, like every other error
        cmd = exc.ctx.command_path if exc.ctx is not None else "rigcal"
        click.echo(f"Error: {exc.format_message()} (see '{cmd} --help')", err=True)
        return exc.exit_code
    except click.exceptions.Abort:
        click.echo("Aborted.", err=True)
        return 130
    except click.ClickException as exc:
        exc.show()
        return exc.exit_code
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    # A command may return its exit code (e.g. a check's verdict); None means success.
    return rv if isinstance(rv, int) else 0


def entry() -> None:  # pragma: no cover - the console script
    sys.exit(main())
