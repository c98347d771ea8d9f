"""Options every command shares: one `-o` metavar per kind of output, `--json` wherever
a result is written."""

from __future__ import annotations

import click
import pytest

from rigcal.cli.main import cli


def _commands(group: click.Group, prefix: str = "") -> dict[str, click.Command]:
    out: dict[str, click.Command] = {}
    for name, cmd in group.commands.items():
        if cmd.hidden:
            continue
        if isinstance(cmd, click.Group):
            out |= _commands(cmd, f"{prefix}{name} ")
        else:
            out[f"{prefix}{name}"] = cmd
    return out


COMMANDS = _commands(cli)
WRITE_FOLDERS = {
    "batch",
    "capture",
    "import-bag",
    "import-carmen",
    "import-laser",
    "localize",
    "simulate",
    "targets print",
}


def test_output_metavar_says_folder_or_file():
    seen = {}
    for name, cmd in COMMANDS.items():
        for p in cmd.params:
            if isinstance(p, click.Option) and "-o" in p.opts:
                seen[name] = p.metavar
    assert len(seen) >= 14
    for name, metavar in seen.items():
        folder = name in WRITE_FOLDERS or name.split()[0] in WRITE_FOLDERS
        assert metavar == ("DIR" if folder else "FILE"), name


def test_every_command_with_a_result_has_json():
    no_result = {"warm-up"}  # compiles kernels; its only output is numba's cache
    for name, cmd in COMMANDS.items():
        flags = {o for p in cmd.params if isinstance(p, click.Option) for o in p.opts}
        assert ("--json" in flags) != (name in no_result), name


def test_option_types_apply_the_rules_the_api_checks():
    """A value the command line refuses is refused by the rule the API checks, and the
    other way round (rigcal.cli.types.option_type over rigcal.io.validate's rules)."""
    from rigcal.calib import options
    from rigcal.cli.types import option_type
    from rigcal.errors import InputError
    from rigcal.jobs import LEVEL, MAX_DIFF_S, MIN_CAPTURES

    rules = [
        options.THRESHOLD_PX,
        options.PICK_SIGMA_PX,
        options.RANGE_SIGMA_M,
        options.CORNER_SIGMA_PX,
        options.SEED,
        options.NOISE,
        options.LOSS,
        LEVEL,
        MIN_CAPTURES,
        MAX_DIFF_S,
    ]
    values = [-1, 0, 2, 3, 1e-6, 0.05, 0.1, 0.5, 0.7, 1e400, float("nan"), "auto", "cauchy", "x"]
    for rule in rules:
        t = option_type(rule)
        for v in values:
            try:
                by_rule = rule.check(v, None, "k")
            except InputError:
                by_rule = None
            try:
                by_option = t.convert(str(v), None, None)
            except click.BadParameter:
                by_option = None
            assert by_option == by_rule, (rule, v)


def test_a_grid_size_is_two_whole_numbers_from_2():
    from rigcal.cli.types import GridSize

    size = GridSize()
    assert size.convert("9x6", None, None) == (9, 6)
    assert size.convert((9, 6), None, None) == (9, 6)
    for bad in ("9", "1x6", "9x1", "9x6x2", "9X6", "-9x6", "123456x2", ""):
        with pytest.raises(click.BadParameter, match="expected WxH"):
            size.convert(bad, None, None)


def test_the_board_commands_share_one_board_declaration():
    from rigcal.cli.types import GridSize

    options = {o.name: o for o in COMMANDS["intrinsics"].params}
    assert isinstance(options["board"].type, GridSize)
    assert isinstance(options["charuco"].type, GridSize)
    assert options["square_m"].required


def test_every_simulate_command_has_the_seed_and_json_options():
    for name, cmd in COMMANDS.items():
        if name.startswith("simulate "):
            opts = {o.name: o for o in cmd.params}
            assert opts["seed"].default == 0, name
            assert opts["seed"].type.min == 0, name
            assert opts["as_json"].is_flag, name
