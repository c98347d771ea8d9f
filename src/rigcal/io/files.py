"""File boundary: YAML reading with error translation, key validation, atomic writes.

Every reader in rigcal goes through :func:`load_yaml` and :func:`check_keys`, so that a
bad file always yields one :class:`~rigcal.errors.InputError` line naming the file, the
key path, the value and what was expected. Every writer goes through
:func:`atomic_write_bytes` (temporary file in the same folder, then rename), so a failed
or refused write leaves nothing half-written.
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from rigcal.errors import InputError, OutputError
from rigcal.io.kinds import binary_message, wrong_kind

try:  # the C loader: much faster on long float lists (scan files)
    _SafeLoader: type[yaml.SafeLoader] = yaml.CSafeLoader  # type: ignore[assignment]
except AttributeError:  # pragma: no cover - depends on how PyYAML was built
    _SafeLoader = yaml.SafeLoader


# A text file rigcal reads (YAML, logs, trajectories) is at most this large, and a YAML
# file stands for at most this many values once its aliases are expanded: a few lines of
# nested aliases can stand for gigabytes (a "billion laughs").
MAX_TEXT_BYTES = 1 << 30
MAX_YAML_VALUES = 10_000_000
# Collections nest at most this deep in a YAML file rigcal reads. The parser builds nested
# values by recursion: 50 000 nested brackets overflow the C stack and kill the process
# (a segmentation fault, no message). rigcal's own files nest 6 deep at most.
MAX_YAML_DEPTH = 100
# Indicators that can open a nesting level: flow brackets, and block entries or keys
# ("- ", "? ", ": " or the same at the end of a line).
_OPENERS = re.compile(r"[\[{]|[-?:](?=[ \t\r\n]|$)", re.MULTILINE)


def read_text(path: str | Path, what: str = "file") -> str:
    """A text file's contents (:func:`decode_text`: UTF-8, or UTF-16 with its byte-order
    mark), line ends made ``\\n``.

    Raises:
        InputError: the file is missing or unreadable, naming it as ``what``.
    """
    path = Path(path)
    if "\0" in str(path):
        raise InputError.at(None, what, str(path), "a path without NUL bytes")
    try:
        if path.stat().st_size > MAX_TEXT_BYTES:
            raise InputError(f"{path}: {what} larger than {MAX_TEXT_BYTES >> 20} MiB; refusing to read it")
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        inside = " (a sequence folder)" if (path / "sequence.yaml").is_file() else ""
        raise InputError(f"{path}: got a folder{inside}; expected a {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what}: {exc}") from None
    # Line ends made "\n" ("\r\n" and a lone "\r" too), as Python's universal newlines.
    return decode_text(data, path, what).replace("\r\n", "\n").replace("\r", "\n")


_UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")


def decode_text(data: bytes, path: Path, what: str, replace: bool = False) -> str:
    """A text file's bytes as text: UTF-8, or UTF-16 when its byte-order mark says so (what
    Windows editors save as "Unicode" and Windows PowerShell's ``>`` writes); a UTF-8
    byte-order mark (a spreadsheet's) dropped. ``replace``: bytes that are not UTF-8
    replaced (old logs' Latin-1 comments) rather than refused.

    Raises:
        InputError: a known binary kind of file; UTF-16 without its byte-order mark; bytes
            that are not UTF-8 (or not UTF-16 after its mark), naming the line.
    """
    if data.startswith(_UTF16_BOMS):
        try:
            text = data.decode("utf-16")
        except UnicodeDecodeError as exc:
            line = data[: exc.start].decode("utf-16", "replace").count("\n") + 1
            raise InputError(
                f"{path}: line {line}: got bytes that are not UTF-16 after its byte-order mark; expected "
                f"UTF-8 or UTF-16 text for this {what}"
            ) from None
    else:
        # ASCII text in UTF-16 without its mark: every other byte NUL, the others not.
        head = data[:64]
        halves = (head[0::2], head[1::2])
        if len(head) >= 4 and any(
            a.count(0) == 0 and b.count(0) == len(b) for a, b in (halves, halves[::-1])
        ):
            message = binary_message(path, what)
            raise InputError(
                message
                or f"{path}: got UTF-16 text without its byte-order mark; expected UTF-8 text (or UTF-16 "
                f"starting with its byte-order mark) for this {what}: save it as UTF-8"
            )
        try:
            text = data.decode("utf-8", errors="replace" if replace else "strict")
        except UnicodeDecodeError as exc:
            message = binary_message(path, what)
            if message is not None:
                raise InputError(message) from None
            line = data[: exc.start].count(b"\n") + 1
            raise InputError(
                f"{path}: line {line}: got byte 0x{data[exc.start]:02X}, not UTF-8; expected UTF-8 text for "
                f"this {what} (saved as Windows-1252 or Latin-1? save it as UTF-8)"
            ) from None
    return text.removeprefix("\ufeff")


# Compressed logs as archives ship them (Radish's CARMEN logs are often .gz), by their
# first bytes, whatever the file's name says.
_COMPRESSED = {b"\x1f\x8b": "gzip", b"BZh": "bzip2"}


def read_bytes(path: str | Path, what: str = "file") -> bytes:
    """A file's bytes.

    Raises:
        InputError: the file is missing, a folder or unreadable, naming it as ``what``.
    """
    path = Path(path)
    try:
        return path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: got a folder; expected a {what}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what}: {exc}") from None


def compressed(path: str | Path) -> bool:
    """Whether the file starts as a gzip or bzip2 stream (False when it cannot be read:
    the reader then says why)."""
    try:
        with Path(path).open("rb") as f:
            head = f.read(3)
    except (OSError, ValueError):
        return False
    return any(head.startswith(magic) for magic in _COMPRESSED)


def read_log_text(path: str | Path, what: str = "log") -> str:
    """A text log's contents, gzip- or bzip2-compressed or not (told by the first bytes);
    bytes that are not UTF-8 are replaced (old logs hold Latin-1 comments), and so is a
    leading byte-order mark.

    Raises:
        InputError: the file is missing or unreadable, its compressed stream is cut short
            or broken, or it holds more than 1 GiB of text.
    """
    import bz2
    import gzip
    import io

    path = Path(path)
    if "\0" in str(path):
        raise InputError.at(None, what, str(path), "a path without NUL bytes")
    too_large = f"{path}: {what} larger than {MAX_TEXT_BYTES >> 20} MiB; refusing to read it"
    with contextlib.suppress(OSError):  # read_bytes says what is wrong with the path
        if path.stat().st_size > MAX_TEXT_BYTES:
            raise InputError(too_large)
    data = read_bytes(path, what)
    kind = next((k for magic, k in _COMPRESSED.items() if data.startswith(magic)), None)
    if kind is not None:
        stream = io.BytesIO(data)
        try:
            with gzip.GzipFile(fileobj=stream) if kind == "gzip" else bz2.BZ2File(stream) as z:
                data = z.read(MAX_TEXT_BYTES + 1)
        except (OSError, EOFError, ValueError) as exc:
            raise InputError(
                f"{path}: {what}: got a broken or cut-short {kind} stream ({exc}); expected a whole "
                f"{kind}-compressed file (download it again?)"
            ) from None
        if len(data) > MAX_TEXT_BYTES:
            raise InputError(too_large + " (uncompressed)")
    return decode_text(data, path, what, replace=True)


def load_yaml(path: str | Path, what: str = "file") -> Any:
    """Read a YAML file with ``safe_load`` semantics.

    Raises:
        InputError: the file is missing, unreadable, not valid YAML, or another kind of
            rigcal file than ``what`` (:mod:`rigcal.io.kinds`).
    """
    path = Path(path)
    text = read_text(path, what)
    return parse_yaml(text, path, what)


def parse_yaml(text: str, path: str | Path, what: str = "file") -> Any:
    """The YAML document ``text`` read from ``path`` (named in errors), checked as
    :func:`load_yaml` checks a file: nesting depth, alias expansion, syntax, file kind."""
    path = Path(path)
    _check_depth(text, path)
    try:
        if "*" in text and "&" in text:  # only then can aliases expand or loop
            _check_expansion(yaml.compose(text, Loader=_SafeLoader), path)
        data = yaml.load(text, Loader=_SafeLoader)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(exc, "problem", None) or "syntax error"
        raise InputError(f"{path}: not valid YAML{where}: {problem}") from None
    message = wrong_kind(path, data, what)
    if message is not None:
        raise InputError(message)
    return data


def _check_depth(text: str, path: Path) -> None:
    """Refuse a document whose collections nest deeper than MAX_YAML_DEPTH, before the
    recursive parser sees it. Each level needs an opening indicator, so a document with
    fewer indicators than the limit is shallow enough (the usual case, a regex count);
    otherwise the parser's event stream, which libyaml produces without recursion, is
    walked and the depth counted exactly."""
    if len(_OPENERS.findall(text, 0, len(text))) <= MAX_YAML_DEPTH:
        return
    depth = 0
    try:
        for event in yaml.parse(text, Loader=_SafeLoader):
            if isinstance(event, (yaml.SequenceStartEvent, yaml.MappingStartEvent)):
                depth += 1
                if depth > MAX_YAML_DEPTH:
                    mark = event.start_mark
                    at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
                    raise InputError(
                        f"{path}: YAML nested deeper than {MAX_YAML_DEPTH} levels{at}; "
                        "expected a rigcal file (a few levels deep)"
                    )
            elif isinstance(event, (yaml.SequenceEndEvent, yaml.MappingEndEvent)):
                depth -= 1
    except yaml.YAMLError:
        # Not YAML that PyYAML reads (another parser's dialect, or a syntax error that the
        # parse that follows reports with its place): bound the depth from the text.
        if _text_depth(text) > MAX_YAML_DEPTH:
            raise InputError(
                f"{path}: nested deeper than {MAX_YAML_DEPTH} levels; "
                "expected a rigcal file (a few levels deep)"
            ) from None


def _text_depth(text: str) -> int:
    """An over-estimate of how deep a YAML-like text nests: the deepest run of unclosed
    brackets plus, per line, its indentation and its chained "- " entries."""
    depth = deepest = 0
    for c in text:
        if c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth = max(depth - 1, 0)
    block = max(
        (len(line) - len(line.lstrip(" -")) for line in text.splitlines() if line.lstrip(" -")),
        default=0,
    )
    return deepest + block


def check_markup_depth(path: str | Path, what: str = "file") -> None:
    """Refuse a YAML or XML file that another library will parse (OpenCV's FileStorage,
    which recurses and crashes on 50 000 nested levels) when it nests deeper than
    MAX_YAML_DEPTH: XML counted with expat (no recursion), YAML as :func:`load_yaml`
    counts it (after OpenCV's ``%YAML:1.0`` line).

    Raises:
        InputError: the file is missing, unreadable or too deep.
    """
    path = Path(path)
    text = read_text(path, what)
    if not text.lstrip().startswith("<"):
        _check_depth(re.sub(r"\A%YAML:1\.0[^\n]*", "", text), path)  # (keeps the line numbers)
        return
    import xml.parsers.expat

    parser = xml.parsers.expat.ParserCreate()
    depth = [0]

    def start(*_: Any) -> None:
        depth[0] += 1
        if depth[0] > MAX_YAML_DEPTH:
            raise InputError(
                f"{path}: XML nested deeper than {MAX_YAML_DEPTH} levels at line {parser.CurrentLineNumber}; "
                f"expected a {what} (a few levels deep)"
            )

    def end(*_: Any) -> None:
        depth[0] -= 1

    parser.StartElementHandler, parser.EndElementHandler = start, end
    try:
        parser.Parse(text, True)
    except xml.parsers.expat.ExpatError:
        return  # not well-formed: the reader reports it


def _check_expansion(root: yaml.Node | None, path: Path) -> None:
    """Refuse a YAML document whose aliases expand to more than MAX_YAML_VALUES values, or
    refer to themselves (a value that contains itself has no end)."""
    if root is None:
        return
    size: dict[int, int] = {}
    open_: set[int] = set()
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    while stack:
        node, done = stack.pop()
        key = id(node)
        children: list[yaml.Node] = []
        if isinstance(node, yaml.SequenceNode):
            children = list(node.value)
        elif isinstance(node, yaml.MappingNode):
            children = [x for pair in node.value for x in pair]
        if done:
            open_.discard(key)
            size[key] = 1 + sum(size[id(c)] for c in children)
            if size[key] > MAX_YAML_VALUES:
                raise InputError(f"{path}: its YAML aliases expand to over {MAX_YAML_VALUES} values")
            continue
        if key in size:
            continue
        if key in open_:
            raise InputError(f"{path}: a YAML alias refers to a value that contains it (no end)")
        open_.add(key)
        stack.append((node, True))
        stack.extend((c, False) for c in children if id(c) not in size)
    return


_LINE_BREAK = re.compile(r"\r\n|\r|\n")


def text_lines(text: str) -> list[str]:
    """The lines of a text file as editors and other tools number them: split at ``\n``,
    ``\r\n`` and a lone ``\r`` only (mixed freely), not at the form feeds, vertical tabs,
    file separators and Unicode line separators ``str.splitlines`` also splits at (one in
    a log's comment would put the number of every later line in an error off)."""
    lines = _LINE_BREAK.split(text)
    if lines and not lines[-1]:
        lines.pop()
    return lines


def csv_fields(line: str) -> list[str]:
    """A CSV line's fields, each stripped of the spaces around it, as a spreadsheet writes
    them (RFC 4180): a field in double quotes may hold commas and doubled quotes
    (``"cam 1, left.png"``, ``"a ""b"".png"``), and some programs quote every field. A quote
    left open keeps the rest of the line in its field (the caller's own check names it)."""
    if '"' not in line:
        return [f.strip() for f in line.split(",")]
    import csv

    return [f.strip() for f in next(csv.reader([line], skipinitialspace=True))]


def check_keys(
    mapping: Any,
    path: str | Path | None,
    keypath: str,
    required: Iterable[str],
    optional: Iterable[str] = (),
    versions: Iterable[int] = (),
) -> Mapping[str, Any]:
    """Check that ``mapping`` is a mapping with all required keys and no unknown ones.

    Args:
        mapping: the parsed value to check.
        path: file it came from, for the message.
        keypath: where in the file it sits ("" for the top level), for the message.
        required: keys that must be present.
        optional: keys that may be present.
        versions: a versioned file's top level: the ``schema_version`` values this rigcal
            reads; a newer one is named as such first (:func:`check_not_newer`).

    Returns:
        The mapping, typed as such.
    """
    check_not_newer(mapping, path, versions)
    label = keypath or "(top level)"
    required = list(required)
    allowed = set(required) | set(optional)
    if not isinstance(mapping, Mapping):
        raise InputError.at(path, label, mapping, f"a mapping with keys {sorted(allowed)}")
    for key in mapping:
        if key not in allowed:
            raise InputError.at(
                path,
                _join(keypath, str(key)),
                mapping[key],
                f"no such key; allowed keys are {sorted(allowed)}",
            )
    for key in required:
        if key not in mapping:
            raise InputError(f"{path}: {_join(keypath, key)}: missing; this key is required")
    return mapping


def check_not_newer(mapping: Any, path: str | Path | None, versions: Iterable[int]) -> None:
    """Refuse a file of a newer ``schema_version`` than ``versions`` (the ones this rigcal
    reads) as such, before its keys are checked: a newer file's new keys would otherwise
    read as typos ("no such key"). Other values are left to the reader's own check."""
    known = sorted(versions)
    v = mapping.get("schema_version") if isinstance(mapping, Mapping) else None
    if known and type(v) is int and v > known[-1]:
        listed = " or ".join([", ".join(str(k) for k in known[:-1]), str(known[-1])][len(known) == 1 :])
        which = "versions" if len(known) > 1 else "version"
        raise InputError.at(
            path,
            "schema_version",
            v,
            f"{listed} (the {which} this rigcal reads; a file of a newer rigcal: upgrade rigcal to read it)",
        )


def _join(keypath: str, key: str) -> str:
    return f"{keypath}.{key}" if keypath else key


def get_float(
    mapping: Mapping[str, Any],
    key: str,
    path: str | Path | None,
    keypath: str = "",
    *,
    positive: bool = False,
    finite: bool = True,
) -> float:
    """Read a real number from a mapping, rejecting booleans, strings and NaN."""
    from rigcal.io.validate import real

    value = mapping[key]
    full = _join(keypath, key)
    if not finite and isinstance(value, float) and not math.isfinite(value) and not (positive and value < 0):
        return value
    return real(value, path, full, positive=positive)


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (for provenance records)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_writable(path: str | Path, force: bool, inputs: Iterable[str | Path] = ()) -> Path:
    """Refuse to overwrite an existing file (or symlink, even a dangling one) unless
    ``force``, a folder in its place, and a path that is one of ``inputs``."""
    path = Path(path)
    check_apart(path, inputs)
    if (path.exists() or path.is_symlink()) and not force:
        raise OutputError(f"{path}: exists; pass --force to overwrite it")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; expected a file path")
    return path


def check_apart(output: str | Path, inputs: Iterable[str | Path]) -> None:
    """An output must not be, contain or sit inside any input (compared after resolving
    symlinks and ``..``), so that no write or ``--force`` can touch what is being read.

    An output whose path holds a control or bidi character (:func:`hidden_char`) is
    refused too: its name would not show as it is in a terminal or a file browser.

    Raises:
        OutputError: naming the output and the input it collides with.
    """
    from rigcal.io.validate import hidden_char

    bad = hidden_char(str(output))
    if bad is not None:
        raise OutputError(
            f"{ascii(str(output))[1:-1]}: output path holds U+{ord(bad):04X}; expected a path without "
            "control or bidi characters"
        )
    _check_parents(Path(output))
    out = _resolved(output)
    for given in inputs:
        inp = _resolved(given)
        if out == inp:
            raise OutputError(f"{output}: is the input {given}; choose another output")
        if inp.is_relative_to(out):
            raise OutputError(f"{output}: contains the input {given}; choose another output")
        if out.is_relative_to(inp) and Path(given).is_dir():
            raise OutputError(f"{output}: is inside the input {given}; choose another output")


def _check_parents(output: Path) -> None:
    """An output under a path one of whose folders is a file (``-o run.log/out``), or
    whose nearest existing folder cannot be written (read-only, another user's), cannot be
    written: say which, before any work (the write would fail after it, with "File
    exists" or "Permission denied"; every write makes its temporary beside the output)."""
    for parent in output.absolute().parents:
        if parent.exists():
            if not parent.is_dir():
                raise OutputError(f"{output}: {parent} is a file; expected a folder to write into")
            if not os.access(parent, os.W_OK | os.X_OK):
                raise OutputError(f"{output}: cannot write into {parent} (read-only or not yours)")
            return


def _resolved(path: str | Path) -> Path:
    try:
        return Path(path).resolve()
    except (OSError, RuntimeError, ValueError):
        return Path(os.path.abspath(path))


def current_umask() -> int:
    """The process's umask, read without changing it where the system allows."""
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError, IndexError):
        pass
    mask = os.umask(0o022)  # pragma: no cover - systems without /proc
    os.umask(mask)  # pragma: no cover
    return mask  # pragma: no cover


def atomic_write_bytes(path: str | Path, data: bytes, force: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder + rename).

    Creates the parent folder if needed. Refuses to overwrite unless ``force``. The file
    gets the mode any new file gets (0666 less the umask). Temporary files of killed runs
    (``.NAME.PID.*.tmp`` of a process that is gone) are removed.

    Raises:
        OutputError: the file exists and ``force`` is false, or the write failed.
    """
    path = check_writable(path, force)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(path)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.{os.getpid()}.", suffix=".tmp")
        try:
            os.fchmod(fd, 0o666 & ~current_umask())
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    except ValueError as exc:  # e.g. a NUL byte in the path
        raise OutputError(f"{path!r}: cannot write: {exc}") from None
    return path


def remove_stale_temporaries(target: Path) -> None:
    """Remove the temporary siblings of ``target`` (``.NAME.PID.*.tmp`` files and folders,
    ``.NAME.PID.*.old`` folders) left by rigcal processes that no longer run.

    An ``.old`` folder is the previous output moved aside just before the new one took its
    place; if the process died between the two renames and ``target`` is missing, the old
    folder is put back.
    """
    parent = target.absolute().parent
    try:
        names = os.listdir(parent)
    except OSError:
        return
    prefix = f".{target.name}."
    for name in names:
        if not name.startswith(prefix):
            continue
        pid_text, _, rest = name[len(prefix) :].partition(".")
        tag = rest.rpartition(".")[2]
        if tag not in ("tmp", "old") or not pid_text.isdigit() or _alive(int(pid_text)):
            continue
        p = parent / name
        if tag == "old" and not (target.exists() or target.is_symlink()):
            with contextlib.suppress(OSError):
                os.rename(p, target)
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                p.unlink()


def _alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, OSError):
        return True
    return True


def atomic_write_text(path: str | Path, text: str, force: bool = False) -> Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8)."""
    return atomic_write_bytes(path, text.encode("utf-8"), force=force)


def check_schema_version(mapping: Mapping[str, Any], path: str | Path | None, expected: int) -> None:
    """``schema_version`` must be the integer ``expected`` (booleans and floats rejected)."""
    value = mapping["schema_version"]
    if type(value) is not int or value != expected:
        raise InputError.at(path, "schema_version", value, f"{expected} (the version this rigcal reads)")


MARKER = ".rigcal-output"
"""The file rigcal puts in every folder it writes; ``--force`` replaces only such folders."""


def check_folder_writable(folder: str | Path, force: bool, inputs: Iterable[str | Path] = ()) -> Path:
    """Refuse an output folder that is, contains or sits inside one of ``inputs``; an
    existing one unless ``force``; anything there that is not a folder; and, even with
    ``force``, a non-empty folder rigcal did not write (no :data:`MARKER` file in it)."""
    folder = Path(folder)
    check_apart(folder, inputs)
    if folder.exists() or folder.is_symlink():
        if folder.is_symlink() or not folder.is_dir():
            raise OutputError(f"{folder}: exists and is not a folder; refusing to replace it")
        if not force:
            raise OutputError(f"{folder}: exists; pass --force to replace it")
        try:
            foreign = not (folder / MARKER).is_file() and any(folder.iterdir())
        except OSError as exc:
            raise OutputError(f"{folder}: cannot read: {exc.strerror or exc}") from None
        if foreign:
            raise OutputError(
                f"{folder}: exists and was not written by rigcal (no {MARKER} file); "
                "--force replaces only rigcal's output folders: remove it or choose another"
            )
    return folder


@contextlib.contextmanager
def atomic_folder(
    folder: str | Path, force: bool = False, inputs: Iterable[str | Path] = ()
) -> Iterator[Path]:
    """Write a whole folder atomically: yields a fresh hidden sibling to fill, which then
    replaces ``folder`` by rename (an existing folder is moved aside first and removed
    after, or put back if the rename fails). On any error the sibling is removed and
    ``folder`` is left as it was. The folder gets a :data:`MARKER` file, so that a later
    ``--force`` knows it may replace it; temporary siblings of killed runs are removed.

    Raises:
        OutputError: the folder exists and ``force`` is false, it was not written by
            rigcal, it is, holds or sits inside one of ``inputs``, or a write failed.
    """
    folder = check_folder_writable(folder, force, inputs)
    try:
        folder.absolute().parent.mkdir(parents=True, exist_ok=True)
        remove_stale_temporaries(folder)
        tmp = _fresh_sibling(folder, "tmp")
        tmp.mkdir()
    except OSError as exc:
        raise OutputError(f"{folder}: cannot write: {exc.strerror or exc}") from None
    except ValueError as exc:  # e.g. a NUL byte in the path
        raise OutputError(f"{folder!r}: cannot write: {exc}") from None
    try:
        (tmp / MARKER).write_text(
            "This folder was written by rigcal; `--force` may replace it as a whole.\n", encoding="utf-8"
        )
        yield tmp
        _swap_into_place(tmp, folder)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(f"{folder}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fresh_sibling(folder: Path, tag: str) -> Path:
    """A name next to ``folder`` that does not exist yet (hidden, with this process's id)."""
    while True:
        p = folder.absolute().parent / f".{folder.name}.{os.getpid()}.{secrets.token_hex(4)}.{tag}"
        if not p.exists():
            return p


def _swap_into_place(tmp: Path, folder: Path) -> None:
    """Rename tmp to folder; an existing folder is moved aside first and removed after."""
    if not folder.exists():
        os.rename(tmp, folder)
        return
    old = _fresh_sibling(folder, "old")
    os.rename(folder, old)
    try:
        os.rename(tmp, folder)
    except BaseException:
        os.rename(old, folder)
        raise
    shutil.rmtree(old, ignore_errors=True)
