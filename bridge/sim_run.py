"""Running the simulated cylinder ECU and the planner link together over CAN (issue 6 §2, §4).

The nodes (:class:`~bridge.can_link.CanLink`, :class:`~bridge.ecu_sim.can_node.EcuCanNode`)
own no clock. Here they run in **simulated time**: :class:`SimRig` puts both on a private
python-can ``virtual`` channel and advances an integer tick counter (``now = k · tick_s``,
1 ms by default: no float drift). Each tick runs ``link.poll(t)``, ``node.poll(t)``,
``link.poll(t)``, so a reference sent at ``t`` reaches the ECU at ``t`` (which first steps
its model to ``t``) and a measurement sent at ``t`` reaches the link at ``t``; the bus adds
no latency (a frame takes 0.5 ms at 250 kbit/s). Nothing reads the wall clock: runs are
deterministic and much faster than real time, through the real codec, identifiers and
python-can queues. (Real time: :class:`bridge.cli_sim.RealtimeRunner`.)

:func:`run_move` is the closed-loop experiment of ``hitch sim move`` (a step reference,
thesis style, or the Ruckig plan streamed at the control rate); :func:`build_move_figures`
turns its trace into the reported figures.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import can
import numpy as np

from planner.kinematics import HitchModel
from planner.sensors import SensorScaling
from planner.trajectory import MotionState, TrajectoryPlanner

from .can_link import CanLink
from .ecu_sim.can_node import EcuCanNode, EcuNodeConfig
from .ecu_sim.ecu import CylinderECU
from .j1939 import bus_load
from .link_state import LinkConfig

__all__ = [
    "LossyBus", "MoveFigures", "MoveSettings", "MoveTrace", "REFERENCE_KINDS", "SimError", "SimRig",
    "SimSettings", "build_move_figures", "run_move", "unit_loop_lag_s",
]

REFERENCE_KINDS = ("step", "trajectory")
_POSE = ("x", "z", "roll", "pitch")


class SimError(ValueError):
    """A simulation that cannot run as asked; the message names the field or the fault."""


class LossyBus(can.BusABC):
    """Wraps a bus and loses each received frame with probability ``loss`` (seeded)."""

    def __init__(self, inner: can.BusABC, loss: float, rng: np.random.Generator) -> None:
        if isinstance(loss, bool) or not isinstance(loss, (int, float)) or not 0.0 <= loss < 1.0:
            raise SimError(f"frame loss must be a fraction in [0, 1), got {loss!r}")
        self._inner, self._loss, self._rng = inner, float(loss), rng
        self.dropped = 0
        """Frames lost so far."""
        super().__init__(channel=inner.channel_info)

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        self._inner.send(msg, timeout)

    def _recv_internal(self, timeout: float | None):
        while (msg := self._inner.recv(timeout)) is not None:
            if self._rng.random() >= self._loss:
                return msg, False
            self.dropped += 1
            timeout = 0.0
        return None, False

    def shutdown(self) -> None:
        self._inner.shutdown()
        super().shutdown()


@dataclass(frozen=True)
class SimSettings:
    """The simulated machine and bus.

    Attributes:
        tick_s: simulation tick, s (a whole multiple of the ECU's 1 ms step).
        noise_counts: AD noise standard deviation of every channel, counts.
        gain_error: relative valve-gain error of the simulated plant (0.1 = 10 % fast).
        seed: seed of the AD noise and of the frame loss.
        frame_loss: probability that a node misses a received frame, 0..<1.
        watchdog_timeout_s: the ECU's reference watchdog, s.
        link: link settings; node: ECU node settings.
    """

    tick_s: float = 0.001
    noise_counts: float = 0.0
    gain_error: float = 0.0
    seed: int = 0
    frame_loss: float = 0.0
    watchdog_timeout_s: float = 0.1
    link: LinkConfig = field(default_factory=LinkConfig)
    node: EcuNodeConfig = field(default_factory=EcuNodeConfig)

    def __post_init__(self) -> None:
        ratio = self.tick_s / 1e-3 if isinstance(self.tick_s, (int, float)) else math.nan
        if not (math.isfinite(ratio) and 1 <= round(ratio) <= 10 and abs(ratio - round(ratio)) < 1e-9):
            raise SimError(f"tick_s must be 1..10 ms in whole ms, got {self.tick_s!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SimError(f"seed must be a non-negative integer, got {self.seed!r}")
        if isinstance(self.frame_loss, bool) or not isinstance(self.frame_loss, (int, float)) \
                or not 0.0 <= self.frame_loss < 1.0:
            raise SimError(f"frame_loss must be a fraction in [0, 1), got {self.frame_loss!r}")


class SimRig:
    """An ECU node and a link on a private ``virtual`` channel, advanced in simulated time.

    A third "tap" bus on the channel counts every frame for the bus-load figure.
    Use as a context manager (or call :meth:`close`) so every bus is shut down.

    Args:
        model: kinematic model of the machine (its profile configures the ECU).
        settings: the simulated machine and bus.
        initial_actuators: start position of the pistons, SI (default: the profile's neutral).
    """

    def __init__(self, model: HitchModel, settings: SimSettings | None = None, *, initial_actuators=None) -> None:
        self.settings = s = settings if settings is not None else SimSettings()
        rng = np.random.default_rng(s.seed)
        noise_rng, loss_rng = rng.spawn(2)
        initial = None
        if initial_actuators is not None:  # unrounded counts: the pistons sit between AD steps
            sc = SensorScaling(model.profile)
            initial = sc.counts_min + (np.asarray(initial_actuators, dtype=float).reshape(5) - sc.si_min) / sc.resolution
        ecu = CylinderECU(model.profile, rng=noise_rng, noise_counts=s.noise_counts, gain_error=s.gain_error,
                          watchdog_timeout_s=s.watchdog_timeout_s, initial_counts=initial)
        self.channel = channel = f"hitch-sim-{uuid.uuid4().hex}"
        """The private virtual channel (other buses may join it, e.g. in tests)."""
        buses = [can.Bus(interface="virtual", channel=channel) for _ in range(3)]
        if s.frame_loss > 0.0:
            buses[:2] = [LossyBus(b, s.frame_loss, loss_rng) for b in buses[:2]]
        self._buses = buses
        self.node = EcuCanNode(ecu, buses[0], s.node)
        self.link = CanLink(model, buses[1], s.link)
        self._tap = buses[2]
        self._k = 0
        self._tick_ms = int(round(s.tick_s * 1e3))
        self.ecu_paused = False
        """Fault injection: while True the ECU node is not polled (a stalled ECU or a cut
        cable): it neither sends nor reads; its frames wait in its queue."""
        self.frames_by_dlc: dict[int, int] = {}
        """Frames seen on the bus since the last :meth:`reset_traffic`, by DLC."""
        self._traffic_since_s = 0.0

    @property
    def ecu(self) -> CylinderECU:
        """The simulated ECU behind the node."""
        return self.node.ecu

    @property
    def now_s(self) -> float:
        """Simulated time, s."""
        return self._k * self._tick_ms / 1000.0

    @property
    def next_tick_s(self) -> float:
        """The time the next :meth:`tick` advances to, s."""
        return (self._k + 1) * self._tick_ms / 1000.0

    def start(self) -> None:
        """Power up both nodes at the current time (address claims)."""
        self.node.start(self.now_s)
        self.link.start(self.now_s)

    def tick(self) -> float:
        """Advance one tick and exchange frames; returns the new time."""
        self._k += 1
        t = self.now_s
        self.link.poll(t)
        if not self.ecu_paused:
            self.node.poll(t)
            self.link.poll(t)
        while (frame := self._tap.recv(timeout=0.0)) is not None:
            self.frames_by_dlc[frame.dlc] = self.frames_by_dlc.get(frame.dlc, 0) + 1
        return t

    def run_until(self, t_end_s: float, every_tick: Callable[[float], None] | None = None) -> None:
        """Tick until ``t_end_s``; ``every_tick(t)`` runs before each tick's polls at time t."""
        while self.now_s < t_end_s - 1e-9:
            if every_tick is not None:
                every_tick(self.next_tick_s)
            self.tick()

    def reset_traffic(self) -> None:
        """Start a new bus-load window."""
        self.frames_by_dlc = {}
        self._traffic_since_s = self.now_s

    def bus_load(self) -> float:
        """Measured bus load since :meth:`reset_traffic`, fraction of 250 kbit/s (worst-case stuffing)."""
        span = self.now_s - self._traffic_since_s
        return bus_load({d: n / span for d, n in self.frames_by_dlc.items()}) if span > 0 else 0.0

    def close(self) -> None:
        """Shut every bus down."""
        for b in self._buses:
            b.shutdown()

    def __enter__(self) -> SimRig:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@dataclass(frozen=True)
class MoveSettings:
    """One closed-loop move.

    Attributes:
        reference: "step" (goal actuators at once, thesis style) or "trajectory"
            (Ruckig plan samples streamed at the link's control rate).
        start: start pose (any of x, z, roll, pitch; default the neutral pose).
        speed_scale: fraction of full trajectory speed, (0, 1].
        lead: trajectory only: stream each actuator's plan :func:`unit_loop_lag_s` ahead,
            so the unit controllers' ramp lag (different per cylinder) cancels; the slow
            cylinders' first reference is then τ_i into their plan (a bounded step).
        warmup_s: time for address claims and first measurements before the move, s.
        hold_s: the run ends once every valve command stayed zero this long, s.
        max_time_s: ... or this long after the move started, s.
    """

    reference: str = "trajectory"
    start: Mapping[str, float] | None = None
    speed_scale: float = 1.0
    lead: bool = False
    warmup_s: float = 0.5
    hold_s: float = 1.0
    max_time_s: float = 30.0

    def __post_init__(self) -> None:
        if self.reference not in REFERENCE_KINDS:
            raise SimError(f"reference must be one of {', '.join(REFERENCE_KINDS)}, got {self.reference!r}")
        for name, low in (("warmup_s", 0.3), ("hold_s", 0.05), ("max_time_s", 0.1)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not low <= v <= 600.0:
                raise SimError(f"{name} must be a number of seconds in [{low:g}, 600], got {v!r}")


@dataclass(frozen=True)
class MoveTrace:
    """A closed-loop move sampled every 10 ms from the first command (t = 0).

    Arrays: ``t`` (N,) s; poses (N, 4) x, z, roll, pitch in m and rad — ``measured``
    (link state over CAN), ``truth`` (forward kinematics of the simulated pistons),
    ``planned`` (the plan at t; the goal for a step); actuators (N, 5) in SI —
    ``reference`` (what was streamed), ``measured_actuators``; ``valves`` (N, 5)
    command units. ``start`` is the measured start pose (the plan's), ``truth_start`` the
    true one (they differ by the AD quantisation), ``goal`` the goal pose.
    """

    reference_kind: str  # "step", "trajectory" or "trajectory+lead"
    start: np.ndarray
    truth_start: np.ndarray
    goal: np.ndarray
    plan_duration_s: float
    t: np.ndarray
    measured: np.ndarray
    truth: np.ndarray
    planned: np.ndarray
    reference: np.ndarray
    measured_actuators: np.ndarray
    valves: np.ndarray
    link_counters: dict[str, int]
    node_counters: dict[str, int]
    faults: tuple[str, ...]
    bus_load: float


def unit_loop_lag_s(ecu: CylinderECU) -> np.ndarray:
    """How long each cylinder of ``ecu`` lags a ramp reference, s (actuator order).

    With k = a/(Kv L) (thesis 2.57) and dead-zone compensation, the unit loop is
    ẋ ≈ (m a / L)·e for valve multiplier m; the derivative on the measurement adds T_F,
    so a ramp is followed with a constant lag L/(m a) + T_F: 0.18 s lift, 0.35 s tilt and
    top link, 0.87 s sway limiters for the thesis values. (The minimum flow Kv·dy_min
    shortens the P part by the factor 1 − Kv·dy_min/v: under 5 % at planned speeds.)
    """
    a = ecu.config.a
    return np.array([p.transport_delay_s / (p.valve_multiplier * a) + p.time_constant_s for p in ecu.params])


def run_move(model: HitchModel, goal: Mapping[str, float], move: MoveSettings | None = None,
             sim: SimSettings | None = None) -> MoveTrace:
    """Drive the simulated ECU through the CAN path from ``move.start`` to ``goal``.

    Raises:
        SimError: no measurement after warm-up, or the link refused a command.
        PlanError: the goal is outside the workspace or cannot be planned.
    """
    move = move if move is not None else MoveSettings()
    sim = sim if sim is not None else SimSettings()
    tp = TrajectoryPlanner(model, rate=sim.link.control_rate_hz)
    p_start = tp.goal_vector(model.neutral_pose.controlled(), move.start or {})
    tp.check_in_workspace(p_start, "start")
    with SimRig(model, sim, initial_actuators=tp.inverse.solve(p_start)[0]) as rig:
        rig.start()
        rig.run_until(move.warmup_s)
        state = rig.link.latest_state()
        if state is None:
            raise SimError(f"no measurement from the ECU after {move.warmup_s} s (faults: "
                           f"{', '.join(rig.link.faults.reasons) or 'none'})")
        p0 = state.pose.controlled()
        p1 = tp.goal_vector(p0, goal)
        tp.check_in_workspace(p1)
        if move.reference == "step":
            return _drive(rig, model, np.zeros(1), tp.inverse.solve(p1)[0][None, :], lambda t: p1, p0, p1, 0.0, move)
        plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(_POSE, p1)), speed_scale=move.speed_scale)
        sp = tp.sample(plan)
        refs = sp.actuators
        if move.lead:  # actuator i streams its own plan τ_i ahead (a value the plan takes, never beyond its end)
            lag = unit_loop_lag_s(rig.ecu)
            refs = np.column_stack([np.interp(np.minimum(sp.t + lag[i], sp.t[-1]), sp.t, refs[:, i]) for i in range(5)])
        return _drive(rig, model, sp.t, refs, lambda t: plan.state_at(t).position, p0, p1, plan.duration, move)


def _drive(rig: SimRig, model: HitchModel, times, refs, planned_at, p0, p1, duration, move) -> MoveTrace:
    """Stream ``refs`` at ``times`` after now, record every 10 ms, stop when the valves rest."""
    t0, k, quiet_since, n, rows = rig.now_s, 0, None, 0, []
    every = max(1, round(0.01 / rig.settings.tick_s))
    params = rig.ecu.params
    def truth_pose() -> np.ndarray:  # forward kinematics of the simulated pistons (not measured)
        q = [p.counts_to_si(c) for p, c in zip(params, rig.ecu.piston_counts())]
        return model.forward(np.array(q)).pose.controlled()

    truth_start = truth_pose()
    rig.reset_traffic()
    while True:
        while k < len(times) and rig.next_tick_s >= t0 + times[k] - 1e-9:
            try:
                rig.link.send_reference(refs[k], rig.next_tick_s)
            except ValueError as exc:
                raise SimError(f"t = {rig.next_tick_s - t0:.3f} s: {exc}") from None
            k += 1
        t = rig.tick()
        n += 1
        valves = rig.ecu.valve_commands()
        quiet_since = (quiet_since if quiet_since is not None else t) if k == len(times) and not valves.any() else None
        if n % every == 0:
            st = rig.link.latest_state()
            ref = [p.counts_to_si(c) for p, c in zip(params, rig.link.status(t).reference_counts)]
            rows.append((t - t0, st.pose.controlled() if st else np.full(4, np.nan), truth_pose(), planned_at(t - t0), ref,
                         st.actuators.as_array() if st else np.full(5, np.nan), valves.copy()))
        if (quiet_since is not None and t - quiet_since >= move.hold_s - 1e-9) or t - t0 >= move.max_time_s - 1e-9:
            break
    cols = list(zip(*rows))
    kind = move.reference + ("+lead" if move.lead and move.reference == "trajectory" else "")
    return MoveTrace(kind, np.asarray(p0), truth_start, np.asarray(p1), float(duration), np.array(cols[0]),
                     *(np.array(c, dtype=float) for c in cols[1:]), link_counters=rig.link.counters.as_dict(),
                     node_counters=rig.node.counters.as_dict(), faults=rig.link.faults.reasons,
                     bus_load=rig.bus_load())


@dataclass(frozen=True)
class MoveFigures:
    """Figures of one move from one pose signal (``measured`` over CAN, or ``truth``).

    The planned path is the straight segment start → goal in pose space
    (x, z, roll, pitch; m and rad as they are, as the planner's straight line); the start
    is the measured one for ``measured``, the true one for ``truth``.

    Attributes:
        final_error: final pose − goal per DOF (x, z, roll, pitch), SI; the final pose
            is the mean over the last ``final_window_s`` of the run.
        final_error_position_m: |(Δx, Δz)| of ``final_error``, m.
        final_error_angle_rad: max(|Δroll|, |Δpitch|), rad.
        max_path_deviation_m: max over the run of |(e_x, e_z)|, e = pose − nearest
            point of the segment, m.
        max_path_deviation_rad: max of |(e_roll, e_pitch)|, rad.
        overshoot: how far the pose went beyond the goal along the segment, fraction
            of the segment (0 = none).
        settling_time_s: from the first command until the pose stays within the band
            (``band_position_m`` on |(Δx, Δz)|, ``band_angle_rad`` on both angles) of
            the goal; None if it is outside at the end.
    """

    final_error: dict[str, float]
    final_error_position_m: float
    final_error_angle_rad: float
    max_path_deviation_m: float
    max_path_deviation_rad: float
    overshoot: float
    settling_time_s: float | None
    band_position_m: float
    band_angle_rad: float


def build_move_figures(trace: MoveTrace, which: str = "measured", *, band_position_m: float = 0.005,
                       band_angle_rad: float = 0.005, final_window_s: float = 0.5) -> MoveFigures:
    """The figures of ``trace`` from its ``measured`` or ``truth`` poses (see :class:`MoveFigures`)."""
    if which not in ("measured", "truth"):
        raise SimError(f"which must be 'measured' or 'truth', got {which!r}")
    for name, v in (("band_position_m", band_position_m), ("band_angle_rad", band_angle_rad),
                    ("final_window_s", final_window_s)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 < v <= 10.0:
            raise SimError(f"{name} must be a number in (0, 10], got {v!r}")
    pose = getattr(trace, which)
    ok = np.all(np.isfinite(pose), axis=1)
    t, pose = trace.t[ok], pose[ok]
    if len(t) == 0:
        raise SimError(f"the trace has no {which} pose")
    p0, p1 = (trace.start if which == "measured" else trace.truth_start), trace.goal
    final = pose[t >= t[-1] - final_window_s + 1e-9].mean(axis=0) - p1
    d = p1 - p0
    dd = float(d @ d)
    s = (pose - p0) @ d / dd if dd > 0 else np.zeros(len(t))
    e = pose - (p0 + np.clip(s, 0.0, 1.0)[:, None] * d)
    err = pose - p1
    outside = (np.hypot(err[:, 0], err[:, 1]) > band_position_m) | (np.max(np.abs(err[:, 2:]), axis=1) > band_angle_rad)
    last_out = np.flatnonzero(outside)
    settle = None if outside[-1] else float(t[last_out[-1] + 1]) if len(last_out) else float(t[0])
    return MoveFigures(
        final_error=dict(zip(_POSE, map(float, final))),
        final_error_position_m=float(np.hypot(final[0], final[1])),
        final_error_angle_rad=float(np.max(np.abs(final[2:]))),
        max_path_deviation_m=float(np.max(np.hypot(e[:, 0], e[:, 1]))),
        max_path_deviation_rad=float(np.max(np.hypot(e[:, 2], e[:, 3]))),
        overshoot=float(max(0.0, np.max(s) - 1.0)) if dd > 0 else 0.0,
        settling_time_s=settle, band_position_m=float(band_position_m), band_angle_rad=float(band_angle_rad))
