"""The seam between the motion controller and the CAN link: :class:`LinkPort`.

Exactly what :class:`~bridge.service.motion.controller.MotionController` uses of the link;
:class:`bridge.link.can_link.CanLink` satisfies it structurally (no inheritance), and so can a
test double. Times are the link's clock [s]; actuators are SI in actuator order (lift [rad];
tilt, top, left, right [m]).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Protocol

import numpy as np

from bridge.link.state import LinkConfig, LinkState, LinkStatus

__all__ = ["LinkPort"]


class LinkPort(Protocol):
    """The CAN link as the motion controller sees it."""

    @property
    def config(self) -> LinkConfig:
        """The link's settings (the controller reads ``stale_after_s``)."""
        ...

    def status(self, now_s: float) -> LinkStatus:
        """A consistent snapshot at ``now_s``: claim, measurements, faults, heartbeat, counters."""
        ...

    def latest_state(self) -> LinkState | None:
        """The newest measured state (None before the first complete measurement)."""
        ...

    def check_reference(self, actuators: np.ndarray) -> object:
        """Check a reference against every hard limit and the AD range, sending nothing;
        raises :class:`bridge.link.state.ReferenceRefused` naming the limit."""
        ...

    def send_reference(self, actuators: np.ndarray, now_s: float) -> object:
        """Check and stream a reference from ``now_s`` on; raises
        :class:`bridge.link.state.ReferenceRefused` (a limit) or
        :class:`bridge.link.state.LinkFaultError` (the link cannot move the machine)."""
        ...

    def stop_motion(self) -> None:
        """End the reference stream (the ECU watchdog then zeroes the valves)."""
        ...

    def clear_faults(self, now_s: float, names: Iterable[str] | None = None) -> object:
        """Acknowledge the latched faults (only ``names`` when given) whose causes are gone at ``now_s``;
        never starts the stream. One raised again afterwards is reported afresh."""
        ...
