"""CLI commands on the black box: ``hitch log [--follow]`` and ``hitch replay FILE``.

``hitch log`` prints the service's event log (``<data dir>/log/events.jsonl`` and its rotated
files, oldest first; :mod:`bridge.service.blackbox`): who asked what, accepted or refused,
faults and motion outcomes; ``--kind``, ``--key`` (a request's key or an event's name) and ``--since`` (a
duration ago or a local time) pick records. ``--follow`` then keeps printing new records (Ctrl-C ends it).
It first says on stderr which log file(s) it reads (and that the folder is the default one, shared by every run
of this user), so stdout stays the records (``--json``: one JSON object a line, its numbers exact). The text
lines round numbers to their resolution with the unit the field's name says (``duration=11.674 s``,
``depth_m=0.1235 m``, ``draft_n=12346 N``, a share such as ``speed_scale`` in %), poses in mm/mrad and a
``limit_reached`` event's limits in the operator's words (:func:`bridge.web.wording.limited_entries`).
``hitch replay FILE`` reads a CAN log recorded with ``hitch serve --can-log FILE`` (or any
``.asc``/``.blf``/candump ``.log`` of the same bus) into a CAN link and prints what it decodes:
references, measurements with the measured pose (the ECU's system state in words), the tractor's sensors,
heartbeats (``--all``) and every fault the link raises and clears in the log's time (a stale measurement or
missing heartbeat at the log's start, before the first one arrived, is said to be that and not counted). Each
message is printed at most once per ``--interval`` per sender (the bus carries some 400 frames a second),
``--only`` picks message names — for ``--json`` too; faults and frames that cannot be decoded are always
printed, and the closing line counts every frame and the faults raised and cleared, and the frames stamped out
of time order by a bus's jitter (up to 0.25 s back: the CAN hub's senders), taken in the file's order (``--json``:
a last record ``out_of_order``); a larger step back is refused, naming the frame. The first line says when
the log starts (local and Unix time), ``--clock`` puts each line's local time of day in front, and JSON
records carry ``timestamp`` (Unix s): to line a replay up with ``hitch log``.
"""

from __future__ import annotations

import argparse
import math
import re
import time
from collections.abc import Callable, Sequence
from enum import Enum
from pathlib import Path
from typing import Any

from bridge.cli.errors import CLIError
from bridge.cli.model import add_model_options, bounded_float, model_from_args, whole_number
from bridge.cli.output import console
from bridge.service.wire import to_json_text

__all__ = ["add_commands", "format_record"]

_QUIET_MESSAGES = frozenset({"Heartbeat", "AddressClaimed", "RequestPgn", "WheelBasedSpeed", "PressureMeasurement"})


def _when(t: Any) -> str:
    if not isinstance(t, (int, float)) or isinstance(t, bool):
        return "-"
    try:
        return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t)) + f".{int((t % 1) * 1000):03d}"
    except (OverflowError, OSError, ValueError):  # a damaged record's time (1e300, NaN): shown as it is
        return f"t={t!r}"


#: the fields of a pose [m, rad] and the unit each is shown in (a thousandth of it: mm, mrad)
_POSE_UNITS: dict[str, str] = {"x": "mm", "y": "mm", "z": "mm", "roll": "mrad", "pitch": "mrad", "yaw": "mrad"}
#: the controlled DOFs: what ``_where`` says of a measured pose
_CONTROLLED = ("x", "z", "roll", "pitch")


def _is_number(v: Any) -> bool:
    """An int or a float, not a bool."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _pose_parts(pose: dict[str, Any], names: Sequence[str]) -> list[str]:
    """``["x +12.0 mm", "roll -1.5 mrad", …]``: the fields ``names`` of a pose [m, rad] that are numbers, in
    mm and mrad (0.1 resolution)."""
    return [f"{n} {pose[n] * 1000:+.1f} {_POSE_UNITS[n]}" for n in names if _is_number(pose.get(n))]


def _where(rec: dict[str, Any]) -> str:
    """`` | at x … mm, z … mm, roll … mrad, pitch … mrad (measured … s before)`` from an event's
    ``measured_pose`` [m, rad] and ``measured_age_s``; "" without them (or with values that are no numbers)."""
    pose, age = rec.get("measured_pose"), rec.get("measured_age_s")
    if not isinstance(pose, dict):
        return ""
    parts = _pose_parts(pose, _CONTROLLED)
    if not parts:
        return ""
    ago = f" (measured {age:.3f} s before)" if _is_number(age) else ""
    return " | at " + ", ".join(parts) + ago


#: a field's unit by the end of its name, first match first (``_m_s`` before ``_s``): (suffix, factor to the
#: shown unit, shown unit, decimals); the service's events, requests and CAN frames name their units so
_SUFFIX_UNITS: tuple[tuple[str, float, str, int], ...] = (
    ("_m_s", 1.0, "m/s", 4),
    ("_rad_s", 1.0, "rad/s", 4),
    ("_ms", 1.0, "ms", 1),
    ("_mm", 1.0, "mm", 1),
    ("_s", 1.0, "s", 3),
    ("_m", 1.0, "m", 4),
    ("_rad", 1.0, "rad", 4),
    ("_deg", 1.0, "°", 2),
    ("_kg", 1.0, "kg", 1),
    ("_n", 1.0, "N", 0),
    ("_pa", 1e-5, "bar", 2),
    ("_hz", 1.0, "Hz", 2),
)
#: fields in seconds without a ``_s`` in their name (maneuver events, motion replies, the service's clock)
_SECONDS = frozenset({"duration", "elapsed", "timeout", "clock"})
#: fields that are a share of full [1]: shown in % (``speed_scale`` 0.5: 50 %)
_SHARES = frozenset({"progress", "speed_scale", "speed_factor", "front_axle_share"})
#: fields that hold a ``state.limited``-like map (limit or guard sentence by key): shown in words
_LIMIT_MAPS = frozenset({"limits", "limited", "control_limited"})


def _fixed(v: float, decimals: int) -> str:
    """``v`` with at most ``decimals`` decimals, trailing zeros dropped (``45``, ``11.674``), never ``-0``."""
    text = f"{round(v, decimals) + 0.0:.{decimals}f}"
    return text.rstrip("0").rstrip(".") if "." in text else text


def _unit_of(key: str) -> tuple[float, str, int] | None:
    """(factor, unit, decimals) of a field by its name, None when its name says no unit."""
    if key in _SECONDS:
        return 1.0, "s", 3
    for suffix, factor, unit, decimals in _SUFFIX_UNITS:
        if key.endswith(suffix):
            return factor, unit, decimals
    return None


def _number_text(key: str, v: float) -> str:
    """A number of field ``key`` rounded and with its unit (a share [1] in %); an int with no unit as it is,
    a float with no unit to 4 significant digits, a non-finite one as it is."""
    if not math.isfinite(v):
        return str(v)
    if key in _SHARES:
        return f"{_fixed(100.0 * v, 1)} %"
    unit = _unit_of(key)
    if unit is not None:
        factor, shown, decimals = unit
        return f"{_fixed(v * factor, decimals)} {shown}"
    return str(v) if isinstance(v, int) else f"{v:.4g}"


def _limits_text(limits: dict[Any, Any]) -> str:
    """A ``limit_reached`` event's ``limits`` (limit or guard sentence by key) in the operator's words, each with
    its code: ``[tilt cylinder (right lift rod) at its speed limit: slowed to 51 % (velocity:tilt)]``."""
    from bridge.web.wording import limited_entries

    return "[" + "; ".join(f"{w} ({k})" for k, w in limited_entries(limits)) + "]"


def _value_text(key: str, v: Any) -> str:
    """One field's value for the text output: numbers rounded with their unit (by the field's name), a pose in
    mm/mrad, limits in words, maps and lists without Python's quotes."""
    if isinstance(v, Enum):
        return v.name
    if _is_number(v):
        return _number_text(key, v)
    if isinstance(v, dict):
        if key in _LIMIT_MAPS and v:
            return _limits_text(v)
        if v and set(v) <= set(_POSE_UNITS) and all(_is_number(x) for x in v.values()):
            return "(" + ", ".join(_pose_parts(v, tuple(_POSE_UNITS))) + ")"
        return "(" + ", ".join(f"{k}={_value_text(str(k), x)}" for k, x in v.items()) + ")"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value_text(key, x) for x in v) + "]"
    return str(v)


def _fields_text(rec: dict[str, Any], skip: frozenset[str] | set[str]) -> str:
    """``k=v, k=v`` of a record's fields but ``skip``, each value by :func:`_value_text`."""
    return ", ".join(f"{k}={_value_text(k, v)}" for k, v in rec.items() if k not in skip)


#: an event logged this much after it happened [s] has both times shown
_LOGGED_LATE_S = 0.5


def _event_head(rec: dict[str, Any]) -> str:
    """An event's line starts with when it happened (``event_t``, the service's Unix time), and when it was
    logged too where that came later by more than :data:`_LOGGED_LATE_S` (a field trial: after a frozen service
    an abort, service_lost and a finish all showed the time they were written, 1 s after the abort)."""
    t, happened = rec.get("t"), rec.get("event_t")
    # the event's own time where it is the service's Unix time (before the log, at most an hour: older services
    # stamped some events with their control clock)
    if not (isinstance(happened, (int, float)) and isinstance(t, (int, float)) and _is_number(happened)):
        return f"{_when(t)} #{rec.get('seq', '-')} "
    if isinstance(t, bool) or not 0.0 <= float(t) - float(happened) <= 3600.0:
        return f"{_when(t)} #{rec.get('seq', '-')} "
    late = float(t) - float(happened) > _LOGGED_LATE_S
    return f"{_when(happened)} #{rec.get('seq', '-')} " + (f"(logged {_when(t)[11:]}) " if late else "")


def format_record(rec: dict[str, Any]) -> str:
    """One line of plain text for an event-log record."""
    kind = rec.get("kind")
    head = f"{_when(rec.get('t'))} #{rec.get('seq', '-')} "
    if kind == "request":
        who = rec.get("user") or "-"
        if rec.get("accepted"):
            what = "accepted" + (f" (motion {rec['motion_id']})" if rec.get("motion_id") is not None else "")
            if rec.get("read"):  # a writing key's request that changed nothing (``hitch work status``)
                what += " (read only, nothing changed)"
        else:
            what = f"REFUSED {rec.get('error')}: {rec.get('message', '')}"
        body = f" {rec['request']}" if rec.get("request") else ""
        return f"{head}request {rec.get('key')} by {who}{body}: {what}"
    if kind == "event":
        skip = {"t", "seq", "kind", "event", "event_t", "measured_pose", "measured_age_s"}
        rest = _fields_text(rec, skip)
        return f"{_event_head(rec)}event {rec.get('event')}" + (f": {rest}" if rest else "") + _where(rec)
    if kind in ("gap", "suppressed") and isinstance(rec.get("message"), str):  # their sentence says it all
        return f"{head}{kind}: {rec['message']}"
    rest = _fields_text(rec, {"t", "seq", "kind"})
    return f"{head}{kind}" + (f": {rest}" if rest else "")


def _reading_note(path: Path, files: Sequence[Path], *, default: bool, follow: bool) -> str:
    """The line ``hitch log`` says first (on stderr): which log it reads, its rotated files (oldest first: the
    order read) and, for the default folder, that it is one (``--data-dir`` names another)."""
    rotated = [f.name for f in files if f != path]
    more = f" and {len(rotated)} rotated file(s) before it ({', '.join(rotated)})" if rotated else ""
    where = " (the default data dir; --data-dir names another)" if default else ""
    then = ", then following it (Ctrl-C ends)" if follow else ""
    return f"(reading the event log {path}{more}{where}{then})"


def _cmd_log(args) -> int:
    from bridge.service.blackbox import event_log_path, follow_events, log_files, read_events
    from bridge.service.config import default_data_dir

    if args.data_dir is not None and not args.data_dir.is_dir():  # a typo'd folder: not an empty log
        raise CLIError(
            f"--data-dir {args.data_dir}: no such folder (the folder `hitch serve --data-dir` was given; "
            "default $XDG_DATA_HOME/hitch-planner)"
        )
    path = event_log_path(args.data_dir or default_data_dir())
    c = console(soft_wrap=True)
    if path.exists() or log_files(path):  # else the lines below say where it looked
        # on stderr: stdout stays the records (--json: one per line); a default folder may hold a stranger's run
        console(soft_wrap=True, stderr=True).print(
            _reading_note(path, log_files(path), default=args.data_dir is None, follow=args.follow),
            markup=False,
            highlight=False,
        )

    def show(rec: dict[str, Any]) -> None:
        if args.json:
            print(to_json_text(rec), flush=True)
        else:
            c.print(format_record(rec), markup=False, highlight=False)

    keep = _record_filter(args)
    every = read_events(path)
    records = [r for r in every if keep(r)]
    absent = not every and not path.exists()
    if absent:
        if not args.follow:  # --json: on stderr, stdout stays JSON lines (none)
            out = console(soft_wrap=True, stderr=True) if args.json else c
            out.print(f"(no event log at {path}; `hitch serve` writes it)", markup=False, highlight=False)
            return 0
        # said on stderr: --json output stays one record per line
        console(soft_wrap=True, stderr=True).print(
            f"(no event log at {path} yet; waiting for `hitch serve` to write it — Ctrl-C ends)",
            markup=False,
            highlight=False,
        )
    filtered = args.kind is not None or args.key is not None or args.since is not None
    if every and not records and filtered and not args.follow and not args.json:
        c.print(f"(no record of {path} matches --kind / --key / --since)", markup=False, highlight=False)
    for rec in records[-args.last :] if args.last else records:
        show(rec)
    if args.follow:
        try:
            for rec in follow_events(path, from_start=absent):  # a log that appears since: all of it
                if keep(rec):
                    show(rec)
        except KeyboardInterrupt:
            return 0
    return 0


#: the kinds of black-box record (bridge.service.blackbox): ``hitch log --kind``
RECORD_KINDS = ("request", "event", "service", "gap", "dropped", "suppressed", "unreadable")
_AGO = re.compile(r"^(\d+(?:\.\d+)?)\s*(s|min|m|h|d)$")
_AGO_S = {"s": 1.0, "m": 60.0, "min": 60.0, "h": 3600.0, "d": 86400.0}


def _names(what: str, allowed: Callable[[], Sequence[str]] | None = None):
    """argparse type: comma-separated names of ``what``; ``allowed()`` (read when an option is parsed: the codec's
    names load only then) lists the names allowed, None: any. argparse names the option."""

    def parse(text: str) -> frozenset[str]:
        names = [n.strip() for n in text.split(",") if n.strip()]
        known = None if allowed is None else tuple(allowed())
        unknown = [n for n in names if known is not None and n not in known]
        if not names or unknown:
            raise argparse.ArgumentTypeError(
                f"unknown {what} {', '.join(unknown) or '(none given)'}; allowed: "
                + (", ".join(known) if known is not None else "names separated by commas")
            )
        return frozenset(names)

    return parse


def _since(text: str) -> float:
    """argparse type for ``--since``: a duration ago (``90s``, ``10m``, ``2h``, ``1d``) or a local time
    (``2026-12-06 21:00``, ``…:30``, ``21:00`` today) → Unix time [s]."""
    t = text.strip()
    m = _AGO.match(t)
    if m:
        return time.time() - float(m.group(1)) * _AGO_S[m.group(2)]
    for fmt in ("%Y-%m-%d %H:%M:%S", "%Y-%m-%d %H:%M", "%Y-%m-%dT%H:%M:%S", "%Y-%m-%dT%H:%M", "%H:%M:%S", "%H:%M"):
        try:
            parsed = time.strptime(t, fmt)
        except ValueError:
            continue
        if fmt.startswith("%H"):  # today
            today = time.localtime()
            parsed = time.struct_time((today.tm_year, today.tm_mon, today.tm_mday, *parsed[3:6], 0, 0, -1))
        return time.mktime(parsed)
    raise argparse.ArgumentTypeError(
        f"{text!r}: a duration ago (90s, 10m, 2h, 1d) or a local time (2026-12-06 21:00[:30], 21:00)"
    )


def _record_filter(args):
    """The records ``hitch log`` shows: ``--kind``, ``--key`` (a request's key or an event's name), ``--since``."""
    kinds, keys, since = args.kind, args.key, args.since

    def keep(rec: dict[str, Any]) -> bool:
        if kinds is not None and rec.get("kind") not in kinds:
            return False
        if keys is not None and rec.get("key") not in keys and rec.get("event") not in keys:
            return False
        t = rec.get("t")
        return since is None or (isinstance(t, (int, float)) and t >= since)

    return keep


def _fmt_fields(fields: dict[str, Any]) -> str:
    """A decoded CAN frame's fields as ``k=v k=v``: enums by name, the ECU's system state in words, floats rounded
    with the unit their name says (:func:`_number_text`)."""
    from bridge.service.blackbox import describe_system_state

    out = []
    for k, v in fields.items():
        if isinstance(v, Enum):
            v = v.name
        elif k == "system_state" and isinstance(v, int) and not isinstance(v, bool):
            v = f"{v} ({describe_system_state(v)})"  # the ECU's bit field in words: watchdog tripped …
        elif isinstance(v, dict):
            v = "/".join(str(x) for x in v.values())
        elif isinstance(v, float):
            v = _number_text(k, v)  # rounded, with the unit its name says (x_m, latency_s, lift_pa …)
        out.append(f"{k}={v}")
    return " ".join(out)


def _local(t: float, fmt: str) -> str:
    """Local time ``t`` (Unix s) to the millisecond, rounded (``_when`` cuts: 1.16 would show as .159)."""
    secs, ms = divmod(round(t * 1000), 1000)
    try:
        return time.strftime(fmt, time.localtime(secs)) + f".{ms:03d}"
    except (OverflowError, OSError, ValueError):
        return f"t={t!r}"


def _time_of_day(t: float | None) -> str:
    """``--clock``: local time of day of a record (``-`` when the log has no date)."""
    return f"{'-':12}" if t is None else _local(t, "%H:%M:%S")


def _cmd_replay(args) -> int:
    from bridge.service.blackbox import OUT_OF_ORDER, replay_can_log

    model = model_from_args(args)
    c = console(soft_wrap=True)
    counts: dict[str, int] = {}
    raised = cleared = at_start = 0
    last_t: dict[tuple[str, int | None], float] = {}  # per message and sender: when it was last printed
    only: frozenset[str] | None = args.only
    started = False
    out_of_order = ""  # the replay's count of frames stamped out of time order (taken in file order), said last

    def shown(r) -> bool:
        """--only, --interval and --all pick the frames shown (text and JSON alike); faults and frames that
        cannot be decoded are always shown."""
        if r.name in ("fault", "fault_cleared") or r.error:
            return True
        if only is not None and r.name not in only:
            return False
        if not args.all:
            if only is None and r.name in _QUIET_MESSAGES:
                return False
            key = (r.name, r.source)
            if r.t_s - last_t.get(key, -float("inf")) < args.interval:
                return False
            last_t[key] = r.t_s
        return True

    def say(r, text: str) -> None:
        head = f"{_time_of_day(r.timestamp)}  " if args.clock else ""
        c.print(f"{head}{r.t_s:9.3f} s  {text}", markup=False, highlight=False)

    for r in replay_can_log(Path(args.file), model, stale_after_s=args.stale_after):
        if not started and not args.json:  # the log's wall-clock start, to line it up with `hitch log`
            started = True
            if r.timestamp is None:
                c.print(
                    "log starts at an unknown time (its header names no date; times below count from its first frame)",
                    markup=False,
                    highlight=False,
                )
            else:
                start = r.timestamp - r.t_s
                c.print(f"log starts {_local(start, '%Y-%m-%d %H:%M:%S')} ({start:.6f})", markup=False, highlight=False)
        if r.name == OUT_OF_ORDER:  # the closing count, no frame: in the closing line (--json: a last record)
            out_of_order = r.faults[0] if r.faults else ""
            if args.json:
                print(to_json_text(r.to_json()))
            continue
        if r.name == "fault":
            at_start += r.log_start
            raised += not r.log_start
        elif r.name == "fault_cleared":
            cleared += not r.log_start
        else:
            counts[r.name] = counts.get(r.name, 0) + 1
        if not shown(r):
            continue
        if args.json:
            print(to_json_text(r.to_json()))
            continue
        if r.name == "fault":
            for f in r.faults:
                say(r, f if r.log_start else f"FAULT {r.fault}: {f}")
        elif r.name == "fault_cleared":
            say(r, r.faults[0] if r.log_start and r.faults else f"CLEARED {r.fault}")
        elif r.error:
            say(r, f"{r.name} from {r.source}: not decoded ({r.error})")
        else:
            line = f"{r.name} from {r.source}: {_fmt_fields(dict(r.fields))}"
            if r.pose is not None:
                p = r.pose
                line += (
                    f"  -> pose x={p['x']:+.4f} m z={p['z']:+.4f} m roll={p['roll']:+.4f} rad "
                    f"pitch={p['pitch']:+.4f} rad"
                )
            say(r, line)
    if not counts:  # python-can's text readers skip what they cannot parse: say it, not "0 frames"
        size = Path(args.file).stat().st_size
        raise CLIError(
            f"CAN log {args.file} ({size} bytes): no CAN frame in it — a recording of a bus with no traffic, or "
            f"not a {Path(args.file).suffix or 'CAN'} log (its reader skips lines it cannot parse)"
        )
    if not args.json:
        c.print(
            f"{sum(counts.values())} frames: "
            + (", ".join(f"{n} {k}" for k, n in sorted(counts.items())) or "none")
            + f"; {raised} faults raised, {cleared} cleared"
            + (f" (and {at_start} at the log's start, before its first measurement or heartbeat)" if at_start else "")
            + (f"; {out_of_order}" if out_of_order else ""),
            markup=False,
            highlight=False,
        )
    return 0


def _codec_names() -> Sequence[str]:
    """The message names the codec knows (``hitch replay --only``)."""
    from bridge.isobus.codec import PAYLOAD_NAMES

    return PAYLOAD_NAMES


def add_commands(sub) -> None:
    p = sub.add_parser("log", help="the service's event log (black box): requests, faults, motion outcomes")
    p.add_argument("--follow", action="store_true", help="keep printing new records (Ctrl-C ends it)")
    p.add_argument(
        "--data-dir",
        type=Path,
        default=None,
        help="the service's data dir (default $XDG_DATA_HOME/hitch-planner, ~/.local/share/hitch-planner)",
    )
    p.add_argument(
        "--last", type=whole_number("--last"), default=0, help="print only the last N records first, N >= 0 (0: all)"
    )
    p.add_argument("--json", action="store_true", help="print the records as JSON lines")
    p.add_argument(
        "--kind",
        type=_names("kind", lambda: RECORD_KINDS),
        default=None,
        metavar="KINDS",
        help=f"only these record kinds, comma-separated: {', '.join(RECORD_KINDS)}",
    )
    p.add_argument(
        "--key",
        type=_names("key"),
        default=None,
        metavar="NAMES",
        help="only requests on these keys and events of these names, comma-separated (e.g. goto,stop,fault)",
    )
    p.add_argument(
        "--since",
        type=_since,
        default=None,
        metavar="WHEN",
        help="only records from then on: a duration ago (90s, 10m, 2h, 1d) or a local time (2026-12-06 21:00, 21:00)",
    )
    p.set_defaults(handler=_cmd_log)

    p = sub.add_parser("replay", help="replay a recorded CAN log (hitch serve --can-log) into a link, decoded")
    p.add_argument("file", help="the log: .asc, .blf or candump .log")
    p.add_argument("--all", action="store_true", help="every frame (heartbeats, claims, every measurement)")
    p.add_argument(
        "--interval",
        type=bounded_float("--interval", 0.0, 3600.0, unit="s", lo_open=False),
        default=0.1,
        help="print each message (per sender) at most this often, [0, 3600] s (default 0.1; --all: every frame)",
    )
    p.add_argument(
        "--only",
        type=_names("message", _codec_names),
        default=None,
        metavar="NAMES",
        help="print only these messages, comma-separated (e.g. PositionMeasurement,PositionCounts); faults always",
    )
    p.add_argument(
        "--stale-after",
        type=bounded_float("--stale-after", 0.0, 10.0, unit="s"),
        default=0.2,
        help="the link's stale-measurement limit, (0, 10] s (default 0.2, the service's)",
    )
    p.add_argument(
        "--clock",
        action="store_true",
        help="print each line's local time of day too (the log's own timestamps), to line it up with `hitch log`",
    )
    add_model_options(p)
    p.set_defaults(handler=_cmd_replay)
