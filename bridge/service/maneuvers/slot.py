"""The maneuver slot of the motion controller: at most one running maneuver.

Holds the :class:`~bridge.service.maneuvers.runner.ManeuverRunner` of the running maneuver with
the id and name the service gave it, forwards the control loop's ticks and tags the runner's
events (``maneuver_started``, ``maneuver_step``, ``maneuver_finished``, ``maneuver_aborted``) with
``maneuver_id`` for ``<prefix>/events``; :class:`ManeuverProgress` is the state message's
``maneuver``. Not thread-safe by itself: the controller's lock guards it.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

from bridge.service.maneuvers.language import ValidationResult
from bridge.service.maneuvers.runner import (
    AbortReason,
    Command,
    LineTrigger,
    LoopState,
    ManeuverRunError,
    ManeuverRunner,
)

__all__ = ["ManeuverSlot", "ManeuverProgress"]


@dataclass(frozen=True)
class ManeuverProgress:
    """The running maneuver: its name, id and the script step in progress; ``detail``: the step's ``kind``,
    ``paused`` and ``time_left`` [s] or ``distance_left`` [m] (waits, triggers). In JSON the id is
    ``maneuver_id`` (the id of its events) and, for older clients, also ``motion_id``: it names no
    motion (each step runs as a motion of its own, the state's top-level ``motion_id``)."""

    name: str | None
    motion_id: int | None
    step: int | None
    detail: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        mid = self.motion_id
        return {**self.detail, "name": self.name, "maneuver_id": mid, "motion_id": mid, "step": self.step}


class ManeuverSlot:
    """At most one running maneuver (see the module docstring)."""

    def __init__(self, lines: LineTrigger | None = None) -> None:
        self.lines = lines  # the line trigger of ``wait_for: {line: …}`` steps (GNSS), None: none
        self.runner: ManeuverRunner | None = None
        self.id: int | None = None
        self.name: str | None = None

    @property
    def running(self) -> bool:
        return self.runner is not None

    def start(self, validated: ValidationResult, name: str | None, maneuver_id: int) -> None:
        """Take a validated maneuver (the caller aborted the previous one)."""
        self.runner, self.id, self.name = ManeuverRunner(validated, lines=self.lines), maneuver_id, name

    def owns(self, runner: ManeuverRunner | None, request: int | None = None) -> bool:
        """Is ``runner`` still the running maneuver, waiting for the motion it asked for (not aborted,
        replaced, paused or its step skipped meanwhile)? With ``request`` (the ``goto`` command's
        :attr:`~bridge.service.maneuvers.runner.Command.request`): waiting for that very request — a
        plan made for a step that was skipped (or paused and resumed) meanwhile is not installed."""
        if runner is None or runner is not self.runner:
            return False
        return runner.awaiting_motion if request is None else runner.awaits(request)

    def abort(self, now: float, reason: AbortReason, message: str, events: list[dict[str, Any]]) -> None:
        """Abort the running maneuver (if any), appending its ``maneuver_aborted`` event."""
        if self.runner is not None:
            events.extend(self._tag(self.runner.abort(now, reason, message).events))
            self.runner = None

    def tick(
        self, now: float, loop: LoopState, distance_m: float | None, events: list[dict[str, Any]]
    ) -> Command | None:
        """One control tick; the runner's command (None when nothing runs). After ``stop`` or
        ``done`` the slot is empty."""
        if self.runner is None:
            return None
        cmd = self.runner.step(now, loop, distance_m)
        events.extend(self._tag(cmd.events))
        if cmd.action in ("stop", "done"):
            self.runner = None
        return cmd

    def progress(self) -> ManeuverProgress | None:
        """The running maneuver for the state message (None when none runs)."""
        if self.runner is None:
            return None
        return ManeuverProgress(self.name, self.id, self.runner.current_step, self.runner.progress())

    def control(self, action: str, now: float, events: list[dict[str, Any]]) -> bool:
        """``pause``, ``resume`` or ``skip`` the running maneuver, appending its event; True when the
        hitch must brake (pause; skip of a motion step). Raises ManeuverRunError when nothing runs."""
        r = self.runner
        if r is None:
            raise ManeuverRunError(f"{action}: no maneuver is running")
        if action == "pause":
            events.extend(self._tag([r.pause(now)]))
            return True
        if action == "resume":
            events.extend(self._tag([r.resume(now)]))
            return False
        if action == "skip":
            evs, motion = r.skip(now)
            events.extend(self._tag(evs))
            if r.status != "running":  # the last step was skipped: the maneuver is over (finished)
                self.runner = None
            return motion
        raise ManeuverRunError(f"action must be one of pause, resume, skip, got {action!r}")

    def _tag(self, events: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
        """The runner's events with the maneuver's id, and named as the state names it: the saved name it was
        run by (a script without ``name:`` gave ``"maneuver": null`` in every event and the black box: a new
        user's report), else the script's own."""
        named = {} if self.name is None else {"maneuver": self.name}
        return [{**e, "maneuver_id": self.id, **(named if "maneuver" in e else {})} for e in events]
