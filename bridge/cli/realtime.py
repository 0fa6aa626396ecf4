"""Real-time scheduling of the CLI commands that are a control path or a computer of their own.

``hitch can-hub`` and ``hitch ecu-sim`` stand for the bus and the ECU's computer of the twin in its own
process; ``hitch calibrate sensors`` on a bus is the planner's control path without the service. Each puts
its threads under ``SCHED_FIFO`` where permitted (:func:`bridge.service.scheduling.process_to_fifo`), as the
service does its control path; ``--no-realtime`` opts out.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Iterator
from contextlib import contextmanager

from bridge.cli.output import console

__all__ = ["add_realtime_option", "realtime_process"]


@contextmanager
def realtime_process(args: argparse.Namespace, priority: int, who: str) -> Iterator[None]:
    """This command's threads under ``SCHED_FIFO`` at ``priority`` where permitted (not with ``--no-realtime``),
    for the ``with`` block: the calling thread now, the threads it starts inside inherit it; the calling thread
    gets its own policy back at the end (a command run in-process — a test's ``main([...])`` — leaves the
    interpreter as it was). A twin process or a hub at ordinary priority let a busy computer delay its frames
    past the link's limits (:func:`bridge.service.scheduling.process_to_fifo`). Not permitted: a note on
    stderr, and it runs on."""
    if getattr(args, "no_realtime", False):
        yield
        return
    from bridge.service.scheduling import process_to_fifo

    own: tuple[int, os.sched_param] | None
    try:
        own = os.sched_getscheduler(0), os.sched_getparam(0)
    except (AttributeError, OSError):
        own = None
    why = process_to_fifo(priority)
    if why is not None:
        console(stderr=True).print(
            f"{who}: runs at ordinary priority (real-time SCHED_FIFO {why}: run as root or with CAP_SYS_NICE, or "
            "with chrt, for steady timing on a busy computer)",
            markup=False,
            highlight=False,
        )
    try:
        yield
    finally:
        if why is None and own is not None:
            try:
                os.sched_setscheduler(0, *own)
            except OSError:  # lowering is always permitted; nothing else to do
                pass


def add_realtime_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--no-realtime",
        action="store_true",
        help="run at ordinary priority (default: its threads under SCHED_FIFO where permitted, root or "
        "CAP_SYS_NICE, so a busy computer does not delay its frames)",
    )
