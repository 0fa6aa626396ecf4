"""Terminal output of the ``hitch`` commands: one console factory and markup escaping.

Text that comes from data (limit names such as ``workspace:x:max``, fault reasons, preset and
maneuver names, service messages) must print as it is: rich would read ``:x:`` as an emoji code
and ``[red]`` as markup. :func:`console` turns emoji codes off for every command; :func:`esc`
escapes markup in a data value that is embedded in a line with the command's own markup.
"""

from __future__ import annotations

import argparse
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.markup import escape

__all__ = ["console", "esc", "limited_text", "output_path", "p95_words", "plot_path", "pose_text", "signed"]


#: the width of a console whose output is not a terminal (a pipe, a file, a log): wide enough that no
#: record is split from its unit
PIPE_WIDTH = 200


def p95_words(p95: Mapping[str, float]) -> str:
    """A predicted p95 pose error (``{x_m, z_m, roll_rad, pitch_rad}``, SI: ``PredictedAccuracy.as_dict``) as an
    operator reads it: ``x 0.48 mm, z 0.58 mm, roll 0.64 mrad, pitch 0.64 mrad``."""
    return (
        f"x {1e3 * p95['x_m']:.2f} mm, z {1e3 * p95['z_m']:.2f} mm, roll {1e3 * p95['roll_rad']:.2f} mrad, "
        f"pitch {1e3 * p95['pitch_rad']:.2f} mrad"
    )


def console(**kwargs: Any) -> Console:
    """A rich console that never turns ``:name:`` into an emoji (kwargs as for :class:`Console`).

    Lines are not wrapped (``soft_wrap``), and into a pipe or a file the console is
    :data:`PIPE_WIDTH` columns wide (rich would take 80): ``hitch plan | grep …`` and logs keep each
    record, number and unit on one line. A terminal keeps its own width."""
    kwargs.setdefault("soft_wrap", True)
    c = Console(emoji=False, **kwargs)
    if "width" not in kwargs and not c.is_terminal:
        c.width = PIPE_WIDTH
    return c


def esc(value: object) -> str:
    """``str(value)`` with rich markup escaped, for data inside a marked-up line."""
    return escape(str(value))


def signed(value: float, digits: int) -> str:
    """``value`` with a sign and ``digits`` decimals; a value that rounds to zero prints ``+0.000…``,
    never ``-0.000…``."""
    return f"{round(float(value), digits) + 0.0:+.{digits}f}"


#: the unit of each pose field [SI] as the commands print it
POSE_UNITS = {"x": "m", "y": "m", "z": "m", "roll": "rad", "pitch": "rad", "yaw": "rad"}


def milli_text(name: str, value: float, per_s: bool = False) -> str:
    """``z +7.4 mm`` / ``roll -3.0 mrad`` (``/s`` with ``per_s``) of a pose field's value in SI [m, rad]."""
    unit = "mm" if POSE_UNITS[name] == "m" else "mrad"
    return f"{name} {signed(1e3 * value, 1)} {unit}{'/s' if per_s else ''}"


def pose_text(values: Any, names: tuple[str, ...] = ("x", "y", "z", "roll", "pitch", "yaw"), digits: int = 4) -> str:
    """``x=+0.0123 m  z=… m  roll=… rad …``: a pose's fields, each with its unit (``values`` in the
    order of ``names``)."""
    return "  ".join(
        f"{n}={signed(v, digits)} {POSE_UNITS[n]}" for n, v in zip(names, [float(v) for v in values], strict=True)
    )


def plot_path(text: str) -> str:
    """``--plot FILE`` checked where it is read (an argparse type), before a run that may take minutes:
    its folder must exist and its suffix must be a format matplotlib writes (``.png``, ``.pdf``,
    ``.svg`` …)."""
    from matplotlib.backend_bases import FigureCanvasBase  # only when --plot is given

    path = Path(text)
    formats = FigureCanvasBase.get_supported_filetypes()
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in formats:
        raise argparse.ArgumentTypeError(
            f"{text!r}: the file name must end in one of {', '.join('.' + f for f in sorted(formats))}"
        )
    folder = path.parent
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: the folder {str(folder)!r} does not exist")
    return text


def output_path(text: str) -> str:
    """An output ``FILE`` checked where it is read (an argparse type), before a run that may take minutes:
    its folder must exist and it must not be a folder itself. ``-`` (standard output) passes."""
    if text == "-":
        return text
    path = Path(text)
    if path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} is a folder; give a file name")
    folder = path.parent
    if not folder.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r}: the folder {str(folder)!r} does not exist")
    return text


def limited_text(limited: Mapping[str, Any]) -> str:
    """A state's ``limited`` (or a track session's ``control_limited``) entries in the operator's words, each
    with its code: ``lift arm slowing before its stroke end (end_stop:lift), …`` (the guard's own sentence,
    "end_stop:lift: speed: end_stop:lift would be 0.8086 (threshold 1) at t = 0.00 s", named the limit twice
    and gave a speed factor without saying so: a new user's report). Each limit once
    (:func:`bridge.web.wording.limited_entries`): a track DOF flagged by the implement's lowering speed limit
    and the guard's reason on that limit are one entry, ``lowering faster than the implement allows: 0.060 m/s
    (limit 0.050 m/s): slowed (vz)``; a speed factor reads as a share of full speed."""
    from bridge.web.wording import limited_entries

    return ", ".join(f"{w} ({k})" for k, w in limited_entries(limited))
