"""Implements at runtime and the operator's quick raise / return to work (``docs/implements.md``).

:class:`ImplementService` is the logic behind the API keys ``implements/list|define|select|delete|lock|
unlock`` and ``hitch/raise`` / ``hitch/return`` (:class:`~bridge.service.api.ServiceAPI` routes them
here); the J1939 operator switch and the CLI end up in the same methods.

* **Implements** live in the store (:meth:`~bridge.service.store.HitchStore.save_implement`): name,
  ISO 730 category, mass [kg], centre of mass in the implement frame [m], the limits
  (:class:`planner.limits.implement_limits.ImplementLimits`: upper height, lowering speed, transport
  lock), the headland pose and the last work pose. The tractor profile's implement records are offered
  too (``source: "profile"``); selecting one stores it (without limits) first.
* **Selecting** an implement gives the motion controller its record and limits
  (``select_implement``: the guards' stability uses its mass and CoM, their limit checks its limits),
  is refused while the hitch moves (``busy``; send stop first), makes the presets keys use its presets
  and is persisted (setting ``selected_implement``): a restarted service selects it again (unless
  ``hitch serve --implement`` names another: the flag comes first, then the persisted selection, then the config
  file's implement, then none; :meth:`ImplementService.restore` takes the first of them that is defined and of the
  hitch's category, and says at start which runs and why each other named one was not taken,
  :attr:`ImplementService.warnings`). The planning
  processes get it too (:attr:`ImplementService.on_applied` → ``PlanningWorkers.set_implement``), so
  previews and maneuver validation plan with the selected implement's guard.
* ``sim/switch`` makes the simulated tractor send one press of the operator switch (in the service's
  threads or in the core process: :attr:`ImplementService.sim_switch`).
* **Quick raise** goes to the headland pose: the implement's own ``headland`` pose if defined, else its
  preset named :data:`HEADLAND_PRESET`; the pose the hitch was at when the raise was accepted becomes
  the implement's ``last_work`` pose (persisted). Only a raise that starts from a work position records
  one: not a raise that starts at the headland pose already, nor one that starts while the hitch is on its
  way between work and the headland because the last quick motion (a raise, or a return that has not
  arrived) is still running or was stopped or replaced — pressing raise twice, or raise / stop / raise,
  keeps the work pose. A raise after a return arrived, or after the operator moved the hitch since the
  last quick motion (a goto, preset, jog, track or work session, maneuver: their ``motion_started``
  events, which :meth:`ImplementService.on_event` watches; a stop is no such move; a mode change counts as
  one: the hitch left the planner's hands), records the pose it starts from. What was the last quick motion
  lives in memory: after a restart the first raise records its start pose (unless at the headland).
  **Return** goes to ``last_work``.
* **Transport lock** (``implements/lock``) forgets the work a quick raise paused (reply
  ``work_paused_cleared``): the lock means road transport, so the next return after the unlock only goes
  back to the work pose and never starts work control again by itself (``work/start`` does).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from typing import Any, Protocol

from bridge.service.motion.types import Event, MotionError, implement_selected_event, pose_dict
from bridge.service.schemas import ImplementDefine, QuickMove, RequestError, check_pose_in_workspace
from bridge.service.store import DEFAULT_IMPLEMENT, HitchStore, StoredImplement
from bridge.service.work import call_work
from planner.errors import HitchError, unit_hint
from planner.limits.implement_limits import ImplementLimits
from planner.limits.tractor import ImplementRecord, TractorProfile, load_tractor_profile
from planner.trajectory import TrajectoryPlanner

#: switch edges :attr:`ImplementService.switch_log` keeps
SWITCH_HISTORY = 16

__all__ = [
    "HEADLAND_PRESET",
    "SELECTED_SETTING",
    "ImplementService",
    "ImplementMotion",
    "record_of",
    "implement_handlers",
]

#: the preset a quick raise goes to when the implement has no headland pose of its own
HEADLAND_PRESET = "headland"
#: the store setting that keeps the selected implement across restarts
SELECTED_SETTING = "selected_implement"
#: a raise that starts this close to the headland pose [m or rad] keeps the previous work pose
_AT_HEADLAND = 5e-3


_NO_IMPLEMENT = "no implement is selected (select one first: `hitch implement select NAME`, key implements/select)"


class Dispatch(Protocol):
    """How the implement logic sends a request of its own (the API's ``handle``: the black box records it)."""

    def __call__(
        self, key: str, payload: bytes, user: str | None = None, *, received: float | None = None
    ) -> tuple[bool, dict[str, Any]]: ...


#: a ``hitch_switch`` event that reaches this process later than this after it was posted [s] is not acted on
#: (the service stalled; the switch node drops edges whose frames are older: bridge.link.hitch_switch)
SWITCH_EVENT_MAX_DELAY_S = 1.0


def _monotonic_of(event: Mapping[str, Any]) -> float:
    """``time.monotonic()`` of when ``event`` happened, from its wall-clock ``t`` [s] (now when it has none, or a
    ``t`` in the future)."""
    now = time.monotonic()
    t = event.get("t")
    if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t):
        return now
    return now - max(0.0, time.time() - float(t))


class ImplementMotion(Protocol):
    """What the implement logic needs of the motion controller (or its proxy to the core process)."""

    planner: TrajectoryPlanner

    def current_state(self) -> Any: ...

    def goto(
        self,
        goal: Mapping[str, float],
        speed_scale: float = 1.0,
        *,
        kind: str = "goto",
        label: str | None = None,
        deadline: float | None = None,
        issued: float | None = None,
    ) -> Any: ...

    def select_implement(
        self, implement: ImplementRecord | None, limits: ImplementLimits, *, announce: bool = True
    ) -> Any: ...


def record_of(imp: StoredImplement) -> ImplementRecord:
    """The stability record of a stored implement."""
    return ImplementRecord(imp.name, imp.category, imp.mass_kg, imp.com_m, imp.description)


class ImplementService:
    """See the module docstring. ``on_select(name)`` is told the selected implement (the API's presets)."""

    def __init__(
        self,
        store: HitchStore,
        motion: ImplementMotion,
        *,
        selected: str | None = None,
        tractor_profile: str | None = None,
        on_select: Callable[[str], None] | None = None,
        category: str | None = None,
        selected_by: str = "file",
    ):
        self.store, self.motion = store, motion
        #: the hitch's ISO 730 category (its lower-link span): only implements of it are selected (None: any)
        self.category = category
        self.on_select = on_select
        self._lock = threading.Lock()  # one implement change at a time
        self._profile: TractorProfile | None = None
        if tractor_profile is not None:
            try:
                self._profile = load_tractor_profile(tractor_profile)
            except ValueError:
                self._profile = None
        # an API built without a store (some tests embed one) runs without the implement keys' data
        persisted = store.get_setting(SELECTED_SETTING) if store is not None else None
        # the implement named at start-up (``selected_by``: "flag", --implement; "file", the config file's) and the
        # persisted selection: the flag wins over the persisted one, the persisted one over the file's, the file's
        # over none (a user trial: --implement was ignored once a selection was persisted; docs/implements.md).
        # ``selected`` is that choice until :meth:`restore` takes the first valid one of them (it falls through).
        named = selected if selected and selected != DEFAULT_IMPLEMENT else None
        self._named = None if named is None else (named, "flag" if selected_by == "flag" else "file")
        self._persisted = persisted or None
        if self._named is not None and self._named[1] == "flag":
            self.selected: str = self._named[0]
        else:
            self.selected = persisted or selected or DEFAULT_IMPLEMENT
        #: what the start-up has to say about the implement (one line: the one that runs and each one named at start
        #: that was not taken, and why); the service's start-up warnings (printed by ``hitch serve``, in the black box)
        self.warnings: list[str] = []
        #: how a switch edge is served (``key`` → the API's handling of it; set by :func:`implement_handlers`)
        self.dispatch: Dispatch | None = None
        #: told every implement the controller accepted (the planning processes: previews and maneuver
        #: validation plan with the selected implement's guard; set by :func:`implement_handlers`)
        self.on_applied: Callable[[ImplementRecord | None, ImplementLimits], None] | None = None
        #: ``sim/switch``: a momentary press of the operator switch sent by the simulated tractor (position →
        #: the positions sent; None: no twin in this service). Thread mode: :meth:`use_twin`; the core
        #: process: its ``sim_switch`` (``MotionProxy``).
        self.sim_switch: Callable[[str], Any] | None = None
        self._switch_busy = threading.Lock()
        #: the switch's edges and what became of them, newest last (key, the dispatch's answer or
        #: "dropped: busy"), at most :data:`SWITCH_HISTORY` — a press that did not move the hitch says why
        self.switch_log: deque[tuple[str, tuple[bool, dict[str, Any]] | str]] = deque(maxlen=SWITCH_HISTORY)
        #: the work session a quick raise ended (``implement``, ``session``, ``z`` [m], ``mode``) and the return
        #: motion that starts it again on arrival (``return_motion``); None: a return only goes back
        self.paused_work: dict[str, Any] | None = None
        # its own lock: the event listener reads it on the thread that reads the core's replies, which must never
        # wait for ``_lock`` (held across calls to the core: a select waited 10 s for a reply that thread was to
        # read; a reviewer's finding)
        self._pause_lock = threading.Lock()
        #: the last motions that ended (their ``motion_finished`` / ``motion_aborted`` events): a return whose end
        #: was announced before its own reply was read (the core in its own process) still starts the work
        self._ended_motions: deque[Mapping[str, Any]] = deque(maxlen=16)
        # the last quick raise / return (``implement``, ``what``: raise | return, ``motion_id``, ``arrived``) and the
        # newest motion the operator started since (not a stop): whether a raise starts from a work position
        # (a field trial: a second raise on the way up overwrote the work pose). Its own lock, never held
        # across a call: the event thread takes it.
        self._quick_lock = threading.Lock()
        self._quick: dict[str, Any] | None = None
        self._newest_start: int | None = None

    # ------------------------------------------------------------------ start
    def restore(self) -> None:
        """Give the controller and the planning the implement to start with: the first one of the precedence — the
        ``--implement`` flag's, the persisted selection, the config file's, none — that can be taken. A candidate is
        taken when it is defined (stored, or a record of the tractor profile: its record, no limits), of the hitch's
        ISO 730 category, and the controller accepts it; otherwise the next one is tried (a review: a persisted
        selection no longer defined, or a flag of another category, left the service without an implement although
        a valid one came next — and the guard then counted no implement mass: front axle share 0.506 against 0.309
        with the harrow). A persisted ``default`` is taken as none. The guards are built without an implement
        (:func:`bridge.service.machine.build_guard`, the planning workers): this is the one way in, so the category
        check holds on every path. Nothing is written to the store (the flag's implement is not persisted, a
        profile record is not stored). Whenever one named at start is left out, :attr:`warnings` says in one line
        which runs and why each one left out was not taken."""
        candidates = self._candidates()
        reasons: list[str | None] = []  # per candidate: why it cannot be taken (None: it can)
        taken: int | None = None
        apply_failed = False
        announced: Event | None = None  # the implement_selected event of what the guards were given last
        for i, (name, _where) in enumerate(candidates):
            if name == DEFAULT_IMPLEMENT:  # a persisted `default`: none, chosen
                reasons.append(None)
                if taken is None:
                    taken = i
                continue
            why, imp = self._check_candidate(name)
            if why is None and taken is None and imp is not None:
                try:
                    announced = self._apply(record_of(imp), imp.limits)
                except HitchError as exc:  # the next one is tried; the service starts anyway, and says why
                    why, apply_failed = f"it could not be applied: {exc}", True
                else:
                    taken = i
            reasons.append(why)
        self.selected = DEFAULT_IMPLEMENT if taken is None else candidates[taken][0]
        if apply_failed and self.selected == DEFAULT_IMPLEMENT:  # undo what a half-applied one may have left
            try:
                announced = self._apply(None, ImplementLimits())
            except HitchError as exc:
                self.warnings.append(f"implement: the controller's implement could not be cleared at start: {exc}")
        line = self._start_line(candidates, reasons, taken)
        if line is not None:
            self.warnings.append(line)
        self._announce()
        if announced is not None:
            self._post(announced)

    def _candidates(self) -> list[tuple[str, str]]:
        """The implements named at start in the order of precedence (name, where it was named): the flag's, the
        persisted selection, the config file's; one named twice is one candidate, at its first place."""
        out: list[tuple[str, str]] = []
        named, persisted = self._named, self._persisted
        if named is not None and named[1] == "flag":
            out.append((named[0], "--implement"))
        if persisted is not None:
            out.append((persisted, "the persisted selection"))
        if named is not None and named[1] == "file":
            out.append((named[0], "the config file's implement"))
        merged: list[tuple[str, str]] = []
        for name, where in out:
            first = next((k for k, (n, _) in enumerate(merged) if n == name), None)
            if first is None:
                merged.append((name, where))
            else:
                merged[first] = (name, f"{merged[first][1]} and {where}")
        return merged

    def _check_candidate(self, name: str) -> tuple[str | None, StoredImplement | None]:
        """(why ``name`` cannot be taken or None, its stored implement or the tractor profile's record of it —
        not stored: a start writes nothing)."""
        imp = self.store.get_implement(name)
        if imp is None:
            rec = self._builtin(name)
            if rec is not None:
                imp = StoredImplement(rec.name, rec.category, rec.mass, rec.centre_of_mass, description=rec.description)
        if imp is None:
            return "it is not defined (neither stored nor a record of the tractor profile)", None
        if self.category is not None and imp.category != self.category:
            return f"it is an ISO 730 category {imp.category} implement, this hitch category {self.category}", imp
        return None, imp

    def _start_line(
        self, candidates: list[tuple[str, str]], reasons: list[str | None], taken: int | None
    ) -> str | None:
        """One line when an implement named at start (flag, persisted selection, file) is not the one that runs:
        which runs (and where it was named), each one not taken and why (its own fault, or one before it in the
        precedence was taken — and whether it could be taken otherwise), how to change it; None when none was
        left out."""
        not_taken = []
        for i, ((name, where), why) in enumerate(zip(candidates, reasons, strict=True)):
            if i == taken:
                continue
            shown = "none" if name == DEFAULT_IMPLEMENT else repr(name)
            if taken is not None and i > taken:  # one before it was taken
                first = candidates[taken][1]
                if first.startswith("--implement"):
                    why = (
                        f"--implement comes first; a start without it selects {shown} again"
                        if why is None
                        else f"--implement comes first; a start without it would not select it either: {why}"
                    )
                else:
                    before = (
                        "the persisted selection comes before it"
                        if first.startswith("the persisted selection")
                        else f"{first} comes before it"
                    )
                    why = before if why is None else f"{before}; nor could it be taken: {why}"
            not_taken.append(f"{shown} ({where}: {why})")
        if not not_taken:
            return None
        if taken is None:
            runs = "no implement"
        elif candidates[taken][0] == DEFAULT_IMPLEMENT:
            runs = f"no implement ({candidates[taken][1]})"
        else:
            runs = f"{candidates[taken][0]!r} ({candidates[taken][1]})"
        return (
            f"implement: {runs} is selected; not taken: {'; '.join(not_taken)}. Change it with "
            f"`hitch implement select NAME` (persisted; `default` selects none)"
        )

    # ------------------------------------------------------------------ queries
    def list(self) -> dict[str, Any]:
        stored = {i.name: i for i in self.store.list_implements()}
        out = [{**i.to_json(), "source": "store"} for i in stored.values()]
        if self._profile is not None:
            for name, rec in self._profile.implements.items():
                if name not in stored:
                    out.append(
                        {
                            **StoredImplement(rec.name, rec.category, rec.mass, rec.centre_of_mass).to_json(),
                            "description": rec.description,
                            "source": "profile",
                        }
                    )
        out.sort(key=lambda d: d["name"])
        return {"implements": out, "selected": self.selected}

    def current(self) -> StoredImplement | None:
        """The selected implement as stored (None: none selected, or a profile record not stored yet)."""
        return None if self.selected == DEFAULT_IMPLEMENT else self.store.get_implement(self.selected)

    # ------------------------------------------------------------------ changes
    def define(self, r: ImplementDefine, owner: str | None = None) -> dict[str, Any]:
        """Insert or replace an implement; redefining the selected one applies it (refused while moving).
        Its transport lock and last work pose are kept: read under the lock :meth:`set_lock` changes them under."""
        if r.name == DEFAULT_IMPLEMENT:  # it selects "no implement": a stored one of that name changed the checks
            raise RequestError(
                "bad_request",
                f"implements/define: name {DEFAULT_IMPLEMENT!r} is reserved (implements/select {DEFAULT_IMPLEMENT!r} "
                "runs without an implement); give the implement another name",
            )
        with self._lock:
            old = self.store.get_implement(r.name)
            limits = ImplementLimits(
                r.upper_height_m, r.lowering_speed_m_s, old.limits.transport_locked if old is not None else False
            )
            imp = StoredImplement(
                r.name,
                r.category,
                r.mass_kg,
                (float(r.com_m[0]), float(r.com_m[1]), float(r.com_m[2])),
                limits,
                None if r.headland is None else r.headland.model_dump(),
                None if old is None else old.last_work,
                r.description,
            )
            announced: Event | None = None
            if r.name == self.selected:
                self._check_category(imp, "implements/define")  # as a select would: it stays selected
                announced = self._apply(record_of(imp), limits)  # busy while moving: nothing stored
            stored = self.store.save_implement(imp, owner=owner)
            if announced is not None:
                self._post(announced)
        return {
            "defined": stored.name,
            "implement": stored.to_json(),
            "selected": self.selected,
            "cleared": _cleared(old, stored),
        }

    def select(self, name: str) -> dict[str, Any]:
        """Select an implement (stored, or a tractor profile record: stored first), or ``default`` for none
        (the hitch alone: no implement mass in the stability check, no implement limits); busy while moving."""
        with self._lock:
            if name == DEFAULT_IMPLEMENT:
                announced = self._apply(None, ImplementLimits())
                self.selected = DEFAULT_IMPLEMENT
                self.store.set_setting(SELECTED_SETTING, DEFAULT_IMPLEMENT)
                with self._pause_lock:
                    self.paused_work = None
                self._announce()
                self._post(announced)
                return {"selected": DEFAULT_IMPLEMENT, "implement": None}
            imp = self._stored_or_builtin(name, save=False)
            self._check_category(imp)
            new_record = self.store.get_implement(imp.name) is None  # a tractor profile's record: stored once applied
            if new_record:  # a full store refuses it before the guards take it (they planned with it, unselected)
                self.store.check_implement_room(imp.name)
            announced = self._apply(record_of(imp), imp.limits)  # refused while moving: nothing is stored either
            if new_record:
                imp = self.store.save_implement(imp)
            self.selected = imp.name
            self.store.set_setting(SELECTED_SETTING, imp.name)
            with self._pause_lock:
                if self.paused_work is not None and self.paused_work["implement"] != imp.name:
                    self.paused_work = None  # another implement's work never starts again by a return
            self._announce()
            self._post(announced)
        return {"selected": imp.name, "implement": imp.to_json()}

    def delete(self, name: str) -> dict[str, Any]:
        with self._lock:  # not between a select's check and its store write
            if name == self.selected:
                raise RequestError(
                    "busy", f"implements/delete: {name!r} is the selected implement; select another first"
                )
            if not self.store.delete_implement(name):
                raise RequestError("not_found", f"implements/delete: no implement {name!r} in the store")
        return {"deleted": name}

    def set_lock(self, locked: bool) -> dict[str, Any]:
        """Transport lock of the selected implement on or off (refused while moving). Locking forgets the work a
        quick raise paused (reply ``work_paused_cleared``, as ``work/stop`` at the headland): the lock means road
        transport, and work control never starts again by itself after it — the next return (after the unlock)
        only goes back to the work pose; ``work/start`` starts work."""
        key = "implements/lock" if locked else "implements/unlock"
        with self._lock:
            if self.selected == DEFAULT_IMPLEMENT:
                raise RequestError(
                    "not_found",
                    f"{key}: {_NO_IMPLEMENT}",
                )
            imp = self._stored_or_builtin(self.selected)
            limits = ImplementLimits(imp.limits.upper_height_m, imp.limits.lowering_speed_m_s, locked)
            announced = self._apply(record_of(imp), limits)
            imp = self.store.update_implement(imp.name, transport_locked=locked)
            self._post(announced)
        out: dict[str, Any] = {"implement": imp.name, "transport_locked": imp.limits.transport_locked}
        if locked:
            cleared = self.clear_paused_work()
            if cleared is not None:
                out["work_paused_cleared"] = cleared
        return out

    # ------------------------------------------------------------------ quick raise / return
    def quick_raise(self, r: QuickMove, deadline: float | None, issued: float | None) -> dict[str, Any]:
        """Go to the headland pose; the pose it starts from becomes the last work pose (persisted) when it starts
        from a work position (:meth:`_raise_from_work`, and not at the headland pose); the reply's ``last_work`` is
        the work pose the return goes to, with ``last_work_kept: true`` when this raise kept the earlier one."""
        imp = self._need_current("hitch/raise")
        goal = imp.headland
        if goal is None:
            p = self.store.get_preset(HEADLAND_PRESET, implement=imp.name)
            goal = None if p is None else dict(p.pose)
        if goal is None:
            raise RequestError(
                "not_found",
                f"hitch/raise: implement {imp.name!r} has no headland pose (define it with 'headland' or save "
                f"a preset named {HEADLAND_PRESET!r})",
            )
        # at work (work/start): the work session ends smoothly and the raise takes over; the return starts it again
        paused = self._pause_work(imp.name, deadline, issued)
        # the implement's pose (the mechanism less the profile's lag): a return aims the mechanism back here
        here = pose_dict(self.motion.planner.implement_pose(self.motion.current_state().position))
        # pressing raise at the headland, or again on the way up (or after a stop there), keeps the work pose;
        # decided before the goto, whose own motion_started the listener may see first
        from_work = self._raise_from_work(imp.name) and not _close(here, goal)
        scale = r.speed_scale or 1.0
        try:
            acc = self.motion.goto(dict(goal), scale, kind="preset", label="raise", deadline=deadline, issued=issued)
        except MotionError as exc:
            if paused is None:
                raise
            # work ended here: the return goes back here, not to an earlier headland turn's pose
            self._record_last_work(imp.name, here)
            with self._quick_lock:
                self._quick = None  # the hitch is at work: the next raise starts from a work position
            raise MotionError(  # the work session has ended all the same: say so
                exc.code, f"{exc}; the work session {paused['session']} has ended (the hitch brakes to rest there)"
            ) from exc
        accepted = acc.to_json()
        self._quick_started(imp.name, "raise", accepted.get("motion_id"))
        if from_work:
            self._record_last_work(imp.name, here)
            last_work: dict[str, float] | None = here
        else:
            last_work = None if imp.last_work is None else dict(imp.last_work)
        out = {**accepted, "raise": True, "headland": dict(goal), "last_work": last_work}
        if not from_work:
            out["last_work_kept"] = True
        with self._pause_lock:
            if self.paused_work is not None and self.paused_work["implement"] == imp.name:
                out["work_paused"] = _paused_json(self.paused_work)
        return out

    def _record_last_work(self, implement: str, pose: dict[str, float]) -> None:
        """Persist ``pose`` as the implement's last work pose (where a return goes), then announce it:
        ``last_work_recorded`` ``{implement, last_work}`` — a raise from the cab's switch or another client changed it
        without a word, and the terminal's Implement tab kept the old pose (an audit). Under the lock: serialised
        with define, which rewrites the whole record."""
        with self._lock:
            self.store.update_implement(implement, last_work=pose)
            self._post({"event": "last_work_recorded", "implement": implement, "last_work": dict(pose)})

    def _pause_work(self, implement: str, deadline: float | None, issued: float | None) -> dict[str, Any] | None:
        """End a running work session for a quick raise (``work_paused`` event); what was paused, or None."""
        try:
            reply = call_work(self.motion, "pause", deadline, issued, "quick raise (hitch/raise)")
        except RequestError as exc:
            if exc.code == "unavailable":  # a service without work control: nothing to pause
                return None
            raise
        paused = reply.get("paused")
        if not paused:
            return None
        with self._pause_lock:
            self.paused_work = {"implement": implement, **paused, "return_motion": None}
        self._post(
            {
                "event": "work_paused",
                "session": paused["session"],
                "mode": paused["mode"],
                "z_operator": paused["z"],
                "message": f"quick raise: work session {paused['session']} ({paused['mode']} control) ended; "
                "hitch/return lowers to the work pose and starts work again",
            }
        )
        return dict(paused)

    def clear_paused_work(self) -> dict[str, Any] | None:
        """Forget the work a quick raise paused (a new work/start or work/stop, another implement): the
        return then only goes back. The paused work, or None."""
        with self._pause_lock:
            paused, self.paused_work = self.paused_work, None
        return None if paused is None else _paused_json(paused)

    def _post(self, event: dict[str, Any]) -> None:
        post = getattr(self.motion, "post_event", None)
        if callable(post):
            try:
                post(event)
            except Exception:  # noqa: BLE001 — the core is gone (closing)
                pass

    def quick_return(self, r: QuickMove, deadline: float | None, issued: float | None) -> dict[str, Any]:
        """Go back to the last work pose (where the last raise started)."""
        imp = self._need_current("hitch/return")
        if imp.last_work is None:
            raise RequestError(  # a raise from the headland pose records none: "raise it once" was no advice
                "not_found",
                f"hitch/return: implement {imp.name!r} has no work pose yet: a raise records the pose it starts "
                f"from, but not one that starts at the headland pose (within {_AT_HEADLAND * 1000:g} mm / "
                f"{_AT_HEADLAND * 1000:g} mrad of it); raise from a work pose first",
            )
        scale = r.speed_scale or 1.0
        goal = dict(imp.last_work)
        acc = self.motion.goto(goal, scale, kind="preset", label="return", deadline=deadline, issued=issued)
        out = {**acc.to_json(), "return": True, "last_work": dict(imp.last_work)}
        self._quick_started(imp.name, "return", out.get("motion_id"))
        with self._pause_lock:
            paused = self.paused_work
            if paused is not None and paused["implement"] == imp.name:
                paused["return_motion"] = out["motion_id"]  # work starts again when it arrives (on_event)
                out["resumes_work"] = _paused_json(paused)
        for ended in list(self._ended_motions):  # it ended already (a return of almost no length)
            if ended.get("motion_id") == out["motion_id"]:
                self._resume_paused_work(ended)
        return out

    def _raise_from_work(self, implement: str) -> bool:
        """Whether a raise of ``implement`` starting now starts from a work position: no quick motion of it is
        remembered, or the last one was a return that arrived, or the operator started a motion (not a stop)
        after it. False while the hitch is between work and the headland because of a raise (running, stopped
        or replaced by another raise) or a return that has not arrived: its work pose is kept."""
        with self._quick_lock:
            q = self._quick
            if q is None or q["implement"] != implement:
                return True
            if q["what"] == "return" and q["arrived"]:
                return True
            mid, newest = q["motion_id"], self._newest_start
            return _is_id(mid) and _is_id(newest) and newest > mid

    def _quick_started(self, implement: str, what: str, motion_id: Any) -> None:
        """Remember the quick raise / return just accepted (its end may have been announced already). Looked up
        under the lock: :meth:`on_event` files an end in ``_ended_motions`` before :meth:`_note_motion` takes the
        lock, so an end is either seen here or marks this record there, never lost between (a review)."""
        with self._quick_lock:
            arrived = any(
                e.get("motion_id") == motion_id and e.get("event") == "motion_finished"
                for e in list(self._ended_motions)
            )
            self._quick = {"implement": implement, "what": what, "motion_id": motion_id, "arrived": arrived}

    def _note_motion(self, event: Mapping[str, Any]) -> None:
        """Follow the motions for :meth:`_raise_from_work` (on the event thread: a short lock only)."""
        mid = event.get("motion_id")
        with self._quick_lock:
            if event.get("event") == "motion_started":
                if event.get("kind") != "stop" and isinstance(mid, int) and _is_id(mid):  # a stop: no move
                    newest = self._newest_start
                    self._newest_start = mid if newest is None or mid > newest else newest
            elif event.get("event") == "mode_changed":  # out of the planner's hands (manual …): moved, perhaps
                self._quick = None
            elif event.get("event") == "motion_finished":
                q = self._quick
                if q is not None and q["motion_id"] == mid:
                    q["arrived"] = True

    def _resume_paused_work(self, event: Mapping[str, Any]) -> None:
        """The return motion of paused work ended: arrived (``motion_finished``) → ``work/start`` at the
        operator's z of the paused session, on a thread of its own (through :attr:`dispatch`, so the black box
        records it and work/start's checks apply); replaced or stopped (``motion_aborted``) → no work, the
        pause is kept (a later return starts it). A refused start is announced (``work_resume_refused``)."""
        name = event.get("event")
        if self.paused_work is None:  # the common case: no lock taken on the event thread
            return
        # the arrival's own time: a stop sent after the return arrived cancels the start, however late this runs
        arrived = _monotonic_of(event)
        with self._pause_lock:
            paused = self.paused_work
            if paused is None or paused.get("return_motion") is None:
                return
            if event.get("motion_id") != paused["return_motion"]:
                return
            paused["return_motion"] = None
            if name != "motion_finished" or self.dispatch is None:
                return
            self.paused_work = None
        dispatch = self.dispatch
        payload = json.dumps({"z": paused["z"]}).encode()

        def run() -> None:
            try:
                ok, reply = dispatch("work/start", payload, received=arrived)
            except Exception as exc:  # noqa: BLE001 — announced, never lost with the thread
                ok, reply = False, {"error": "internal", "message": f"{type(exc).__name__}: {exc}"}
            if ok:
                self._post(
                    {
                        "event": "work_resumed",
                        "session": reply.get("session"),
                        "after": paused["session"],
                        "z_operator": paused["z"],
                    }
                )
            else:
                self._post(
                    {
                        "event": "work_resume_refused",
                        "session": paused["session"],
                        "error": str(reply.get("error", "refused")),
                        "message": str(reply.get("message", ""))[:500],
                    }
                )

        threading.Thread(target=run, name="hitch-work-resume", daemon=True).start()

    # ------------------------------------------------------------------ the operator switch
    def on_event(self, event: Mapping[str, Any]) -> None:
        """A ``hitch_switch`` event (an edge of the operator's CAN switch, ``bridge.link.hitch_switch``):
        ``hitch/raise`` or ``hitch/return`` through :attr:`dispatch` on a thread of its own (the event
        thread must not plan). One at a time: an edge while the previous request runs is dropped. A
        press the API refuses is announced as ``hitch_switch_refused`` (``command``, ``error``,
        ``message``): the operator sees why the hitch did not move. Motion events (``motion_started`` …) and
        ``mode_changed`` are followed for the quick raise's work pose (:meth:`_raise_from_work`) and the paused
        work's return."""
        if event.get("event") in ("motion_started", "mode_changed"):
            self._note_motion(event)
            return
        if event.get("event") in ("motion_finished", "motion_aborted"):
            self._ended_motions.append(event)
            self._note_motion(event)
            self._resume_paused_work(event)
            return
        if event.get("event") != "hitch_switch" or self.dispatch is None:
            return
        key = {"raise": "hitch/raise", "return": "hitch/return"}.get(str(event.get("command")))
        if key is None:
            return
        late = time.monotonic() - _monotonic_of(event)
        if late > SWITCH_EVENT_MAX_DELAY_S:  # this process stalled: a press of seconds ago must not move now
            answer = (
                False,
                {
                    "error": "busy",
                    "message": f"the switch press reached the service {late:.2f} s after it happened (limit "
                    f"{SWITCH_EVENT_MAX_DELAY_S:g} s: the service was stalled); not acted on — press it again",
                },
            )
            self.switch_log.append((key, answer))
            self._announce_refusal(key, answer)
            return
        if not self._switch_busy.acquire(blocking=False):
            self.switch_log.append((key, "dropped: the previous switch request still runs"))
            return
        dispatch = self.dispatch

        def run() -> None:
            try:
                try:
                    answer = dispatch(key, b"{}")
                except Exception as exc:  # noqa: BLE001 — logged and announced, never lost with the thread
                    answer = (False, {"error": "internal", "message": f"{type(exc).__name__}: {exc}"})
                self.switch_log.append((key, answer))
                self._announce_refusal(key, answer)
            finally:
                self._switch_busy.release()

        threading.Thread(target=run, name="hitch-switch", daemon=True).start()

    def _announce_refusal(self, key: str, answer: tuple[bool, dict[str, Any]]) -> None:
        """``hitch_switch_refused`` for an ``(ok, reply)`` answer that is not ok (nothing otherwise; a core that
        is gone loses it: the refusal is in switch_log)."""
        ok, reply = answer
        if ok:
            return
        self._post(
            {
                "event": "hitch_switch_refused",
                "command": key.removeprefix("hitch/"),
                "error": str(reply.get("error", "refused")),
                "message": str(reply.get("message", ""))[:500],
            }
        )

    def use_twin(self, tractor: Any) -> None:
        """``sim/switch`` on the simulated tractor ``tractor`` (its ``bus``; None: no twin here)."""
        if tractor is None:
            return
        from bridge.link.hitch_switch import press_switch

        self.sim_switch = lambda position: press_switch(tractor.bus, position)  # type: ignore[arg-type]

    def press(self, position: str) -> dict[str, Any]:
        """``sim/switch``: the simulated tractor sends one momentary press of the operator switch."""
        if self.sim_switch is None:
            raise RequestError(
                "unavailable",
                "sim/switch: no simulated tractor runs in this service (a real machine is connected); the "
                "switch can only be pressed on the twin",
            )
        sent = self.sim_switch(position)
        return {"position": position, "sent": list(sent)}

    # ------------------------------------------------------------------ internals
    def _check_category(self, imp: StoredImplement, key: str = "implements/select") -> None:
        """An implement of another ISO 730 category is refused (an engineer's report: a category 2 implement was
        selected on a category 3 hitch, and its stability check ran with the wrong geometry; and redefining the
        selected one in another category bypassed this: a new user's report)."""
        if self.category is not None and imp.category != self.category:
            raise RequestError(
                "bad_request",
                f"{key}: {imp.name!r} is an ISO 730 category {imp.category} implement; this hitch is set "
                f"up for category {self.category} (its lower-link span): define it for category {self.category}, "
                f"or start the service with --category {imp.category}",
            )

    def _apply(self, record: ImplementRecord | None, limits: ImplementLimits) -> Event:
        """The controller's guards first (refused while moving: nothing else changes), then the planning. Returns
        the ``implement_selected`` event, for the caller to post once the change is recorded (selection, store,
        the API's presets): the terminal reads ``implements/list`` and ``presets/list`` back on that event, and
        the controller's own event came before them (CI: the chooser kept "no implement", Raise disabled)."""
        self.motion.select_implement(record, limits, announce=False)
        if self.on_applied is not None:
            self.on_applied(record, limits)
        return implement_selected_event(record, limits)

    def _need_current(self, key: str) -> StoredImplement:
        if self.selected == DEFAULT_IMPLEMENT:
            raise RequestError(
                "not_found",
                f"{key}: {_NO_IMPLEMENT}",
            )
        imp = self.store.get_implement(self.selected)
        if imp is None:
            imp = self._stored_or_builtin(self.selected)
        return imp

    def _builtin(self, name: str) -> ImplementRecord | None:
        return None if self._profile is None else self._profile.implements.get(name)

    def _stored_or_builtin(self, name: str, *, save: bool = True) -> StoredImplement:
        """The stored implement ``name``, else the tractor profile's record of it (stored, unless ``save`` is
        False: a select that is refused must change nothing, it left the record stored: a field trial)."""
        imp = self.store.get_implement(name)
        if imp is not None:
            return imp
        rec = self._builtin(name)
        if rec is None:
            known = [i["name"] for i in self.list()["implements"]]
            raise RequestError(
                "not_found",
                f"no implement {name!r} (defined: {', '.join(known) or 'none'}; implements/define; "
                f"{DEFAULT_IMPLEMENT!r} selects none)",
            )
        built = StoredImplement(rec.name, rec.category, rec.mass, rec.centre_of_mass, description=rec.description)
        return self.store.save_implement(built) if save else built

    def _announce(self) -> None:
        if self.on_select is not None:
            self.on_select(self.selected)


def _is_id(v: Any) -> bool:
    """A motion id that orders (the controller numbers its motions 1, 2, …)."""
    return isinstance(v, int) and not isinstance(v, bool)


def _cleared(old: StoredImplement | None, new: StoredImplement) -> list[str]:
    """The fields a redefinition left out that the record had (a define replaces the whole record: a newcomer
    changed the mass and lost the upper height, the lowering speed and the headland pose without a word)."""
    if old is None:
        return []
    had = {
        "upper_height_m": (old.limits.upper_height_m, new.limits.upper_height_m),
        "lowering_speed_m_s": (old.limits.lowering_speed_m_s, new.limits.lowering_speed_m_s),
        "headland": (old.headland, new.headland),
        "description": (old.description or None, new.description or None),
    }
    return [name for name, (before, after) in had.items() if before is not None and after is None]


def _close(a: Mapping[str, float], b: Mapping[str, float]) -> bool:
    return all(math.isclose(float(a[k]), float(b[k]), abs_tol=_AT_HEADLAND) for k in ("x", "z", "roll", "pitch"))


def implement_handlers(api: Any) -> dict[str, Callable[[Any], dict[str, Any]]]:
    """The API keys of this module for ``api`` (a :class:`~bridge.service.api.ServiceAPI` whose motion,
    store, implement, info and caller are set): builds ``api.implements`` (restoring the persisted
    selection) and returns key → handler."""

    def on_select(name: str) -> None:
        api.implement = name
        api.info["implement"] = None if name == DEFAULT_IMPLEMENT else name

    planner = getattr(api.motion, "planner", None)
    profile = None if planner is None else planner.model.profile.stability.tractor_profile
    svc = ImplementService(
        api.store,
        api.motion,
        selected=api.implement,
        selected_by=getattr(api, "implement_source", "file"),
        tractor_profile=profile,
        on_select=on_select,
        category=api.info.get("category") or (None if planner is None else planner.model.category),
    )
    api.implements = svc
    set_planning = getattr(api.planning, "set_implement", None)  # planning processes (in-process: the guards)
    if callable(set_planning):
        svc.on_applied = set_planning
    core_switch = getattr(api.motion, "sim_switch", None)  # the core process's twin (MotionProxy)
    if callable(core_switch):
        svc.sim_switch = core_switch
    try:
        svc.restore()
    except HitchError as exc:  # the service starts anyway (without the implement), and says why
        svc.warnings.append(f"implement: no implement could be given to the controller at start: {exc}")

    svc.dispatch = api.handle  # the black box records it like any request

    def user() -> str | None:
        return getattr(api._caller, "user", None)

    def define(r: ImplementDefine) -> dict[str, Any]:
        workspace = (api.info.get("limits") or {}).get("workspace")
        if r.headland is not None:  # a raise must be able to go there: refused now, naming the range, not at the raise
            check_pose_in_workspace(r.headland.model_dump(), workspace, key="implements/define", what="headland")
        if r.upper_height_m is not None and workspace and "z" in workspace:
            z_min = float(workspace["z"][0])
            # the hitch could never be under it: every motion up refused, a track session pulled down
            if r.upper_height_m < z_min:
                raise RequestError(
                    "bad_request",
                    f"implements/define: upper_height_m = {r.upper_height_m:g} m is below the workspace's lowest z "
                    f"({z_min:.4g} m): the hitch could never be under it (allowed: >= {z_min:.4g} and <= 2 m)"
                    + unit_hint(r.upper_height_m, z_min, 2.0, "m"),
                )
        if r.headland is not None and r.upper_height_m is not None and r.headland.z > r.upper_height_m:
            # every quick raise would be refused at the upper height (a new user's report)
            raise RequestError(
                "bad_request",
                f"implements/define: headland.z = {r.headland.z:g} m is above upper_height_m = "
                f"{r.upper_height_m:g} m: a quick raise could never reach it (allowed: headland.z <= "
                f"{r.upper_height_m:g} m, or a higher upper_height_m)",
            )
        return svc.define(r, owner=user())

    return {
        "implements/list": lambda _r: svc.list(),
        "implements/define": define,
        "implements/select": lambda r: svc.select(r.name),
        "implements/delete": lambda r: svc.delete(r.name),
        "implements/lock": lambda _r: svc.set_lock(True),
        "implements/unlock": lambda _r: svc.set_lock(False),
        "hitch/raise": lambda r: _taught(api, r, svc.quick_raise(r, *api._timing(r.deadline_ms)), "headland"),
        "hitch/return": lambda r: _taught(api, r, svc.quick_return(r, *api._timing(r.deadline_ms)), "last_work"),
        "sim/switch": lambda r: svc.press(r.position),
    }


def _taught(api: Any, r: QuickMove, reply: dict[str, Any], goal: str) -> dict[str, Any]:
    """A teach-in records an accepted quick raise or return as the ``goto`` it is (to the reply's ``goal`` pose:
    the headland, the work pose): a maneuver script has no raise step, and before, the recording left both out
    without a word (a field trial). Returns ``reply``."""
    rec = getattr(api, "recorder", None)  # read once: a record/stop may run meanwhile
    pose = reply.get(goal)
    if rec is not None and isinstance(pose, Mapping):
        rec.on_goto(pose, r.speed_scale or 1.0, float(reply.get("duration", 0.0)))
    return reply


def _paused_json(paused: Mapping[str, Any]) -> dict[str, Any]:
    """The paused work as a reply shows it: ``session``, ``mode``, ``z_operator`` [m]."""
    return {"session": paused["session"], "mode": paused["mode"], "z_operator": paused["z"]}
