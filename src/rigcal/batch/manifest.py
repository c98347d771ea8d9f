"""The batch manifest: which command to run over which inputs (docs/formats/batch.md).

A manifest is a versioned YAML file naming one command (``check``, ``solve``,
``localize`` or ``evaluate``), options shared by every item (``defaults``) and the items,
each with its inputs and options. A glob over input files or folders stands in for a
manifest when every item takes the same options. Either way the result is a list of
:class:`Item`, each carrying the exact command line the single command would be given.
"""

from __future__ import annotations

import glob as globmod
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rigcal.errors import InputError
from rigcal.io.files import check_keys, check_schema_version, load_yaml
from rigcal.io.validate import MAX_NAME_BYTES

MANIFEST_SCHEMA_VERSION = 1

NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass(frozen=True)
class Option:
    """One key of an item: how it reaches the single command's command line."""

    flag: str | None  # None: a positional argument
    kind: str  # "path", "str", "int", "float", "bool", "list"
    required: bool = False
    choices: tuple[str, ...] = ()  # a "str" option's values, when it has a fixed set


@dataclass(frozen=True)
class Command:
    """A command batch can run: its options, the key a glob fills and what each item writes."""

    options: dict[str, Option]
    glob_key: str
    outputs: tuple[str, ...]  # files/folders (relative to the item folder) a finished item has


COMMANDS: dict[str, Command] = {
    "check": Command(
        {
            "rig": Option(None, "path", required=True),
            # One of these three (ONE_OF): a box session, a board session, a drive.
            "picks": Option("--picks", "path"),
            "session": Option("--session", "path"),
            "sequence": Option("--sequence", "path"),
            "trajectory": Option("--trajectory", "path"),  # with sequence: the laser's poses
            "wheel_odometry": Option("--wheel-odometry", "str", choices=("use", "ignore")),
            "level": Option("--level", "float"),
            "min_captures": Option("--min-captures", "int"),
            "log": Option("--log", "path"),
            "no_log": Option("--no-log", "bool"),
        },
        glob_key="picks",
        outputs=(),
    ),
    "solve": Command(
        {
            "picks": Option(None, "path", required=True),
            "truth": Option("--truth", "path"),
            "seed": Option("--seed", "int"),
            "threshold_px": Option("--threshold-px", "float"),
            "pick_sigma_px": Option("--pick-sigma-px", "float"),
            "range_sigma_m": Option("--range-sigma-m", "float"),
            "loss": Option("--loss", "str"),
            "paper_endpoints": Option("--paper-endpoints", "bool"),
        },
        glob_key="picks",
        outputs=("rig.yaml", "report/report.json"),
    ),
    "localize": Command(
        {
            "sequence": Option(None, "path", required=True),
            "method": Option("--method", "str"),
            "rig": Option("--rig", "path"),
            "kitti": Option("--kitti", "bool"),
            "iasm": Option("--iasm", "list"),
            "tracks": Option("--tracks", "list"),
        },
        glob_key="sequence",
        outputs=("localize/summary.json",),
    ),
    "evaluate": Command(
        {
            "trajectory": Option(None, "path", required=True),
            "gt": Option("--gt", "path", required=True),
        },
        glob_key="trajectory",
        outputs=(),
    ),
}


# Options of which an item needs exactly one: what a check checks against.
ONE_OF = {"check": ("picks", "session", "sequence")}


@dataclass(frozen=True)
class Item:
    """One run of a command.

    Attributes:
        name: unique within the batch; names the item's folder under the output folder.
        command: ``check``, ``solve``, ``localize`` or ``evaluate``.
        options: the item's options after defaults, paths absolute.
    """

    name: str
    command: str
    options: dict[str, Any]

    def argv(self, folder: Path) -> list[str]:
        """The single command's command line (without ``rigcal``), writing into ``folder``.

        Every item prints JSON (``--json``); ``solve`` writes ``folder/rig.yaml`` and
        ``folder/report/``, ``localize`` writes ``folder/localize/``; an unfinished earlier
        attempt's outputs are replaced (``--force``).
        """
        spec = COMMANDS[self.command]
        positional: list[str] = []
        flags: list[str] = []
        for key, opt in spec.options.items():
            if key not in self.options:
                continue
            value = self.options[key]
            if opt.flag is None:
                positional.append(str(value))
            elif opt.kind == "bool":
                flags += [opt.flag] if value else []
            elif opt.kind == "list":
                for v in value:
                    flags += [opt.flag, str(v)]
            else:
                flags += [opt.flag, str(value)]
        if self.command == "solve":
            flags += ["-o", str(folder / "rig.yaml"), "--report", str(folder / "report"), "--force"]
        elif self.command == "localize":
            flags += ["-o", str(folder / "localize"), "--force"]
        return [self.command, *positional, *flags, "--json"]


def read_manifest(path: str | Path) -> list[Item]:
    """Read and validate a manifest; relative paths are taken from the manifest's folder.

    Raises:
        InputError: missing or unreadable file, unknown or missing keys, a value of the
            wrong type, a bad or repeated item name.
    """
    path = Path(path)
    doc = check_keys(
        load_yaml(path, "batch manifest"),
        path,
        "",
        ["schema_version", "command", "items"],
        ["defaults"],
        [MANIFEST_SCHEMA_VERSION],
    )
    check_schema_version(doc, path, MANIFEST_SCHEMA_VERSION)
    command = _command(doc["command"], path, "command")
    base = path.resolve().parent
    defaults = _options(doc.get("defaults") or {}, command, path, "defaults", base, partial=True)
    items = doc["items"]
    if not isinstance(items, list) or not items:
        raise InputError.at(path, "items", items, "a non-empty list of items")
    named: list[tuple[Any, dict[str, Any]]] = []
    for i, entry in enumerate(items):
        where = f"items[{i}]"
        if not isinstance(entry, Mapping):
            raise InputError.at(path, where, entry, "a mapping of an item's options")
        entry = dict(entry)
        name = entry.pop("name", None)
        merged = {**defaults, **_options(entry, command, path, where, base, partial=True)}
        _check_required(merged, command, path, where)
        named.append((name, merged))
    derived = _derived_names([Path(_main_input(m, command)) for _, m in named])
    out = [
        Item(derived[i] if name is None else _name(name, path, f"items[{i}].name"), command, merged)
        for i, (name, merged) in enumerate(named)
    ]
    _check_unique(out, path)
    return out


def glob_items(pattern: str, command: str, options: Mapping[str, Any]) -> list[Item]:
    """Items from a glob over the command's main input (``picks`` of check and solve, the
    ``sequence`` folder of localize, the ``trajectory`` of evaluate), each with the same
    ``options`` (values as strings from the command line, converted by kind).

    Raises:
        InputError: no match, an unknown command or option, a value of the wrong type.
    """
    spec = COMMANDS[_command(command, None, "--command")]
    matches = sorted(globmod.glob(pattern, recursive=True))
    if not matches:
        raise InputError.at(None, "manifest glob", pattern, "a pattern matching at least one input")
    shared = _options(dict(options), command, None, "--set", Path.cwd(), partial=True, from_text=True)
    for key in ONE_OF.get(command, (spec.glob_key,)):
        if key in shared:
            raise InputError.at(None, "--set", key, "an option other than the one the glob fills")
    paths = [Path(m).resolve() for m in matches]
    items = []
    for name, p in zip(_derived_names(paths), paths, strict=True):
        # A check's glob over folders names drives (targetless), over files sessions.
        key = "sequence" if command == "check" and p.is_dir() else spec.glob_key
        merged = {**shared, key: p}
        _check_required(merged, command, None, f"glob match {p}")
        items.append(Item(name, command, merged))
    return items


def _main_input(options: Mapping[str, Any], command: str) -> Any:
    """The input an item's name is derived from: the glob key's, or the one given of
    ``ONE_OF``."""
    for key in ONE_OF.get(command, ()):
        if key in options:
            return options[key]
    return options[COMMANDS[command].glob_key]


def _command(value: Any, path: Path | None, key: str) -> str:
    if not isinstance(value, str) or value not in COMMANDS:
        raise InputError.at(path, key, value, f"one of {sorted(COMMANDS)}")
    return str(value)


def _options(
    mapping: Mapping[str, Any],
    command: str,
    path: Path | None,
    where: str,
    base: Path,
    *,
    partial: bool,
    from_text: bool = False,
) -> dict[str, Any]:
    """Validate an item's (or the defaults') options by kind; paths made absolute."""
    spec = COMMANDS[command].options
    check_keys(mapping, path, where, [], spec)
    out: dict[str, Any] = {}
    for key, value in mapping.items():
        kind = spec[key].kind
        full = f"{where}.{key}"
        out[key] = _convert(value, kind, path, full, base, from_text)
        if spec[key].choices and out[key] not in spec[key].choices:
            raise InputError.at(path, full, out[key], f"one of {list(spec[key].choices)}")
    return out


def _convert(value: Any, kind: str, path: Path | None, key: str, base: Path, from_text: bool) -> Any:
    if from_text and kind != "list":
        value = _from_text(value, kind, key)
    if kind == "path":
        if not isinstance(value, str) or not value or "\0" in value:
            raise InputError.at(path, key, value, "a path (a non-empty string without NUL bytes)")
        return (base / Path(value).expanduser()).resolve()
    if kind == "str":
        if not isinstance(value, str):
            raise InputError.at(path, key, value, "a string")
        return value
    if kind == "bool":
        if not isinstance(value, bool):
            raise InputError.at(path, key, value, "true or false")
        return value
    if kind == "int":
        if type(value) is not int:
            raise InputError.at(path, key, value, "an integer")
        return value
    if kind == "float":
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise InputError.at(path, key, value, "a number")
        return float(value)
    # list: KEY=VALUE settings of IASM, given as a list of strings or a mapping
    if isinstance(value, Mapping):
        value = [f"{k}={_yaml_scalar(v)}" for k, v in value.items()]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise InputError.at(path, key, value, "a list of KEY=VALUE strings or a mapping")
    return list(value)


def _yaml_scalar(v: Any) -> str:
    return str(v).lower() if isinstance(v, bool) else str(v)


def _from_text(value: Any, kind: str, key: str) -> Any:
    """A command-line string as the kind a manifest would hold."""
    text = str(value)
    try:
        if kind == "int":
            return int(text)
        if kind == "float":
            return float(text)
    except ValueError:
        raise InputError.at(None, key, text, f"a{'n integer' if kind == 'int' else ' number'}") from None
    if kind == "bool":
        if text.lower() in ("true", "1", "yes"):
            return True
        if text.lower() in ("false", "0", "no"):
            return False
        raise InputError.at(None, key, text, "true or false")
    return text


def _check_required(options: Mapping[str, Any], command: str, path: Path | None, where: str) -> None:
    for key, opt in COMMANDS[command].options.items():
        if opt.required and key not in options:
            raise InputError(f"{path or 'batch'}: {where}.{key}: missing; {command} needs it")
    one_of = ONE_OF.get(command)
    if one_of and sum(k in options for k in one_of) != 1:
        given = [k for k in one_of if k in options]
        raise InputError.at(path, where, given or "none of them", f"exactly one of {list(one_of)}")
    for key in ("trajectory", "wheel_odometry"):
        if command == "check" and key in options and "sequence" not in options:
            # A drive's laser poses or wheel odometry: refused before any item runs, as
            # `rigcal check` refuses it.
            raise InputError.at(path, f"{where}.{key}", str(options[key]), "an item with a sequence")


def _name(value: Any, path: Path | None, key: str) -> str:
    if not isinstance(value, str) or not NAME_RE.match(value) or len(value) > MAX_NAME_BYTES:
        raise InputError.at(
            path, key, value, f"a name of letters, digits, '.', '_' and '-' (at most {MAX_NAME_BYTES})"
        )
    return value


def _check_unique(items: list[Item], path: Path | None) -> None:
    seen: set[str] = set()
    for i, item in enumerate(items):
        if item.name in seen:
            raise InputError.at(path, f"items[{i}].name", item.name, "a name no other item has")
        seen.add(item.name)


def _derived_names(paths: list[Path]) -> list[str]:
    """Short unique names from paths: the parts that differ between them.

    ``fleet/r01/today/picks.yaml`` and ``fleet/r02/today/picks.yaml`` give ``r01`` and
    ``r02``; a single path gives its folder's or file's own name.
    """
    parts = [list(p.with_suffix("").parts) if p.suffix else list(p.parts) for p in paths]
    if len(parts) > 1:
        while all(len(q) > 1 for q in parts) and len({q[-1] for q in parts}) == 1:
            for q in parts:
                q.pop()
        while all(len(q) > 1 for q in parts) and len({q[0] for q in parts}) == 1:
            for q in parts:
                q.pop(0)
    else:
        generic = ("picks", "trajectory", "board_session", "session")
        parts = [[parts[0][-1] if parts[0][-1] not in generic else parts[0][-2]]]
    names = [
        re.sub(r"[^A-Za-z0-9._-]", "_", "_".join(q)).lstrip("._-")[-MAX_NAME_BYTES:].lstrip("._-") or "item"
        for q in parts
    ]
    if len(set(names)) != len(names):  # cannot happen for distinct paths; keep names unique anyway
        names = [f"{n}-{i}" for i, n in enumerate(names)]
    return names
