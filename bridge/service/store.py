"""Presets and maneuvers in SQLite: durable, versioned, safe for a threaded service.

* **Presets** per implement: name → pose (x, z [m]; roll, pitch [rad]) and an optional speed
  scale (0, 1]; a name is unique per implement.
* **Maneuvers**: name → YAML script text (unique name). The script is parsed and schema-checked
  (:func:`~bridge.service.maneuvers.language.parse_maneuver`) before it is stored; the parsed
  form is cached in memory, keyed by the script text, so reading a maneuver back does not parse
  it again.

Durability. The database runs in WAL mode with ``synchronous=FULL``: every commit appends to the
write-ahead log and fsyncs it before ``save_…`` returns, so an acknowledged save survives the
process being killed (``kill -9``) *and* a power cut (a tractor's key-off). WAL with
``synchronous=NORMAL`` would only survive the former; the cost of FULL is one fsync per save,
negligible at the rate people save presets. Saves are single ``INSERT … ON CONFLICT DO UPDATE``
statements in an immediate transaction: atomic insert-or-replace, never a half-written row.

Threads. One connection (``check_same_thread=False``) guarded by a re-entrant lock: every call
holds the lock for one short statement or transaction. SQLite serialises writers anyway, and a
single connection can be closed cleanly from the shutdown thread (per-thread connections could
not). :meth:`HitchStore.close` checkpoints the WAL into the main file and closes.

Schema versions live in ``PRAGMA user_version``; :data:`MIGRATIONS` are applied in order at open,
each in its own transaction. A database written by a newer program (a higher version) is refused.
"""

from __future__ import annotations

import hashlib
import math
import sqlite3
import threading
import time
from collections import OrderedDict
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bridge.service.maneuvers.language import (
    POSE_BOUNDS,
    ManeuverSchemaError,
    ManeuverScript,
    check_name,
    parse_maneuver,
)
from planner.errors import HitchInputError

__all__ = ["StoreError", "Preset", "StoredManeuver", "HitchStore", "MIGRATIONS", "SCHEMA_VERSION", "DEFAULT_IMPLEMENT"]

#: the implement key used when the service runs without a named implement
DEFAULT_IMPLEMENT = "default"

#: schema migrations; entry k takes the database from version k to k + 1
MIGRATIONS: tuple[str, ...] = (
    """
    CREATE TABLE presets (
        implement   TEXT NOT NULL,
        name        TEXT NOT NULL,
        x           REAL NOT NULL,
        z           REAL NOT NULL,
        roll        REAL NOT NULL,
        pitch       REAL NOT NULL,
        speed_scale REAL,
        updated_s   REAL NOT NULL,
        PRIMARY KEY (implement, name)
    ) WITHOUT ROWID;
    CREATE TABLE maneuvers (
        name      TEXT PRIMARY KEY,
        script    TEXT NOT NULL,
        updated_s REAL NOT NULL
    ) WITHOUT ROWID;
    """,
)
SCHEMA_VERSION = len(MIGRATIONS)
_CACHE_SIZE = 64


class StoreError(HitchInputError):
    """A value the store refuses, or a database it cannot use; ``field`` names the offending field."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(message if message.startswith(field) else f"{field}: {message}")


@dataclass(frozen=True)
class Preset:
    """A saved pose of one implement: x, z [m]; roll, pitch [rad]; optional speed scale (0, 1]."""

    implement: str
    name: str
    pose: Mapping[str, float]
    speed_scale: float | None = None
    updated_s: float = 0.0  # Unix time of the last save [s]

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"name": self.name, "implement": self.implement, "pose": dict(self.pose)}
        if self.speed_scale is not None:
            out["speed_scale"] = self.speed_scale
        return out


@dataclass(frozen=True)
class StoredManeuver:
    """A saved maneuver: its name, script text, the parsed script and the Unix time of the last save [s]."""

    name: str
    script: str
    parsed: ManeuverScript = field(repr=False)
    updated_s: float = 0.0

    def to_json(self, *, script: bool = True) -> dict[str, Any]:
        """Name, script text (unless ``script`` is False: the listing), description, step count, timeout [s]."""
        out: dict[str, Any] = {"name": self.name}
        if script:
            out["script"] = self.script
        out.update(description=self.parsed.description, steps=len(self.parsed.steps), timeout=self.parsed.timeout_s)
        return out


def _name(value: Any, what: str) -> str:
    try:
        return check_name(value, what)
    except ManeuverSchemaError as exc:
        raise StoreError(what, str(exc)) from None


def _pose(pose: Any) -> dict[str, float]:
    if not isinstance(pose, Mapping):
        raise StoreError("pose", f"must be a mapping with x, z [m], roll, pitch [rad], got {type(pose).__name__}")
    unknown = sorted(set(map(str, pose)) - set(POSE_BOUNDS))
    if unknown:
        raise StoreError("pose", f"unknown field(s) {', '.join(unknown)} (allowed: x, z, roll, pitch)")
    out = {}
    for k, (lo, hi) in POSE_BOUNDS.items():
        if k not in pose:
            raise StoreError(f"pose.{k}", "is required (a preset is a full pose: x, z, roll, pitch)")
        v = pose[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            unit = "m" if k in ("x", "z") else "rad"
            raise StoreError(f"pose.{k}", f"must be a finite number within [{lo:.6g}, {hi:.6g}] {unit}, got {v!r}")
        out[k] = float(v)
    return out


def _scale(v: Any) -> float | None:
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0.0 < v <= 1.0:
        raise StoreError("speed_scale", f"must be a number in (0, 1] or absent, got {v!r}")
    return float(v)


class HitchStore:
    """Presets and maneuvers in one SQLite file; see the module docstring."""

    def __init__(self, path: str | Path, *, timeout_s: float = 5.0):
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=timeout_s, isolation_level=None, check_same_thread=False)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError("path", f"cannot open database {self.path}: {exc}") from None
        self._lock = threading.RLock()
        self._cache: OrderedDict[str, ManeuverScript] = OrderedDict()
        self._closed = False
        try:
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise StoreError("path", f"database {self.path} cannot use WAL mode (got {mode})")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._migrate()
        except sqlite3.DatabaseError as exc:
            self._db.close()
            raise StoreError("path", f"{self.path} is not a usable SQLite database: {exc}") from None
        except StoreError:
            self._db.close()
            raise

    # ------------------------------------------------------------------ lifecycle
    def _migrate(self) -> None:
        version = self._db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            raise StoreError(
                "schema_version",
                f"database {self.path} has schema version {version}, newer than "
                f"this program supports (at most {SCHEMA_VERSION})",
            )
        for v in range(version, SCHEMA_VERSION):
            self._db.execute("BEGIN IMMEDIATE")
            try:
                for statement in MIGRATIONS[v].split(";"):
                    if statement.strip():
                        self._db.execute(statement)
                self._db.execute(f"PRAGMA user_version = {v + 1}")
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    @property
    def schema_version(self) -> int:
        with self._locked() as db:
            return db.execute("PRAGMA user_version").fetchone()[0]

    def pragmas(self) -> dict[str, Any]:
        """The durability settings in force: journal_mode ('wal') and synchronous (2 = FULL)."""
        with self._locked() as db:
            return {
                "journal_mode": db.execute("PRAGMA journal_mode").fetchone()[0],
                "synchronous": db.execute("PRAGMA synchronous").fetchone()[0],
            }

    def close(self) -> None:
        """Checkpoint the WAL into the database file and close; later calls raise StoreError."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            except sqlite3.Error:
                pass  # another process may hold a read lock; the WAL stays valid
            self._db.close()

    def __enter__(self) -> HitchStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    @contextmanager
    def _locked(self) -> Iterator[sqlite3.Connection]:
        with self._lock:
            if self._closed:
                raise StoreError("store", f"database {self.path} is closed")
            yield self._db

    def _write(self, sql: str, args: tuple[Any, ...]) -> int:
        with self._locked() as db:
            try:
                db.execute("BEGIN IMMEDIATE")
                cur = db.execute(sql, args)
                db.execute("COMMIT")
            except sqlite3.Error as exc:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise StoreError("database", f"write failed: {exc}") from None
            return cur.rowcount

    # ------------------------------------------------------------------ presets
    def save_preset(
        self,
        name: str,
        pose: Mapping[str, float],
        *,
        implement: str = DEFAULT_IMPLEMENT,
        speed_scale: float | None = None,
    ) -> Preset:
        """Insert or replace a preset (atomically, durably); returns what was stored."""
        preset = Preset(
            _name(implement, "implement"), _name(name, "name"), _pose(pose), _scale(speed_scale), time.time()
        )
        p = preset.pose
        self._write(
            "INSERT INTO presets (implement, name, x, z, roll, pitch, speed_scale, updated_s) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (implement, name) DO UPDATE SET "
            "x = excluded.x, z = excluded.z, roll = excluded.roll, pitch = excluded.pitch, "
            "speed_scale = excluded.speed_scale, updated_s = excluded.updated_s",
            (
                preset.implement,
                preset.name,
                p["x"],
                p["z"],
                p["roll"],
                p["pitch"],
                preset.speed_scale,
                preset.updated_s,
            ),
        )
        return preset

    def get_preset(self, name: str, *, implement: str = DEFAULT_IMPLEMENT) -> Preset | None:
        """The preset, or None if this implement has none of that name."""
        args = (_name(implement, "implement"), _name(name, "name"))
        with self._locked() as db:
            row = db.execute(
                "SELECT implement, name, x, z, roll, pitch, speed_scale, updated_s FROM presets "
                "WHERE implement = ? AND name = ?",
                args,
            ).fetchone()
        return None if row is None else _preset(row)

    def list_presets(self, implement: str | None = DEFAULT_IMPLEMENT) -> list[Preset]:
        """Presets of one implement (``None``: of every implement), sorted by implement and name."""
        with self._locked() as db:
            if implement is None:
                rows = db.execute(
                    "SELECT implement, name, x, z, roll, pitch, speed_scale, updated_s FROM presets "
                    "ORDER BY implement, name"
                ).fetchall()
            else:
                rows = db.execute(
                    "SELECT implement, name, x, z, roll, pitch, speed_scale, updated_s FROM presets "
                    "WHERE implement = ? ORDER BY name",
                    (_name(implement, "implement"),),
                ).fetchall()
        return [_preset(r) for r in rows]

    def delete_preset(self, name: str, *, implement: str = DEFAULT_IMPLEMENT) -> bool:
        """Delete; True if it existed."""
        args = (_name(implement, "implement"), _name(name, "name"))
        return self._write("DELETE FROM presets WHERE implement = ? AND name = ?", args) > 0

    # ------------------------------------------------------------------ maneuvers
    def save_maneuver(self, name: str, script: str) -> StoredManeuver:
        """Parse (ManeuverError lists the problems) and insert or replace a maneuver.

        A ``name:`` inside the script, if any, must equal ``name``.
        """
        name = _name(name, "name")
        parsed = self._parse(script)
        if parsed.name is not None and parsed.name != name:
            raise StoreError(
                "name",
                f"the script calls itself {parsed.name!r} but is saved as {name!r}; "
                "make them equal or drop 'name:' from the script",
            )
        stored = StoredManeuver(name, script, parsed, time.time())
        self._write(
            "INSERT INTO maneuvers (name, script, updated_s) VALUES (?, ?, ?) ON CONFLICT (name) "
            "DO UPDATE SET script = excluded.script, updated_s = excluded.updated_s",
            (name, script, stored.updated_s),
        )
        return stored

    def get_maneuver(self, name: str) -> StoredManeuver | None:
        args = (_name(name, "name"),)
        with self._locked() as db:
            row = db.execute("SELECT name, script, updated_s FROM maneuvers WHERE name = ?", args).fetchone()
        return None if row is None else StoredManeuver(row[0], row[1], self._parse(row[1]), row[2])

    def list_maneuvers(self) -> list[StoredManeuver]:
        with self._locked() as db:
            rows = db.execute("SELECT name, script, updated_s FROM maneuvers ORDER BY name").fetchall()
        return [StoredManeuver(n, s, self._parse(s), t) for n, s, t in rows]

    def delete_maneuver(self, name: str) -> bool:
        return self._write("DELETE FROM maneuvers WHERE name = ?", (_name(name, "name"),)) > 0

    def _parse(self, script: str) -> ManeuverScript:
        if not isinstance(script, str):
            raise StoreError("script", f"must be YAML text, got {type(script).__name__}")
        key = hashlib.sha256(script.encode("utf-8", "surrogatepass")).hexdigest()
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        parsed = parse_maneuver(script)  # ManeuverError (a HitchInputError) with the step errors
        with self._lock:
            self._cache[key] = parsed
            while len(self._cache) > _CACHE_SIZE:
                self._cache.popitem(last=False)
        return parsed


def _preset(row: tuple[Any, ...]) -> Preset:
    implement, name, x, z, roll, pitch, scale, updated = row
    return Preset(implement, name, {"x": x, "z": z, "roll": roll, "pitch": pitch}, scale, updated)
