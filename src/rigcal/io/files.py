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
import os
import secrets
import shutil
import tempfile
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml

from rigcal.errors import InputError, OutputError
from rigcal.io.kinds import binary_message, wrong_kind

try:  # the C loader is ~10x faster on long float lists (scan files)
    _SafeLoader: type[yaml.SafeLoader] = yaml.CSafeLoader  # type: ignore[assignment]
except AttributeError:  # pragma: no cover - depends on how PyYAML was built
    _SafeLoader = yaml.SafeLoader


def read_text(path: str | Path, what: str = "file") -> str:
    """A UTF-8 text file's contents.

    Raises:
        InputError: the file is missing or unreadable, naming it as ``what``.
    """
    path = Path(path)
    try:
        return path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        inside = " (a sequence folder)" if (path / "sequence.yaml").is_file() else ""
        raise InputError(f"{path}: got a folder{inside}; expected a {what}") from None
    except UnicodeDecodeError as exc:
        raise InputError(binary_message(path, what) or f"{path}: cannot read {what}: {exc}") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what}: {exc}") from None


def load_yaml(path: str | Path, what: str = "file") -> Any:
    """Read a YAML file with ``safe_load`` semantics.

    Raises:
        InputError: the file is missing, unreadable, not valid YAML, or another kind of
            rigcal file than ``what`` (:mod:`rigcal.io.kinds`).
    """
    path = Path(path)
    text = read_text(path, what)
    try:
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


def check_keys(
    mapping: Any,
    path: str | Path | None,
    keypath: str,
    required: Iterable[str],
    optional: Iterable[str] = (),
) -> Mapping[str, Any]:
    """Check that ``mapping`` is a mapping with all required keys and no unknown ones.

    Args:
        mapping: the parsed value to check.
        path: file it came from, for the message.
        keypath: where in the file it sits ("" for the top level), for the message.
        required: keys that must be present.
        optional: keys that may be present.

    Returns:
        The mapping, typed as such.
    """
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
    value = mapping[key]
    full = _join(keypath, key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputError.at(path, full, value, "a number")
    out = float(value)
    if finite and not (out == out and abs(out) != float("inf")):
        raise InputError.at(path, full, value, "a finite number")
    if positive and not out > 0:
        raise InputError.at(path, full, value, "a number > 0")
    return out


def sha256_file(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes (for provenance records)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def check_writable(path: str | Path, force: bool) -> Path:
    """Refuse to overwrite an existing file unless ``force``; check the folder exists."""
    path = Path(path)
    if path.exists() and not force:
        raise OutputError(f"{path}: exists; pass --force to overwrite it")
    if path.is_dir():
        raise OutputError(f"{path}: is a folder; expected a file path")
    return path


def atomic_write_bytes(path: str | Path, data: bytes, force: bool = False) -> Path:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder + rename).

    Creates the parent folder if needed. Refuses to overwrite unless ``force``.

    Raises:
        OutputError: the file exists and ``force`` is false, or the write failed.
    """
    path = check_writable(path, force)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
    return path


def atomic_write_text(path: str | Path, text: str, force: bool = False) -> Path:
    """Text version of :func:`atomic_write_bytes` (UTF-8)."""
    return atomic_write_bytes(path, text.encode("utf-8"), force=force)


def check_schema_version(mapping: Mapping[str, Any], path: str | Path | None, expected: int) -> None:
    """``schema_version`` must be the integer ``expected`` (booleans and floats rejected)."""
    value = mapping["schema_version"]
    if type(value) is not int or value != expected:
        raise InputError.at(path, "schema_version", value, f"{expected} (the version this rigcal reads)")


def check_folder_writable(folder: str | Path, force: bool) -> Path:
    """Refuse an existing folder unless ``force``, and anything there that is not a folder."""
    folder = Path(folder)
    if folder.exists() or folder.is_symlink():
        if not force:
            raise OutputError(f"{folder}: exists; pass --force to replace it")
        if not folder.is_dir() or folder.is_symlink():
            raise OutputError(f"{folder}: exists and is not a folder; refusing to replace it")
    return folder


@contextlib.contextmanager
def atomic_folder(folder: str | Path, force: bool = False) -> Iterator[Path]:
    """Write a whole folder atomically: yields a fresh hidden sibling to fill, which then
    replaces ``folder`` by rename (an existing folder is moved aside first and removed
    after, or put back if the rename fails). On any error the sibling is removed and
    ``folder`` is left as it was.

    Raises:
        OutputError: the folder exists and ``force`` is false, or a write failed.
    """
    folder = check_folder_writable(folder, force)
    try:
        folder.absolute().parent.mkdir(parents=True, exist_ok=True)
        tmp = _fresh_sibling(folder, "tmp")
        tmp.mkdir()
    except OSError as exc:
        raise OutputError(f"{folder}: cannot write: {exc.strerror or exc}") from None
    try:
        yield tmp
        _swap_into_place(tmp, folder)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        raise OutputError(f"{folder}: cannot write: {exc.strerror or exc}") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _fresh_sibling(folder: Path, tag: str) -> Path:
    """A name next to ``folder`` that does not exist yet (hidden, random)."""
    while True:
        p = folder.absolute().parent / f".{folder.name}.{secrets.token_hex(4)}.{tag}"
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
