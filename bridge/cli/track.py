"""``hitch track``: stream setpoints to the service's track mode (``docs/tracking.md``).

A session is started with ``track/start`` (``--frame``, ``--dof``, ``--ttl-ms``), setpoints are put on
``track/setpoint`` at ``--rate`` Hz from a signal, and at the end (``--duration``, the end of the file,
or Ctrl-C) ``track/stop`` is sent and the command waits until the service reports the motion finished.

Signals, all SI (m, rad, s):

* ``--sine x=0.02@0.05Hz,roll=0.01@0.1Hz``: ``centre + A·sin(2π·f·t)`` per DOF with its velocity
  ``A·2π·f·cos(2π·f·t)``; the centre is the pose at the start (read from the state), except roll and
  pitch in frame ``level`` (centre 0: level) and z in frame ``ground`` (``--around z=H`` required);
  ``--around`` sets any centre.
* ``--from-file signal.csv``: a header ``t`` [s] and DOF names (``x``, ``z`` [m], ``roll``,
  ``pitch`` [rad]), optionally ``v_<dof>`` velocities [m/s, rad/s]; linear interpolation at the rate;
  played from the first row's time. A column may carry its SI unit (``t_s``, ``z_m``, ``roll_rad``,
  ``v_z_m_s``, as the scenario CSVs do); other units (``z_mm``, ``z [m]``) are refused.

DOFs in ``--dof`` without a signal hold their centre. :class:`SineSignal`, :class:`CsvSignal` and
:func:`setpoints` are pure (``--dry-run`` prints the first setpoints without connecting).
"""

from __future__ import annotations

import argparse
import csv
import math
import re
import signal as signals
import sys
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from bridge.cli.errors import CLIError
from bridge.cli.model import PLAIN_NUMBER, PLAIN_NUMBER_WORDS, bounded_float
from bridge.cli.output import console, esc, limited_text, milli_text
from bridge.cli.plan import parse_pose_arg
from bridge.cli.service import STOP_TIMEOUT_S, _client_options, _run
from bridge.service.maneuvers.steps import POSE_BOUNDS, SETPOINT_VELOCITY_BOUND
from bridge.service.wire import to_json_text
from planner.errors import HitchError, unit_hint
from planner.model.types import CONTROLLED_POSE_UNITS
from planner.textfile import csv_error_words, read_text_file

__all__ = [
    "CsvSignal",
    "SineSignal",
    "SineTerm",
    "TrackSignal",
    "add_commands",
    "parse_dofs",
    "parse_sine",
    "read_signal_csv",
    "setpoints",
]

DOFS: tuple[str, ...] = ("x", "z", "roll", "pitch")
FRAMES: tuple[str, ...] = ("tractor", "level", "ground")
#: largest sine amplitude [m or rad]: beyond it a value is not a plausible SI value (mm, deg)
MAX_AMPLITUDE = 0.5
#: highest sine frequency [Hz]
MAX_FREQUENCY_HZ = 10.0
#: highest setpoint rate [Hz] (the service takes setpoints at up to 100 Hz)
MAX_RATE_HZ = 100.0
#: the longest a run streams [s]: ``--duration``, and a file played whole (its span from its first row)
MAX_DURATION_S = 3600.0
#: setpoints ``--dry-run`` prints
DRY_RUN_COUNT = 10
#: the longest the command waits for the service to report the motion finished after track/stop [s]
FINISH_TIMEOUT_S = 15.0
#: progress lines this often [s]
PROGRESS_EVERY_S = 1.0


# ---------------------------------------------------------------------------------------- signals
@dataclass(frozen=True)
class SineTerm:
    """``amplitude`` [m or rad] at ``frequency_hz`` of one DOF."""

    dof: str
    amplitude: float
    frequency_hz: float


def parse_sine(text: str) -> tuple[SineTerm, ...]:
    """``"x=0.02@0.05Hz,roll=0.01@0.1Hz"`` → terms (argparse type: errors name ``--sine`` and the range)."""
    terms: list[SineTerm] = []
    for part in filter(None, (p.strip() for p in text.split(","))):
        m = re.fullmatch(r"([a-z]+)\s*=\s*([^@\s]+)\s*@\s*([^\s]+?)\s*(hz)?", part, flags=re.IGNORECASE)
        if m is None:
            raise argparse.ArgumentTypeError(
                f"--sine: {part!r} is not DOF=AMPLITUDE@FREQUENCYHz, e.g. x=0.02@0.05Hz (SI: m, rad; Hz)"
            )
        dof, a_text, f_text = m.group(1), m.group(2), m.group(3)
        if dof not in DOFS:
            raise argparse.ArgumentTypeError(f"--sine: unknown DOF {dof!r}; allowed: {', '.join(DOFS)}")
        if any(t.dof == dof for t in terms):
            raise argparse.ArgumentTypeError(f"--sine: DOF {dof!r} given twice; give each of x, z, roll, pitch once")
        unit = CONTROLLED_POSE_UNITS[dof]
        try:
            a, f = float(a_text), float(f_text)
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--sine {dof}: amplitude and frequency must be numbers, got {a_text!r} and {f_text!r}"
            ) from None
        if not (math.isfinite(a) and 0.0 < a <= MAX_AMPLITUDE):
            hint = f" (SI units: {unit}, not mm or deg)" if math.isfinite(a) and a > MAX_AMPLITUDE else ""
            raise argparse.ArgumentTypeError(
                f"--sine {dof}: amplitude must lie in (0, {MAX_AMPLITUDE:g}] {unit}, got {a_text}{hint}"
            )
        if not (math.isfinite(f) and 0.0 < f <= MAX_FREQUENCY_HZ):
            raise argparse.ArgumentTypeError(
                f"--sine {dof}: frequency must lie in (0, {MAX_FREQUENCY_HZ:g}] Hz, got {f_text}"
            )
        peak = 2.0 * math.pi * f * a  # the sine's velocity amplitude: sent with every setpoint
        if peak > SETPOINT_VELOCITY_MAX:  # before: shown by --dry-run, refused by the service mid-session
            raise argparse.ArgumentTypeError(
                f"--sine {dof}: its velocity 2π·f·A = {peak:.4g} {unit}/s exceeds the ±{SETPOINT_VELOCITY_MAX:g} "
                f"{unit}/s a setpoint may carry: at {f:g} Hz the amplitude must be at most "
                f"{SETPOINT_VELOCITY_MAX / (2.0 * math.pi * f):.4g} {unit}"
            )
        terms.append(SineTerm(dof, a, f))
    if not terms:
        raise argparse.ArgumentTypeError("--sine: no terms given, e.g. x=0.02@0.05Hz,roll=0.01@0.1Hz")
    return tuple(terms)


def parse_dofs(text: str) -> tuple[str, ...]:
    """``"x,z"`` → ``("x", "z")`` in the canonical order (argparse type)."""
    names = [p.strip() for p in text.split(",") if p.strip()]
    for n in names:
        if n not in DOFS:
            raise argparse.ArgumentTypeError(f"--dof: unknown DOF {n!r}; allowed: a subset of {', '.join(DOFS)}")
    if len(set(names)) != len(names):
        raise argparse.ArgumentTypeError(f"--dof: each of {', '.join(DOFS)} at most once, got {text!r}")
    if not names:
        raise argparse.ArgumentTypeError(f"--dof: at least one of {', '.join(DOFS)}")
    return tuple(k for k in DOFS if k in names)


class TrackSignal(Protocol):
    """A setpoint signal: pose [m, rad] and velocity [m/s, rad/s] (None: not given) at time ``t`` [s]."""

    @property
    def dofs(self) -> tuple[str, ...]: ...

    @property
    def duration_s(self) -> float | None: ...

    def sample(self, t: float) -> tuple[dict[str, float], dict[str, float] | None]: ...


@dataclass(frozen=True)
class SineSignal:
    """``centre[k] + A·sin(2π f t)`` for each term, the held DOFs at ``centre`` (velocity 0)."""

    terms: tuple[SineTerm, ...]
    centre: Mapping[str, float]
    held: tuple[str, ...] = ()
    duration_s: float | None = None

    @property
    def dofs(self) -> tuple[str, ...]:
        names = {t.dof for t in self.terms} | set(self.held)
        return tuple(k for k in DOFS if k in names)

    def sample(self, t: float) -> tuple[dict[str, float], dict[str, float] | None]:
        pose = {k: float(self.centre[k]) for k in self.held}
        vel = {k: 0.0 for k in self.held}
        for term in self.terms:
            w = 2.0 * math.pi * term.frequency_hz
            pose[term.dof] = float(self.centre[term.dof]) + term.amplitude * math.sin(w * t)
            vel[term.dof] = term.amplitude * w * math.cos(w * t)
        return pose, vel


@dataclass(frozen=True)
class CsvSignal:
    """A recorded signal: times ``t`` [s] (from 0, strictly increasing), positions and optional
    velocities per DOF; linear interpolation, held at the ends; ``held`` DOFs at ``centre``."""

    path: str
    t: np.ndarray
    positions: Mapping[str, np.ndarray]
    velocities: Mapping[str, np.ndarray] = field(default_factory=dict)
    held: tuple[str, ...] = ()
    centre: Mapping[str, float] = field(default_factory=dict)
    duration: float | None = None

    @property
    def dofs(self) -> tuple[str, ...]:
        names = set(self.positions) | set(self.held)
        return tuple(k for k in DOFS if k in names)

    @property
    def span_s(self) -> float:
        return float(self.t[-1])

    @property
    def duration_s(self) -> float | None:
        return self.span_s if self.duration is None else self.duration

    def sample(self, t: float) -> tuple[dict[str, float], dict[str, float] | None]:
        pose = {k: float(np.interp(t, self.t, v)) for k, v in self.positions.items()}
        pose.update({k: float(self.centre[k]) for k in self.held})
        if not self.velocities:
            return pose, None
        vel = {k: float(np.interp(t, self.t, v)) for k, v in self.velocities.items()}
        vel.update({k: 0.0 for k in self.held})
        return pose, vel


_UNIT_SUFFIX = re.compile(
    r"^(?P<name>[a-z_]+?)\s*(?:[\[(].*[\])]|_(?:m|mm|cm|rad|mrad|deg|s|ms|m_s|mm_s|rad_s|deg_s)|\s+(?:m|mm|rad|deg|s))$",
    re.IGNORECASE,
)


#: a column name may carry its SI unit as the scenario files' CSV do (``t_s``, ``z_m``, ``roll_rad``, ``v_z_m_s``)
_SI_SUFFIX = {"t": "_s", "x": "_m", "z": "_m", "roll": "_rad", "pitch": "_rad"}


def _column_kind(name: str) -> tuple[str, str] | None:
    """(``"t"`` | ``"pos"`` | ``"vel"``, dof) of a header cell (its name, or the name with its SI unit as a
    suffix), None when unknown."""
    for bare, unit in _SI_SUFFIX.items():
        if name == bare + unit:
            return _column_kind(bare)
        if bare != "t" and name == f"v_{bare}{unit}_s":
            return _column_kind(f"v_{bare}")
    if name == "t":
        return "t", ""
    if name in DOFS:
        return "pos", name
    if name.startswith("v_") and name[2:] in DOFS:
        return "vel", name[2:]
    return None


#: the largest |velocity| a setpoint may carry [m/s, rad/s] (the service's track/setpoint schema)
SETPOINT_VELOCITY_MAX = SETPOINT_VELOCITY_BOUND


def _check_value(p: Path, line: int, col: int, name: str, kind: tuple[str, str], v: float) -> None:
    """A position or velocity outside what a setpoint may carry (the service's ``track/setpoint`` bounds,
    whatever the frame): refused at load, naming the line, the column, the range and a unit hint —
    not by the service after the session has started."""
    what, dof = kind
    if what == "pos":
        lo, hi = POSE_BOUNDS[dof]
        unit = CONTROLLED_POSE_UNITS[dof]
    elif what == "vel":
        lo, hi = -SETPOINT_VELOCITY_MAX, SETPOINT_VELOCITY_MAX
        unit = CONTROLLED_POSE_UNITS[dof] + "/s"
    else:
        return
    if not lo <= v <= hi:
        hint = unit_hint(v, lo, hi, unit) if what == "pos" else ""
        raise CLIError(
            f"{p}: line {line}, column {col} ({name}): {v:g} {unit} is outside [{lo:.4g}, {hi:.4g}] {unit} "
            f"(SI units){hint}"
        )


#: a CSV cell that is a number: what Python's ``float`` reads, less its digit separators (``1_0``) and non-ASCII
#: digits (a spreadsheet writes neither); a non-finite one is refused as such before this is asked
_PLAIN_NUMBER = PLAIN_NUMBER  # the command line's (bridge.cli.model)


#: the most data rows a signal file may hold: what the longest run (:data:`MAX_DURATION_S`) plays at the highest
#: setpoint rate (:data:`MAX_RATE_HZ`), both ends included; a file of more rows has more than a run can use (a
#: 3-million-row file took 55 s and 1.7 GB before a run was refused or began: a fuzz trial)
MAX_SIGNAL_ROWS = round(MAX_DURATION_S * MAX_RATE_HZ) + 1
#: the most characters of a header cell an error shows (a binary file's "header" echoed 2.4 KB of junk)
_SHOWN_CHARS = 60


def _shown(text: str) -> str:
    """``text`` as an error shows it: its ``repr``, cut to :data:`_SHOWN_CHARS` characters and "…"."""
    shown = repr(text)
    return shown if len(shown) <= _SHOWN_CHARS else shown[:_SHOWN_CHARS] + "…"


def _csv_rows(p: Path, f: Any) -> Iterator[tuple[int, list[str]]]:
    """``(line, cells)`` of the rows of the open file ``f`` that are neither blank nor a comment ('#…'); a row the
    CSV reader cannot read (a stray quote: the rest of the file one cell) as :class:`CLIError` naming its line."""
    reader = csv.reader(f)
    while True:
        first = reader.line_num + 1
        try:
            row = next(reader, None)
        except csv.Error as exc:
            raise CLIError(f"{p}: line {first}: {csv_error_words(exc, first, reader.line_num)}") from None
        if row is None:
            return
        if row and not row[0].lstrip().startswith("#") and any(c.strip() for c in row):
            yield reader.line_num, row


def read_signal_csv(path: str | Path) -> CsvSignal:
    """Read a signal file (see the module docstring); :class:`CLIError` naming the file, line and column.
    The file is read row by row, and refused past :data:`MAX_SIGNAL_ROWS` data rows."""
    p = Path(path)
    if not p.is_file():  # a folder, /dev/zero or a pipe exist, but hold no signal (a fuzz trial: "no such file")
        what = "is a folder" if p.is_dir() else "is not a regular file" if p.exists() else "does not exist"
        raise CLIError(f"--from-file {p}: {what}: give a CSV signal file (header t and DOF names)")
    try:
        # utf-8-sig: a spreadsheet's "CSV UTF-8" starts with a byte-order mark
        with p.open(encoding="utf-8-sig", newline="") as f:
            return _read_signal_rows(p, _csv_rows(p, f))
    except OSError as exc:
        raise CLIError(f"--from-file {p}: cannot read it ({exc.strerror or exc})") from None
    except UnicodeDecodeError:
        read_text_file(p, "--from-file", CLIError)  # names the byte and line
        raise CLIError(f"--from-file {p}: not UTF-8 text") from None  # (the file changed meanwhile)


def _read_signal_rows(p: Path, rows: Iterator[tuple[int, list[str]]]) -> CsvSignal:
    first = next(rows, None)
    if first is None:
        raise CLIError(f"{p}: empty; expected a header such as 't,z,roll' and rows of numbers (SI: s, m, rad)")
    head_line, header = first
    names = [h.strip() for h in header]
    if len(names) == 1 and ";" in names[0]:  # the wording of the calibration CSV reader's (planner.calibration)
        raise CLIError(
            f"{p}: line {head_line}: the header is separated by semicolons (a spreadsheet's CSV with decimal "
            "commas?); save it as CSV with commas between cells and decimal points"
        )
    kinds: list[tuple[str, str]] = []
    for col, name in enumerate(names, 1):
        kind = _column_kind(name)
        if kind is None:
            m = _UNIT_SUFFIX.match(name)
            if m is not None and _column_kind(m.group("name")) is not None:
                raise CLIError(
                    f"{p}: line {head_line}, column {col} ({_shown(name)}): only SI units — the values are SI (t in "
                    f"s, x z in m, roll pitch in rad, v_<dof> in m/s or rad/s); name the column {m.group('name')!r} "
                    "(or with its SI unit: t_s, z_m, roll_rad, v_z_m_s, …)"
                )
            raise CLIError(
                f"{p}: line {head_line}, column {col}: unknown column {_shown(name)}; allowed: t, "
                f"{', '.join(DOFS)}, {', '.join('v_' + k for k in DOFS)} (SI units)"
            )
        if kind in kinds:
            raise CLIError(f"{p}: line {head_line}, column {col}: column {name!r} given twice")
        kinds.append(kind)
    if ("t", "") not in kinds:
        raise CLIError(f"{p}: line {head_line}: no 't' column (time in s)")
    pos = [d for k, d in kinds if k == "pos"]
    if not pos:
        raise CLIError(f"{p}: line {head_line}: no DOF column; give at least one of {', '.join(DOFS)}")
    for col, (k, d) in enumerate(kinds, 1):
        if k == "vel" and d not in pos:
            raise CLIError(f"{p}: line {head_line}, column {col}: v_{d} without a {d} column")
    ti = kinds.index(("t", ""))
    bounds = [_value_bounds(k) for k in kinds]
    data: list[float] = []  # flat, row after row: a list per row cost 1.7 GB for 3 million rows
    last_t: float | None = None
    n_rows = 0
    for n, row in rows:
        n_rows += 1
        if n_rows > MAX_SIGNAL_ROWS:
            raise CLIError(
                f"{p}: line {n}: more than {MAX_SIGNAL_ROWS} rows of values (allowed: at most {MAX_SIGNAL_ROWS}, "
                f"{MAX_DURATION_S:g} s at {MAX_RATE_HZ:g} Hz, the longest run at the highest setpoint rate); "
                "play a part of the file, or resample it"
            )
        if len(row) != len(names):
            raise CLIError(f"{p}: line {n}: {len(row)} values, the header has {len(names)} columns")
        for col, cell in enumerate(row):
            try:
                v = float(cell)
            except ValueError:
                v = math.nan
                bad = True
            else:
                bad = not (bounds[col][0] <= v <= bounds[col][1]) or not _PLAIN_NUMBER.fullmatch(cell)
            if bad:  # the exact reason (the common case above costs one comparison a cell)
                _check_cell(p, n, col + 1, names[col], kinds[col], cell)
            data.append(v)
        t = data[-len(names) + ti]
        if last_t is None and t < 0:
            raise CLIError(f"{p}: line {n}, column {ti + 1} (t): t must be >= 0 s, got {t:g}")
        if last_t is not None and t <= last_t:
            raise CLIError(
                f"{p}: line {n}, column {ti + 1} (t): t must increase strictly, got {t:g} s after {last_t:g} s"
            )
        last_t = t
    if n_rows < 2:
        raise CLIError(f"{p}: needs at least 2 rows of values after the header (got {n_rows})")
    arr = np.asarray(data, float).reshape(n_rows, len(names))
    t_col = arr[:, ti] - arr[0, ti]
    positions = {d: arr[:, i].copy() for i, (k, d) in enumerate(kinds) if k == "pos"}
    velocities = {d: arr[:, i].copy() for i, (k, d) in enumerate(kinds) if k == "vel"}
    return CsvSignal(str(p), t_col, positions, velocities)


def _value_bounds(kind: tuple[str, str]) -> tuple[float, float]:
    """The values a column of ``kind`` may hold (:func:`_check_value`): finite, within a setpoint's bounds."""
    what, dof = kind
    if what == "pos":
        return POSE_BOUNDS[dof]
    if what == "vel":
        return -SETPOINT_VELOCITY_MAX, SETPOINT_VELOCITY_MAX
    return -sys.float_info.max, sys.float_info.max  # t: any finite number (checked after)


def _check_cell(p: Path, n: int, col: int, name: str, kind: tuple[str, str], cell: str) -> None:
    """:class:`CLIError` for a cell that is not a plain finite number within its column's bounds."""
    try:
        v = float(cell)
    except ValueError:
        raise CLIError(f"{p}: line {n}, column {col} ({name}): not a number: {cell.strip()!r}") from None
    if not math.isfinite(v):
        raise CLIError(f"{p}: line {n}, column {col} ({name}): must be finite, got {cell.strip()!r}")
    if not _PLAIN_NUMBER.fullmatch(cell):  # Python's float() also reads "1_0" as 10, "١٠" as 10
        raise CLIError(f"{p}: line {n}, column {col} ({name}): not a number: {cell.strip()!r} ({PLAIN_NUMBER_WORDS})")
    _check_value(p, n, col, name, kind, v)


def setpoints(
    signal: TrackSignal, rate_hz: float, duration_s: float | None = None
) -> Iterator[tuple[int, float, dict]]:
    """``(seq, t, body)`` at ``t = seq / rate`` for ``t`` ≤ ``duration_s`` (None: the signal's, or without
    end), and one more at ``t = duration_s`` when the end is not a whole number of periods: the last
    setpoint is always the signal at its end (the hitch ends where the recording ends; before, a file of
    0.05 s at 50 Hz ended with its value at 0.04 s, its last row never sent); ``body`` ``{"pose",
    "velocity"?}`` as a setpoint carries them."""
    end = signal.duration_s if duration_s is None else duration_s
    k = 0
    while True:
        t = k / rate_hz
        if end is not None and t > end + 1e-9:
            t = end  # the end itself, less than a period after the one before (the last one)
        pose, vel = signal.sample(t)
        body: dict[str, Any] = {"pose": pose}
        if vel is not None:
            body["velocity"] = vel
        yield k, t, body
        if end is not None and t >= end - 1e-9:
            return
        k += 1


# ---------------------------------------------------------------------------------------- the plan
@dataclass(frozen=True)
class _Spec:
    frame: str
    dofs: tuple[str, ...]
    ttl_ms: int
    rate_hz: float
    duration_s: float | None
    sine: tuple[SineTerm, ...] | None
    csv: CsvSignal | None
    around: Mapping[str, float]

    def signal_dofs(self) -> tuple[str, ...]:
        if self.sine is not None:
            return tuple(t.dof for t in self.sine)
        assert self.csv is not None
        return tuple(self.csv.positions)

    def centre(self, pose: Mapping[str, float] | None) -> dict[str, float]:
        """The centre of every DOF (sine centre, held value): ``--around``, else 0 for roll and pitch in
        frame level, else the start pose (``pose``; None in a dry run: 0)."""
        out: dict[str, float] = {}
        for k in self.dofs:
            if k in self.around:
                out[k] = float(self.around[k])
            elif self.frame == "level" and k in ("roll", "pitch"):
                out[k] = 0.0
            elif self.frame == "ground" and k == "z":
                if self.csv is not None and "z" in self.csv.positions:
                    continue  # the file's heights above the ground are absolute
                raise CLIError(
                    "--frame ground: z is the height above the ground there, which the state does not "
                    "carry; give its centre with --around z=HEIGHT (m)"
                )
            elif pose is None:
                out[k] = 0.0
            else:
                out[k] = float(pose[k])
        return out

    def signal(self, pose: Mapping[str, float] | None) -> TrackSignal:
        centre = self.centre(pose)
        held = tuple(k for k in self.dofs if k not in self.signal_dofs())
        if self.sine is not None:
            return SineSignal(self.sine, centre, held, self.duration_s)
        assert self.csv is not None
        c = self.csv
        return CsvSignal(c.path, c.t, c.positions, c.velocities, held, centre, self.duration_s)


def _spec(args) -> _Spec:
    if (args.sine is None) == (args.from_file is None):
        raise CLIError("hitch track: give exactly one signal: --sine DOF=A@FHz[,…] or --from-file signal.csv")
    csv_signal = read_signal_csv(args.from_file) if args.from_file is not None else None
    sig_dofs = tuple(t.dof for t in args.sine) if args.sine is not None else tuple(csv_signal.positions)  # type: ignore[union-attr]
    source = "--sine" if args.sine is not None else f"--from-file {args.from_file}"
    dofs = args.dof or tuple(k for k in DOFS if k in sig_dofs)
    extra = [k for k in sig_dofs if k not in dofs]
    if extra:
        raise CLIError(f"{source} names {', '.join(extra)}, which --dof {','.join(dofs)} does not track")
    if args.around:
        bad = [k for k in args.around if k not in dofs]
        if bad:
            raise CLIError(f"--around names {', '.join(bad)}, which --dof {','.join(dofs)} does not track")
        given = [k for k in args.around if csv_signal is not None and k in sig_dofs]
        if given:  # before: silently ignored, the file's values played
            raise CLIError(
                f"--around {', '.join(given)}: {args.from_file} gives {', '.join(given)} itself (absolute values); "
                "--around sets the centre of a --sine, or the value of a DOF the file does not give"
            )
        from planner.errors import unit_hint

        for k, v in args.around.items():
            lo, hi = POSE_BOUNDS[k]
            unit = "m" if k in ("x", "z") else "rad"
            if not lo <= v <= hi:  # before: sent, then refused by the service after the session had started
                raise CLIError(
                    f"--around {k} = {v:g} {unit} lies outside [{lo:g}, {hi:g}] {unit}" + unit_hint(v, lo, hi, unit)
                )
    ttl_ms = args.ttl_ms
    period_ms = 1000.0 / args.rate
    if period_ms > ttl_ms / 2 + 1e-6:  # (a rate given with 10 digits, 13.3333333333 Hz for 150 ms, is exactly half)
        raise CLIError(
            f"--rate {args.rate:g} Hz sends a setpoint every {period_ms:.0f} ms, more than half of --ttl-ms {ttl_ms} "
            f"ms: the session would go stale; use --rate >= {2000.0 / ttl_ms:g} Hz or a longer --ttl-ms"
        )
    if args.sine is not None:
        for term in args.sine:
            if term.frequency_hz > args.rate / 2:
                raise CLIError(
                    f"--sine {term.dof}: {term.frequency_hz:g} Hz is above half the setpoint rate "
                    f"(--rate {args.rate:g} Hz: at most {args.rate / 2:g} Hz)"
                )
    if csv_signal is not None and args.duration is not None and args.duration > csv_signal.span_s + 1e-9:
        raise CLIError(
            f"--duration {args.duration:g} s is longer than {args.from_file} ({csv_signal.span_s:g} s); "
            "leave it out to play the whole file"
        )
    if csv_signal is not None and args.duration is None and csv_signal.span_s > MAX_DURATION_S:
        # before: a file spanning 1e9 s was played whole, while --duration is capped at an hour
        raise CLIError(
            f"--from-file {args.from_file}: the file spans {csv_signal.span_s:g} s from its first row, more than the "
            f"{MAX_DURATION_S:g} s a track run may last (as --duration (0, {MAX_DURATION_S:g}] s); play a part of "
            "it with --duration S or split the file"
        )
    return _Spec(args.frame, dofs, ttl_ms, args.rate, args.duration, args.sine, csv_signal, args.around or {})


# ---------------------------------------------------------------------------------------- running
class _Monitor:
    """The session's progress (the state's ``track`` entry) and its end (an event or the state)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.session: int | None = None
        self.motion_id: int | None = None
        self.track: dict[str, Any] | None = None
        self.pose: dict[str, Any] | None = None
        self.outcome: dict[str, Any] | None = None
        #: the last state of the session before it began to brake (its ``track.ending`` false): the measured
        #: ``pose``, the commanded ``velocity`` and what ``limited`` the control then (:func:`_end_note`)
        self.at_stop: dict[str, Any] | None = None
        self.seen = False
        self.ended = threading.Event()
        self.outcome_seen = threading.Event()

    def watch(self, session: int, motion_id: int) -> None:
        with self.lock:
            self.session, self.motion_id = session, motion_id

    def on_event(self, e: dict) -> None:
        with self.lock:
            mid = self.motion_id
        if mid is not None and e.get("motion_id") == mid and e.get("event") in ("motion_finished", "motion_aborted"):
            with self.lock:
                self.outcome = e
            self.outcome_seen.set()
            self.ended.set()

    def on_state(self, s: dict) -> None:
        tr = s.get("track")
        with self.lock:
            self.pose = s.get("pose")
            if self.session is None:
                return
            if isinstance(tr, dict) and tr.get("session") == self.session:
                self.track, self.seen = dict(tr), True
                if not tr.get("ending") and isinstance(s.get("pose"), dict):
                    self.at_stop = {
                        "pose": dict(s["pose"]),
                        "velocity": dict(s.get("velocity") or {}),
                        "limited": {**(s.get("limited") or {}), **(tr.get("control_limited") or {})},
                    }
            elif self.seen:  # it was live and is gone
                self.ended.set()


def _progress_line(t: float, sent: int, tr: dict | None) -> str:
    """One line of rich markup (data escaped)."""
    if not tr:
        return esc(f"t {t:6.1f} s  sent {sent}  (no track state yet)")
    text = esc(
        f"t {t:6.1f} s  sent {sent}  taken {tr.get('setpoints')}  rejected {tr.get('rejected')}  "
        f"ignored {tr.get('ignored_seq')}"
    )
    lim = tr.get("control_limited") or {}
    if lim:
        text += f"  [red]control limited: {esc(limited_text(lim))}[/red]"
    if tr.get("last_rejection") and tr.get("rejected"):
        text += f"  last rejection: {esc(tr['last_rejection'])}"
    return text


def _end_session(c, mon: _Monitor, session: int, last_seq: int | None) -> str | None:
    """Send ``track/stop`` (a second Ctrl-C meanwhile is ignored; ``last_seq``: the last setpoint sent,
    taken by the service before it brakes) and wait for the motion's end; the reason the stop could not
    be confirmed, or None."""
    from bridge.service.client import ServiceError

    main = threading.current_thread() is threading.main_thread()
    # a second Ctrl-C, or the hang-up of a terminal closing after the first, must not end the wait (nor the stop)
    ignored = (signals.SIGINT, signals.SIGHUP) if hasattr(signals, "SIGHUP") else (signals.SIGINT,)
    old = {sig: signals.signal(sig, signals.SIG_IGN) for sig in ignored} if main else {}
    problem: str | None = None
    try:
        if not mon.ended.is_set():
            try:
                c.track_stop(session, last_seq=last_seq, timeout_s=STOP_TIMEOUT_S)
            except ServiceError as exc:
                if exc.code != "not_found":  # not_found: it had ended already
                    problem = f"track/stop was not confirmed ({exc})"
        if not mon.ended.wait(FINISH_TIMEOUT_S):
            problem = (problem + "; " if problem else "") + f"the session did not finish within {FINISH_TIMEOUT_S:g} s"
        mon.outcome_seen.wait(1.0)  # the outcome event follows the state that shows the end
    finally:
        for sig, handler in old.items():
            signals.signal(sig, handler)
    return problem


#: a gap between the end pose and the last setpoint beyond which the summary says so [m or rad]
END_GAP_NOTE = 0.005


def _end_gap(frame: str, last: dict[str, float], pose: dict[str, Any] | None) -> dict[str, float] | None:
    """The end pose minus the last setpoint sent, per DOF it named [m, rad] (frame ``tractor``: the state's
    pose is in that frame; None otherwise, or without either)."""
    if frame != "tractor" or not last or not pose:
        return None
    return {k: float(pose[k]) - float(v) for k, v in last.items() if k in pose}


def _end_note(
    gap: Mapping[str, float] | None, at_stop: Mapping[str, Any] | None, pose: Mapping[str, Any] | None
) -> tuple[str | None, dict[str, float] | None]:
    """``(text, braking)``: the note on an end pose more than :data:`END_GAP_NOTE` from the last setpoint sent
    (``gap``: end pose minus that setpoint, :func:`_end_gap`), None without one; ``braking``: how far the hitch
    travelled after the stop began [m, rad] — the end pose minus the pose in the last state before the session
    began to brake (``at_stop``; None when no such state was seen).

    ``track/stop`` brakes from the velocity the hitch has then: a hitch that follows a moving signal comes to
    rest beyond the last setpoint, in the direction it travelled, by at most the distance it braked (less the
    little it trailed the stream). A gap that way and no larger is the stop's braking distance (the README's
    quick-start sine, 63 mm/s through its centre: z +7.4 mm after braking 14.8 mm, the hitch 7.4 mm behind the
    setpoint as the stop began: transport and measurement). Only a gap beyond the braking distance, against the
    travel (short of the setpoint), or with the control limited when the stop began blames the signal; before,
    every gap did ("the signal ran faster than the hitch may follow" for that unclipped sine)."""
    far = {k: g for k, g in (gap or {}).items() if abs(g) > END_GAP_NOTE}
    if not far:
        return None, None
    gaps = ", ".join(milli_text(k, g) for k, g in far.items())
    braking: dict[str, float] | None = None
    before = (at_stop or {}).get("pose") or {}
    if at_stop is not None and pose and all(k in pose and k in before for k in far):
        braking = {k: float(pose[k]) - float(before[k]) for k in (gap or {}) if k in pose and k in before}
    blame = (
        "the signal ran faster than the hitch may follow, or it began far from where the hitch stood (the hitch "
        "starts where it is: docs/tracking.md)"
    )
    if braking is None:  # no state before the stop: what the stop did is not known
        return (
            f"hitch: note: the hitch ended away from the last setpoint sent ({gaps}: end pose minus setpoint): "
            f"{blame.removesuffix(' (the hitch starts where it is: docs/tracking.md)')}, or it braked that far "
            "after track/stop (docs/tracking.md)",
            braking,
        )
    travelled = ", ".join(milli_text(k, braking[k]) for k in far)
    limited = (at_stop or {}).get("limited") or {}
    explained = all(g * braking[k] > 0 and abs(g) <= abs(braking[k]) for k, g in far.items())
    if limited or not explained:
        why = f"it travelled {travelled} after the stop began"
        if limited:
            why += f"; control limited as the stop began: {limited_text(limited)}"
        return (
            f"hitch: note: the hitch ended away from the last setpoint sent ({gaps}: end pose minus setpoint; {why}): "
            + blame,
            braking,
        )
    velocity = (at_stop or {}).get("velocity") or {}
    rates = ", ".join(milli_text(k, float(velocity[k]), per_s=True) for k in far if k in velocity)
    return (
        f"hitch: note: the hitch came to rest {gaps} beyond the last setpoint sent (end pose minus setpoint): the "
        "braking distance of track/stop, which brakes from the velocity the hitch had"
        + (f" ({rates})" if rates else "")
        + f"; it travelled {travelled} after the stop began (docs/tracking.md)",
        braking,
    )


def _missed_outcome(c: Any, motion_id: int, instance: Any) -> dict[str, Any] | None:
    """The end event of ``motion_id`` from the service's recent events (``events/recent``), when the subscription
    missed it (a frozen service, a router restart: the field trial's "outcome UNKNOWN"); None when it is not kept,
    cannot be asked, or the service is another run than ``instance`` (the one the session began in: motion ids
    restart with a run, a review)."""
    try:
        first = c.recent_events(0)
        if instance is None or first.get("instance") != instance:
            return None
        reply = c.recent_events(max(0, int(first.get("latest") or 0) - MAX_EVENTS_ASKED))
        got = reply.get("events") or [] if reply.get("instance") == instance else []
    except Exception:  # noqa: BLE001 — an older service without the key, or the link still down: unknown it stays
        return None
    ends = [
        e for e in got if e.get("motion_id") == motion_id and e.get("event") in ("motion_finished", "motion_aborted")
    ]
    return ends[-1] if ends else None


def _run_of(c: Any) -> Any:
    """The service run ``c`` talks to (``config``'s ``instance``); None when it cannot be asked (an older service)."""
    try:
        return c.config().get("instance")
    except Exception:  # noqa: BLE001 — not known: a missed outcome is then not looked up
        return None


#: how many of the newest events :func:`_missed_outcome` looks through (one reply's worth)
MAX_EVENTS_ASKED = 500


def _say(text: str) -> None:
    """A line on stderr; nothing when stderr is gone (a closed terminal after SIGHUP: the stop goes on)."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


#: how ``hitch track`` names the signal that ended its stream (SIGINT: Ctrl-C)
_SIGNAL_WORDS: dict[int, str] = {signals.SIGTERM: "terminated (SIGTERM)"}
if hasattr(signals, "SIGHUP"):
    _SIGNAL_WORDS[signals.SIGHUP] = "hung up (SIGHUP: the terminal closed)"


def _stream(args, c, spec: _Spec) -> int:
    mon = _Monitor()
    c.subscribe("events", mon.on_event)
    c.subscribe("state", mon.on_state)
    start_state = c.state()
    run = _run_of(c)  # the service's run the session begins in (config's instance)
    sig = spec.signal(start_state.get("pose") or {})
    quiet = args.json
    out = console(soft_wrap=True, stderr=False)
    r = c.track_start(spec.frame, spec.dofs, spec.ttl_ms, replace=args.replace)
    session, mid = int(r["session"]), int(r["motion_id"])
    mon.watch(session, mid)
    if not quiet:
        out.print(
            esc(
                f"track session {session} (motion {mid}): frame {r.get('frame')}, dof {','.join(r.get('dof', []))}, "
                f"ttl {r.get('ttl_ms')} ms, {spec.rate_hz:g} Hz"
                + (f", {sig.duration_s:g} s" if sig.duration_s is not None else ", until Ctrl-C")
            ),
            highlight=False,
        )
    sent, t_sent, interrupted = 0, 0.0, False
    last_seq: int | None = None
    last_pose: dict[str, float] = {}
    # SIGTERM (a supervisor, `kill`) and SIGHUP (the terminal closed) end the stream as Ctrl-C does: track/stop
    # sent and awaited, not a silent exit that leaves the service to brake at the ttl (new users' reports)
    caught: list[int] = []

    def on_signal(signum: int, _frame: object) -> None:
        caught.append(signum)
        raise KeyboardInterrupt

    old_handlers = (
        {sig: signals.signal(sig, on_signal) for sig in _SIGNAL_WORDS}
        if threading.current_thread() is threading.main_thread()
        else {}
    )
    t0 = time.monotonic()
    next_progress = PROGRESS_EVERY_S
    stream = setpoints(sig, spec.rate_hz, spec.duration_s)
    try:
        ahead = next(stream, None)
        while ahead is not None:
            (seq, t, body), ahead = ahead, next(stream, None)
            if mon.ended.is_set():
                break
            due = t0 + t
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif -delay > 2.0 / spec.rate_hz and seq > 0 and ahead is not None:
                # late (a loaded machine): skip to the setpoint of now rather than replaying the past — never the
                # last one: the hitch ends where the signal ends
                continue
            last_seq = seq  # before it goes: a stop after an interrupted put waits for it (at most the ttl)
            if seq == 0:  # the first one answered: a bad value is named at once
                c.track_setpoint_request(session, seq, body["pose"], body.get("velocity"), timeout_s=STOP_TIMEOUT_S)
            else:
                c.track_setpoint(session, seq, body["pose"], body.get("velocity"))
            sent, t_sent, last_pose = sent + 1, t, body["pose"]
            if not quiet and t >= next_progress:
                next_progress += PROGRESS_EVERY_S
                with mon.lock:
                    tr = mon.track
                out.print(_progress_line(t, sent, tr), highlight=False)
    except KeyboardInterrupt:
        interrupted = True
        _say(
            f"hitch: {_SIGNAL_WORDS.get(caught[-1], 'interrupted') if caught else 'interrupted'}: sending track/stop "
            f"(session {session})"
        )
    except HitchError:  # the first setpoint refused (or a client error): end the session, then report
        _end_session(c, mon, session, last_seq)
        raise
    finally:
        for signum, handler in old_handlers.items():
            signals.signal(signum, handler)
    problem = _end_session(c, mon, session, last_seq)
    with mon.lock:
        outcome, tr, pose, at_stop = mon.outcome, mon.track, mon.pose, mon.at_stop
    if outcome is None and problem is None:  # its end was seen in the state only: the event never came
        outcome = _missed_outcome(c, mid, run)  # asked for afterwards (events/recent), from the same run
    end_gap = _end_gap(spec.frame, last_pose, pose)
    note, braking = _end_note(end_gap, at_stop, pose)
    reason = (outcome or {}).get("reason")
    ours = reason == "track/stop"
    if note is not None and outcome is not None and not ours:
        # ended by something else (a stale stream, a fault, a stop): that is why it is away from the last setpoint,
        # not the signal (a field trial: a stale stream and a killed ECU were blamed on the signal's speed)
        far = ", ".join(milli_text(k, g) for k, g in (end_gap or {}).items() if abs(g) > END_GAP_NOTE)
        note = (
            f"hitch: note: the hitch ended away from the last setpoint sent ({far}: end pose minus setpoint): the "
            f"session ended before track/stop — {reason or (outcome or {}).get('event')}"
        )
    unknown = None
    if outcome is None and problem is None:  # not heard, and no longer kept (or not asked: an older service)
        note = None  # the end note would blame the signal for what the link did
        unknown = (
            f"hitch: outcome UNKNOWN: session {session} (motion {mid}) ended, but its end event was not heard — "
            "events were missed (the link to the service broke, or a router restarted); `hitch log` on the "
            "service says how it ended"
        )
    summary = {
        "session": session,
        "motion_id": mid,
        "frame": r.get("frame"),
        "dof": r.get("dof"),
        "sent": sent,
        "last_seq": last_seq,  # the seq of the last setpoint sent
        "streamed_s": round(t_sent, 6),
        "finished": mon.ended.is_set(),
        "outcome": outcome,
        "reason": reason,
        "track": tr,
        "pose": pose,
        "problem": problem,
        "interrupted": interrupted,
        "end_gap": end_gap,
        "end_braking": braking,
        "outcome_unknown": unknown is not None,  # (``reason`` stays the service's own: None here)
    }
    try:
        _summary(out, summary, quiet)
    except OSError:  # stdout gone (a closed terminal): the session has ended all the same
        pass
    if note is not None and not interrupted:
        _say(note)
    ignored, taken = (tr or {}).get("ignored_seq") or 0, (tr or {}).get("last_seq")
    if ignored and isinstance(taken, int) and last_seq is not None and taken > last_seq:
        # the session took a seq this stream never sent: another client put into it (a fleet trial: its stream
        # was then ignored until it went stale, and the note blamed the signal)
        _say(
            f"hitch: note: {ignored} setpoint(s) of this stream were ignored: session {session} took seq {taken}, "
            f"above the last this stream sent ({last_seq}) — another client sent into this session"
        )
    if problem is not None:
        _say(f"hitch: {problem}; stop the hitch another way (`hitch stop`, STOP)")
    if unknown is not None:
        _say(unknown)
    if interrupted:
        raise KeyboardInterrupt
    if problem is not None:
        return 1
    return 0 if ours else 1


def _summary(out, summary: dict[str, Any], quiet: bool) -> None:
    """The summary at the end of a stream: one JSON object (``--json``), else one line."""
    session, mid, sent, tr, pose = (summary[k] for k in ("session", "motion_id", "sent", "track", "pose"))
    outcome, reason, t_sent = summary["outcome"], summary["reason"], summary["streamed_s"]
    if quiet:
        print(to_json_text(summary))
    else:
        text = f"track session {session} (motion {mid}) " + (
            "ended: outcome unknown (its end event was not heard)"
            if summary.get("outcome_unknown")
            else f"{(outcome or {}).get('event', 'ended').replace('motion_', '')}: {reason or '-'}"
            if summary["finished"]
            else "did not finish"
        )
        text += f"; sent {sent} setpoints over {t_sent:.2f} s"
        if tr:
            text += (
                f"; service took {tr.get('setpoints')}, rejected {tr.get('rejected')}, ignored {tr.get('ignored_seq')}"
            )
            if tr.get("rejected") and tr.get("last_rejection"):  # why (a new user's report: only `hitch log` said)
                text += f"; last rejection: {tr['last_rejection']}"
            missing = sent - (tr.get("setpoints") or 0) - (tr.get("rejected") or 0)
            if summary["finished"] and missing > 0:
                last = summary.get("last_seq")
                if last is not None and tr.get("last_seq") == last:
                    # the last one was taken: the ones missing were lost on the way (a put is dropped under
                    # congestion, never queued), not sent after the end (a field trial: 151 sent, 150 taken, ended
                    # by its own track/stop, and told "sent after the session ended")
                    text += f"; {missing} setpoint put(s) did not reach the service (a put is dropped, never queued)"
                else:
                    text += "; setpoints sent after the session ended were not taken"
        if pose:
            text += "; now at " + "  ".join(f"{k}={pose[k]:+.4f} {CONTROLLED_POSE_UNITS[k]}" for k in DOFS if k in pose)
        out.print(esc(text), highlight=False)


def _dry_run(args, spec: _Spec) -> int:
    sig = spec.signal(None)
    rows = []
    for seq, t, body in setpoints(sig, spec.rate_hz, spec.duration_s):
        if seq >= DRY_RUN_COUNT:
            break
        rows.append({"seq": seq, "t": round(t, 9), **body})
    centre = spec.centre(None)
    note = (
        f"dry run: frame {spec.frame}, dof {','.join(spec.dofs)}, ttl {spec.ttl_ms} ms, {spec.rate_hz:g} Hz; "
        f"first {len(rows)} setpoints (SI: m, rad, m/s, rad/s)"
    )
    if args.sine is not None:
        unset = [
            k for k in spec.dofs if k not in spec.around and not (spec.frame == "level" and k in ("roll", "pitch"))
        ]
        if unset:
            note += f"; centre of {', '.join(unset)} shown as 0: the start pose is added when it runs"
    if args.json:
        print(to_json_text({"frame": spec.frame, "dof": list(spec.dofs), "centre": centre, "setpoints": rows}))
        return 0
    lines = [note]
    for row in rows:
        v = row.get("velocity")
        lines.append(
            f"{row['seq']:5d}  t={row['t']:8.3f}  "
            + "  ".join(f"{k}={row['pose'][k]:+.6f}" for k in spec.dofs)
            + ("  v: " + "  ".join(f"{k}={v[k]:+.6f}" for k in spec.dofs if k in v) if v else "")
        )
    console(soft_wrap=True).print("\n".join(lines), markup=False, highlight=False)
    return 0


def _cmd_track(args) -> int:
    spec = _spec(args)
    if args.dry_run:
        return _dry_run(args, spec)
    return _run(args, lambda c: _stream(args, c, spec))


def _ttl(text: str) -> int:
    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--ttl-ms must be a whole number of ms in [50, 1000], got {text!r}") from None
    if not 50 <= v <= 1000:
        raise argparse.ArgumentTypeError(f"--ttl-ms must lie in [50, 1000] ms, got {text}")
    return v


def add_commands(sub) -> None:
    p = sub.add_parser(
        "track",
        help="stream setpoints to the service's track mode (a sine or a CSV signal; docs/tracking.md)",
        description=(
            "Start a track session, stream setpoints at --rate Hz, and at the end (--duration, the end of the "
            "file, Ctrl-C) send track/stop and wait until the motion finished. All values SI: m, rad, s."
        ),
    )
    p.add_argument(
        "--dof",
        type=parse_dofs,
        default=None,
        help="tracked DOFs, a subset of x,z,roll,pitch (default: those of the signal; others listed hold their centre)",
    )
    p.add_argument(
        "--frame",
        choices=FRAMES,
        default="tractor",
        help="tractor (default); level: roll and pitch relative to gravity (the slope sensor's attitude added); "
        "ground: z above the ground (the ground-distance sensor)",
    )
    p.add_argument(
        "--ttl-ms",
        type=_ttl,
        default=200,
        help="the service brakes without a setpoint this long, [50, 1000] ms (default 200)",
    )
    p.add_argument(
        "--rate",
        type=bounded_float("--rate", 0.0, MAX_RATE_HZ, unit="Hz"),
        default=50.0,
        help=f"setpoints per second, (0, {MAX_RATE_HZ:g}] Hz (default 50)",
    )
    p.add_argument(
        "--sine",
        type=parse_sine,
        default=None,
        metavar="DOF=A@FHz[,…]",
        help="e.g. x=0.02@0.05Hz,roll=0.01@0.1Hz: amplitude A in SI (m, rad; (0, 0.5]) at F Hz ((0, 10], at most "
        "half of --rate) around the pose at the start (read from the state); in frame level roll and pitch "
        "around 0 (level); in frame ground z around --around z=H",
    )
    p.add_argument(
        "--from-file",
        default=None,
        metavar="CSV",
        help="columns t [s] and DOF names x, z [m], roll, pitch [rad], optional v_<dof> [m/s, rad/s]; SI only, "
        "a column may carry its SI unit (t_s, z_m, roll_rad, v_z_m_s); interpolated linearly at --rate, played from "
        "the first row",
    )
    p.add_argument(
        "--around",
        type=parse_pose_arg,
        default=None,
        metavar="POSE",
        help="centre of the sine and value of held DOFs, e.g. z=0.3 (SI; default: see --sine)",
    )
    p.add_argument(
        "--duration",
        type=bounded_float("--duration", 0.0, MAX_DURATION_S, unit="s"),
        default=None,
        help=f"stream this long, (0, {MAX_DURATION_S:g}] s (default: the whole file, at most {MAX_DURATION_S:g} s "
        "long; a sine until Ctrl-C)",
    )
    p.add_argument(
        "--replace",
        action="store_true",
        help="take over a track session another client streams (default: refused busy while its stream is live)",
    )
    p.add_argument(
        "--dry-run",
        action="store_true",
        help=f"print the first {DRY_RUN_COUNT} setpoints without connecting (centres not given as 0)",
    )
    _client_options(p)
    p.set_defaults(handler=_cmd_track)
