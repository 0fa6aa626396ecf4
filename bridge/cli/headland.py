"""Headland commands: ``hitch maneuver record start|stop [--save NAME]``, ``hitch maneuver
pause|resume|skip`` and ``hitch lines save NAME FILE.geojson|list|delete NAME`` (docs/maneuvers.md).

Registered by :func:`bridge.cli.main.build_parser`: :func:`add_maneuver_actions` on the ``maneuver``
sub-parsers :func:`bridge.cli.service.add_commands` returns, :func:`add_lines_command` on the top level.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from bridge.cli.errors import CLIError
from bridge.cli.service import _client_command, _client_options, _deadline, _print, _run, add_deadline_option, step_text

__all__ = ["add_maneuver_actions", "add_lines_command"]

#: the largest GeoJSON file ``hitch lines save`` reads [bytes]
MAX_GEOJSON_BYTES = 4 * 1024 * 1024


def add_maneuver_actions(ms: Any) -> None:
    """``record start|stop`` and ``pause``, ``resume``, ``skip`` under ``hitch maneuver``."""
    q = ms.add_parser("record", help="teach-in: record goto, preset and jog commands into a script")
    _client_options(q, outer=True)
    rs = q.add_subparsers(dest="record_action", required=True, parser_class=type(q))
    _client_command(rs, "start", "start recording", _cmd_record)
    r = _client_command(rs, "stop", "stop recording and print the script (YAML)", _cmd_record)
    r.add_argument("--save", metavar="NAME", default=None, help="also save the script as maneuver NAME")
    r.add_argument(
        "--replace",
        action="store_true",
        help="with --save: replace a maneuver NAME (else refused, and the recording goes on)",
    )
    for action, text in (
        ("pause", "pause the running maneuver (the hitch brakes to rest and holds)"),
        ("resume", "resume the paused maneuver (its motion step is planned again from the pose now)"),
        ("skip", "end the step in progress and go on with the next"),
    ):
        q = _client_command(ms, action, text, _cmd_control)
        if action != "pause":  # resume and skip start motion; a pause only brakes (docs/maneuvers.md)
            add_deadline_option(
                q, "it and the motion it leads to must start within this, else refused busy or the maneuver aborts"
            )


def add_lines_command(sub: Any) -> None:
    """``hitch lines save NAME FILE|list|delete NAME``."""
    p = sub.add_parser("lines", help="field-boundary and headland lines (GeoJSON) for maneuver wait_for line")
    _client_options(p, outer=True)
    ls = p.add_subparsers(dest="action", required=True, parser_class=type(p))
    q = _client_command(
        ls, "save", "save the LineString(s) of a GeoJSON file (one line: under NAME)", _cmd_lines, "name", "file"
    )
    q.add_argument("--replace", action="store_true", help="replace lines of those names (else refused: in_use)")
    _client_command(ls, "list", "the saved lines and the tractor's position", _cmd_lines)
    q = _client_command(ls, "delete", "delete a line", _cmd_lines, "name")
    q.add_argument(
        "--force", action="store_true", help="delete it even while saved maneuvers wait for it (else refused: in_use)"
    )


def _cmd_record(args: Any) -> int:
    if getattr(args, "replace", False) and (args.record_action != "stop" or args.save is None):
        raise CLIError("--replace needs record stop --save NAME (the maneuver to replace)")

    def record(c: Any) -> int:
        if args.record_action == "start":
            r = c.request("maneuvers/record/start", {})
            _print(args, r, "recording (hitch maneuver record stop to end)")
            return 0
        body = {} if args.save is None else {"name": args.save, **({"replace": True} if args.replace else {})}
        r = c.request("maneuvers/record/stop", body)
        text = r["script"].rstrip("\n")
        if args.save is not None and "saved" in r:  # the service saved it (record/stop with a name)
            text += f"\n{'replaced' if r.get('replaced') else 'saved'} {r['saved']} ({r['steps']} steps)"
        elif args.save is not None:
            text += f"\nnot saved: {r.get('not_saved', 'the service did not save it')}"
        _print(args, r, text)
        return 0 if args.save is None or "saved" in r else 1

    return _run(args, record)


def _cmd_control(args: Any) -> int:
    def control(c: Any) -> int:
        r = c.request(f"maneuvers/{args.action}", _deadline(args))
        m = r.get("maneuver")
        if m is None:  # a skip of the last step finished the maneuver (docs/maneuvers.md)
            text = f"{args.action}: maneuver {r.get('maneuver_id')} finished (no step left)"
        else:
            state = "paused" if m.get("paused") else "running"
            text = f"{args.action}: maneuver {r.get('maneuver_id')} {state}, {step_text(m.get('step'))}"
        _print(args, r, text)
        return 0

    return _run(args, control)


def _read_geojson(path: str) -> Any:
    p = Path(path)
    if not p.is_file():  # /dev/null and a folder exist, but hold no GeoJSON
        raise CLIError(f"GeoJSON file {p} {'is not a regular file' if p.exists() else 'does not exist'}")
    if p.stat().st_size > MAX_GEOJSON_BYTES:
        raise CLIError(f"GeoJSON file {p} is larger than {MAX_GEOJSON_BYTES} bytes")
    try:
        return json.loads(p.read_text(encoding="utf-8").removeprefix("\ufeff"))
    except (ValueError, UnicodeDecodeError) as exc:
        raise CLIError(f"GeoJSON file {p} is not valid JSON: {exc}") from None


def _cmd_lines(args: Any) -> int:
    def lines(c: Any) -> int:
        if args.action == "save":
            geo = _read_geojson(args.file)
            r = c.request(
                "lines/save", {"name": args.name, "geojson": geo, **({"replace": True} if args.replace else {})}
            )
            replaced = r.get("replaced") or []
            _print(
                args, r, f"saved {', '.join(r['saved'])}" + (f" (replaced {', '.join(replaced)})" if replaced else "")
            )
        elif args.action == "list":
            r = c.request("lines/list", {})
            rows = [f"{ln['name']}: {ln['vertices']} vertices, crossed {ln['crossings']} time(s)" for ln in r["lines"]]
            pos = r.get("position")
            rows.append("position: -" if pos is None else f"position: east {pos[0]:+.2f} m, north {pos[1]:+.2f} m")
            g = r.get("gnss") or {}
            if g.get("rejected"):
                rows[-1] += f"; GNSS fixes {g['fixes']}, rejected {g['rejected']} (last: {g['last_rejection']})"
            _print(args, r, "\n".join(rows) if r["lines"] else "(no lines)\n" + rows[-1])
        else:
            r = c.request("lines/delete", {"name": args.name, **({"force": True} if args.force else {})})
            _print(args, r, f"deleted {r['deleted']}" + (f" (warning: {r['warning']})" if r.get("warning") else ""))
        return 0

    return _run(args, lines)
