"""Reading the project's text files (profiles, maneuvers, scenarios, CSV): UTF-8, or one clear error.

``Path.read_text`` raises ``UnicodeDecodeError`` (a ``ValueError`` that is not a
:class:`~planner.errors.HitchError`: the CLI shows it as a traceback) for a byte that is not
UTF-8, and ``OSError`` for a file it cannot read. :func:`read_text_file` turns both into the
caller's :class:`~planner.errors.HitchInputError`, naming the file and the byte.
"""

from __future__ import annotations

import csv
from importlib.resources.abc import Traversable
from pathlib import Path

from planner.errors import HitchInputError

__all__ = ["read_text_file", "csv_error_words"]


def read_text_file(
    path: str | Path | Traversable,
    what: str,
    error: type[HitchInputError] = HitchInputError,
    *,
    max_bytes: int | None = None,
) -> str:
    """The text of ``path`` (UTF-8, a leading byte-order mark dropped: Windows editors and spreadsheets write
    one, and TOML read it as "Invalid statement at line 1, column 1"); ``error`` naming ``what`` (e.g.
    "maneuver file"), the path and the offending byte when it cannot be read or is not UTF-8 text; and, with
    ``max_bytes``, naming the size and the limit of a larger file before reading it."""
    p = Path(path) if isinstance(path, str) else path
    if max_bytes is not None and isinstance(p, Path):
        try:
            size = p.stat().st_size
        except OSError:
            size = 0  # read_bytes says why
        if size > max_bytes:
            raise error(
                f"{what} {p}: {size / 2**20:.1f} MiB, larger than this kind of file may be "
                f"({max_bytes / 2**20:g} MiB allowed)"
            )
    try:
        data = p.read_bytes()
    except OSError as exc:
        raise error(f"{what} {p}: cannot read it ({exc.strerror or exc})") from None
    try:
        return data.decode("utf-8").removeprefix("\ufeff")
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise error(
            f"{what} {p}: not UTF-8 text (byte {exc.start}, line {line}: 0x{data[exc.start]:02x}); save it as UTF-8"
        ) from None


def csv_error_words(exc: csv.Error, first_line: int, last_line: int) -> str:
    """What a :class:`csv.Error` of a row from ``first_line`` to ``last_line`` (the reader's line when it gave
    up) means, in the operator's words: an opening quote without its closing one reads the rest of the file
    as one cell (a 210 KB file with a stray ``"`` in a label raised ``_csv.Error: field larger than field
    limit`` as a traceback, a trial); a single line too long is no CSV such a file holds."""
    limit = csv.field_size_limit()
    if "field larger than field limit" in str(exc) or "unexpected end of data" in str(exc):
        if last_line > first_line or "unexpected end" in str(exc):
            return f'a quoted field never ends (a stray " ?; it ran on to line {last_line})'
        return f"a cell longer than {limit} characters (not a CSV file of this kind?)"
    return f"not readable as CSV ({exc})"
