"""Presets and maneuvers in SQLite: durable, versioned, safe for a threaded service.

* **Presets** per implement: name → pose (x, z [m]; roll, pitch [rad]) and an optional speed
  scale [0.05, 1]; a name is unique per implement.
* **Maneuvers**: name → YAML script text (unique name). The script is parsed and schema-checked
  (:func:`~bridge.service.maneuvers.language.parse_maneuver`) exactly once, when it is saved; the
  parsed form (its normalised JSON) and the listing fields (description, step count, timeout,
  size) are stored with it. Listing reads those columns and parses nothing; reading one maneuver
  back rebuilds it from the stored form without YAML. Cost of a list: one query, independent of
  the scripts' sizes; of a read: one maneuver.
* **Implements** (schema version 3, ``docs/implements.md``): name → ISO 730 category, mass [kg],
  centre of mass [m], upper height limit [m], lowering speed limit [m/s], transport lock, headland
  and last work poses (JSON); and the service's persisted **settings** (the selected implement).
* **Field lines** (schema version 4, ``docs/maneuvers.md``): name → GeoJSON line (the headland and
  field-boundary lines of position triggers).
* **Work settings** (schema version 5, ``docs/soil.md``): implement → its draft / mixed / float
  control settings (JSON of :class:`~planner.work_control.controller.WorkSettings`).
* **Owners and limits** (:class:`StoreLimits`): every row records the user who saved it last
  (``owner``; ``""`` when the transport authorised the request without naming a user, as Zenoh's
  access control does). Per owner the store refuses more than ``max_presets_per_user`` presets,
  ``max_maneuvers_per_user`` maneuvers and ``max_script_bytes_per_user`` bytes of script text
  (each script at most :data:`~bridge.service.maneuvers.language.MAX_SCRIPT_BYTES`); the
  :class:`StoreError` names the limit (its ``field``). Replacing a name you already count does
  not count twice.
* **Integrity**: at open, ``PRAGMA quick_check`` must answer ``ok``; a database with damaged pages
  is refused (:class:`StoreError` naming the file) instead of starting and failing later.

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

import json
import math
import sqlite3
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from dataclasses import replace as dc_replace
from pathlib import Path
from typing import Any

from bridge.service.maneuvers.language import (
    MAX_SCRIPT_BYTES,
    MIN_SPEED_SCALE,
    POSE_BOUNDS,
    ManeuverSchemaError,
    ManeuverScript,
    check_name,
    parse_maneuver,
)
from planner.errors import HitchInputError
from planner.limits.implement_limits import ImplementLimits
from planner.limits.tractor import ISO730_CATEGORIES

__all__ = [
    "StoreError",
    "ManeuverExists",
    "StoreLimits",
    "Preset",
    "StoredManeuver",
    "ManeuverSummary",
    "HitchStore",
    "MIGRATIONS",
    "SCHEMA_VERSION",
    "DEFAULT_IMPLEMENT",
    "StoredImplement",
    "MAX_IMPLEMENTS",
    "IMPLEMENT_MASS_RANGE_KG",
    "IMPLEMENT_COM_RANGE_M",
]

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
    # 1 → 2: owners, the parsed form and the listing fields of a maneuver (rows of version 1 are
    # parsed once at open, see HitchStore._backfill)
    """
    ALTER TABLE presets ADD COLUMN owner TEXT NOT NULL DEFAULT '';
    ALTER TABLE maneuvers ADD COLUMN owner TEXT NOT NULL DEFAULT '';
    ALTER TABLE maneuvers ADD COLUMN parsed TEXT;
    ALTER TABLE maneuvers ADD COLUMN problem TEXT;
    ALTER TABLE maneuvers ADD COLUMN description TEXT NOT NULL DEFAULT '';
    ALTER TABLE maneuvers ADD COLUMN steps INTEGER NOT NULL DEFAULT 0;
    ALTER TABLE maneuvers ADD COLUMN timeout_s REAL NOT NULL DEFAULT 0;
    ALTER TABLE maneuvers ADD COLUMN size_bytes INTEGER NOT NULL DEFAULT 0;
    CREATE INDEX presets_owner ON presets (owner);
    CREATE INDEX maneuvers_owner ON maneuvers (owner);
    """,
    # 2 → 3: implements defined at runtime (their mass, centre of mass, limits, headland and last work
    # poses as JSON) and the service's persisted settings (the selected implement)
    """
    CREATE TABLE implements (
        name               TEXT PRIMARY KEY,
        category           TEXT NOT NULL,
        mass_kg            REAL NOT NULL,
        com_x              REAL NOT NULL,
        com_y              REAL NOT NULL,
        com_z              REAL NOT NULL,
        upper_height_m     REAL,
        lowering_speed_m_s REAL,
        transport_locked   INTEGER NOT NULL DEFAULT 0,
        headland           TEXT,
        last_work          TEXT,
        description        TEXT NOT NULL DEFAULT '',
        owner              TEXT NOT NULL DEFAULT '',
        updated_s          REAL NOT NULL
    ) WITHOUT ROWID;
    CREATE TABLE settings (
        key   TEXT PRIMARY KEY,
        value TEXT NOT NULL
    ) WITHOUT ROWID;
    """,
    # 3 → 4: the field's lines (maneuver wait_for line; bridge.service.gnss): [lon, lat] vertices as JSON
    """
    CREATE TABLE lines (
        name        TEXT PRIMARY KEY,
        coordinates TEXT NOT NULL,
        owner       TEXT NOT NULL DEFAULT '',
        updated_s   REAL NOT NULL
    ) WITHOUT ROWID;
    """,
    # 4 → 5: the work-control settings of each implement (bridge.service.work; JSON, SI)
    """
    CREATE TABLE work_settings (
        implement TEXT PRIMARY KEY,
        settings  TEXT NOT NULL,
        owner     TEXT NOT NULL DEFAULT '',
        updated_s REAL NOT NULL
    ) WITHOUT ROWID;
    """,
)
SCHEMA_VERSION = len(MIGRATIONS)
#: implements the store keeps (all owners together)
MAX_IMPLEMENTS = 500
#: allowed implement mass [kg] (as the tractor profiles' implement records) and CoM coordinates [m]
IMPLEMENT_MASS_RANGE_KG = (0.0, 20_000.0)
IMPLEMENT_COM_RANGE_M = 10.0
_CACHE_SIZE = 64


class StoreError(HitchInputError):
    """A value the store refuses, or a database it cannot use; ``field`` names the offending field."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(message if message.startswith(field) else f"{field}: {message}")


class ManeuverExists(StoreError):
    """:meth:`HitchStore.save_maneuver` without ``replace``: a maneuver of that name is saved (``steps`` of it)."""

    def __init__(self, name: str, steps: int | None):
        self.name, self.steps = name, steps
        super().__init__("name", f"a maneuver {name!r} is saved already")


class PresetExists(StoreError):
    """:meth:`HitchStore.save_preset` without ``replace``: the implement has a preset of that name (``pose``)."""

    def __init__(self, name: str, pose: dict[str, float]):
        self.name, self.pose = name, pose
        super().__init__("name", f"a preset {name!r} is saved already")


@dataclass(frozen=True)
class StoreLimits:
    """Per-owner limits of the store (see the module docstring); each must be >= 1."""

    max_presets_per_user: int = 1000  # over every implement
    max_maneuvers_per_user: int = 200
    #: total script text of one owner's maneuvers [bytes] (one script: at most MAX_SCRIPT_BYTES)
    max_script_bytes_per_user: int = 4 * 1024 * 1024

    def __post_init__(self) -> None:
        for name in ("max_presets_per_user", "max_maneuvers_per_user", "max_script_bytes_per_user"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise StoreError(name, f"must be an integer >= 1, got {v!r}")


@dataclass(frozen=True)
class Preset:
    """A saved pose of one implement: x, z [m]; roll, pitch [rad]; optional speed scale [0.05, 1]."""

    implement: str
    name: str
    pose: Mapping[str, float]
    speed_scale: float | None = None
    updated_s: float = 0.0  # Unix time of the last save [s]
    owner: str = ""  # who saved it last ("" when the transport named no user)

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
    owner: str = ""
    #: set by :meth:`HitchStore.save_maneuver`: this save replaced a maneuver of that name
    replaced: bool = field(default=False, compare=False)

    def to_json(self, *, script: bool = True) -> dict[str, Any]:
        """Name, script text (unless ``script`` is False: the listing), description, step count, timeout [s]."""
        out: dict[str, Any] = {"name": self.name}
        if script:
            out["script"] = self.script
        out.update(description=self.parsed.description, steps=len(self.parsed.steps), timeout=self.parsed.timeout_s)
        return out


@dataclass(frozen=True)
class ManeuverSummary:
    """A maneuver in the listing: the fields stored at save, nothing parsed.

    ``problem`` is set for a row saved by an older program that no longer parses (save it again).
    """

    name: str
    description: str
    steps: int
    timeout_s: float
    size_bytes: int
    updated_s: float = 0.0
    owner: str = ""
    problem: str | None = None

    def to_json(self, *, script: bool = False) -> dict[str, Any]:
        """Name, description, step count, timeout [s] (and ``problem`` if any); a summary has no script text."""
        if script:
            raise StoreError("script", "a maneuver summary has no script text; read it with get_maneuver")
        out: dict[str, Any] = {
            "name": self.name,
            "description": self.description,
            "steps": self.steps,
            "timeout": self.timeout_s,
        }
        if self.problem is not None:
            out["problem"] = self.problem
        return out


@dataclass(frozen=True)
class StoredImplement:
    """An implement defined at runtime: ISO 730 ``category``, ``mass_kg`` [kg], ``com_m`` (x_i, y_i, z_i)
    in the implement frame [m] (as :class:`planner.limits.tractor.ImplementRecord`), its limits
    (:class:`planner.limits.implement_limits.ImplementLimits`), the ``headland`` pose a quick raise goes
    to (None: the implement's preset ``headland``) and the ``last_work`` pose (where the last raise
    started; the quick return goes there). Poses: x, z [m]; roll, pitch [rad]."""

    name: str
    category: str
    mass_kg: float
    com_m: tuple[float, float, float]
    limits: ImplementLimits = field(default_factory=ImplementLimits)
    headland: Mapping[str, float] | None = None
    last_work: Mapping[str, float] | None = None
    description: str = ""
    updated_s: float = 0.0
    owner: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "category": self.category,
            "mass_kg": self.mass_kg,
            "com_m": list(self.com_m),
            **self.limits.to_json(),
            "headland": None if self.headland is None else dict(self.headland),
            "last_work": None if self.last_work is None else dict(self.last_work),
            "description": self.description,
        }


def _implement_values(imp: StoredImplement) -> StoredImplement:
    """``imp`` checked field by field (StoreError naming the field and its allowed range)."""
    name = _name(imp.name, "name")
    if imp.category not in ISO730_CATEGORIES:
        raise StoreError(
            "category", f"must be an ISO 730 category ({', '.join(ISO730_CATEGORIES)}), got {imp.category!r}"
        )
    lo, hi = IMPLEMENT_MASS_RANGE_KG
    m = imp.mass_kg
    if isinstance(m, bool) or not isinstance(m, (int, float)) or not math.isfinite(m) or not lo < m <= hi:
        raise StoreError("mass_kg", f"must be a finite number in ({lo:g}, {hi:g}] kg, got {m!r}")
    com = tuple(imp.com_m) if isinstance(imp.com_m, (tuple, list)) else ()
    if len(com) != 3 or not all(
        not isinstance(c, bool) and isinstance(c, (int, float)) and math.isfinite(c) and abs(c) <= IMPLEMENT_COM_RANGE_M
        for c in com
    ):
        raise StoreError(
            "com_m", f"must be 3 finite numbers [x, y, z] within ±{IMPLEMENT_COM_RANGE_M:g} m, got {imp.com_m!r}"
        )
    if not isinstance(imp.limits, ImplementLimits):
        raise StoreError("limits", f"must be ImplementLimits, got {type(imp.limits).__name__}")
    if not isinstance(imp.description, str) or len(imp.description) > 200:
        raise StoreError("description", "must be text of at most 200 characters")
    headland = None if imp.headland is None else _pose(imp.headland, "headland")
    last_work = None if imp.last_work is None else _pose(imp.last_work, "last_work")
    return StoredImplement(
        name,
        imp.category,
        float(m),
        (float(com[0]), float(com[1]), float(com[2])),
        imp.limits,
        headland,
        last_work,
        imp.description,
        imp.updated_s,
        _owner(imp.owner),
    )


def _name(value: Any, what: str) -> str:
    try:
        return check_name(value, what)
    except ManeuverSchemaError as exc:
        raise StoreError(what, str(exc)) from None


def _pose(pose: Any, what: str = "pose") -> dict[str, float]:
    if not isinstance(pose, Mapping):
        raise StoreError(what, f"must be a mapping with x, z [m], roll, pitch [rad], got {type(pose).__name__}")
    unknown = sorted(set(map(str, pose)) - set(POSE_BOUNDS))
    if unknown:
        raise StoreError(what, f"unknown field(s) {', '.join(unknown)} (allowed: x, z, roll, pitch)")
    out = {}
    for k, (lo, hi) in POSE_BOUNDS.items():
        if k not in pose:
            raise StoreError(f"{what}.{k}", "is required (a full pose: x, z, roll, pitch)")
        v = pose[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            unit = "m" if k in ("x", "z") else "rad"
            raise StoreError(f"{what}.{k}", f"must be a finite number within [{lo:.6g}, {hi:.6g}] {unit}, got {v!r}")
        out[k] = float(v)
    return out


def _scale(v: Any) -> float | None:
    if v is None:
        return None
    if (
        isinstance(v, bool)
        or not isinstance(v, (int, float))
        or not math.isfinite(v)
        or not MIN_SPEED_SCALE <= v <= 1.0
    ):
        raise StoreError("speed_scale", f"must be a number in [{MIN_SPEED_SCALE:g}, 1] or absent, got {v!r}")
    return float(v)


def _owner(v: Any) -> str:
    if v is None:
        return ""
    if not isinstance(v, str) or len(v) > 64 or not v.isprintable():
        raise StoreError("owner", f"must be a user name of at most 64 printable characters, got {v!r}")
    return v


def _who(owner: str) -> str:
    return f"user {owner!r}" if owner else "the anonymous user (no user named by the transport)"


def _check_implement_room(db: sqlite3.Connection, name: str) -> None:
    """StoreError ``max_implements`` when storing ``name`` (not stored yet) would pass :data:`MAX_IMPLEMENTS`."""
    (n,) = db.execute("SELECT COUNT(*) FROM implements WHERE name != ?", (name,)).fetchone()
    if n >= MAX_IMPLEMENTS:
        raise StoreError("max_implements", f"the store already has {n} implements (limit {MAX_IMPLEMENTS}); delete one")


class HitchStore:
    """Presets and maneuvers in one SQLite file; see the module docstring."""

    def __init__(self, path: str | Path, *, timeout_s: float = 5.0, limits: StoreLimits | None = None):
        self.path = Path(path)
        self.limits = limits if limits is not None else StoreLimits()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=timeout_s, isolation_level=None, check_same_thread=False)
        except (OSError, sqlite3.Error) as exc:
            raise StoreError("path", f"cannot open database {self.path}: {exc}") from None
        self._lock = threading.RLock()
        self._cache: OrderedDict[tuple[str, float], ManeuverScript] = OrderedDict()
        self._closed = False
        try:
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if mode.lower() != "wal":
                raise StoreError("path", f"database {self.path} cannot use WAL mode (got {mode})")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._check_integrity()
            self._migrate()
            self._backfill()
        except sqlite3.DatabaseError as exc:
            self._db.close()
            raise StoreError("path", f"{self.path} is not a usable SQLite database: {exc}") from None
        except StoreError:
            self._db.close()
            raise

    # ------------------------------------------------------------------ lifecycle
    def _check_integrity(self) -> None:
        """``PRAGMA quick_check``: a database with damaged pages is refused at open, naming the file."""
        try:
            problems = [str(r[0]) for r in self._db.execute("PRAGMA quick_check(5)").fetchall()]
        except sqlite3.DatabaseError as exc:  # pages so damaged that the check itself cannot read them
            problems = [str(exc)]
        if problems != ["ok"]:
            raise StoreError(
                "path",
                f"database {self.path} is damaged (PRAGMA quick_check: {'; '.join(problems)[:300]}); "
                "restore it from a backup or move it away to start with an empty store",
            )

    def _backfill(self) -> None:
        """Parse, once, maneuvers stored without their parsed form (rows of schema version 1)."""
        rows = self._db.execute(
            "SELECT name, script FROM maneuvers WHERE parsed IS NULL AND problem IS NULL"
        ).fetchall()
        for name, script in rows:
            try:
                parsed, problem = parse_maneuver(script), None
            except HitchInputError as exc:
                parsed, problem = None, str(exc)[:500]
            cols = _listing(parsed, script)
            self._db.execute(
                "UPDATE maneuvers SET parsed = ?, problem = ?, description = ?, steps = ?, timeout_s = ?, "
                "size_bytes = ? WHERE name = ?",
                (cols[0], problem or (None if parsed is not None else "does not parse"), *cols[1:], name),
            )

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

    def _write(self, sql: str, args: tuple[Any, ...], check: Callable[[sqlite3.Connection], None] | None = None) -> int:
        """One statement in an immediate transaction; ``check`` (the limits) runs inside it first."""
        with self._locked() as db:
            try:
                db.execute("BEGIN IMMEDIATE")
                if check is not None:
                    check(db)
                cur = db.execute(sql, args)
                db.execute("COMMIT")
            except sqlite3.Error as exc:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise StoreError("database", f"write failed: {exc}") from None
            except BaseException:
                if db.in_transaction:
                    db.execute("ROLLBACK")
                raise
            return cur.rowcount

    # ------------------------------------------------------------------ presets
    def save_preset(
        self,
        name: str,
        pose: Mapping[str, float],
        *,
        implement: str = DEFAULT_IMPLEMENT,
        speed_scale: float | None = None,
        owner: str | None = None,
        replace: bool = True,
    ) -> Preset:
        """Insert or replace a preset (atomically, durably); returns what was stored.

        ``owner``: the user saving it (None: no user named); :class:`StoreError` with field
        ``max_presets_per_user`` when a new name would exceed the owner's limit. ``replace=False``:
        :class:`PresetExists` when the implement has a preset of that name (checked in the same transaction).
        """
        preset = Preset(
            _name(implement, "implement"),
            _name(name, "name"),
            _pose(pose),
            _scale(speed_scale),
            time.time(),
            _owner(owner),
        )
        p = preset.pose
        limit = self.limits.max_presets_per_user

        def check(db: sqlite3.Connection) -> None:
            if not replace:
                old = db.execute(
                    "SELECT x, z, roll, pitch FROM presets WHERE implement = ? AND name = ?",
                    (preset.implement, preset.name),
                ).fetchone()
                if old is not None:
                    raise PresetExists(preset.name, dict(zip(("x", "z", "roll", "pitch"), old, strict=True)))
            (n,) = db.execute(
                "SELECT COUNT(*) FROM presets WHERE owner = ? AND NOT (implement = ? AND name = ?)",
                (preset.owner, preset.implement, preset.name),
            ).fetchone()
            if n >= limit:
                raise StoreError(
                    "max_presets_per_user",
                    f"{_who(preset.owner)} already has {n} presets (limit: max_presets_per_user = {limit}); "
                    "delete one or save under an existing name",
                )

        self._write(
            "INSERT INTO presets (implement, name, x, z, roll, pitch, speed_scale, updated_s, owner) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (implement, name) DO UPDATE SET "
            "x = excluded.x, z = excluded.z, roll = excluded.roll, pitch = excluded.pitch, "
            "speed_scale = excluded.speed_scale, updated_s = excluded.updated_s, owner = excluded.owner",
            (
                preset.implement,
                preset.name,
                p["x"],
                p["z"],
                p["roll"],
                p["pitch"],
                preset.speed_scale,
                preset.updated_s,
                preset.owner,
            ),
            check,
        )
        return preset

    def get_preset(self, name: str, *, implement: str = DEFAULT_IMPLEMENT) -> Preset | None:
        """The preset, or None if this implement has none of that name."""
        args = (_name(implement, "implement"), _name(name, "name"))
        with self._locked() as db:
            row = db.execute(
                "SELECT implement, name, x, z, roll, pitch, speed_scale, updated_s, owner FROM presets "
                "WHERE implement = ? AND name = ?",
                args,
            ).fetchone()
        return None if row is None else _preset(row)

    def list_presets(self, implement: str | None = DEFAULT_IMPLEMENT) -> list[Preset]:
        """Presets of one implement (``None``: of every implement), sorted by implement and name."""
        with self._locked() as db:
            if implement is None:
                rows = db.execute(
                    "SELECT implement, name, x, z, roll, pitch, speed_scale, updated_s, owner FROM presets "
                    "ORDER BY implement, name"
                ).fetchall()
            else:
                rows = db.execute(
                    "SELECT implement, name, x, z, roll, pitch, speed_scale, updated_s, owner FROM presets "
                    "WHERE implement = ? ORDER BY name",
                    (_name(implement, "implement"),),
                ).fetchall()
        return [_preset(r) for r in rows]

    def delete_preset(self, name: str, *, implement: str = DEFAULT_IMPLEMENT) -> bool:
        """Delete; True if it existed."""
        args = (_name(implement, "implement"), _name(name, "name"))
        return self._write("DELETE FROM presets WHERE implement = ? AND name = ?", args) > 0

    # ------------------------------------------------------------------ maneuvers
    def save_maneuver(
        self,
        name: str,
        script: str,
        *,
        owner: str | None = None,
        parsed: ManeuverScript | None = None,
        replace: bool = True,
    ) -> StoredManeuver:
        """Parse (once; ManeuverError lists the problems; ``parsed``: ``script`` parsed already) and insert or
        replace a maneuver (the result's ``replaced`` says which).

        A ``name:`` inside the script, if any, must equal ``name``. ``owner``: the user saving it;
        :class:`StoreError` with field ``max_maneuvers_per_user`` or ``max_script_bytes_per_user``
        when the owner's limits would be exceeded. ``replace`` False: a maneuver of that name is not
        replaced — :class:`ManeuverExists` (checked in the write's transaction).
        """
        name, who = _name(name, "name"), _owner(owner)
        if not isinstance(script, str):
            raise StoreError("script", f"must be YAML text, got {type(script).__name__}")
        if parsed is None:
            parsed = parse_maneuver(script)  # ManeuverError (a HitchInputError) with the step errors
        if parsed.name is not None and parsed.name != name:
            raise StoreError(
                "name",
                f"the script calls itself {parsed.name!r} but is saved as {name!r}; "
                "make them equal or drop 'name:' from the script",
            )
        stored = StoredManeuver(name, script, parsed, time.time(), who)
        form, description, steps, timeout_s, size = _listing(parsed, script)
        max_count, max_bytes = self.limits.max_maneuvers_per_user, self.limits.max_script_bytes_per_user

        existed: list[bool] = []

        def check(db: sqlite3.Connection) -> None:
            old = db.execute("SELECT steps FROM maneuvers WHERE name = ?", (name,)).fetchone()
            existed.append(old is not None)
            if old is not None and not replace:
                raise ManeuverExists(name, old[0])
            n, total = db.execute(
                "SELECT COUNT(*), COALESCE(SUM(size_bytes), 0) FROM maneuvers WHERE owner = ? AND name != ?",
                (who, name),
            ).fetchone()
            if n >= max_count:
                raise StoreError(
                    "max_maneuvers_per_user",
                    f"{_who(who)} already has {n} maneuvers (limit: max_maneuvers_per_user = {max_count}); "
                    "delete one or save under an existing name",
                )
            if total + size > max_bytes:
                raise StoreError(
                    "max_script_bytes_per_user",
                    f"{_who(who)} would store {total + size} bytes of scripts with this one of {size} bytes "
                    f"(limit: max_script_bytes_per_user = {max_bytes} bytes; one script at most "
                    f"{MAX_SCRIPT_BYTES} bytes)",
                )

        self._write(
            "INSERT INTO maneuvers (name, script, updated_s, owner, parsed, problem, description, steps, timeout_s, "
            "size_bytes) VALUES (?, ?, ?, ?, ?, NULL, ?, ?, ?, ?) ON CONFLICT (name) DO UPDATE SET "
            "script = excluded.script, updated_s = excluded.updated_s, owner = excluded.owner, "
            "parsed = excluded.parsed, problem = NULL, description = excluded.description, steps = excluded.steps, "
            "timeout_s = excluded.timeout_s, size_bytes = excluded.size_bytes",
            (name, script, stored.updated_s, who, form, description, steps, timeout_s, size),
            check,
        )
        with self._lock:
            self._remember((name, stored.updated_s), parsed)
        return dc_replace(stored, replaced=bool(existed and existed[-1]))

    def get_maneuver(self, name: str) -> StoredManeuver | None:
        """The maneuver with its parsed form (rebuilt from the stored form, no YAML), or None.

        A row saved by an older program that no longer parses raises :class:`StoreError` (``script``).
        """
        args = (_name(name, "name"),)
        with self._locked() as db:
            row = db.execute(
                "SELECT name, script, updated_s, owner, parsed, problem FROM maneuvers WHERE name = ?", args
            ).fetchone()
        if row is None:
            return None
        n, script, updated, owner, form, problem = row
        if form is None:
            raise StoreError(
                "script", f"stored maneuver {n!r} does not parse with this program ({problem}); save it again"
            )
        key = (n, float(updated))
        with self._lock:
            parsed = self._cache.get(key)
            if parsed is not None:
                self._cache.move_to_end(key)
        if parsed is None:
            try:
                parsed = ManeuverScript.from_json(json.loads(form))
            except (ValueError, ManeuverSchemaError) as exc:
                raise StoreError("script", f"stored maneuver {n!r} is damaged ({exc}); save it again") from None
            with self._lock:
                self._remember(key, parsed)
        return StoredManeuver(n, script, parsed, updated, owner)

    def list_maneuvers(self) -> list[ManeuverSummary]:
        """Every maneuver's listing fields, sorted by name: one query, nothing parsed."""
        with self._locked() as db:
            rows = db.execute(
                "SELECT name, description, steps, timeout_s, size_bytes, updated_s, owner, problem "
                "FROM maneuvers ORDER BY name"
            ).fetchall()
        return [ManeuverSummary(*r) for r in rows]

    def delete_maneuver(self, name: str) -> bool:
        return self._write("DELETE FROM maneuvers WHERE name = ?", (_name(name, "name"),)) > 0

    # ------------------------------------------------------------------ implements
    def save_implement(self, implement: StoredImplement, *, owner: str | None = None) -> StoredImplement:
        """Insert or replace an implement (every field checked; StoreError names the field); returns what
        was stored. At most :data:`MAX_IMPLEMENTS` implements."""
        imp = _implement_values(implement)
        imp = StoredImplement(**{**imp.__dict__, "updated_s": time.time(), "owner": _owner(owner)})

        def check(db: sqlite3.Connection) -> None:
            _check_implement_room(db, imp.name)

        lim = imp.limits
        self._write(
            "INSERT INTO implements (name, category, mass_kg, com_x, com_y, com_z, upper_height_m, "
            "lowering_speed_m_s, transport_locked, headland, last_work, description, owner, updated_s) "
            "VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?) ON CONFLICT (name) DO UPDATE SET "
            "category = excluded.category, mass_kg = excluded.mass_kg, com_x = excluded.com_x, "
            "com_y = excluded.com_y, com_z = excluded.com_z, upper_height_m = excluded.upper_height_m, "
            "lowering_speed_m_s = excluded.lowering_speed_m_s, transport_locked = excluded.transport_locked, "
            "headland = excluded.headland, last_work = excluded.last_work, description = excluded.description, "
            "owner = excluded.owner, updated_s = excluded.updated_s",
            (
                imp.name,
                imp.category,
                imp.mass_kg,
                *imp.com_m,
                lim.upper_height_m,
                lim.lowering_speed_m_s,
                int(lim.transport_locked),
                _pose_text(imp.headland),
                _pose_text(imp.last_work),
                imp.description,
                imp.owner,
                imp.updated_s,
            ),
            check,
        )
        return imp

    def check_implement_room(self, name: str) -> None:
        """StoreError ``max_implements`` when :meth:`save_implement` of ``name`` would be refused for the number of
        implements: checked before a change that must not happen unless the implement can be stored."""
        args = _name(name, "name")
        with self._locked() as db:
            _check_implement_room(db, args)

    def get_implement(self, name: str) -> StoredImplement | None:
        args = (_name(name, "name"),)
        with self._locked() as db:
            row = db.execute(f"SELECT {_IMPLEMENT_COLUMNS} FROM implements WHERE name = ?", args).fetchone()
        return None if row is None else _implement(row)

    def list_implements(self) -> list[StoredImplement]:
        """Every implement, sorted by name."""
        with self._locked() as db:
            rows = db.execute(f"SELECT {_IMPLEMENT_COLUMNS} FROM implements ORDER BY name").fetchall()
        return [_implement(r) for r in rows]

    def delete_implement(self, name: str) -> bool:
        """Delete an implement (its presets stay, under its name); True if it existed."""
        return self._write("DELETE FROM implements WHERE name = ?", (_name(name, "name"),)) > 0

    def update_implement(
        self,
        name: str,
        *,
        transport_locked: bool | None = None,
        last_work: Mapping[str, float] | None = None,
    ) -> StoredImplement:
        """Set the transport lock and/or the last work pose of a stored implement (StoreError ``name``
        when there is none); returns it as stored."""
        n = _name(name, "name")
        sets: list[str] = []
        args: list[Any] = []
        if transport_locked is not None:
            if not isinstance(transport_locked, bool):
                raise StoreError("transport_locked", f"must be true or false, got {transport_locked!r}")
            sets.append("transport_locked = ?")
            args.append(int(transport_locked))
        if last_work is not None:
            sets.append("last_work = ?")
            args.append(_pose_text(_pose(last_work, "last_work")))
        if sets and self._write(f"UPDATE implements SET {', '.join(sets)} WHERE name = ?", (*args, n)) == 0:
            raise StoreError("name", f"no implement {n!r} in the store")
        imp = self.get_implement(n)
        if imp is None:
            raise StoreError("name", f"no implement {n!r} in the store")
        return imp

    # ------------------------------------------------------------------ lines
    def save_line(self, name: str, coordinates: Any, *, owner: str | None = None) -> None:
        """Save (replace) a field line: its ``[lon, lat]`` vertices (checked by the GNSS tracker first)."""
        self._write(
            "INSERT INTO lines (name, coordinates, owner, updated_s) VALUES (?, ?, ?, ?) ON CONFLICT (name) DO "
            "UPDATE SET coordinates = excluded.coordinates, owner = excluded.owner, updated_s = excluded.updated_s",
            (_name(name, "name"), json.dumps([list(c) for c in coordinates]), _owner(owner), time.time()),
        )

    def list_lines(self) -> list[tuple[str, list[list[float]]]]:
        """Every saved line (name, ``[lon, lat]`` vertices), sorted by name."""
        with self._locked() as db:
            rows = db.execute("SELECT name, coordinates FROM lines ORDER BY name").fetchall()
        return [(str(n), json.loads(c)) for n, c in rows]

    def delete_line(self, name: str) -> bool:
        return self._write("DELETE FROM lines WHERE name = ?", (_name(name, "name"),)) > 0

    # ------------------------------------------------------------------ work settings
    def get_work_settings(self, implement: str) -> dict[str, Any] | None:
        """The work-control settings stored for ``implement`` (JSON object; validated by the caller), or None."""
        with self._locked() as db:
            args = (_name(implement, "implement"),)
            row = db.execute("SELECT settings FROM work_settings WHERE implement = ?", args).fetchone()
        return None if row is None else dict(json.loads(row[0]))

    def save_work_settings(self, implement: str, settings: Mapping[str, Any], *, owner: str | None = None) -> None:
        """Save (replace) the work-control settings of ``implement`` (a JSON object of at most 2000 characters)."""
        text = json.dumps(dict(settings), allow_nan=False)
        if len(text) > 2000:
            raise StoreError("settings", "work settings must be a JSON object of at most 2000 characters")
        self._write(
            "INSERT INTO work_settings (implement, settings, owner, updated_s) VALUES (?, ?, ?, ?) ON CONFLICT "
            "(implement) DO UPDATE SET settings = excluded.settings, owner = excluded.owner, "
            "updated_s = excluded.updated_s",
            (_name(implement, "implement"), text, _owner(owner), time.time()),
        )

    # ------------------------------------------------------------------ settings
    def get_setting(self, key: str) -> str | None:
        """A persisted service setting (e.g. ``selected_implement``), or None."""
        with self._locked() as db:
            row = db.execute("SELECT value FROM settings WHERE key = ?", (str(key),)).fetchone()
        return None if row is None else str(row[0])

    def set_setting(self, key: str, value: str) -> None:
        if not isinstance(value, str) or len(value) > 1000:
            raise StoreError(key, "a setting must be text of at most 1000 characters")
        self._write(
            "INSERT INTO settings (key, value) VALUES (?, ?) ON CONFLICT (key) DO UPDATE SET value = excluded.value",
            (str(key), value),
        )

    def _remember(self, key: tuple[str, float], parsed: ManeuverScript) -> None:
        self._cache[key] = parsed
        self._cache.move_to_end(key)
        while len(self._cache) > _CACHE_SIZE:
            self._cache.popitem(last=False)


def _listing(parsed: ManeuverScript | None, script: str) -> tuple[str | None, str, int, float, int]:
    """The stored form and listing columns of a maneuver: parsed JSON, description, steps, timeout, size."""
    size = len(script.encode("utf-8", "surrogatepass"))
    if parsed is None:
        return None, "", 0, 0.0, size
    form = json.dumps(parsed.to_json(), allow_nan=False, separators=(",", ":"))
    return form, parsed.description, len(parsed.steps), parsed.timeout_s, size


def _preset(row: tuple[Any, ...]) -> Preset:
    implement, name, x, z, roll, pitch, scale, updated, owner = row
    if scale is not None:  # saved by an older program below today's bound: runs at the bound
        scale = max(float(scale), MIN_SPEED_SCALE)
    return Preset(implement, name, {"x": x, "z": z, "roll": roll, "pitch": pitch}, scale, updated, owner)


_IMPLEMENT_COLUMNS = (
    "name, category, mass_kg, com_x, com_y, com_z, upper_height_m, lowering_speed_m_s, transport_locked, "
    "headland, last_work, description, updated_s, owner"
)


def _pose_text(pose: Mapping[str, float] | None) -> str | None:
    return None if pose is None else json.dumps(dict(pose), allow_nan=False, separators=(",", ":"))


def _pose_of(text: str | None) -> dict[str, float] | None:
    if text is None:
        return None
    try:
        return {str(k): float(v) for k, v in json.loads(text).items()}
    except (ValueError, AttributeError, TypeError):
        return None  # a damaged pose reads as none: the quick raise / return then says it has none


def _implement(row: tuple[Any, ...]) -> StoredImplement:
    name, category, mass, cx, cy, cz, upper, lowering, locked, headland, last_work, desc, updated, owner = row
    return StoredImplement(
        name,
        category,
        float(mass),
        (float(cx), float(cy), float(cz)),
        ImplementLimits(
            None if upper is None else float(upper), None if lowering is None else float(lowering), bool(locked)
        ),
        _pose_of(headland),
        _pose_of(last_work),
        desc,
        float(updated),
        owner,
    )
