"""The faults the motion controller holds, and the policy that raises and clears them (``docs/faults.md``).

A :class:`FaultBook` keeps one :class:`~bridge.service.motion.types.Fault` per name. Every control cycle
:meth:`FaultBook.review` compares the link's latched faults with what it holds:

* a fault the link raised since the last cycle is taken (its own reason from the link) and the cycle must
  abort everything (an old plan never resumes): the review returns a ``fault`` event;
* ``stale_measurement`` and ``ecu_heartbeat``
  (:data:`~bridge.service.motion.types.SELF_CLEARING_FAULTS`) are released once their cause has been absent
  for :data:`~bridge.service.motion.types.FAULT_CLEAR_AFTER_S` without a break (a ``fault_cleared`` event,
  ``by: fresh data``); a cleared one whose cause comes back while the link still latches it is raised again;
* every other fault latches until :meth:`FaultBook.acknowledge` (``faults/ack``), which keeps the ones whose
  cause the link still sees (another node holds or uses our address).

The controller's own faults (``internal``, ``following_error``) come in through :meth:`FaultBook.hold`.
While anything is held, motion is refused (:meth:`FaultBook.refusal`). The book does no locking: the
controller calls it under its lock.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from bridge.link.state import LinkStatus
from bridge.service.motion.types import FAULT_CLEAR_AFTER_S, SELF_CLEARING_FAULTS, Event, Fault

__all__ = ["FaultBook", "link_reason"]


def link_reason(name: str, status: LinkStatus) -> str:
    """The link's reason for fault ``name``: the one it recorded for that name (a guess from the fault's last
    word picked another fault's text: stale_measurement showed references_lost's, a new user's report)."""
    own = status.faults.reason_of(name)
    if own is not None:
        return own
    hint = name.replace("_", " ").split()[-1]
    for r in status.faults.reasons:
        if hint.lower() in r.lower():
            return r
    return "; ".join(status.faults.reasons) or name


class FaultBook:
    """What the controller holds, by name, in the order raised; ``stale_after_s``: the link's measurement
    age limit [s] (the cause of ``stale_measurement``)."""

    def __init__(self, stale_after_s: float):
        self.stale_after_s = float(stale_after_s)
        self._held: dict[str, Fault] = {}
        self._link_reported: tuple[str, ...] = ()  # the link's latched faults seen at the last review
        self._fresh_since: float | None = None  # every self-clearing cause absent since [s]
        #: faults held from the data before the link latched them (their reason is replaced by the link's own)
        self._ahead_of_link: set[str] = set()

    # ------------------------------------------------------------------ reading
    def __bool__(self) -> bool:
        return bool(self._held)

    @property
    def held(self) -> tuple[Fault, ...]:
        """The faults held, in the order raised."""
        return tuple(self._held.values())

    @property
    def names(self) -> list[str]:
        return list(self._held)

    def refusal(self, kind: str) -> str | None:
        """Why a ``kind`` motion is refused while faults are held, naming each with its reason and what clears
        it (None: nothing held)."""
        if not self._held:
            return None
        held = self.held
        latched = [f.name for f in held if f.latches]
        what = "; ".join(f"{f.name} ({f.reason})" for f in held)
        hint = (
            f"acknowledge {', '.join(latched)} with faults/ack once the cause is fixed"
            if latched
            else "it clears itself once the ECU's data is fresh again"
        )
        return f"{kind} refused: fault held: {what}; {hint}"

    # ------------------------------------------------------------------ raising and clearing
    def hold(self, fault: Fault) -> Event:
        """Hold the controller's own ``fault`` (it latches or not as it says); its ``fault`` event."""
        self._held[fault.name] = fault
        self._fresh_since = None
        return {
            "event": "fault",
            "faults": self.names,
            "new": [fault.name],
            "ack_required": fault.latches,
            "message": fault.reason,
        }

    def latch_link(self, status: LinkStatus, now: float) -> None:
        """Hold the link's latched faults that do not clear themselves (after the link refused a reference)."""
        for name in status.faults.active():
            if name not in SELF_CLEARING_FAULTS and name not in self._held:
                self._held[name] = Fault(name, link_reason(name, status), True, now)

    def cause_present(self, name: str, status: LinkStatus, now: float, link_faults: tuple[str, ...]) -> bool:
        """Whether the cause of self-clearing fault ``name`` is there at ``now`` (judged from the data itself)."""
        if name == "stale_measurement":
            ls = status.state
            return ls is None or ls.age_s(now) > self.stale_after_s
        if name == "ecu_heartbeat":
            return not status.heartbeat.healthy
        return name in link_faults

    def _stale_ahead_of_link(self, status: LinkStatus, now: float) -> str | None:
        """Why the measurement is stale at ``now`` when the link has not latched ``stale_measurement`` yet (it
        does so in its own poll, on its own thread, every ``check_period_s``): a cycle between the crossing and
        that poll said ``online: false`` with no fault and the motion running (a review). None: not stale, or
        no measurement yet (before the first one the link raises nothing either)."""
        ls = status.state
        if ls is None or "stale_measurement" in self._held:
            return None
        age = ls.age_s(now)
        if age <= self.stale_after_s:
            return None
        return f"the ECU measurements are {age:.3f} s old (limit {self.stale_after_s:g} s)"

    def review(self, status: LinkStatus, now: float) -> Event | None:
        """One cycle of the policy at clock time ``now`` [s]: a ``fault`` event when the link raised something
        new, or the measurement went stale before the link's own poll latched it (the caller aborts everything
        and stops the stream), a ``fault_cleared`` event when self-clearing faults were released, else None."""
        link_faults = status.faults.active() if status.faults.any else ()
        for f in link_faults:  # held from the data first: the link's own reason now (it names the sender, why)
            if f in self._ahead_of_link and f in self._held:
                self._held[f] = replace(self._held[f], reason=link_reason(f, status))
                self._ahead_of_link.discard(f)
        raised = [f for f in link_faults if f not in self._link_reported and f not in self._held]
        for f in link_faults:  # cleared here, still latched in the link, and its cause came back
            if f in SELF_CLEARING_FAULTS and f not in self._held and f not in raised:
                if self.cause_present(f, status, now, link_faults):
                    raised.append(f)
        self._link_reported = link_faults
        reasons = {f: link_reason(f, status) for f in raised}
        if "stale_measurement" not in raised:
            ahead = self._stale_ahead_of_link(status, now)
            if ahead is not None:
                raised.append("stale_measurement")
                reasons["stale_measurement"] = ahead
                self._ahead_of_link.add("stale_measurement")
        if raised:
            for f in raised:
                self._held[f] = Fault(f, reasons[f], f not in SELF_CLEARING_FAULTS, now)
            self._fresh_since = None
            # the new faults' own reasons (every reason the link held repeated those of faults acknowledged
            # long ago: a safety trial's ecu_heartbeat event began with references_lost's text)
            return {
                "event": "fault",
                "faults": self.names,
                "new": raised,
                "ack_required": any(f not in SELF_CLEARING_FAULTS for f in raised),
                "message": "; ".join(self._held[f].reason for f in raised),
            }
        clearing = [n for n, f in self._held.items() if not f.latches]
        if not clearing:
            return None
        if any(self.cause_present(n, status, now, link_faults) for n in clearing):
            self._fresh_since = None
            return None
        if self._fresh_since is None:
            self._fresh_since = now
        if now - self._fresh_since < FAULT_CLEAR_AFTER_S - 1e-9:
            return None
        for n in clearing:
            del self._held[n]
            self._ahead_of_link.discard(n)
        self._fresh_since = None
        return {"event": "fault_cleared", "cleared": clearing, "by": "fresh data", "faults": self.names}

    def acknowledge(self, status: LinkStatus) -> tuple[str, ...]:
        """Clear the latched faults whose cause the link no longer sees (``LinkStatus.fault_causes``: our
        address held or used by another node); those stay, and ``address_lost`` then says what holds it. The
        names cleared (the caller clears the link's flags of these and posts ``fault_cleared``)."""
        causes = set(getattr(status, "fault_causes", ()) or ())
        acked = tuple(n for n, f in self._held.items() if f.latches and n not in causes)
        for n in acked:
            del self._held[n]
        # one raised again after this ack is new to the link and reported as a fault
        self._link_reported = tuple(n for n in self._link_reported if n not in acked)
        problem = getattr(status, "address_problem", "")
        held = self._held.get("address_lost")
        if held is not None and problem:
            self._held["address_lost"] = replace(held, reason=problem)
        return acked

    def cleared_event(self, acked: tuple[str, ...]) -> dict[str, Any]:
        """The ``fault_cleared`` event of an acknowledge that cleared ``acked``."""
        return {"event": "fault_cleared", "cleared": list(acked), "by": "ack", "faults": self.names}
