"""The black box: a rotating JSON-lines event log, a CAN bus recorder and a replay of recorded buses.

:class:`EventLog` writes one JSON object per line to ``<data_dir>/log/events.jsonl`` (see
:func:`event_log_path`), rotated by size (:class:`logging.handlers.RotatingFileHandler`:
``events.jsonl.1`` … ``.N``, the oldest dropped). Each record carries ``t`` (wall clock, s since
the epoch), ``seq`` (1, 2, … per log, continued across service starts: a new :class:`EventLog` on an
existing log goes on after the last record's number, so a number names one record) and ``kind``:

* ``request`` — who asked what and what came of it: ``key``, ``user`` (None: not named, a request
  on the plain keys that Zenoh's access control let through), ``accepted`` (bool), ``error`` and
  ``message`` of a refusal, ``motion_id`` of an accepted motion, ``request`` (the JSON body of a
  request on a motion or writing key — :data:`WRITING_KEYS`, :data:`WRITING_PREFIXES`: every operator key of
  :mod:`bridge.service.security` — capped at :data:`MAX_BODY_CHARS` characters), ``read`` (true: a request on
  such a key that changed nothing and only read, :data:`READ_OR_WRITE_KEYS`: ``hitch work status``'s
  ``work/settings`` without a setting); every request but ``config``
  (:data:`UNRECORDED_KEYS`: the service's fixed description, which every client asks once), within
  the limits of :class:`RecordLimits` (below);
* ``suppressed`` — requests of one group (``key``, ``user``, ``accepted``, ``error``) counted but not
  written one by one (``count``, ``since``: wall time of the first, ``window_s``, ``message``);
* ``event`` — an event of this service (faults, motion and maneuver outcomes, mode changes …) as
  the service itself hands it to its in-process ``event`` listeners — never read back from the public
  ``<prefix>/events`` key, where anyone allowed to put could forge one and which a router outage cuts —
  its fields as they are, the service's time ``t`` kept as ``event_t``, its number as ``event_seq`` and
  its own ``kind`` (a motion's ``goto``, ``preset``, ``jog``, ``stop`` …; a maneuver step's) as ``event_kind``;
* ``gap`` — events of the service that did not reach the black box (their numbers ``event_seq`` are
  consecutive: ``missing``, ``first_event_seq`` … ``last_event_seq``);
* ``service`` — start and stop of the service; ``dropped`` — records lost because the
  writer fell behind (``count``).

:meth:`EventLog.record` never blocks and never raises: the record goes into a bounded queue
that a writer thread empties, so the control thread that reports an event does no file I/O.
Attach it with :meth:`EventLog.attach` (the service's ``event`` listener and the API's
``on_request`` hook).

Request floods cannot rotate the log away (:class:`RecordLimits`): events, ``service``, ``gap``,
``dropped`` and ``suppressed`` records are always written; request records pass token buckets per
group — accepted motion and writing requests (:func:`is_writing_key`; not their reads) and accepted terminal
logins / logouts generously per key and user, every other request record (reads, refusals, failed logins)
sparingly per key, user, outcome, error and read and all of them together under one shared budget (reads of a
key never share a bucket with its writes, so reads cannot crowd a write out); what a bucket holds
back is counted and written as one ``suppressed`` record per group at most every
``summary_s`` seconds (and at close), so the counts add up to every request.

:class:`CanRecorder` records every frame of a bus with python-can's own writers
(:class:`can.SizedRotatingLogger`: ``.asc``, ``.blf``, candump ``.log``, ``.csv`` by the file's
suffix) through a listener bus of its own on the same channel, in the order it receives them and in time order (a
frame stamped before one written already — the CAN hub's senders' jitter — is written at the latest time), rotated
by size like the event log:
``bus.asc`` is the newest, ``bus.1.asc`` the one before … ``bus.N.asc`` the oldest kept (the
format's suffix stays last, so every file reads back with :class:`can.LogReader` and ``hitch replay``).
:func:`replay_can_log` reads a recorded
log (:class:`can.LogReader`) into a :class:`~bridge.link.can_link.CanLink` on a private channel,
in the log's time, and yields what the link made of it: decoded frames (with their Unix time), measured
poses and each fault the link raised or cleared.
"""

from __future__ import annotations

import copy
import json
import logging
import logging.handlers
import math
import os
import queue
import threading
import time
import uuid
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, is_dataclass
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import can
from can.io.generic import TextIOMessageWriter

from bridge.service.security import MOTION_KEYS, WRITE_KEYS, WRITE_PREFIXES
from planner.errors import HitchInputError, first_line

if TYPE_CHECKING:
    from bridge.service.config import ServiceConfig
    from bridge.service.motion.outbox import Outbox

__all__ = [
    "BlackBoxError",
    "EventLog",
    "RecordLimits",
    "CanRecorder",
    "ReplayRecord",
    "announce_can_log_stop",
    "can_log_stopped_event",
    "event_log_path",
    "log_files",
    "last_seq",
    "read_events",
    "follow_events",
    "replay_can_log",
    "WRITING_KEYS",
    "last_record",
    "ended_cleanly",
    "WRITING_PREFIXES",
    "READ_OR_WRITE_KEYS",
    "is_writing_key",
    "STREAMED_KEYS",
    "UNRECORDED_KEYS",
    "MAX_BODY_CHARS",
    "MAX_OUT_OF_ORDER_S",
    "OUT_OF_ORDER",
    "describe_out_of_order",
]

#: request keys whose JSON body is kept in the log and whose accepted requests are kept generously: every key
#: that moves the hitch or changes the stored data or the service's state — taken from the access control's own
#: lists (:data:`~bridge.service.security.MOTION_KEYS`, :data:`~bridge.service.security.WRITE_KEYS`), so a key
#: added there is recorded without a change here (a list of its own here had missed hitch/raise|return,
#: work/…, implements/…, lines/…, maneuvers/pause|resume|skip|record/…) — and ``stop`` (open to viewers, but a
#: command of the machine)
WRITING_KEYS = frozenset(MOTION_KEYS) | frozenset(WRITE_KEYS) | {"stop"}
#: every key under these prefixes is a writing key too (:data:`~bridge.service.security.WRITE_PREFIXES`:
#: ``track/start``, ``track/setpoint``, ``track/stop``)
WRITING_PREFIXES: tuple[str, ...] = tuple(WRITE_PREFIXES)
#: writing keys whose request changes nothing when it gives no value: it reads (``mode`` without a mode,
#: ``work/settings`` without a setting: ``hitch work status``); per key the fields whose null is still a
#: change (``work/settings``: ``"slip_limit": null`` switches slip limiting off). Such a read is recorded
#: with ``read: true`` and limited as a read, apart from the key's writes.
READ_OR_WRITE_KEYS: Mapping[str, frozenset[str]] = {
    "mode": frozenset(),
    "work/settings": frozenset({"slip_limit"}),
}


#: writing keys limited as reads all the same: the streamed ``track/setpoint`` (up to 100 a second for hours:
#: kept generously it would rotate the rest of the log away; its session's start and stop are kept)
STREAMED_KEYS = frozenset({"track/setpoint"})


def is_writing_key(key: str) -> bool:
    """Whether requests on ``key`` move the hitch or change data (:data:`WRITING_KEYS`, :data:`WRITING_PREFIXES`),
    not counting the streamed setpoints (:data:`STREAMED_KEYS`)."""
    return (
        isinstance(key, str) and key not in STREAMED_KEYS and (key in WRITING_KEYS or key.startswith(WRITING_PREFIXES))
    )


def _body_text(payload: bytes | bytearray | memoryview | str | None) -> str:
    if payload is None:
        return ""
    try:
        return payload if isinstance(payload, str) else bytes(payload).decode("utf-8", "replace")
    except (TypeError, ValueError):
        return ""


def _only_reads(key: str, text: str, ok: bool, reply: Any) -> bool:
    """Whether a request on a key of :data:`READ_OR_WRITE_KEYS` only read: an accepted ``work/settings`` whose
    reply did not save; else a body that is empty or gives no value (null, except where null is a change)."""
    changes_when_null = READ_OR_WRITE_KEYS.get(key)
    if changes_when_null is None:
        return False
    if key == "work/settings" and ok and isinstance(reply, Mapping) and "settings" in reply:
        return not reply.get("saved")  # the service's own word: it saved the settings or only read them
    if not text.strip():
        return True
    try:
        body = json.loads(text)
    except ValueError:
        return False
    return isinstance(body, dict) and all(v is None and k not in changes_when_null for k, v in body.items())


#: a logged request body is cut to this many characters
MAX_BODY_CHARS = 2000
#: the writer looks for due ``suppressed`` summaries at least this often while the log is quiet [s]
_SUMMARY_POLL_S = 1.0
_LOG_NAME = "events.jsonl"


#: requests the black box does not record: reading the service's fixed description (every client asks
#: it once, to learn whether the service serves its user's own keys: docs/security.md)
UNRECORDED_KEYS = frozenset({"config"})


class BlackBoxError(HitchInputError):
    """A log setting or file that cannot be used; the message names it and what is allowed."""


#: accepted requests recorded generously (:attr:`RecordLimits.write_burst`): the machine's commands, the
#: stored data's changes (:func:`is_writing_key`; keys under :data:`WRITING_PREFIXES` too, not the reads of
#: :data:`READ_OR_WRITE_KEYS`) and the terminal's logins and logouts
KEPT_ACCEPTED_KEYS = WRITING_KEYS | {"web/login", "web/logout"}


def _kept(key: str, ok: bool, read: bool) -> bool:
    """Whether a request record is limited generously (an accepted command or change, login or logout)."""
    return ok and not read and (key in KEPT_ACCEPTED_KEYS or is_writing_key(key))


@dataclass(frozen=True)
class RecordLimits:
    """How many request records the black box writes one by one before it counts them instead.

    Token buckets (``burst`` records at once, refilled at ``per_s`` records a second):

    * accepted requests on :data:`KEPT_ACCEPTED_KEYS`, per key and user: ``write_burst``, ``write_per_s``
      (an operator's gotos are all written; a held jog button, 12 requests a second, is written for its
      first ``write_burst`` requests, then about ``write_per_s`` a second and the rest counted);
    * every other request record (reads, refusals of any kind, failed logins), per key, user, outcome
      and error: ``other_burst``, ``other_per_s``; and all of those together: ``total_burst``,
      ``total_per_s`` (names and error codes cannot multiply the budget).

    A group whose bucket is empty is counted and written as one ``suppressed`` record at most every
    ``summary_s`` seconds (and when its next record passes, and at close). At most ``max_groups``
    groups are tracked; beyond, new groups are counted together under key and user ``"*"``.

    Worst case with the defaults: the refused / reading requests of any number of clients write at most
    about 1 record a second plus 65 summaries a minute — under 1 kB/s with records like a refused ``ik``
    (the default log, 6 files of 5 MB, then holds some 8 hours of the flood), about 5 kB/s with every
    record at its longest (:data:`MAX_BODY_CHARS` of body and of message: some 1.5 hours); before, 20 s
    of refused ``ik`` requests rotated the whole log away.
    """

    write_burst: int = 100
    write_per_s: float = 2.0
    other_burst: int = 10
    other_per_s: float = 0.1
    total_burst: int = 100
    total_per_s: float = 1.0
    summary_s: float = 60.0
    max_groups: int = 64

    def __post_init__(self) -> None:
        for name in ("write_burst", "other_burst", "total_burst", "max_groups"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 10**6:
                raise BlackBoxError(f"RecordLimits.{name} must be an integer in 1..1000000, got {v!r}")
        for name in ("write_per_s", "other_per_s", "total_per_s", "summary_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v <= 1e6 or not math.isfinite(v):
                raise BlackBoxError(f"RecordLimits.{name} must be a number in (0, 1e6], got {v!r}")


#: (key, user, accepted, error, read) of a request record: the reads of a writing key (:data:`READ_OR_WRITE_KEYS`)
#: are a group of their own, limited as reads, never in the bucket of the key's writes
_Group = tuple[str, str | None, bool, str | None, bool]
_OVERFLOW: _Group = ("*", "*", False, None, False)
#: accepted writing requests beyond their groups' cap: one group, still written (by its own bucket), not counted away
_OVERFLOW_KEPT: _Group = ("*", "*", True, None, False)
#: accepted writing requests may hold this many times ``max_groups`` groups (keys × the users who write)
KEPT_GROUPS_FACTOR = 4


class _Bucket:
    __slots__ = ("burst", "per_s", "tokens", "at")

    def __init__(self, burst: int, per_s: float, now: float) -> None:
        self.burst, self.per_s, self.tokens, self.at = float(burst), float(per_s), float(burst), now

    def refill(self, now: float) -> None:
        if now > self.at:
            self.tokens = min(self.burst, self.tokens + (now - self.at) * self.per_s)
        self.at = max(self.at, now)


class _Tally:
    __slots__ = ("bucket", "count", "since", "first", "last")

    def __init__(self, bucket: _Bucket) -> None:
        self.bucket = bucket
        self.count = 0  # held back since the last summary
        self.since: float | None = None  # wall time of the first held back
        self.first = self.last = 0.0  # clock of the first and the last held back


class _RequestLimiter:
    """The token buckets of :class:`RecordLimits` and the counts of what they held back (thread-safe)."""

    def __init__(self, limits: RecordLimits, clock: Callable[[], float]) -> None:
        self.limits, self.clock = limits, clock
        self._lock = threading.Lock()
        self._groups: dict[_Group, _Tally] = {}
        self._total = _Bucket(limits.total_burst, limits.total_per_s, clock())
        self.pending = 0  # groups with a count not yet summarised

    def admit(self, group: _Group, kept: bool) -> tuple[bool, dict[str, Any] | None]:
        """Whether a record of ``group`` is written; and the summary of what the group held back before
        (to be written first) when it is."""
        lim, now = self.limits, self.clock()
        with self._lock:
            tally = self._groups.get(group)
            if tally is None:
                # accepted writing requests always get a group of their own (keys × users: bounded), never the
                # overflow, so a flood of made-up keys cannot silence an operator's gotos and stops
                cap = lim.max_groups * (KEPT_GROUPS_FACTOR if kept else 1)  # made-up user names: bounded too
                if len(self._groups) >= cap:
                    self._prune(now)
                if len(self._groups) >= cap:
                    group, kept = (_OVERFLOW_KEPT, True) if kept else (_OVERFLOW, False)
                    tally = self._groups.get(group)
                if tally is None:
                    burst, per_s = (lim.write_burst, lim.write_per_s) if kept else (lim.other_burst, lim.other_per_s)
                    tally = self._groups[group] = _Tally(_Bucket(burst, per_s, now))
            tally.bucket.refill(now)
            ok = group != _OVERFLOW and tally.bucket.tokens >= 1.0
            if ok and not kept:
                self._total.refill(now)
                ok = self._total.tokens >= 1.0
                if ok:
                    self._total.tokens -= 1.0
            if ok:
                tally.bucket.tokens -= 1.0
                return True, self._summary(group, tally, now)
            if tally.count == 0:
                tally.since, tally.first = time.time(), now
                self.pending += 1
            tally.count += 1
            tally.last = now
            return False, None

    def due(self, *, force: bool = False) -> list[dict[str, Any]]:
        """The summaries of the groups whose first held-back record is ``summary_s`` old (all: ``force``)."""
        now = self.clock()
        with self._lock:
            if not self.pending:
                return []
            out = []
            for group, tally in list(self._groups.items()):
                if tally.count and (force or now - tally.first >= self.limits.summary_s):
                    rec = self._summary(group, tally, now)
                    if rec is not None:
                        out.append(rec)
            return out

    def _summary(self, group: _Group, tally: _Tally, now: float) -> dict[str, Any] | None:
        if not tally.count:
            return None
        key, user, accepted, error, read = group
        window = max(0.0, now - tally.first)
        span = f"{window:.1f}" if window < 10.0 else f"{window:.0f}"  # "in the last 0 s" for 0.4 s (a trial)
        what = "accepted" if accepted else "refused"
        rec: dict[str, Any] = {
            "key": key,
            "user": user,
            "accepted": accepted,
            "error": error,
            "count": tally.count,
            "since": tally.since,
            "window_s": round(window, 3),
            **({"read": True} if read else {}),
            "message": (
                f"{tally.count} further request records of other groups (more than {self.limits.max_groups} "
                f"groups) in the last {span} s"
                if group == _OVERFLOW
                else f"{tally.count} further {what} {key} {'reads' if read else 'requests'}"
                f"{f' ({error})' if error else ''} from "
                f"{user if user is not None else 'unnamed'} in the last {span} s"
            ),
        }
        tally.count, tally.since = 0, None
        self.pending -= 1
        return rec

    def _prune(self, now: float) -> None:
        """Forget the groups with nothing held back whose bucket is full again (they start over alike)."""
        for group, tally in list(self._groups.items()):
            tally.bucket.refill(now)
            if not tally.count and tally.bucket.tokens >= tally.bucket.burst:
                del self._groups[group]


def event_log_path(data_dir: str | Path) -> Path:
    """The event log of a service whose data dir is ``data_dir``: ``data_dir/log/events.jsonl``."""
    return Path(data_dir) / "log" / _LOG_NAME


def _plain(value: Any) -> Any:
    """A JSON-able rendering of event values (dataclasses, enums, numpy scalars, non-finite floats)."""
    if isinstance(value, Enum):
        return _plain(value.value)
    if is_dataclass(value) and not isinstance(value, type):
        return _plain(asdict(value))
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, set, frozenset)):
        return [_plain(v) for v in value]
    if isinstance(value, bool) or value is None or isinstance(value, (int, str)):
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    try:
        f = float(value)
    except (TypeError, ValueError):
        return str(value)
    return f if math.isfinite(f) else str(f)


class _PrivateRotatingFileHandler(logging.handlers.RotatingFileHandler):
    """Each log file readable by the service's user only (0600, also after a rotation): the records name users
    and carry their requests. They were 0644 wherever the data folder existed already (a fleet trial)."""

    def _open(self):
        try:  # created 0600: not readable by others for an instant either
            os.close(os.open(self.baseFilename, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o600))
        except OSError:
            pass  # the open below says why
        stream = super()._open()
        try:
            os.chmod(self.baseFilename, 0o600)
        except OSError:
            pass
        return stream


class EventLog:
    """Rotating JSON-lines log written by its own thread (see the module docstring).

    Args:
        path: the log file (its folder is created).
        max_bytes: rotate when the file would grow beyond this, (0, 1e10] bytes.
        backup_count: rotated files kept, 1..1000.
        queue_size: records waiting for the writer, 1..1e6; more are counted as dropped.
        limits: how many request records are written one by one (:class:`RecordLimits`; default its defaults).
        clock: the limits' clock [s] (monotonic; tests pass their own).
    """

    def __init__(
        self,
        path: str | Path,
        *,
        max_bytes: int = 5_000_000,
        backup_count: int = 5,
        queue_size: int = 10_000,
        limits: RecordLimits | None = None,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or not 0 < max_bytes <= 10**10:
            raise BlackBoxError(f"max_bytes must be an integer in (0, 1e10], got {max_bytes!r}")
        if isinstance(backup_count, bool) or not isinstance(backup_count, int) or not 1 <= backup_count <= 1000:
            raise BlackBoxError(f"backup_count must be an integer in 1..1000, got {backup_count!r}")
        if isinstance(queue_size, bool) or not isinstance(queue_size, int) or not 1 <= queue_size <= 10**6:
            raise BlackBoxError(f"queue_size must be an integer in 1..1000000, got {queue_size!r}")
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
            _end_torn_line(self.path)
            self._handler = _PrivateRotatingFileHandler(
                self.path, maxBytes=max_bytes, backupCount=backup_count, encoding="utf-8"
            )
        except OSError as exc:
            raise BlackBoxError(f"event log {self.path}: cannot open ({exc})") from None
        self._handler.setFormatter(logging.Formatter("%(message)s"))
        self._queue: queue.Queue[dict[str, Any] | None] = queue.Queue(maxsize=queue_size)
        self._lock = threading.Lock()
        self._seq = last_seq(self.path)
        self._dropped = 0
        self._dropped_reported = 0
        self._limiter = _RequestLimiter(limits if limits is not None else RecordLimits(), clock)
        self._event_seq: int | None = None  # the last event number heard (None: none yet, any first is fine)
        self._event_lock = threading.Lock()
        self._closed = False
        self._thread = threading.Thread(target=self._write_loop, name="hitch-blackbox", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ recording (never blocks)
    @property
    def dropped(self) -> int:
        """Records lost because the queue was full."""
        return self._dropped

    def record(self, kind: str, **fields: Any) -> bool:
        """Queue one record; False (and counted as dropped) when the writer is behind or closed."""
        if self._closed:
            return False
        rec = {"t": time.time(), "kind": kind, **fields}
        try:
            self._queue.put_nowait(rec)
        except queue.Full:
            with self._lock:
                self._dropped += 1
            return False
        return True

    def on_event(self, event: Mapping[str, Any]) -> None:
        """Listener for the service's own ``event`` dicts (in-process: :meth:`attach`). The service numbers
        its events 1, 2, … (``seq``); a number skipped — an event that did not reach the black box, e.g. a
        bounded queue on the way overflowed — is written as a ``gap`` record before the event."""
        e = dict(event)
        if "t" in e:
            e["event_t"] = e.pop("t")
        if "kind" in e:  # the motion's (goto, preset, jog, stop …) or step's kind; ``kind`` is the record's
            e["event_kind"] = e.pop("kind")
        if "seq" in e:  # the service's own event sequence number; ``seq`` is the log's
            e["event_seq"] = e.pop("seq")
        n = e.get("event_seq")
        with self._event_lock:  # one listener call at a time in practice; the lock keeps gap and event in order
            if isinstance(n, int) and not isinstance(n, bool):
                last = self._event_seq
                if last is not None and n > last + 1:
                    self.record(
                        "gap",
                        missing=n - last - 1,
                        first_event_seq=last + 1,
                        last_event_seq=n - 1,
                        message=f"{n - last - 1} event(s) of the service (numbers {last + 1}..{n - 1}) were not "
                        "recorded: published before the black box was attached, or lost on the way to it",
                    )
                if last is None or n > last:
                    self._event_seq = n
            self.record("event", **e)

    def on_request(
        self, key: str, user: str | None, payload: bytes | bytearray | memoryview | str | None, ok: bool, reply: Any
    ) -> None:
        """Hook for :class:`~bridge.service.api.ServiceAPI` (``on_request``): one ``request`` record
        (none for :data:`UNRECORDED_KEYS`)."""
        if key in UNRECORDED_KEYS:
            return
        rec: dict[str, Any] = {"key": key, "user": user, "accepted": bool(ok)}
        if isinstance(reply, Mapping):
            if ok:
                if reply.get("motion_id") is not None:
                    rec["motion_id"] = reply.get("motion_id")
            else:
                rec["error"] = reply.get("error")
                rec["message"] = str(reply.get("message", ""))[:MAX_BODY_CHARS]
        error = rec.get("error")
        writing = is_writing_key(key)
        text = _body_text(payload) if key in READ_OR_WRITE_KEYS else None
        read = text is not None and _only_reads(key, text, bool(ok), reply)
        if read:
            rec["read"] = True
        group: _Group = (
            str(key)[:200],
            None if user is None else str(user)[:200],
            bool(ok),
            None if error is None else str(error)[:200],
            read,
        )
        admitted, summary = self._limiter.admit(group, _kept(key, bool(ok), read))
        if summary is not None:
            self.record("suppressed", **summary)
        if not admitted:
            return
        if writing:
            text = _body_text(payload) if text is None else text
            if text:
                rec["request"] = text[:MAX_BODY_CHARS]
        self.record("request", **rec)

    def summarize(self) -> None:
        """Queue a ``suppressed`` record for every group with requests held back now (e.g. before the
        service's stop record; :meth:`close` writes the rest)."""
        for summary in self._limiter.due(force=True):
            self.record("suppressed", **summary)

    def attach(self, service: Any) -> None:
        """Record the events of a started :class:`~bridge.service.server.HitchService` (its in-process
        ``event`` listener: the dicts the service itself publishes, never what is heard on its public
        ``events`` key) and, when its API has the ``on_request`` hook, its requests. The service numbers
        its events from 1: events it had already published when attached are noted as a ``gap``."""
        with self._event_lock:
            if self._event_seq is None:
                self._event_seq = 0
        service.add_listener("event", self.on_event)
        api = getattr(service, "api", None)
        if api is not None and hasattr(api, "on_request"):
            api.on_request = self.on_request

    # ------------------------------------------------------------------ writer thread
    def _write_loop(self) -> None:
        while True:
            try:
                rec = self._queue.get(timeout=_SUMMARY_POLL_S)
            except queue.Empty:  # quiet: summaries whose time has come
                self._write_summaries()
                continue
            try:
                if rec is None:
                    self._write_summaries(force=True)
                    return
                with self._lock:
                    lost = self._dropped - self._dropped_reported
                    self._dropped_reported = self._dropped
                if lost:
                    self._write({"t": time.time(), "kind": "dropped", "count": lost})
                self._write(rec)
                self._write_summaries()
            finally:
                self._queue.task_done()

    def _write_summaries(self, *, force: bool = False) -> None:
        if not self._limiter.pending:
            return
        for summary in self._limiter.due(force=force):
            self._write({"t": time.time(), "kind": "suppressed", **summary})

    def _write(self, rec: dict[str, Any]) -> None:
        self._seq += 1
        line = json.dumps({"seq": self._seq, **_plain(rec)}, separators=(",", ":"), allow_nan=False)
        self._handler.emit(logging.makeLogRecord({"msg": line, "args": None}))

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait (bounded) until every queued record is written; True if the queue emptied."""
        end = time.monotonic() + timeout_s
        while self._queue.unfinished_tasks and self._thread.is_alive():
            if time.monotonic() >= end:
                return False
            time.sleep(0.005)
        return True

    def close(self, timeout_s: float = 5.0) -> None:
        """Write what is queued (bounded wait), stop the writer and close the file."""
        if self._closed:
            return
        self._closed = True
        end = time.monotonic() + timeout_s
        while True:
            try:
                self._queue.put(None, timeout=max(0.01, end - time.monotonic()))
                break
            except queue.Full:
                if time.monotonic() >= end:
                    break
        self._thread.join(max(0.0, end - time.monotonic()))
        self._handler.close()

    def __enter__(self) -> EventLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------------- reading
def log_files(path: Path) -> list[Path]:
    """Rotated files oldest first, then the live file."""
    rotated = []
    for p in path.parent.glob(path.name + ".*"):
        suffix = p.name[len(path.name) + 1 :]
        if suffix.isdigit():
            rotated.append((int(suffix), p))
    return [p for _, p in sorted(rotated, reverse=True)] + ([path] if path.exists() else [])


def last_record(path: str | Path, *, tail_bytes: int = 65_536) -> dict[str, Any] | None:
    """The newest readable record (with a ``seq``) of the log at ``path`` (the live file, else the newest
    rotated one), None for none. Reads only the files' last ``tail_bytes``; a torn last line (a killed
    writer) is skipped."""
    p = Path(path)
    for f in reversed(log_files(p)):
        try:
            with f.open("rb") as fh:
                fh.seek(0, os.SEEK_END)
                fh.seek(max(0, fh.tell() - tail_bytes))
                tail = fh.read().decode("utf-8", errors="replace")
        except OSError:
            continue
        for line in reversed(tail.splitlines()):
            rec = _parse_line(line)
            seq = None if rec is None else rec.get("seq")
            if rec is not None and isinstance(seq, int) and not isinstance(seq, bool) and seq >= 0:
                return rec
    return None


def last_seq(path: str | Path, *, tail_bytes: int = 65_536) -> int:
    """The ``seq`` of :func:`last_record`, 0 for none."""
    rec = last_record(path, tail_bytes=tail_bytes)
    return 0 if rec is None else int(rec["seq"])


def ended_cleanly(record: dict[str, Any] | None) -> bool:
    """Whether a log whose newest record is ``record`` was closed by its service (``service`` ``stopped``), or
    holds none; False after a kill, a crash or a power loss, which leave no stop record."""
    return record is None or (record.get("kind") == "service" and record.get("what") == "stopped")


def _end_torn_line(path: Path) -> None:
    """A log whose last line was cut (a writer killed mid-line, power lost) gets its newline, so the next record
    starts a line of its own (it was appended to the torn one: both unreadable)."""
    try:
        with path.open("rb+") as fh:
            fh.seek(0, os.SEEK_END)
            if fh.tell() == 0:
                return
            fh.seek(-1, os.SEEK_END)
            if fh.read(1) != b"\n":
                fh.write(b"\n")
    except FileNotFoundError:
        return


def _parse_line(line: str) -> dict[str, Any] | None:
    line = line.strip()
    if not line:
        return None
    try:
        rec = json.loads(line)
    except ValueError:
        return {"kind": "unreadable", "line": line[:200]}
    return rec if isinstance(rec, dict) else {"kind": "unreadable", "line": line[:200]}


def read_events(path: str | Path) -> list[dict[str, Any]]:
    """Every record of the log at ``path`` and its rotated files, oldest first."""
    p = Path(path)
    out: list[dict[str, Any]] = []
    for f in log_files(p):
        try:
            text = f.read_text(encoding="utf-8", errors="replace")
        except OSError:
            continue  # rotated away meanwhile
        out.extend(r for r in map(_parse_line, text.splitlines()) if r is not None)
    return out


def follow_events(
    path: str | Path,
    *,
    poll_s: float = 0.2,
    should_stop: Callable[[], bool] = lambda: False,
    from_start: bool = False,
) -> Iterator[dict[str, Any]]:
    """New records of the live log as they are written (like ``tail -F``: follows rotation). A log that
    exists now is read from its end, unless ``from_start`` (a caller that found no log before: one that
    appeared since holds records nobody has seen); one that appears later is read from its start."""
    p = Path(path)
    f = None
    partial = ""
    try:
        if p.exists():
            f = p.open("r", encoding="utf-8", errors="replace")
            if not from_start:
                f.seek(0, 2)  # only what is written from now on
        while not should_stop():
            if f is None:
                try:
                    f = p.open("r", encoding="utf-8", errors="replace")
                except OSError:
                    time.sleep(poll_s)
                    continue
            chunk = f.read()
            if chunk:
                lines = (partial + chunk).split("\n")
                partial = lines.pop()
                for line in lines:
                    rec = _parse_line(line)
                    if rec is not None:
                        yield rec
                continue
            try:
                replaced = os.stat(p).st_ino != os.fstat(f.fileno()).st_ino
            except OSError:
                replaced = True
            if replaced:  # rotated: the old file was read to its end above; go on with the new one
                f.close()
                f, partial = None, ""
                continue
            time.sleep(poll_s)
    finally:
        if f is not None:
            f.close()


# ---------------------------------------------------------------------------------------- CAN
#: a text CAN log is flushed to the file at least this often while frames arrive [s] (a crash loses less)
FLUSH_EVERY_S = 0.25


class _Flusher(can.Listener):
    """Flushes a log writer's file every ``every_s`` seconds of frames (a BLF writer's container too; runs after
    the writer; the rotating logger's current writer, which changes at each rotation)."""

    def __init__(self, logger: can.io.BaseRotatingLogger, every_s: float) -> None:
        self._logger, self._every_s = logger, every_s
        self._last = time.monotonic()

    def on_message_received(self, msg: can.Message) -> None:
        now = time.monotonic()
        if now - self._last >= self._every_s:
            self._last = now
            writer = self._logger.writer
            try:
                if isinstance(writer, can.BLFWriter):
                    # a BLF writer holds up to a 128 KiB container (some 7 s of this bus) in memory: a kill or a
                    # power loss lost it (an incident investigator's trial: a whole goto missing). Its container
                    # is written now; python-can has no public call for it (4.x: _flush), so only if it is there
                    write_container = getattr(writer, "_flush", None)
                    if callable(write_container):
                        write_container()
                    writer.file.flush()
                elif isinstance(writer, TextIOMessageWriter):
                    writer.file.flush()
            except (OSError, ValueError):  # closed meanwhile
                pass


class _Counter(can.Listener):
    """Counts the frames the listeners before it have taken; keeps the error that ended the recording, calls
    ``end`` (on the notifier's thread: the recording ends there) and tells the error to the callback given to
    :meth:`watch` (exactly once, whichever comes first)."""

    def __init__(self, end: Callable[[], None] | None = None) -> None:
        self.n = 0
        self.error: BaseException | None = None
        self._end = end
        self._callback: Callable[[BaseException], None] | None = None
        self._mu = threading.Lock()

    def on_message_received(self, msg: can.Message) -> None:
        if self.error is None:
            self.n += 1

    def on_error(self, exc: Exception) -> None:
        with self._mu:
            if self.error is not None:  # told once: the first error is what stopped the recording
                return
            self.error, callback = exc, self._callback
        if self._end is not None:
            self._end()
        if callback is not None:
            try:
                callback(exc)
            except Exception:  # noqa: BLE001 — the recording has ended either way; its thread ends quietly
                pass

    def watch(self, callback: Callable[[BaseException], None]) -> None:
        with self._mu:
            self._callback, error = callback, self.error
        if error is not None:
            callback(error)


class _SizedLog(can.SizedRotatingLogger):
    """python-can's size-rotating logger, its size looked up every :data:`_SIZE_EVERY` frames: a text
    writer's ``file_size`` is ``tell()``, which flushes the file, so asking it for every frame made one
    write per frame. A file grows past ``max_bytes`` by less than that many frames."""

    def __init__(self, base_filename: str, max_bytes: int) -> None:
        self._since_size = 0
        self.failed: BaseException | None = None
        self._last_t = -math.inf  # the latest timestamp written
        self.out_of_order = 0  # frames written at the latest time, stamped before it (below)
        self.max_back_s = 0.0  # the most such a frame was stamped before the latest one [s]
        super().__init__(base_filename, max_bytes=max_bytes)

    def _in_order(self, msg: can.Message) -> can.Message:
        """``msg``, or a copy at the latest time written when it is stamped before it by at most
        :data:`MAX_OUT_OF_ORDER_S`: the frames are written in the order the recorder received them, in time order.

        A CAN hub (:class:`~bridge.link.loopback.LoopbackHub`: python-can's ``virtual`` bus in one process)
        stamps each frame when a sender's thread hands it on and then puts it into every client's queue; the
        threads of several senders interleave between the two, so a frame stamped earlier can reach the
        recorder after one stamped later (up to 15 ms measured). A larger step back is no such jitter (the
        computer's clock set back): written as it is, and the log's time goes on from there."""
        t = float(msg.timestamp)
        if t >= self._last_t or not self._last_t - t <= MAX_OUT_OF_ORDER_S:
            self._last_t = t
            return msg
        if self._last_t - t > _BACKWARDS_TOLERANCE_S:
            self.out_of_order += 1
            self.max_back_s = max(self.max_back_s, self._last_t - t)
        taken = copy.copy(msg)
        taken.timestamp = self._last_t
        return taken

    def on_message_received(self, msg: can.Message) -> None:
        """Write ``msg`` (in time order: :meth:`_in_order`); after an error (a rotation that could not rename
        leaves the writer closed) nothing more: the error went to the notifier's listeners once, not again for
        every frame."""
        if self.failed is not None:
            return
        try:
            super().on_message_received(self._in_order(msg))
        except Exception as exc:
            self.failed = exc
            raise

    def should_rollover(self, msg: can.Message) -> bool:
        self._since_size += 1
        if self._since_size < _SIZE_EVERY:
            return False
        self._since_size = 0
        return super().should_rollover(msg)


#: frames between two size look-ups of the CAN log (about 10 kB of ASC text, a quarter second at rest)
_SIZE_EVERY = 100


def _holds_frames(path: Path) -> bool:
    """True if the log at ``path`` holds a frame (or cannot be read: kept rather than lost); a log with
    only its header (a run that recorded nothing) is not worth a rotated slot."""
    if not path.is_file() or path.stat().st_size == 0:
        return False
    try:
        reader = can.LogReader(str(path))
        try:
            return next(iter(reader), None) is not None
        finally:
            stop = getattr(reader, "stop", None)
            if callable(stop):
                stop()
    except Exception:  # noqa: BLE001 — a damaged log (a killed run's BLF) is kept
        return True


#: the suffixes :class:`CanRecorder` writes (python-can's size-rotating writers)
CAN_LOG_SUFFIXES = (".asc", ".blf", ".log", ".csv")
_SUFFIX_HINT = "suffixes: .asc, .blf, .log (candump), .csv"
#: how far a replayed frame's timestamp may lie before the latest one (the writers' rounding) [s]
_BACKWARDS_TOLERANCE_S = 1e-6
#: how far a frame's timestamp may lie before an earlier frame's and still be a bus's timestamp jitter, taken in
#: the file's order at the latest time (by the recorder, :class:`CanRecorder`, and by the replay,
#: :func:`replay_can_log`) [s]. The product's own hub interleaves its senders' stamps by up to 15 ms (an
#: integrator's 150 000-frame log), more on a loaded computer; software-stamped loggers of real buses (USB
#: adapters that buffer frames, channels merged) by a few to tens of ms. Ten times the hub's worst seen and
#: more: 0.25 s. A step back of more than this is no jitter but two recordings put together, a damaged file or a
#: clock set back — refused by the replay, which says how many frames it took late and by how much (a frame
#: taken late by about a stale or heartbeat limit, 0.2 / 0.3 s, could show a fault the bus did not have).
MAX_OUT_OF_ORDER_S = 0.25


def rotated_can_log(path: str | Path, k: int) -> Path:
    """The ``k``-th rotated file of the CAN log ``path`` (``bus.asc`` → ``bus.k.asc``; 0: ``path``)."""
    p = Path(path)
    return p if k == 0 else p.with_name(f"{p.stem}.{k}{p.suffix}")


def can_log_stopped_event(path: str | Path, error: BaseException) -> dict[str, Any]:
    """The service event that says the CAN log stopped recording (the service goes on without it)."""
    return {
        "event": "can_log_stopped",
        "path": str(path),
        "message": f"--can-log {path}: recording stopped ({type(error).__name__}: {error}); the service goes on "
        "without a CAN log — unless the bus itself failed (a CAN hub that went away ends the service too)",
    }


def announce_can_log_stop(recorder: CanRecorder, outbox: Outbox) -> None:
    """When an error stops ``recorder``, put :func:`can_log_stopped_event` into the controller's
    ``outbox`` and deliver it: the black box and every
    client hear that the bus is no longer recorded."""

    def stopped(error: BaseException) -> None:
        outbox.put_event(can_log_stopped_event(recorder.path, error))
        outbox.flush()

    recorder.on_stop(stopped)


#: python-can's ``Notifier.stop`` timeout from the notifier's own thread: far enough below zero that no step of the
#: wall clock between its two readings of ``time.time()`` makes it join its own thread (a review) [s]
_ON_OWN_THREAD_S = -86400.0


class CanRecorder:
    """Record every frame of ``interface``/``channel`` to ``path`` with python-can's writers.

    Opens its own listener bus on the channel (the service's buses are not touched) and a
    :class:`can.Notifier` thread. The file is rotated when it reaches ``max_bytes``: the full
    file becomes ``<stem>.1<suffix>``, older ones move up by one, and beyond ``keep`` rotated
    files the oldest is deleted — the log takes at most about (``keep`` + 1) × ``max_bytes`` of
    disk however long the service runs. ``close()`` stops it and closes the file.

    Args:
        path: the log file; its suffix picks the format (:data:`CAN_LOG_SUFFIXES`).
        interface, channel: the bus to record (:func:`bridge.link.realtime.open_bus`).
        max_bytes: size of one file, [1e5, 1e11] bytes.
        keep: rotated files kept, 1..1000.
    """

    def __init__(
        self,
        path: str | Path,
        interface: str,
        channel: str | None = None,
        *,
        max_bytes: int = 50_000_000,
        keep: int = 10,
    ) -> None:
        from bridge.link.realtime import open_bus

        self.path = Path(path)
        self._writer = self._open(self.path, max_bytes, keep)
        try:
            self._bus = open_bus(interface, channel)
        except HitchInputError:
            self._writer.stop()
            raise
        self._notifier: can.Notifier | None = None
        self._ended = False  # the notifier was stopped (by the first error, or by close)
        self._end_lock = threading.Lock()
        self._stopped = threading.Event()  # its listeners stopped: the file is complete
        self._count = _Counter(end=self._end)
        listeners: list[can.Listener] = [self._writer]
        if isinstance(self._writer.writer, (TextIOMessageWriter, can.BLFWriter)):  # on the disk within 0.25 s
            listeners.append(_Flusher(self._writer, FLUSH_EVERY_S))
        self._notifier = can.Notifier(self._bus, [*listeners, self._count], timeout=0.1)
        self._closed = False
        if self._count.error is not None:  # the first error came before the notifier was kept
            self._end()

    def _end(self, timeout_s: float = _ON_OWN_THREAD_S) -> None:
        """Stop the notifier once (its listeners close the file); a second call waits (up to 2 s) until the first
        has stopped them. From the notifier's own thread (the first error: a negative ``timeout_s``, so python-can's
        ``stop`` joins no thread — it would be its own —, whatever the wall clock does meanwhile): a listener that
        returns from ``on_error`` tells python-can the error was handled and its thread reads the bus again at
        once — a remote hub that went away raised on every read, and that thread spun at the control core's
        real-time priority holding the GIL: stop refused for 14 s to minutes (a field trial)."""
        with self._end_lock:
            notifier = self._notifier
            if notifier is None:  # an error before the notifier was kept: __init__ ends it
                return
            first, self._ended = not self._ended, True
        if not first:
            if timeout_s > 0.0:  # close() during the error's stop: the file complete before it returns
                self._stopped.wait(timeout_s)
            return
        try:
            notifier.stop(timeout=timeout_s)
        except Exception:  # noqa: BLE001 — a listener that cannot close after the error: the recording ended anyway
            pass
        finally:
            self._stopped.set()

    @property
    def frames_written(self) -> int:
        """Frames handed to the writer so far (on the notifier's thread)."""
        return self._count.n

    @property
    def frames_out_of_order(self) -> int:
        """Frames stamped before one written earlier (the hub's senders' jitter, by at most
        :data:`MAX_OUT_OF_ORDER_S`), written in the order received at the latest time written."""
        return self._writer.out_of_order

    @property
    def max_out_of_order_s(self) -> float:
        """The most one of :attr:`frames_out_of_order` was stamped before the latest time written [s]."""
        return self._writer.max_back_s

    @property
    def error(self) -> BaseException | None:
        """What stopped the recording (a rotation that could not rename, a full disk), or None."""
        return self._count.error

    def on_stop(self, callback: Callable[[BaseException], None]) -> None:
        """Call ``callback(error)`` once when an error stops the recording (on the recorder's thread),
        or at once if one already has: the service announces it (:func:`can_log_stopped_event`)."""
        self._count.watch(callback)

    @classmethod
    def of_config(cls, cfg: ServiceConfig) -> CanRecorder:
        """The recorder a service configuration asks for (``can_log``, ``can_log_max_mb``, ``can_log_keep``)."""
        if cfg.can_log is None:
            raise BlackBoxError("no can_log configured")
        max_bytes = int(round(cfg.can_log_max_mb * 1e6))
        return cls(cfg.can_log, cfg.can_interface, cfg.can_channel, max_bytes=max_bytes, keep=cfg.can_log_keep)

    @staticmethod
    def _open(path: Path, max_bytes: int, keep: int) -> _SizedLog:
        if isinstance(max_bytes, bool) or not isinstance(max_bytes, int) or not 100_000 <= max_bytes <= 10**11:
            raise BlackBoxError(f"--can-log: max_bytes must be an integer in [100000, 1e11], got {max_bytes!r}")
        if isinstance(keep, bool) or not isinstance(keep, int) or not 1 <= keep <= 1000:
            raise BlackBoxError(f"--can-log: keep must be an integer in 1..1000, got {keep!r}")
        CanRecorder.check_path(path)

        def shift(source: str | os.PathLike[str], _default_dest: str | os.PathLike[str] = "") -> None:
            """The full file becomes .1, every older one moves up by one, the oldest beyond ``keep`` goes."""
            rotated_can_log(path, keep).unlink(missing_ok=True)
            for k in range(keep - 1, 0, -1):
                older = rotated_can_log(path, k)
                if older.exists():
                    older.replace(rotated_can_log(path, k + 1))
            Path(source).replace(rotated_can_log(path, 1))

        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            if _holds_frames(path):  # an earlier run's log is kept, as the newest rotated one
                shift(path)
            logger = _SizedLog(str(path), max_bytes=max_bytes)
        except (ValueError, OSError, ImportError, TypeError) as exc:  # unwritable file
            raise BlackBoxError(f"--can-log {path}: cannot record ({exc}); {_SUFFIX_HINT}") from None
        logger.rotator = shift
        return logger

    @staticmethod
    def check_path(path: str | Path) -> None:
        """Refuse a file the recorder cannot write (unknown suffix, a folder that cannot be made or
        written) before recording starts; an existing log is not touched."""
        p = Path(path)
        if p.suffix.lower() not in CAN_LOG_SUFFIXES:
            raise BlackBoxError(f"--can-log {p}: cannot record files of type {p.suffix or '(none)'!r}; {_SUFFIX_HINT}")
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BlackBoxError(f"--can-log {p}: cannot record ({exc})") from None
        # rotating renames and deletes files in the folder: the folder must be writable, and the file if it is there
        if p.is_dir() or not os.access(p.parent, os.W_OK) or (p.exists() and not os.access(p, os.W_OK)):
            raise BlackBoxError(f"--can-log {p}: cannot record (the file or its folder {p.parent} is not writable)")

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._end(timeout_s=2.0)  # stops its listeners too: the writer flushes and closes the file
        from bridge.link.realtime import shutdown_bus

        shutdown_bus(self._bus)  # a remote hub that went away: its socket is gone already (said, never raised)

    def __enter__(self) -> CanRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def describe_system_state(value: Any) -> str:
    """The cylinder ECU's system-state byte (0xFF22 byte 8) in words: its bits by name and the restart count,
    e.g. ``controllers on, watchdog tripped; restart count 0`` (a value that is no byte: as it is)."""
    from bridge.isobus.messages import CodecError
    from bridge.isobus.system_state import decode_system_state

    try:
        s = decode_system_state(value)
    except CodecError:
        return repr(value)
    words = ["controllers on" if s.controllers_on else "controllers off"]
    words += [
        text
        for on, text in (
            (s.watchdog_tripped, "watchdog tripped"),
            (s.end_stop_relay, "end-stop relay engaged"),
            (s.no_reference_since_restart, "no reference since restart"),
        )
        if on
    ]
    return ", ".join(words) + f"; restart count {s.restart_count_mod16}"


def _named(value: Any) -> Any:
    """JSON-able fields with enums by name (as the text shows them), the rest as :func:`_plain` renders it."""
    if isinstance(value, Enum):
        return value.name
    if is_dataclass(value) and not isinstance(value, type):
        return _named(asdict(value))
    if isinstance(value, Mapping):
        return {str(k): _named(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_named(v) for v in value]
    return _plain(value)


@dataclass(frozen=True)
class ReplayRecord:
    """One replayed frame: log time ``t_s`` (from the first frame), J1939 source, message and fields.

    ``timestamp`` is the frame's own time (Unix time [s]; python-can's ASC reader is asked for absolute times,
    from the log's header date) — None when the log carries no date (an ``.asc`` whose header names none:
    its times only count from its start). ``pose`` is the link's measured pose (x, z [m], roll, pitch [rad])
    after a measurement; ``error`` the codec's reason for a frame it could not decode.

    Records named ``fault`` and ``fault_cleared`` (no source) say that the link raised fault ``fault`` at
    ``t_s`` (``faults``: its reason) or that it cleared (its cause gone), between or at frames; every raise
    and every clear is one record. ``log_start``: a stale measurement or a missing ECU heartbeat at the start
    of the log, before the first complete measurement (or heartbeat) arrived — the recording began before the
    link heard it, which is no fault of the machine — and, on a ``fault_cleared``, the end of that.
    """

    t_s: float
    source: int | None
    name: str
    fields: Mapping[str, Any] = field(default_factory=dict)
    pose: Mapping[str, float] | None = None
    faults: tuple[str, ...] = ()
    error: str = ""
    timestamp: float | None = None
    fault: str = ""
    log_start: bool = False

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "t": self.t_s,
            "timestamp": self.timestamp,
            "source": self.source,
            "message": self.name,
            "fields": _named(self.fields),
            "pose": None if self.pose is None else dict(self.pose),
            "faults": list(self.faults),
        }
        if "system_state" in self.fields:
            out["system_state"] = describe_system_state(self.fields["system_state"])
        if self.fault:
            out["fault"] = self.fault
            out["log_start"] = self.log_start
        if self.error:
            out["error"] = self.error
        return out


#: the name of the replay's closing record that counts the frames of the log stamped out of time order
#: (:func:`replay_can_log`)
OUT_OF_ORDER = "out_of_order"


def describe_out_of_order(frames: int, max_back_s: float) -> str:
    """``N frames out of time order by up to X ms, taken in file order`` (``max_back_s`` [s])."""
    what = "frames" if frames != 1 else "frame"
    return f"{frames} {what} out of time order by up to {max_back_s * 1000:.1f} ms, taken in file order"


#: source address of the replaying link (J1939: off-board diagnostic-service tool #1), so the
#: recorded planner's frames are read as another node's
REPLAY_ADDRESS = 249
#: the replaying link is polled at least this often through gaps of the log [s]
_REPLAY_STEP_S = 0.01


def _is_asc(path: Path) -> bool:
    suffixes = [x.lower() for x in path.suffixes]
    return suffixes[-1:] == [".asc"] or suffixes[-2:] == [".asc", ".gz"]


#: the fraction of a second in an ASC header date (``… 21:51:58.42 2026``)
_ASC_FRACTION = r"(:\d{2})\.(\d{1,3})(?=\s)"


class _AscReader(can.ASCReader):
    """python-can's ASC reader with absolute times read right: its writer puts the header's milliseconds
    unpadded (42 ms as ``58.42``) and its reader takes them as a fraction (``.42`` s), up to 0.9 s wrong; here
    one to three digits are milliseconds (CANoe writes three, where both readings agree). ``dated``: a header
    date was read (without one, python-can counts the times from 0 even when asked for absolute ones)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.dated = False

    def _datetime_to_timestamp(self, datetime_string: str) -> float:  # type: ignore[override]  # called on self
        import re

        fixed = re.sub(_ASC_FRACTION, lambda m: f"{m.group(1)}.{int(m.group(2)):03d}", datetime_string)
        t = can.ASCReader._datetime_to_timestamp(fixed)
        self.dated = True
        return t


def _reader(path: Path, wall: bool) -> tuple[Any, Iterator[can.Message]]:
    """python-can's reader of ``path`` and its frames; an ``.asc`` with absolute times (``wall``) — its reader's
    default are times relative to the header's date."""
    if not _is_asc(path):
        reader = can.LogReader(str(path))
    elif path.suffix.lower() == ".gz":
        import gzip

        reader = _AscReader(gzip.open(path, mode="rt"), relative_timestamp=not wall)
    else:
        reader = _AscReader(str(path), relative_timestamp=not wall)
    return reader, iter(reader)


@dataclass
class _Order:
    """Frames of a replayed log stamped before an earlier one (by more than the writers' rounding, by at most
    :data:`MAX_OUT_OF_ORDER_S`), taken in the file's order at the latest time: how many, the most one lay
    before [s] and the first one's number (1: the log's first frame)."""

    frames: int = 0
    max_back_s: float = 0.0
    first_frame: int = 0


def _frames(path: Path, clock: dict[str, bool] | None = None, order: _Order | None = None) -> Iterator[can.Message]:
    """The frames of a CAN log in time order; a :class:`BlackBoxError` naming the frame for what cannot be read
    (python-can's readers raise whatever their parsing meets: ValueError, UnicodeDecodeError, struct.error,
    BLFParseError …), for a timestamp that is not a finite number and for one that goes back in time by more than
    :data:`MAX_OUT_OF_ORDER_S` (two logs put together, a damaged file). A frame stamped before an earlier one by
    less — a bus's timestamp jitter, several senders stamping their own times (the product's own hub) — is
    yielded in the file's order at the latest time (its ``timestamp`` set to it) and counted in ``order``.

    Timestamps are Unix times: python-can's ASC reader gives times relative to the header's date unless asked
    for absolute ones (``relative_timestamp=False``: the header's date + the relative time), which it is; for an
    ``.asc`` whose header names no date it can parse, the times count from its start and ``clock["wall"]`` (if
    given) says False."""
    if not path.is_file():
        raise BlackBoxError(
            f"CAN log {path} is a folder: give one of its log files (.asc, .blf, .log, .csv)"
            if path.is_dir()
            else f"CAN log {path} is not a regular file (a device or a pipe): give a log file (.asc, .blf, .log, .csv)"
            if path.exists()
            else f"CAN log {path} does not exist"
        )
    if clock is None:
        clock = {}
    clock["wall"] = True
    try:
        source, reader = _reader(path, wall=True)
    except Exception as exc:  # noqa: BLE001 — as below: the BLF reader parses its header here
        raise BlackBoxError(f"CAN log {path}: cannot read ({first_line(exc)}); {_SUFFIX_HINT}") from None
    n, last = 0, -math.inf
    while True:
        try:
            msg = next(reader)
        except StopIteration:
            return
        except ValueError as exc:
            if n == 0 and clock["wall"] and _is_asc(path) and "datetime" in str(exc):
                clock["wall"] = False  # a header date the reader cannot parse: times from the log's start
                source, reader = _reader(path, wall=False)
                continue
            raise BlackBoxError(
                f"CAN log {path}: cannot read frame {n + 1} ({first_line(exc)}); {_SUFFIX_HINT}"
            ) from None
        except Exception as exc:  # noqa: BLE001 — a third-party parser on a damaged file: any of its errors
            raise BlackBoxError(
                f"CAN log {path}: cannot read frame {n + 1} ({first_line(exc)}); {_SUFFIX_HINT}"
            ) from None
        n += 1
        if n == 1 and not getattr(source, "dated", True):
            clock["wall"] = False  # an .asc without a header date: its times count from its start
        t = float(msg.timestamp)
        if not math.isfinite(t):
            raise BlackBoxError(f"CAN log {path}: frame {n} has timestamp {t}; a timestamp is a finite number of s")
        if t < last - MAX_OUT_OF_ORDER_S:
            raise BlackBoxError(
                f"CAN log {path}: frame {n} at {t:.6f} s goes back in time from {last:.6f} s, by {last - t:.6f} s "
                f"(more than the {MAX_OUT_OF_ORDER_S * 1000:.0f} ms of a bus's timestamp jitter: two logs put "
                "together or a damaged file? A log is replayed in time order)"
            )
        if t < last:  # jitter: taken in the file's order, at the latest time
            if order is not None and t < last - _BACKWARDS_TOLERANCE_S:
                order.frames += 1
                order.max_back_s = max(order.max_back_s, last - t)
                order.first_frame = order.first_frame or n
            msg.timestamp = last
        last = max(last, t)
        yield msg


#: how long after a log's first frame a missing measurement or heartbeat is the recording's start, not a fault
#: [s]: a few of the machine's own periods and limits (the stale limit 0.2 s, the heartbeat timeout 0.3 s); a
#: reading still missing later is a fault of the machine (a review: an ECU that never sent a heartbeat read as
#: "not a fault of the machine" through a whole log)
_LOG_START_S = 1.0


def replay_can_log(path: str | Path, model: Any, *, stale_after_s: float = 0.2) -> Iterator[ReplayRecord]:
    """Feed a recorded CAN log into a :class:`~bridge.link.can_link.CanLink` in the log's time.

    ``model`` is the :class:`~planner.model.kinematics.HitchModel` of the recorded machine. The
    link runs on a private virtual channel (it sends nowhere) with its own address
    (:data:`REPLAY_ADDRESS`), so every recorded node — the planner's references included — is
    read as traffic. Yields one :class:`ReplayRecord` per frame, and one ``fault`` / ``fault_cleared``
    per fault the link raises / clears (checked at least every 10 ms of log time, so a silence shows
    when its limit passed): the link's latched faults are compared step by step and acknowledged
    (:meth:`~bridge.link.can_link.CanLink.clear_faults`) as soon as their causes are gone, so a fault
    that comes back is raised again (an event fault — ``ecu_restart`` — is raised each time it happens).
    A stale measurement before the log's first complete measurement, or a missing ECU heartbeat before its
    first heartbeat, is marked ``log_start`` with a reason that says so.

    Frames stamped before an earlier frame by at most :data:`MAX_OUT_OF_ORDER_S` (timestamp jitter: the
    product's own hub, software-stamped loggers) are taken in the file's order at the latest time; a last record
    named :data:`OUT_OF_ORDER` (no source) counts them: ``fields`` ``frames``, ``max_back_s`` (the most one lay
    before [s]), ``first_frame`` (its number in the file, from 1), ``limit_s``; ``faults`` the sentence
    (:func:`describe_out_of_order`). A larger step back raises :class:`BlackBoxError` naming the frame and both
    times.
    """
    from bridge.isobus.codec import CodecError, load_codec
    from bridge.isobus.j1939 import J1939Error, decode_id
    from bridge.isobus.messages import Heartbeat, PositionMeasurement, RearHitchStatus
    from bridge.link.can_link import CanLink
    from bridge.link.realtime import open_bus
    from bridge.link.state import LinkConfig

    codec = load_codec()
    cfg = LinkConfig(source_address=REPLAY_ADDRESS, stale_after_s=stale_after_s)
    clock: dict[str, bool] = {}
    order = _Order()
    frames = _frames(Path(path), clock, order)
    bus = open_bus("virtual", f"hitch-replay-{uuid.uuid4().hex}")
    link = CanLink(model, bus, cfg, own_bus=True)
    heard: set[str] = set()  # of the log so far: "measurement", "lift", "heartbeat"
    latched: set[str] = set()  # the link's faults latched after the last acknowledge
    at_start: set[str] = set()  # of those, the ones raised at the log's start (below)
    t0 = 0.0

    def stamp(t: float) -> float | None:
        return t0 + t if clock.get("wall") else None

    def start_reason(name: str, t: float) -> str | None:
        """The plain reason of a fault raised at the log's start (within :data:`_LOG_START_S` of its first
        frame); None: a fault of the machine (an ECU that never sends is one, however the log began)."""
        if t > _LOG_START_S:
            return None
        if name == "stale_measurement" and link.latest_state() is None:
            missing = [
                what
                for key, what in (
                    ("measurement", f"cylinder positions (0xFF22) from the cylinder ECU (address {cfg.ecu_address})"),
                    ("lift", f"lift position (rear hitch status) from the tractor (address {cfg.hitch_source})"),
                )
                if key not in heard
            ]
            said = " and no ".join(missing) if missing else "valid measurement"
            return (
                f"log start: no {said} in the log yet ({t:.3f} s after its first frame), so no complete "
                "measurement — the recording began before it arrived; not a fault of the machine"
            )
        if name == "ecu_heartbeat" and "heartbeat" not in heard:
            return (
                f"log start: no ECU heartbeat (address {cfg.ecu_address}) in the log yet ({t:.3f} s after its "
                "first frame) — the recording began before it arrived; not a fault of the machine"
            )
        return None

    def changes(t: float) -> Iterator[ReplayRecord]:
        """Faults raised since the last step (by name, in the link's order), then acknowledged: those whose
        causes are gone (and every event fault) clear, and a clear is reported for each one latched before."""
        nonlocal latched
        faults = link.faults
        if t > _LOG_START_S:  # a start fault still held past the log's start is the machine's: said as such
            for name in sorted(at_start & latched):
                at_start.discard(name)
                what = "no complete measurement" if name == "stale_measurement" else "no ECU heartbeat"
                text = f"{what} still {t:.3f} s into the log: {faults.reason_of(name) or name}"
                yield ReplayRecord(t, None, "fault", faults=(text,), timestamp=stamp(t), fault=name)
        for name in faults.active():
            if name in latched:
                continue
            reason = faults.reason_of(name) or name
            plain = start_reason(name, t)
            if plain is not None:
                at_start.add(name)
            yield ReplayRecord(
                t, None, "fault", faults=(plain or reason,), timestamp=stamp(t), fault=name, log_start=plain is not None
            )
        now = set(link.clear_faults(t).active()) if faults.any else set()
        for name in faults.names():
            if name in latched and name not in now:
                start = name in at_start
                at_start.discard(name)
                if start:
                    what = "a complete measurement" if name == "stale_measurement" else "the ECU's heartbeat"
                    text = f"log start over: {what} in the log"
                else:
                    text = f"{name} cleared (its cause is gone)"
                yield ReplayRecord(
                    t, None, "fault_cleared", faults=(text,), timestamp=stamp(t), fault=name, log_start=start
                )
        latched = now

    try:
        link.start(-cfg.claim_wait_s - 0.01)
        link.poll(-0.001)  # the claim is made before the first recorded frame
        last = -0.001
        first = True
        for msg in frames:
            if first:
                t0, first = float(msg.timestamp), False
            t = round(float(msg.timestamp) - t0, 6)  # the logs' resolution: 1 µs (0.2, not 0.20000004768)
            try:
                source: int | None = decode_id(msg.arbitration_id).source_address if msg.is_extended_id else None
            except J1939Error:
                source = None
            step = max(_REPLAY_STEP_S, (t - last) / 1000.0)  # the link's checks run through gaps, bounded
            while last + step < t:
                last += step
                link.poll(last)
                yield from changes(last)
            last = max(last, t)
            state_before = link.latest_state()
            link.handle(msg, t)
            link.poll(t)
            error = ""
            try:
                payload: Any = codec.decode_frame(msg).payload
            except CodecError as exc:
                payload, error = None, str(exc) or type(exc).__name__
            else:
                if source == cfg.ecu_address and isinstance(payload, PositionMeasurement):
                    heard.add("measurement")
                if source == cfg.ecu_address and isinstance(payload, Heartbeat):
                    heard.add("heartbeat")
                if source == cfg.hitch_source and isinstance(payload, RearHitchStatus):
                    heard.add("lift")
            yield from changes(t)
            if error:
                name = "error_frame" if msg.is_error_frame else f"0x{msg.arbitration_id:08X}"
                yield ReplayRecord(t, source, name, error=error, timestamp=stamp(t))
                continue
            fields = asdict(payload) if is_dataclass(payload) and not isinstance(payload, type) else {}
            state = link.latest_state()
            pose = None
            if state is not None and state is not state_before:
                p = state.pose
                pose = {"x": float(p.x), "z": float(p.z), "roll": float(p.roll), "pitch": float(p.pitch)}
            yield ReplayRecord(t, source, type(payload).__name__, fields, pose, timestamp=stamp(t))
        if order.frames:
            yield ReplayRecord(
                last,
                None,
                OUT_OF_ORDER,
                {
                    "frames": order.frames,
                    "max_back_s": round(order.max_back_s, 6),
                    "first_frame": order.first_frame,
                    "limit_s": MAX_OUT_OF_ORDER_S,
                },
                faults=(describe_out_of_order(order.frames, order.max_back_s),),
                timestamp=stamp(last),
            )
    finally:
        link.close()
