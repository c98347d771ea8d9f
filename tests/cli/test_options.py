"""Options every command shares: one `-o` metavar per kind of output, `--json` wherever
a result is written."""

from __future__ import annotations

import click

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
