"""The importers' shared options: how stamps are repaired, where the laser sits on the base."""

from __future__ import annotations

from typing import TYPE_CHECKING

import click

from rigcal.cli.options import choice_option

if TYPE_CHECKING:
    from rigcal.io.log_lines import CutLine
    from rigcal.io.stamps import StampRepair

stamps_option = choice_option(
    "--stamps",
    ["repair", "strict"],
    "repair: equal stamps and small steps back are placed evenly between their increasing "
    "neighbours, and an incomplete last line (a log cut short) is left out, each with one warning "
    "(docs/formats/sequence.md); strict: refuse them.",
)

laser_offset_option = click.option(
    "--laser-offset",
    metavar="X,Y,YAW_DEG",
    help="The laser's pose on the robot base (m, m, deg) for the wheel odometry.",
)


def warn_stamps(repair: StampRepair | None, what: str) -> None:
    """Print the stamp repair's one warning line (stderr), if it did anything."""
    msg = repair.message(what) if repair is not None else None
    if msg:
        click.echo(f"warning: {msg}", err=True)


def warn_cut(cut: CutLine | None, path: object) -> None:
    """Print the one warning line of a log's incomplete last line left out (stderr), if any."""
    if cut is not None:
        click.echo(f"warning: {cut.warning(path)}", err=True)
