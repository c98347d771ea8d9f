"""``rigcal targets``: describe and print calibration targets."""

from __future__ import annotations

import json
from pathlib import Path

import click

from rigcal.cli.options import force_option, json_option, output_option
from rigcal.cli.types import Real


@click.group("targets")
def targets() -> None:
    """Describe and print the marker target (docs/formats/targets.md).

    \b
    Examples:
      rigcal targets new -o targets.yaml
      rigcal targets print targets.yaml -o print/
    """


@targets.command("new")
@output_option("Targets file to write.")
@force_option("Overwrite an existing file.")
@json_option("Print what was written as JSON on stdout.")
def new(output: Path, force: bool, as_json: bool) -> None:
    """Write the default V target's targets file (two 0.5 x 0.6 m faces at 90 degrees,
    4 x 5 ChArUco squares of 110 mm, DICT_4X4_50) to edit and print.

    \b
    Examples:
      rigcal targets new -o targets.yaml
    """
    from rigcal.io.files import atomic_write_text, check_writable
    from rigcal.targets.marker import default_target, targets_text

    check_writable(output, force)
    atomic_write_text(output, targets_text(default_target()), force=force)
    if as_json:
        click.echo(json.dumps({"output": str(output)}))
        return
    click.echo(f"wrote {output}; print it with: rigcal targets print {output} -o print/", err=True)


@targets.command("print")
@click.argument("targets_file", type=click.Path(path_type=Path))
@output_option("Folder to create.", "DIR")
@click.option(
    "--dpi",
    default=300.0,
    show_default=True,
    type=Real(min=50.0, max=1200.0),
    help="Resolution of the pages.",
)
@force_option("Replace an existing folder.")
@json_option("Print the files written as JSON on stdout.")
def print_cmd(targets_file: Path, output: Path, dpi: float, force: bool, as_json: bool) -> None:
    """Write one printable page per face (PNG and PDF at true scale, with its ids and a
    100 mm measuring bar) and the targets file beside them. Print at 100 % (no "fit to
    page"), measure the bar, cut along the grey line and glue each face on its side of
    the V, the pattern the right way up (the text strip below it).

    \b
    Examples:
      rigcal targets print targets.yaml -o print/
      rigcal targets print targets.yaml -o print/ --dpi 600 --force
    """
    from rigcal.io.files import check_folder_writable
    from rigcal.targets.marker import read_targets
    from rigcal.targets.marker_print import write_print

    check_folder_writable(output, force, [targets_file])
    target = read_targets(targets_file)
    files = write_print(target, output, dpi=dpi, force=force)
    if as_json:
        click.echo(
            json.dumps({"output": str(output), "files": [str(f) for f in files], "dpi": dpi}, indent=1)
        )
        return
    sizes = ", ".join(f"{f.name} {1000 * f.width_m:g} x {1000 * target.edge_m:g} mm" for f in target.faces)
    click.echo(
        f"wrote {len(files)} files to {output}/ (faces: {sizes}); print at 100 % and measure the bar",
        err=True,
    )
