"""The ``hitch`` command line: every sub-command, arm included. Nothing outside ``bridge.cli`` imports it.

``hitch stop`` (the program's first argument ``stop``) is put under ``SCHED_FIFO`` where permitted (root or
CAP_SYS_NICE) before the command line is imported: the imports (0.75 s idle) ran at ordinary priority and took
2.3–3.2 s with four busy processes on two cores — 7–10 s on a loaded field computer (a field trial) — before the
stop left; now 0.8 s either way.
"""

import sys


def _stop_first() -> None:
    if sys.argv[1:2] == ["stop"]:  # the hitch program (or python -m bridge.cli) asked to stop
        from bridge.service.scheduling import CLIENT_RT_PRIORITY, caller_to_fifo

        caller_to_fifo(CLIENT_RT_PRIORITY)  # not permitted: runs as before (the client says why with --realtime)


_stop_first()

try:  # after the stop's priority (module docstring)
    from bridge.cli.main import build_parser, main
except KeyboardInterrupt:  # Ctrl-C while the command line loads (~2 s on a loaded computer): no traceback
    sys.stderr.write("hitch: interrupted while starting\n")
    raise SystemExit(130) from None

__all__ = ["build_parser", "main"]
