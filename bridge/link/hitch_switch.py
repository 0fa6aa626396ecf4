"""The operator's rear hitch raise / lower switch on the CAN bus (``docs/implements.md``).

ISO 11783-7 *Hitch and PTO commands* (PGN 65090, 0xFE42; the rear hitch position command SPN 1875,
0.4 %/bit) from the operator switch (source address 229, 0xE5): a command of at least
:data:`RAISE_AT` is the switch's raise position, at most :data:`LOWER_AT` its lower position, anything
between (or not available) the released switch. :class:`SwitchEdges` turns the positions into
commands: an edge into raise → ``"raise"``, an edge into lower → ``"return"``; the first frame only
sets the position (a switch resting at lower when the service starts returns nothing), and holding a
position repeats nothing. :class:`HitchSwitchNode` is the bus node (for a
:class:`~bridge.link.realtime.SharedBusNodes` runner): it decodes the frames and hands each command
to ``on_command`` (called on the CAN thread: it must only queue work, never plan). An edge whose frame is
older than :data:`MAX_EDGE_AGE_S` when the node reads it (its bus stamp against the wall clock: the frame
waited in the bus while the service stalled) gives no command — a "lower" pressed seconds ago must not
start a return and resume work when the service runs again (a safety trial) — and goes to ``on_stale``.
:func:`press_frames` / :func:`press_switch` are the twin's side: the frames of one momentary press
(released, the position, released: one edge whatever the switch's last position), as the service's
``sim/switch`` key makes the simulated tractor send them.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Literal

import can

from bridge.isobus.codec import decode_frame, encode
from bridge.isobus.j1939 import decode_id
from bridge.isobus.messages import OPERATOR_SWITCH_ADDRESS, PGN_HITCH_PTO_COMMANDS, CodecError, HitchCommand
from bridge.link.realtime import ReceivingNode
from bridge.link.state import frame_stamp

__all__ = [
    "RAISE_AT",
    "LOWER_AT",
    "SwitchPosition",
    "switch_position",
    "switch_frame",
    "press_frames",
    "press_switch",
    "SwitchEdges",
    "HitchSwitchNode",
    "MAX_EDGE_AGE_S",
]

#: an edge read this long after its frame's bus stamp [s] gives no command (module docstring); a press is
#: read within a few ms, under CPU load within tens of ms
MAX_EDGE_AGE_S = 0.5

#: rear hitch position command (fraction) from which the switch counts as raised / lowered
RAISE_AT = 0.9
LOWER_AT = 0.1
SwitchPosition = Literal["raise", "lower", "released"]
Command = Literal["raise", "return"]


def switch_position(rear_position: float | None) -> SwitchPosition:
    """The switch position a rear hitch position command (0..1, None: not available) stands for."""
    if rear_position is None:
        return "released"
    if rear_position >= RAISE_AT - 1e-9:
        return "raise"
    if rear_position <= LOWER_AT + 1e-9:
        return "lower"
    return "released"


def switch_frame(position: SwitchPosition, source: int = OPERATOR_SWITCH_ADDRESS) -> can.Message:
    """The frame an operator switch in ``position`` sends (raise: 100 %, lower: 0 %, released: not available)."""
    value = {"raise": 1.0, "lower": 0.0, "released": None}
    if position not in value:
        raise CodecError(f"switch position must be raise, lower or released, got {position!r}")
    return encode(HitchCommand(rear_position=value[position]), source=source)


def press_frames(position: SwitchPosition, source: int = OPERATOR_SWITCH_ADDRESS) -> list[can.Message]:
    """The frames of one momentary press into ``position`` from the released switch: released, the
    position, released (exactly one edge into raise / lower even right after the service started, when
    the first frame only sets the position); ``released``: the released frame alone."""
    if position not in ("raise", "lower", "released"):
        raise CodecError(f"switch position must be raise, lower or released, got {position!r}")
    if position == "released":
        return [switch_frame("released", source)]
    return [switch_frame("released", source), switch_frame(position, source), switch_frame("released", source)]


def press_switch(bus: can.BusABC, position: SwitchPosition) -> list[str]:
    """Send :func:`press_frames` of ``position`` on ``bus`` (in order); the positions sent."""
    sent: list[str] = []
    for frame in press_frames(position):
        bus.send(frame)
        d = decode_frame(frame).payload
        sent.append(switch_position(d.rear_position if isinstance(d, HitchCommand) else None))
    return sent


class SwitchEdges:
    """Edges of the switch position → commands (module docstring)."""

    def __init__(self) -> None:
        self.position: SwitchPosition | None = None  # None: no frame yet

    def update(self, position: SwitchPosition) -> Command | None:
        previous, self.position = self.position, position
        if previous is None or previous == position:
            return None
        return "raise" if position == "raise" else "return" if position == "lower" else None


class HitchSwitchNode(ReceivingNode):
    """Bus node for the operator switch (module docstring). ``source``: the switch's address (None: any)."""

    def __init__(
        self,
        bus: can.BusABC,
        on_command: Callable[[Command], None] | None = None,
        *,
        source: int | None = OPERATOR_SWITCH_ADDRESS,
    ) -> None:
        self._bus = bus
        self.on_command = on_command
        self.source = source
        self.edges = SwitchEdges()
        self._now = 0.0
        self.frames = self.ignored = self.commands = self.stale = 0
        #: called with (command, age [s]) for an edge too old to act on (on the CAN thread: queue work only)
        self.on_stale: Callable[[Command, float], None] | None = None
        self.max_age_s = MAX_EDGE_AGE_S
        self.wall_clock: Callable[[], float] = time.time  # the bus stamps' clock

    def take(self, frame: can.Message, now_s: float) -> Command | None:
        """One frame at ``now_s``; the command it gives (None: none, or not a switch frame)."""
        self._now = now_s
        if not frame.is_extended_id or frame.is_error_frame or frame.is_remote_frame:
            return None
        try:
            ident = decode_id(frame.arbitration_id)
        except ValueError:
            return None
        if ident.pgn != PGN_HITCH_PTO_COMMANDS or (self.source is not None and ident.source_address != self.source):
            return None
        try:
            payload = decode_frame(frame).payload
        except CodecError:
            self.ignored += 1
            return None
        if not isinstance(payload, HitchCommand):
            return None
        self.frames += 1
        cmd = self.edges.update(switch_position(payload.rear_position))  # the position is taken, old or not
        if cmd is None:
            return None
        stamp = frame_stamp(frame)
        age = None if stamp is None else self.wall_clock() - stamp
        if age is not None and age > self.max_age_s:
            self.stale += 1
            stale_hook = self.on_stale
            if stale_hook is not None:
                stale_hook(cmd, age)
            return None
        self.commands += 1
        hook = self.on_command
        if hook is not None:
            hook(cmd)
        return cmd
