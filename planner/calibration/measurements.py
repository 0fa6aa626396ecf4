"""The measurement file of a geometry calibration: one CSV row per measured pose.

Columns (header row required; order free; unknown columns are an error):

* ``pose`` — optional label of the row (text);
* the actuator readings, for each of ``lift, tilt, top, left, right`` **either** ``<name>_counts`` —
  the raw AD reading the ECU reports (may be fractional for an averaged reading), within the nominal AD
  map's span ± 10 % (and 0…1023), converted with the *nominal* profile's AD map — **or** ``<name>`` —
  the reading in SI (rad for ``lift``, m for the others) through the nominal AD map, within the stroke
  ± 10 %;
* the measured pose in SI: ``x, z, roll, pitch`` (m, rad; all four or none) and optionally ``y, yaw``;
* optionally marked points in m: ``L_x, L_y, L_z`` (left ball centre), ``R_*`` (right), ``U_*``
  (top-link pin), three columns per point;
* optionally the pose the row was meant to be (``target_x, target_z, target_roll, target_pitch``, m and
  rad, as ``hitch calibrate plan-poses --out`` writes them): a note for the operator, not used by the fit;
* optionally ``approach`` — the side the pose was reached from in every DOF: ``below`` (a goto with the
  profile's ``motion.final_approach``: it ends rising), ``above`` (ends falling), or empty (unknown, or the
  play averaged). With any row below or above the fit also finds the lag the pin play leaves
  (:mod:`planner.calibration.parameters`).

A row that repeats an earlier one exactly (the same readings, approach side and measured values: a
copied row) is dropped and listed in :attr:`MeasurementSet.copies`; a repeat with other measured values is a
repeated measurement of that pose and kept. Every row needs its five readings and at least one measured
quantity; an empty cell means "not
measured" (only for the measured columns). Measured values must lie within ±3 m (positions) and
±π/2 (angles). A bad file raises :class:`~planner.calibration.parameters.CalibrationError` naming the
row (1 = first data row; the header is row 0) with its line, the column and the allowed range.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from planner.calibration.parameters import CalibrationError
from planner.calibration.parametric import OUTPUT_NAMES
from planner.errors import unit_hint
from planner.model.sensors import AD_COUNTS_MAX, SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import Profile
from planner.textfile import csv_error_words

__all__ = [
    "APPROACH_COLUMN",
    "APPROACH_SIDES",
    "MEASURED_COLUMNS",
    "TARGET_COLUMNS",
    "MeasurementSet",
    "load_measurements",
    "load_plan_targets",
    "measurements_csv",
    "parse_measurements",
]

_POINT_COLUMNS = tuple(f"{p}_{c}" for p in ("L", "R", "U") for c in "xyz")
#: measured quantities a file may hold (the rows of the model's output, :data:`OUTPUT_NAMES`)
MEASURED_COLUMNS: tuple[str, ...] = OUTPUT_NAMES
#: the planned pose a row was meant to be (m, rad): written by plan-poses, read by measure-twin --plan, not fitted
TARGET_COLUMNS: tuple[str, ...] = ("target_x", "target_z", "target_roll", "target_pitch")
#: the column naming the side each pose was approached from, and its words
APPROACH_COLUMN = "approach"
APPROACH_SIDES: dict[str, float] = {"below": -1.0, "above": 1.0, "": 0.0}
_ANGLES = {"roll", "pitch", "yaw"}
_POSITION_MAX_M = 3.0
_ANGLE_MAX = math.pi / 2
_STROKE_MARGIN = 0.10


@dataclass(frozen=True)
class MeasurementSet:
    """Measured poses: actuator readings (N, 5) in SI through the nominal AD map, measured outputs (N, 15)
    in :data:`OUTPUT_NAMES` order with ``mask`` (N, 15) true where measured, the row labels and the side
    each pose was approached from (N,: −1 below, +1 above, 0 unknown; default all 0). ``rows``: the data row
    numbers of the file the rows come from (1 = the first; default 1…N: a file's exact copies of earlier rows
    are dropped, so the numbers may skip), ``copies``: the (row, earlier row) pairs so dropped."""

    readings: np.ndarray
    values: np.ndarray
    mask: np.ndarray
    labels: tuple[str, ...]
    sides: np.ndarray | None = None
    rows: tuple[int, ...] | None = None
    copies: tuple[tuple[int, int], ...] = ()

    def __post_init__(self) -> None:
        n = self.readings.shape[0] if self.readings.ndim == 2 else -1
        if n < 1 or self.readings.shape != (n, 5) or self.values.shape != (n, 15) or self.mask.shape != (n, 15):
            raise CalibrationError("measurements: readings (N, 5), values and mask (N, 15) with N >= 1")
        if len(self.labels) != n:
            raise CalibrationError("measurements: one label per row")
        sides = np.zeros(n) if self.sides is None else np.asarray(self.sides, dtype=float).reshape(-1)
        if sides.shape != (n,) or not np.all(np.isin(sides, (-1.0, 0.0, 1.0))):
            raise CalibrationError("measurements: one approach side per row, each -1 (below), 0 or +1 (above)")
        object.__setattr__(self, "sides", sides)
        rows = tuple(range(1, n + 1)) if self.rows is None else tuple(int(r) for r in self.rows)
        if len(rows) != n:
            raise CalibrationError("measurements: one row number per row")
        object.__setattr__(self, "rows", rows)
        if not np.all(np.isfinite(self.readings)) or not np.all(np.isfinite(self.values[self.mask])):
            raise CalibrationError("measurements: readings and measured values must be finite")

    @property
    def n_rows(self) -> int:
        return int(self.readings.shape[0])

    @property
    def row_numbers(self) -> tuple[int, ...]:
        """The file's data row number of each row (1 = the first data row)."""
        assert self.rows is not None  # set in __post_init__
        return self.rows

    @property
    def n_poses(self) -> int:
        """Distinct poses: distinct readings, a pose measured from both sides once (the larger number of the
        two sides' distinct readings, plus the rows of unknown side: a pose's readings differ by the lag from
        one side to the other, and labels need not name poses)."""
        side = self.side_vector

        def distinct(rows: np.ndarray) -> int:
            return int(np.unique(self.readings[rows], axis=0).shape[0]) if np.any(rows) else 0

        return max(distinct(side < 0), distinct(side > 0)) + distinct(side == 0)

    @property
    def n_observations(self) -> int:
        return int(self.mask.sum())

    @property
    def n_distinct_observations(self) -> int:
        """Measured values of distinct poses: rows with the same readings (and approach side) count once per
        measured output (a repeat of a pose, or a copied row, adds no new direction to what the data determine;
        the same readings from the other side do: the lag)."""
        key = np.column_stack([self.readings, self.side_vector])
        _, group = np.unique(key, axis=0, return_inverse=True)
        group = np.asarray(group).reshape(-1)
        seen = np.zeros((int(group.max()) + 1, self.mask.shape[1]), bool)
        np.logical_or.at(seen, group, self.mask)
        return int(seen.sum())

    @property
    def sided(self) -> bool:
        """True when some row was approached from a known side."""
        return bool(np.any(self.side_vector != 0.0))

    @property
    def two_sided(self) -> bool:
        """True when rows were approached from below and rows from above: the fit can then find the lag."""
        return bool(np.any(self.side_vector < 0.0) and np.any(self.side_vector > 0.0))

    @property
    def side_vector(self) -> np.ndarray:
        """The approach sides (N,) as an array (−1 below, +1 above, 0 unknown)."""
        assert self.sides is not None  # set in __post_init__
        return self.sides

    def subset(self, rows: Sequence[int]) -> MeasurementSet:
        idx = list(rows)
        return MeasurementSet(
            self.readings[idx],
            self.values[idx],
            self.mask[idx],
            tuple(self.labels[i] for i in idx),
            self.side_vector[idx],
            tuple(self.row_numbers[i] for i in idx),
        )


def _cell(text: str, where: str, col: str, lo: float, hi: float, unit: str) -> float:
    """The number in ``text`` within [lo, hi] ``unit``; ``where``: the file and row, for the message."""
    allowed = f"[{lo:g}, {hi:g}] {unit}"
    try:
        v = float(text)
    except ValueError:
        hint = ""
        if text.count(",") == 1:  # a spreadsheet's decimal comma, quoted into a comma-separated file
            try:
                float(text.replace(",", "."))  # a number once the comma is a point
                hint = f"; a decimal comma? write {text.replace(',', '.')} with a decimal point"
            except ValueError:
                pass
        raise CalibrationError(f"{where}, column {col}: {text!r} is not a number (allowed: {allowed}){hint}") from None
    if not math.isfinite(v):
        raise CalibrationError(f"{where}, column {col}: {text!r} is not a finite number (allowed: {allowed})")
    if not lo <= v <= hi:
        raise CalibrationError(
            f"{where}, column {col}: {v:g} {unit} is outside the allowed {allowed}{unit_hint(v, lo, hi, unit)}"
        )
    return v


#: the most data rows a measurement or plan file may hold: poses measured by hand (20 are planned; a
#: 480 000-row file kept the CLI busy for minutes)
MAX_DATA_ROWS = 2000


def _next_row(reader: Any, source: str, row: int) -> list[str] | None:
    """The next row of ``reader`` (None at the end); a :class:`csv.Error` as :class:`CalibrationError` naming
    the file, the ``row`` (0: the header) and its line, and what it means (:func:`csv_error_words`)."""
    first = reader.line_num + 1
    try:
        return next(reader, None)
    except csv.Error as exc:
        line = f"the header, line {first}" if row == 0 else f"line {first}"
        raise CalibrationError(f"{source} row {row} ({line}): {csv_error_words(exc, first, reader.line_num)}") from None


def _data_rows(reader: Any, n_cells: int, source: str) -> Iterator[tuple[str, list[str]]]:
    """The data rows of a CSV ``reader`` past its header: ``(where, stripped cells)``, ``where`` naming the
    file, the row (1 = the first; blank lines are not rows) and its line; a row of another width is refused,
    and so is a file of more than :data:`MAX_DATA_ROWS` rows, and a row the CSV reader cannot read (a stray
    quote) names its row and line."""
    r = 0
    while True:
        line = _next_row(reader, source, r + 1)
        if line is None:
            return
        if not line or all(not c.strip() for c in line):
            continue
        r += 1
        if r > MAX_DATA_ROWS:
            raise CalibrationError(f"{source}: more than {MAX_DATA_ROWS} data rows (allowed: at most {MAX_DATA_ROWS})")
        where = f"{source} row {r} (line {reader.line_num})"
        if len(line) != n_cells:
            raise CalibrationError(f"{where}: {len(line)} cells, the header has {n_cells}")
        yield where, [c.strip() for c in line]


def _header(reader: Any, source: str) -> list[str]:
    """The header row (blank lines before it skipped), or :class:`CalibrationError` saying what the file holds
    instead: nothing, a comment line, semicolons (a spreadsheet's CSV with decimal commas) or tabs. Before, a file
    of blank lines was refused for a missing lift column, and a semicolon or tab file as one unknown column
    (trials)."""
    while (row := _next_row(reader, source, 0)) is not None:
        cells = [h.strip() for h in row]
        if not any(cells):
            continue
        if cells[0].startswith("#"):
            raise CalibrationError(
                f"{source} line {reader.line_num}: a comment line ('#…'); the first line that is not blank must "
                "be the header: remove the comment"
            )
        if len(cells) == 1 and "\t" in cells[0]:
            raise CalibrationError(
                f"{source} line {reader.line_num}: the header is separated by tabs (a spreadsheet's text export?); "
                "save it as CSV with commas between cells and decimal points"
            )
        if len(cells) == 1 and ";" in cells[0]:
            raise CalibrationError(
                f"{source} line {reader.line_num}: the header is separated by semicolons (a spreadsheet's CSV with "
                "decimal commas?); save it as CSV with commas between cells and decimal points"
            )
        return cells
    raise CalibrationError(f"{source}: empty file (a header row is required)")


def parse_measurements(text: str, profile: Profile, *, source: str = "measurements") -> MeasurementSet:
    """Parse measurement CSV text (module docstring) against the nominal ``profile`` (its AD map and strokes).
    A UTF-8 byte-order mark (a spreadsheet's "CSV UTF-8") is allowed."""
    reader = csv.reader(io.StringIO(text.removeprefix("\ufeff")))
    header = _header(reader, source)
    head = f"row 0 (the header, line {reader.line_num})"
    allowed = {
        "pose",
        APPROACH_COLUMN,
        *ACTUATOR_NAMES,
        *(f"{n}_counts" for n in ACTUATOR_NAMES),
        *MEASURED_COLUMNS,
        *TARGET_COLUMNS,
    }
    unknown = [h for h in header if h not in allowed]
    if unknown:
        raise CalibrationError(
            f"{source} {head}: unknown column(s) {unknown}; allowed: pose, {APPROACH_COLUMN}, "
            f"{', '.join(ACTUATOR_NAMES)} (SI) or <name>_counts, {', '.join(MEASURED_COLUMNS)}, "
            f"{', '.join(TARGET_COLUMNS)}"
        )
    dup = sorted({h for h in header if header.count(h) > 1})
    if dup:
        raise CalibrationError(f"{source} {head}: duplicate column(s) {dup}")
    cols = {h: i for i, h in enumerate(header)}
    for n in ACTUATOR_NAMES:
        has_si, has_counts = n in cols, f"{n}_counts" in cols
        if has_si == has_counts:
            raise CalibrationError(
                f"{source} {head}: actuator {n} needs exactly one column, {n} (SI) or {n}_counts (AD counts)"
            )
    pose4 = [c for c in ("x", "z", "roll", "pitch") if c in cols]
    if pose4 and len(pose4) != 4:
        raise CalibrationError(f"{source} {head}: the pose needs all of x, z, roll, pitch (has {', '.join(pose4)})")
    for p in ("L", "R", "U"):
        got = [c for c in _POINT_COLUMNS if c.startswith(p + "_") and c in cols]
        if got and len(got) != 3:
            raise CalibrationError(f"{source} {head}: point {p} needs all of {p}_x, {p}_y, {p}_z")
    measured = [c for c in MEASURED_COLUMNS if c in cols]
    if not measured:
        raise CalibrationError(f"{source} {head}: no measured column (x, z, roll, pitch and/or L_x … U_z)")
    sc = SensorScaling(profile)
    readings, values, masks, labels, sides, rows = [], [], [], [], [], []
    copies: list[tuple[int, int]] = []
    first: dict[tuple[Any, ...], int] = {}
    for r, (where, cells) in enumerate(_data_rows(reader, len(header), source), start=1):
        q = np.zeros(5)
        for k, n in enumerate(ACTUATOR_NAMES):
            if n in cols:
                lo, hi = sc.si_min[k], sc.si_max[k]
                m = _STROKE_MARGIN * (hi - lo)
                q[k] = _cell(cells[cols[n]], where, n, lo - m, hi + m, "rad" if n == "lift" else "m")
            else:
                c = _cell(cells[cols[f"{n}_counts"]], where, f"{n}_counts", 0.0, float(AD_COUNTS_MAX), "counts")
                lo, hi = _counts_range(sc, k)
                if not lo <= c <= hi:  # a count the sensor cannot give (0 for a span 28…258) was accepted
                    raise CalibrationError(
                        f"{where}, column {n}_counts: {c:g} counts is outside the allowed [{lo:g}, {hi:g}] counts "
                        f"(the profile's {n} sensor span {sc.counts_min[k]:.0f}…{sc.counts_max[k]:.0f} counts ± 10 %)"
                    )
                q[k] = sc.si_min[k] + (c - sc.counts_min[k]) * sc.resolution[k]
        vals = np.full(15, np.nan)
        mask = np.zeros(15, dtype=bool)
        for col in measured:
            text = cells[cols[col]]
            if text == "":
                continue
            lim = _ANGLE_MAX if col in _ANGLES else _POSITION_MAX_M
            i = MEASURED_COLUMNS.index(col)
            vals[i] = _cell(text, where, col, -lim, lim, "rad" if col in _ANGLES else "m")
            mask[i] = True
        if not mask.any():
            raise CalibrationError(f"{where}: no measured value (all measured columns empty)")
        for group in (("x", "z", "roll", "pitch"), *((f"{p}_x", f"{p}_y", f"{p}_z") for p in "LRU")):
            idx = [MEASURED_COLUMNS.index(g) for g in group if g in cols]
            if idx and 0 < mask[idx].sum() < len(idx):
                raise CalibrationError(f"{where}: columns {', '.join(group)} must be all given or all empty")
        il, ir = MEASURED_COLUMNS.index("L_x"), MEASURED_COLUMNS.index("R_x")
        if mask[il] and mask[ir] and vals[il] <= vals[ir]:  # the left ball lies at +x (the lower links ~0.8 m apart)
            raise CalibrationError(
                f"{where}, columns L_x, R_x: L_x = {vals[il]:g} m is not left of R_x = {vals[ir]:g} m (x points to "
                "the left: L_x > R_x at every pose); are the L and R points swapped, or x measured to the other side?"
            )
        side = 0.0
        if APPROACH_COLUMN in cols:
            word = cells[cols[APPROACH_COLUMN]].lower()
            if word not in APPROACH_SIDES:
                raise CalibrationError(
                    f"{where}, column {APPROACH_COLUMN}: {cells[cols[APPROACH_COLUMN]]!r} is not a side "
                    "(allowed: below, above, or empty for unknown)"
                )
            side = APPROACH_SIDES[word]
        key = (tuple(q), side, tuple(np.where(mask, vals, 0.0)), tuple(mask))
        if key in first:  # an exact copy of an earlier row (readings, side and every measured value): no new data
            copies.append((r, first[key]))
            continue
        first[key] = r
        readings.append(q)
        values.append(vals)
        masks.append(mask)
        labels.append(cells[cols["pose"]] if "pose" in cols else str(r))
        sides.append(side)
        rows.append(r)
    if not readings:
        raise CalibrationError(f"{source}: no data rows after the header")
    return MeasurementSet(
        np.array(readings),
        np.array(values),
        np.array(masks),
        tuple(labels),
        np.array(sides),
        tuple(rows),
        tuple(copies),
    )


def _counts_range(sc: SensorScaling, k: int) -> tuple[float, float]:
    """The counts a reading of actuator ``k`` may have: the nominal AD map's span ± 10 % (as the SI columns'
    stroke ± 10 %: the map is fitted, so a reading may lie a little beyond it), within 0…1023. A count the
    sensor cannot give (0 for a span 28…258) was accepted, and the fit blamed other rows (a trial)."""
    m = _STROKE_MARGIN * (sc.counts_max[k] - sc.counts_min[k])
    return max(0.0, math.floor(sc.counts_min[k] - m)), min(float(AD_COUNTS_MAX), math.ceil(sc.counts_max[k] + m))


def load_measurements(path: str | Path, profile: Profile) -> MeasurementSet:
    """Read a measurement CSV file (module docstring); errors name the file, row, column and range."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(f"measurements file {p}: cannot read it ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise CalibrationError(f"measurements file {p}: not UTF-8 text") from None
    return parse_measurements(text, profile, source=str(p))


def measurements_csv(
    counts: np.ndarray,
    values: np.ndarray,
    mask: np.ndarray | None = None,
    labels: Sequence[str] | None = None,
    sides: np.ndarray | None = None,
) -> str:
    """CSV text of measurements with readings in AD counts (N, 5) and measured outputs (N, 15; NaN = not
    measured); ``sides`` (N,: −1, 0, +1) adds the ``approach`` column."""
    counts = np.asarray(counts, dtype=float)
    values = np.asarray(values, dtype=float)
    m = np.isfinite(values) if mask is None else np.asarray(mask, dtype=bool)
    used = [i for i in range(15) if m[:, i].any()]
    words = {v: k for k, v in APPROACH_SIDES.items()}
    side_col = [] if sides is None else [APPROACH_COLUMN]
    header = ["pose", *(f"{n}_counts" for n in ACTUATOR_NAMES), *(MEASURED_COLUMNS[i] for i in used), *side_col]
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow(header)
    for k in range(counts.shape[0]):
        lab = labels[k] if labels is not None else f"p{k + 1}"
        side = [] if sides is None else [words[float(sides[k])]]
        w.writerow(
            [
                lab,
                *(f"{c:.6g}" for c in counts[k]),
                *(repr(float(values[k, i])) if m[k, i] else "" for i in used),
                *side,
            ]
        )
    return out.getvalue()


def load_plan_targets(path: str | Path) -> tuple[tuple[str, ...], np.ndarray]:
    """The labels and target poses (N, 4: x, z, roll, pitch in m, rad) of a plan file of ``hitch calibrate
    plan-poses --out`` (its ``pose`` and ``target_*`` columns; a row repeating an earlier one's pose and label
    (or pose, without labels), as the second pass of a two-sided template does, is the same pose, listed once);
    errors name the file, row and column."""
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8").removeprefix("\ufeff")
    except OSError as exc:
        raise CalibrationError(f"plan file {p}: cannot read it ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise CalibrationError(f"plan file {p}: not UTF-8 text") from None
    reader = csv.reader(io.StringIO(text))
    header = _header(reader, f"plan file {p}")
    missing = [c for c in TARGET_COLUMNS if c not in header]
    if missing:
        raise CalibrationError(
            f"plan file {p} row 0 (the header, line {reader.line_num}): no column(s) {', '.join(missing)} "
            "(a plan of hitch calibrate plan-poses --out)"
        )
    cols = {h: i for i, h in enumerate(header)}
    labels: list[str] = []
    poses: list[list[float]] = []
    seen: set[tuple[str | None, tuple[float, ...]]] = set()
    for r, (where, cells) in enumerate(_data_rows(reader, len(header), f"plan file {p}"), start=1):
        pose = []
        for c in TARGET_COLUMNS:
            lim, unit = (_ANGLE_MAX, "rad") if c.endswith(("roll", "pitch")) else (_POSITION_MAX_M, "m")
            pose.append(_cell(cells[cols[c]], where, c, -lim, lim, unit))
        label = cells[cols["pose"]] if "pose" in cols else f"p{r}"
        key = (label if "pose" in cols else None, tuple(pose))
        if key in seen:
            continue  # the same pose again (measured from the other side)
        seen.add(key)
        poses.append(pose)
        labels.append(label)
    if not poses:
        raise CalibrationError(f"plan file {p}: no poses after the header")
    return tuple(labels), np.array(poses)
