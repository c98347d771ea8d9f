"""Line-based logs cut short: one rule for every importer that reads a record per line.

A log copied while it was being recorded, a logger killed mid-write or a partial download
ends mid-line. Every line-based importer (CARMEN logs, RADLOCC ``laser.txt``, CSV laser
logs) applies the same rule (docs/formats/sequence.md, "Logs cut short"):

- The file's **last** line is left out as incomplete when it does not read as a whole
  record and either has too few fields for its record (:class:`ShortLineError`) or lacks
  its newline (a number cut in two). A record that spans lines (a CSV scan: one row per
  beam) is left out with it when the cut line belongs to it.
- The import goes on with one warning naming the file, the line, what was wrong with it
  and how many bytes (and whole records) were dropped (:meth:`CutLine.warning`).
- ``--stamps strict`` (``strict=True``) refuses it: the line's own error, saying the log
  was cut short.

Any other malformed line, and a bad last line that has its newline and all its fields,
is an error as before: only the end of a log can be cut short.
"""

from __future__ import annotations

from dataclasses import dataclass

from rigcal.errors import InputError


class ShortLineError(InputError):
    """A record's line with fewer fields than the record needs."""


@dataclass(frozen=True)
class CutLine:
    """The last line of a log, left out because it was incomplete.

    Attributes:
        line: its 1-based line number.
        message: what it starts with (a CARMEN message name, or its first field).
        problem: why it does not read (the error's text after the file name).
        n_bytes: its length in bytes (UTF-8).
        records: whole records left out with it (a CSV scan whose rows it ended), besides
            the line itself.
    """

    line: int
    message: str
    problem: str
    n_bytes: int
    records: int = 0

    def warning(self, path: object) -> str:
        """The importers' one warning line (without ``warning: ``)."""
        also = f", and the {self.records} line(s) of the scan it ended" if self.records else ""
        return (
            f"{path}:{self.line}: {self.problem}; the log's last line ({self.n_bytes} bytes){also}, "
            "left out as incomplete (a log cut short; --stamps strict refuses it)"
        )


def cut_last_line(
    exc: InputError, text: str, no: int, last: int, line: str, where: str, strict: bool
) -> CutLine:
    """The :class:`CutLine` for line ``no`` (of ``last`` lines, 1-based) that raised
    ``exc``, when the rule above says the log was cut there.

    Args:
        text: the whole log (to tell whether it ends with a newline).
        line: the line's text; ``where``: the prefix ``exc``'s message starts with.
        strict: refuse a cut log instead (``--stamps strict``).

    Raises:
        InputError: ``exc`` itself when the line is not the cut end of the log; with
            ``strict``, ``exc``'s message saying that the log was cut short.
    """
    short = isinstance(exc, ShortLineError)
    if no != last or not (short or not text.endswith(("\n", "\r"))):
        raise exc
    if strict:
        raise InputError(
            f"{exc} (the log's last line, incomplete: a log cut short; --stamps repair leaves it out)"
        ) from None
    problem = str(exc).removeprefix(f"{where}: ")
    fields = line.split()
    return CutLine(no, fields[0] if fields else "", problem, len(line.encode("utf-8")))
