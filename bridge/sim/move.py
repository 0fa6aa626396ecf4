"""Running the simulated cylinder ECU and the planner link together over CAN: closed-loop moves.

The simulated rig (:class:`SimRig`, :class:`SimSettings`, :class:`LossyBus`) lives in
:mod:`bridge.sim.rig` and is re-exported here: both nodes
on a private python-can ``virtual`` channel, advanced in simulated time (deterministic and
much faster than real time; real time: :class:`bridge.link.realtime.RealtimeRunner`).

:func:`run_move` is the closed-loop experiment of ``hitch sim move`` (a step reference,
thesis style, or the Ruckig plan streamed at the control rate, by default through the unit
loops' feed-forward of :mod:`bridge.link.unit_loop`); :func:`build_move_figures`
turns its trace into the reported figures.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from bridge.link.count_tail import plan_count_tail
from bridge.link.unit_loop import FeedforwardShaper, build_unit_loops
from bridge.sim.cylinder import build_cylinder_params
from bridge.sim.ecu import ACTUATOR_ORDER
from bridge.sim.rig import LossyBus, SimError, SimRig, SimSettings
from bridge.sim.truth import MachineTruth
from planner.limits.guard import Guard
from planner.model.kinematics import HitchModel
from planner.trajectory import MotionState, TrajectoryPlanner

__all__ = [
    "LossyBus",
    "MoveFigures",
    "MoveSettings",
    "MoveTrace",
    "REFERENCE_KINDS",
    "SimError",
    "SimRig",
    "SimSettings",
    "build_move_figures",
    "run_move",
]

REFERENCE_KINDS = ("step", "trajectory")
_POSE = ("x", "z", "roll", "pitch")


@dataclass(frozen=True)
class MoveSettings:
    """One closed-loop move.

    Attributes:
        reference: "step" (goal actuators at once, thesis style) or "trajectory"
            (Ruckig plan samples streamed at the link's control rate).
        start: start pose (any of x, z, roll, pitch; default the neutral pose).
        speed_scale: fraction of full trajectory speed, (0, 1].
        feedforward: trajectory only: stream the reference under which each unit loop
            follows its plan (:mod:`bridge.link.unit_loop`), instead of the plan's actuator
            positions themselves (which each cylinder follows with its own lag).
        warmup_s: time for address claims and first measurements before the move, s.
        hold_s: the run ends once every valve command stayed zero this long, s.
        max_time_s: ... or this long after the move started, s.
    """

    reference: str = "trajectory"
    start: Mapping[str, float] | None = None
    speed_scale: float = 1.0
    feedforward: bool = True
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

    reference_kind: str  # "step", "trajectory" or "trajectory+feedforward"
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


def run_move(
    model: HitchModel,
    goal: Mapping[str, float],
    move: MoveSettings | None = None,
    sim: SimSettings | None = None,
    *,
    truth: MachineTruth | None = None,
) -> MoveTrace:
    """Drive the simulated ECU through the CAN path from ``move.start`` to ``goal``.

    ``truth``: the twin's own true machine (:mod:`bridge.sim.truth`; default exactly ``model``'s
    profile): the ECU reads the pistons through its AD map, and the ``truth`` poses of the trace are
    its geometry and play (:meth:`SimRig.true_pose`); the planner and the link stay on ``model``.

    Raises:
        SimError: no measurement after warm-up, or the link refused a command.
        PlanError: the goal is outside the workspace or cannot be planned.
    """
    move = move if move is not None else MoveSettings()
    sim = sim if sim is not None else SimSettings()
    tp = TrajectoryPlanner(model, rate=sim.link.control_rate_hz)
    p_start = tp.goal_vector(model.neutral_pose.controlled(), move.start or {})
    tp.check_in_workspace(p_start, "start")
    with SimRig(model, sim, initial_actuators=tp.inverse.solve(p_start)[0], truth=truth) as rig:
        rig.start()
        rig.run_until(move.warmup_s)
        state = rig.link.latest_state()
        if state is None:
            raise SimError(
                f"no measurement from the ECU after {move.warmup_s} s (faults: "
                f"{', '.join(rig.link.faults.reasons) or 'none'})"
            )
        p0 = state.pose.controlled()
        p1 = tp.goal_vector(p0, goal)
        tp.check_in_workspace(p1)
        if move.reference == "step":
            return _drive(rig, model, np.zeros(1), tp.inverse.solve(p1)[0][None, :], lambda t: p1, p0, p1, 0.0, move)
        plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(_POSE, p1, strict=True)), speed_scale=move.speed_scale)
        sp = tp.sample(plan)
        refs = sp.actuators
        if move.feedforward:
            shaper = FeedforwardShaper(
                build_unit_loops(model.profile, rig.ecu.config.a), tp.inverse.solve_full, rig.link.check_reference
            )
            refs = np.array(
                [
                    shaper.for_plan(plan.state_at, float(t), q, qd)
                    for t, q, qd in zip(sp.t, sp.actuators, sp.actuator_velocity, strict=True)
                ]
            )
        times = sp.t
        # the profile's count approach after the plan, as the service streams it (bridge.link.count_tail)
        tail = plan_count_tail(tp, plan, rig.link.check_reference, Guard(tp))
        if tail is not None:
            t_end = float(sp.t[-1])
            times = np.r_[sp.t, t_end + 1.0 / tp.rate, t_end + tail.approach.via_hold_s]
            refs = np.vstack([refs, tail.via_actuators, tail.final_actuators])
        return _drive(rig, model, times, refs, lambda t: plan.state_at(t).position, p0, p1, plan.duration, move)


@dataclass(frozen=True)
class _Sample:
    """One 10 ms row of a :class:`MoveTrace` (see there for the units)."""

    t: float
    measured: np.ndarray
    truth: np.ndarray
    planned: np.ndarray
    reference: np.ndarray
    measured_actuators: np.ndarray
    valves: np.ndarray


def _drive(
    rig: SimRig,
    model: HitchModel,
    times: np.ndarray,
    refs: np.ndarray,
    planned_at: Callable[[float], np.ndarray],
    p0: np.ndarray,
    p1: np.ndarray,
    duration: float,
    move: MoveSettings,
) -> MoveTrace:
    """Stream ``refs`` (SI actuators) at ``times`` (s) after now, record every 10 ms, stop when the valves rest."""
    t0, k, n = rig.now_s, 0, 0
    quiet_since: float | None = None
    rows: list[_Sample] = []
    every = max(1, round(0.01 / rig.settings.tick_s))
    # the streamed reference in SI through the planner's calibration (what it commanded; the ECU's own
    # AD map is the truth's)
    params = tuple(build_cylinder_params(n, model.profile.actuator(n)) for n in ACTUATOR_ORDER)

    def truth_pose() -> np.ndarray:  # the simulated pistons through the twin's true machine (not measured)
        return rig.true_pose().controlled()

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
            counts = rig.link.status(t).reference_counts
            ref = (
                np.full(5, np.nan)
                if counts is None
                else np.array([p.counts_to_si(c) for p, c in zip(params, counts, strict=True)])
            )
            rows.append(
                _Sample(
                    t=t - t0,
                    measured=st.pose.controlled() if st else np.full(4, np.nan),
                    truth=truth_pose(),
                    planned=planned_at(t - t0),
                    reference=ref,
                    measured_actuators=st.actuators.as_array() if st else np.full(5, np.nan),
                    valves=valves.copy(),
                )
            )
        if (quiet_since is not None and t - quiet_since >= move.hold_s - 1e-9) or t - t0 >= move.max_time_s - 1e-9:
            break
    kind = move.reference + ("+feedforward" if move.feedforward and move.reference == "trajectory" else "")
    return MoveTrace(
        reference_kind=kind,
        start=np.asarray(p0),
        truth_start=truth_start,
        goal=np.asarray(p1),
        plan_duration_s=float(duration),
        t=np.array([r.t for r in rows]),
        measured=np.array([r.measured for r in rows], dtype=float),
        truth=np.array([r.truth for r in rows], dtype=float),
        planned=np.array([r.planned for r in rows], dtype=float),
        reference=np.array([r.reference for r in rows], dtype=float),
        measured_actuators=np.array([r.measured_actuators for r in rows], dtype=float),
        valves=np.array([r.valves for r in rows], dtype=float),
        link_counters=rig.link.counters.as_dict(),
        node_counters=rig.node.counters.as_dict(),
        faults=rig.link.faults.reasons,
        bus_load=rig.bus_load(),
    )


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


def build_move_figures(
    trace: MoveTrace,
    which: str = "measured",
    *,
    band_position_m: float = 0.005,
    band_angle_rad: float = 0.005,
    final_window_s: float = 0.5,
) -> MoveFigures:
    """The figures of ``trace`` from its ``measured`` or ``truth`` poses (see :class:`MoveFigures`)."""
    if which not in ("measured", "truth"):
        raise SimError(f"which must be 'measured' or 'truth', got {which!r}")
    for name, v in (
        ("band_position_m", band_position_m),
        ("band_angle_rad", band_angle_rad),
        ("final_window_s", final_window_s),
    ):
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
        final_error=dict(zip(_POSE, map(float, final), strict=True)),
        final_error_position_m=float(np.hypot(final[0], final[1])),
        final_error_angle_rad=float(np.max(np.abs(final[2:]))),
        max_path_deviation_m=float(np.max(np.hypot(e[:, 0], e[:, 1]))),
        max_path_deviation_rad=float(np.max(np.hypot(e[:, 2], e[:, 3]))),
        overshoot=float(max(0.0, np.max(s) - 1.0)) if dd > 0 else 0.0,
        settling_time_s=settle,
        band_position_m=float(band_position_m),
        band_angle_rad=float(band_angle_rad),
    )
