"""CLI commands of the Zenoh service: run it, and talk to a running one.

``hitch serve`` runs the service (embedded defaults; flags or ``--config FILE.toml``).
Client commands talk to a running service over Zenoh, each with ``--connect ENDPOINT``
(default ``tcp/127.0.0.1:7447``), ``--prefix`` (default ``hitch``), ``--security FILE``
(the client's credentials / TLS CA) and ``--json``:

``hitch goto|jog|stop|mode|state [--follow]``, ``hitch preset save|list|go|delete``,
``hitch maneuver validate|save|list|run|delete``, ``hitch fleet ls``.

A refused request (:class:`~bridge.service.client.ServiceError`) exits with status 2 and the
service's message on one line.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from rich.console import Console

from bridge.cli.errors import CLIError
from bridge.cli.model import finite_float
from bridge.cli.plan import parse_pose_arg
from bridge.service.config import DEFAULT_LISTEN, load_service_config
from planner.errors import HitchError

__all__ = ["add_commands"]


def _client(args):
    from bridge.service.client import HitchClient  # zenoh is imported only by the commands that use it

    return HitchClient(
        args.connect or [DEFAULT_LISTEN], prefix=args.prefix, timeout_s=args.timeout, security=args.security
    )


def _print(args, reply: dict, text: str | None = None) -> None:
    if args.json:
        print(json.dumps(reply))
    else:
        Console(soft_wrap=True).print(text if text is not None else json.dumps(reply, indent=1))


def _fmt_pose(p: dict | None) -> str:
    if not p:
        return "-"
    return "  ".join(f"{k}={p[k]:+.4f}" for k in ("x", "z", "roll", "pitch") if k in p)


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
        can_interface=args.can_interface,
        can_channel=args.can_channel,
        simulate_ecu=False if args.no_sim_ecu else None,
        sim_ground_speed=args.sim_ground_speed,
        profile=args.profile,
        category=args.category,
        implement=args.implement,
        control_rate=args.control_rate,
        state_rate=args.state_rate,
        data_dir=args.data_dir,
        http=args.http,
        http_user=args.http_user,
        feedforward=False if args.no_feedforward else None,
    )
    sys.setswitchinterval(5e-4)  # threads waiting for the GIL (the 50 Hz loop) wait ≤ 0.5 ms, not 5 ms

    def ready(service) -> None:
        for w in service.warnings:
            print(f"hitch serve: warning: {w}", file=sys.stderr)
        print(
            f"hitch serve: ready on {', '.join(cfg.listen or ()) or '(no listener)'}"
            f"{' connected to ' + ', '.join(cfg.connect) if cfg.connect else ''} prefix {cfg.prefix!r}, "
            f"data {cfg.database_path}",
            flush=True,
        )

    took = serve(cfg, ready=ready)
    print(f"hitch serve: stopped in {took * 1000:.0f} ms", flush=True)
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
    p.add_argument("--can-interface", choices=("virtual", "socketcan", "udp_multicast"), default=None)
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
    p.add_argument("--profile", default=None, help="hitch profile (default thesis-t132)")
    p.add_argument("--category", default=None, help="ISO 730 category (default: the profile's)")
    p.add_argument(
        "--implement", default=None, help="implement record of the tractor profile (presets are per implement)"
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
        "--http-user",
        default=None,
        metavar="USER",
        help="user the terminal's commands run as when access control is on (needed then)",
    )
    p.set_defaults(handler=_cmd_serve)


# ---------------------------------------------------------------------------------------- clients
def _client_options(p) -> None:
    p.add_argument(
        "--connect",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"service or router endpoint (repeatable; default {DEFAULT_LISTEN})",
    )
    p.add_argument("--prefix", default="hitch", help="key prefix of the service (default hitch)")
    p.add_argument("--security", default=None, help="Zenoh security config of this client (credentials, TLS CA)")
    p.add_argument("--timeout", type=finite_float("--timeout"), default=5.0, help="seconds to wait for a reply")
    p.add_argument("--json", action="store_true", help="print JSON")


def _run(args, fn) -> int:
    with _client(args) as c:
        return fn(c)


def _cmd_goto(args) -> int:
    def go(c) -> int:
        r = c.goto(args.to, args.speed_scale)
        if args.wait:
            st = c.wait_motion(r["motion_id"], timeout_s=max(args.timeout, r["duration"] + 10.0))
            r = {**r, "final": {"pose": st.get("pose"), "motion_id": st.get("motion_id"), "moving": st.get("moving")}}
        _print(
            args,
            r,
            f"motion {r['motion_id']} accepted, {r['duration']:.2f} s"
            + (f" (slowed x{r['speed_factor']:.2f})" if r["speed_factor"] < 1 else "")
            + (f"; now at {_fmt_pose(r['final']['pose'])}" if args.wait else ""),
        )
        return 0

    return _run(args, go)


def _cmd_jog(args) -> int:
    def jog(c) -> int:
        end = time.monotonic() + args.duration
        period = min(0.1, args.ttl_ms / 2000.0)
        r = c.jog(args.vx, args.vz, args.vroll, args.vpitch, args.ttl_ms)
        while time.monotonic() < end:  # dead-man: keep refreshing while "held"
            time.sleep(period)
            r = c.jog(args.vx, args.vz, args.vroll, args.vpitch, args.ttl_ms)
        _print(args, r, f"jog motion {r['motion_id']}" + (f", limited: {r['limited']}" if r["limited"] else ""))
        return 0

    return _run(args, jog)


def _cmd_stop(args) -> int:
    def stop(c) -> int:
        r = c.stop()
        _print(args, r, "stopping (motion {})".format(r["motion_id"]) if r["motion_id"] else "at rest")
        return 0

    return _run(args, stop)


def _cmd_mode(args) -> int:
    def mode(c) -> int:
        r = c.mode(args.set)
        _print(args, r, f"mode: {r['mode']}")
        return 0

    return _run(args, mode)


def _state_line(s: dict) -> str:
    ecu = s.get("ecu") or {}
    lim = s.get("limited") or {}
    return (
        f"#{s.get('seq')} {s.get('mode')} {'moving' if s.get('moving') else 'at rest'} "
        f"motion {s.get('motion_id')}  pose {_fmt_pose(s.get('pose'))}  ECU "
        f"{'online' if ecu.get('online') else 'OFFLINE'}"
        f"{' ' + ','.join(ecu.get('faults', [])) if ecu.get('faults') else ''}"
        + (f"  [red]control limited: {', '.join(f'{k}: {v}' for k, v in lim.items())}[/red]" if lim else "")
    )


def _cmd_state(args) -> int:
    def state(c) -> int:
        if not args.follow:
            s = c.state()
            _print(args, s, _state_line(s))
            return 0
        for n, s in enumerate(c.follow("state"), 1):
            _print(args, s, _state_line(s))
            if args.count and n >= args.count:
                return 0
        return 0

    return _run(args, state)


def _cmd_preset(args) -> int:
    def preset(c) -> int:
        if args.action == "list":
            r = c.request("presets/list", {})
            _print(args, r, "\n".join(f"{p['name']}: {_fmt_pose(p['pose'])}" for p in r["presets"]) or "(no presets)")
        elif args.action == "save":
            body = {
                "name": args.name,
                **({"pose": args.pose} if args.pose else {}),
                **({"speed_scale": args.speed_scale} if args.speed_scale is not None else {}),
            }
            r = c.request("presets/save", body)
            _print(args, r, f"saved {r['saved']}: {_fmt_pose(r['pose'])}")
        elif args.action == "go":
            body = {"name": args.name, **({"speed_scale": args.speed_scale} if args.speed_scale is not None else {})}
            r = c.request("presets/go", body)
            _print(args, r, f"motion {r['motion_id']} to preset {args.name}, {r['duration']:.2f} s")
        else:
            r = c.request("presets/delete", {"name": args.name})
            _print(args, r, f"deleted {r['deleted']}")
        return 0

    return _run(args, preset)


def _read_script(path: str) -> str:
    p = Path(path)
    if not p.is_file():
        raise CLIError(f"maneuver file {p} does not exist")
    return p.read_text(encoding="utf-8")


def _cmd_maneuver(args) -> int:
    def maneuver(c) -> int:
        a = args.action
        if a == "validate":
            r = c.request("maneuvers/validate", {"script": _read_script(args.file)})
            _print(
                args,
                r,
                f"ok, {r['duration']:.2f} s"
                if r["ok"]
                else "invalid:\n" + "\n".join(f"  step {e['step']}: {e['message']}" for e in r["errors"]),
            )
            return 0 if r["ok"] else 1
        if a == "save":
            r = c.request("maneuvers/save", {"name": args.name, "script": _read_script(args.file)})
            _print(args, r, f"saved {r['saved']} ({r['steps']} steps)")
        elif a == "list":
            r = c.request("maneuvers/list", {})
            _print(
                args,
                r,
                "\n".join(
                    f"{m['name']}: {m['steps']} steps, timeout {m['timeout']:g} s {m['description']}"
                    for m in r["maneuvers"]
                )
                or "(no maneuvers)",
            )
        elif a == "run":
            r = c.request("maneuvers/run", {"name": args.name})
            _print(args, r, f"maneuver {args.name} started (id {r['motion_id']}, planned {r['duration']:.2f} s)")
        else:
            r = c.request("maneuvers/delete", {"name": args.name})
            _print(args, r, f"deleted {r['deleted']}")
        return 0

    return _run(args, maneuver)


def _cmd_fleet(args) -> int:
    def fleet(c) -> int:
        rows = []
        for prefix in c.fleet(timeout_s=min(args.timeout, 5.0)):
            try:
                cfg = c.config(prefix)
                st = c.request("mode", {}, prefix=prefix)
                rows.append(
                    {
                        "prefix": prefix,
                        "profile": cfg.get("profile"),
                        "category": cfg.get("category"),
                        "implement": cfg.get("implement"),
                        "mode": st.get("mode"),
                    }
                )
            except HitchError as exc:  # ServiceError: that service refused or did not answer
                rows.append({"prefix": prefix, "error": str(exc)})
        _print(
            args,
            {"fleet": rows},
            "\n".join(
                f"{r['prefix']}: "
                + (
                    r["error"]
                    if "error" in r
                    else f"{r['profile']} cat {r['category']}, implement {r['implement'] or '-'}, mode {r['mode']}"
                )
                for r in rows
            )
            or "(no services)",
        )
        return 0

    return _run(args, fleet)


def add_commands(sub) -> None:
    _add_serve(sub)
    p = sub.add_parser("goto", help="move the hitch to a (partial) pose through the service")
    p.add_argument(
        "--to", type=parse_pose_arg, required=True, help="goal, e.g. x=0.02,z=0.25 (others keep their value)"
    )
    p.add_argument("--speed-scale", type=finite_float("--speed-scale"), default=1.0, help="(0, 1], default 1")
    p.add_argument("--wait", action="store_true", help="wait until the motion has ended and print the pose")
    _client_options(p)
    p.set_defaults(handler=_cmd_goto)

    p = sub.add_parser("jog", help="jog at pose rates while the command is repeated (dead-man)")
    for n, unit in (("vx", "m/s"), ("vz", "m/s"), ("vroll", "rad/s"), ("vpitch", "rad/s")):
        p.add_argument(f"--{n}", type=finite_float(f"--{n}"), default=0.0, help=f"rate [{unit}]")
    p.add_argument("--ttl-ms", type=finite_float("--ttl-ms"), default=200.0, help="life of each command, ms")
    p.add_argument("--duration", type=finite_float("--duration"), default=0.0, help="keep jogging this long, s")
    _client_options(p)
    p.set_defaults(handler=_cmd_jog)

    p = sub.add_parser("stop", help="stop any motion (jerk-limited)")
    _client_options(p)
    p.set_defaults(handler=_cmd_stop)

    p = sub.add_parser("mode", help="read or set the operating mode")
    p.add_argument("set", nargs="?", choices=("auto", "manual", "attach", "transport", "config"), default=None)
    _client_options(p)
    p.set_defaults(handler=_cmd_mode)

    p = sub.add_parser("state", help="the service's published state")
    p.add_argument("--follow", action="store_true", help="keep printing every sample")
    p.add_argument("--count", type=int, default=0, help="with --follow: stop after N samples")
    _client_options(p)
    p.set_defaults(handler=_cmd_state)

    p = sub.add_parser("preset", help="saved poses of the current implement")
    ps = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    for action, needs_name in (("save", True), ("list", False), ("go", True), ("delete", True)):
        q = ps.add_parser(action)
        if needs_name:
            q.add_argument("name")
        if action == "save":
            q.add_argument("--pose", type=parse_pose_arg, default=None, help="x=..,z=.. (default: the current pose)")
        if action in ("save", "go"):
            q.add_argument("--speed-scale", type=finite_float("--speed-scale"), default=None)
        _client_options(q)
        q.set_defaults(handler=_cmd_preset)

    p = sub.add_parser("maneuver", help="scripted maneuvers (YAML)")
    ms = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    for action, pos in (
        ("validate", ("file",)),
        ("save", ("name", "file")),
        ("list", ()),
        ("run", ("name",)),
        ("delete", ("name",)),
    ):
        q = ms.add_parser(action)
        for a in pos:
            q.add_argument(a)
        _client_options(q)
        q.set_defaults(handler=_cmd_maneuver)

    p = sub.add_parser("fleet", help="services reachable through a router")
    fs = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    q = fs.add_parser("ls", help="list live services (liveliness tokens) with their profile and mode")
    _client_options(q)
    q.set_defaults(handler=_cmd_fleet)
