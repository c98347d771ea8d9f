"""The command line's option types, each applying a rule of :mod:`rigcal.io.validate`
(the rule the Python API checks its keywords with): :func:`option_type` turns a rule into
its click type. A bad value is click's usage error (exit code 2)."""

from __future__ import annotations

import math
import re
from typing import Any

import click

from rigcal.io import validate


class Real(click.FloatRange):
    """A float option: finite (no ``nan``, ``inf``), optionally within a range."""

    name = "float"

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        """The arguments of :class:`rigcal.io.validate.Real` (``min``, ``max``, ``min_open``,
        ``max_open``)."""
        self.rule = r = validate.Real(*args, **kwargs)
        super().__init__(r.min, r.max, min_open=r.min_open, max_open=r.max_open)

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        out = super().convert(value, param, ctx)
        if not math.isfinite(out):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return out


class GridSize(click.ParamType):
    """A ``WxH`` option (a board's inner corners or squares, an image's pixels): two whole
    numbers from 2 to 99999, as (W, H)."""

    name = "WxH"

    def __init__(self, example: str = "9x6") -> None:
        self.example = example

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, tuple):
            return value
        m = re.fullmatch(r"([0-9]{1,5})x([0-9]{1,5})", value)
        if not m or int(m[1]) < 2 or int(m[2]) < 2:
            shown = value if len(value) < 40 else value[:37] + "..."
            self.fail(
                f"{shown!r}: expected WxH with whole numbers from 2 to 99999, e.g. {self.example}", param, ctx
            )
        return int(m[1]), int(m[2])


def option_type(rule: validate.Real | validate.Whole | validate.OneOf) -> click.ParamType:
    """The click type of an option that follows ``rule``."""
    if isinstance(rule, validate.Real):
        return Real(rule.min, rule.max, rule.min_open, rule.max_open)
    if isinstance(rule, validate.Whole):
        return click.IntRange(rule.min, rule.max)
    return click.Choice(rule.choices)
