"""CLI commands of the Zenoh service: run it, and talk to a running one.

``hitch serve`` runs the service (embedded defaults; flags or ``--config FILE.toml``).
Client commands talk to a running service over Zenoh, each with ``--connect ENDPOINT``
(default ``tcp/127.0.0.1:7447``), ``--prefix`` (default ``hitch``), ``--security FILE``
(the client's credentials / TLS CA) and ``--json``:

``hitch goto|jog|stop|mode|state [--follow]``, ``hitch preset save|list|go|delete``,
``hitch maneuver validate|save|list|run|delete``, ``hitch faults list|ack``, ``hitch fleet ls``.

A refused request (:class:`~bridge.service.client.ServiceError`) exits with status 2 and the
service's message on one line; no answer at all names the endpoint tried and says to start
``hitch serve`` (one that holds its liveliness token but does not answer is said to be busy or hung).
``goto``, ``preset go`` and ``maneuver run`` take ``--wait`` (until the motion or maneuver has ended: a motion
exits 0 only when its ``motion_finished`` event was heard; aborted, or its end not heard — the link to the
service interrupted, said as UNKNOWN — exits 1); Ctrl-C then stops the motion (a ``stop`` is sent and its answer
awaited, at most :data:`STOP_TIMEOUT_S`) unless ``--detach`` is given, which leaves the motion
running as it is. Text from the service is printed as it is (no rich markup or emoji codes).

``hitch serve --can-log FILE`` records the bus (:class:`~bridge.service.blackbox.CanRecorder`);
the service's black box (:class:`~bridge.service.blackbox.EventLog`) is always written to
``<data dir>/log/events.jsonl`` (``hitch log``).
"""

from __future__ import annotations

import argparse
import re
import signal
import sys
import threading
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from bridge.cli.errors import CLIError
from bridge.cli.model import bounded_float, bounded_int, finite_float, whole_number
from bridge.cli.output import console, esc, limited_text
from bridge.cli.plan import parse_pose_arg
from bridge.link.realtime import INTERFACES
from bridge.service.config import DEFAULT_LISTEN, load_service_config
from bridge.service.maneuvers.language import MIN_SPEED_SCALE
from bridge.service.maneuvers.steps import step_words
from bridge.service.schemas import DEFAULT_DEADLINE_MS, MAX_DEADLINE_MS
from bridge.service.wire import to_json_text
from planner.errors import HitchError
from planner.model.types import ACTUATOR_UNITS, CONTROLLED_POSE_UNITS
from planner.textfile import read_text_file

__all__ = ["add_commands", "STOP_TIMEOUT_S"]

#: the longest a Ctrl-C'd command waits for the answer to its ``stop`` [s]
STOP_TIMEOUT_S = 3.0
#: the longest ``maneuver run --wait`` waits (the service aborts a maneuver at its timeout, ≤ 3600 s)
_MANEUVER_WAIT_S = 3600.0 + 30.0


def _client(args):
    from bridge.service.client import HitchClient  # zenoh is imported only by the commands that use it

    asked = bool(getattr(args, "realtime", False))
    with warnings.catch_warnings():  # the client's RuntimeWarning is for programs: said plainly below
        warnings.simplefilter("ignore", RuntimeWarning)
        client = HitchClient(
            args.connect or [DEFAULT_LISTEN],
            prefix="hitch" if args.prefix is None else args.prefix,  # None: `fleet ls` without its filter
            timeout_s=args.timeout,
            security=args.security,
            # `hitch stop` asks for real-time priority whenever it is permitted (silent where it is not)
            realtime=asked or bool(getattr(args, "realtime_where_permitted", False)),
            user=getattr(args, "user", None),
        )
    if client.realtime_refused is not None and asked:
        print(f"--realtime: this client runs at ordinary priority: {client.realtime_refused}", file=sys.stderr)
    return client


def _print(args, reply: dict, text: str | None = None, *, markup: bool = False) -> None:
    """JSON with ``--json``, else ``text``: printed as it is, or as rich markup when ``markup`` (the
    caller escaped the data in it with :func:`~bridge.cli.output.esc`)."""
    if args.json:
        print(to_json_text(reply))
    else:
        console(soft_wrap=True).print(
            text if text is not None else to_json_text(reply, indent=1), markup=markup, highlight=False
        )


def _fmt_pose(p: dict | None) -> str:
    """A pose in SI with each value's unit: ``x=+0.0100 m  z=+0.1500 m  roll=+0.0000 rad …``."""
    if not p:
        return "-"
    return "  ".join(f"{k}={p[k]:+.4f} {u}" for k, u in CONTROLLED_POSE_UNITS.items() if k in p)


# ---------------------------------------------------------------------------------------- serve
def _cmd_serve(args) -> int:
    from bridge.service.server import serve  # zenoh + CAN + models only for the long-running job

    cfg = load_service_config(
        args.config,
        mode=args.mode,
        listen=args.listen,
        connect=args.connect,
        prefix=args.prefix,
        security=args.security,
        user_keys=True if args.user_keys else None,
        can_interface=args.can_interface,
        can_channel=args.can_channel,
        simulate_ecu=False if args.no_sim_ecu else None,
        sim_ground_speed=args.sim_ground_speed,
        sim_truth=args.sim_truth,
        sim_field=args.sim_field,
        sim_scenario=args.sim_scenario,
        profile=args.profile,
        category=args.category,
        implement=args.implement,
        control_rate=args.control_rate,
        state_rate=args.state_rate,
        data_dir=args.data_dir,
        http=args.http,
        http_hosts=tuple(args.http_host) if args.http_host else None,
        http_user=args.http_user,
        feedforward=False if args.no_feedforward else None,
        planning_processes=args.planning_processes,
        can_log=args.can_log,
        can_log_max_mb=args.can_log_max_mb,
        can_log_keep=args.can_log_keep,
    )
    from bridge.service.blackbox import CanRecorder, EventLog, ended_cleanly, event_log_path, last_record

    sys.setswitchinterval(5e-4)  # threads waiting for the GIL (the 50 Hz loop) wait ≤ 0.5 ms, not 5 ms
    if cfg.can_log is not None:  # refuse a bad suffix before anything starts (the recorder runs with the CAN buses)
        CanRecorder.check_path(cfg.can_log)
    blackbox: EventLog | None = None
    served: list[Any] = []  # the service, for what it holds at the stop (an unsaved teach-in recording)

    def ready(service) -> None:
        nonlocal blackbox
        served.append(service)
        reached = service.nodes_reached() if cfg.connect else None
        if reached == 0:  # a peer whose router is down starts serving locally (a new user's trial: "connected to")
            service.warnings.append(
                f"connect {', '.join(cfg.connect)}: not reached yet; the service serves locally and is watched from "
                "the first router it reaches (link_lost, on_link_loss)"
            )
        before = last_record(event_log_path(cfg.data_dir))
        blackbox = EventLog(event_log_path(cfg.data_dir))
        if not ended_cleanly(before):  # killed, crashed, power lost: its last motion has no outcome in the log
            assert before is not None
            blackbox.record(
                "service",
                what="previous_run_unclean",
                message=f"the previous run ended without a stop record (killed, crashed or power lost) after "
                f"record #{before.get('seq')}; what it did last has no outcome here",
                last_seq=before.get("seq"),
                last_t=before.get("t"),
            )
        blackbox.record(
            "service",
            what="started",
            prefix=cfg.prefix,
            listen=list(cfg.listen or ()),
            profile=cfg.profile,
            # the implement the guard plans with from the start (its implement_selected event came before the
            # black box: a restarted service's log did not say which: a field-scripting user's report)
            implement=getattr(getattr(service, "api", None), "implement", None),
            warnings=list(service.warnings),  # what the start said (its events came before the black box)
        )
        blackbox.attach(service)  # the service's own events, in-process (events it published before: a gap record)
        for w in service.warnings:
            print(f"hitch serve: warning: {w}", file=sys.stderr)
        http = getattr(service, "http", None)
        if http is not None:
            print(f"hitch serve: operator terminal at {http.url}", flush=True)
        link = (" connecting to " if reached == 0 else " connected to ") + ", ".join(cfg.connect) if cfg.connect else ""
        print(
            f"hitch serve: ready on {', '.join(cfg.listen or ()) or '(no listener)'}{link} prefix {cfg.prefix!r}, "
            f"profile {cfg.profile}{', twin truth ' + str(cfg.sim_truth) if cfg.sim_truth is not None else ''}, "
            f"data {cfg.database_path}, log {event_log_path(cfg.data_dir)}"
            + (f", CAN log {cfg.can_log}" if cfg.can_log is not None else ""),
            flush=True,
        )
        hint = access_check_hint(cfg)
        if hint is not None:
            print(f"hitch serve: {hint}", flush=True)

    why: str | None = None  # why serve ended other than by a signal (a control core that died …)
    from bridge.service.data_lock import DataDirLock

    # the data folder is this service's until its event log is closed below, after the service's own close (a
    # review: the service gave the lock up before the stop record was written, and a second one took the folder)
    cfg.data_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
    data_lock = DataDirLock(cfg.data_dir).acquire()
    try:
        took = serve(cfg, ready=ready, data_lock=data_lock)
    except BaseException as exc:
        why = f"{type(exc).__name__}: {exc}" if not isinstance(exc, KeyboardInterrupt) else None
        raise
    finally:
        if blackbox is not None:
            blackbox.summarize()  # the requests held back by the flood limits, counted before the stop record
            from bridge.service.maneuvers.recorder import discarded_recording

            lost = discarded_recording(getattr(served[0], "api", None)) if served else None
            if lost is not None:  # discarded without trace, before (a field user's report)
                blackbox.record("service", **lost)
            # the reason when it was not a stop signal (a killed control core read as a normal stop: a trial)
            blackbox.record("service", what="stopped", **({"reason": why} if why else {}))
            blackbox.close()
        data_lock.release()
    print(f"hitch serve: stopped in {took * 1000:.0f} ms", flush=True)
    args.end_process = True  # everything is closed: the program ends here (bridge.cli.main)
    return 0


def _add_serve(sub) -> None:
    p = sub.add_parser("serve", help="run the Zenoh service (simulated ECU on a virtual CAN bus by default)")
    p.add_argument("--config", default=None, help="TOML config file (flags override it)")
    p.add_argument("--mode", choices=("peer", "client"), default=None, help="Zenoh mode (default peer)")
    p.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"listen endpoint (repeatable; default {DEFAULT_LISTEN})",
    )
    p.add_argument("--connect", action="append", default=None, metavar="ENDPOINT", help="connect endpoint (repeatable)")
    p.add_argument("--prefix", default=None, help="key prefix (default hitch; a fleet: fleet/t07/hitch)")
    p.add_argument("--security", default=None, help="Zenoh security config (JSON5: usrpwd, access_control, TLS)")
    p.add_argument(
        "--user-keys",
        action="store_true",
        help="serve each user's own keys <prefix>/user/<name>/<key> (default: only when --security's access "
        "control checks them; behind a router whose access control does, say so here; docs/security.md)",
    )
    p.add_argument(
        "--can-interface",
        choices=INTERFACES,
        default=None,
        help="python-can interface (default virtual: this process's channel, with the simulated ECU; "
        "remote: a CAN hub on this computer, `hitch can-hub`; socketcan: a real bus)",
    )
    p.add_argument("--can-channel", default=None, help="CAN channel (default hitch)")
    p.add_argument("--no-sim-ecu", action="store_true", help="do not run the simulated ECU in this process")
    p.add_argument(
        "--no-feedforward",
        action="store_true",
        help="stream the plan's actuator positions as they are, not the unit loops' feed-forward reference",
    )
    p.add_argument(
        "--sim-ground-speed",
        type=finite_float("--sim-ground-speed"),
        default=None,
        help="m/s of the simulated tractor (wheel-based speed for maneuver wait_for; default 1.5)",
    )
    p.add_argument(
        "--sim-truth",
        default=None,
        metavar="FILE",
        help="the simulated machine's own true profile (hitch sim perturb); default: the planner's profile",
    )
    p.add_argument(
        "--sim-scenario",
        default=None,
        metavar="SCENARIO",
        help="the simulated tractor drives over this track scenario's terrain, slope and row signal (a built-in "
        "name: levelling, levelling-inside, guidance, terrain, flat; or a .toml file; docs/tracking.md); "
        "default: flat ground",
    )
    p.add_argument(
        "--sim-field",
        default=None,
        metavar="FIELD",
        help="the simulated tractor drives over this field, its draft on the draft pins (a built-in name or a .toml "
        "file; docs/soil.md); not with --sim-scenario",
    )
    p.add_argument("--profile", default=None, help="hitch profile (default thesis-t132)")
    p.add_argument("--category", default=None, help="ISO 730 category (default: the profile's)")
    p.add_argument(
        "--implement",
        default=None,
        help="implement record of the tractor profile, for this start: it comes before the persisted selection, "
        "which comes before the config file's (presets are per implement; docs/implements.md)",
    )
    p.add_argument("--control-rate", type=finite_float("--control-rate"), default=None, help="Hz, 10..200 (default 50)")
    p.add_argument("--state-rate", type=finite_float("--state-rate"), default=None, help="Hz, 1..100 (default 50)")
    p.add_argument(
        "--data-dir",
        type=Path,
        default=None,
        help="presets and maneuvers (default $XDG_DATA_HOME/hitch-planner, ~/.local/share/hitch-planner)",
    )
    p.add_argument(
        "--http", default=None, metavar="HOST:PORT", help="also serve the operator terminal (off by default)"
    )
    p.add_argument(
        "--http-host",
        action="append",
        default=None,
        metavar="HOST:PORT",
        help="a further name the terminal is reached by, e.g. cab-display.local:8080 (repeatable; its address "
        "and loopback always work; other names are refused: DNS-rebinding protection)",
    )
    p.add_argument(
        "--http-user",
        default=None,
        metavar="USER",
        help="user the terminal runs as without a login (security files with users require a login; ignored then)",
    )
    p.add_argument(
        "--planning-processes",
        type=int,
        default=None,
        metavar="N",
        help="processes for plan previews, maneuver validation and IK, 0..32 (default 2; 0: in the service's threads)",
    )
    p.add_argument(
        "--can-log",
        default=None,
        metavar="FILE",
        help="record every CAN frame to FILE (.asc, .blf, candump .log or .csv; replay with `hitch replay FILE`); "
        "rotated by size: FILE is the newest, FILE's stem .1 the one before …",
    )
    p.add_argument(
        "--can-log-max-mb",
        type=float,
        default=None,
        metavar="MB",
        help="size of one CAN log file in megabytes (10^6 bytes), 0.1..100000 (default 50)",
    )
    p.add_argument(
        "--can-log-keep",
        type=int,
        default=None,
        metavar="N",
        help="rotated CAN log files kept, 1..1000 (default 10; the oldest beyond them is deleted)",
    )
    p.set_defaults(handler=_cmd_serve)


# ---------------------------------------------------------------------------------------- clients
#: ``hitch fleet ls --prefix``: a filter, not one service's prefix
FLEET_PREFIX_HELP = (
    "list only the services whose key prefix is this one or under it, e.g. fleet or fleet/t07/hitch (default: every "
    "service)"
)
#: the namespace attribute of ``--connect`` given before a group's action (merged into ``connect``)
OUTER_CONNECT = "outer_connect"
#: the namespace attribute holding the client options' defaults (applied by the top-level parser after parsing)
CLIENT_OPTION_DEFAULTS = "client_option_defaults"


def _client_options(p, *, prefix_help: str | None = None, outer: bool = False) -> None:
    """The options every client command has; ``prefix_help``: ``--prefix`` is a filter with this help and no
    default (``hitch fleet ls``), not the one service's prefix.

    ``outer``: the same options on a group's parser, so they may also stand before the action
    (``hitch faults --connect X list``, as ``hitch faults list --connect X``; given at both, the action's
    wins, but ``--connect`` endpoints given at both are all taken). Their defaults are therefore not
    argparse's (a subcommand's default would override the value given before it): they are recorded under
    :data:`CLIENT_OPTION_DEFAULTS` and applied by the top-level parser (:func:`apply_client_option_defaults`)
    to what neither place gave."""
    defaults: dict[str, Any] = {}

    def option(*flags: str, default: Any, **kwargs: Any) -> None:
        action = p.add_argument(*flags, default=argparse.SUPPRESS, **kwargs)
        defaults[action.dest] = default

    option(
        "--connect",
        **({"dest": OUTER_CONNECT} if outer else {}),  # endpoints given at both levels are all taken
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"service or router endpoint (repeatable; default {DEFAULT_LISTEN})",
    )
    if prefix_help is None:
        option("--prefix", default="hitch", help="key prefix of the service (default hitch)")
    else:
        option("--prefix", default=None, help=prefix_help)
    option("--security", default=None, help="Zenoh security config of this client (credentials, TLS CA)")
    option(
        "--user",
        default=None,
        help="send the requests as this user, on its own keys where the service serves them (default: the user "
        "--security logs in as; '' for the shared keys; docs/security.md)",
    )
    option(
        "--timeout",
        type=bounded_float("--timeout", 0.0, 600.0, unit="s"),
        default=5.0,
        help="seconds to wait for a reply, (0, 600] (default 5)",
    )
    option(
        "--realtime",
        action="store_true",
        default=False,
        help="run this client's Zenoh threads under SCHED_FIFO (needs root or CAP_SYS_NICE): on a busy "
        "computer its stop (the stop command, Ctrl-C) leaves at once instead of after the busy programs' turn",
    )
    option("--json", action="store_true", default=False, help="print JSON")
    if not outer:
        p.set_defaults(**{CLIENT_OPTION_DEFAULTS: defaults})


def apply_client_option_defaults(args: argparse.Namespace) -> argparse.Namespace:
    """Give a parsed client command the defaults of the client options neither its action nor its group got
    (:func:`_client_options`); other commands are returned as they are."""
    outer = getattr(args, OUTER_CONNECT, None)
    if outer is not None:  # --connect before the action and after it: every endpoint, in the order given
        args.connect = [*outer, *(getattr(args, "connect", None) or [])]
        delattr(args, OUTER_CONNECT)
    for dest, value in getattr(args, CLIENT_OPTION_DEFAULTS, {}).items():
        if not hasattr(args, dest):
            setattr(args, dest, list(value) if isinstance(value, list) else value)
    return args


def _client_command(sub, name: str, help_text: str, handler, *positionals: str):
    """Sub-command ``name`` of ``sub`` that calls the service: its ``positionals``, the client options
    and ``handler``; the parser (more arguments may follow)."""
    p = sub.add_parser(name, help=help_text)
    for positional in positionals:
        p.add_argument(positional)
    _client_options(p)
    p.set_defaults(handler=handler)
    return p


def add_deadline_option(
    p, meaning: str = "the motion must start within this, else the service refuses it busy (never runs it later)"
) -> None:
    """``--deadline-ms`` (the request's ``deadline_ms``; None: the service's default)."""
    p.add_argument(
        "--deadline-ms",
        type=bounded_int("--deadline-ms", 1, MAX_DEADLINE_MS, unit="ms"),
        default=None,
        help=f"{meaning}; [1, {MAX_DEADLINE_MS}] ms, the service's default {DEFAULT_DEADLINE_MS}",
    )


def _wait_options(p) -> None:
    p.add_argument(
        "--wait",
        action="store_true",
        help="wait until the motion has ended (exit status 1 when it was aborted or its end was not heard); "
        "Ctrl-C (or SIGTERM: a supervisor, `timeout`) then stops it",
    )
    p.add_argument(
        "--detach", action="store_true", help="with --wait: Ctrl-C (or SIGTERM) only stops waiting, the motion goes on"
    )
    add_deadline_option(p)
    p.set_defaults(term_interrupts=True)  # SIGTERM is taken as Ctrl-C: the motion is stopped (bridge.cli.main)


def _deadline(args) -> dict[str, int]:
    """``{"deadline_ms": …}`` when given on the command line, else {} (the service's default)."""
    d = getattr(args, "deadline_ms", None)
    return {} if d is None else {"deadline_ms": int(d)}


def _alive(c, timeout_s: float = 1.0) -> bool:
    """Does a service with the client's prefix hold its liveliness token?"""
    try:
        for reply in c.session.liveliness().get(f"{c.prefix}/alive", timeout=timeout_s):
            if reply.ok is not None:
                return True
    except Exception:  # noqa: BLE001 — the session is closing: nothing is known
        return False
    return False


def _service_down(args, exc: Exception) -> CLIError:
    tried = ", ".join(args.connect or [DEFAULT_LISTEN])
    why = re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(exc)).strip()  # Zenoh's source location is noise here
    secured = (
        f"; with --security {args.security}: the user and password may be refused there, its certificate may be "
        "refused (a client certificate needs version 3 and extendedKeyUsage=clientAuth: sign it with -extfile, "
        "docs/security.md §4), or the access list may not let this user see that service"
        if getattr(args, "security", None)
        else "; a service with access control answers only clients with credentials: give them with --security FILE"
    )
    prefix = getattr(args, "prefix", None)  # None: `fleet ls` without its filter (it said "prefix None")
    which = "no hitch service" if prefix is None else f"no hitch service with prefix {prefix!r}"
    return CLIError(
        f"{why} — {which} answers at {tried}; start one with "
        f"`hitch serve` (it listens on {DEFAULT_LISTEN} by default) or give its endpoint with --connect ENDPOINT"
        + secured
    )


def _run(args, fn) -> int:
    from bridge.service.client import ServiceError, ServiceTimeout

    try:
        with _client(args) as c:
            try:
                return fn(c)
            except ServiceTimeout as exc:
                if _alive(c):  # the service is up: slow, or this user may not use that key
                    if getattr(exc, "timeout_s", None) is not None:  # its query went out, no answer came
                        raise ServiceTimeout(
                            f"{exc}; the service holds its liveliness token {c.prefix}/alive — it is up but did not "
                            f"answer within {exc.timeout_s:g} s: busy or hung",
                            timeout_s=exc.timeout_s,
                        ) from None
                    raise
                raise _service_down(args, exc) from None
    except ServiceError as exc:
        if exc.code == "connect":  # no router or service accepted the session
            raise _service_down(args, exc) from None
        raise


def _stop_after_interrupt(c, motion_id: object) -> None:
    """Ctrl-C (or SIGTERM) during a motion command: send ``stop`` and wait (bounded) for its answer; a second
    Ctrl-C or SIGTERM meanwhile is ignored, so the stop is not cut short."""
    from bridge.service.client import ServiceError

    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    # a second SIGTERM (taken as Ctrl-C while the command ran: bridge.cli.main) would cut the stop short too
    old_term = signal.signal(signal.SIGTERM, signal.SIG_IGN)
    t0 = time.monotonic()
    try:
        r = c.request("stop", {}, timeout_s=STOP_TIMEOUT_S)
        print(
            f"hitch: interrupted: stop sent (motion {r.get('motion_id', motion_id)}), "
            f"answered in {(time.monotonic() - t0) * 1000:.0f} ms",
            file=sys.stderr,
            flush=True,
        )
    except ServiceError as exc:
        print(
            f"hitch: interrupted: the stop was not confirmed ({exc}); stop the hitch another way (`hitch stop`, STOP)",
            file=sys.stderr,
            flush=True,
        )
    finally:
        signal.signal(signal.SIGINT, old)
        signal.signal(signal.SIGTERM, old_term)


def _motion(args, c, start: Callable[[], dict], wait: Callable[[dict], dict]) -> tuple[dict, dict | None]:
    """Start a motion (``start()`` → the reply) and, with ``--wait``, wait for its end (``wait(reply)``).

    Ctrl-C (while starting or waiting) sends ``stop`` unless ``--detach``; then KeyboardInterrupt
    goes on up (exit status 130).
    """
    reply: dict | None = None
    # the events and states of the motion from its start on (its outcome may come before a wait subscribes)
    watch = _MotionWatch(c) if args.wait else None
    args.motion_watch = watch
    try:
        reply = start()
        if args.wait and not getattr(args, "json", False):  # said at once: the wait may be long
            planned = reply.get("duration")
            plan = f", planned {planned:.2f} s" if isinstance(planned, (int, float)) else ""
            stop = "the motion goes on" if args.detach else "stops it"
            print(f"started (id {reply.get('motion_id')}{plan}); waiting for the end (Ctrl-C: {stop})", flush=True)
        return reply, (wait(reply) if args.wait else None)
    except KeyboardInterrupt:
        if args.detach:
            if reply is not None:
                print(
                    f"hitch: interrupted: motion {reply.get('motion_id')} goes on (--detach)",
                    file=sys.stderr,
                    flush=True,
                )
        else:
            _stop_after_interrupt(c, None if reply is None else reply.get("motion_id"))
        raise
    finally:
        args.motion_watch = None
        if watch is not None:
            watch.close()


#: a pose this far from the goal [m, rad] is "away from the goal" in the words on an unknown outcome
GOAL_TOLERANCE = 0.005
#: consecutive state samples further apart than this [s] mean samples were missed (the link interrupted)
STATE_GAP_S = 2.0


class _MotionWatch:
    """The ``events`` and ``state`` samples a motion command hears from before its request on: the outcome event of
    its motion (``motion_finished`` / ``motion_aborted``), the motion's goal, and whether samples were missed on
    the way (a gap in the events' or states' numbers, or in the states' time: the link to the service was
    interrupted), so that a missing outcome is said as unknown, never taken for a success (a fleet trial)."""

    def __init__(self, c) -> None:
        self.lock = threading.Lock()
        self.heard = threading.Event()
        self.motion_id: int | None = None
        self.events: list[dict] = []  # before the motion id is known (the reply), every motion event
        self.outcome: dict | None = None
        self.goal: dict | None = None
        self.state: dict | None = None
        self.missed_events = 0
        self.missed_states = 0
        self.gap_s = 0.0  # the longest time between two state samples beyond STATE_GAP_S [s]
        self._event_seq: int | None = None
        self._state_seq: int | None = None
        self._state_t: float | None = None
        self._subs = [c.subscribe("events", self.on_event), c.subscribe("state", self.on_state)]

    def close(self) -> None:
        for sub in self._subs:
            close = getattr(sub, "close", None)
            if callable(close):
                close()
        self._subs = []

    def watch(self, motion_id: int) -> None:
        with self.lock:
            self.motion_id = motion_id
            for e in self.events:
                self._take(e)
            self.events = []

    def on_event(self, e: dict) -> None:
        if not isinstance(e, dict):
            return
        with self.lock:
            n = e.get("seq")
            if isinstance(n, int) and not isinstance(n, bool):
                last = self._event_seq
                if last is not None and n != last + 1:  # skipped numbers, or the service restarted (fewer)
                    self.missed_events += max(1, n - last - 1)
                self._event_seq = n
            if self.motion_id is None:
                if e.get("motion_id") is not None:
                    self.events.append(e)
                return
            self._take(e)

    def _take(self, e: dict) -> None:
        if e.get("motion_id") != self.motion_id:
            return
        if e.get("event") == "motion_started" and isinstance(e.get("goal"), dict):
            self.goal = dict(e["goal"])
        if e.get("event") in ("motion_finished", "motion_aborted") and self.outcome is None:
            self.outcome = dict(e)
            self.heard.set()

    def on_state(self, st: dict) -> None:
        if not isinstance(st, dict):
            return
        with self.lock:
            self.state = st
            n, t = st.get("seq"), st.get("t")
            if isinstance(n, int) and not isinstance(n, bool):
                if self._state_seq is not None and n != self._state_seq + 1:
                    self.missed_states += max(1, n - self._state_seq - 1)
                self._state_seq = n
            if isinstance(t, (int, float)) and not isinstance(t, bool):
                if self._state_t is not None and t - self._state_t > STATE_GAP_S:
                    self.gap_s = max(self.gap_s, t - self._state_t)
                self._state_t = float(t)
            goal = st.get("goal")
            if st.get("motion_id") == self.motion_id and isinstance(goal, dict) and isinstance(goal.get("pose"), dict):
                self.goal = dict(goal["pose"])


def _wait_motion(args, c, r: dict) -> dict:
    """Wait until motion ``r["motion_id"]`` has ended: the pose then and its ``outcome`` event
    (``motion_finished`` or ``motion_aborted`` with the reason; None if none was heard, and then ``unknown``:
    why its outcome is not known — never a success)."""
    from bridge.service.client import ServiceTimeout

    mid = r["motion_id"]
    pre: _MotionWatch | None = getattr(args, "motion_watch", None)
    own = pre is None
    # not started through _motion: subscribed now (an outcome before this is missed)
    watch = _MotionWatch(c) if pre is None else pre
    watch.watch(mid)
    lost: str | None = None
    try:
        try:
            st = c.wait_motion(mid, timeout_s=max(args.timeout, float(r.get("duration", 0.0)) + 10.0))
        except ServiceTimeout as exc:
            if not getattr(exc, "link_lost", False):
                raise
            lost, st = str(exc), {}
        if lost is None:
            watch.heard.wait(1.0)  # the outcome follows the state that shows the end
        with watch.lock:
            outcome = dict(watch.outcome) if watch.outcome else None
            if not st and watch.state:
                st = dict(watch.state)
            unknown = None if outcome is not None else _unknown_outcome(args, watch, mid, st, lost)
    finally:
        if own:
            watch.close()
    final = {"pose": st.get("pose"), "motion_id": st.get("motion_id"), "moving": st.get("moving"), "outcome": outcome}
    if unknown is not None:
        final["unknown"] = unknown
    if lost is not None:  # the pose is the last one heard before the link was lost
        final["link_lost"] = True
    return final


def _unknown_outcome(args, watch: _MotionWatch, mid: int, st: dict, lost: str | None) -> str:
    """Why the outcome of motion ``mid`` is not known, and what the service's state shows instead (under the
    watch's lock)."""
    if lost is not None:
        why = lost
    else:
        why = "its end event (motion_finished / motion_aborted) was not heard"
        gaps = []
        if watch.missed_events:
            gaps.append(f"{watch.missed_events} event(s)")
        if watch.missed_states:
            gaps.append(f"{watch.missed_states} state sample(s)")
        if watch.gap_s:
            gaps.append(f"no state for {watch.gap_s:.1f} s")
        if gaps:
            why += f": events were missed ({', '.join(gaps)}): the link to the service was interrupted"
        else:
            why += ": it may have been missed (e.g. the link to the service was interrupted)"
    shows = []
    state = (
        "the last state heard (before the link was lost) showed" if lost is not None else "the service's state shows"
    )
    now_mid = st.get("motion_id")
    if isinstance(now_mid, int) and now_mid != mid:
        shows.append(f"{state} motion {now_mid}, not {mid} (it was replaced or aborted)")
    elif st.get("moving"):
        shows.append(f"{state} motion {mid} still moving")
    goal = watch.goal or (args.to if isinstance(getattr(args, "to", None), dict) else None)
    pose = st.get("pose") or {}
    if goal and pose:
        away = {
            k: float(pose[k]) - float(v)
            for k, v in goal.items()
            if k in CONTROLLED_POSE_UNITS and k in pose and isinstance(v, (int, float))
        }
        far = {k: g for k, g in away.items() if abs(g) > GOAL_TOLERANCE}
        if far:
            shows.append(
                f"the hitch {'was' if lost is not None else 'is'} away from the goal ("
                + ", ".join(f"{k} {g:+.4f} {CONTROLLED_POSE_UNITS[k]}" for k, g in far.items())
                + ": pose minus goal)"
            )
        elif away:
            shows.append(f"the hitch {'was' if lost is not None else 'is'} at the goal")
    return why + ("; " + "; ".join(shows) if shows else "") + " — see the service's black box (`hitch log`)"


def _ended(final: dict | None) -> tuple[str, int]:
    """The text and exit status for how an awaited motion ended: 0 only when its ``motion_finished`` event was
    heard; aborted (a stop, a fault, a replacing command) is said with the service's reason and exits 1; an
    outcome not heard (events missed: the link to the service interrupted) is said as UNKNOWN and exits 1."""
    if final is None:
        return "", 0
    where = f"; now at {_fmt_pose(final['pose'])}" if final.get("pose") else ""
    out = final.get("outcome") or {}
    if out.get("event") == "motion_aborted":
        return f"; ABORTED: {out.get('reason') or 'no reason given'}{where}", 1
    if out.get("event") == "motion_finished":
        return f"; finished{where}", 0
    why = final.get("unknown") or "its end event (motion_finished / motion_aborted) was not heard"
    if final.get("link_lost") and final.get("pose"):
        where = f"; last heard at {_fmt_pose(final['pose'])}"
    return f"; outcome UNKNOWN: {why}{where}", 1


def _cmd_goto(args) -> int:
    def go(c) -> int:
        r, final = _motion(
            args,
            c,
            lambda: c.goto(args.to, args.speed_scale, **_deadline(args)),
            lambda reply: _wait_motion(args, c, reply),
        )
        if final is not None:
            r = {**r, "final": final}
        ended, status = _ended(final)
        _print(
            args,
            r,
            f"motion {r['motion_id']} accepted, {r['duration']:.2f} s"
            + (f" (slowed x{r['speed_factor']:.2f}{_by(r)})" if r["speed_factor"] < 1 else "")
            + ended,
        )
        return status

    return _run(args, go)


def _by(reply: Mapping[str, Any]) -> str:
    """What slowed a goto, from its reply's ``limited`` (``{measure: "caution: sentence"}``): " by <sentence>; …"
    ("motion 11 accepted, 4.96 s (slowed x0.80)" named no limit, an operator's trial; the reply did)."""
    limited = reply.get("limited") or {}
    said = [str(v).split(": ", 1)[-1] for v in limited.values()]
    return f" by {'; '.join(said)}" if said else ""


def jog_refresh_period(ttl_ms: float) -> float:
    """How often a held jog is sent again [s]: 100 ms, or half its ttl when that is shorter."""
    return min(0.1, ttl_ms / 2000.0)


def _refresh_until(refresh: Callable[[], dict], last: dict, end: float, period_s: float) -> dict:
    """Call ``refresh`` on a fixed grid of ``period_s`` until ``end`` (``time.monotonic()``); the last reply. A
    refresh that came late is followed by the next at once on a new grid — not ``period_s`` after the late reply
    (a fixed sleep after each reply added the reply's own time to every period, and a late one's delay to the
    next)."""
    due = time.monotonic() + period_s
    while due <= end:  # the last one at the end: the jog holds until ttl after it, as long as asked
        time.sleep(max(0.0, due - time.monotonic()))
        last = refresh()
        due = max(due + period_s, time.monotonic())
    return last


def _cmd_jog(args) -> int:
    rates = (args.vx, args.vz, args.vroll, args.vpitch)
    if all(r is None for r in rates):  # a zero-rate jog holds; asked for by an explicit 0, never by omission
        raise CLIError("jog: give at least one rate: --vx, --vz [m/s], --vroll, --vpitch [rad/s] (0 holds)")
    args.vx, args.vz, args.vroll, args.vpitch = (0.0 if r is None else r for r in rates)

    def jog(c) -> int:
        r: dict = {}
        ids: list[Any] = []  # the jog's motions: a second one means it lapsed between two refreshes

        def refresh() -> dict:
            reply = c.jog(args.vx, args.vz, args.vroll, args.vpitch, args.ttl_ms)
            if not ids or ids[-1] != reply["motion_id"]:
                ids.append(reply["motion_id"])
            return reply

        try:
            r = refresh()
            r = _refresh_until(refresh, r, time.monotonic() + (args.duration or 0.0), jog_refresh_period(args.ttl_ms))
        except KeyboardInterrupt:  # brake now, as goto --wait does (before: silent, braked by the ttl ~0.7 s later)
            _stop_after_interrupt(c, ids[-1] if ids else r.get("motion_id"))  # the jog's latest motion (a review)
            raise
        limited = ", ".join(f"{k} by {v}" for k, v in (r.get("limited") or {}).items())
        text = f"jog motion {r['motion_id']}" + (f", limited: {limited}" if limited else "")
        if len(ids) > 1:  # a field trial: one gap of 297 ms under load split it in two, the CLI said only the last
            text = (
                f"jog motions {', '.join(map(str, ids))}: it lapsed {len(ids) - 1} time(s) — a refresh came later "
                f"than its ttl {args.ttl_ms:g} ms (a busy computer: --realtime, or a longer --ttl-ms) and the hitch "
                "braked before it went on" + (f"; limited: {limited}" if limited else "")
            )
        if r.get("guard") == "refused":  # the jog holds: nothing moves (a re-run: "jog motion 95, limited: …", exit 0)
            _print(
                args,
                r,
                f"jog refused by the guard at its last refresh (motion {r['motion_id']} holds the hitch)"
                + (f": {limited}" if limited else ""),
            )
            return 1
        _print(args, r, text)
        return 0

    return _run(args, jog)


def access_check_hint(cfg: Any) -> str | None:
    """What to check after a start behind a router with access control (``security`` and ``connect``), else None:
    the router drops what this login may not declare without telling the service (a fleet trial: a service whose
    prefix the router's policy did not give its login said ready, and nobody could see or stop it)."""
    if cfg.security is None or not cfg.connect:
        return None
    return (
        f"behind a router with access control, check the fleet sees this service: hitch fleet ls --connect "
        f"{cfg.connect[0]} --prefix {cfg.prefix} --security OPERATOR.json5 must list it (docs/security.md)"
    )


def _cmd_stop(args) -> int:
    def stop(c) -> int:
        r = c.stop()
        text = "stopping (motion {})".format(r["motion_id"]) if r["motion_id"] else "at rest"
        ended = [str(e) for e in r.get("ended") or ()]  # a maneuver waiting between its motions has no motion
        _print(args, r, f"{text}; aborted {', '.join(ended)}" if ended else text)
        return 0

    return _run(args, stop)


def _cmd_mode(args) -> int:
    def mode(c) -> int:
        # reading it is the configuration's (a viewer may ask that); the mode key sets it (operators only)
        r = c.mode(args.set) if args.set is not None else {"mode": c.config()["mode"]}
        _print(args, r, f"mode: {r['mode']}")
        return 0

    return _run(args, mode)


def _cmd_config(args) -> int:
    def config(c) -> int:
        r = c.config()
        # no value (no implement selected) reads "-", as in `fleet ls`, never Python's "None"
        keys = ("prefix", "profile", "category", "implement", "mode", "user_keys")
        text = [f"{k}: {'-' if r[k] is None else r[k]}" for k in keys if k in r]
        text += _can_lines(r.get("can") or {})
        text += _limit_lines(r.get("limits") or {})
        _print(args, r, "\n".join(text) + "\n(--json for everything: every limit in SI, the actuators)")
        return 0

    return _run(args, config)


def _can_lines(can: Mapping[str, Any]) -> list[str]:
    """The bus and, with the simulated ECU, what its tractor drives over and how fast (km/h beside m/s) of a
    ``config`` reply's ``can`` part (a field technician's trial: the plain text did not say which scenario the twin
    was started with; only ``--json`` did)."""
    if not can:
        return []
    bus = f"can: {can.get('interface', '-')} {can.get('channel', '-')}"
    if not can.get("simulated_ecu"):
        return [bus + " (a real cylinder ECU)"]
    over = (
        f"scenario {can['simulated_scenario']}"
        if can.get("simulated_scenario")
        else f"field {can['simulated_field']}"
        if can.get("simulated_field")
        else "flat ground"
    )
    v = can.get("simulated_ground_speed")
    speed = "varies (the scenario's speed profile)" if v is None else f"{float(v):.2f} m/s ({3.6 * float(v):.1f} km/h)"
    return [bus + " (the simulated ECU and tractor)", f"simulated tractor: {over}, ground speed {speed}"]


def _limit_lines(limits: Mapping[str, Any]) -> list[str]:
    """The workspace box, the strokes and the jog's top rates of a ``config`` reply, in mm and mrad with their
    units (an operator's trial: ``hitch config`` said "profile, limits, workspace" and printed neither)."""
    units = {**CONTROLLED_POSE_UNITS, **ACTUATOR_UNITS}

    def milli_unit(name: str) -> str:
        return "mm" if units.get(name) == "m" else "mrad"

    def span(values: Any, unit: str) -> str:
        lo, hi = (float(v) for v in values)
        return f"[{1e3 * lo:.1f}, {1e3 * hi:.1f}] {unit}"

    out = []
    ws = limits.get("workspace") or {}
    if ws:
        out.append("workspace: " + ", ".join(f"{k} {span(v, milli_unit(k))}" for k, v in ws.items()))
    strokes = limits.get("strokes") or {}
    if strokes:
        out.append("strokes: " + ", ".join(f"{k} {span(v, milli_unit(k))}" for k, v in strokes.items()))
    jog = limits.get("jog_velocity") or {}
    if jog:
        out.append("jog top rates: " + ", ".join(f"{k} {1e3 * float(v):.1f} {milli_unit(k)}/s" for k, v in jog.items()))
    return out


def faults_text(ecu: dict) -> str:
    """The faults the service holds, from its state's ``ecu`` part: one line each with its kind and reason."""
    names = [str(n) for n in ecu.get("faults") or []]
    if not names:
        return "no fault held"
    reasons = [str(r) for r in ecu.get("fault_reasons") or []]
    ack = {str(n) for n in ecu.get("ack_required") or []}
    lines = []
    for i, name in enumerate(names):
        kind = "latching: `hitch faults ack` once its cause is gone" if name in ack else "self-clearing"
        reason = reasons[i] if i < len(reasons) and len(reasons) == len(names) else ""
        lines.append(f"{name} ({kind})" + (f": {reason}" if reason else ""))
    if len(reasons) != len(names) and reasons:
        lines.append("reasons: " + "; ".join(reasons))
    return "\n".join(lines)


def _cmd_faults(args) -> int:
    def ack(c) -> int:
        fn = getattr(c, "ack_faults", None)
        r = fn() if callable(fn) else c.request("faults/ack", {})
        if isinstance(r, dict):
            acked, left = r.get("acknowledged") or [], r.get("faults") or []
            details = ("cleared " + ", ".join(map(str, acked))) if acked else "nothing latched to clear"
            details += ("; still held: " + ", ".join(map(str, left))) if left else "; no fault held"
            if set(r) - {"acknowledged", "faults"}:  # a reply of another shape: as it came
                details = ", ".join(f"{k}: {v}" for k, v in r.items())
        else:
            details = str(r)
        _print(args, r, "faults acknowledged" + (f" ({details})" if details else ""))
        return 0

    def held(c) -> int:
        ecu = c.state().get("ecu") or {}
        keys = ("faults", "fault_reasons", "ack_required", "link_faults")
        _print(args, {k: ecu.get(k, []) for k in keys}, faults_text(ecu))
        return 0

    return _run(args, ack if args.action == "ack" else held)


def step_text(step: object) -> str:
    """A state's or reply's maneuver ``step`` (the API's 0-based index) as every text names it (:func:`step_words`);
    ``step -`` when there is none."""
    return step_words(step) if isinstance(step, int) and not isinstance(step, bool) else "step -"


def _activity(s: dict) -> str:
    """What runs besides the motion: the maneuver and its step (a wait says what it waits for), the track
    session, work control (a field trial: "auto at rest motion 13" while a maneuver waited for a line 16.8 m
    ahead and work control ran)."""
    parts = []
    m = s.get("maneuver")
    if isinstance(m, dict):
        text = f"maneuver {m.get('name') or '-'} {step_text(m.get('step'))}"
        if m.get("kind"):
            text += f" {m['kind']}"
        if m.get("paused"):
            text += " PAUSED"
        for key, unit in (("time_left", "s"), ("distance_left", "m")):
            v = m.get(key)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                text += f" {v:.1f} {unit} left"
        parts.append(text)
    tr = s.get("track")
    if isinstance(tr, dict):
        parts.append(
            f"track session {tr.get('session')} ({tr.get('frame')}, {','.join(map(str, tr.get('dof') or []))})"
            + (" stale" if tr.get("stale") else "")
        )
    w = s.get("work")
    if isinstance(w, dict) and w.get("running"):
        text = f"work {w.get('active') or w.get('mode')}"
        if w.get("fallback"):
            text += f" (fallback: {w['fallback']})"
        parts.append(text)
    return "  ".join(parts)


def _state_line(s: dict) -> str:
    """One line of rich markup (data escaped)."""
    ecu = s.get("ecu") or {}
    lim = s.get("limited") or {}
    doing = _activity(s)
    motion = "moving" if s.get("moving") else "at rest"
    pose = _fmt_pose(s.get("pose"))
    age = ecu.get("measurement_age_s")
    if not ecu.get("online") and isinstance(age, (int, float)) and not isinstance(age, bool):
        # an old measurement is not the hitch now (an operator's trial: "at rest … z=+0.1074 m" 3.5 s after the
        # ECU fell silent, read as live)
        # nor is "at rest": that is the planner's (it aborted the motion), the hitch may still move (a re-run: "last
        # seen at rest" for a pose measured while it moved, 41 mm from where it stood)
        motion, pose = "moving or not: unknown (ECU silent)", f"{pose} (measured {age:.1f} s ago)"
    return esc(
        f"#{s.get('seq')} {s.get('mode')} {motion} "
        f"motion {s.get('motion_id') if s.get('motion_id') is not None else '-'}  pose {pose}  ECU "
        f"{'online' if ecu.get('online') else 'OFFLINE'}"
        f"{' ' + ','.join(map(str, ecu.get('faults', []))) if ecu.get('faults') else ''}"
        + (f"  {doing}" if doing else "")
    ) + (f"  [red]control limited: {esc(limited_text(lim))}[/red]" if lim else "")


def _cmd_state(args) -> int:
    def state(c) -> int:
        from bridge.service.client import ServiceTimeout

        if not args.follow:
            s = c.state()
            _print(args, s, _state_line(s), markup=True)
            return 0
        n, silent = 0, False
        while True:
            try:
                for s in c.follow("state"):
                    n, silent = n + 1, False
                    _print(args, s, _state_line(s), markup=True)
                    if args.count and n >= args.count:
                        return 0
                return 0
            except ServiceTimeout as exc:
                if n == 0:  # never heard: no service there (the setup error)
                    raise
                if not silent:  # heard before: it stopped or the link is down; keep following, as tail -f does (an
                    # operator's trial: --follow ended with "no state sample … start one with hitch serve")
                    print(
                        f"hitch: note: {exc}: the service stopped or the link is down; following on (Ctrl-C ends)",
                        file=sys.stderr,
                    )
                    silent = True

    return _run(args, state)


def _cmd_preset(args) -> int:
    def preset(c) -> int:
        if args.action == "list":
            r = c.request("presets/list", {})
            _print(
                args,
                r,
                "\n".join(
                    f"{p['name']}: {_fmt_pose(p['pose'])}"
                    + (f"  speed scale {p['speed_scale']:g}" if p.get("speed_scale") is not None else "")
                    for p in r["presets"]
                )
                or "(no presets)",
            )
        elif args.action == "save":
            body = {
                "name": args.name,
                **({"pose": args.pose} if args.pose else {}),
                **({"speed_scale": args.speed_scale} if args.speed_scale is not None else {}),
                **({"replace": True} if args.replace else {}),
            }
            r = c.request("presets/save", body)
            said = f"{'replaced' if r.get('replaced') else 'saved'} {r['saved']}: {_fmt_pose(r['pose'])}"
            _print(args, r, said + (f"\nnote: {r['note']}" if r.get("note") else ""))
        elif args.action == "go":
            body = {
                "name": args.name,
                **({"speed_scale": args.speed_scale} if args.speed_scale is not None else {}),
                **_deadline(args),
            }
            r, final = _motion(
                args, c, lambda: c.request("presets/go", body), lambda reply: _wait_motion(args, c, reply)
            )
            if final is not None:
                r = {**r, "final": final}
            ended, status = _ended(final)
            _print(args, r, f"motion {r['motion_id']} to preset {args.name}, {r['duration']:.2f} s" + ended)
            return status
        else:
            r = c.request("presets/delete", {"name": args.name, **({"force": True} if args.force else {})})
            _print(args, r, f"deleted {r['deleted']}" + (f"; warning: {r['warning']}" if r.get("warning") else ""))
        return 0

    return _run(args, preset)


def _read_script(path: str) -> str:
    p = Path(path)
    if not p.is_file():
        raise CLIError(f"maneuver file {p} " + ("is not a regular file" if p.exists() else "does not exist"))
    return read_text_file(p, "maneuver file", CLIError)


def _maneuver_outcome(out: dict) -> str:
    e = out.get("outcome")
    if not isinstance(e, dict):
        return "ended"
    if e.get("event") == "maneuver_finished":
        return "finished"
    why = e.get("reason") or ""
    return "aborted" + (f" ({why}{': ' + str(e['message']) if e.get('message') else ''})" if why else "")


def script_errors(errors: list[dict]) -> str:
    """A maneuver's validation errors, one indented line each: ``step N (index i)`` — counted from 1 as a reader
    counts the script's steps, with the API's 0-based index (events, ``steps[i]``) beside it — or, before any
    step, ``script``."""

    def where(step: object) -> str:
        return "script" if not isinstance(step, int) or isinstance(step, bool) else step_words(step)

    return "\n".join(f"  {where(e.get('step'))}: {e['message']}" for e in errors)


def _cmd_maneuver(args) -> int:
    # the file is read before any connection: a file that cannot be read fails at once, with its own error
    script = _read_script(args.file) if args.action in ("validate", "save") else None

    def maneuver(c) -> int:
        a = args.action
        if a == "validate":
            r = c.request("maneuvers/validate", {"script": script})
            _print(
                args,
                r,
                f"{args.file}: ok, {r['duration']:.2f} s"
                if r["ok"]
                else f"{args.file}: invalid:\n" + script_errors(r["errors"]),
            )
            return 0 if r["ok"] else 1
        if a == "save":
            body = {"name": args.name, "script": script, **({"replace": True} if args.replace else {})}
            r = c.request("maneuvers/save", body)
            steps = f"{r['steps']} step" + ("" if r["steps"] == 1 else "s")
            what = "replaced" if r.get("replaced") else "saved"
            _print(args, r, f"{what} {r['saved']} ({steps}; parsed only: `hitch maneuver validate` plans it)")
        elif a == "list":
            r = c.request("maneuvers/list", {})
            _print(
                args,
                r,
                "\n".join(
                    f"{m['name']}: {m['steps']} step{'' if m['steps'] == 1 else 's'}, timeout {m['timeout']:g} s"
                    + (f" — {m['description']}" if m.get("description") else "")
                    for m in r["maneuvers"]
                )
                or "(no maneuvers)",
            )
        elif a == "run":
            r, final = _motion(
                args,
                c,
                lambda: c.request("maneuvers/run", {"name": args.name, **_deadline(args)}),
                lambda reply: c.wait_maneuver(
                    reply["maneuver_id"], timeout_s=_MANEUVER_WAIT_S, instance=reply.get("instance")
                ),
            )
            text = f"maneuver {args.name} started (id {r['maneuver_id']}, planned {r['duration']:.2f} s)"
            if final is not None:
                r = {**r, "outcome": final.get("outcome")}
                text += f"; {_maneuver_outcome(final)}"
            _print(args, r, text)
            if final is not None and isinstance(final.get("outcome"), dict):
                return 0 if final["outcome"].get("event") == "maneuver_finished" else 1
        else:
            r = c.request("maneuvers/delete", {"name": args.name})
            _print(args, r, f"deleted {r['deleted']}")
        return 0

    return _run(args, maneuver)


def _fleet_row(c, prefix: str) -> dict[str, Any]:
    """One live service of ``hitch fleet ls``: its ``config`` (which any role that may read may ask, and
    which carries the mode: the ``mode`` key is the operators'), or why it gave none (``error``: the message,
    ``code``: ``timeout`` when it did not answer, else the service's refusal; ``timeout_s`` when its query went
    out and no answer came within it: the service, listed by its token, is busy or hung)."""
    from bridge.service.client import ServiceError

    try:
        cfg = c.config(prefix)
    except ServiceError as exc:  # that service refused, or did not answer
        row = {"prefix": prefix, "error": str(exc), "code": exc.code}
        waited = getattr(exc, "timeout_s", None)
        if waited is not None:  # its query went out, no answer came: busy or hung
            row["timeout_s"] = waited
        return row
    except HitchError as exc:  # e.g. a token whose key is no prefix this client can send to
        return {"prefix": prefix, "error": str(exc), "code": "error"}
    return {
        "prefix": prefix,
        "profile": cfg.get("profile"),
        "category": cfg.get("category"),
        "implement": cfg.get("implement"),
        "mode": cfg.get("mode"),
    }


#: how long ``fleet ls`` waits for one state of every listed service (all at once) [s]; the state runs at 50 Hz
FLEET_STATE_WAIT_S = 1.0


def fleet_states(c, prefixes: list[str], wait_s: float = FLEET_STATE_WAIT_S) -> dict[str, dict[str, Any]]:
    """One ``state`` of each of ``prefixes``, all subscribed at once and waited for at most ``wait_s`` [s]: per
    prefix its ECU link (``ecu_online``, ``faults`` held, ``ack_required``) and motion (``moving``, ``motion``);
    a prefix with no state in that time is absent (its control core silent, or this login may not read it)."""
    got: dict[str, dict[str, Any]] = {}
    lock, all_in = threading.Lock(), threading.Event()
    wanted = [len(prefixes)]  # the states to wait for: one per subscription made (a review: one that failed
    # made every listing wait the whole time)

    def taker(prefix: str) -> Callable[[dict], None]:
        def take(state: dict) -> None:
            raw = state.get("ecu")
            ecu: dict[str, Any] = raw if isinstance(raw, dict) else {}
            with lock:
                got.setdefault(
                    prefix,
                    {
                        "ecu_online": bool(ecu.get("online")),
                        "faults": [str(f) for f in ecu.get("faults") or ()],
                        "ack_required": [str(f) for f in ecu.get("ack_required") or ()],
                        "moving": bool(state.get("moving")),
                        "motion": state.get("motion"),
                    },
                )
                if len(got) >= wanted[0]:
                    all_in.set()

        return take

    subs = []
    try:
        for prefix in prefixes:
            try:
                subs.append(c.subscribe("state", taker(prefix), prefix=prefix))
            except HitchError:  # a token whose key is no prefix this client can subscribe to: no state
                with lock:
                    wanted[0] -= 1
                continue
        with lock:
            if len(got) >= wanted[0]:
                all_in.set()
        if subs:
            all_in.wait(wait_s)
    finally:
        for sub in subs:
            sub.close()
    with lock:
        return dict(got)


def _state_words(st: dict[str, Any] | None, prefix: str) -> str:
    """A fleet row's machine part: the ECU link, the faults held (and the command that acknowledges the latched
    ones, for this service's ``prefix``), what moves."""
    if st is None:
        return f"no state within {FLEET_STATE_WAIT_S:g} s"
    ecu = "ECU online" if st["ecu_online"] else "ECU OFFLINE"
    faults = st["faults"]
    ack = f" (acknowledge: hitch faults ack --prefix {prefix})" if st["ack_required"] else ""
    held = f", faults {', '.join(faults)}{ack}"
    moving = f", moving ({st['motion']})" if st["moving"] else ", at rest"
    return ecu + (held if faults else "") + moving


def _fleet_line(r: dict[str, Any]) -> str:
    machine = "; " + _state_words(r.get("state"), r["prefix"])
    if "error" not in r:
        return (
            f"{r['prefix']}: {r['profile']} cat {r['category']}, implement {r['implement'] or '-'}, mode {r['mode']}"
            + machine
        )
    if r.get("code") == "timeout" and r.get("timeout_s") is not None:  # its token listed it: it is up
        return (
            f"{r['prefix']}: NO ANSWER within {r['timeout_s']:g} s (the service is up — its liveliness token is "
            "there — but did not answer: busy or hung)" + machine
        )
    what = "NO ANSWER" if r.get("code") == "timeout" else f"REFUSED ({r.get('code')})"
    return f"{r['prefix']}: {what}: {r['error']}" + machine


def _cmd_fleet(args) -> int:
    """The live services (their liveliness tokens), each with its ``config``. Exit status: 0 when every listed
    service answered (or none is live), 1 when some did not (each shown as such), 2 when none did."""

    def fleet(c) -> int:
        live = c.fleet(timeout_s=min(args.timeout, 5.0), under=args.prefix)
        rows = [_fleet_row(c, prefix) for prefix in live]
        states = fleet_states(c, live)
        for r in rows:  # each service's machine now: its ECU link, faults and motion (None: no state came)
            r["state"] = states.get(r["prefix"])
        # with a login, access control may hide every service from it (its tokens are not shown to this user)
        none = (
            "(no services visible: none runs, or this login may see none — access control)"
            if args.security
            else "(no services)"
        )
        if args.prefix is not None:
            none = none.replace("(no services", f"(no services under {args.prefix}", 1)
        _print(args, {"fleet": rows}, "\n".join(map(_fleet_line, rows)) or none)
        failed = [r for r in rows if "error" in r]
        if failed and not args.json:  # the status says it; the line says why on stderr too
            print(
                f"hitch: {len(failed)} of {len(rows)} services gave no configuration: "
                + ", ".join(r["prefix"] for r in failed),
                file=sys.stderr,
            )
        return 0 if not failed else 2 if len(failed) == len(rows) else 1

    return _run(args, fleet)


def add_commands(sub) -> Any:
    """The service's client commands on ``sub``; returns the ``hitch maneuver`` sub-parsers (the headland
    commands add theirs: :func:`bridge.cli.headland.add_maneuver_actions`)."""
    _add_serve(sub)
    p = sub.add_parser("goto", help="move the hitch to a (partial) pose through the service")
    p.add_argument(
        "--to",
        type=parse_pose_arg,
        required=True,
        help="goal in SI: x, z [m], roll, pitch [rad], e.g. x=0.02,z=0.25 (others keep their value)",
    )
    p.add_argument(
        "--speed-scale",
        type=bounded_float("--speed-scale", MIN_SPEED_SCALE, 1.0, lo_open=False),
        default=1.0,
        help=f"fraction of full speed, [{MIN_SPEED_SCALE:g}, 1], default 1",
    )
    _wait_options(p)
    _client_options(p)
    p.set_defaults(handler=_cmd_goto)

    p = sub.add_parser("jog", help="jog at pose rates while the command is repeated (dead-man)")
    for n, unit in (("vx", "m/s"), ("vz", "m/s"), ("vroll", "rad/s"), ("vpitch", "rad/s")):
        p.add_argument(
            f"--{n}",
            type=finite_float(f"--{n}"),
            default=None,
            help=f"rate [{unit}] (default 0); the service caps it at its jog speed (from the profile's actuator "
            "speeds, not a service setting; `hitch config --json` shows it as limits.jog_velocity) and says so "
            "in 'limited'",
        )
    p.add_argument(
        "--ttl-ms",
        type=bounded_float("--ttl-ms", 0.0, 5000.0, unit="ms"),
        default=200.0,
        help="life of each command, (0, 5000] ms (default 200)",
    )
    p.add_argument(
        "--duration",
        type=bounded_float("--duration", 0.0, 3600.0, unit="s"),
        default=None,
        help="keep jogging this long, (0, 3600] s (default: one command of --ttl-ms); Ctrl-C or SIGTERM stops",
    )
    p.set_defaults(term_interrupts=True)  # SIGTERM is taken as Ctrl-C: the jog is stopped (bridge.cli.main)
    _client_options(p)
    p.set_defaults(handler=_cmd_jog)

    p = sub.add_parser(
        "stop",
        help="stop any motion (jerk-limited); its Zenoh threads run under SCHED_FIFO where permitted (root or "
        "CAP_SYS_NICE), as with --realtime, so the stop leaves at once on a busy computer",
    )
    _client_options(p)
    p.set_defaults(handler=_cmd_stop, realtime_where_permitted=True)

    p = sub.add_parser("config", help="the service's configuration: profile, limits, workspace, mode (viewers too)")
    _client_options(p)
    p.set_defaults(handler=_cmd_config)

    p = sub.add_parser("mode", help="read or set the operating mode")
    p.add_argument(
        "set",
        nargs="?",
        metavar="MODE",
        choices=("auto", "manual", "attach", "transport", "config"),
        default=None,
        help="the mode to set: auto, manual, attach, transport or config (none: read it)",
    )
    _client_options(p)
    p.set_defaults(handler=_cmd_mode)

    p = sub.add_parser("state", help="the service's published state")
    p.add_argument("--follow", action="store_true", help="keep printing every sample")
    p.add_argument(
        "--count", type=whole_number("--count"), default=0, help="with --follow: stop after N samples (0: never)"
    )
    _client_options(p)
    p.set_defaults(handler=_cmd_state)

    p = sub.add_parser("preset", help="saved poses of the current implement")
    _client_options(p, outer=True)
    ps = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    for action, needs_name, what in (
        ("save", True, "save a pose (default: the current one) under a name"),
        ("list", False, "the presets of the current implement"),
        ("go", True, "move to a preset"),
        ("delete", True, "delete a preset (refused while a saved maneuver uses it, unless --force)"),
    ):
        q = ps.add_parser(action, help=what)
        if needs_name:
            q.add_argument("name")
        if action == "delete":
            q.add_argument(
                "--force", action="store_true", help="delete it although saved maneuvers use it (they then fail)"
            )
        if action == "save":
            q.add_argument(
                "--replace", action="store_true", help="replace a preset of that name (else refused: in_use)"
            )
            q.add_argument(
                "--pose",
                type=parse_pose_arg,
                default=None,
                help="x, z [m], roll, pitch [rad], e.g. x=0.02,z=0.25 (default: the current pose)",
            )
        if action in ("save", "go"):
            q.add_argument(
                "--speed-scale",
                type=finite_float("--speed-scale"),
                default=None,
                help=f"fraction of full speed, [{MIN_SPEED_SCALE:g}, 1] (save: the preset's own; go: this time only)",
            )
        if action == "go":
            _wait_options(q)
        _client_options(q)
        q.set_defaults(handler=_cmd_preset)

    p = sub.add_parser("maneuver", help="scripted maneuvers (YAML)")
    _client_options(p, outer=True)
    ms = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    for action, pos, what in (
        ("validate", ("file",), "check a YAML script against the service (parse, then plan every step)"),
        ("save", ("name", "file"), "check a YAML script and store it under a name"),
        ("list", (), "the stored maneuvers"),
        ("run", ("name",), "run a stored maneuver"),
        ("delete", ("name",), "delete a stored maneuver"),
    ):
        q = ms.add_parser(action, help=what)
        for a in pos:
            q.add_argument(a)
        if action == "run":
            _wait_options(q)
        if action == "save":
            q.add_argument(
                "--replace", action="store_true", help="replace a maneuver of that name (else refused: in_use)"
            )
        _client_options(q)
        q.set_defaults(handler=_cmd_maneuver)
    maneuver_actions = ms  # bridge.cli.headland adds record, pause, resume, skip (bridge.cli.main)
    p = sub.add_parser("fleet", help="services reachable through a router")
    _client_options(p, prefix_help=FLEET_PREFIX_HELP, outer=True)
    fs = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    q = fs.add_parser(
        "ls",
        help="list live services (liveliness tokens) with their profile and mode, and from one state each its ECU "
        "link, faults and motion; exit status 1 when some did not answer, 2 when none did",
    )
    _client_options(q, prefix_help=FLEET_PREFIX_HELP)
    q.set_defaults(handler=_cmd_fleet)

    p = sub.add_parser("faults", help="faults the service holds: list | ack")
    _client_options(p, outer=True)
    fs = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    q = fs.add_parser("list", help="the faults held now, each latching or self-clearing, with its reason")
    _client_options(q)
    q.set_defaults(handler=_cmd_faults)
    q = fs.add_parser("ack", help="acknowledge latched faults (those whose cause is gone are cleared)")
    _client_options(q)
    q.set_defaults(handler=_cmd_faults)
    return maneuver_actions
