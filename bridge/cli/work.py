"""CLI commands of work control in the live service (``docs/soil.md``, "Work control"):

``hitch work settings [--mode … --draft-setpoint-kn … --blend … --sensitivity … --depth-min … --depth-max …
--slip-limit …|--no-slip-limit]`` reads (no option) or sets the selected implement's settings;
``hitch work start [--z M]``, ``hitch work stop`` (at the headland after a quick raise, where no session
runs: clears the paused work, so the return only goes back), ``hitch work resume`` (after a fallback: says
whether there was one to clear) and ``hitch work status``: client commands of ``hitch serve``. The draft
setpoint is given in kN at this boundary (``--draft-setpoint-kn``) and sent in N.
"""

from __future__ import annotations

from typing import Any

from bridge.cli.model import bounded_float, finite_float
from bridge.cli.service import _client_command, _client_options, _print, _run
from planner.work_control import DRAFT_SETPOINT_MAX_N

__all__ = ["add_commands", "format_resume", "format_status", "format_stop"]


def _opt(v: Any, fmt: str, unit: str) -> str:
    return "-" if v is None else f"{v:{fmt}} {unit}"


def format_status(status: dict[str, Any]) -> str:
    """The work block of the state (or a work reply) in words with units."""
    if not status.get("running"):
        head = f"work control: not running (mode {status.get('mode')})"
    else:
        head = (
            f"work control: session {status.get('session')}, mode {status.get('mode')}, active {status.get('active')}"
        )
    parts = [head]
    if status.get("fallback"):
        parts.append(f"fallback to position: {status['fallback']} (hitch work resume)")
    draft = status.get("draft_n")
    sp = status.get("draft_setpoint_n")
    parts.append(
        f"draft {_opt(None if draft is None else draft / 1000.0, '.2f', 'kN')} "
        f"(setpoint {_opt(None if sp is None else sp / 1000.0, '.2f', 'kN')}), "
        f"depth {_opt(status.get('depth_m'), '.3f', 'm')}, z setpoint {_opt(status.get('z_setpoint'), '.3f', 'm')}"
    )
    slip = status.get("slip")
    parts.append(
        f"slip {'unknown' if slip is None else f'{slip:.3f}'}, slip action {status.get('slip_action', 'none')}"
        + (f" ({status['slip_note']})" if status.get("slip_note") else "")
    )
    if status.get("limited"):
        parts.append("limited: " + ", ".join(f"{k}: {v}" for k, v in status["limited"].items()))
    return "\n".join(parts)


def _fmt_settings(s: dict[str, Any]) -> str:
    def num(k: str, per: float = 1.0) -> str:
        v = s.get(k)
        return "-" if isinstance(v, bool) or not isinstance(v, (int, float)) else f"{v / per:g}"

    slip = s.get("slip_limit")
    return (
        f"mode {s.get('mode', '-')}, draft setpoint {num('draft_setpoint_n', 1000.0)} kN, blend {num('blend')}, "
        f"sensitivity {num('sensitivity')}, depth {num('depth_min_m')}..{num('depth_max_m')} m, "
        f"slip limit {'off' if slip is None else num('slip_limit')}"
    )


def format_stop(reply: dict[str, Any]) -> str:
    """A ``work/stop`` reply in words: the session that stops, or — at the headland after a quick raise, where no
    session runs — the paused work it cleared (``stopping: false``, ``work_paused_cleared``, docs/implements.md)."""
    cleared = reply.get("work_paused_cleared")
    if reply.get("stopping") is False or (reply.get("session") is None and cleared is not None):
        if not isinstance(cleared, dict):
            return "no work session was running: nothing to stop"
        z = cleared.get("z_operator")
        what = ", ".join(
            part
            for part in (
                None if cleared.get("session") is None else f"session {cleared['session']}",
                None if cleared.get("mode") is None else f"{cleared['mode']} mode",
                None if not isinstance(z, (int, float)) else f"operator's z {z:.3f} m",
            )
            if part
        )
        return (
            f"no work session was running; paused work cleared{f' ({what})' if what else ''}: it will not restart on "
            "return (hitch return only goes back)"
        )
    mid = reply.get("motion_id")
    return f"work session {reply.get('session', '-')} stopping" + (f" (motion {mid})" if mid is not None else "")


def format_resume(reply: dict[str, Any]) -> str:
    """A ``work/resume`` reply (the work block as the resume found it) in words: what the resume does. It takes
    effect on the next control cycle, so a ``fallback`` in the reply is the one it clears; while its cause
    remains (no draft reading) the session falls back again at once — said, not a bare "resumed"."""
    session, mode, fallback = reply.get("session"), reply.get("mode"), reply.get("fallback")
    if reply.get("running") is False:
        head = "work resume: no work session is running (hitch work start): nothing resumed"
    elif fallback:
        head = (
            f"work session {session}: resume asked: {mode} control engages again on the next control cycle, "
            f"leaving the fallback to position ({fallback}); if that cause remains it falls back again at once "
            "(a work_fallback event; check with hitch work status)"
        )
    else:
        active = reply.get("active")
        head = f"work session {session}: nothing to resume: no fallback latched" + (
            f", {active} control in effect" if active else f" ({mode} mode)"
        )
    detail = format_status({**reply, "fallback": None}).split("\n")[1:]  # draft, depth, slip: the block's numbers
    return "\n".join([head, *detail])


def settings_body(args: Any) -> dict[str, Any]:
    """The ``work/settings`` payload of the given options (SI: the draft setpoint in N)."""
    body: dict[str, Any] = {}
    for key, value in (
        ("mode", args.mode),
        ("draft_setpoint_n", None if args.draft_setpoint_kn is None else args.draft_setpoint_kn * 1000.0),
        ("blend", args.blend),
        ("sensitivity", args.sensitivity),
        ("depth_min_m", args.depth_min),
        ("depth_max_m", args.depth_max),
        ("slip_limit", args.slip_limit),
    ):
        if value is not None:
            body[key] = value
    if args.no_slip_limit:
        body["slip_limit"] = None
    return body


def _cmd_work(args: Any) -> int:
    def run(c: Any) -> int:
        if args.action == "settings":
            r = c.request("work/settings", settings_body(args))
            what = "saved" if r.get("saved") else "settings"
            _print(args, r, f"{r.get('implement', '-')}: {what}: {_fmt_settings(r.get('settings') or {})}")
        elif args.action == "status":
            r = c.request("work/settings", {})
            _print(
                args,
                r,
                f"{r.get('implement', '-')}: {_fmt_settings(r.get('settings') or {})}\n"
                f"{format_status(r.get('status') or {})}",
            )
        elif args.action == "start":
            r = c.request("work/start", {} if args.z is None else {"z": args.z})
            mode = (r.get("work") or {}).get("mode", "-")
            _print(args, r, f"work session {r.get('session', '-')} started (motion {r.get('motion_id', '-')}): {mode}")
        elif args.action == "stop":
            r = c.request("work/stop", {})
            _print(args, r, format_stop(r))
        else:
            r = c.request("work/resume", {})
            _print(args, r, format_resume(r))
        return 0

    return _run(args, run)


def add_commands(sub: Any) -> None:
    p = sub.add_parser("work", help="work control: draft / mixed / float on the live service")
    _client_options(p, outer=True)
    acts = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    q = acts.add_parser("settings", help="read (no option) or set the selected implement's work settings")
    q.add_argument("--mode", choices=("position", "draft", "mixed", "float"), default=None)
    q.add_argument(
        "--draft-setpoint-kn",
        type=bounded_float("--draft-setpoint-kn", 0.0, DRAFT_SETPOINT_MAX_N / 1000.0, unit="kN"),
        default=None,
        help=f"(0, {DRAFT_SETPOINT_MAX_N / 1000.0:g}] kN",
    )
    q.add_argument("--blend", type=finite_float("--blend"), default=None, help="mixed: the draft share, [0, 1]")
    q.add_argument("--sensitivity", type=finite_float("--sensitivity"), default=None, help="[0.1, 2], 1 = nominal")
    q.add_argument("--depth-min", type=finite_float("--depth-min"), default=None, help="[m], 0 <= min < max")
    q.add_argument("--depth-max", type=finite_float("--depth-max"), default=None, help="[m], max <= 0.6")
    slip = q.add_mutually_exclusive_group()  # both given: the one meant is not known (the off switch won)
    slip.add_argument("--slip-limit", type=finite_float("--slip-limit"), default=None, help="(0, 0.5]")
    slip.add_argument("--no-slip-limit", action="store_true", help="switch slip limiting off")
    _client_options(q)
    q.set_defaults(handler=_cmd_work)
    q = _client_command(acts, "start", "start a work session with the selected implement's settings", _cmd_work)
    q.add_argument("--z", type=finite_float("--z"), default=None, help="operator's position setpoint [m]")
    for action, text in (
        ("stop", "end the work session smoothly"),
        ("resume", "the configured mode again after a fallback"),
        ("status", "settings and the live work block"),
    ):
        _client_command(acts, action, text, _cmd_work)
