"""The machine side of a service: models, guards, the CAN buses with the twin, the link, the controller.

Built the same way whether the control core runs in the service's own process (threads) or in
a process of its own (:mod:`bridge.service.core`): :func:`start_can` opens the buses and starts
their real-time runners — the simulated cylinder ECU and the tractor twin when configured, the
tractor's sensors, then the link (last: its runner's clock is the service's clock) — and
:func:`build_controller` puts a :class:`~bridge.service.motion.controller.MotionController` on
top. Every :class:`~planner.model.kinematics.HitchModel` is used by one thread only (their
CasADi buffers are shared state), so each part gets its own.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from bridge.isobus.j1939 import (
    PGN_ADDRESS_CLAIMED,
    PGN_HEARTBEAT,
    PGN_PARAMETERS,
    PGN_POSITION_MEASUREMENT,
    PGN_POSITION_REFERENCE,
    PGN_REAR_HITCH_STATUS,
    PGN_REQUEST,
    PGN_WHEEL_BASED_SPEED,
)
from bridge.isobus.messages import (
    PGN_GROUND_DISTANCE,
    PGN_HITCH_PTO_COMMANDS,
    PGN_ROW_GUIDANCE,
    PGN_SLOPE_SENSOR_INFORMATION,
    PGN_SLOPE_SENSOR_INFORMATION_2,
)
from bridge.link.can_link import CanLink
from bridge.link.hitch_switch import HitchSwitchNode
from bridge.link.realtime import RealtimeRunner, SharedBusNodes, open_bus
from bridge.link.state import LinkConfig
from bridge.link.tractor_sensors import TractorSensors, TractorSensorsConfig
from bridge.service.config import ServiceConfig
from bridge.service.motion.controller import MotionController
from bridge.service.motion.following import FollowingErrorLimits
from bridge.service.motion.types import MODES, actuator_dict
from bridge.service.work import build_work_control, sim_field_tractor, sim_scenario_tractor, simulated_ground_speed
from bridge.sim.can_node import EcuCanNode
from bridge.sim.ecu import CylinderECU
from bridge.sim.tractor_node import TractorTwinNode, hitch_height_from_ecu
from bridge.sim.truth import MachineTruth, load_machine_truth
from planner.limits.guard import Guard
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES
from planner.trajectory import TrajectoryPlanner

__all__ = [
    "CanParts",
    "PLANNER_PGNS",
    "TWIN_PGNS",
    "pgn_filters",
    "planner_filters",
    "ReadingsAsTrackSensors",
    "build_controller",
    "build_guard",
    "build_model",
    "service_info",
    "start_can",
]

#: what the planner's bus receives: the ECU's measurements, heartbeat and hitch status, the tractor's
#: sensors and wheel-based speed, address claims and requests (the ECU's pressures and everything else
#: are filtered out: on a loopback hub by the hub, before they are sent to this process)
PLANNER_PGNS = frozenset(
    {
        PGN_POSITION_MEASUREMENT,
        PGN_HEARTBEAT,
        PGN_REAR_HITCH_STATUS,
        PGN_WHEEL_BASED_SPEED,
        PGN_SLOPE_SENSOR_INFORMATION,
        PGN_SLOPE_SENSOR_INFORMATION_2,
        PGN_GROUND_DISTANCE,
        PGN_ROW_GUIDANCE,
        PGN_ADDRESS_CLAIMED,
        PGN_REQUEST,
        PGN_HITCH_PTO_COMMANDS,  # the operator's rear hitch raise / lower switch (bridge.link.hitch_switch)
    }
)
#: what the machine twin's bus receives: references, parameters, the planner's heartbeat, claims, requests
TWIN_PGNS = frozenset({PGN_POSITION_REFERENCE, PGN_PARAMETERS, PGN_HEARTBEAT, PGN_ADDRESS_CLAIMED, PGN_REQUEST})


def pgn_filters(pgns: frozenset[int]) -> list[dict[str, Any]]:
    """python-can receive filters passing the J1939 PGNs ``pgns`` from any source (and, for a PDU1
    PGN, to any destination): the PGN's bits of the 29-bit identifier must match."""
    out: list[dict[str, Any]] = []
    for pgn in sorted(pgns):
        pdu1 = ((pgn >> 8) & 0xFF) < 0xF0
        mask = 0x3FF0000 if pdu1 else 0x3FFFF00  # data page + PF (+ PS for PDU2), never the priority or source
        out.append({"can_id": (pgn << 8) & mask, "can_mask": mask, "extended": True})
    return out


def planner_filters(source_address: int) -> list[dict[str, Any]]:
    """The planner bus's receive filters: :data:`PLANNER_PGNS` from any source, and every frame with the link's
    own ``source_address`` whatever its PGN. The bus never gives the link its own frames back (python-can's
    virtual bus, the loopback hub and socketcan deliver a frame to the other buses only), so such a frame is
    another node's using our address — the link's ``address_conflict`` (J1939-81). Before, the PGN filter
    dropped 0xFF21 and 0xFF23 and spoofed references from 166 went unnoticed (an integrator's finding)."""
    return [*pgn_filters(PLANNER_PGNS), {"can_id": source_address, "can_mask": 0xFF, "extended": True}]


#: the longest a CAN runner waits for a frame before it polls its node again [s]
_MAX_WAIT_S = 0.02
#: the shortest check period of the planner's link at rest (the control period, but never more often than
#: the 10 ms of a link on its own); the longest is _MAX_WAIT_S
_MIN_CHECK_PERIOD_S = 0.01


def build_model(cfg: ServiceConfig) -> HitchModel:
    """A fresh model of the configured profile and category (one per thread that uses it)."""
    return HitchModel.from_profile(cfg.profile, cfg.category)


def build_guard(cfg: ServiceConfig, model: HitchModel) -> Guard:
    """The guard of ``model`` at the control rate, without an implement: the service's implement (the configured
    one, or the persisted selection) comes from :meth:`bridge.service.implements.ImplementService.restore`, which
    checks its ISO 730 category. Built with ``cfg.implement`` before, a category-2 implement named on a category-3
    hitch went into every guard unchecked (a user trial)."""
    return Guard(TrajectoryPlanner(model, rate=cfg.control_rate))


@dataclass
class CanParts:
    """What :func:`start_can` started: the link, the twin's nodes (None with a real machine), the
    tractor's sensors, and every runner and bus (to stop and shut down, in reverse order)."""

    link: CanLink
    sensors: TractorSensors
    ecu_node: EcuCanNode | None = None
    tractor_node: TractorTwinNode | None = None
    runners: list[RealtimeRunner] = field(default_factory=list)
    buses: list[can.BusABC] = field(default_factory=list)
    switch: HitchSwitchNode | None = None  # the operator's raise / lower switch (docs/implements.md)

    @property
    def clock(self) -> Callable[[], float]:
        """The service's clock: the link runner's node time [s]."""
        return self.runners[-1].now

    def close(self) -> None:
        """Stop the reference stream, the runners, the link and the buses (never raises)."""
        now = self.clock()
        for step in (lambda: self.link.stop(now), *[lambda r=r: r.stop(0.5) for r in reversed(self.runners)]):
            try:
                step()
            except Exception:  # noqa: BLE001 — closing continues whatever one part does
                pass
        for part in (self.link.close, *[b.shutdown for b in self.buses]):
            try:
                part()
            except Exception:  # noqa: BLE001
                pass


def start_can(cfg: ServiceConfig, *, runners_out: list[RealtimeRunner] | None = None) -> CanParts:
    """Open the buses and start their runners (module docstring). ``runners_out`` receives each
    runner as it starts (so a caller can stop them if a later step fails).

    Two buses, one runner each (:class:`~bridge.link.realtime.SharedBusNodes`): the machine twin's
    (the ECU and the tractor, when simulated) and the planner's (the tractor's sensors and the
    link). Each frame is then copied to one other bus instead of one per node."""
    started: list[RealtimeRunner] = runners_out if runners_out is not None else []
    buses: list[can.BusABC] = []

    def bus(filters: list[dict[str, Any]]) -> can.BusABC:
        b = open_bus(cfg.can_interface, cfg.can_channel, can_filters=filters)
        buses.append(b)
        return b

    ecu_node: EcuCanNode | None = None
    tractor: TractorTwinNode | None = None
    try:
        if cfg.simulate_ecu:
            ecu_model = build_model(cfg)
            # the twin's own true machine (bridge.sim.truth): its AD map in the ECU, its geometry for the
            # height sensor; the link and the planner stay on the nominal profile
            truth = (
                MachineTruth.nominal(ecu_model.profile) if cfg.sim_truth is None else load_machine_truth(cfg.sim_truth)
            )
            # the twin starts with the pistons at the model's neutral actuators (x = roll = pitch = 0)
            scale = SensorScaling(truth.profile)
            neutral_counts = scale.counts_min + (ecu_model.neutral - scale.si_min) / scale.resolution
            twin = SharedBusNodes(bus(pgn_filters(TWIN_PGNS)))
            ecu = CylinderECU(truth.profile, initial_counts=list(neutral_counts), calibration=ecu_model.profile)
            ecu_node = EcuCanNode(ecu, twin.port())
            true_model = build_model(cfg) if cfg.sim_truth is None else HitchModel(truth.profile, cfg.category)
            height = hitch_height_from_ecu(ecu_node.ecu, true_model)
            pivot = float(true_model.profile.geometry.pivot_height)  # the field's terrain and draft (sim_field)
            tractor = (
                sim_field_tractor(cfg, twin.port(), height, ecu_node, pivot)
                or sim_scenario_tractor(cfg, twin.port(), height)
                or TractorTwinNode(twin.port(), ground_speed_m_s=cfg.sim_ground_speed, hitch_height_m=height)
            )
            twin.add(ecu_node).add(tractor)
            # frames as they arrive while changing references feed the ECU; otherwise (at rest, or holding a
            # pose) at its 10 ms ticks, as an ECU's control task reads its mailbox: the planner's heartbeats and
            # repeated references do not wake it between them
            started.append(
                RealtimeRunner(
                    twin, max_wait_s=_MAX_WAIT_S, name="EcuCanNode-rt", prompt=lambda: ecu.fed and not ecu.holding
                ).start()
            )
        # real time: the bus stamps frames on a real clock, so a stall of this process alone is not
        # taken for a late ECU heartbeat (LinkConfig.bus_timestamps)
        # at rest the link is checked once a control period, within [10, 20] ms (LinkConfig.check_period_s)
        link_cfg = LinkConfig(
            hitch_status_address=cfg.hitch_status_address,
            hitch_status_period_s=cfg.hitch_status_period(),
            control_rate_hz=cfg.control_rate,
            stale_after_s=cfg.stale_timeout_s,
            bus_timestamps=True,
            check_period_s=min(max(1.0 / cfg.control_rate, _MIN_CHECK_PERIOD_S), _MAX_WAIT_S),
        )
        planner = SharedBusNodes(bus(planner_filters(link_cfg.source_address)))
        sensors = TractorSensors(planner.port(), TractorSensorsConfig(read_draft=True))  # draft: work control
        link = CanLink(build_model(cfg), planner.port(), link_cfg)
        switch = HitchSwitchNode(planner.port())
        planner.add(sensors).add(link).add(switch)
        # frames as they arrive only while changing references stream; at rest, and while the link holds a
        # pose (re-sending the last reference), the bus is read at the link's deadlines: its checks and its
        # reference slots (the control cycle reads the state once a period; RealtimeRunner's prompt)
        runner = RealtimeRunner(
            planner, max_wait_s=_MAX_WAIT_S, name="CanLink-rt", prompt=lambda: link.streaming and not link.holding
        )
        started.append(runner.start())
    except BaseException:
        for r in reversed(started):
            r.stop(0.5)
        for b in buses:
            b.shutdown()
        raise
    return CanParts(link, sensors, ecu_node, tractor, list(started), buses, switch=switch)


class _Rate:
    """The rate of a sampled signal: a smoothed difference of its new samples (time constant ``tau_s``)."""

    def __init__(self, tau_s: float = 0.1):
        self.tau_s = tau_s
        self._t: float | None = None
        self._v = 0.0
        self.rate = 0.0

    def update(self, t: float, value: float) -> float:
        if self._t is None or t <= self._t:
            if self._t is None:
                self._t, self._v = t, value
            return self.rate
        dt = t - self._t
        raw = (value - self._v) / dt
        self.rate += (raw - self.rate) * (dt / (self.tau_s + dt))
        self._t, self._v = t, value
        return self.rate


class ReadingsAsTrackSensors:
    """The tractor's sensors as a track session's frames read them
    (:class:`~bridge.service.motion.controller.TrackSensors`): fresh, plausible readings or None,
    judged at ``now`` (the sensors run on the link's runner: one clock with the controller).

    Rates: the slope sensor's pitch rate; the roll rate and the ground distance's rate from their
    new samples (a difference smoothed over 0.1 s); ``rates=False`` offers none (the frames then
    convert positions only). Also the crop-row offset (guidance)."""

    def __init__(self, sensors: TractorSensors, *, rates: bool = True):
        self.node = sensors
        self.rates = rates
        self._roll_rate, self._dist_rate = _Rate(), _Rate()

    def attitude(self, now: float) -> tuple[float, float] | None:
        r = self.node.readings(now)
        if r.roll.usable and r.pitch.usable and r.roll.value is not None and r.pitch.value is not None:
            return float(r.roll.value), float(r.pitch.value)
        return None

    def attitude_rate(self, now: float) -> tuple[float, float] | None:
        if not self.rates:
            return None
        r = self.node.readings(now)
        if not (r.roll.usable and r.roll.value is not None and r.roll.received_s is not None):
            return None
        roll_rate = self._roll_rate.update(r.roll.received_s, r.roll.value)
        pitch_rate = r.pitch_rate.value if r.pitch_rate.usable and r.pitch_rate.value is not None else 0.0
        return roll_rate, pitch_rate

    def ground_distance(self, now: float) -> float | None:
        g = self.node.readings(now).ground_distance
        return float(g.value) if g.usable and g.value is not None else None

    def ground_distance_rate(self, now: float) -> float | None:
        if not self.rates:
            return None
        g = self.node.readings(now).ground_distance
        if not (g.usable and g.value is not None and g.received_s is not None):
            return None
        return self._dist_rate.update(g.received_s, g.value)

    def row_offset(self, now: float) -> tuple[float, float] | None:
        """(offset [m], receive time [s]) of the latest usable camera sample."""
        r = self.node.readings(now).row_offset
        if r.usable and r.value is not None and r.received_s is not None:
            return float(r.value), float(r.received_s)
        return None


def build_controller(
    cfg: ServiceConfig,
    parts: CanParts,
    *,
    on_state: Callable[[dict[str, Any]], None],
    on_event: Callable[[dict[str, Any]], None],
) -> tuple[MotionController, Guard]:
    """The motion controller on ``parts`` (its guard, a planning guard, each on its own model);
    returns it and its control guard (for :func:`service_info`)."""
    guard, plan_guard = build_guard(cfg, build_model(cfg)), build_guard(cfg, build_model(cfg))
    mc = MotionController(
        guard,
        plan_guard,
        parts.link,
        parts.clock,
        on_state=on_state,
        on_event=on_event,
        state_every=max(1, round(cfg.control_rate / cfg.state_rate)),
        odometer=parts.sensors.distance_m,
        feedforward=cfg.feedforward,
        following=FollowingErrorLimits(
            lift_rad=cfg.following_error_lift_rad,
            length_m=cfg.following_error_m,
            lag_s=cfg.following_error_lag_s,
            time_s=cfg.following_error_s,
        ),
        sensors=ReadingsAsTrackSensors(parts.sensors),
    )
    pivot = float(mc.planner.model.profile.geometry.pivot_height)
    mc.work = build_work_control(cfg, mc, parts.sensors, parts.link, pivot)  # work/… (bridge.service.work)
    if (switch := parts.switch) is not None:  # a switch edge becomes an event; the service raises / returns on it
        switch.on_command = lambda cmd: mc.post_event({"event": "hitch_switch", "command": cmd})
        switch.on_stale = lambda cmd, age: mc.post_event(
            {
                "event": "hitch_switch_ignored",
                "command": cmd,
                "age_s": round(age, 3),
                "message": f"switch {cmd} read {age:.2f} s after it was pressed (limit "
                f"{switch.max_age_s:g} s: the service was stalled); not acted on — press it again",
            }
        )
    return mc, guard


def service_info(cfg: ServiceConfig, guard: Guard) -> dict[str, Any]:
    """The static part of the ``config`` reply: profile, rates, CAN, limits, modes."""
    tp, model = guard.planner, guard.model
    return {
        "prefix": cfg.prefix,
        "profile": model.profile.name,
        "category": model.category,
        "implement": cfg.implement,
        "control_rate": tp.rate,
        "state_rate": cfg.state_rate,
        "can": {
            "interface": cfg.can_interface,
            "channel": cfg.can_channel,
            "simulated_ecu": cfg.simulate_ecu,
            "simulated_ground_speed": simulated_ground_speed(cfg),  # the speed the twin drives (a field's own)
            # what the twin's tractor drives over (None: flat ground, or no twin)
            "simulated_scenario": cfg.sim_scenario if cfg.simulate_ecu else None,
            "simulated_field": cfg.sim_field if cfg.simulate_ecu else None,
        },
        "limits": {
            "workspace": {k: list(tp.workspace[k]) for k in CONTROLLED_POSE_NAMES},
            "strokes": {
                n: [float(lo), float(hi)] for n, lo, hi in zip(ACTUATOR_NAMES, model.lower, model.upper, strict=True)
            },
            "actuator_velocity": actuator_dict(tp.limits.velocity),
            "actuator_acceleration": actuator_dict(tp.limits.acceleration),
            # a jog's top rates [m/s, rad/s]: the pose rates reachable in any direction from anywhere
            "jog_velocity": {
                k: float(v) for k, v in zip(CONTROLLED_POSE_NAMES, tp.any_direction.velocity, strict=True)
            },
        },
        "modes": list(MODES),
    }
