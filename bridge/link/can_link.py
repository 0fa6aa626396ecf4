"""The planner side of the CAN bridge: reference stream out, measured state in.

:class:`CanLink` talks to the cylinder ECU (the real one, or the simulated ``bridge.sim.can_node``):

* **References.** :meth:`CanLink.send_reference` takes actuators in SI, checks them
  against every hard limit (strokes, top-link angles, ground clearance — names as in
  :mod:`planner.model.hard_limits`) and converts them with
  :meth:`planner.model.sensors.SensorScaling.to_counts`; a reference that fails raises
  :class:`~bridge.link.state.ReferenceRefused` naming the limit and never reaches the
  bus. The accepted reference is streamed as 0xFF21 at the control rate (default
  50 Hz) on a grid of one period P per frame, never faster: a fresh reference goes at
  once when its grid slot is open (up to P/2 early — a caller's jitter never holds it
  back), a caller faster than P waits for the next slot; without a fresh one the last
  is repeated, P/2 after its slot (so a repetition never takes the slot of the
  caller's next reference; frames at least P/2 and at most 2 P apart, one per
  period on average). The ECU's watchdog needs this stream.
* **Measurements.** 0xFF22 (tilt, top, right, left, system state) and the rear hitch
  status (lift, fraction of travel) → SI through the AD calibration → exact forward
  kinematics → :class:`~bridge.link.state.LinkState`.
* **Safety.** A measurement older than ``stale_after_s`` (200 ms), an ECU heartbeat
  silent > 300 ms / in error / shut down, an ECU restart (heartbeat 251 again, a
  change of the restart counter or the no-reference bit reappearing in the system
  state), references that do not arrive (while streaming, the ECU's system state says
  its watchdog expired), a lost address claim, a frame with our source address that we did not
  send (another node uses our address: ``address_conflict``) or repeated send failures latch a fault
  (:class:`~bridge.link.state.LinkFaults` lists each, how fast and whether it latches)
  and **stop the reference stream**; the ECU's watchdog then zeroes its valves within its timeout
  (100 ms). Motion resumes only on a fresh :meth:`send_reference`, accepted once the
  causes are gone; the old reference is never resumed.
* **What it tells the ECU.** Once its address is claimed, when the ECU starts (its first heartbeat 251) and
  whenever the ECU restarts, one 0xFF23 with controllers on and the reference watchdog the link assumes
  (``LinkConfig.ecu_watchdog_timeout_s``); every :data:`MEASURED_POSE_PERIOD_S` (100 ms) the newest measured
  pose as 0xFF25 while the measurements are fresh, none while they are stale (both on :meth:`poll`).
* **Reasons.** Each occurrence of a fault gives its own reason: a cause that comes back while its fault is
  still latched, or changes its kind (a heartbeat timeout become a sequence error), replaces the older reason.
  The stale fault says why the frames that arrived were not taken (the last rejection and how many, or their
  sender's other address: :meth:`~bridge.link.state.MeasurementAssembler.why_stale`). The link follows the address
  claims of the ECU's address it sees: when the ECU lost it to a lower NAME, the stale and heartbeat reasons say so
  (its NAME, the winner's, when) instead of pointing at the cable (:meth:`CanLink._ecu_claim_loss`). An all-0xFF
  0xFF22 (J1939 "not available") is no measurement and has no system state: not a restart, not lost references.
* **Address.** The link claims its address at :meth:`CanLink.start`. Lost to a lower NAME, it asks
  the address every ``LinkConfig.address_recheck_s`` (1 s) whether the winner still holds it and
  claims it back when nobody with a lower NAME answers (a spoofed claim does not take it for ever);
  meanwhile :attr:`CanLink.address_problem` names the NAME that holds it, and ``address_lost``
  stays present in :meth:`CanLink.fault_causes`. A frame with our source address is our own echo only
  when we sent one with the same identifier and data within the last second
  (:data:`ECHO_WINDOW_S`); any other is an address conflict (J1939-81): fault ``address_conflict``,
  present while such frames arrive (:data:`CONFLICT_HOLD_S`), and our claim is sent again so that the
  other node sees the contention.
* **Accounting.** Malformed frames (codec rejections), unknown PGNs (other ISOBUS
  traffic — counted, not a fault), frames from other sources, our own echo
  (udp_multicast), unavailable or out-of-span readings, dropped periodic frames
  (inferred from arrival gaps), error frames and failed sends are counted in
  :class:`~bridge.link.state.LinkCounters`.

Time: the link owns no clock and no thread. Every method takes ``now_s`` (any
monotonic clock in seconds). :meth:`poll` drains the bus without blocking — a
simulation calls it from its simulated clock (the rig of ``bridge.sim.rig``); in real time a
:class:`bridge.link.realtime.RealtimeRunner` calls it from a background thread that blocks on the bus
between deadlines (no busy loop). All public methods take an internal lock, so a
service thread may call :meth:`send_reference` while the runner polls.
"""

from __future__ import annotations

import math
import re
import threading
from collections import deque
from collections.abc import Iterable
from dataclasses import replace

import can
from numpy.typing import ArrayLike

from bridge.isobus.address_claim import AddressClaimer, ClaimState, Name
from bridge.isobus.codec import (
    AddressClaimed,
    CodecError,
    EcuParameters,
    Heartbeat,
    MeasuredPose,
    PositionCounts,
    PositionMeasurement,
    RearHitchStatus,
    load_codec,
)
from bridge.isobus.heartbeat import INITIAL_SEQUENCE, HeartbeatMonitor, HeartbeatSender, HeartbeatState
from bridge.isobus.j1939 import (
    PGN_ADDRESS_CLAIMED,
    PGN_HEARTBEAT,
    PGN_POSITION_MEASUREMENT,
    PGN_REAR_HITCH_STATUS,
    PGN_REQUEST,
    J1939Error,
    decode_id,
)
from bridge.isobus.system_state import STATE_WATCHDOG_TRIPPED, measurement_not_available
from bridge.link.realtime import shutdown_bus
from bridge.link.reference_check import ReferenceCheck
from bridge.link.state import (
    HITCH,
    MEASUREMENT,
    LinkConfig,
    LinkCounters,
    LinkFaultError,
    LinkFaults,
    LinkState,
    LinkStatus,
    MeasurementAssembler,
    ReferenceRefused,
    frame_stamp,
)
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling

__all__ = ["CONFLICT_HOLD_S", "ECHO_WINDOW_S", "CanLink", "HOLD_AFTER_RESENT", "MEASURED_POSE_PERIOD_S"]

_EPS_S = 1e-6  # float-time tolerance of the stream schedule
#: a fresh reference may go this fraction of a period before its slot; a repetition waits as long after
_SLOT_SLACK = 0.5


#: frames in a row re-sending an older reference after which the link counts as holding (:attr:`CanLink.holding`):
#: one late control cycle while moving does not count
HOLD_AFTER_RESENT = 2
#: a received frame with our source address is our echo if we sent its identifier and data this recently, s
ECHO_WINDOW_S = 1.0
#: an address conflict (a frame with our source address we did not send) stays present this long after the
#: last such frame, s: the link refuses to stream meanwhile
CONFLICT_HOLD_S = 1.0
#: our claim is sent again on an address conflict at most this often, s
_CONFLICT_CLAIM_EVERY_S = 1.0
#: claim states in which frames with our source address are another node's (not a conflict)
_ADDRESS_NOT_OURS = (ClaimState.IDLE, ClaimState.CANNOT_CLAIM)
#: a condition's kind: its reason up to the first digit (the numbers — ages, counters, counts — change from one
#: check to the next, the words do not: "ECU heartbeat timeout: none for ", "ECU heartbeat sequence error; …")
_KIND = re.compile(r"[^0-9]*")
#: the period of the measured pose the link sends (0xFF25, to a logging PC), s
MEASURED_POSE_PERIOD_S = 0.1
#: a loss of the ECU's address this long before its last frame taken still explains its silence (the frames it
#: sent before it saw the winning claim), s
_CLAIM_LOSS_BEFORE_S = 1.0
#: the messages the link reads (every other known message is counted ``foreign`` without decoding it)
_CONSUMED_PGNS = frozenset({PGN_HEARTBEAT, PGN_POSITION_MEASUREMENT, PGN_REAR_HITCH_STATUS})


class CanLink:
    """Planner-side link to one cylinder ECU over ``bus`` (see the module docstring).

    Args:
        model: kinematic model (its profile gives strokes and AD calibration).
        bus: an open python-can bus.
        config: addresses, rates, timeouts.
        own_bus: close ``bus`` in :meth:`close`.
    """

    def __init__(
        self, model: HitchModel, bus: can.BusABC, config: LinkConfig | None = None, *, own_bus: bool = False
    ) -> None:
        self._model = model
        self._bus = bus
        self._own_bus = bool(own_bus)
        self._cfg = config if config is not None else LinkConfig()
        self._scaling = SensorScaling(model.profile)
        # every hard limit and the counts; it keeps the last values it accepted: the controller checks the
        # reference it is about to send (the feed-forward's safe_reference) and send_reference checks it again
        self._check = ReferenceCheck(model)
        self._codec = load_codec()
        self._known_pgns = frozenset(decode_id(m.frame_id).pgn for m in self._codec.database.messages)
        cfg = self._cfg
        self._claimer = AddressClaimer(
            cfg.name, cfg.source_address, wait_s=cfg.claim_wait_s, recheck_s=cfg.address_recheck_s or None
        )
        self._hb_tx = HeartbeatSender(cfg.source_address, period_s=cfg.heartbeat_period_s)
        self._hb_rx = HeartbeatMonitor(cfg.ecu_address, timeout_s=cfg.heartbeat_timeout_s)
        self._lock = threading.RLock()
        self._counts = dict(LinkCounters().__dict__)  # counted in place per frame; LinkCounters snapshots on read
        self._faults = LinkFaults()
        self._last_malformed = ""
        self._operating_s: float | None = None  # when our claim succeeded
        self._last_poll_s = 0.0
        self._reference: PositionCounts | None = None
        self._streaming = False
        self._stream_since_s = math.inf  # when the current stream started
        self._next_tx_s = math.inf  # the stream's next slot (a frame per slot, module docstring)
        self._fresh = False  # a reference was taken since the last frame went out
        self._resent = 0  # frames in a row that re-sent a reference taken before the previous frame
        self._last_tx_s = -math.inf  # when the last reference frame went out (kept across restarts)
        self._tx_error_run = 0
        self._tx_error_last = ""  # what the last failed send raised
        self._sent: dict[tuple[int, bytes], deque[float]] = {}  # (id, data) → send times within ECHO_WINDOW_S
        self._sent_pruned_s = -math.inf
        self._conflict_s = -math.inf  # the last frame with our source address that we did not send
        self._conflict_reason = ""
        self._conflict_claim_s = -math.inf  # when our claim last went out because of a conflict
        # the condition causes present at the last check, name → its kind (_kind): a cause that was absent, or of
        # another kind, is a new occurrence and records its own reason though its fault is still latched
        self._occurring: dict[str, str] = {}
        self._pose_due_s = math.inf  # when the next measured pose (0xFF25) is due
        # the claims of the ECU's address seen on the bus (_on_ecu_address_claim): the NAME holding it, a higher
        # NAME's claim the holder has not answered yet (NAME, when), the holder's last loss (when, loser, winner)
        self._ecu_holder: Name | None = None
        self._ecu_challenger: tuple[Name, float] | None = None
        self._ecu_claim_lost: tuple[float, Name, Name] | None = None
        self._rx = MeasurementAssembler(model, self._scaling, self._cfg, self._bump)
        # what the stale fault calls the lift's sender
        self._hitch_sender = "cylinder ECU" if cfg.hitch_source == cfg.ecu_address else "tractor"
        # 0xFF23: controllers on, the ECU's reference watchdog as the link assumes it (_send_ecu_parameters)
        self._parameters_frame = self._codec.encode(
            EcuParameters(controllers_enabled=True, watchdog_timeout_s=cfg.ecu_watchdog_timeout_s),
            source=cfg.source_address,
        )

    # -- read-only views ---------------------------------------------------------------
    @property
    def model(self) -> HitchModel:
        return self._model

    @property
    def bus(self) -> can.BusABC:
        return self._bus

    @property
    def config(self) -> LinkConfig:
        return self._cfg

    @property
    def counters(self) -> LinkCounters:
        """Frame counters (a snapshot)."""
        with self._lock:
            return LinkCounters(**self._counts)

    @property
    def faults(self) -> LinkFaults:
        """Latched faults (a snapshot)."""
        return self._faults

    @property
    def claimed(self) -> bool:
        """Our address claim succeeded and holds."""
        return self._claimer.claimed

    @property
    def address_problem(self) -> str:
        """Why our address is not ours, "" while it is claimed or being claimed: e.g. "address 166 lost, not
        claimed: NAME 0x0000000000000000 holds it (a lower NAME than ours, 0x…)". Present as long as it
        is true (the link re-checks the holder every ``address_recheck_s`` and claims the address
        back when it is silent); also the reason of ``address_lost`` and :attr:`LinkStatus.address_problem`."""
        with self._lock:
            return self._address_problem()

    def _address_problem(self) -> str:
        if self._claimer.state is not ClaimState.CANNOT_CLAIM:
            return ""
        sa, ours = self._cfg.source_address, self._claimer.name.value
        holder = self._claimer.holder
        who = f"NAME 0x{holder.value:016X} holds it" if holder is not None else "another node holds it"
        again = (
            f"; asked again every {self._cfg.address_recheck_s:g} s, claimed back once the holder is silent"
            if self._cfg.address_recheck_s
            else ""
        )
        return f"address {sa} lost, not claimed: {who} (a lower NAME than ours, 0x{ours:016X}){again}"

    @property
    def streaming(self) -> bool:
        """References are being sent."""
        return self._streaming

    @property
    def holding(self) -> bool:
        """Streaming a held reference: the last :data:`HOLD_AFTER_RESENT` frames re-sent one the controller
        handed over before them (at rest after a move, the link keeps the ECU's watchdog fed). Nothing on
        the bus then needs reading as it arrives (the runner's ``prompt``: :func:`bridge.service.machine.start_can`)."""
        return self._streaming and self._resent >= HOLD_AFTER_RESENT

    def peer_name(self, address: int) -> Name | None:
        """The ISO 11783-5 NAME the node at ``address`` claimed it with (the ECU's: its identity), None if unheard."""
        with self._lock:
            return self._claimer.peers.get(address)

    def latest_state(self) -> LinkState | None:
        """The newest measured state, or None before the first complete measurement."""
        return self._rx.state

    def status(self, now_s: float) -> LinkStatus:
        """A consistent snapshot for a supervisor. A cause that came back since the last :meth:`poll` while its
        fault is still latched gives its own reason in it already (raising is the poll's)."""
        with self._lock:
            conditions = self._conditions(now_s)
            self._raise_present(conditions, latch=False)
            ref = self._reference.as_tuple() if self._reference is not None else None
            return LinkStatus(
                now_s,
                self.claimed,
                self._streaming,
                ref,
                self._rx.state,
                self._faults,
                self._hb_rx.status(now_s),
                LinkCounters(**self._counts),
                self._last_malformed,
                self._rx.last_problem,
                self._address_problem(),
                tuple(dict.fromkeys(name for name, _ in conditions)),
            )

    def next_due_s(self) -> float:
        """When :meth:`poll` must run next (the stream's deadline, or ``check_period_s`` after the last
        poll), s."""
        return min(self._stream_due_s() if self._streaming else math.inf, self._last_poll_s + self._cfg.check_period_s)

    # -- commands ----------------------------------------------------------------------
    def start(self, now_s: float) -> None:
        """Ask who is on the bus (their claims name the ECU: :meth:`peer_name`) and claim our address; heartbeat
        and streaming are possible once it is claimed."""
        with self._lock:
            self._operating_s, self._pose_due_s = None, math.inf
            self._streaming = False
            self._last_poll_s = now_s
            self._send([self._claimer.who_is_there(), *self._claimer.start(now_s)], now_s)

    def stop(self, now_s: float) -> None:
        """Stop streaming and say goodbye (heartbeat 255). The bus stays open."""
        with self._lock:
            self._streaming = False
            if self._operating_s is not None:
                self._send(self._hb_tx.shutdown(), now_s)
            self._operating_s, self._pose_due_s = None, math.inf

    def close(self) -> None:
        """Stop streaming and shut the bus down if the link owns it."""
        with self._lock:
            self._streaming = False
            if self._own_bus:
                shutdown_bus(self._bus)  # a hub that went away: nothing raised, nothing retried at collection

    def fault_causes(self, now_s: float) -> tuple[str, ...]:
        """Names of the condition faults whose causes are present at ``now_s`` (see
        :class:`~bridge.link.state.LinkFaults`); event faults never appear here."""
        with self._lock:
            return tuple(dict.fromkeys(name for name, _ in self._conditions(now_s)))

    def clear_faults(self, now_s: float, names: Iterable[str] | None = None) -> LinkFaults:
        """Acknowledge: clear the latched faults whose causes are gone at ``now_s`` (only those in ``names``
        when given), keep the others (their reasons too). Never starts the stream; returns the faults left.
        A fault cleared so and raised again is a new occurrence the link reports afresh."""
        with self._lock:
            present = set(self.fault_causes(now_s))
            only = None if names is None else set(names)
            keep = {name: name in present or (only is not None and name not in only) for name in self._faults.active()}
            held = {k for k, v in keep.items() if v}
            old = self._faults
            if len(old.reason_names) == len(old.reasons):  # the cleared faults' reasons go with them (a review)
                pairs = [(n, r) for n, r in zip(old.reason_names, old.reasons, strict=True) if n in held]
                reasons, reason_names = tuple(r for _, r in pairs), tuple(n for n, _ in pairs)
            else:  # reasons without their names (an older record): kept whole while any fault is
                reasons, reason_names = (old.reasons, old.reason_names) if held else ((), ())
            self._faults = replace(
                LinkFaults(), **dict.fromkeys(held, True), reasons=reasons, reason_names=reason_names
            )
            return self._faults

    def stop_motion(self) -> None:
        """Stop the reference stream (the ECU watchdog then zeroes the valves)."""
        with self._lock:
            self._streaming = False

    def check_reference(self, actuators: ArrayLike) -> PositionCounts:
        """The 0xFF21 counts of ``actuators`` (SI, actuator order) if within every hard limit.

        Raises:
            ReferenceRefused: naming the limit, the value and the bound.
        """
        with self._lock:  # the model's evaluation buffers are shared with the link's own thread
            return self._check(actuators)

    def send_reference(self, actuators: ArrayLike, now_s: float) -> PositionCounts:
        """Check ``actuators`` (SI) and stream them from ``now_s`` on; a fresh command also
        re-arms the link after a fault once its causes are gone.

        Raises:
            ReferenceRefused: outside a limit (nothing is sent).
            LinkFaultError: no address, no measurement yet, or a fault still active.
        """
        with self._lock:
            try:
                counts = self.check_reference(actuators)
                if not self.claimed:
                    raise LinkFaultError(
                        f"address {self._cfg.source_address} is not claimed ({self._claimer.state.value})"
                    )
                active = self._conditions(now_s)
                if active:
                    self._raise_present(active)
                    raise LinkFaultError("motion refused, fault active: " + "; ".join(r for _, r in active))
                if self._rx.state is None:
                    raise LinkFaultError("motion refused: no complete measurement from the ECU yet")
            except (ReferenceRefused, LinkFaultError):
                self._bump(references_refused=1)
                raise
            self._faults = LinkFaults()
            self._reference, self._fresh = counts, True
            if not self._streaming:  # a (re)start: its slot now (never within P/2 of the last frame)
                self._stream_since_s = self._next_tx_s = now_s
            self._streaming = True
            self._stream(now_s)
            return counts

    def send_parameters(self, parameters: EcuParameters, now_s: float) -> None:
        """Send a 0xFF23 parameters frame (e.g. controllers off) once."""
        with self._lock:
            if not self.claimed:
                raise LinkFaultError(f"address {self._cfg.source_address} is not claimed")
            self._send([self._codec.encode(parameters, source=self._cfg.source_address)], now_s)

    # -- the loop ----------------------------------------------------------------------
    def poll(self, now_s: float) -> None:
        """Handle every waiting frame, run the claim and heartbeat, check faults, stream; once claimed, bring the
        ECU to the parameters the link assumes (0xFF23, :meth:`_send_ecu_parameters`) and send the measured pose
        every :data:`MEASURED_POSE_PERIOD_S` while it is fresh (0xFF25)."""
        with self._lock:
            while (frame := self._bus.recv(timeout=0.0)) is not None:
                self.handle(frame, now_s)
            self._last_poll_s = now_s
            self._send(self._claimer.poll(now_s), now_s)
            if self._claimer.claimed:
                if self._operating_s is None:
                    self._operating_s, self._pose_due_s = now_s, now_s
                    self._send(self._hb_tx.start(now_s), now_s)
                    self._send_ecu_parameters(now_s)
                else:
                    self._send(self._hb_tx.poll(now_s), now_s)
            elif self._claimer.state is ClaimState.CANNOT_CLAIM:
                # silent; a claim won back starts over (heartbeat 251)
                self._operating_s, self._pose_due_s = None, math.inf
            if now_s - self._sent_pruned_s >= ECHO_WINDOW_S:
                self._prune_sent(now_s)
            self._raise_present(self._conditions(now_s))
            self._stream(now_s)
            if now_s >= self._pose_due_s - _EPS_S:
                self._send_pose(now_s)

    def handle(self, frame: can.Message, now_s: float) -> None:
        """Process one received frame at ``now_s``."""
        with self._lock:
            self._bump(frames_rx=1)
            if frame.is_error_frame:
                self._bump(bus_errors=1)
                return
            if not frame.is_extended_id or frame.is_remote_frame:
                self._bump(foreign=1)
                return
            try:
                ident = decode_id(frame.arbitration_id)
            except J1939Error as exc:
                self._malformed(str(exc))
                return
            self._send(self._claimer.handle(frame, now_s), now_s)
            if ident.source_address == self._cfg.source_address:
                if self._is_echo(frame, now_s):
                    self._bump(own_echo=1)
                elif ident.pgn == PGN_ADDRESS_CLAIMED or self._claimer.state in _ADDRESS_NOT_OURS:
                    self._bump(foreign=1)  # a contending claim (the claimer decides), or the address is not ours
                else:
                    self._on_conflict(ident.pgn, now_s)
                return
            if ident.pgn in (PGN_ADDRESS_CLAIMED, PGN_REQUEST):
                if ident.pgn == PGN_ADDRESS_CLAIMED and ident.source_address == self._cfg.ecu_address:
                    self._on_ecu_address_claim(frame, now_s)
                return
            if ident.pgn not in self._known_pgns:
                self._bump(unknown_pgn=1)
                return
            if ident.pgn not in _CONSUMED_PGNS:  # another node's traffic (slope sensor, pressures …): not decoded
                self._bump(foreign=1)
                return
            src, cfg = ident.source_address, self._cfg
            try:
                decoded = self._codec.decode_frame(frame)
            except CodecError as exc:
                self._malformed(str(exc))
                # a measurement its sender sent that cannot be read: the stale fault says why (why_stale)
                if ident.pgn == PGN_POSITION_MEASUREMENT and src == cfg.ecu_address:
                    self._rx.reject(MEASUREMENT, str(exc), now_s)
                elif ident.pgn == PGN_REAR_HITCH_STATUS and src == cfg.hitch_source:
                    self._rx.reject(HITCH, str(exc), now_s)
                return
            payload = decoded.payload
            if isinstance(payload, Heartbeat) and src == cfg.ecu_address:
                self._on_heartbeat(payload.sequence, now_s, frame_stamp(frame) if cfg.bus_timestamps else None)
            elif isinstance(payload, PositionMeasurement) and src == cfg.ecu_address:
                if measurement_not_available(payload):
                    self._on_measurement_not_available(frame, now_s)
                    return
                restart = self._rx.on_measurement(payload, now_s, frame_stamp(frame), decoded.errors)
                if restart:
                    self._on_restart(restart, now_s)
                else:
                    self._check_references_arrive(payload.system_state, now_s)
            elif isinstance(payload, RearHitchStatus) and src == cfg.hitch_source:
                self._rx.on_hitch_status(payload, now_s, frame_stamp(frame), decoded.errors)
            else:
                if isinstance(payload, PositionMeasurement):  # named by the stale fault (why_stale)
                    self._rx.from_elsewhere(MEASUREMENT, src, now_s)
                elif isinstance(payload, RearHitchStatus):
                    self._rx.from_elsewhere(HITCH, src, now_s)
                self._bump(foreign=1)

    # -- receive internals -------------------------------------------------------------
    def _on_heartbeat(self, sequence: int, now_s: float, stamp_s: float | None) -> None:
        self._bump(heartbeats_rx=1)
        before = self._hb_rx.status(now_s).restarts
        self._hb_rx.handle_sequence(sequence, now_s, stamp_s=stamp_s)
        if self._hb_rx.status(now_s).restarts > before:
            self._on_restart("the cylinder ECU restarted (its heartbeat counter began again at 251)", now_s)
        elif sequence == INITIAL_SEQUENCE:  # the ECU starts (its first heartbeat): it may have missed our 0xFF23
            self._send_ecu_parameters(now_s)

    def _on_ecu_address_claim(self, frame: can.Message, now_s: float) -> None:
        """An Address Claimed for the ECU's address: who holds it (J1939-81: the lower NAME wins a contention;
        a higher NAME's claim that the holder does not answer within the claim window takes it). A claim with a
        lower NAME than the holder's is the holder losing the address: kept (when, who lost, who won) for the
        stale and heartbeat reasons (:meth:`_ecu_claim_loss`) until the loser holds the address again."""
        try:
            payload = self._codec.decode_frame(frame).payload
        except CodecError:
            return  # counted by nobody: the claimer ignores it too
        if not isinstance(payload, AddressClaimed):
            return
        name = Name.from_int(payload.name)
        self._settle_ecu_claim(now_s)
        holder = self._ecu_holder
        if holder is None or name == holder:
            self._ecu_holder, self._ecu_challenger = name, None  # the first claim heard, or the holder's defence
        elif name.value < holder.value:
            self._ecu_holder, self._ecu_challenger = name, None
            self._ecu_claim_lost = (now_s, holder, name)
        else:
            self._ecu_challenger = (name, now_s)

    def _settle_ecu_claim(self, now_s: float) -> None:
        """A higher NAME's claim of the ECU's address that the holder did not answer within the claim window
        holds it now (the holder left); the ECU's own NAME holding it again ends a kept loss."""
        challenger = self._ecu_challenger
        if challenger is not None and now_s >= challenger[1] + self._cfg.claim_wait_s - _EPS_S:
            self._ecu_holder, self._ecu_challenger = challenger[0], None
        lost = self._ecu_claim_lost
        if lost is not None and self._ecu_holder == lost[1]:
            self._ecu_claim_lost = None

    def _ecu_claim_loss(self, last_s: float, now_s: float) -> str:
        """Why the ECU may have fallen silent since ``last_s`` [s]: it lost its address to a lower NAME (seen
        at most :data:`_CLAIM_LOSS_BEFORE_S` before ``last_s``, or after it, and not won back), "" if not."""
        self._settle_ecu_claim(now_s)
        lost = self._ecu_claim_lost
        if lost is None or lost[0] < last_s - _CLAIM_LOSS_BEFORE_S:
            return ""
        t, loser, winner = lost
        return (
            f"the cylinder ECU (NAME 0x{loser.value:016X}) lost its address {self._cfg.ecu_address} to NAME "
            f"0x{winner.value:016X} (address claim at t = {t:.3f} s), a lower NAME"
        )

    def _on_measurement_not_available(self, frame: can.Message, now_s: float) -> None:
        """A 0xFF22 from the ECU with no reading and the system-state byte 0xFF (an all-0xFF frame: J1939 "not
        available", :func:`~bridge.isobus.system_state.measurement_not_available`): no measurement, and no system
        state — its restart counter is not read as "15" (a fuzz trial latched "ECU restart counter 0 -> 15", and
        the next real frame "15 -> 0"), nor its watchdog bit as lost references. Counted as a measurement with
        unavailable readings; the stale fault says it (:meth:`~bridge.link.state.MeasurementAssembler.why_stale`)."""
        self._bump(measurements_rx=1, unavailable_readings=1)
        said = "an all-0xFF frame" if bytes(frame.data) == b"\xff" * 8 else "no reading and system state 0xFF"
        self._rx.reject(MEASUREMENT, f"{said} = not available (no reading, no system state)", now_s)

    def _check_references_arrive(self, system_state: int, now_s: float) -> None:
        """While streaming, a measurement saying the ECU's watchdog expired proves that our
        references do not reach it (once the stream is older than the allowed latency)."""
        if not self._streaming or not system_state & STATE_WATCHDOG_TRIPPED:
            return
        running_s = now_s - self._stream_since_s
        cfg = self._cfg
        if running_s > cfg.references_lost_after_s + _EPS_S:
            self._raise(
                [
                    (
                        "references_lost",
                        f"the ECU reports its reference watchdog expired (no fresh reference for "
                        f"{cfg.ecu_watchdog_timeout_s:g} s) while references are being sent: they are lost on the "
                        f"way, or arrive later than the link allows ({cfg.link_latency_s * 1000:.0f} ms each way)",
                    )
                ]
            )

    def _is_echo(self, frame: can.Message, now_s: float) -> bool:
        """The frame is one we sent within :data:`ECHO_WINDOW_S` (each sent frame echoes once)."""
        times = self._sent.get((frame.arbitration_id, bytes(frame.data)))
        while times and times[0] < now_s - ECHO_WINDOW_S:
            times.popleft()
        if not times:
            return False
        times.popleft()
        return True

    def _prune_sent(self, now_s: float) -> None:
        """Forget the sends older than :data:`ECHO_WINDOW_S`, of every frame: a bus that echoes nothing
        (socketcan, the virtual bus) never pops them, and a held pose re-sends one frame at 50 Hz (its times
        grew without bound before: 30 000 after 10 minutes, a reviewer's finding)."""
        old = now_s - ECHO_WINDOW_S
        for times in self._sent.values():
            while times and times[0] < old:
                times.popleft()
        self._sent = {k: v for k, v in self._sent.items() if v}
        self._sent_pruned_s = now_s

    def _on_conflict(self, pgn: int, now_s: float) -> None:
        """A frame with our source address that we did not send: another node uses our address
        (J1939-81). Raise ``address_conflict`` and send our claim again (at most once a second), so that
        the other node sees the contention."""
        self._bump(address_conflicts=1)
        sa = self._cfg.source_address
        self._conflict_s = now_s
        self._conflict_reason = (
            f"address conflict: a frame with our source address {sa} (PGN 0x{pgn:04X}) that this link did not "
            f"send: another node on the bus uses address {sa} (spoofed or misconfigured); motion refused until "
            f"none has arrived for {CONFLICT_HOLD_S:g} s"
        )
        # frames of one conflict (present until none for CONFLICT_HOLD_S) give its reason once; a later one its own
        new = "address_conflict" not in self._occurring
        self._occurring["address_conflict"] = _kind(self._conflict_reason)
        self._raise([("address_conflict", self._conflict_reason)], {"address_conflict"} if new else ())
        if self._claimer.claimed and now_s - self._conflict_claim_s >= _CONFLICT_CLAIM_EVERY_S:
            self._conflict_claim_s = now_s
            self._send(self._claimer.announce(), now_s)

    def _on_restart(self, reason: str, now_s: float) -> None:
        self._rx.forget_reference()
        self._raise([("ecu_restart", reason)])
        self._send_ecu_parameters(now_s)  # a restarted ECU starts on its own defaults

    def _malformed(self, reason: str) -> None:
        self._last_malformed = reason
        self._bump(malformed=1)

    # -- safety and sending ------------------------------------------------------------
    def _conditions(self, now_s: float) -> list[tuple[str, str]]:
        """Fault causes present now (name, reason); empty when motion may run."""
        out: list[tuple[str, str]] = []
        cfg = self._cfg
        if self._claimer.state is ClaimState.CANNOT_CLAIM:
            out.append(("address_lost", self._address_problem()))
        if now_s - self._conflict_s < CONFLICT_HOLD_S:
            out.append(("address_conflict", self._conflict_reason))
        if self._tx_error_run >= cfg.max_consecutive_tx_errors:
            out.append(("bus_error", f"{self._tx_error_run} sends failed in a row (last: {self._tx_error_last})"))
        if self._operating_s is None:
            return out
        st = self._rx.state
        since = self._operating_s
        for source, what, src, t in (  # said so an operator can act on it, with the bus names for the engineer
            (
                MEASUREMENT,
                "cylinder positions (0xFF22) from the cylinder ECU",
                cfg.ecu_address,
                st.measurement_t_s if st else since,
            ),
            (
                HITCH,
                f"lift position (rear hitch status) from the {self._hitch_sender}",
                cfg.hitch_source,
                st.lift_t_s if st else since,
            ),
        ):
            if now_s - t > cfg.stale_after_s + _EPS_S:
                # the ECU lost its address (a claim seen on the bus); why the frames that did arrive were not
                # taken; or that none did
                lost = self._ecu_claim_loss(t, now_s) if src == cfg.ecu_address else ""
                why = "; ".join(w for w in (lost, self._rx.why_stale(source, t, src)) if w)
                why = why or "check the CAN cable and the ECU's power"
                out.append(
                    (
                        "stale_measurement",
                        f"no valid {what} (address {src}) for {now_s - t:.3f} s (limit {cfg.stale_after_s:g} s): "
                        + why,
                    )
                )
                break
        hb = self._hb_rx.status(now_s)
        if hb.state in (
            HeartbeatState.TIMEOUT,
            HeartbeatState.SENDER_ERROR,
            HeartbeatState.SHUTDOWN,
            HeartbeatState.SEQUENCE_ERROR,  # a repeated or jumping counter: a hung sender (ISO 11783-7)
        ):
            # how long, against what limit, and the counter last heard (an incident investigator's report: it
            # said "ECU heartbeat timeout" alone, where the stale fault says its age and limit)
            said = f"ECU heartbeat {hb.state.value}"
            if hb.state is HeartbeatState.TIMEOUT and hb.age_s is not None:
                if hb.age_s > cfg.heartbeat_timeout_s or hb.last_gap_s is None:
                    said += f": none for {hb.age_s:.3f} s (limit {cfg.heartbeat_timeout_s:g} s)"
                else:  # heartbeats again after a gap: not yet 8 in sequence ("none for 0.000 s" contradicted itself)
                    said += (
                        f": a gap of {hb.last_gap_s:.3f} s between two (limit {cfg.heartbeat_timeout_s:g} s); "
                        "heartbeats arrive again, not yet 8 in sequence"
                    )
            hint = hb.sequence_error_hint()  # interleaved counters: two nodes with the ECU's address
            if hint is not None:  # before the counter: a latched reason is re-recorded when its words change
                said += f": {hint}"
            if hb.state is HeartbeatState.TIMEOUT and hb.age_s is not None:  # silent since it lost its address?
                if lost := self._ecu_claim_loss(now_s - hb.age_s, now_s):
                    said += f": {lost}"
            if hb.last_sequence is not None:
                said += f"; last counter {hb.last_sequence}"
            out.append(("ecu_heartbeat", said))
        elif hb.state is HeartbeatState.WAITING and now_s - since > cfg.heartbeat_timeout_s + _EPS_S:
            lost = self._ecu_claim_loss(since, now_s)
            out.append(("ecu_heartbeat", f"no ECU heartbeat for {now_s - since:.3f} s" + (f": {lost}" if lost else "")))
        return out

    def _raise_present(self, causes: list[tuple[str, str]], *, latch: bool = True) -> None:
        """Raise the condition ``causes`` present now (:meth:`_conditions`). A cause that was absent at the last
        check, or is of another kind now (a heartbeat timeout become a sequence error), is a new occurrence: it
        records its own reason even while its fault is still latched (every later heartbeat fault repeated the
        first one's "timeout" before, an integrator's report). ``latch=False`` (a status snapshot): only the
        reasons of faults latched already; raising is the poll's."""
        before, occurring, renew = self._occurring, {}, set()
        for name, reason in causes:
            if name not in occurring:
                occurring[name] = kind = _kind(reason)
                if before.get(name) != kind:
                    renew.add(name)
        self._occurring = occurring
        if latch:
            self._raise(causes, renew)
        elif renew:
            self._raise([(n, r) for n, r in causes if n in renew and getattr(self._faults, n)], renew)

    def _raise(self, causes: list[tuple[str, str]], renew: set[str] | tuple[str, ...] = ()) -> None:
        """Latch the faults of ``causes`` (name, reason) and stop the stream; a fault latched already records
        the new reason only if its name is in ``renew`` (a new occurrence; its older reasons are dropped)."""
        for name, reason in causes:
            latched = getattr(self._faults, name)
            if not latched or name in renew:
                f = self._faults
                keep = [(n, r) for n, r in zip(f.reason_names, f.reasons, strict=True) if n != name]
                self._faults = replace(
                    self._faults,
                    **{name: True},
                    reasons=tuple(r for _, r in keep) + (reason,),
                    reason_names=tuple(n for n, _ in keep) + (name,),
                )
                if not latched:
                    self._bump(faults_raised=1)
        if self._faults.any:
            self._streaming = False

    def _stream_due_s(self) -> float:
        """When the stream's next frame may go: a fresh reference up to half a period before its slot (and
        not within half a period of the last frame), a repetition half a period after it."""
        slack = _SLOT_SLACK * self._cfg.control_period_s
        if self._fresh:
            return max(self._next_tx_s - slack, self._last_tx_s + slack)
        return self._next_tx_s + slack

    def _stream(self, now_s: float) -> None:
        """Send the reference if its frame is due. Each frame moves the slot on by one period (to now after
        a gap of more than a period): frames at least P/2 apart (also across a stop and restart), at most
        ⌊T/P + ½⌋ + 2 in any window of T seconds, one per period on average."""
        if not self._streaming or self._reference is None or now_s < self._stream_due_s() - _EPS_S:
            return
        self._next_tx_s = max(self._next_tx_s + self._cfg.control_period_s, now_s)
        self._last_tx_s = now_s
        self._resent = 0 if self._fresh else self._resent + 1
        self._fresh = False
        if self._send([self._codec.encode(self._reference, source=self._cfg.source_address)], now_s):
            self._bump(references_tx=1)

    def _send_ecu_parameters(self, now_s: float) -> None:
        """Bring the ECU to what the link assumes of it: controllers on, its reference watchdog
        ``ecu_watchdog_timeout_s`` (0xFF23; the valve multipliers unchanged). Sent once our address is claimed,
        when the ECU starts (its first heartbeat 251: it may have been deaf to the first) and when it restarts:
        an ECU that powers up with its controllers off or another watchdog would otherwise not move, or not
        stop when the stream stops, as the link's fault timing assumes. Counted (``parameters_tx``)."""
        if self._operating_s is not None and self._send([self._parameters_frame], now_s):
            self._bump(parameters_tx=1)

    def _send_pose(self, now_s: float) -> None:
        """Send the newest measured pose (0xFF25, x, z, roll, pitch for a logging PC) while the measurements
        are fresh, none while they are stale; the next one :data:`MEASURED_POSE_PERIOD_S` later on its grid."""
        self._pose_due_s = max(self._pose_due_s + MEASURED_POSE_PERIOD_S, now_s)
        st = self._rx.state
        if st is None or st.age_s(now_s) > self._cfg.stale_after_s + _EPS_S:
            return
        p = st.pose
        try:
            frame = self._codec.encode(MeasuredPose(p.x, p.z, p.roll, p.pitch), source=self._cfg.source_address)
        except CodecError:
            return  # beyond the frame's ±3.2 m, rad: nothing a hitch reaches, nothing to log
        if self._send([frame], now_s):
            self._bump(poses_tx=1)

    def _send(self, frames: list[can.Message], now_s: float) -> bool:
        ok = True
        for frame in frames:
            try:
                self._bus.send(frame)
            except (can.CanError, OSError) as exc:  # OSError: a remote hub that went away (BrokenPipeError)
                ok = False
                self._tx_error_last = f"{type(exc).__name__}: {str(exc)[:160]}"
                self._tx_error_run += 1
                self._bump(tx_errors=1)
            else:
                self._tx_error_run = 0
                self._bump(frames_tx=1)
                key = (frame.arbitration_id, bytes(frame.data))  # its echo is ours (_is_echo)
                times = self._sent.get(key)
                if times is None:
                    times = self._sent[key] = deque()
                times.append(now_s)
        return ok

    def _bump(self, **deltas: int) -> None:
        counts = self._counts
        for k, v in deltas.items():
            counts[k] += v


def _kind(reason: str) -> str:
    """The kind of a condition's ``reason`` (:data:`_KIND`): the same words, whatever the numbers."""
    m = _KIND.match(reason)
    return m.group() if m is not None else reason
