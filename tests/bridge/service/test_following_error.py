"""Following-error supervision (bridge.service.motion.following): the cylinders must follow the references.

An integrator's trial with his own ECU: an ECU whose controllers were off (or a cylinder that did not move)
let a goto run its plan to the end and announce ``motion_finished`` 50 mm short of the goal, exit status 0.
Now a cylinder that stays beyond its allowance for ``time_s`` raises the latching fault ``following_error``,
aborts the motion and stops the stream; a motion is refused while the ECU reports its controllers off.

Truth: the allowance's closed form ``e_max + lag_s · |q̇_ref|`` and its time, on hand-made histories; the
simulated ECU with its controllers switched off mid-move (its valves at zero: nothing follows).
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion.following import FollowingErrorLimits, FollowingSupervisor
from planner.model.types import ACTUATOR_NAMES
from tests.helpers import SimService

TOP = ACTUATOR_NAMES.index("top")
LIFT = ACTUATOR_NAMES.index("lift")


def _q(top: float = 0.1, lift: float = 0.5) -> np.ndarray:
    q = np.full(len(ACTUATOR_NAMES), 0.05)
    q[TOP], q[LIFT] = top, lift
    return q


_REF = object()  # one streamed reference, recorded once


def _run(sup: FollowingSupervisor, ref_q, ref_qd, meas, times, ref=_REF) -> list[tuple[float, str | None]]:
    out = []
    for t in times:
        sup.streamed(t, ref, ref_q, ref_qd)  # the same reference object: recorded once
        out.append((t, sup.check(meas, t, t)))
    return out


def test_an_error_beyond_the_allowance_trips_after_time_s_and_not_before():
    lim = FollowingErrorLimits(lift_rad=0.02, length_m=0.01, lag_s=0.3, time_s=0.5)
    times = np.arange(0.0, 1.0001, 0.02)
    zero = np.zeros(len(ACTUATOR_NAMES))
    # top link 11 mm off at rest (allowance 10 mm): over from t = 0, tripped at t = 0.5 s exactly
    got = _run(FollowingSupervisor(lim), _q(), zero, _q(top=0.111), times)
    first = next(t for t, why in got if why is not None)
    assert first == pytest.approx(0.5, abs=1e-9)
    why = dict(got)[first]
    assert why is not None and why.startswith("top +11.0 mm from its reference") and "0.50 s" in why
    # 9 mm off: never
    assert all(why is None for _, why in _run(FollowingSupervisor(lim), _q(), zero, _q(top=0.109), times))
    # the lift in rad: 25 mrad (allowance 20) trips, 15 does not
    assert any(w is not None for _, w in _run(FollowingSupervisor(lim), _q(), zero, _q(lift=0.525), times))
    assert all(w is None for _, w in _run(FollowingSupervisor(lim), _q(), zero, _q(lift=0.515), times))


def test_the_allowance_grows_with_the_reference_speed():
    lim = FollowingErrorLimits(length_m=0.01, lag_s=0.3, time_s=0.5)
    qd = np.zeros(len(ACTUATOR_NAMES))
    qd[TOP] = 0.05  # 50 mm/s: allowance 10 + 0.3 × 50 = 25 mm
    times = np.arange(0.0, 1.0001, 0.02)
    assert all(w is None for _, w in _run(FollowingSupervisor(lim), _q(), qd, _q(top=0.1 - 0.024), times))
    assert any(w is not None for _, w in _run(FollowingSupervisor(lim), _q(), qd, _q(top=0.1 - 0.026), times))


def test_a_late_measurement_is_compared_with_the_reference_of_its_own_time():
    """A measurement that arrived at t = 0.9 s (read late, under CPU load) is compared with the reference
    streamed then, not with the step to +100 mm streamed at t = 1 s."""
    sup = FollowingSupervisor(FollowingErrorLimits(time_s=0.1))
    zero = np.zeros(len(ACTUATOR_NAMES))
    old, new = object(), object()
    sup.streamed(0.0, old, _q(top=0.1), zero)
    sup.streamed(1.0, new, _q(top=0.2), zero)
    for _ in range(20):  # read again and again: still the reference of t = 0.9
        assert sup.check(_q(top=0.1), 0.9, 0.9) is None
    assert sup.check(_q(top=0.1), 1.0, 1.0) is None  # over from here …
    assert sup.check(_q(top=0.1), 1.1, 1.1) is not None  # … for time_s


def test_limits_out_of_range_are_refused_by_name():
    with pytest.raises(ValueError, match=r"time_s must be a number in \[0.05, 10\]"):
        FollowingErrorLimits(time_s=0.0)
    with pytest.raises(ValueError, match="length_m"):
        FollowingErrorLimits(length_m=float("nan"))


def test_a_cylinder_that_stops_following_aborts_the_motion_and_latches_following_error(model, tmp_path):
    """The real CAN path to the simulated ECU in simulated time (no CPU-load faults): its controllers switched
    off 0.4 s into a goto (valves at zero, nothing follows) — the fault comes within time_s + the lag allowance
    + a few cycles, the goto is aborted, never finished, and a motion is refused until the controllers are on
    and the fault acknowledged."""
    s = SimService(model, tmp_path / "hitch.sqlite3", settle_s=0.5)
    try:

        def ended(mid: int, what: str) -> list[dict]:
            return [e for e in s.events if e.get("event") == what and e.get("motion_id") == mid]

        def faults() -> set[str]:
            return {f.name for f in s.mc.faults}

        mid = s.ok("goto", {"goal": {"z": -0.1}})["motion_id"]
        s.run(6.0)
        assert ended(mid, "motion_finished") and not faults(), s.events
        mid = s.ok("goto", {"goal": {"z": 0.25}, "speed_scale": 0.5})["motion_id"]
        s.run(0.4)
        s.rig.ecu.controllers_enabled = False  # valves at zero: nothing follows any more
        t_off = s.rig.now_s
        while "following_error" not in faults() and s.rig.now_s < t_off + 5.0:
            s.run(0.02)
        took = s.rig.now_s - t_off
        assert "following_error" in faults(), [(e["event"], e.get("reason") or e.get("message")) for e in s.events]
        # time_s after the error outgrew its allowance: at a reference speed v that takes lag_s + e_max / v
        # (here ~0.3 + 0.4 s for the lift at half speed)
        assert 0.5 <= took <= 2.0, took
        aborted = ended(mid, "motion_aborted")
        assert aborted and "following error" in aborted[0]["reason"] and not ended(mid, "motion_finished")
        fault = next(f for f in s.mc.faults if f.name == "following_error")
        assert fault.latches and "from its reference" in fault.reason, fault
        s.run(1.0)
        ok, r = s.call("goto", {"goal": {"z": 0.0}})
        assert not ok and "following_error" in r["message"], r
        s.ok("faults/ack")
        ok, r = s.call("goto", {"goal": {"z": 0.0}})
        assert not ok and "controllers off" in r["message"], r
        s.rig.ecu.controllers_enabled = True
        s.run(0.2)
        mid = s.ok("goto", {"goal": {"z": 0.0}})["motion_id"]
        s.run(6.0)
        assert ended(mid, "motion_finished") and not faults(), s.events
    finally:
        s.close()


def test_the_settings_reach_the_controller_and_bad_ones_are_refused_by_name(tmp_path):
    from bridge.service.config import ServiceConfigError, load_service_config
    from bridge.service.machine import build_controller, start_can

    f = tmp_path / "service.toml"
    f.write_text("[hitch]\nfollowing_error_m = 0.02\nfollowing_error_lift_rad = 0.05\nfollowing_error_s = 1.5\n")
    cfg = load_service_config(f, data_dir=str(tmp_path), can_channel=f"fe-{tmp_path.name}")
    parts = start_can(cfg)
    try:
        mc, _ = build_controller(cfg, parts, on_state=lambda m: None, on_event=lambda e: None)
        assert mc.following.limits == FollowingErrorLimits(lift_rad=0.05, length_m=0.02, lag_s=0.3, time_s=1.5)
    finally:
        parts.close()
    f.write_text("[hitch]\nfollowing_error_s = 0\n")
    with pytest.raises(ServiceConfigError, match=r"following_error_s.*0\.05"):
        load_service_config(f)


def test_a_cylinder_closing_in_on_a_stepped_reference_follows_a_frozen_one_does_not():
    """A stalled control thread (the reference held, the plan's time going on) then streams a step: the top link
    catches up, its error beyond the allowance for longer than time_s but shrinking by more than e_max / 2 per
    time_s — it follows, late (the slow-planning test tripped it). The same error not shrinking trips."""
    lim = FollowingErrorLimits(length_m=0.01, lag_s=0.3, time_s=0.5)
    zero = np.zeros(len(ACTUATOR_NAMES))
    times = np.arange(0.0, 2.0001, 0.02)
    catching = FollowingSupervisor(lim)
    frozen = FollowingSupervisor(lim)
    ref = object()
    got_catching, got_frozen = [], []
    for t in times:
        catching.streamed(t, ref, _q(top=0.1), zero)
        frozen.streamed(t, ref, _q(top=0.1), zero)
        err = max(0.0, 0.06 - 0.03 * t)  # 60 mm behind, closing at 30 mm/s (> 10 mm / 2 per 0.5 s)
        got_catching.append(catching.check(_q(top=0.1 - err), t, t))
        got_frozen.append(frozen.check(_q(top=0.1 - 0.06), t, t))
    assert all(w is None for w in got_catching)
    first = next(t for t, w in zip(times, got_frozen, strict=True) if w is not None)
    assert first == pytest.approx(0.5, abs=1e-9)


def test_a_maneuver_step_is_refused_while_the_controllers_are_off_and_the_run_says_so(model, tmp_path):
    """A maneuver's next motion step came while the ECU's controllers were off: it started its plan with
    nothing moving (the following error aborted it a second later as a ``fault``). Now the step is refused
    when it comes: the maneuver aborts at once as ``refused``, naming the controllers, no motion starts."""
    s = SimService(model, tmp_path / "hitch.sqlite3", settle_s=0.5)
    try:
        script = "steps:\n  - goto: {z: 0.0}\n  - wait: 1.0\n  - goto: {z: 0.2}\n"
        assert s.call("maneuvers/save", {"name": "m", "script": script})[0]
        s.run(0.2)
        ok, r = s.call("maneuvers/run", {"name": "m"})
        assert ok, r
        while not any(e.get("event") == "maneuver_step" and e.get("step") == 1 for e in s.events):
            assert s.rig.now_s < 20.0, s.events
            s.run(0.02)
        s.rig.ecu.controllers_enabled = False  # during the wait
        started = sum(e.get("event") == "motion_started" for e in s.events)
        s.run(2.0)
        aborted = [e for e in s.events if e.get("event") == "maneuver_aborted"]
        assert aborted, [(e["event"], e.get("step"), e.get("reason") or e.get("message")) for e in s.events]
        assert aborted[0]["reason"] == "refused", aborted
        assert "controllers off" in aborted[0]["message"] and "step 3 (index 2)" in aborted[0]["message"], aborted
        assert sum(e.get("event") == "motion_started" for e in s.events) == started  # nothing started
        assert "following_error" not in {f.name for f in s.mc.faults}
    finally:
        s.close()
