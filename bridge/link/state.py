"""The state side of the planner-side CAN link (:mod:`bridge.link.can_link`): settings, the
measured state and how it is assembled from frames, fault flags, frame counters and
the errors a refused command raises.

The value types are frozen snapshots: the link builds new ones, callers (CLI,
simulation, a Zenoh service) read them without locks. :class:`MeasurementAssembler`
turns decoded 0xFF22 and rear-hitch-status payloads into a :class:`LinkState` through
the AD calibration (thesis tables 3-1, 3-2) and exact forward kinematics, and spots
ECU restarts in the system-state byte. SI units throughout; AD counts only in fields
named ``counts``/``*_counts``.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, fields

import can
import numpy as np

from bridge.isobus.address_claim import CLAIM_WAIT_S, Name, planner_name
from bridge.isobus.codec import PositionMeasurement, RearHitchStatus
from bridge.isobus.heartbeat import HEARTBEAT_PERIOD_S, HEARTBEAT_TIMEOUT_S, HeartbeatStatus
from bridge.isobus.j1939 import CYLINDER_ECU_ADDRESS, PLANNER_ADDRESS
from bridge.isobus.system_state import SystemStatus, decode_system_state
from bridge.link.arrival_rate import RATE_FACTOR, STAMP_SLACK_S, ArrivalRate
from planner.errors import HitchInputError
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES, Actuators, KinematicsError, Pose

__all__ = [
    "frame_stamp",
    "LinkConfig",
    "LinkCounters",
    "LinkError",
    "LinkFaultError",
    "LinkFaults",
    "LinkState",
    "HITCH",
    "HITCH_POSITION_STEPS",
    "MEASUREMENT",
    "LinkStatus",
    "MeasurementAssembler",
    "ReferenceRefused",
    "check_address",
    "check_period",
    "lift_counts_from_fraction",
]


class LinkError(HitchInputError):
    """Base of the link's errors; the message names the field, limit or fault.

    A :class:`ValueError` (through :class:`~planner.errors.HitchInputError`): a setting
    out of range, a refused reference and a command the link cannot take now are all
    the caller's request failing, and callers catch them as ``ValueError``.
    """


class ReferenceRefused(LinkError):
    """A reference that must not reach the bus (outside a limit, not a number, unreachable)."""


class LinkFaultError(LinkError):
    """A command refused because the link is not in a state to move the machine."""


def check_address(name: str, value: object, *, allow_none: bool = False) -> None:
    """Raise :class:`LinkError` unless ``value`` is a source address 0..253 (or None if allowed)."""
    if value is None and allow_none:
        return
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= 253:
        raise LinkError(f"{name} must be a source address in 0..253, got {value!r}")


#: Steps of the ISO 11783-7 hitch position field over the full travel (0.4 %/bit).
HITCH_POSITION_STEPS = 250


def lift_counts_from_fraction(
    fraction: float, counts_min: float, counts_max: float, *, on_count_grid: bool = True
) -> float:
    """Lift sensor reading [counts] from the rear hitch position [fraction of the calibrated travel].

    The sender maps the reading linearly, ``(counts − counts_min) / span``, onto the 0.4 %
    grid. While the span is at most 250 counts that grid is finer than one count, so the
    nearest count is the reading itself, exactly (the fraction alone is off by up to half a
    0.4 % step, 0.46 count for the thesis's 229-count lift). ``on_count_grid=False``, or a
    longer span, gives the linear value.
    """
    span = counts_max - counts_min
    counts = counts_min + fraction * span
    if on_count_grid and span <= HITCH_POSITION_STEPS:
        return float(math.floor(counts + 0.5))
    return float(counts)


def check_period(name: str, value: object, low: float, high: float) -> None:
    """Raise :class:`LinkError` unless ``value`` is a number of seconds in [low, high]."""
    if (
        isinstance(value, bool)
        or not isinstance(value, (int, float))
        or not math.isfinite(value)
        or not low <= value <= high
    ):
        raise LinkError(f"{name} must be a number of seconds in [{low:g}, {high:g}], got {value!r}")


def frame_stamp(frame: can.Message) -> float | None:
    """A received frame's bus timestamp [s], or None when the bus gave none (0, negative, not finite)."""
    ts = frame.timestamp
    return float(ts) if isinstance(ts, (int, float)) and math.isfinite(ts) and ts > 0.0 else None


#: the two sources of a :class:`LinkState`: the cylinder ECU's 0xFF22 and the rear hitch status (the lift)
#: (:meth:`MeasurementAssembler.reject`, :meth:`~MeasurementAssembler.why_stale`)
MEASUREMENT, HITCH = "measurement", "hitch"
#: the raw values of a 10-bit 0xFF22 reading that are no reading (J1939: error indicator, not available)
_READING_ERROR_COUNTS, _READING_NOT_AVAILABLE_COUNTS = 1022, 1023
#: the 0xFF22 readings in frame order: name, DBC signal
_READING_SIGNALS = (
    ("tilt", "TiltMeasurement"),
    ("top", "TopMeasurement"),
    ("right", "RightMeasurement"),
    ("left", "LeftMeasurement"),
)

#: the ECU's full valve command: a cylinder's fastest motion is its valve gain × this [counts/s] (thesis tables
#: 3-3, 3-4: kv in counts/s per command unit, commands in −254…254)
VALVE_FULL_COMMAND = 254
#: implausible readings that keep to a new level among themselves this long are taken [s] (longer than the
#: stale limit: motion has stopped by then)
REANCHOR_S = 0.3
#: readings that jump by more than twice the allowance this many times within CONFLICT_WINDOW_S, while others
#: are plausible, come from two senders: none is taken until no such jump came for CONFLICT_WINDOW_S [s]
CONFLICT_COUNT = 5
CONFLICT_WINDOW_S = 0.3


@dataclass(frozen=True)
class LinkConfig:
    """Settings of one :class:`~bridge.link.can_link.CanLink`.

    Attributes:
        source_address: our source address (thesis planner: 166).
        ecu_address: the cylinder ECU's source address (thesis: 169); 0xFF22
            measurements and heartbeats are taken from it only.
        hitch_status_address: sender of the ISO 11783-7 rear hitch status carrying the
            lift; ``None`` = the cylinder ECU (the simulated ECU sends it; on the thesis
            tractor it was the TECU, 240).
        control_rate_hz: reference stream rate, 1..200 Hz (profile default 50 Hz).
        stale_after_s: a measurement older than this stops motion (default 0.2 s).
        measurement_period_s: expected 0xFF22 period, s, for counting dropped frames.
        hitch_status_period_s: expected rear hitch status period, s, likewise.
        heartbeat_timeout_s: ECU heartbeat silence that stops motion (ISO 11783-7: 0.3 s).
        heartbeat_period_s: our own heartbeat period (ISO 11783-7: 0.1 s).
        reading_tolerance_counts: AD readings this far outside the calibrated span are
            still taken (AD noise at an end stop); farther out they are rejected.
        reading_rate_factor: a reading that moved since the last one taken by more than this many
            times what its cylinder can at full valve (``max(kv_pos, kv_neg) · 254`` counts/s, the
            profile's valve gains) over the time between them, plus ``reading_jump_counts``, is
            implausible and not taken (a glitch, a second node sending as the ECU); readings that keep
            to a new level among themselves for :data:`REANCHOR_S` are taken then (a sensor replaced
            mid-run; the stale fault has stopped motion meanwhile). 0 turns the check off.
        reading_jump_counts: how far a reading may always move from one taken to the next, whatever the
            time between (AD noise: the twin's ``--noise-counts 2`` moves a reading by up to about 8
            counts between two frames, 2.9 σ of their difference), counts in [0, 100].
        max_consecutive_tx_errors: failed sends in a row that raise the bus fault.
        lift_on_count_grid: the hitch position (0.4 %/bit of the calibrated travel) comes
            from an integer-count lift sensor (thesis table 3-2: 26..255) mapped as
            (counts − counts_min)/span and rounded: take the nearest count, which recovers
            the reading exactly while the travel spans at most 250 counts. False: use the
            fraction as it is. None (default): True when the cylinder ECU sends the hitch
            status (``hitch_status_address`` None or its address: its mapping is ours), False when another
            node (the tractor ECU) does, whose sensor and rounding we do not know.
        name: our ISO 11783-5 NAME (claimed at start, 250 ms contention window).
        claim_wait_s: contention window, s.
        ecu_watchdog_timeout_s: the ECU's reference watchdog, s, in [0.01, 2.5] (thesis ECU: 0.1 s; the
            link sets it in the ECU with 0xFF23 after its claim and whenever the ECU starts or restarts,
            10 ms resolution). While references stream, a 0xFF22 whose system state says "watchdog expired" proves
            that they do not arrive (fault ``references_lost``).
        address_recheck_s: after losing our address to a lower NAME, ask every this many seconds
            whether its holder is still there and claim it back when it is silent (0: never, the
            link stays "cannot claim" until restarted), s.
        ecu_rearm_s: after its watchdog expired, how long the ECU's references must arrive
            without a break before it drives again, s (the simulated ECU: 0.05 s,
            :mod:`bridge.sim.watchdog`; references queued up during a link stall then never move
            a cylinder). A new stream after a stop or a fault shows "watchdog expired" that much
            longer (:attr:`references_lost_after_s`).
        link_latency_s: transport allowance per direction on top of the watchdog, s.
            A measurement is believed about the stream only once the stream has run for
            :attr:`references_lost_after_s`.
        bus_timestamps: the bus stamps each received frame on a real clock (python-can's
            ``timestamp``: socketcan's kernel receive time, the virtual bus's and the loopback
            hub's send time). The ECU's heartbeat gap is then judged by the frames' own spacing
            as well as by read times (the smaller counts,
            :meth:`~bridge.isobus.heartbeat.HeartbeatMonitor.handle_sequence`): a stall of this
            process alone is not an ECU heartbeat fault, and dropped periodic frames are counted
            from the stamps' spacing (frames read together, as a loop that reads the bus only at
            its deadlines does, are not taken for gaps). False (default) for a
            link driven on a simulated clock, whose frames carry wall-clock stamps.
        check_period_s: while no reference streams, how often a real-time loop must
            :meth:`~bridge.link.can_link.CanLink.poll` the link (its fault checks and its
            heartbeat, sent on the first poll at or after its due time), s, in [0.001, 0.05]:
            a fault at rest is raised at most this late, our heartbeat is at most this late.
            Default 0.01; the service uses its control period within [0.01, 0.02] s (a loop
            that reads the link's state once a period gains nothing from checking it more often).
    """

    source_address: int = PLANNER_ADDRESS
    ecu_address: int = CYLINDER_ECU_ADDRESS
    hitch_status_address: int | None = None
    control_rate_hz: float = 50.0
    stale_after_s: float = 0.2
    measurement_period_s: float = 0.01
    hitch_status_period_s: float = 0.01
    heartbeat_timeout_s: float = HEARTBEAT_TIMEOUT_S
    heartbeat_period_s: float = HEARTBEAT_PERIOD_S
    reading_tolerance_counts: float = 2.0
    reading_rate_factor: float = 3.0
    reading_jump_counts: float = 8.0
    max_consecutive_tx_errors: int = 3
    lift_on_count_grid: bool | None = None
    name: Name = field(default_factory=planner_name)
    claim_wait_s: float = CLAIM_WAIT_S
    ecu_watchdog_timeout_s: float = 0.1
    link_latency_s: float = 0.02
    bus_timestamps: bool = False
    check_period_s: float = 0.01
    ecu_rearm_s: float = 0.05
    address_recheck_s: float = 1.0

    def __post_init__(self) -> None:
        check_address("source_address", self.source_address)
        check_address("ecu_address", self.ecu_address)
        check_address("hitch_status_address", self.hitch_status_address, allow_none=True)
        if self.source_address == self.ecu_address:
            raise LinkError(f"source_address and ecu_address must differ, both {self.source_address}")
        rate = self.control_rate_hz
        if (
            isinstance(rate, bool)
            or not isinstance(rate, (int, float))
            or not math.isfinite(rate)
            or not 1.0 <= rate <= 200.0
        ):
            raise LinkError(f"control_rate_hz must be a number in [1, 200] Hz, got {rate!r}")
        check_period("stale_after_s", self.stale_after_s, 0.005, 10.0)
        check_period("measurement_period_s", self.measurement_period_s, 0.001, 1.0)
        check_period("hitch_status_period_s", self.hitch_status_period_s, 0.001, 1.0)
        check_period("heartbeat_timeout_s", self.heartbeat_timeout_s, 0.01, 10.0)
        check_period("heartbeat_period_s", self.heartbeat_period_s, 0.01, 10.0)
        check_period("claim_wait_s", self.claim_wait_s, 0.001, 10.0)
        # the range 0xFF23 sets it in (the link sends it to the ECU: CanLink._send_ecu_parameters)
        check_period("ecu_watchdog_timeout_s", self.ecu_watchdog_timeout_s, 0.01, 2.5)
        check_period("link_latency_s", self.link_latency_s, 0.0, 1.0)
        check_period("ecu_rearm_s", self.ecu_rearm_s, 0.0, 1.0)
        check_period("address_recheck_s", self.address_recheck_s, 0.0, 3600.0)
        check_period("check_period_s", self.check_period_s, 0.001, 0.05)
        tol = self.reading_tolerance_counts
        if isinstance(tol, bool) or not isinstance(tol, (int, float)) or not 0.0 <= tol <= 50.0:
            raise LinkError(f"reading_tolerance_counts must be a number in [0, 50] counts, got {tol!r}")
        jump = self.reading_jump_counts
        if isinstance(jump, bool) or not isinstance(jump, (int, float)) or not 0.0 <= jump <= 100.0:
            raise LinkError(f"reading_jump_counts must be a number in [0, 100] counts, got {jump!r}")
        k = self.reading_rate_factor
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (k == 0.0 or 1.0 <= k <= 100.0):
            raise LinkError(f"reading_rate_factor must be 0 (off) or a number in [1, 100], got {k!r}")
        n = self.max_consecutive_tx_errors
        if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 1000:
            raise LinkError(f"max_consecutive_tx_errors must be an integer in 1..1000, got {n!r}")
        if self.lift_on_count_grid is not None and not isinstance(self.lift_on_count_grid, bool):
            raise LinkError(f"lift_on_count_grid must be true, false or None, got {self.lift_on_count_grid!r}")
        if not isinstance(self.bus_timestamps, bool):
            raise LinkError(f"bus_timestamps must be true or false, got {self.bus_timestamps!r}")
        if not isinstance(self.name, Name):
            raise LinkError(f"name must be a bridge.isobus.address_claim.Name, got {type(self.name).__name__}")

    @property
    def references_lost_after_s(self) -> float:
        """How long a stream runs before a "watchdog expired" measurement means its references
        are lost, s: the ECU's watchdog, its re-arm window (a stream starting after a trip drives
        only once it has been continuous that long), the transport allowance and one measurement
        period (0.1 + 0.05 + 0.02 + 0.01 = 0.18 s by default). Measurements older than that cannot
        describe the stream yet."""
        return self.ecu_watchdog_timeout_s + self.ecu_rearm_s + self.link_latency_s + self.measurement_period_s

    @property
    def control_period_s(self) -> float:
        """Reference stream period, s."""
        return 1.0 / self.control_rate_hz

    @property
    def lift_count_grid(self) -> bool:
        """Whether the lift is taken on its sensor's count grid (see ``lift_on_count_grid``)."""
        # the cylinder ECU's own hitch status (its mapping is ours), also when its address is set explicitly (an
        # explicit 169 fell back to the fraction as it is: a documentation review)
        return self.hitch_source == self.ecu_address if self.lift_on_count_grid is None else self.lift_on_count_grid

    @property
    def hitch_source(self) -> int:
        """Source address the lift (rear hitch status) is taken from."""
        return self.ecu_address if self.hitch_status_address is None else self.hitch_status_address


@dataclass(frozen=True)
class LinkState:
    """The machine as measured over the bus, through forward kinematics.

    Attributes:
        t_s: link time of the newest frame that went into this state, s.
        measurement_t_s: arrival of the 0xFF22 frame used, s.
        lift_t_s: arrival of the rear hitch status used, s.
        counts: the five readings in actuator order; the lift as its sensor count
            recovered from the hitch status (:func:`lift_counts_from_fraction`).
        lift_fraction: rear hitch position, fraction of the calibrated travel.
        actuators: actuators in SI (lift rad, others m) through the AD calibration.
        pose: forward kinematics of ``actuators``.
        system: the ECU's system-state byte, decoded.
        points: the named points of that forward kinematics [m] (read-only arrays;
            :attr:`planner.model.kinematics.HitchState.points`), for the stability at the
            measured pose without solving the kinematics again; None when not kept.
    """

    t_s: float
    measurement_t_s: float
    lift_t_s: float
    counts: tuple[float, float, float, float, float]
    lift_fraction: float
    actuators: Actuators
    pose: Pose
    system: SystemStatus
    points: Mapping[str, np.ndarray] | None = field(default=None, repr=False, compare=False)

    def age_s(self, now_s: float) -> float:
        """Age of the older of the two measurement sources at ``now_s``, s."""
        return now_s - min(self.measurement_t_s, self.lift_t_s)


@dataclass(frozen=True)
class LinkFaults:
    """Latched link faults; any of them stops the reference stream at once (the ECU's
    watchdog then zeroes its valves within its 100 ms timeout, and the machine holds).

    Every fault **latches in the link**: the stream stays stopped, and the old reference is
    never resumed, until a fresh :meth:`~bridge.link.can_link.CanLink.send_reference` is
    accepted; that command clears all latched faults, and is refused while a fault's cause
    is still present. :meth:`~bridge.link.can_link.CanLink.fault_causes` tells which causes
    are present now; :meth:`~bridge.link.can_link.CanLink.clear_faults` clears the latched
    faults whose causes are gone without moving (an acknowledge). Two kinds:

    * **Condition faults** have a cause that can be re-checked — they may clear themselves
      when data is fresh again (the cause disappears from ``fault_causes``):
      ``stale_measurement``, ``ecu_heartbeat``, ``address_lost``, ``address_conflict``, ``bus_error``.
    * **Event faults** record something that happened and has no present cause to re-check —
      they stay latched until a fresh command or an acknowledge: ``ecu_restart``,
      ``references_lost``.

    Attributes:
        stale_measurement: no valid 0xFF22 (ECU → planner) or no lift (rear hitch status)
            for longer than ``stale_after_s`` (200 ms); raised at the first poll after
            that (within 1 ms in simulated time; in real time within one
            ``check_period_s`` while the link is at rest, and as the frames arrive while it
            streams; at rest a frame is read up to one check period after its arrival, so up to
            two check periods after ``stale_after_s``). Covers ECU → planner loss. Its reason names
            the sender's address and why the frames that arrived were not taken (the last rejection and
            how many, frames from another address), or that none arrived. Condition: gone when both are fresh.
        ecu_heartbeat: ECU heartbeat silent for more than ``heartbeat_timeout_s``
            (ISO 11783-7: 300 ms), or it says error (254) / shut down (255); raised at the
            next poll. Condition: gone with the next valid heartbeat.
        ecu_restart: the ECU restarted (heartbeat 251 again, a change of the restart
            counter, or the no-reference bit of the system state reappearing); raised on
            the frame that shows it. Event.
        references_lost: while the link streams references, a 0xFF22 arrived whose
            system state says the ECU's watchdog expired (bit 1): the ECU has had no
            reference for its watchdog timeout, so planner → ECU frames are lost (or the
            stream stalled). Believed only once the stream has run for
            ``references_lost_after_s`` (180 ms); raised on that frame, i.e. at most
            watchdog (100 ms) + one reference period (20 ms) + one measurement period
            (10 ms) + transport after the first lost reference (about 130 ms; a stream that
            starts into a cut link: after 180 ms). Event.
        address_lost: our address claim was lost (cannot claim); raised at the next poll.
            Condition: present while another NAME holds our address
            (:attr:`~bridge.link.can_link.CanLink.address_problem` names it; the link asks every
            ``address_recheck_s`` and claims the address back once the holder is silent).
        address_conflict: a frame with our source address that this link did not send (not our
            echo: :data:`~bridge.link.can_link.ECHO_WINDOW_S`) — another node uses our address
            (J1939-81), e.g. spoofed references; raised on that frame. Condition: present until
            none has arrived for :data:`~bridge.link.can_link.CONFLICT_HOLD_S` (1 s).
        bus_error: ``max_consecutive_tx_errors`` (3) sends failed in a row; raised at the
            failing send. Condition: gone with the next successful send.
        reasons: one line per fault raised since the last re-arm, oldest first: the latest occurrence's (a
            cause that came back while its fault was latched, or changed its kind, replaces the older line).
        reason_names: the fault each of ``reasons`` is about (same order; :meth:`reason_of`).

    The field names are stable: the service reports them as fault names.
    """

    stale_measurement: bool = False
    ecu_heartbeat: bool = False
    ecu_restart: bool = False
    address_lost: bool = False
    bus_error: bool = False
    references_lost: bool = False
    address_conflict: bool = False
    reasons: tuple[str, ...] = ()
    reason_names: tuple[str, ...] = ()

    def reason_of(self, name: str) -> str | None:
        """The latest reason given for fault ``name`` (None: none recorded)."""
        for n, r in zip(reversed(self.reason_names), reversed(self.reasons), strict=False):
            if n == name:
                return r
        return None

    @property
    def any(self) -> bool:
        """True if any fault is latched."""
        return any(getattr(self, name) for name in _FAULT_NAMES)

    @staticmethod
    def names() -> tuple[str, ...]:
        """Every fault's name (the boolean fields; not the reasons)."""
        return _FAULT_NAMES

    def active(self) -> tuple[str, ...]:
        """Names of the latched faults."""
        return tuple(name for name in _FAULT_NAMES if getattr(self, name))


#: the fault fields of :class:`LinkFaults` (every field but the reasons), looked up once (checked every poll)
_FAULT_NAMES = tuple(f.name for f in fields(LinkFaults) if f.name not in ("reasons", "reason_names"))


@dataclass(frozen=True)
class LinkCounters:
    """Frame counters of a link since it was built (monotonic).

    ``unknown_pgn`` counts valid frames of PGNs the DBC does not describe (other ISOBUS
    traffic: counted, never a fault); ``foreign`` frames of known PGNs from sources we
    do not listen to (and frames with our own source address while the address is not ours);
    ``own_echo`` our own frames received back; ``address_conflicts`` frames with our source
    address that we did not send; ``malformed`` frames rejected by the codec; ``dropped_*``
    periodic frames inferred lost from arrival gaps; ``bus_errors`` error frames
    received; ``tx_errors`` failed sends; ``parameters_tx`` 0xFF23 frames the link sent of itself
    (controllers on and the watchdog it assumes: after its claim, when the ECU starts or restarts);
    ``poses_tx`` 0xFF25 measured poses sent (every 100 ms while the measurements are fresh).
    """

    frames_rx: int = 0
    frames_tx: int = 0
    references_tx: int = 0
    references_refused: int = 0
    measurements_rx: int = 0
    hitch_status_rx: int = 0
    heartbeats_rx: int = 0
    malformed: int = 0
    unknown_pgn: int = 0
    foreign: int = 0
    own_echo: int = 0
    unavailable_readings: int = 0
    rejected_readings: int = 0
    kinematics_failures: int = 0
    dropped_measurements: int = 0
    dropped_hitch_status: int = 0
    bus_errors: int = 0
    tx_errors: int = 0
    faults_raised: int = 0
    address_conflicts: int = 0
    parameters_tx: int = 0
    poses_tx: int = 0

    def as_dict(self) -> dict[str, int]:
        """The counters by name."""
        return {f.name: getattr(self, f.name) for f in fields(self)}


@dataclass(frozen=True)
class LinkStatus:
    """Everything a supervisor needs at one instant.

    Attributes:
        now_s: when the snapshot was taken (link time), s.
        claimed: our address claim succeeded.
        streaming: references are being sent.
        reference_counts: the reference being streamed (actuator order), or None.
        state: latest measured state, or None before the first complete measurement.
        faults: latched faults.
        heartbeat: the ECU heartbeat monitor's conclusion.
        counters: frame counters.
        last_malformed: the codec's reason for the last rejected frame, or "".
        last_reading_problem: why the last reading was not used (unavailable, outside the
            calibrated span, mechanism cannot close), or "".
        address_problem: why our address is not ours while another NAME holds it (e.g. "address 166
            lost, not claimed: NAME 0x… holds it …"), "" while it is claimed or being claimed: a supervisor
            keeps ``address_lost`` held (refuses to acknowledge it) while this is non-empty.
        fault_causes: names of the faults whose causes are present at ``now_s``
            (:meth:`~bridge.link.can_link.CanLink.fault_causes`): an acknowledge of one of them
            cannot hold (e.g. ``address_lost`` while another NAME holds our address,
            ``address_conflict`` while frames with our address keep arriving).
    """

    now_s: float
    claimed: bool
    streaming: bool
    reference_counts: tuple[int, ...] | None
    state: LinkState | None
    faults: LinkFaults
    heartbeat: HeartbeatStatus
    counters: LinkCounters
    last_malformed: str = ""
    last_reading_problem: str = ""
    address_problem: str = ""
    fault_causes: tuple[str, ...] = ()


class MeasurementAssembler:
    """Builds :class:`LinkState` from the ECU's 0xFF22 and rear hitch status payloads.

    Readings that are unavailable (J1939 "not available"/"error") or outside the
    calibrated span by more than ``reading_tolerance_counts`` are rejected and counted;
    the state keeps the arrival times of the two sources it was built from, so a
    stream of rejected frames ages it (and the link's staleness check stops motion).
    Why the frames of each source were not taken since the last one that was (the link adds
    the codec's refusals and frames from another address) is :meth:`why_stale`, which the
    stale fault's reason says.

    Args:
        model: kinematic model (forward kinematics).
        scaling: AD calibration of the same profile.
        config: periods (for counting dropped frames) and the reading tolerance.
        bump: ``bump(counter=delta, …)`` adds to the owner's :class:`LinkCounters`.
    """

    def __init__(
        self, model: HitchModel, scaling: SensorScaling, config: LinkConfig, bump: Callable[..., None]
    ) -> None:
        self._model = model
        self._scaling = scaling
        self._cfg = config
        self._bump = bump
        self._meas: tuple[float, tuple[int, int, int, int]] | None = None  # tilt, top, left, right
        self._hitch: tuple[float, float] | None = None  # (t, fraction)
        self._system: SystemStatus | None = None
        # per source: (bus-stamped?, time of the last frame (stamp or read time), its read time)
        self._rx_t: dict[str, tuple[bool, float, float]] = {}
        self._restart_bits: int | None = None
        self._ecu_had_reference = False
        self._solved: tuple[tuple[float, ...], Actuators, Pose, Mapping[str, np.ndarray]] | None = None
        self.state: LinkState | None = None
        """The newest complete state, or None."""
        self.last_problem = ""
        """Why the last reading was rejected ("" if none)."""
        # per source (MEASUREMENT, HITCH), while frames of it are not taken: (why the last was rejected, how many
        # since one was taken, when [s]); (the other address the last came from, how many, when [s])
        self._rejected: dict[str, tuple[str, int, float]] = {}
        self._elsewhere: dict[str, tuple[int, int, float]] = {}
        # the plausibility of each reading's motion: per actuator the fastest a cylinder can move at full valve
        # [counts/s]; per source the last reading taken (read time, bus stamp or None, counts in actuator order
        # with NaN where the source has none) and the readings of an implausible jump kept to since (when it
        # began, the last of them)
        prof = model.profile
        self._full_speed_counts_s = np.array(
            [max(prof.actuator(n).kv_pos, prof.actuator(n).kv_neg) * VALVE_FULL_COMMAND for n in ACTUATOR_NAMES]
        )
        self._last_taken: dict[str, tuple[float, float | None, np.ndarray]] = {}
        self._jump: dict[str, tuple[float, tuple[float, float | None, np.ndarray]]] = {}
        # per source: the times of the last far jumps, when a reading was last plausible, a conflict's end and
        # its step (name, counts moved, s, allowed), the last implausible step
        self._far: dict[str, deque[float]] = {}
        self._plausible_at: dict[str, float] = {}
        self._conflict: dict[str, tuple[float, tuple[str, float, float, float]]] = {}
        self._conflict_steps: dict[str, tuple[str, float, float, float]] = {}
        # per source: the check of the rate its frames arrive at (bridge.link.arrival_rate)
        self._rates: dict[str, ArrivalRate] = {}

    def reject(self, source: str, reason: str, now_s: float) -> None:
        """A frame of ``source`` (:data:`MEASUREMENT`: 0xFF22, :data:`HITCH`: the rear hitch status) from its
        sender was not taken at ``now_s`` [s] for ``reason`` (e.g. the codec refused it): counted for
        :meth:`why_stale` until one is taken."""
        self.last_problem = reason
        prev = self._rejected.get(source)
        self._rejected[source] = (reason, 1 if prev is None else prev[1] + 1, now_s)

    def from_elsewhere(self, source: str, address: int, now_s: float) -> None:
        """A frame of ``source`` arrived at ``now_s`` [s] from ``address``, not the sender it is taken from."""
        prev = self._elsewhere.get(source)
        self._elsewhere[source] = (address, 1 if prev is None else prev[1] + 1, now_s)

    def why_stale(self, source: str, since_s: float, sender: int) -> str:
        """Why no frame of ``source`` has been taken since ``since_s`` [s] although some arrived, "" when none
        did: the last rejection and how many were rejected, and frames from another address than ``sender``
        (the address it is taken from), e.g. "last 0xFF22 rejected: tilt reading 1022 = error indicator (12
        rejected); frames from address 170 ignored: the ECU is 169"."""
        out = []
        rejected = self._rejected.get(source)
        if rejected is not None and rejected[2] >= since_s:
            what = "0xFF22" if source == MEASUREMENT else "rear hitch status"
            out.append(f"last {what} rejected: {rejected[0]} ({rejected[1]} rejected)")
        other = self._elsewhere.get(source)
        if other is not None and other[2] >= since_s:
            if source == MEASUREMENT:
                out.append(f"frames from address {other[0]} ignored ({other[1]}): the ECU is {sender}")
            else:
                out.append(
                    f"rear hitch status arrives from {other[0]}, the service takes it from {sender}: "
                    "set [can] hitch_status_address"
                )
        return "; ".join(out)

    def _taken(self, source: str) -> None:
        """A frame of ``source`` went into the state: its rejections are over."""
        if self._rejected:
            self._rejected.pop(source, None)
        if self._elsewhere:
            self._elsewhere.pop(source, None)

    def forget_reference(self) -> None:
        """The ECU restarted: its reference is gone until the link sends one again."""
        self._ecu_had_reference = False

    def on_measurement(
        self, m: PositionMeasurement, now_s: float, stamp_s: float | None = None, errors: tuple[str, ...] = ()
    ) -> str | None:
        """Take a 0xFF22 payload read at ``now_s``, stamped ``stamp_s`` by the bus (None: unstamped);
        ``errors``: the DBC signals that carried the error indicator (the other missing readings were "not
        available"). Returns a restart reason if the system state shows one."""
        self._bump(measurements_rx=1)
        self._count_gap("measurement", now_s, stamp_s, self._cfg.measurement_period_s, "dropped_measurements")
        if crowded := self._too_many(MEASUREMENT, now_s, stamp_s, self._cfg.measurement_period_s):
            self.reject(MEASUREMENT, crowded, now_s)  # its system state is not read either: whose would it be?
            return None
        system = decode_system_state(m.system_state)
        bits, restart = system.restart_count_mod16, None
        if self._restart_bits is not None and bits != self._restart_bits:
            restart = f"ECU restart counter {self._restart_bits} -> {bits}"
        elif system.no_reference_since_restart and self._ecu_had_reference:
            restart = "ECU lost its reference (no-reference bit set again)"
        self._restart_bits = bits
        self._ecu_had_reference = (self._ecu_had_reference and restart is None) or not system.no_reference_since_restart
        self._system = system
        tilt, top, left, right = m.tilt_counts, m.top_counts, m.left_counts, m.right_counts
        if tilt is None or top is None or left is None or right is None:
            self.reject(MEASUREMENT, self._missing_reading(m, errors), now_s)
            self._bump(unavailable_readings=1)
        elif problem := self._out_of_span((tilt, top, left, right)):
            self.reject(MEASUREMENT, problem, now_s)
        elif problem := self._implausible(
            MEASUREMENT, np.array([np.nan, tilt, top, left, right], dtype=float), now_s, stamp_s
        ):
            self.reject(MEASUREMENT, problem, now_s)
        else:
            self._meas = (now_s, (tilt, top, left, right))
            if self._update(now_s):
                self._taken(MEASUREMENT)
        return restart

    @staticmethod
    def _missing_reading(m: PositionMeasurement, errors: tuple[str, ...]) -> str:
        """Which reading of ``m`` is missing and why, e.g. "tilt reading 1022 = error indicator"."""
        for name, signal in _READING_SIGNALS:
            if getattr(m, f"{name}_counts") is None:
                if signal in errors:
                    return f"{name} reading {_READING_ERROR_COUNTS} = error indicator"
                return f"{name} reading {_READING_NOT_AVAILABLE_COUNTS} = not available"
        return "0xFF22 reading not available or in error"

    def on_hitch_status(
        self, h: RearHitchStatus, now_s: float, stamp_s: float | None = None, errors: tuple[str, ...] = ()
    ) -> None:
        """Take a rear hitch status payload (the lift, fraction of travel) read at ``now_s``, stamped
        ``stamp_s`` by the bus (None: unstamped); ``errors``: the DBC signals that carried the error indicator."""
        self._bump(hitch_status_rx=1)
        self._count_gap("hitch", now_s, stamp_s, self._cfg.hitch_status_period_s, "dropped_hitch_status")
        if crowded := self._too_many(HITCH, now_s, stamp_s, self._cfg.hitch_status_period_s):
            self.reject(HITCH, crowded, now_s)
            return
        if h.position is None:
            said = "254 = error indicator" if "RearHitchPosition" in errors else "255 = not available"
            self.reject(HITCH, f"rear hitch position {said}", now_s)
            self._bump(unavailable_readings=1)
            return
        sc = self._scaling
        lift = lift_counts_from_fraction(
            float(h.position), sc.counts_min[0], sc.counts_max[0], on_count_grid=self._cfg.lift_count_grid
        )
        if problem := self._implausible(HITCH, np.array([lift, *[np.nan] * 4], dtype=float), now_s, stamp_s):
            self.reject(HITCH, problem, now_s)
            return
        self._hitch = (now_s, float(h.position))
        if self._update(now_s):
            self._taken(HITCH)

    def _implausible(self, source: str, counts: np.ndarray, now_s: float, stamp_s: float | None) -> str:
        """Why the readings ``counts`` [AD counts, actuator order, NaN: not in this source] read at ``now_s``
        (bus stamp ``stamp_s``) are not taken, "" when they are (they then count as the last taken): they moved
        faster than their cylinders can since the last ones taken, or the source's readings alternate between
        two levels (:data:`CONFLICT_COUNT` jumps of more than twice the allowance within
        :data:`CONFLICT_WINDOW_S` while others are taken: two nodes sending as one) — then none is taken until
        no such jump came for :data:`CONFLICT_WINDOW_S`, whichever level came first (the stale fault stops
        motion and says why). A level kept among itself for the re-anchor time is taken then."""
        k = self._cfg.reading_rate_factor
        stamp = stamp_s if self._cfg.bus_timestamps else None
        here = (now_s, stamp, counts)
        prev = self._last_taken.get(source)
        if k == 0.0 or prev is None:
            self._last_taken[source] = here
            return ""
        step = self._too_fast(prev, here, k)
        far = self._far.setdefault(source, deque(maxlen=CONFLICT_COUNT))
        if step is None:
            self._plausible_at[source] = now_s
        elif abs(step[1]) > 2.0 * step[3]:
            far.append(now_s)
        if (
            len(far) == CONFLICT_COUNT
            and now_s - far[0] <= CONFLICT_WINDOW_S
            and self._plausible_at.get(source, -math.inf) > far[0]  # the other level came between: interleaved
        ):
            self._conflict[source] = (
                now_s + CONFLICT_WINDOW_S,
                step if step is not None else self._conflict_step(source),
            )
        conflict = self._conflict.get(source)
        if conflict is not None and now_s < conflict[0]:
            if step is None:
                self._last_taken[source] = here  # follow the level held; taken again once the conflict ends
            self._bump(rejected_readings=1)
            name, moved, _, _ = conflict[1]
            sender = self._cfg.ecu_address if source == MEASUREMENT else self._cfg.hitch_source
            what = "0xFF22" if source == MEASUREMENT else "rear hitch status"
            return (
                f"{what} readings alternate between two levels ({name} {moved:+.0f} counts apart, {CONFLICT_COUNT} "
                f"times within {CONFLICT_WINDOW_S:g} s): two nodes sending as address {sender}? none taken until "
                f"one level holds for {CONFLICT_WINDOW_S:g} s"
            )
        self._conflict.pop(source, None)
        if step is None:
            self._last_taken[source] = here
            self._jump.pop(source, None)
            return ""
        self._conflict_steps[source] = step
        jump = self._jump.get(source)
        reanchor_s = max(REANCHOR_S, self._cfg.stale_after_s + 0.1)  # after the stale fault, whatever its limit
        if jump is not None and self._too_fast(jump[1], here, k) is None:  # keeps to the new level
            if now_s - jump[0] >= reanchor_s - 1e-9:
                self._last_taken[source] = here
                self._jump.pop(source, None)
                return ""
            self._jump[source] = (jump[0], here)
        else:
            self._jump[source] = (now_s, here)
        self._bump(rejected_readings=1)
        name, moved, dt_s, allowed = step
        sender = self._cfg.ecu_address if source == MEASUREMENT else self._cfg.hitch_source
        return (
            f"{name} reading jumped {moved:+.0f} counts in {dt_s * 1000:.0f} ms since the last one taken: faster "
            f"than the cylinder can move (at most {allowed:.1f} counts; a glitch, or a second node sending as "
            f"address {sender})"
        )

    def _too_many(self, source: str, now_s: float, stamp_s: float | None, period_s: float) -> str:
        """Why frames of ``source`` are not taken because they arrive faster than their sender sends them, ""
        if they do not (:class:`~bridge.link.arrival_rate.ArrivalRate`: more than :data:`RATE_FACTOR` × the rate
        ``1/period_s`` beyond a burst's allowance, on bus stamps when trusted, else on read times, a gap's backlog
        credited): a second node sends as the same address — the readings of both may lie within the jump
        allowance of each other (a recheck: a spoof 8 counts off alternated with the ECU's frames and was taken
        as the pose). None is taken until the rate is normal again."""
        stamped = self._cfg.bus_timestamps and stamp_s is not None
        rate = self._rates.get(source)
        if rate is None:
            rate = self._rates[source] = ArrivalRate(period_s)
        if not rate.arrive(now_s, stamp_s if stamped else None):
            return ""
        self._bump(rejected_readings=1)
        sender = self._cfg.ecu_address if source == MEASUREMENT else self._cfg.hitch_source
        if source == MEASUREMENT:
            what, setting = "0xFF22", "measurement_period_s"
        else:
            what, setting = "rear hitch status", "hitch_status_period_s"
        return (
            f"{what} arrives {rate.arrival_words()} from address {sender}, more than {RATE_FACTOR:g} × "
            f"the {1.0 / period_s:.0f} a second its sender sends ({setting}): two nodes sending as "
            f"address {sender}? none taken until the rate is normal again"
        )

    def _conflict_step(self, source: str) -> tuple[str, float, float, float]:
        return self._conflict_steps.get(source, ("reading", 0.0, 0.0, 0.0))

    def _too_fast(
        self, prev: tuple[float, float | None, np.ndarray], here: tuple[float, float | None, np.ndarray], k: float
    ) -> tuple[str, float, float, float] | None:
        """The first actuator whose reading moved from ``prev`` to ``here`` faster than ``k`` times its full-valve
        speed (plus ``reading_jump_counts``): (name, counts moved, time between [s], counts allowed); None if none."""
        dt = now_dt = max(here[0] - prev[0], 0.0)
        if here[1] is not None and prev[1] is not None:
            stamp_dt = here[1] - prev[1]
            if 0.0 <= stamp_dt <= now_dt + STAMP_SLACK_S:  # else the bus's clock stepped: the read times
                dt = max(now_dt, stamp_dt)
        moved = here[2] - prev[2]
        allowed = k * self._full_speed_counts_s * dt + self._cfg.reading_jump_counts
        for i, name in enumerate(ACTUATOR_NAMES):
            if math.isfinite(moved[i]) and abs(moved[i]) > allowed[i]:
                return name, float(moved[i]), dt, float(allowed[i])
        return None

    def _out_of_span(self, readings: tuple[int, int, int, int]) -> str:
        """Which reading (tilt, top, left, right) lies outside its calibrated span ± tolerance, "" if none."""
        s, tol = self._scaling, self._cfg.reading_tolerance_counts
        for i, r in enumerate(readings, start=1):
            if not s.counts_min[i] - tol <= r <= s.counts_max[i] + tol:
                self._bump(rejected_readings=1)
                return (
                    f"{ACTUATOR_NAMES[i]} reading {r} counts outside the calibrated "
                    f"span [{s.counts_min[i]:.0f}, {s.counts_max[i]:.0f}] ± {tol:g}"
                )
        return ""

    def _update(self, now_s: float) -> bool:
        """Build the state from the newest readings; False if they do not close the mechanism (a rejected
        0xFF22: :meth:`reject`), True otherwise (also while a source is still missing)."""
        if self._meas is None or self._hitch is None or self._system is None:
            return True
        (t_m, (tilt, top, left, right)), (t_h, frac) = self._meas, self._hitch
        s = self._scaling
        lift_counts = lift_counts_from_fraction(
            frac, s.counts_min[0], s.counts_max[0], on_count_grid=self._cfg.lift_count_grid
        )
        counts = (lift_counts, float(tilt), float(top), float(left), float(right))
        solved = self._solved
        if solved is not None and solved[0] == counts:
            # Same readings as the last solved ones (the hitch at rest: 110 readings/s of the same
            # counts): the calibration and the kinematics are pure functions of the counts, so their
            # last (immutable) result is the answer.
            actuators, pose, points = solved[1], solved[2], solved[3]
        else:
            q = s.to_si(counts, tolerance_counts=self._cfg.reading_tolerance_counts)
            try:
                hs = self._model.forward(q)
            except KinematicsError as exc:
                self.reject(MEASUREMENT, f"measured actuators do not close the mechanism: {exc}", now_s)
                self._bump(kinematics_failures=1)
                return False
            actuators, pose, points = hs.actuators, hs.pose, hs.points
            for a in points.values():
                a.setflags(write=False)
            self._solved = (counts, actuators, pose, points)
        self.state = LinkState(now_s, t_m, t_h, counts, frac, actuators, pose, self._system, points)
        return True

    def _count_gap(self, key: str, now_s: float, stamp_s: float | None, period_s: float, counter: str) -> None:
        """Count the frames missing before this one from the spacing of the bus stamps when the link
        trusts them (``bus_timestamps``), else of the read times. Frames read together (a backlog, or a
        loop that reads the bus only at its deadlines) share one read time: their stamps tell the gaps."""
        stamped = self._cfg.bus_timestamps and stamp_s is not None
        t = stamp_s if stamped and stamp_s is not None else now_s
        prev = self._rx_t.get(key)
        self._rx_t[key] = (stamped, t, now_s)
        if prev is not None and prev[0] == stamped:  # never a read time against a stamp
            gap = t - prev[1]
            if stamped and not 0.0 <= gap <= now_s - prev[2] + STAMP_SLACK_S:
                gap = now_s - prev[2]  # the bus's wall clock stepped (NTP, a GNSS time fix): read times
            missed = int(math.floor(gap / period_s + 0.5)) - 1
            if missed > 0:
                self._bump(**{counter: missed})
