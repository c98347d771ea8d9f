"""Option blocks several commands share, declared once."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import click


def output_option(
    help: str,
    metavar: str = "FILE",
    *,
    file_okay: bool = True,
    dir_okay: bool = True,
    required: bool = True,
) -> Callable[[Any], Any]:
    """``-o/--output PATH``: the file or folder a command writes (a :class:`~pathlib.Path`)."""
    return click.option(
        "-o",
        "--output",
        "output",
        required=required,
        type=click.Path(path_type=Path, file_okay=file_okay, dir_okay=dir_okay),
        metavar=metavar,
        help=help,
    )


def force_option(help: str) -> Callable[[Any], Any]:
    """``--force``: replace what the command's outputs would overwrite."""
    return click.option("--force", is_flag=True, help=help)


def choice_option(flag: str, choices: list[str], help: str) -> Callable[[Any], Any]:
    """``FLAG CHOICE``: one of ``choices``, the first the default (shown in --help)."""
    return click.option(flag, type=click.Choice(choices), default=choices[0], show_default=True, help=help)


def wheel_odometry_option(help: str) -> Callable[[Any], Any]:
    """``--wheel-odometry use|ignore``: whether a run uses the sequence's odometry.tum."""
    return choice_option("--wheel-odometry", ["use", "ignore"], help)


def json_option(help: str) -> Callable[[Any], Any]:
    """``--json``: the result as JSON on stdout (``as_json``), for scripts."""
    return click.option("--json", "as_json", is_flag=True, help=help)


def board_options(f: Callable[..., Any]) -> Callable[..., Any]:
    """The board a command detects: ``--board WxH`` (a chessboard's inner corners) or
    ``--charuco WxH`` (squares) with ``--marker-m`` and ``--dictionary``, and ``--square-m``.
    The sizes arrive as (W, H) (:class:`rigcal.cli.types.GridSize`)."""
    from rigcal.cli.types import GridSize, Real

    for option in reversed(
        [
            click.option(
                "--board",
                type=GridSize("9x6"),
                help="Chessboard: inner corners per row x per column, e.g. 9x6.",
            ),
            click.option(
                "--charuco",
                type=GridSize("8x6"),
                help="ChArUco board instead: squares per row x per column, e.g. 8x6.",
            ),
            click.option(
                "--marker-m", type=Real(min=0.0, min_open=True), help="ChArUco marker size, metres."
            ),
            click.option(
                "--dictionary",
                default="DICT_5X5_100",
                show_default=True,
                help="ChArUco's ArUco dictionary (cv2.aruco name).",
            ),
            click.option(
                "--square-m", required=True, type=Real(min=0.0, min_open=True), help="Square size, metres."
            ),
        ]
    ):
        f = option(f)
    return f
