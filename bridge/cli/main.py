"""The ``hitch`` command line: argument parsing, dispatch and error reporting.

Every command prints human-readable text by default and JSON with ``--json``. An error the
project raises on purpose (any :class:`~planner.errors.HitchError`: bad arguments, a profile
that does not validate, a pose out of reach, a refused request …) exits with status 2 and one
line on stderr (``hitch: error: …``). Any other exception is a bug and keeps its traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import threading
from collections.abc import Iterator, Sequence
from importlib import metadata
from typing import NoReturn

from bridge.cli import calibrate as cli_calibrate
from bridge.cli import commissioning as cli_commissioning
from bridge.cli import headland as cli_headland
from bridge.cli import ik as cli_ik
from bridge.cli import implements as cli_implements
from bridge.cli import model as cli_model
from bridge.cli import plan as cli_plan
from bridge.cli import records as cli_records
from bridge.cli import router as cli_router
from bridge.cli import service as cli_service
from bridge.cli import sim as cli_sim
from bridge.cli import stability as cli_stability
from bridge.cli import track as cli_track
from bridge.cli import work as cli_work
from bridge.cli.arm import add_arm_parser
from bridge.cli.errors import CLIError
from planner.errors import HitchError

__all__ = ["main", "build_parser", "CLIError"]

PROG = "hitch"
#: the installed distribution (``[project] name`` in pyproject.toml) whose version ``hitch --version`` prints
DISTRIBUTION = "hitch-planner"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:  # one clear line instead of usage + message
        # main() prints "hitch: error: …"; a subcommand's parser names itself ("hitch fk: …"), the top level does not
        raise CLIError(message if self.prog == PROG else f"{self.prog}: {message}")

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        parsed, rest = super().parse_known_args(args, namespace)
        if self.prog == PROG:  # the whole line is parsed: the client options neither level gave get their defaults
            cli_service.apply_client_option_defaults(parsed)
        return parsed, rest


def package_version() -> str:
    """The installed ``hitch-planner`` distribution's version (``unknown`` when run from an uninstalled tree)."""
    try:
        return metadata.version(DISTRIBUTION)
    except metadata.PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog=PROG, description="Motion planning for an advanced tractor rear hitch (SI units).")
    parser.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    cli_model.add_commands(sub)
    cli_ik.add_commands(sub)
    cli_plan.add_commands(sub)
    cli_stability.add_commands(sub)
    cli_sim.add_commands(sub)
    cli_headland.add_maneuver_actions(cli_service.add_commands(sub))  # record, pause, resume, skip
    cli_headland.add_lines_command(sub)
    cli_track.add_commands(sub)
    cli_records.add_commands(sub)
    cli_router.add_commands(sub)
    cli_calibrate.add_commands(sub)
    cli_commissioning.add_commands(sub)
    cli_implements.add_commands(sub)
    cli_work.add_commands(sub)
    add_arm_parser(sub)
    return parser


def one_line(text: str) -> str:
    """A multi-line error as one line: its lines stripped and joined by "; ", a heading that ends in
    ":" followed by a space ("invalid profile p.toml: geometry.x = …; geometry.y = …")."""
    out = ""
    for line in (part.strip() for part in text.splitlines()):
        if not line:
            continue
        out += line if not out else (" " if out.endswith(":") else "; ") + line
    return out


@contextlib.contextmanager
def _term_interrupts(args: argparse.Namespace, terminated: list[int]) -> Iterator[None]:
    """For a command that says what an interruption leaves (``on_interrupt``) or that moves the hitch while it
    runs (``term_interrupts``: a motion waited for, a held jog), SIGTERM (a supervisor, ``kill``, ``timeout``)
    interrupts it as Ctrl-C does, so its clean-up runs (a motion is stopped) and it says so; before, a sensor
    calibration over a bus ended silently and ``timeout 5 hitch goto … --wait`` left the motion going. Only in
    the main thread, and the old handler comes back after."""
    handled = callable(getattr(args, "on_interrupt", None)) or bool(getattr(args, "term_interrupts", False))
    if not handled or threading.current_thread() is not threading.main_thread():
        yield
        return

    def on_term(signum: int, _frame: object) -> None:
        terminated.append(signum)
        raise KeyboardInterrupt

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def main(argv: list[str] | None = None) -> int:
    """The ``hitch`` command. Called as the program (``argv`` None) after a command that ran the service
    (``args.end_process``), the process ends at once with the status once its output is flushed: the service
    closed everything it opened, and the interpreter's finalisation would only list the Ruckig objects still
    referenced by its threads' frames ("nanobind: leaked …", ~40 lines an operator reads as a crash)."""
    args = None
    terminated: list[int] = []
    try:
        args = build_parser().parse_args(argv)
        with _term_interrupts(args, terminated):
            code = int(args.handler(args) or 0)
        if argv is None and getattr(args, "end_process", False):
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(code)
        return code
    except HitchError as exc:  # CLIError, ProfileError, KinematicsError, PlanError, ServiceError, …
        print(f"hitch: error: {one_line(str(exc))}", file=sys.stderr)
    except KeyboardInterrupt:  # a command that keeps something says what (``on_interrupt``: its sentence)
        said = getattr(args, "on_interrupt", None)
        if callable(said):
            print(f"hitch: {'terminated' if terminated else 'interrupted'}: {said(args)}", file=sys.stderr)
        return 143 if terminated else 130
    except BrokenPipeError:  # e.g. `hitch plan --json | head`
        sys.stderr.close()
        return 0
    return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
