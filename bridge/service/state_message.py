"""The ``<prefix>/state`` message: one JSON-ready dict per control cycle (issue 7 §2).

Fields: ``t`` (Unix time [s]), ``clock`` (link clock [s]), ``seq``; ``pose`` and ``actuators``
as measured over CAN (forward kinematics of the ECU's readings; None before the first);
``reference`` (the commanded pose x, z, roll, pitch and actuators, None when nothing is
streamed); ``velocity`` (commanded pose rates [m/s, rad/s]); ``mode``, ``moving``,
``motion_id``, ``motion`` (kind); ``limited`` (what caps the motion → the limit's name: the
"Control limited" of the thesis terminal); ``kinematic_margin`` (time to the nearest limit at the
commanded velocity, :mod:`planner.limits.kinematic_margin`); ``stability`` (tractor + implement
margins at the measured pose); ``ecu`` (``online``, ``watchdog`` tripped, ``controllers_on``,
latched ``faults`` and their reasons, heartbeat, streaming, reference counters); ``maneuver``.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from bridge.service.motion.types import stability_json
from planner.limits.guard import Guard
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES, KinematicsError

__all__ = ["build_state_message", "fault_transition", "link_problem"]


def _safe(fn):
    try:
        return fn()
    except (ValueError, KinematicsError):  # a measured pose the stability model cannot take
        return None


def link_problem(status, now: float, stale_after_s: float) -> str | None:
    """Why motion cannot start now (None: it can). Latched faults whose causes are gone do not
    count: the first reference of a fresh command re-arms the link, which refuses it if a cause
    is still present."""
    if not status.claimed:
        return "the CAN link has not claimed its address yet"
    if status.state is None:
        return "no measurement from the cylinder ECU yet"
    age = status.state.age_s(now)
    if age > stale_after_s:
        return f"the ECU measurements are {age:.3f} s old (limit {stale_after_s:g} s)"
    if not status.heartbeat.healthy:
        return f"the ECU heartbeat is {status.heartbeat.state.value}"
    return None


def fault_transition(reported: tuple[str, ...], status, events: list[dict]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """Compare the link's latched faults with those ``reported`` before; append a ``fault`` event
    when new ones appeared, ``fault_cleared`` when all are gone. Returns (faults now, new faults)."""
    faults = status.faults.active() if status.faults.any else ()
    new = tuple(f for f in faults if f not in reported)
    if new:
        events.append({"event": "fault", "faults": list(faults), "message": "; ".join(status.faults.reasons)})
    elif not faults and reported:
        events.append({"event": "fault_cleared"})
    return faults, new


def build_state_message(
    *,
    seq: int,
    now: float,
    status,
    stale_after_s: float,
    guard: Guard,
    mode: str,
    motion_kind: str | None,
    motion_id: int | None,
    reference,
    limited: dict,
    maneuver: dict | None,
    feedforward=None,
) -> dict[str, Any]:
    """The message for one cycle. ``status``: the link's :class:`~bridge.link.state.LinkStatus` at
    clock time ``now`` [s]; ``reference``: (pose-space state, actuators q, actuator rates q̇) being
    streamed, or None; ``stale_after_s``: the link's measurement age limit [s]; ``feedforward``: the
    :class:`~bridge.link.unit_loop.FeedforwardShaper` (whether it is on, and how many references the
    hard-limit check made it pull back towards the plan)."""
    ls = status.state
    msg: dict[str, Any] = {
        "t": time.time(),
        "clock": now,
        "seq": seq,
        "mode": mode,
        "moving": motion_kind is not None,
        "motion_id": motion_id,
        "motion": motion_kind,
        "limited": dict(limited),
    }
    msg["pose"] = None if ls is None else ls.pose.as_dict()
    msg["actuators"] = None if ls is None else ls.actuators.as_dict()
    if reference is not None:
        st, q, qd = reference
        msg["reference"] = {
            "pose": dict(zip(CONTROLLED_POSE_NAMES, map(float, st.position))),
            "actuators": dict(zip(ACTUATOR_NAMES, map(float, q))),
        }
        msg["velocity"] = dict(zip(CONTROLLED_POSE_NAMES, map(float, st.velocity)))
        msg["kinematic_margin"] = _safe(lambda: guard.margin(q, qd).to_json())
    else:
        msg["reference"] = None
        msg["velocity"] = dict.fromkeys(CONTROLLED_POSE_NAMES, 0.0)
        msg["kinematic_margin"] = (
            None if ls is None else _safe(lambda: guard.margin(ls.actuators.as_array(), np.zeros(5)).to_json())
        )
    msg["stability"] = (
        None if ls is None else _safe(lambda: stability_json(guard.stability_at(ls.actuators.as_array())))
    )
    hb = status.heartbeat
    age = ls.age_s(now) if ls is not None else math.inf
    c = status.counters
    msg["ecu"] = {
        "online": link_problem(status, now, stale_after_s) is None,
        "watchdog": bool(ls is not None and ls.system.watchdog_tripped),
        "controllers_on": bool(ls is not None and ls.system.controllers_on),
        "faults": list(status.faults.active()),
        "fault_reasons": list(status.faults.reasons),
        "heartbeat": hb.state.value,
        "streaming": status.streaming,
        "measurement_age_s": age if math.isfinite(age) else None,
        "references_sent": c.references_tx,
        "references_refused": c.references_refused,
    }
    if feedforward is not None:
        msg["ecu"]["feedforward"] = {"enabled": feedforward.enabled, "pulled_back": feedforward.pulled_back}
    msg["maneuver"] = maneuver
    return msg
