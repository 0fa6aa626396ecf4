"""The simulated cylinder ECU as an ISO 11783 CAN node (the wiring).

:class:`EcuCanNode` puts a :class:`~bridge.sim.ecu.CylinderECU` behind the same
CAN API as the thesis's PhyCORE-MPC555 ECU (the messages of ``bridge/isobus/hitch.dbc``):

* receives 0xFF21 position references (→ :meth:`CylinderECU.set_reference`, which
  feeds the 100 ms watchdog; after a trip the valves stay at zero until the references have
  arrived without a break for 50 ms, so a burst of references queued during a link stall never
  moves a cylinder: :mod:`bridge.sim.watchdog`), 0xFF23 parameters (controllers on/off, watchdog
  timeout) and the planner's heartbeat (monitored);
* sends 0xFF22 position measurements (tilt, top, right, left + system-state byte)
  every ``measurement_period_s`` (100 Hz), the lift through the ISO 11783-7 rear
  hitch status (PGN 65093) every ``hitch_status_period_s``, and its heartbeat
  (100 ms, 251 first);
* claims its address (169) with its NAME at start and after a restart, and sends
  nothing else until the 250 ms contention window has passed; if it loses the
  address it falls silent and ignores references (the watchdog then holds the
  valves at zero).

The lift goes out as a *fraction of the calibrated travel* (thesis table 3-2:
−0.223..0.663 rad ↔ 26..255 counts), ``(counts − 26) / 229`` clipped to 0..1, at the
ISO resolution of 0.4 %/bit — not as raw sensor counts, whose 251..255 would be
reserved values of the 8-bit field. The requantisation costs up to 1.8 mrad of lift
angle on top of the AD count (3.87 mrad).

ISO 11783-7 sends the rear hitch status every 100 ms; here it defaults to the
0xFF22 period (10 ms) because the planner combines it with the four other readings
into one pose and applies the same 200 ms staleness limit to it (configurable).

Fault injection: the node's bus always goes through a
:class:`~bridge.sim.fault_injector.FaultInjector` (no fault by default: frames pass at once);
:meth:`EcuCanNode.apply_fault` changes what it injects at run time (cut a direction, lose or
delay frames, restart the ECU). The system-state byte of every 0xFF22 says whether the
watchdog has expired (bit 1): with references cut, the planner reads from it that they do
not arrive.

Time: the node owns no clock. :meth:`poll` (drain the bus, step the ECU to ``now_s``,
send what is due) is driven either by a simulated clock (deterministic runs, see
:mod:`bridge.sim.rig`) or in real time by :class:`bridge.link.realtime.RealtimeRunner`
(``hitch ecu-sim``). A frame is handled at the ``now_s`` of the poll that reads it.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Protocol

import can

from bridge.isobus.address_claim import CLAIM_WAIT_S, AddressClaimer, ClaimState, Name, cylinder_ecu_name
from bridge.isobus.codec import (
    CodecError,
    EcuParameters,
    Heartbeat,
    Payload,
    PositionCounts,
    PositionMeasurement,
    RearHitchStatus,
    load_codec,
)
from bridge.isobus.heartbeat import HEARTBEAT_PERIOD_S, HeartbeatMonitor, HeartbeatSender, HeartbeatStatus
from bridge.isobus.j1939 import (
    CYLINDER_ECU_ADDRESS,
    PGN_ADDRESS_CLAIMED,
    PGN_HEARTBEAT,
    PGN_PARAMETERS,
    PGN_POSITION_REFERENCE,
    PGN_REQUEST,
    PLANNER_ADDRESS,
    J1939Error,
    LimitStatus,
    decode_id,
)
from bridge.sim.ecu import CylinderECU
from bridge.sim.fault_injector import FaultCounters, FaultInjector, FaultSettings
from planner.errors import HitchInputError

__all__ = ["DraftSource", "EcuCanNode", "EcuNodeConfig", "EcuNodeCounters", "EcuNodeError", "lift_fraction"]


class DraftSource(Protocol):
    """What fills the draft fields of the rear hitch status (e.g. a field run's draft pins): called at
    ``now_s`` when the frame is due, it returns a status whose ``draft_n``, ``nominal_lower_link_force``
    and ``in_work`` the node sends (its position and limit status are the node's own), or None."""

    def __call__(self, now_s: float) -> RearHitchStatus | None: ...


#: the messages the ECU reads (every other known message is counted ``ignored`` without decoding it)
_CONSUMED_PGNS = frozenset({PGN_HEARTBEAT, PGN_POSITION_REFERENCE, PGN_PARAMETERS})

_EPS_S = 1e-6  # float-time tolerance of the periodic schedules


class EcuNodeError(HitchInputError):
    """Bad settings of the simulated ECU node; the message names the field and the allowed range."""


def _check_period(name: str, value: object, low: float, high: float) -> None:
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not low <= value <= high
    ):
        raise EcuNodeError(f"{name} must be a number of seconds in [{low:g}, {high:g}], got {value!r}")


def lift_fraction(counts: float, counts_min: float, counts_max: float) -> float:
    """Lift sensor reading [counts] → rear hitch position, fraction of travel 0..1 (clipped)."""
    return min(1.0, max(0.0, (counts - counts_min) / (counts_max - counts_min)))


@dataclass(frozen=True)
class EcuNodeConfig:
    """Settings of one :class:`EcuCanNode`.

    Attributes:
        source_address: our address (thesis cylinder ECU: 169).
        planner_address: references and parameters are taken from this source only
            (thesis planner: 166); ``None`` accepts any source.
        measurement_period_s: 0xFF22 period, s (100 Hz).
        hitch_status_period_s: rear hitch status (lift) period, s.
        heartbeat_period_s: heartbeat period, s (ISO 11783-7: 0.1).
        name: our NAME; on contention for ``source_address`` the lower NAME wins.
        claim_wait_s: address-claim contention window, s (ISO 11783-5: 0.25).
    """

    source_address: int = CYLINDER_ECU_ADDRESS
    planner_address: int | None = PLANNER_ADDRESS
    measurement_period_s: float = 0.01
    hitch_status_period_s: float = 0.01
    heartbeat_period_s: float = HEARTBEAT_PERIOD_S
    name: Name = field(default_factory=cylinder_ecu_name)
    claim_wait_s: float = CLAIM_WAIT_S

    def __post_init__(self) -> None:
        for attr, allow_none in (("source_address", False), ("planner_address", True)):
            v = getattr(self, attr)
            if not (v is None and allow_none) and (isinstance(v, bool) or not isinstance(v, int) or not 0 <= v <= 253):
                raise EcuNodeError(f"{attr} must be a source address in 0..253, got {v!r}")
        _check_period("measurement_period_s", self.measurement_period_s, 0.001, 1.0)
        _check_period("hitch_status_period_s", self.hitch_status_period_s, 0.001, 1.0)
        _check_period("heartbeat_period_s", self.heartbeat_period_s, 0.01, 10.0)
        _check_period("claim_wait_s", self.claim_wait_s, 0.001, 10.0)
        if not isinstance(self.name, Name):
            raise EcuNodeError(f"name must be a bridge.isobus.address_claim.Name, got {type(self.name).__name__}")


@dataclass(frozen=True)
class EcuNodeCounters:
    """Frame counters of the node (monotonic).

    ``ignored``: frames not for us (other sources, own echo on udp_multicast, PGNs we
    do not consume, references before our address is claimed); ``unknown_pgn``: PGNs
    the DBC does not describe; ``parameters_rejected``: 0xFF23 frames asking for what
    this ECU cannot do (valve multipliers are fixed per profile) — not applied at all.
    """

    frames_rx: int = 0
    frames_tx: int = 0
    references: int = 0
    parameters: int = 0
    parameters_rejected: int = 0
    malformed: int = 0
    unknown_pgn: int = 0
    ignored: int = 0
    error_frames: int = 0
    tx_errors: int = 0
    restarts: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


class _Schedule:
    """A periodic deadline on the grid k · period of node time: without drift, without catch-up
    bursts, and in phase with every other schedule of the same period on the node's clock (the
    machine twin's nodes then send together, and the runners wake once per period, not once per node)."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.due_s = math.inf

    def anchor(self, now_s: float) -> None:
        """First due at the first grid point at or after ``now_s`` (∞: never)."""
        self.due_s = now_s if math.isinf(now_s) else self._grid_at_or_after(now_s)

    def fire(self, now_s: float) -> bool:
        if now_s < self.due_s - _EPS_S:
            return False
        self.due_s += self.period_s
        if self.due_s <= now_s + _EPS_S:  # late by a period or more: the next grid point after now
            self.due_s = self._grid_at_or_after(now_s + 2 * _EPS_S)
        return True

    def _grid_at_or_after(self, t_s: float) -> float:
        return math.ceil(t_s / self.period_s - _EPS_S / self.period_s) * self.period_s


class EcuCanNode:
    """A :class:`CylinderECU` on a python-can bus (virtual, udp_multicast or socketcan).

    Args:
        ecu: the simulated ECU (its clock is advanced by :meth:`poll`).
        bus: an open python-can bus; the node never closes it (the owner does). The node
            reads and sends through a :class:`~bridge.sim.fault_injector.FaultInjector`
            around it (:attr:`bus`).
        config: addresses, periods, NAME.
        fault_clock: the clock injected delays are measured on, s (default
            ``time.monotonic``; a simulation passes its simulated clock).
        fault_seed: seed of the injected frame loss.
    """

    def __init__(
        self,
        ecu: CylinderECU,
        bus: can.BusABC,
        config: EcuNodeConfig | None = None,
        *,
        fault_clock: Callable[[], float] = time.monotonic,
        fault_seed: int = 0,
    ) -> None:
        if not isinstance(ecu, CylinderECU):
            raise EcuNodeError(f"ecu must be a CylinderECU, got {type(ecu).__name__}")
        self._ecu = ecu
        self._faults = FaultInjector(bus, seed=fault_seed, clock=fault_clock)
        self._bus: can.BusABC = self._faults
        self._restart_pending = False
        self._cfg = config if config is not None else EcuNodeConfig()
        self._codec = load_codec()
        self._known_pgns = frozenset(decode_id(m.frame_id).pgn for m in self._codec.database.messages)
        self._claimer = AddressClaimer(self._cfg.name, self._cfg.source_address, wait_s=self._cfg.claim_wait_s)
        self._heartbeat = HeartbeatSender(self._cfg.source_address, period_s=self._cfg.heartbeat_period_s)
        self._planner_hb = (
            HeartbeatMonitor(self._cfg.planner_address) if self._cfg.planner_address is not None else None
        )
        self._measurement = _Schedule(self._cfg.measurement_period_s)
        self._hitch = _Schedule(self._cfg.hitch_status_period_s)
        self._counters = EcuNodeCounters()
        self._operating = False  # address claimed and periodic traffic running
        self._last_malformed = ""
        self._last_frames: dict[str, tuple[tuple[object, ...], int, bytes]] = {}  # _memo_frame
        self._lock = threading.RLock()
        self.draft_source: DraftSource | None = None
        """Fills RearDraft / the nominal lower-link force of the hitch status (None: not available)."""

    # -- properties --------------------------------------------------------------------
    @property
    def ecu(self) -> CylinderECU:
        """The simulated ECU behind the node."""
        return self._ecu

    @property
    def bus(self) -> can.BusABC:
        """The bus the node sends on and reads from: the fault injector around the bus given."""
        return self._bus

    @property
    def fault_settings(self) -> FaultSettings:
        """The faults injected now (``restart_ecu`` as last requested)."""
        return self._faults.settings

    @property
    def fault_counters(self) -> FaultCounters:
        """What the fault injector did to frames so far."""
        return self._faults.counters

    def apply_fault(self, settings: FaultSettings | Mapping[str, object]) -> FaultSettings:
        """Inject ``settings`` from now on (thread-safe; any thread may call it).

        ``settings`` is a :class:`~bridge.sim.fault_injector.FaultSettings` or its JSON object
        ``{"cut", "loss", "delay_ms", "restart_ecu"}`` (missing keys: no fault; the whole
        setting is replaced). ``restart_ecu`` restarts the ECU once, at the node's next
        :meth:`poll` (restart counter +1, no-reference bit, address claimed again).
        Returns the settings now in force.

        Raises:
            FaultError: a setting out of range, naming the field and the allowed range.
        """
        s = settings if isinstance(settings, FaultSettings) else FaultSettings.from_mapping(settings)
        self._faults.apply(s)
        if s.restart_ecu:
            with self._lock:
                self._restart_pending = True
        return s

    @property
    def config(self) -> EcuNodeConfig:
        """The node's settings."""
        return self._cfg

    @property
    def counters(self) -> EcuNodeCounters:
        """Frame counters (a snapshot)."""
        return self._counters

    @property
    def claim_state(self) -> ClaimState:
        """Where the address claim is."""
        return self._claimer.state

    @property
    def last_malformed(self) -> str:
        """The codec's reason for the last rejected frame ("" if none)."""
        return self._last_malformed

    def planner_heartbeat(self, now_s: float) -> HeartbeatStatus | None:
        """The planner heartbeat monitor's conclusion (None when any source is accepted)."""
        return None if self._planner_hb is None else self._planner_hb.status(now_s)

    def next_due_s(self) -> float:
        """Earliest time something must be sent (for a real-time loop's sleep), s."""
        if not self._operating:
            return (
                math.inf
                if self._claimer.state is ClaimState.CANNOT_CLAIM
                else self._ecu.time_s + self._cfg.measurement_period_s
            )
        return min(self._measurement.due_s, self._hitch.due_s, self._ecu.time_s + self._cfg.heartbeat_period_s)

    # -- life cycle --------------------------------------------------------------------
    def start(self, now_s: float) -> None:
        """Power-up: advance the ECU to ``now_s`` and claim our address."""
        with self._lock:
            self._ecu.step(now_s)
            self._operating = False
            self._measurement.anchor(math.inf)
            self._hitch.anchor(math.inf)
            self._send(self._claimer.start(now_s))

    def restart(self, now_s: float) -> None:
        """Reset the ECU (controllers, watchdog, reference forgotten, restart counter +1)
        and start over as after power-up: claim, then heartbeat 251 and measurements."""
        with self._lock:
            self._ecu.step(now_s)
            self._ecu.restart()
            self._bump(restarts=1)
            self.start(now_s)

    def poll(self, now_s: float) -> None:
        """Handle every frame waiting on the bus at ``now_s``, advance the ECU to ``now_s``
        and send what is due. Never blocks."""
        with self._lock:
            if self._restart_pending:
                self._restart_pending = False
                self.restart(now_s)
            self._faults.flush()
            while (frame := self._bus.recv(timeout=0.0)) is not None:
                self.handle(frame, now_s)
            self._ecu.step(now_s)
            self._send(self._claimer.poll(now_s))
            self._periodic(now_s)

    def handle(self, frame: can.Message, now_s: float) -> None:
        """Process one received frame at ``now_s``."""
        with self._lock:
            self._bump(frames_rx=1)
            if frame.is_error_frame:
                self._bump(error_frames=1)
                return
            if not frame.is_extended_id or frame.is_remote_frame:
                self._bump(ignored=1)
                return
            try:
                ident = decode_id(frame.arbitration_id)
            except J1939Error as exc:
                self._last_malformed = str(exc)
                self._bump(malformed=1)
                return
            self._send(self._claimer.handle(frame, now_s))
            if ident.source_address == self._cfg.source_address or ident.pgn in (PGN_ADDRESS_CLAIMED, PGN_REQUEST):
                return  # our own echo (udp_multicast) or claim traffic, handled above
            if ident.pgn not in self._known_pgns:
                self._bump(unknown_pgn=1)
                return
            if ident.pgn not in _CONSUMED_PGNS:  # other nodes' traffic (measurements, the tractor's sensors …)
                self._bump(ignored=1)
                return
            try:
                decoded = self._codec.decode_frame(frame)
            except CodecError as exc:
                self._last_malformed = str(exc)
                self._bump(malformed=1)
                return
            payload, source = decoded.payload, decoded.source_address
            planner = self._cfg.planner_address
            if isinstance(payload, Heartbeat):
                if self._planner_hb is not None and source == planner:
                    self._planner_hb.handle_sequence(payload.sequence, now_s)
                else:
                    self._bump(ignored=1)
                return
            if (
                (planner is not None and source != planner)
                or not self._claimer.claimed
                or not isinstance(payload, (PositionCounts, EcuParameters))
            ):
                self._bump(ignored=1)
                return
            if isinstance(payload, PositionCounts):
                self._ecu.set_reference(payload.as_tuple(), now_s)
                self._bump(references=1)
            else:
                self._apply_parameters(payload, now_s)

    def shutdown(self, now_s: float) -> None:
        """Graceful stop: heartbeat 255 once, then silence (the bus stays open)."""
        with self._lock:
            self._ecu.step(now_s)
            if self._operating:
                self._send(self._heartbeat.shutdown())
            self._operating = False

    # -- internals ---------------------------------------------------------------------
    def _apply_parameters(self, p: EcuParameters, now_s: float) -> None:
        if any(m is not None for m in p.valve_multipliers):
            self._last_malformed = (
                "EcuParameters.valve_multipliers: the simulated ECU's valve "
                "multipliers are fixed by the profile (thesis table 3-3); frame not applied"
            )
            self._bump(parameters_rejected=1)
            return
        self._ecu.step(now_s)
        if p.watchdog_timeout_s is not None:
            self._ecu.watchdog.timeout_s = float(p.watchdog_timeout_s)
        if p.controllers_enabled is not None:
            self._ecu.controllers_enabled = p.controllers_enabled
        self._bump(parameters=1)

    def _periodic(self, now_s: float) -> None:
        if self._claimer.state is not ClaimState.CLAIMED:
            self._operating = False
            return
        if not self._operating:  # just claimed: heartbeat 251, measurements from now on
            self._operating = True
            self._send(self._heartbeat.start(now_s))
            self._measurement.anchor(now_s)
            self._hitch.anchor(now_s)
        else:
            self._send(self._heartbeat.poll(now_s))
        if self._measurement.fire(now_s):
            self._send([self._measurement_frame()])
        if self._hitch.fire(now_s):
            self._send([self._hitch_frame(now_s)])

    def _measurement_frame(self) -> can.Message:
        c = self._ecu.measurement_tuple()  # lift, tilt, top, left, right
        state = self._ecu.system_state()
        return self._memo_frame(
            "measurement",
            (c, state),
            lambda: PositionMeasurement(
                tilt_counts=_reading(c[1]),
                top_counts=_reading(c[2]),
                right_counts=_reading(c[4]),
                left_counts=_reading(c[3]),
                system_state=state,
            ),
        )

    def _hitch_frame(self, now_s: float) -> can.Message:
        lift_min, lift_max = self._ecu.lift_calibration_counts()
        counts = self._ecu.measurement_tuple()[0]
        fraction = lift_fraction(counts, lift_min, lift_max)
        limit = LimitStatus.NOT_LIMITED
        if self._ecu.relay_engaged()[0]:
            limit = LimitStatus.LIMITED_HIGH if fraction > 0.5 else LimitStatus.LIMITED_LOW
        draft = self.draft_source(now_s) if self.draft_source is not None else None
        if draft is not None:
            return self._codec.encode(
                replace(draft, position=fraction, limit_status=limit), source=self._cfg.source_address
            )
        return self._memo_frame(
            "hitch", (fraction, limit), lambda: RearHitchStatus(position=fraction, limit_status=limit)
        )

    def _memo_frame(self, name: str, key: tuple[object, ...], payload: Callable[[], Payload]) -> can.Message:
        """The frame of ``payload()``, built only when ``key`` (what the payload is made of) differs from the
        last frame of ``name``: a hitch at rest sends the same two frames 100 times a second."""
        last = self._last_frames.get(name)
        if last is None or last[0] != key:
            msg = self._codec.encode(payload(), source=self._cfg.source_address)
            last = self._last_frames[name] = (key, msg.arbitration_id, bytes(msg.data))
            return msg
        return can.Message(arbitration_id=last[1], is_extended_id=True, data=last[2])

    def _send(self, frames: list[can.Message]) -> None:
        for frame in frames:
            try:
                self._bus.send(frame)
            except can.CanError:
                self._bump(tx_errors=1)
            else:
                self._bump(frames_tx=1)

    def _bump(self, **deltas: int) -> None:
        c = self._counters
        values = dict(c.__dict__)  # as dataclasses.replace, without its per-field introspection (per frame)
        for k, v in deltas.items():
            values[k] += v
        self._counters = type(c)(**values)


def _reading(counts: int) -> int | None:
    """An AD sample as a 0xFF22 field. Raw 1022/1023 are the J1939 error and
    not-available codes, so a saturated converter cannot be sent as a number: it goes
    out as "not available" (None)."""
    return counts if counts <= 1021 else None
