"""Closed-loop continuous control in simulated time: a scenario's job run by the motion controller.

:func:`run_track_loop` runs one job of a terrain-twin scenario (:mod:`bridge.sim.scenario`) through
the real :class:`~bridge.service.motion.controller.MotionController` on the simulated rig
(:class:`bridge.sim.move.SimRig`: identified hydraulics, 10-bit sensors, the real codec and CAN path),
with control cycles every ``1 / rate`` (20 ms) of simulated time, and returns the time series and
figures (:class:`TrackLoopResult`). Nothing reads the wall clock; runs are deterministic.

The tractor's sensors travel the bus as on the machine: the twin's tractor node
(:class:`bridge.sim.tractor_node.TractorTwinNode`: slope sensor 10 ms, ground distance 20 ms, row
camera 10 Hz, wheel speed 100 ms) sends on the rig's channel, the planner-side decoder
(:class:`bridge.link.tractor_sensors.TractorSensors`) reads them, and
:class:`~bridge.service.machine.ReadingsAsTrackSensors` (positions only) gives the controller
its :class:`~bridge.service.motion.controller.TrackSensors` (fresh readings only). The ground
sensor's height comes from the simulated ECU's true pistons (at the tool point T).

Jobs (frame and DOF of the track session, setpoint, the error in the job's own terms; truth values
from the twin and the forward kinematics of the simulated pistons, never the measurement):

============  ======  ====  ==============================  =================================================
job           frame   DOF   setpoint                        error
============  ======  ====  ==============================  =================================================
levelling     level   roll  0 (implement level)             implement roll relative to gravity, roll_T − φ
guidance      tractor x     the camera's row offset         lateral error against the true row, x_T − row
terrain       ground  z     the working height above ground height above ground − working height
============  ======  ====  ==============================  =================================================

(φ: the tractor's true roll, SAE J670, + right side down; the hitch's roll + raises the right
side, so a level implement has roll_T = φ. The row offset is the row's lateral position in the
tractor frame, + left: the twin's camera sees the row relative to the tractor's centreline.)

Strategies:

* ``track`` — one track session (``track_start`` / ``track_setpoint`` every cycle) in the job's frame;
* ``goto_stream`` — the same setpoints converted to the tractor frame by the client (as the
  controller's frames do: roll + φ read; z_m + (setpoint − d read)), clipped to the workspace and sent
  as a ``goto`` every cycle, each replacing the last (today's API);
* ``hold`` — no correction: the start pose is held.

Setpoint velocity (``track`` only): the controller hands a setpoint's velocity to the follower as it
is (it does not transform it between frames), so the runner sends the *tractor-frame* rate of the
setpoint, estimated by the client from its readings (a least-squares slope over
``LoopSettings.rate_window_s``; for the row camera an α-β filter on the 10 Hz samples, whose
estimate is the setpoint of both streaming strategies).

Row estimator (guidance, ``LoopSettings.row_estimator``): ``alpha_beta`` (above) or ``kalman``
(:class:`RowKalman`): a Kalman filter in *distance* along the travel with a second-order
Gauss–Markov row model (:class:`RowModel`, tuned from the row's stated RMS and wavelength band and
the camera's stated noise, :meth:`RowModel.from_row`), with a Rauch–Tung–Striebel smoother over
the samples already seen; its slope times the ground speed is the setpoint's velocity. The client
keys every camera sample by the distance the camera saw it at (the wheel odometer's distance plus
the camera's look-ahead :attr:`bridge.sim.terrain.RowSignal.camera_ahead_m`, a documented sensor
geometry). ``LoopSettings.row_setpoint``: ``now`` sends the row under the implement now; ``lead``
the row at the implement's position ``lead_s`` ahead (distance + speed × lead): with a camera ahead
of the implement (preview) that point was already seen and is smoothed, with the camera under the
implement it is the model's prediction. The lead (:func:`follower_lead_s`) comes from the
follower's limits: two control cycles (the setpoint is taken at the next cycle, its reference
reaches the ECU one cycle later) plus the follower's rise time to full speed, v/a + a/j. ``plan``
(with a preview): with every camera sample a :class:`PreviewPlanner` path over the preview window
(the smoothed row, within :attr:`PreviewPlanner.MARGIN` of the follower's limits), sent one cycle
ahead (the next cycle's reference reaches the pistons a cycle later) as the B-spline state of the
path (:func:`path_state`: position, velocity, acceleration and jerk, consistent from sample to
sample): a setpoint stream within the limits, which the follower meets exactly (its rendezvous,
:mod:`planner.trajectory.track`).

Counts (:attr:`TrackLoopResult.counts`): streamed references outside the actuator strokes (the link
refuses them: must be 0), refused references (``limit_reached`` events with a message), limit events
of the follower (workspace faces named), rejected setpoints, gotos refused, faults, and measured
samples outside the workspace by more than the sensor quantisation (one count on every sensor,
mapped to the pose at the start: must be 0).
"""

from __future__ import annotations

import bisect
import math
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.linalg import expm

from bridge.link.tractor_sensors import TractorSensors, TractorSensorsConfig
from bridge.link.virtual import InProcessBus
from bridge.service.ground_preview import GroundPreviewGeometry, GroundProfileEstimator
from bridge.service.machine import ReadingsAsTrackSensors
from bridge.service.motion.controller import MotionController
from bridge.service.motion.types import MotionError
from bridge.service.work import WindowSlope
from bridge.sim.cylinder import build_cylinder_params
from bridge.sim.ecu import ACTUATOR_ORDER
from bridge.sim.move import SimRig, SimSettings
from bridge.sim.scenario import Scenario, load_scenario
from bridge.sim.sensors import TwinSensors
from bridge.sim.terrain import RowSignal
from bridge.sim.tractor_node import TractorTwinNode, hitch_height_from_ecu
from bridge.sim.truth import MachineTruth
from planner.errors import HitchError, HitchInputError
from planner.limits.guard import Guard
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import CONTROLLED_POSE_NAMES
from planner.trajectory import MotionState, TrajectoryPlanner
from planner.trajectory.track import PLAUSIBLE_VELOCITY, TrackFollower

__all__ = [
    "JOBS",
    "GROUND_SETPOINTS",
    "ROW_ESTIMATORS",
    "ROW_SETPOINTS",
    "STRATEGIES",
    "ErrorFigures",
    "LoopSettings",
    "PreviewPlanner",
    "RowKalman",
    "RowModel",
    "SimLoop",
    "TrackLoopError",
    "TrackLoopResult",
    "follower_lead_s",
    "path_state",
    "job_of",
    "run_track_loop",
]

STRATEGIES = ("track", "goto_stream", "hold")
ROW_ESTIMATORS = ("alpha_beta", "kalman")
ROW_SETPOINTS = ("now", "lead", "plan")
GROUND_SETPOINTS = ("now", "plan")
JOBS = ("levelling", "guidance", "terrain")
#: frame and DOF of each job's track session
JOB_FRAME = {"levelling": ("level", "roll"), "guidance": ("tractor", "x"), "terrain": ("ground", "z")}
_POSE = CONTROLLED_POSE_NAMES


class TrackLoopError(HitchInputError):
    """A closed loop that cannot run as asked; the message names the field and the allowed range."""


def _seconds(name: str, v: object, lo: float, hi: float, *, optional: bool = False) -> None:
    if optional and v is None:
        return
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise TrackLoopError(f"{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")


@dataclass(frozen=True)
class LoopSettings:
    """One closed-loop run.

    Attributes:
        strategy: one of :data:`STRATEGIES`.
        job: one of :data:`JOBS`; None: from the scenario (:func:`job_of`).
        duration_s: scenario time to run [s] (None: the scenario's ``duration_s``), [1, 3600].
        warmup_s: rig time before the loop starts (address claims, first measurements) [s].
        settle_s: the figures leave out the first ``settle_s`` after the loop started [s].
        ttl_s: the track session's time-to-live [s], [0.05, 1].
        start: start pose (any of x, z, roll, pitch; default the neutral pose).
        working_height_m: terrain: the setpoint, height of T above the ground [m]; None: the
            ground-distance reading when the loop starts.
        send_velocity: track: send the estimated tractor-frame rate with each setpoint.
        rate_window_s: the least-squares window of that rate estimate [s].
        row_filter: guidance: the α-β filter's (α, β) on the camera samples; None: raw samples.
        row_estimator: guidance: ``alpha_beta`` (``row_filter``) or ``kalman`` (:class:`RowKalman`).
        row_setpoint: guidance, ``kalman`` (:data:`ROW_SETPOINTS`): ``now`` the row under the
            implement now; ``lead`` the row at the implement's position ``lead_s`` ahead; ``plan`` a
            preview plan (:class:`PreviewPlanner`) over what the camera saw ahead, sent ``dt`` ahead
            (the reference's way to the pistons) with its acceleration and jerk; without a preview
            of at least 8 cycles ``plan`` acts as ``lead``.
        lead_s: the lead of ``lead`` [s], [0, 5]; None: :func:`follower_lead_s` from the follower's limits.
        ground_setpoint: terrain (:data:`GROUND_SETPOINTS`): ``now`` the working height in frame
            ``ground`` (the service converts it with the implement's ground sensor, as before); ``plan``
            with the twin's look-ahead ground sensor (scenario ``ground_sensor_ahead_m`` > 0): the
            client rebuilds the ground profile in distance (:class:`GroundProfileEstimator`:
            look-ahead sensor, implement sensor, slope sensor's pitch, odometer), predicts the tool
            point's tractor-frame height that keeps the working height over the preview, and streams a
            :class:`PreviewPlanner` path of it in frame ``tractor``, re-planned every ``plan_every``
            cycles, sent ``2·dt`` ahead with its velocity.
        plan_every: re-plan period of ``ground_setpoint="plan"`` in control cycles, [1, 50].
        inside_window_s: a sample counts as "inside" when over the last this-many seconds the demand
            stayed inside the workspace and within the follower's pose velocity and acceleration limits.
        sim: the simulated machine and bus.
        truth: the twin's own true machine (:mod:`bridge.sim.truth`, ``hitch sim perturb``); None: exactly
            the planner's profile. The planner, the link and the figures' demand stay on the model.
    """

    strategy: str = "track"
    job: str | None = None
    duration_s: float | None = None
    warmup_s: float = 0.5
    settle_s: float = 5.0
    ttl_s: float = 0.3
    start: Mapping[str, float] | None = None
    working_height_m: float | None = None
    send_velocity: bool = True
    rate_window_s: float = 0.1
    row_filter: tuple[float, float] | None = (0.35, 0.06)
    row_estimator: str = "alpha_beta"
    row_setpoint: str = "now"
    lead_s: float | None = None
    ground_setpoint: str = "now"
    plan_every: int = 5
    inside_window_s: float = 1.0
    sim: SimSettings = field(default_factory=SimSettings)
    truth: MachineTruth | None = None

    def __post_init__(self) -> None:
        if self.truth is not None and not isinstance(self.truth, MachineTruth):
            raise TrackLoopError(f"truth must be a MachineTruth or None, got {type(self.truth).__name__}")
        if self.strategy not in STRATEGIES:
            raise TrackLoopError(f"strategy must be one of {', '.join(STRATEGIES)}, got {self.strategy!r}")
        if self.job is not None and self.job not in JOBS:
            raise TrackLoopError(f"job must be one of {', '.join(JOBS)} (or None: from the scenario), got {self.job!r}")
        _seconds("warmup_s", self.warmup_s, 0.3, 10.0)
        _seconds("settle_s", self.settle_s, 0.0, 600.0)
        _seconds("duration_s", self.duration_s, 0.0, 3600.0, optional=True)
        least = self.warmup_s + self.settle_s  # the one range a duration has (not [1, 3600] and then this)
        if self.duration_s is not None and self.duration_s <= least:
            raise TrackLoopError(
                f"duration_s = {self.duration_s:g} s must exceed warmup_s + settle_s = {least:g} s "
                f"(allowed: ({least:g}, 3600] s)"
            )
        _seconds("ttl_s", self.ttl_s, 0.05, 1.0)
        _seconds("working_height_m", self.working_height_m, 0.0, 3.0, optional=True)
        _seconds("rate_window_s", self.rate_window_s, 0.02, 2.0)
        _seconds("inside_window_s", self.inside_window_s, 0.0, 10.0)
        _seconds("lead_s", self.lead_s, 0.0, 5.0, optional=True)
        if self.row_estimator not in ROW_ESTIMATORS:
            raise TrackLoopError(
                f"row_estimator must be one of {', '.join(ROW_ESTIMATORS)}, got {self.row_estimator!r}"
            )
        if self.ground_setpoint not in GROUND_SETPOINTS:
            raise TrackLoopError(
                f"ground_setpoint must be one of {', '.join(GROUND_SETPOINTS)}, got {self.ground_setpoint!r}"
            )
        pe = self.plan_every
        if isinstance(pe, bool) or not isinstance(pe, int) or not 1 <= pe <= 50:
            raise TrackLoopError(f"plan_every must be an integer in [1, 50] cycles, got {pe!r}")
        if self.row_setpoint not in ROW_SETPOINTS:
            raise TrackLoopError(f"row_setpoint must be one of {', '.join(ROW_SETPOINTS)}, got {self.row_setpoint!r}")
        if self.row_setpoint != "now" and self.row_estimator != "kalman":
            raise TrackLoopError(
                f"row_setpoint = {self.row_setpoint!r} needs row_estimator = 'kalman' (the row model's)"
            )
        if self.row_filter is not None:
            a, b = self.row_filter
            _seconds("row_filter alpha", a, 1e-3, 1.0)
            _seconds("row_filter beta", b, 0.0, 2.0)
        if self.start is not None:
            for k, v in self.start.items():
                if k not in _POSE:
                    raise TrackLoopError(f"start: unknown DOF {k!r}, allowed {', '.join(_POSE)}")
                _seconds(f"start.{k}", v, -1.0, 1.0)


def job_of(scenario: Scenario) -> str:
    """The job a scenario is made for: guidance when it has a row signal, else levelling when the
    tractor rolls, else terrain when the ground under the implement moves; levelling for flat ground."""
    twin = scenario.twin
    if twin.row.rms_m > 0.0 or twin.row.noise_rms_m > 0.0:
        return "guidance"
    ts = np.linspace(0.0, scenario.duration_s, 401)
    if max(abs(twin.attitude(float(t)).roll_rad) for t in ts) > 1e-6:
        return "levelling"
    if max(abs(twin.implement_ground_z(float(t))) for t in ts) > 1e-6:
        return "terrain"
    return "levelling"


class SimLoop:
    """The rig, the motion controller on it and the tractor twin on its bus (module docstring).

    ``cycle()`` advances one control period and runs one controller cycle; the latest state
    message is :attr:`state`. Use as a context manager (or :meth:`close`).
    """

    def __init__(
        self,
        model: HitchModel,
        scenario: Scenario | str,
        *,
        sim: SimSettings | None = None,
        start: Mapping[str, float] | None = None,
        warmup_s: float = 0.5,
        sensors_config: TractorSensorsConfig | None = None,
        truth: MachineTruth | None = None,
    ) -> None:
        self.model = model
        self.scenario = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
        self.twin = self.scenario.twin
        tp = TrajectoryPlanner(model)
        p0 = tp.goal_vector(model.neutral_pose.controlled(), start or {})
        tp.check_in_workspace(p0, "start")
        self.rig = SimRig(model, sim, initial_actuators=tp.inverse.solve(p0)[0], truth=truth)
        self._buses = [InProcessBus(channel=self.rig.channel) for _ in range(2)]
        # the ground sensor sees the true machine's height (as the service's twin: bridge.service.machine)
        same = self.rig.truth.profile == model.profile
        true_model = model if same else HitchModel(self.rig.truth.profile, model.category)
        self._nominal_params = tuple(build_cylinder_params(n, model.profile.actuator(n)) for n in ACTUATOR_ORDER)
        self.tractor = TractorTwinNode(
            self._buses[0], TwinSensors(self.twin), hitch_height_m=hitch_height_from_ecu(self.rig.ecu, true_model)
        )
        self.decoder = TractorSensors(self._buses[1], sensors_config)
        self.sensors = ReadingsAsTrackSensors(self.decoder, rates=False)  # positions only, as measured
        self.events: list[dict[str, Any]] = []
        self.state: dict[str, Any] | None = None
        self.mc = MotionController(
            Guard(tp),
            Guard(TrajectoryPlanner(model)),
            self.rig.link,
            lambda: self.rig.now_s,
            on_event=self.events.append,
            on_state=self._on_state,
            spawn=lambda fn: fn(),
            sensors=self.sensors,
        )
        self.planner = self.mc.planner
        self.dt = self.mc.dt
        self.cycle_times: list[tuple[float, float]] | None = None
        """Set to a list to record (wall [s], process CPU [s]) of every controller cycle."""
        self.rig.start()
        self.tractor.start(self.rig.now_s)  # the twin's t = 0 is the rig's
        self.decoder.start(self.rig.now_s)
        self._run(warmup_s)
        if self.rig.link.latest_state() is None:
            self.close()
            raise TrackLoopError(f"no measurement from the ECU after warmup_s = {warmup_s} s")

    def _on_state(self, s: dict[str, Any]) -> None:
        self.state = s

    def _every_tick(self, t: float) -> None:
        self.tractor.poll(t)
        self.decoder.poll(t)

    def _run(self, seconds: float) -> None:
        self.rig.run_until(self.rig.now_s + seconds, self._every_tick)

    @property
    def now_s(self) -> float:
        """Rig time = the twin's time [s]."""
        return self.rig.now_s

    def cycle(self) -> None:
        """One control period of simulated time, then one controller cycle."""
        self._run(self.dt)
        if self.cycle_times is None:
            self.mc.cycle()
            return
        w0, c0 = time.perf_counter(), time.process_time()
        self.mc.cycle()
        self.cycle_times.append((time.perf_counter() - w0, time.process_time() - c0))

    def truth_pose(self) -> np.ndarray:
        """The simulated pistons through the twin's true machine (not measured), x, z, roll, pitch."""
        return np.asarray(self.rig.true_pose().controlled(), float)

    def measured_pose(self) -> np.ndarray:
        ls = self.rig.link.latest_state()
        return np.full(4, np.nan) if ls is None else np.asarray(ls.pose.controlled(), float)

    def streamed_actuators(self) -> np.ndarray | None:
        """The reference the link streams now (SI, from its counts through the planner's calibration), None
        when none."""
        counts = self.rig.link.status(self.rig.now_s).reference_counts
        if counts is None:
            return None
        return np.array([p.counts_to_si(c) for p, c in zip(self._nominal_params, counts, strict=True)])

    def close(self) -> None:
        for b in self._buses:
            b.shutdown()
        self.rig.close()

    def __enter__(self) -> SimLoop:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class ErrorFigures:
    """RMS, 95th percentile of |e|, max |e| and the mean of an error over ``n`` samples (SI)."""

    rms: float
    p95: float
    max: float
    mean: float
    n: int

    @classmethod
    def of(cls, e: np.ndarray) -> ErrorFigures:
        e = np.asarray(e, float)
        e = e[np.isfinite(e)]
        if e.size == 0:
            return cls(math.nan, math.nan, math.nan, math.nan, 0)
        a = np.abs(e)
        return cls(
            float(np.sqrt(np.mean(e**2))), float(np.percentile(a, 95)), float(a.max()), float(e.mean()), int(e.size)
        )

    def as_dict(self) -> dict[str, float | int]:
        return {"rms": self.rms, "p95": self.p95, "max": self.max, "mean": self.mean, "n": self.n}


@dataclass(frozen=True)
class TrackLoopResult:
    """One closed-loop run, sampled every control cycle (t = scenario time [s], SI throughout).

    Arrays (N,): ``t``; ``setpoint`` (in the job's frame; NaN when none was sent); ``demand`` (the
    tractor-frame value of the DOF that makes the error zero: φ, the true row, or the z giving the
    working height); ``tractor_roll``, ``tractor_pitch`` (the twin's true attitude); ``ground_height``
    (ground under the implement above the tractor's contact plane); ``row`` (true row offset);
    ``error`` (the job's error, from the true pose); ``evaluated`` (after ``settle_s``); ``inside``
    (evaluated, and the demand inside the workspace and the follower's limits, see
    :class:`LoopSettings`). (N, 4) x, z, roll, pitch: ``reference`` (the controller's tractor-frame
    reference pose; NaN when none), ``measured`` (over CAN), ``truth`` (simulated pistons).
    ``figures``: over ``evaluated``; ``figures_inside``: over ``inside``. ``counts``: see the module
    docstring.
    """

    scenario: str
    job: str
    strategy: str
    frame: str
    dof: str
    working_height_m: float | None
    t: np.ndarray
    setpoint: np.ndarray
    demand: np.ndarray
    reference: np.ndarray
    measured: np.ndarray
    truth: np.ndarray
    tractor_roll: np.ndarray
    tractor_pitch: np.ndarray
    ground_height: np.ndarray
    row: np.ndarray
    error: np.ndarray
    evaluated: np.ndarray
    inside: np.ndarray
    figures: ErrorFigures
    figures_inside: ErrorFigures
    counts: dict[str, int]
    faults: tuple[str, ...]
    workspace_excess: float = 0.0
    """Largest distance of a measured sample beyond a workspace face, beyond the tolerance (m or rad)."""
    notes: tuple[str, ...] = ()
    """The first distinct messages of refused gotos, rejected setpoints and refused references."""

    @property
    def dof_index(self) -> int:
        return _POSE.index(self.dof)

    @property
    def inside_fraction(self) -> float:
        n = int(self.evaluated.sum())
        return float(self.inside.sum() / n) if n else 0.0

    def summary(self) -> dict[str, Any]:
        """JSON-ready figures and counts."""
        return {
            "scenario": self.scenario,
            "job": self.job,
            "strategy": self.strategy,
            "frame": self.frame,
            "dof": self.dof,
            "working_height_m": self.working_height_m,
            "duration_s": float(self.t[-1] - self.t[0]) if len(self.t) else 0.0,
            "error": self.figures.as_dict(),
            "error_inside": self.figures_inside.as_dict(),
            "inside_fraction": self.inside_fraction,
            "counts": dict(self.counts),
            "workspace_excess": self.workspace_excess,
            "faults": list(self.faults),
            "notes": list(self.notes),
        }


class _AlphaBeta:
    """α-β filter of sampled-and-held camera readings: position and rate, extrapolated in between."""

    def __init__(self, alpha: float, beta: float) -> None:
        self.alpha, self.beta = alpha, beta
        self.x: float | None = None
        self.v = 0.0
        self.t = 0.0

    def update(self, z: float, t: float) -> None:
        if self.x is None:
            self.x, self.t = z, t
            return
        dt = t - self.t
        if dt <= 0:
            return
        x = self.x + self.v * dt
        r = z - x
        self.x = x + self.alpha * r
        self.v += self.beta * r / dt
        self.t = t

    def at(self, t: float) -> tuple[float, float]:
        assert self.x is not None
        return self.x + self.v * (t - self.t), self.v


@dataclass(frozen=True)
class RowModel:
    """A crop row's lateral offset as a second-order Gauss–Markov process in the travel distance s:
    ``y'' = −ω²·y − 2ζω·y' + w`` (primes: d/ds), w white with intensity ``q = 4ζω³·rms²`` so that
    the stationary RMS of y is ``rms_m``; the camera measures y with white noise ``noise_rms_m``.

    Attributes:
        rms_m: the row's RMS offset [m] (> 0).
        omega_rad_m: the natural spatial frequency ω [rad/m] (> 0).
        noise_rms_m: the camera's noise per sample [m] (> 0: a floor of 0.1 mm).
        zeta: the damping ratio (default 1/√2, maximally flat).
    """

    rms_m: float
    omega_rad_m: float
    noise_rms_m: float
    zeta: float = 1.0 / math.sqrt(2.0)

    def __post_init__(self) -> None:
        _seconds("rms_m", self.rms_m, 1e-6, 1.0)
        _seconds("omega_rad_m", self.omega_rad_m, 1e-4, 100.0)
        _seconds("noise_rms_m", self.noise_rms_m, 1e-4, 0.5)
        _seconds("zeta", self.zeta, 0.1, 2.0)

    @classmethod
    def from_row(cls, row: RowSignal) -> RowModel:
        """From the row's stated spectrum and the camera's stated noise: ω matches the row's RMS slope
        to its RMS offset (the model's ``rms(y') = ω·rms(y)`` at ζ = 1/√2; the row's band of equal
        sines at log-spaced wavenumbers k_i has ``rms(y')² = rms(y)²·mean(k_i²)``)."""
        k = 2.0 * math.pi / np.geomspace(row.wavelength_max_m, row.wavelength_min_m, row.components)
        return cls(max(row.rms_m, 1e-6), float(np.sqrt(np.mean(k**2))), max(row.noise_rms_m, 1e-4))

    def transition(self, ds: float) -> tuple[np.ndarray, np.ndarray]:
        """The state transition F and process noise Q over a distance ``ds`` ≥ 0 (Van Loan)."""
        w, z = self.omega_rad_m, self.zeta
        a = np.array([[0.0, 1.0], [-w * w, -2.0 * z * w]])
        q = 4.0 * z * w**3 * self.rms_m**2
        m = np.zeros((4, 4))
        m[:2, :2], m[:2, 2:], m[2:, 2:] = -a, np.array([[0.0, 0.0], [0.0, q]]), a.T
        e = expm(m * max(ds, 0.0))
        f = e[2:, 2:].T
        return f, f @ e[:2, 2:]


class RowKalman:
    """Kalman filter of the camera's row samples in the travel distance (:class:`RowModel`), with a
    Rauch–Tung–Striebel smoother over the samples kept (the last ``keep_m`` of distance).

    :meth:`add` takes a sample (the row's offset y [m] seen at distance σ [m]); :meth:`at` gives
    (y, dy/ds) at any distance: smoothed and interpolated (cubic Hermite) between samples already
    seen, the model's prediction beyond the newest."""

    def __init__(self, model: RowModel, *, keep_m: float = 12.0) -> None:
        self.model = model
        self.keep_m = keep_m
        r = model.rms_m
        self._p0 = np.diag([r * r, (model.omega_rad_m * r) ** 2])  # the stationary covariance
        self._r = model.noise_rms_m**2
        self._s: deque[float] = deque()
        self._xf: deque[np.ndarray] = deque()  # filtered
        self._pf: deque[np.ndarray] = deque()
        self._xp: deque[np.ndarray] = deque()  # predicted (before the sample)
        self._pp: deque[np.ndarray] = deque()
        self._f: deque[np.ndarray] = deque()  # transition from the previous sample
        self._smooth: list[np.ndarray] | None = None

    def __len__(self) -> int:
        return len(self._s)

    def add(self, y: float, sigma: float) -> None:
        """One camera sample ``y`` [m] of the row at distance ``sigma`` [m] (not decreasing; a sample
        at a smaller distance than the newest is ignored)."""
        if self._s and sigma < self._s[-1] - 1e-9:
            return
        if not self._s:
            f, xp, pp = np.eye(2), np.zeros(2), self._p0.copy()
        else:
            f, q = self.model.transition(sigma - self._s[-1])
            xp, pp = f @ self._xf[-1], f @ self._pf[-1] @ f.T + q
        k = pp[:, 0] / (pp[0, 0] + self._r)
        xf = xp + k * (y - xp[0])
        pf = pp - np.outer(k, pp[0, :])
        self._s.append(float(sigma))
        for buf, v in ((self._xf, xf), (self._pf, pf), (self._xp, xp), (self._pp, pp), (self._f, f)):
            buf.append(v)
        while len(self._s) > 2 and self._s[1] < sigma - self.keep_m:
            self._s.popleft()
            for b in (self._xf, self._pf, self._xp, self._pp, self._f):
                b.popleft()
        self._smooth = None

    def _smoothed(self) -> list[np.ndarray]:
        if self._smooth is None:
            n = len(self._s)
            xs = [np.zeros(2)] * n
            xs[-1] = self._xf[-1]
            for i in range(n - 2, -1, -1):
                f = self._f[i + 1]
                c = self._pf[i] @ f.T @ np.linalg.inv(self._pp[i + 1])
                xs[i] = self._xf[i] + c @ (xs[i + 1] - self._xp[i + 1])
            self._smooth = xs
        return self._smooth

    def at(self, sigma: float) -> tuple[float, float] | None:
        """(y [m], dy/ds) at distance ``sigma``; None before the first sample."""
        if not self._s:
            return None
        s = self._s
        if sigma >= s[-1]:
            x = self.model.transition(sigma - s[-1])[0] @ self._xf[-1]
            return float(x[0]), float(x[1])
        xs = self._smoothed()
        if sigma <= s[0]:
            return float(xs[0][0]), float(xs[0][1])
        i = bisect.bisect_right(s, sigma) - 1  # s[i] <= sigma < s[i + 1]
        h = s[i + 1] - s[i]
        if h <= 1e-12:
            return float(xs[i][0]), float(xs[i][1])
        u = (sigma - s[i]) / h
        (y0, d0), (y1, d1) = xs[i], xs[i + 1]
        # cubic Hermite on [s_i, s_i+1] and its derivative
        h00, h10, h01, h11 = 2 * u**3 - 3 * u**2 + 1, u**3 - 2 * u**2 + u, -2 * u**3 + 3 * u**2, u**3 - u**2
        g00, g10, g01, g11 = 6 * u**2 - 6 * u, 3 * u**2 - 4 * u + 1, -6 * u**2 + 6 * u, 3 * u**2 - 2 * u
        y = h00 * y0 + h10 * h * d0 + h01 * y1 + h11 * h * d1
        dy = (g00 * y0 + g01 * y1) / h + g10 * d0 + g11 * d1
        return float(y), float(dy)


_PLAN_UNIT_M = 1e-3
"""The preview plan's unit [m] inside its QP (the QP in mm is well scaled for OSQP)."""


class PreviewPlanner:
    """A client-side preview plan: with the row known a horizon ahead (a camera ahead of the
    implement), the closest path to it within the DOF's velocity, acceleration and jerk bounds, as
    the ideal follower (:class:`planner.trajectory.ideal_follower.IdealFollower`) solves it, but over
    the preview window only, continuing the path already sent (its first three samples fixed to the
    previous plan's: position, velocity and acceleration stay continuous; should that QP not solve,
    the previous plan held: a fresh plan would jump). One OSQP instance per window length and number of
    fixed samples; :meth:`plan` returns the path's samples every ``dt`` from ``t0``.

    Args:
        v_max, a_max, j_max: the bounds [m/s, m/s², m/s³] (the follower's, so that it follows the path).
        dt: the sample step [s].
    """

    MARGIN = 0.99
    """The share of the follower's limits a plan uses (the rest lets the follower catch up with it)."""
    EPS = 1e-3

    def __init__(self, v_max: float, a_max: float, j_max: float, dt: float) -> None:
        for name, v in (("v_max", v_max), ("a_max", a_max), ("j_max", j_max), ("dt", dt)):
            _seconds(name, v, 1e-9, 1e9)
        self.bounds = (v_max, a_max, j_max)
        self.dt = dt
        self._solvers: dict[tuple[int, int], Any] = {}  # (samples, fixed): OSQP, fixed columns, their rows
        self._t0: float | None = None
        self._x: np.ndarray | None = None
        self.failures = 0  # plans OSQP did not solve (the previous plan kept instead)

    def plan(self, t0: float, reference: np.ndarray, start: float | None = None) -> np.ndarray:
        """The path from ``t0`` (samples every ``dt``) closest to ``reference`` (same length, ≥ 8),
        continuing the previous plan where it covers ``t0`` (its first three samples then fixed);
        without one, from rest at ``start`` [m] when given (the follower's position: the stream then
        starts where the hitch is)."""
        r = np.asarray(reference, float)
        n = int(r.size)
        if n < 8 or not np.all(np.isfinite(r)):
            raise TrackLoopError(f"preview plan: the reference needs >= 8 finite samples, got {n}")
        prev = self._previous(t0, n, extend=True)
        x = None
        if prev is not None:
            x = self._solve(r, prev, 3)
            if x is None:  # the path already sent, continued: the stream stays within the bounds
                self.failures += 1
                x = prev
        if x is None and prev is None and start is not None:
            x = self._solve(r, np.full(n, float(start)), 3)
        if x is None:
            x = self._solve(r, np.full(n, float(np.mean(r))), 0)
        if x is None:
            self.failures += 1
            x = r
        self._t0, self._x = t0, x
        return x

    def _solve(self, r: np.ndarray, base: np.ndarray, k: int) -> np.ndarray | None:
        """The QP in the deviation δ from ``base`` (the previous plan continued, or a constant), in
        :data:`_PLAN_UNIT_M`, the first ``k`` samples kept at ``base``: its bounds stay of order one
        (OSQP's tolerance is then relative to the bounds, not to the path's offset)."""
        import osqp  # only a previewing client pays its import
        import scipy.sparse as sp_

        n = int(r.size)
        key = (n, k)
        if key not in self._solvers:
            rows = []
            for order, bound in zip((1, 2, 3), self.bounds, strict=True):
                coef = np.array([math.comb(order, i) * (-1) ** (order - i) for i in range(order + 1)], float)
                m = n - order
                rows.append(
                    sp_.diags([np.full(m, c) for c in coef], list(range(order + 1)), shape=(m, n))
                    * (_PLAN_UNIT_M / (bound * self.dt**order))
                )
            a = sp_.vstack(rows, format="csc")
            a_free = a[:, k:].tocsc()
            free_rows = np.diff(a_free.tocsr().indptr) > 0  # rows of kept samples alone decide nothing
            one = np.ones(a.shape[0])
            solver = osqp.OSQP()
            solver.setup(
                sp_.identity(n - k, format="csc"), np.zeros(n - k), a_free, -one, one, eps_abs=self.EPS,
                eps_rel=self.EPS, polishing=False, max_iter=40000, verbose=False, warm_starting=True,
            )  # fmt: skip
            self._solvers[key] = (solver, a.tocsr(), free_rows)
        solver, a_full, free_rows = self._solvers[key]
        at_base = a_full @ (base / _PLAN_UNIT_M)
        lo = np.where(free_rows, -1.0 - at_base, -np.inf)
        hi = np.where(free_rows, 1.0 - at_base, np.inf)
        solver.update(q=(base[k:] - r[k:]) / _PLAN_UNIT_M, l=lo, u=hi)
        res = solver.solve(raise_error=False)
        if res.x is None or not str(res.info.status).startswith("solved"):  # "solved inaccurate" taken too
            return None
        x = base.copy()
        x[k:] += np.asarray(res.x, float) * _PLAN_UNIT_M
        return x

    def _previous(self, t0: float, n: int, *, extend: bool = False) -> np.ndarray | None:
        """The previous plan at the first three samples from ``t0`` (all ``n`` with ``extend``, continued
        with its last velocity beyond its end); None without one covering the first three."""
        if self._x is None or self._t0 is None:
            return None
        tp = self._t0 + self.dt * np.arange(self._x.size)
        ts = t0 + self.dt * np.arange(n if extend else 3)
        if ts[2] > tp[-1] + 1e-9:
            return None
        out = np.interp(ts, tp, self._x)
        if extend and self._x.size >= 2:  # beyond its end: on with its last velocity
            v = (self._x[-1] - self._x[-2]) / self.dt
            past = ts > tp[-1]
            out[past] = self._x[-1] + v * (ts[past] - tp[-1])
        return out


def path_state(path: np.ndarray, i: int, dt: float) -> tuple[float, float, float, float]:
    """The state (position [m], velocity [m/s], acceleration [m/s²], jerk [m/s³]) at sample ``i`` of a
    path sampled every ``dt``, read as the uniform cubic B-spline on its samples: the C²
    piecewise-cubic whose velocity, acceleration and jerk are the path's first, second and third
    differences (at ``i``: central, central, and the jerk of the segment from ``i`` to ``i + 1``). By the
    B-spline's convex hull its |v|, |a|, |j| stay within the largest differences, so a path whose
    differences are within bounds (:class:`PreviewPlanner`) is a stream within them, and its states
    are consistent: the follower meets one from the previous exactly in one cycle. ``i`` is clamped to
    [1, len − 3] (at least four samples)."""
    x = np.asarray(path, float)
    if x.size < 4:
        raise TrackLoopError(f"path_state: the path needs >= 4 samples, got {x.size}")
    i = min(max(int(i), 1), x.size - 3)
    xm, x0, x1, x2 = (float(v) for v in x[i - 1 : i + 3])
    return (
        (xm + 4.0 * x0 + x1) / 6.0,
        (x1 - xm) / (2.0 * dt),
        (x1 - 2.0 * x0 + xm) / dt**2,
        (x2 - 3.0 * x1 + 3.0 * x0 - xm) / dt**3,
    )


def follower_lead_s(limits_velocity: float, limits_acceleration: float, limits_jerk: float, dt: float) -> float:
    """The lead [s] a streaming client gives its setpoints to cover the loop's latency and the
    follower's lag, from the follower's limits of the tracked DOF: two control cycles ``2·dt`` (the
    setpoint is taken at the next cycle; its reference reaches the ECU a cycle later) plus the
    follower's jerk-limited rise time from rest to full speed, ``v/a + a/j``."""
    for name, v in (("velocity", limits_velocity), ("acceleration", limits_acceleration), ("jerk", limits_jerk)):
        _seconds(f"follower {name} limit", v, 1e-9, 1e9)
    return 2.0 * dt + limits_velocity / limits_acceleration + limits_acceleration / limits_jerk


def _pose_tolerance(model: HitchModel, planner: TrajectoryPlanner, p0: np.ndarray) -> np.ndarray:
    """One count on every sensor, mapped to the pose at ``p0`` (x, z, roll, pitch)."""
    jac = planner.inverse.solve(p0)[1]  # d actuators / d pose (5 x 4)
    res = SensorScaling(model.profile).resolution
    return np.asarray(np.abs(np.linalg.pinv(jac)) @ res, float)


def run_track_loop(
    model: HitchModel,
    scenario: Scenario | str,
    settings: LoopSettings | None = None,
    *,
    on_cycle: Callable[[SimLoop], None] | None = None,
) -> TrackLoopResult:
    """Run ``scenario``'s job with ``settings.strategy`` on the simulated rig (module docstring).

    ``on_cycle(loop)`` runs after every controller cycle (e.g. to time it).

    Raises:
        TrackLoopError: bad settings, no ECU measurement, or the track session could not start.
        ScenarioError: the scenario cannot be loaded.
    """
    s = settings if settings is not None else LoopSettings()
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    job = s.job if s.job is not None else job_of(sc)
    frame, dof = JOB_FRAME[job]
    ground_plan = job == "terrain" and s.ground_setpoint == "plan"
    if ground_plan:
        if not sc.twin.ground_sensor.fitted:
            raise TrackLoopError(
                "ground_setpoint = 'plan' needs a look-ahead ground sensor: the scenario's "
                "ground_sensor_ahead_m must be in (implement_behind_m, 20] m, got 0"
            )
        frame = "tractor"  # the client converts: it knows the ground ahead, the service does not
    d = _POSE.index(dof)
    duration = sc.duration_s if s.duration_s is None else s.duration_s
    if duration <= s.warmup_s + s.settle_s:
        raise TrackLoopError(
            f"duration_s = {duration:g} s must exceed warmup_s + settle_s = {s.warmup_s + s.settle_s:g} s"
        )
    twin = sc.twin
    pivot = float(model.profile.geometry.pivot_height)
    with SimLoop(model, sc, sim=s.sim, start=s.start, warmup_s=s.warmup_s, truth=s.truth) as loop:
        mc, tp = loop.mc, loop.planner
        lo, hi = tp.lo, tp.hi
        p0 = loop.measured_pose()
        tol = _pose_tolerance(model, tp, np.clip(p0, lo, hi))
        # the limits a session tracking ``dof`` alone moves within (the subset limits from the start pose)
        follow = TrackFollower(tp, MotionState.at_rest(np.clip(p0, lo, hi)), (dof,), s.ttl_s).limits
        # hold the start (the held reference is streamed from now on)
        mc.goto(dict(zip(_POSE, map(float, tp.implement_pose(p0)), strict=True)))  # with a lag: aimed at p0
        loop.cycle()
        sensors = loop.sensors
        t_loop = loop.now_s
        dist0 = sensors.ground_distance(t_loop)
        working = s.working_height_m
        if job == "terrain" and working is None:
            if dist0 is None:
                raise TrackLoopError("terrain: no ground-distance reading to take the working height from")
            working = dist0
        session: int | None = None
        if s.strategy == "track":
            try:
                session = mc.track_start(frame, (dof,), s.ttl_s).session
            except MotionError as exc:
                raise TrackLoopError(f"the track session could not start: {exc}") from None
        slope = WindowSlope(s.rate_window_s)
        row_f = _AlphaBeta(*s.row_filter) if s.row_filter is not None and s.row_estimator == "alpha_beta" else None
        row_kf = RowKalman(RowModel.from_row(twin.row)) if s.row_estimator == "kalman" else None
        camera_ahead = float(twin.row.camera_ahead_m)
        lead = 0.0
        planner_ahead: PreviewPlanner | None = None
        n_preview = 0
        if s.row_setpoint != "now":
            lead = (
                s.lead_s
                if s.lead_s is not None
                else follower_lead_s(
                    float(follow.velocity[d]), float(follow.acceleration[d]), float(follow.jerk[d]), loop.dt
                )
            )
        if s.row_setpoint == "plan":
            n_preview = int(camera_ahead / max(float(twin.speed.speed_m_s(t_loop)), 0.1) / loop.dt)
            m = PreviewPlanner.MARGIN  # the follower keeps room to catch up with the path
            planner_ahead = PreviewPlanner(
                m * float(follow.velocity[d]), m * float(follow.acceleration[d]), m * float(follow.jerk[d]), loop.dt
            )
        ground_est: GroundProfileEstimator | None = None
        pitch_hist: deque[tuple[float, float]] = deque(maxlen=64)  # (time the pitch was valid, pitch)
        seen: dict[str, float | None] = {"pitch": None, "ahead": None, "under": None}
        n_cycle = 0
        if ground_plan:
            gs = twin.ground_sensor
            ground_est = GroundProfileEstimator(
                GroundPreviewGeometry(
                    wheelbase_m=twin.tractor.wheelbase_m,
                    implement_behind_m=twin.implement_behind_m,
                    sensor_ahead_m=gs.ahead_m,
                    mount_height_m=gs.mount_height_m,
                    sensor_noise_m=gs.noise_rms_m,
                )
            )
            n_preview = max(8, int(gs.ahead_m / max(float(twin.speed.speed_m_s(t_loop)), 0.1) / loop.dt))
            m = PreviewPlanner.MARGIN
            planner_ahead = PreviewPlanner(
                m * float(follow.velocity[d]), m * float(follow.acceleration[d]), m * float(follow.jerk[d]), loop.dt
            )
        row_seen: float | None = None
        row_rate = 0.0
        path = np.zeros(0)
        path_t: np.ndarray | None = None
        seq = 0
        session_over = False
        last_goal: float | None = None
        counts = {
            "references_outside_strokes": 0,
            "refused": 0,
            "limit_events": 0,
            "limited_cycles": 0,
            "setpoints_rejected": 0,
            "gotos": 0,
            "gotos_refused": 0,
            "outside_workspace": 0,
        }
        rows: list[tuple[Any, ...]] = []
        notes: list[str] = list(_coverage_notes(twin, duration))
        excess = 0.0
        n_events = len(loop.events)
        while loop.now_s < duration - 1e-9:
            now = loop.now_s
            sp: float | None = None  # in the job's frame
            row_acc: float | None = None  # the preview plan's acceleration and jerk at the setpoint (plan only)
            row_jerk = 0.0
            target: float | None = None  # the same in the tractor frame (the client's conversion)
            if job == "levelling":
                att = sensors.attitude(now)
                if att is not None:
                    sp, target = 0.0, att[0]
            elif job == "guidance":
                ro = sensors.row_offset(now)
                odo = _odometer(loop.decoder, now) if row_kf is not None else None
                if ro is not None and row_kf is not None:
                    if odo is not None:
                        fresh_sample = ro[1] != row_seen
                        if fresh_sample:  # a new camera sample: keyed by the distance the camera saw it at
                            row_kf.add(ro[0], odo[0] + odo[1] * (ro[1] - now) + camera_ahead)
                            row_seen = ro[1]
                        if planner_ahead is not None and n_preview >= 8 and len(row_kf):
                            if fresh_sample or path_t is None:  # re-plan with every camera sample (10 Hz)
                                ref_row = [row_kf.at(odo[0] + odo[1] * k * loop.dt) for k in range(n_preview)]
                                path = planner_ahead.plan(
                                    now, np.array([r[0] for r in ref_row if r is not None]), start=float(p0[d])
                                )
                                path_t = now + loop.dt * np.arange(path.size)
                            assert path_t is not None
                            # the loop's latency: the reference of the next cycle reaches the pistons a cycle
                            # later (the follower itself meets the setpoint at the next cycle's time)
                            i = int(round((now + loop.dt - path_t[0]) / loop.dt))
                            sp, row_rate, row_acc, row_jerk = path_state(path, i, loop.dt)
                            target = sp
                        else:
                            est = row_kf.at(odo[0] + odo[1] * lead)
                            if est is not None:
                                sp, row_rate = est[0], est[1] * odo[1]
                                target = sp
                elif ro is not None:
                    if row_f is None:
                        sp = ro[0]
                    else:
                        if ro[1] != row_seen:
                            row_f.update(ro[0], ro[1])
                            row_seen = ro[1]
                        sp = row_f.at(now)[0]
                    target = sp
            elif ground_est is not None and planner_ahead is not None:
                assert working is not None
                odo = _odometer(loop.decoder, now)
                if odo is not None:
                    if _ground_samples(ground_est, loop, now, odo, pivot, pitch_hist, seen) and (
                        n_cycle % s.plan_every == 0 or path_t is None
                    ):
                        if ground_est.solve(odo[0]):
                            ahead_s = odo[0] + odo[1] * loop.dt * np.arange(n_preview)
                            ref_z = working - pivot + ground_est.implement_ground(ahead_s)
                            path = planner_ahead.plan(now, np.clip(ref_z, lo[d], hi[d]))
                            path_t = now + loop.dt * np.arange(path.size)
                    if path_t is not None:
                        # the loop's latency: taken next cycle, the pistons answer about one later
                        t_sp = now + 2 * loop.dt
                        sp = target = float(np.interp(t_sp, path_t, path))
                        row_rate = float(np.interp(t_sp, path_t[1:-1], (path[2:] - path[:-2]) / (2 * loop.dt)))
                n_cycle += 1
            else:
                dist = sensors.ground_distance(now)
                ls = loop.rig.link.latest_state()
                if dist is not None and ls is not None and working is not None:
                    sp = working
                    target = float(ls.pose.controlled()[1]) + (working - dist)
            rate = 0.0
            if target is not None:
                if (job == "guidance" and row_kf is not None) or ground_est is not None:
                    rate = row_rate
                elif job == "guidance" and row_f is not None:
                    rate = row_f.at(now)[1]
                else:
                    rate = slope.add(now, target)
            if sp is not None and target is not None:
                if s.strategy == "track" and session is not None:
                    seq += 1
                    # a measured demand may outrun what a setpoint may carry (a ditch's edge at 6 km/h: over
                    # 1.3 m/s); the service refuses such a setpoint whole (and, refused for its ttl, the stream
                    # goes stale and ends the session), and clips any velocity beyond the limits anyway
                    vel = {dof: min(max(rate, -PLAUSIBLE_VELOCITY), PLAUSIBLE_VELOCITY)} if s.send_velocity else None
                    path_derivatives = (
                        {} if row_acc is None else {"acceleration": {dof: row_acc}, "jerk": {dof: row_jerk}}
                    )
                    try:
                        mc.track_setpoint(session, seq, {dof: sp}, vel, **path_derivatives)
                    except MotionError as exc:
                        counts["setpoints_rejected"] += 1
                        if exc.code == "not_found" and not session_over:
                            # said whatever the notes hold already (five different values of one refusal hid it:
                            # the job ran on unfollowed and only a count said so)
                            session_over = True
                            notes.append(
                                f"the track session ended at {now - t_loop:.2f} s of the loop; every later setpoint "
                                f"was refused: {exc}"
                            )
                        else:
                            _note(notes, f"setpoint rejected: {exc}")
                elif s.strategy == "goto_stream":
                    goal = float(np.clip(target, lo[d], hi[d]))
                    if goal != last_goal:
                        counts["gotos"] += 1
                        try:
                            mc.goto({dof: goal})
                            last_goal = goal
                        except HitchError as exc:
                            counts["gotos_refused"] += 1
                            _note(notes, f"goto refused: {exc}")
            loop.cycle()
            if on_cycle is not None:
                on_cycle(loop)
            t = loop.now_s
            st = loop.state or {}
            ref = st.get("reference")
            ref_pose = np.array([ref["pose"][k] for k in _POSE]) if ref else np.full(4, np.nan)
            q = loop.streamed_actuators()
            if q is not None and (np.any(q < model.lower - 1e-9) or np.any(q > model.upper + 1e-9)):
                counts["references_outside_strokes"] += 1
            if st.get("limited"):
                counts["limited_cycles"] += 1
            truth = loop.truth_pose()
            meas = loop.measured_pose()
            beyond = float(np.max(np.maximum(lo - tol - meas, meas - hi - tol)))
            if beyond > 0.0:
                counts["outside_workspace"] += 1
                excess = max(excess, beyond)
            att_true = twin.attitude(t)
            g = twin.implement_ground_z(t)
            row_true = twin.row_true_offset_m(t)
            if job == "levelling":
                demand, err = att_true.roll_rad, truth[2] - att_true.roll_rad
            elif job == "guidance":
                demand, err = row_true, truth[0] - row_true
            else:
                assert working is not None
                demand = working + g - pivot
                err = (pivot + truth[1] - g) - working
            rows.append(
                (t, math.nan if sp is None else sp, demand, ref_pose, meas, truth)
                + (att_true.roll_rad, att_true.pitch_rad, g, row_true, err)
            )
        for e in loop.events[n_events:]:
            if e.get("event") == "limit_reached":
                counts["limit_events" if "limits" in e else "refused"] += 1
                if "limits" not in e:
                    _note(notes, f"reference refused: {e.get('message')}")
        faults = tuple(loop.rig.link.faults.reasons)
    ts = np.array([r[0] for r in rows]) - t_loop
    demand_a = np.array([r[2] for r in rows])
    evaluated = ts >= s.settle_s - 1e-9
    inside = evaluated & _inside(
        ts, demand_a, lo[d], hi[d], float(follow.velocity[d]), float(follow.acceleration[d]), s.inside_window_s
    )
    err_a = np.array([r[10] for r in rows])
    return TrackLoopResult(
        scenario=sc.name,
        job=job,
        strategy=s.strategy,
        frame=frame if s.strategy == "track" else "tractor",
        dof=dof,
        working_height_m=None if working is None else float(working),
        t=ts,
        setpoint=np.array([r[1] for r in rows]),
        demand=demand_a,
        reference=np.array([r[3] for r in rows]),
        measured=np.array([r[4] for r in rows]),
        truth=np.array([r[5] for r in rows]),
        tractor_roll=np.array([r[6] for r in rows]),
        tractor_pitch=np.array([r[7] for r in rows]),
        ground_height=np.array([r[8] for r in rows]),
        row=np.array([r[9] for r in rows]),
        error=err_a,
        evaluated=evaluated,
        inside=inside,
        figures=ErrorFigures.of(err_a[evaluated]),
        figures_inside=ErrorFigures.of(err_a[inside]),
        counts=counts,
        faults=faults,
        workspace_excess=excess,
        notes=tuple(notes),
    )


def _odometer(decoder: TractorSensors, t: float) -> tuple[float, float] | None:
    """The client's odometer at time ``t``: (distance [m], ground speed [m/s]), the wheel-based
    distance extrapolated with the speed from its frame's time; None without a usable reading."""
    r = decoder.readings(t)
    dist, speed = r.distance, r.speed
    if dist.value is None or speed.value is None or dist.received_s is None or dist.stale or speed.stale:
        return None
    return float(dist.value) + float(speed.value) * (t - dist.received_s), float(speed.value)


def _ground_samples(
    est: GroundProfileEstimator,
    loop: SimLoop,
    now: float,
    odo: tuple[float, float],
    pivot: float,
    pitch_hist: deque[tuple[float, float]],
    seen: dict[str, float | None],
) -> bool:
    """Feed the new samples of the slope sensor, the look-ahead and the implement's ground sensors to
    ``est``, each keyed by the rear axle's distance when it was valid (the odometer at ``now`` back by
    the ground speed; the slope sensor's reported latency taken off; the pitch at a ground sample's
    time interpolated from the pitch history). True when the estimator has samples."""
    r = loop.decoder.readings(now)
    lat = r.slope_latency_s or 0.0

    def at(t_x: float) -> float:
        return odo[0] + odo[1] * (t_x - now)

    def pitch_at(t_x: float) -> float:
        ts = [p[0] for p in pitch_hist]
        return float(np.interp(t_x, ts, [p[1] for p in pitch_hist]))

    p = r.pitch
    if p.value is not None and p.received_s is not None and p.received_s != seen["pitch"]:
        seen["pitch"] = p.received_s
        pitch_hist.append((p.received_s - lat, float(p.value)))
        est.add_pitch(at(p.received_s - lat), float(p.value))
    if not pitch_hist:
        return len(est) > 0
    ahead = r.ground_distance_ahead
    if ahead.value is not None and ahead.received_s is not None and ahead.received_s != seen["ahead"]:
        seen["ahead"] = ahead.received_s
        est.add_ahead(at(ahead.received_s), float(ahead.value), pitch_at(ahead.received_s))
    under = r.ground_distance
    ls = loop.rig.link.latest_state()
    if under.value is not None and under.received_s is not None and under.received_s != seen["under"] and ls:
        seen["under"] = under.received_s
        g = pivot + float(ls.pose.controlled()[1]) - float(under.value)
        est.add_implement(at(under.received_s), g, pitch_at(under.received_s))
    return len(est) > 0


def _coverage_notes(twin: Any, duration_s: float) -> tuple[str, ...]:
    """What a scenario's CSV profiles do not cover of the run (their last value then holds; a new user's speed
    file ending at 3 s of a 10 s run, and a 5 m terrain file under 20 m driven, passed unsaid)."""
    from bridge.sim.terrain import SampledGround

    out = []
    speed = twin.speed
    if len(speed.times_s) > 1 and speed.times_s[-1] < duration_s:
        out.append(
            f"the speed profile ends at {speed.times_s[-1]:g} s of the {duration_s:g} s run: its last speed, "
            f"{speed.speeds_m_s[-1]:g} m/s, holds after it"
        )
    ground = twin.ground
    if isinstance(ground, SampledGround):
        # the rear axle drives from distance(0) to distance(end); the implement's ground point is behind it, the
        # front axle and the look-ahead sensor's point ahead
        behind = twin.implement_behind_m
        back = twin.distance_m(0.0) - behind
        reach = twin.distance_m(duration_s) + max(twin.tractor.wheelbase_m, twin.ground_sensor.ahead_m - behind)
        if ground.distances_m[0] > back + 1e-9 or ground.distances_m[-1] < reach - 1e-9:
            out.append(
                f"the terrain profile covers {ground.distances_m[0]:g}…{ground.distances_m[-1]:g} m, the run "
                f"{back:.3g}…{reach:.4g} m (from behind the implement to ahead of the front axle): its end heights "
                "hold beyond it"
            )
    return tuple(out)


def _note(notes: list[str], text: str) -> None:
    if text not in notes and len(notes) < 5:
        notes.append(text)


def _inside(
    t: np.ndarray, demand: np.ndarray, lo: float, hi: float, v_max: float, a_max: float, window_s: float
) -> np.ndarray:
    """Samples whose demand stayed inside [lo, hi] and within the follower's pose velocity and
    acceleration limits (``v_max``, ``a_max``: the subset limits of the tracked DOF) over the
    preceding ``window_s``."""
    if len(t) < 3:
        return np.zeros(len(t), bool)
    vel = np.gradient(demand, t)
    acc = np.gradient(vel, t)
    ok = (demand >= lo) & (demand <= hi)
    ok &= np.abs(vel) <= v_max
    ok &= np.abs(acc) <= a_max
    bad = np.flatnonzero(~ok)
    out = ok.copy()
    for i in bad:  # a window after every bad sample
        out[i : np.searchsorted(t, t[i] + window_s, side="right")] = False
    return out
