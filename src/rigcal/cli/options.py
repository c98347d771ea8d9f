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


def json_option(help: str) -> Callable[[Any], Any]:
    """``--json``: the result as JSON on stdout (``as_json``), for scripts."""
    return click.option("--json", "as_json", is_flag=True, help=help)
