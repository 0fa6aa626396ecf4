"""CLI commands of the implements and the quick raise / return (``docs/implements.md``):

``hitch implement list|define|select|delete|lock|unlock`` and ``hitch raise`` / ``hitch return``
(``--wait`` as ``hitch goto``: Ctrl-C then stops the motion): client commands of ``hitch serve``.
``hitch switch raise|lower|released`` sends the operator switch's CAN frame (a twin's fender switch);
with ``--service`` the service's simulated tractor sends one press instead (``sim/switch``: the twin in
the control core's process, whose bus no other program reaches).
"""

from __future__ import annotations

import argparse
from typing import Any

from bridge.cli.model import finite_float
from bridge.cli.plan import parse_pose_arg
from bridge.cli.service import (
    _client_command,
    _client_options,
    _ended,
    _fmt_pose,
    _motion,
    _print,
    _run,
    _wait_motion,
    _wait_options,
)
from bridge.link.realtime import INTERFACES, open_bus

__all__ = ["add_commands"]


def _fmt_limit(v: Any, unit: str) -> str:
    return "-" if v is None else f"{v:g} {unit}"


def _line(i: dict[str, Any], selected: str) -> str:
    mark = "*" if i["name"] == selected else " "
    com = ", ".join(f"{c:+.3f}" for c in i["com_m"])
    lock = "  LOCKED" if i.get("transport_locked") else ""
    return (
        f"{mark} {i['name']} (cat {i['category']}, {i['mass_kg']:g} kg, CoM [{com}] m, {i.get('source', 'store')}): "
        f"upper {_fmt_limit(i.get('upper_height_m'), 'm')}, lowering {_fmt_limit(i.get('lowering_speed_m_s'), 'm/s')}"
        f"{lock}"
    )


def _cmd_implement(args) -> int:
    def run(c) -> int:
        if args.action == "list":
            r = c.request("implements/list", {})
            text = "\n".join(_line(i, r["selected"]) for i in r["implements"]) or "(no implements)"
            from bridge.service.store import DEFAULT_IMPLEMENT

            if r.get("selected") == DEFAULT_IMPLEMENT:  # not an implement: none is selected (presets are kept under it)
                text += f"\nselected: none ({DEFAULT_IMPLEMENT!r}: the hitch without an implement's data)"
            _print(args, r, text)
        elif args.action == "define":
            body: dict[str, Any] = {
                "name": args.name,
                "category": args.category,
                "mass_kg": args.mass,
                "com_m": list(args.com),
            }
            for key, value in (
                ("upper_height_m", args.upper_height),
                ("lowering_speed_m_s", args.lowering_speed),
                ("description", args.description),
            ):
                if value is not None:
                    body[key] = value
            if args.headland is not None:
                body["headland"] = args.headland
            r = c.request("implements/define", body)
            cleared = r.get("cleared") or []
            said = f"defined {r['defined']}"
            if cleared:  # a define replaces the whole record: what it had and this one leaves out is gone
                said += (
                    f"; cleared {', '.join(cleared)} (a define replaces the whole record: give them again to keep them)"
                )
            _print(args, r, said)
        elif args.action == "select":
            r = c.request("implements/select", {"name": args.name})
            none = r["selected"] == "default"  # bridge.service.store.DEFAULT_IMPLEMENT (not imported for --help)
            _print(args, r, "selected none (the hitch alone)" if none else f"selected {r['selected']}")
        elif args.action == "delete":
            r = c.request("implements/delete", {"name": args.name})
            _print(args, r, f"deleted {r['deleted']}")
        else:
            r = c.request(f"implements/{args.action}", {})
            _print(args, r, f"{r['implement']}: transport lock {'on' if r['transport_locked'] else 'off'}")
        return 0

    return _run(args, run)


def _cmd_quick(args) -> int:
    key = "hitch/raise" if args.command == "raise" else "hitch/return"
    body = {} if args.speed_scale is None else {"speed_scale": args.speed_scale}

    def run(c) -> int:
        r, final = _motion(args, c, lambda: c.request(key, body), lambda reply: _wait_motion(args, c, reply))
        if final is not None:
            r = {**r, "final": final}
        target = r.get("headland") if args.command == "raise" else r.get("last_work")
        ended, status = _ended(final)
        work = ""
        if r.get("work_paused"):
            w = r["work_paused"]
            work = f"; work session {w['session']} paused ({w['mode']}, z {w['z_operator']:.3f} m): return resumes it"
        elif r.get("resumes_work"):
            work = "; work starts again when it arrives"
        _print(
            args,
            r,
            f"motion {r['motion_id']}: {args.command} to {_fmt_pose(target)}, {r['duration']:.2f} s" + work + ended,
        )
        return status

    return _run(args, run)


def _com(text: str) -> tuple[float, float, float]:
    parts = text.split(",")
    check = finite_float("--com")
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"--com needs x,y,z [m] (3 numbers), got {text!r}")
    return check(parts[0]), check(parts[1]), check(parts[2])


def _cmd_switch(args) -> int:
    """Send the operator switch's frame (ISO 11783-7 PGN 65090) on a CAN bus, as a fender switch would."""
    from bridge.link.hitch_switch import press_frames

    if args.service:

        def run(c) -> int:
            r = c.request("sim/switch", {"position": args.position})
            _print(args, r, f"hitch switch: the service's simulated tractor sent {', '.join(r['sent'])}")
            return 0

        return _run(args, run)
    bus = open_bus(args.interface, args.channel)
    try:
        for frame in press_frames(args.position):  # a momentary press: released, the position, released
            bus.send(frame)
    finally:
        bus.shutdown()
    print(f"hitch switch: sent {args.position} (PGN 65090 rear hitch position command) on {args.interface}")
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("implement", help="implements: list, define, select, transport lock")
    _client_options(p, outer=True)
    acts = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    _client_command(acts, "list", "stored and tractor-profile implements (* selected)", _cmd_implement)
    q = acts.add_parser("define", help="define (or replace) an implement")
    q.add_argument("name")
    q.add_argument("--category", required=True, help="ISO 730 category: 1N 1 2N 2 3N 3 4N 4")
    q.add_argument("--mass", type=finite_float("--mass"), required=True, help="mass [kg] (not t), > 20 and <= 20000")
    q.add_argument("--com", type=_com, required=True, help="centre of mass x,y,z in the implement frame [m]")
    q.add_argument("--upper-height", type=finite_float("--upper-height"), default=None, help="upper height [m]")
    q.add_argument("--lowering-speed", type=finite_float("--lowering-speed"), default=None, help="[m/s]")
    q.add_argument("--headland", type=parse_pose_arg, default=None, help="x=..,z=..,roll=..,pitch=.. (full pose)")
    q.add_argument("--description", default=None)
    _client_options(q)
    q.set_defaults(handler=_cmd_implement)
    select = "select an implement, or 'default' for none (refused while moving)"
    for action, text in (("select", select), ("delete", "delete one")):
        _client_command(acts, action, text, _cmd_implement, "name")
    for action, text in (("lock", "transport lock on: no motion but stop"), ("unlock", "transport lock off")):
        _client_command(acts, action, text, _cmd_implement)
    for name, text in (("raise", "quick raise to the headland pose"), ("return", "return to the last work pose")):
        q = _client_command(sub, name, text, _cmd_quick)
        q.add_argument("--speed-scale", type=finite_float("--speed-scale"), default=None)
        _wait_options(q)
    q = sub.add_parser("switch", help="send the operator's rear hitch raise / lower switch frame on a CAN bus")
    q.add_argument("position", choices=("raise", "lower", "released"))
    q.add_argument("--interface", choices=INTERFACES, default="remote", help="python-can interface (default remote)")
    q.add_argument("--channel", default=None, help="channel (remote: the hub's URL, default ws://127.0.0.1:54701/)")
    q.add_argument(
        "--service",
        action="store_true",
        help="let the service's simulated tractor send one press (sim/switch; a press: released, position, released)",
    )
    _client_options(q)
    q.set_defaults(handler=_cmd_switch)
