"""The simulated rig: the cylinder ECU and the planner link together over CAN.

The nodes (:class:`~bridge.link.can_link.CanLink`, :class:`~bridge.sim.can_node.EcuCanNode`)
own no clock. Here they run in **simulated time**: :class:`SimRig` puts both on a private
python-can ``virtual`` channel and advances an integer tick counter (``now = k · tick_s``,
1 ms by default: no float drift). Each tick runs ``link.poll(t)``, ``node.poll(t)``,
``link.poll(t)``, so a reference sent at ``t`` reaches the ECU at ``t`` (which first steps
its model to ``t``) and a measurement sent at ``t`` reaches the link at ``t``; the bus adds
no latency (a frame takes 0.5 ms at 250 kbit/s). Nothing reads the wall clock: runs are
deterministic and much faster than real time, through the real codec, identifiers and
python-can queues. (Real time: :class:`bridge.link.realtime.RealtimeRunner`.)

The experiments that drive the rig live in :mod:`bridge.sim.move`.
"""

from __future__ import annotations

import math
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field

import can
import numpy as np
from numpy.typing import ArrayLike

from bridge.isobus.j1939 import bus_load
from bridge.link.can_link import CanLink
from bridge.link.state import LinkConfig
from bridge.link.virtual import InProcessBus
from bridge.sim.can_node import EcuCanNode, EcuNodeConfig
from bridge.sim.cylinder import GAIN_ERROR_RANGE, NOISE_COUNTS_RANGE
from bridge.sim.ecu import CylinderECU
from bridge.sim.truth import MachineTruth, TrueMachine
from planner.errors import HitchInputError
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import Pose

__all__ = ["LossyBus", "SimError", "SimRig", "SimSettings"]


class SimError(HitchInputError):
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

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
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
        if (
            isinstance(self.frame_loss, bool)
            or not isinstance(self.frame_loss, (int, float))
            or not 0.0 <= self.frame_loss < 1.0
        ):
            raise SimError(f"frame_loss must be a fraction in [0, 1), got {self.frame_loss!r}")
        # checked here, naming the setting (a negative noise was taken and failed only when a rig was built)
        for name, (lo, hi), unit in (
            ("noise_counts", NOISE_COUNTS_RANGE, " counts"),
            ("gain_error", GAIN_ERROR_RANGE, " (relative)"),
            ("watchdog_timeout_s", (0.001, 10.0), " s"),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
                raise SimError(f"{name} must be a number in [{lo:g}, {hi:g}]{unit}, got {v!r}")


class SimRig:
    """An ECU node and a link on a private ``virtual`` channel, advanced in simulated time.

    A third "tap" bus on the channel counts every frame for the bus-load figure.
    Use as a context manager (or call :meth:`close`) so every bus is shut down.

    Args:
        model: kinematic model of the machine (its profile configures the ECU).
        settings: the simulated machine and bus.
        initial_actuators: start position of the pistons, SI (default: the profile's neutral).
        truth: the twin's true machine (:mod:`bridge.sim.truth`): its AD map configures the ECU, its
            geometry and play give :meth:`true_pose`; default the planner's profile exactly. The link
            stays on ``model`` (the nominal profile).
    """

    def __init__(
        self,
        model: HitchModel,
        settings: SimSettings | None = None,
        *,
        initial_actuators: ArrayLike | None = None,
        truth: MachineTruth | None = None,
    ) -> None:
        self.settings = s = settings if settings is not None else SimSettings()
        if truth is not None and not isinstance(truth, MachineTruth):
            raise SimError(f"truth must be a MachineTruth or None, got {type(truth).__name__}")
        self.truth = truth if truth is not None else MachineTruth.nominal(model.profile)
        """The twin's true machine (default: exactly the planner's profile, no play)."""
        self._model = model
        self._true_machine: TrueMachine | None = None
        rng = np.random.default_rng(s.seed)
        noise_rng, loss_rng = rng.spawn(2)
        initial = None
        if initial_actuators is not None:  # unrounded counts: the pistons sit between AD steps
            sc = SensorScaling(self.truth.profile)  # the pistons' true positions through the true AD map
            initial = (
                sc.counts_min + (np.asarray(initial_actuators, dtype=float).reshape(5) - sc.si_min) / sc.resolution
            )
        ecu = CylinderECU(
            self.truth.profile,
            rng=noise_rng,
            noise_counts=s.noise_counts,
            gain_error=s.gain_error,
            watchdog_timeout_s=s.watchdog_timeout_s,
            initial_counts=initial,
            calibration=model.profile,  # the ECU is configured with the planner's (nominal) calibration
        )
        self.channel = channel = f"hitch-sim-{uuid.uuid4().hex}"
        """The private virtual channel (other buses may join it, e.g. in tests)."""
        buses: list[can.BusABC] = [InProcessBus(channel=channel) for _ in range(3)]
        if s.frame_loss > 0.0:
            buses[:2] = [LossyBus(b, s.frame_loss, loss_rng) for b in buses[:2]]
        self._buses = buses
        self.node = EcuCanNode(ecu, buses[0], s.node, fault_clock=lambda: self.now_s, fault_seed=s.seed)
        """The ECU node; its :meth:`~bridge.sim.can_node.EcuCanNode.apply_fault` injects faults on
        simulated time."""
        self.link = CanLink(model, buses[1], s.link)
        self._tap = buses[2]
        self._k = 0
        self._tick_ms = int(round(s.tick_s * 1e3))
        self.ecu_paused = False
        """A stalled ECU: while True the ECU node is not polled (a stalled ECU or a cut
        cable): it neither sends nor reads; its frames wait in its queue."""
        self.frames_by_dlc: dict[int, int] = {}
        """Frames seen on the bus since the last :meth:`reset_traffic`, by DLC."""
        self._traffic_since_s = 0.0
        if self.truth.play.any:  # the play hysteresis needs the pistons' history
            self._observe_truth()

    @property
    def true_machine(self) -> TrueMachine:
        """The true machine of the twin (truth geometry + play), built on first use."""
        if self._true_machine is None:
            same = self.truth.profile == self._model.profile
            self._true_machine = TrueMachine(self.truth, self._model.category, model=self._model if same else None)
        return self._true_machine

    def true_pose(self) -> Pose:
        """The implement's true pose now: the ECU's true pistons through the truth geometry and play."""
        return self.true_machine.observe(self.ecu.piston_counts())

    def _observe_truth(self) -> None:
        try:
            self.true_pose()
        except HitchInputError:  # pistons the truth geometry cannot close: the play state waits
            pass

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
        if self._true_machine is not None and self.truth.play.any:
            self._observe_truth()
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

    def __exit__(self, *exc: object) -> None:
        self.close()
