"""The simulated cylinder ECU: closed-loop steps, watchdog, on/off switch, restart,
end-stop relay, system-state byte and reproducible noise."""

import numpy as np
import pytest

from bridge.isobus.system_state import (
    STATE_CONTROLLERS_ON,
    STATE_END_STOP_RELAY,
    STATE_NO_REFERENCE,
    STATE_WATCHDOG_TRIPPED,
    decode_system_state,
)
from bridge.sim import ACTUATOR_ORDER, ControllerConfig, CylinderECU, ECUError
from planner.profiles.hitch import load_profile

PERIOD = 0.01


@pytest.fixture(scope="module")
def profile():
    return load_profile("thesis-t132")


def drive(ecu, ref, t_from, t_to, period=PERIOD):
    """Stream the same reference every ``period`` from t_from (inclusive) until t_to, as a planner would.
    Returns the time of the last reference sent."""
    k, last = 0, None
    while t_from + k * period < t_to - 1e-9:
        last = t_from + k * period
        ecu.set_reference(ref, last)
        k += 1
    ecu.step(t_to)
    return last


def test_initial_state(profile):
    ecu = CylinderECU(profile)
    # neutral positions of the profile (lift 0.220 rad, tilt 0.630 m), mid-stroke otherwise
    tilt = ecu.params[1]
    assert ecu.measurement_counts()[1] == round(tilt.si_to_counts(0.630))
    assert ecu.measurement_counts()[3] == 270  # left: (30 + 510) / 2
    assert ecu.measurement_counts().dtype.kind == "i"
    assert np.all(ecu.valve_commands() == 0)
    assert ecu.system_state() == STATE_CONTROLLERS_ON | STATE_WATCHDOG_TRIPPED | STATE_NO_REFERENCE
    x0 = ecu.piston_counts()
    ecu.step(1.0)  # no reference: nothing moves
    assert np.array_equal(ecu.piston_counts(), x0)
    si = ecu.positions_si()
    for i, p in enumerate(ecu.params):
        assert si[i] == pytest.approx(p.counts_to_si(int(ecu.measurement_counts()[i])))
    assert si[0] == pytest.approx(0.220, abs=0.5 / ecu.params[0].counts_per_unit)


def _step_figures(ecu, deltas, duration=8.0):
    start = ecu.measurement_counts().copy()
    ref = start + np.asarray(deltas)
    ts, ys, us = [], [], []
    t = 0.0
    for k in range(int(round(duration / PERIOD))):
        t = k * PERIOD
        ecu.set_reference(ref, t)
        ecu.step(t + PERIOD)
        ts.append(t + PERIOD)
        ys.append(ecu.measurement_counts().copy())
        us.append(ecu.valve_commands().copy())
    ts, ys, us = np.array(ts), np.array(ys), np.array(us)
    sign = np.sign(deltas)
    overshoot = np.maximum(0, np.max(sign * (ys - ref), axis=0))
    settle = []
    for i in range(5):
        outside = np.nonzero(np.abs(ys[:, i] - ref[i]) > 2)[0]
        settle.append(ts[outside[-1] + 1] if outside.size else 0.0)
    return ref, ys, us, overshoot, np.array(settle)


@pytest.mark.parametrize("direction", [1, -1])
def test_closed_loop_step_settles_on_every_cylinder(profile, direction):
    ecu = CylinderECU(profile)
    spans = np.array([p.counts_max - p.counts_min for p in ecu.params])
    deltas = direction * np.round(0.2 * spans).astype(int)  # 20 % of each stroke
    ref, ys, us, overshoot, settle = _step_figures(ecu, deltas)
    for i, n in enumerate(ACTUATOR_ORDER):
        print(f"{n:6s} step {deltas[i]:+4d} counts: overshoot {overshoot[i]} counts, settling (±2) {settle[i]:.2f} s")
    # settles on the reference count (settle_counts = 0) and stays there: valves closed, piston at rest
    assert np.all(np.abs(ys[-1] - ref) <= ecu.config.settle_counts)
    assert np.all(us[-100:] == 0)
    assert np.all(ys[-100:] == ys[-1])
    assert np.all(overshoot <= 1)
    assert np.all(settle < 5.0)
    # the ramp during saturation runs at Kv·(m·254 + dz − dz + dy_min) for the tilt (thesis 1.1)
    tilt = ecu.params[1]
    kv = tilt.kv_pos if direction > 0 else tilt.kv_neg
    slope = (ys[150, 1] - ys[100, 1]) / 0.5
    assert slope == pytest.approx(direction * kv * (127 + tilt.min_flow), rel=0.02)


def test_watchdog_zeroes_valves_within_timeout_and_motion_stops(profile):
    ecu = CylinderECU(profile)
    ref = ecu.measurement_counts() + np.array([0, 300, 0, 0, 0])
    last = drive(ecu, ref, 0.0, 1.0)
    assert last == pytest.approx(0.99)
    assert ecu.valve_commands()[1] > 0 and not ecu.system_state() & STATE_WATCHDOG_TRIPPED
    ecu.step(last + 0.099)
    assert ecu.valve_commands()[1] > 0
    ecu.step(last + 0.100)
    assert np.all(ecu.valve_commands() == 0)
    assert ecu.system_state() & STATE_WATCHDOG_TRIPPED
    assert ecu.watchdog.trip_count == 1
    x_trip = ecu.piston_counts()[1]
    # the oil already on its way (transport delay L = 0.1 s) still moves the piston …
    ecu.step(last + 0.2)
    assert ecu.piston_counts()[1] > x_trip + 3
    # … then the lag (T_F = 0.01 s) dies out and the piston is at rest
    ecu.step(last + 0.4)
    x_rest = ecu.piston_counts().copy()
    ecu.step(3.0)
    assert np.allclose(ecu.piston_counts(), x_rest, atol=1e-6)
    assert ecu.watchdog.trip_count == 1
    # after a trip one reference is not enough: valves stay zero until the stream has been continuous for
    # the re-arm window (50 ms); commands resume at the next controller tick after it
    ecu.set_reference(ref, 3.0)
    assert ecu.system_state() & STATE_WATCHDOG_TRIPPED
    ecu.step(3.0 + PERIOD)
    assert not ecu.valve_commands().any()
    drive(ecu, ref, 3.01, 3.05)
    assert ecu.system_state() & STATE_WATCHDOG_TRIPPED and not ecu.valve_commands().any()
    ecu.set_reference(ref, 3.05)
    assert not ecu.system_state() & STATE_WATCHDOG_TRIPPED
    ecu.step(3.05 + PERIOD)
    assert ecu.valve_commands()[1] > 0


def test_fed_says_whether_references_arrive_as_the_watchdog_judges_and_counts_no_trip(profile):
    ecu = CylinderECU(profile, watchdog_timeout_s=0.05)
    assert not ecu.fed  # nothing arrived yet
    ecu.set_reference(ecu.measurement_counts(), 0.1)
    for t, fed in ((0.1, True), (0.149, True), (0.15, False), (0.3, False)):
        ecu.step(t)
        assert ecu.fed is fed and ecu.fed is not ecu.watchdog.expired(ecu.time_s), t
    trips = ecu.watchdog.trip_count
    for _ in range(3):
        assert not ecu.fed
    assert ecu.watchdog.trip_count == trips


def test_holding_is_one_reference_repeated_twice_while_fed_and_ends_with_a_new_one_or_a_restart(profile):
    ecu = CylinderECU(profile, watchdog_timeout_s=0.05)
    ref = list(ecu.measurement_counts())
    other = [*ref[:1], ref[1] + 3, *ref[2:]]
    seen = []
    for k, r in enumerate([ref, ref, ref, ref, other, other, other]):
        ecu.set_reference(r, 0.02 * (k + 1))
        seen.append(ecu.holding)
    assert seen == [False, False, True, True, False, False, True]
    ecu.step(0.2)  # no reference for longer than the watchdog's timeout: not fed, not holding
    assert not ecu.fed and not ecu.holding
    ecu.set_reference(other, 0.21)  # the same reference again after the gap: counted on
    assert ecu.holding
    ecu.restart()
    ecu.set_reference(other, 0.22)
    assert not ecu.holding  # a restart forgets the reference


def test_watchdog_timeout_is_configurable(profile):
    ecu = CylinderECU(profile, watchdog_timeout_s=0.05)
    ref = ecu.measurement_counts() + np.array([0, 300, 0, 0, 0])
    drive(ecu, ref, 0.0, 0.5, period=0.04)  # 40 ms < 50 ms: never trips
    assert ecu.watchdog.trip_count == 0 and ecu.valve_commands()[1] > 0
    ecu.step(0.48 + 0.049)
    assert ecu.valve_commands()[1] > 0
    ecu.step(0.48 + 0.05)
    assert np.all(ecu.valve_commands() == 0)
    slow = CylinderECU(profile, watchdog_timeout_s=0.05)
    drive(slow, ref, 0.0, 0.5, period=0.06)  # 60 ms > 50 ms: trips between references
    assert slow.watchdog.trip_count >= 7


def test_controllers_off_means_valves_zero(profile):
    ecu = CylinderECU(profile)
    ref = ecu.measurement_counts() + np.array([20, 300, 40, 60, -60])
    drive(ecu, ref, 0.0, 0.5)
    assert np.count_nonzero(ecu.valve_commands()) == 5
    ecu.controllers_enabled = False
    assert np.all(ecu.valve_commands() == 0)
    assert not ecu.system_state() & STATE_CONTROLLERS_ON
    drive(ecu, ref, 0.5, 0.8)  # references keep coming: still zero
    assert np.all(ecu.valve_commands() == 0)
    x = ecu.piston_counts().copy()
    drive(ecu, ref, 0.8, 2.0)
    assert np.allclose(ecu.piston_counts(), x, atol=1e-6)
    ecu.controllers_enabled = True
    drive(ecu, ref, 2.0, 2.0 + PERIOD)
    assert np.count_nonzero(ecu.valve_commands()) == 5
    assert ecu.system_state() & STATE_CONTROLLERS_ON
    off = CylinderECU(profile, controllers_enabled=False)
    drive(off, ref, 0.0, 1.0)
    assert np.all(off.valve_commands() == 0)
    with pytest.raises(ECUError, match="controllers_enabled"):
        ecu.controllers_enabled = 1


def test_restart_is_visible_in_the_state_byte(profile):
    ecu = CylinderECU(profile)
    ref = ecu.measurement_counts() + np.array([0, 300, 0, 0, 0])
    drive(ecu, ref, 0.0, 0.5)
    s = decode_system_state(ecu.system_state())
    assert (s.controllers_on, s.watchdog_tripped, s.no_reference_since_restart, s.restart_count_mod16) == (
        True,
        False,
        False,
        0,
    )
    ecu.restart()
    assert np.all(ecu.valve_commands() == 0) and ecu.reference_counts() is None
    s = decode_system_state(ecu.system_state())
    assert (s.watchdog_tripped, s.no_reference_since_restart, s.restart_count_mod16) == (True, True, 1)
    ecu.step(0.8)
    x = ecu.piston_counts().copy()
    ecu.step(1.5)  # no new reference: no motion
    assert np.allclose(ecu.piston_counts(), x, atol=1e-6)
    drive(ecu, ref, 1.5, 1.5 + PERIOD)
    s = decode_system_state(ecu.system_state())
    assert not s.no_reference_since_restart and s.restart_count_mod16 == 1
    assert ecu.valve_commands()[1] > 0
    for _ in range(15):
        ecu.restart()
    assert ecu.restart_count == 16 and decode_system_state(ecu.system_state()).restart_count_mod16 == 0


def test_end_stop_relay_in_the_loop(profile):
    ecu = CylinderECU(profile)
    top = ecu.params[2]
    ref = ecu.measurement_counts().copy()
    ref[2] = top.counts_max  # reference at the stroke end
    drive(ecu, ref, 0.0, 6.0)
    assert ecu.relay_engaged()[2]
    assert ecu.system_state() & STATE_END_STOP_RELAY
    out = ecu.controller_outputs()[2]
    assert out.valve_unlimited > 0 and out.relay_blocked and ecu.valve_commands()[2] == 0
    high = ecu._controllers[2].relay.limits.high_counts
    assert high <= ecu.piston_counts()[2] < top.counts_max - 1
    ref[2] = 140  # back towards safety: passes, relay releases
    drive(ecu, ref, 6.0, 12.0)
    assert not any(ecu.relay_engaged())
    assert not ecu.system_state() & STATE_END_STOP_RELAY
    assert abs(ecu.measurement_counts()[2] - 140) <= 1


def test_noise_is_reproducible_with_a_seed(profile):
    def run(rng):
        ecu = CylinderECU(profile, rng=rng, noise_counts=1.5)
        ref = ecu.measurement_counts() + np.array([5, 50, 10, 20, -20])
        out = []
        for k in range(100):
            ecu.set_reference(ref, k * PERIOD)
            ecu.step((k + 1) * PERIOD)
            out.append(ecu.measurement_counts().copy())
        return np.array(out), ecu.piston_counts()

    a, xa = run(7)
    b, xb = run(np.random.default_rng(7))
    c, _ = run(8)
    assert np.array_equal(a, b) and np.array_equal(xa, xb)
    assert not np.array_equal(a, c)
    quiet = CylinderECU(profile, noise_counts=[0, 0, 0, 0, 2.0])
    meas = []
    for k in range(200):
        quiet.step(k * PERIOD)
        meas.append(quiet.measurement_counts().copy())
    meas = np.array(meas)
    assert np.all(meas[:, :4] == meas[0, :4]) and meas[:, 4].std() > 1.0


def test_gain_error_speeds_up_the_plant_not_the_controller(profile):
    ecu = CylinderECU(profile, gain_error={"tilt": 0.5})
    nominal = CylinderECU(profile)
    for e in (ecu, nominal):
        ref = e.measurement_counts() + np.array([0, 300, 0, 0, 0])
        drive(e, ref, 0.0, 1.5)
    moved = ecu.piston_counts()[1] - ecu.params[1].si_to_counts(0.630)
    moved_nominal = nominal.piston_counts()[1] - nominal.params[1].si_to_counts(0.630)
    # both saturated at u = 132 after the first 100 ms: 1.5× the distance
    assert moved / moved_nominal == pytest.approx(1.5, rel=0.02)
    with pytest.raises(ECUError, match="unknown actuator"):
        CylinderECU(profile, gain_error={"tilts": 0.1})
    with pytest.raises(ECUError, match="5 values"):
        CylinderECU(profile, gain_error=[0.1, 0.2])


def test_reference_input_forms_and_latching(profile):
    ecu = CylinderECU(profile)
    m = ecu.measurement_counts()
    ecu.set_reference(dict(zip(ACTUATOR_ORDER, (int(v) for v in m), strict=True)), 0.0155)
    assert ecu.time_s == pytest.approx(0.015) and ecu.watchdog.last_feed_s == pytest.approx(0.015)
    ecu.set_reference(m.astype(np.int16), 0.02)
    ecu.set_reference([float(v) for v in m], 0.03)
    assert np.array_equal(ecu.reference_counts(), m)


@pytest.mark.parametrize(
    "ref, word",
    [
        ([100, 200, 100, 200], "5 counts"),
        ([100, 200, 100, 200, 1024], "right"),
        ([100, 200.5, 100, 200, 200], "tilt"),
        ([100, 200, True, 200, 200], "top"),
        ({"lift": 1, "tilt": 2, "top": 3, "left": 4}, "missing"),
        ("12345", "mapping or a sequence"),
    ],
)
def test_bad_references_are_rejected(profile, ref, word):
    ecu = CylinderECU(profile)
    with pytest.raises(ECUError, match=word):
        ecu.set_reference(ref, 0.0)
    assert ecu.reference_counts() is None and ecu.time_s == 0.0


def test_bad_times_and_settings_are_rejected(profile):
    ecu = CylinderECU(profile)
    ecu.step(1.0)
    with pytest.raises(ECUError, match="before"):
        ecu.step(0.5)
    with pytest.raises(ECUError, match="before"):
        ecu.set_reference(ecu.measurement_counts(), 0.9)
    with pytest.raises(ECUError, match="finite"):
        ecu.step(float("nan"))
    with pytest.raises(ECUError, match="multiple"):
        CylinderECU(profile, controller=ControllerConfig(period_s=0.0105))
    with pytest.raises(ECUError, match="rng"):
        CylinderECU(profile, rng=-3)
    with pytest.raises(ValueError, match="timeout_s"):
        CylinderECU(profile, watchdog_timeout_s=0.0)
    with pytest.raises(ValueError, match="initial_counts"):
        CylinderECU(profile, initial_counts={"tilt": 5.0})


def test_watchdog_expires_exactly_at_the_timeout():
    from bridge.sim import Watchdog, WatchdogError

    w = Watchdog(0.1)
    assert w.expired(0.0)  # never fed
    w.feed(0.5)
    assert not w.expired(0.5999)
    assert w.expired(0.6)  # age 0.1 s (0.6 − 0.5 < 0.1 in floats)
    assert w.trip_count == 1 and w.expired(0.61) and w.trip_count == 1
    w.feed(0.7)  # after a trip: re-armed only by a stream without a break for rearm_s (50 ms)
    assert w.expired(0.75) and w.trip_count == 1
    w.feed(0.74)
    assert w.expired(0.745)
    w.feed(0.75)
    assert not w.expired(0.75) and not w.expired(0.8499)
    w.reset()
    assert w.expired(0.75) and w.last_feed_s is None
    w.feed(0.8)  # after power-up or a restart the first reference arms it
    assert not w.expired(0.8)
    with pytest.raises(WatchdogError, match="earlier"):
        w.feed(0.8) or w.feed(0.7)
    with pytest.raises(WatchdogError, match="timeout_s"):
        Watchdog(float("inf"))


def test_watchdog_acts_between_controller_ticks(profile):
    ecu = CylinderECU(profile)
    ref = ecu.measurement_counts() + np.array([0, 300, 0, 0, 0])
    drive(ecu, ref, 0.0, 0.99)
    ecu.set_reference(ref, 0.995)  # latched at the 1 ms step 995
    ecu.step(1.094)
    assert ecu.valve_commands()[1] > 0
    ecu.step(1.095)
    assert np.all(ecu.valve_commands() == 0)
    ecu.step(1.099)  # the next controller tick (1.100) is not needed
    assert np.all(ecu.valve_commands() == 0)


def test_result_does_not_depend_on_how_time_is_stepped(profile):
    def run(chunks):
        ecu = CylinderECU(profile, rng=3, noise_counts=0.7)
        ref = ecu.measurement_counts() + np.array([30, 200, -40, 60, -50])
        ecu.set_reference(ref, 0.0)
        ecu.set_reference(ref, 0.0554)  # last reference at the 1 ms step 55: expires off-tick
        for t in np.linspace(0.06, 1.0, chunks) if chunks > 1 else [1.0]:
            ecu.step(float(t))
        return ecu.piston_counts(), ecu.measurement_counts(), ecu.watchdog.trip_count

    one, many = run(1), run(377)
    assert np.array_equal(one[0], many[0]) and np.array_equal(one[1], many[1])
    assert one[2] == many[2] == 1


def test_one_call_per_internal_step_gives_the_same_machine_as_one_call(profile):
    """The ECU advances closed valves a controller period at a time; stepping it one internal step
    per call (each call then integrates that single step) must give bit for bit the same pistons,
    samples, valves and watchdog: a move, a rest with the valves closed, the watchdog expiring
    between controller ticks, and a second move from rest."""

    def run(per_step):
        ecu = CylinderECU(profile, rng=9, noise_counts=0.4)
        ref = ecu.measurement_counts() + np.array([20, 150, -30, 40, -25])
        trace = []
        for t_ref, t_end in ((0.0, 0.8), (0.8037, 2.0), (2.0, 2.6)):
            ecu.set_reference(ref, t_ref)
            ticks = range(int(round(t_ref / ecu.step_s)) + 1, int(round(t_end / ecu.step_s)) + 1)
            for t in (k * ecu.step_s for k in ticks) if per_step else (t_end,):
                ecu.step(t)
            trace.append((ecu.piston_counts(), ecu.measurement_counts(), ecu.valve_commands()))
            ref = ref + np.array([0, -60, 10, 0, 5])
        return trace, ecu.watchdog.trip_count

    (one, trips_one), (many, trips_many) = run(False), run(True)
    for a, b in zip(one, many, strict=True):
        assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    assert trips_one == trips_many >= 2


def test_settled_cylinders_stay_put_under_ad_noise(profile):
    """AD noise of 0.5 count: every cylinder settles on its reference (true piston within one
    count) and, once settled, the hold band keeps the valves shut nearly all the time instead of
    chasing the flicker (without the band, cutoff_counts = 0, they are open 33–40 % of the time)."""
    ecu = CylinderECU(profile, rng=5, noise_counts=0.5)
    spans = np.array([p.counts_max - p.counts_min for p in ecu.params])
    ref = ecu.measurement_counts().copy() + np.round(0.1 * spans).astype(int)
    active, t = [], 0.0
    for k in range(int(round(12.0 / PERIOD))):
        t = k * PERIOD
        ecu.set_reference(ref, t)
        ecu.step(t + PERIOD)
        if t >= 6.0:  # well after the moves (≤ 3 s)
            active.append(ecu.valve_commands() != 0)
    duty = np.mean(active, axis=0)
    print("valve duty after settling:", dict(zip(ACTUATOR_ORDER, np.round(duty, 3), strict=True)))
    assert np.all(np.abs(ecu.piston_counts() - ref) <= 1.0)
    assert np.all(duty < 0.05)


def test_the_ecu_runs_with_the_profiles_controller_tuning():
    """The twin's unit controllers take a (thesis 2.57) from the profile, the same value the
    planner's feed-forward inverts; a profile with another a gives another controller."""
    from planner.profiles.hitch import THESIS_CONTROLLER_A, load_profile

    profile = load_profile("thesis-t132")
    assert CylinderECU(profile).config.a == profile.motion.controller_a == THESIS_CONTROLLER_A
    other = profile.model_copy(update={"motion": profile.motion.model_copy(update={"controller_a": 0.4})})
    assert CylinderECU(other).config.a == 0.4


def test_watchdog_after_a_trip_a_burst_of_queued_references_never_re_arms_it():
    """References that queued up during a stall arrive in a burst: never enough to re-arm (the
    ECU would otherwise drive on references seconds old); a live stream re-arms it after 50 ms."""
    from bridge.sim import Watchdog

    w = Watchdog(0.1)
    for k in range(50):  # a 50 Hz stream for 1 s
        w.feed(0.02 * k)
        assert not w.expired(0.02 * k)
    assert w.expired(0.98 + 0.1) and w.trip_count == 1
    for k in range(10):  # the stall's backlog, read within 9 ms 3 s later
        w.feed(4.0 + 0.001 * k)
        assert w.expired(4.0 + 0.001 * k)
    assert all(w.expired(4.009 + 0.01 * k) for k in range(30))
    assert w.trip_count == 2  # each reference's expiry counted once
    # a stream with a break (≥ the timeout) starts its run again
    for t in (5.0, 5.02, 5.04, 5.2, 5.22, 5.24):
        w.feed(t)
        assert w.expired(t), t
    w.feed(5.26)
    assert not w.expired(5.26) and not w.expired(5.3599)
    assert w.expired(5.36)
    w.feed(5.4)
    assert w.expired(5.4)  # a trip again: latched again
    with pytest.raises(ValueError, match="rearm_s"):
        Watchdog(0.1, rearm_s=-0.01)
    free = Watchdog(0.1, rearm_s=0.0)  # 0: the first reference re-arms it (the behaviour before)
    free.feed(0.0)
    assert free.expired(0.1)
    free.feed(3.0)
    assert not free.expired(3.0)


def test_watchdog_a_long_backlog_delivered_back_to_back_never_re_arms_it():
    """A reviewer's finding: a re-arm by duration alone (every gap below the timeout for 50 ms) was met by a long
    backlog: 250 queued references at 0.52 ms each (an 8-byte extended frame at 250 kbit/s) span 130 ms, so
    the watchdog re-armed at frame 97 and the ECU drove on references seconds old. Frames back to back do not
    count as a stream; a live 50 Hz stream after the backlog re-arms it."""
    from bridge.sim import Watchdog

    w = Watchdog(0.1)
    for k in range(50):
        w.feed(0.02 * k)
    assert w.expired(1.2)
    t = 6.0
    for _ in range(250):
        w.feed(t)
        assert w.expired(t), t
        t += 0.00052
    assert w.expired(t)
    live = [t + 0.02 * (k + 1) for k in range(5)]  # the planner streams again at 50 Hz
    for s in live:
        w.feed(s)
    assert not w.expired(live[-1])
