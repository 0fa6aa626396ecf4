"""The thesis's field accuracy test (thesis tables 3-8 … 3-10) run against the twin.

:func:`run_accuracy_test` drives a :class:`~bridge.sim.rig.SimRig` whose twin has its own true
machine (:mod:`bridge.sim.truth`) through the pose sequence of
:func:`planner.calibration.accuracy.thesis_sequence`: each pose is a real goto over the CAN path
(the Ruckig plan from the pose the link measures, streamed at the control rate through the unit
loops' feed-forward, as ``hitch sim move``), held until every valve stayed closed for
``hold_s``; then the implement is measured and compared with the commanded pose. The planner
stays on its nominal profile throughout; only the twin knows the truth.

The measurement is the thesis's (thesis §3.3, tables 3-8 … 3-10): the heights of the four
corners of the test implement's frame (2300 mm wide, 1300 mm long, its near edge 290 mm behind
the lower hitch points, in the plane of the lower hitch points) and the lateral position of T
(a plumb line). Each of the five linear readings carries the instrument's position noise
(``tape``: uniform ±10 mm; ``total-station``: Gaussian σ = 1 mm; ``none``); the pose read is the
least-squares fit of z, roll and pitch to the four heights (x from the plumb line).

:func:`visit_poses` drives the same real gotos to any list of poses and records where the implement
truly is, what the link reads and what an instrument reads: the operator's measuring procedure for a
geometry calibration (``hitch calibrate measure-twin --by goto``) and the calibration bench's
evaluation through the twin.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from bridge.link.count_tail import CountTail, plan_count_tail
from bridge.link.state import LinkFaultError, LinkState, ReferenceRefused
from bridge.link.unit_loop import FeedforwardShaper, build_unit_loops
from bridge.sim.rig import SimError, SimRig, SimSettings
from bridge.sim.truth import Instrument, InstrumentNoise, MachineTruth, Measurement
from planner.calibration.accuracy import (
    AccuracyPose,
    DofStatistics,
    accuracy_statistics,
    thesis_sequence,
)
from planner.limits.guard import Guard
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.trajectory import MotionState, PlanError, TrajectoryPlanner

__all__ = [
    "INSTRUMENTS",
    "AccuracyRun",
    "AccuracyRunSettings",
    "FrameReading",
    "PoseVisits",
    "STOP_SD_MAX_COUNTS",
    "StopOffsets",
    "measure_stop_offsets",
    "read_frame",
    "run_accuracy_test",
    "visit_poses",
]

#: instrument names of the test → the noise preset of :class:`~bridge.sim.truth.InstrumentNoise`
INSTRUMENTS: dict[str, str] = {"tape": "tape", "total-station": "station", "none": "none"}
_DOF = ("x", "z", "roll", "pitch")


@dataclass(frozen=True)
class FrameReading:
    """What the tape read: the four corner heights [m] (front-left, front-right, rear-left, rear-right),
    the lateral position of T [m] and the pose fitted to them (x, z, roll, pitch; m, rad)."""

    corner_heights: tuple[float, float, float, float]
    lateral: float
    pose: tuple[float, float, float, float]


def _rotation(roll: float, pitch: float) -> np.ndarray:
    """Roll about the longitudinal y axis, then pitch about the lateral x axis (as :mod:`bridge.sim.truth`)."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    r_y = np.array([[cr, 0.0, sr], [0.0, 1.0, 0.0], [-sr, 0.0, cr]])
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    return r_y @ r_x


def _corners(width_m: float, length_m: float, offset_m: float, rear_sign: float) -> np.ndarray:
    w, y0, y1 = 0.5 * width_m, rear_sign * offset_m, rear_sign * (offset_m + length_m)
    return np.array([[-w, y0, 0.0], [w, y0, 0.0], [-w, y1, 0.0], [w, y1, 0.0]])


def _heights(z: float, roll: float, pitch: float, corners: np.ndarray) -> np.ndarray:
    return z + (corners @ _rotation(roll, pitch).T)[:, 2]


def read_frame(
    true_pose: ArrayLike,
    noise: InstrumentNoise,
    rng: np.random.Generator,
    *,
    width_m: float = 2.3,
    length_m: float = 1.3,
    offset_m: float = 0.29,
    rear_sign: float = 1.0,
) -> FrameReading:
    """The thesis's tape reading of a true pose (x, z, roll, pitch): corner heights and plumb line, fitted."""
    x, z, roll, pitch = (float(v) for v in np.asarray(true_pose, dtype=float).reshape(4))
    corners = _corners(width_m, length_m, offset_m, rear_sign)
    h = _heights(z, roll, pitch, corners) + noise.draw(rng, 4, noise.position_m)
    lateral = x + float(noise.draw(rng, 1, noise.position_m)[0])
    p = np.array([float(h.mean()), 0.0, 0.0])  # Gauss-Newton from level
    for _ in range(8):
        r = _heights(p[0], p[1], p[2], corners) - h
        jac = np.empty((4, 3))
        for j in range(3):
            d = np.zeros(3)
            d[j] = 1e-7
            hi, lo = p + d, p - d
            jac[:, j] = (_heights(hi[0], hi[1], hi[2], corners) - _heights(lo[0], lo[1], lo[2], corners)) / 2e-7
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        p += step
        if float(np.max(np.abs(step))) < 1e-12:
            break
    return FrameReading(
        (float(h[0]), float(h[1]), float(h[2]), float(h[3])), lateral, (lateral, float(p[0]), float(p[1]), float(p[2]))
    )


@dataclass(frozen=True)
class AccuracyRunSettings:
    """One run of the test.

    Attributes:
        instrument: ``tape`` (±10 mm per reading), ``total-station`` (σ 1 mm) or ``none``.
        seed: seed of the instrument's noise.
        tick_s: the rig's simulated tick [s] (5 ms: the ECU still integrates at 1 ms).
        hold_s: a pose is measured once every valve stayed closed this long [s].
        max_move_s: longest time for one goto, plan and settling [s].
        warmup_s: address claims and first measurement before the first move [s].
    """

    instrument: str = "tape"
    seed: int = 0
    tick_s: float = 0.005
    hold_s: float = 0.5
    max_move_s: float = 20.0
    warmup_s: float = 0.5

    def __post_init__(self) -> None:
        if self.instrument not in INSTRUMENTS:
            raise SimError(f"instrument must be one of {', '.join(INSTRUMENTS)}, got {self.instrument!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SimError(f"seed must be a non-negative integer, got {self.seed!r}")
        for name, lo, hi in (("hold_s", 0.05, 10.0), ("max_move_s", 1.0, 600.0), ("warmup_s", 0.3, 10.0)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and lo <= v <= hi):
                raise SimError(f"{name} must be a number of seconds in [{lo:g}, {hi:g}], got {v!r}")


@dataclass(frozen=True)
class AccuracyRun:
    """The result of one test: per measured pose (rows, x z roll pitch, SI) the ``commanded`` pose, the
    instrument's reading ``measured``, the twin's ``true`` pose and the ``planner`` pose (the link's
    measurement, nominal profile); ``labels`` name the poses; ``statistics`` are those of measured −
    commanded (the thesis's columns), ``true_statistics`` of true − commanded (no instrument noise)."""

    truth: str
    instrument: str
    labels: tuple[str, ...]
    commanded: np.ndarray
    measured: np.ndarray
    true: np.ndarray
    planner: np.ndarray
    statistics: dict[str, DofStatistics]
    true_statistics: dict[str, DofStatistics]
    simulated_s: float

    def as_dict(self) -> dict:
        def rows(a: np.ndarray) -> list[dict[str, float]]:
            return [dict(zip(_DOF, map(float, r), strict=True)) for r in a]

        return {
            "truth": self.truth,
            "instrument": self.instrument,
            "statistics": {k: v.as_dict() for k, v in self.statistics.items()},
            "true_statistics": {k: v.as_dict() for k, v in self.true_statistics.items()},
            "poses": [
                {"label": lab, "commanded": c, "measured": m, "true": t, "planner": p}
                for lab, c, m, t, p in zip(
                    self.labels,
                    rows(self.commanded),
                    rows(self.measured),
                    rows(self.true),
                    rows(self.planner),
                    strict=True,
                )
            ],
            "simulated_s": self.simulated_s,
        }


@dataclass(frozen=True)
class PoseVisits:
    """Poses reached by real gotos on the twin (:func:`visit_poses`): per pose the ``commanded`` pose
    (N, 4; x, z, roll, pitch, SI), the twin's ``true`` pose (N, 4), the link's AD ``counts`` at rest
    (N, 5, actuator order; the lift recovered from the hitch status; with the profile's count approach,
    its stop inside the count where the reading is on it: :meth:`_TwinGotos.counts_estimate`) and the
    ``planner`` pose (N, 4, the link's measurement through the model's profile); ``simulated_s`` of the run."""

    commanded: np.ndarray
    true: np.ndarray
    counts: np.ndarray
    planner: np.ndarray
    simulated_s: float
    refused: tuple[tuple[int, str], ...] = ()
    """Poses the planner refused (``skip_refused``): (index, reason); their rows are NaN."""
    measurements: tuple[Measurement | None, ...] = ()
    """The ``instrument``'s reading of each pose (None where refused; empty without an instrument)."""
    points: tuple[dict[str, np.ndarray], ...] = ()
    """True positions of the named ``points`` at each pose (empty dicts where refused or none asked)."""
    play_offset: np.ndarray | None = None
    """(N, 4) the true implement pose minus the true mechanism's at each pose: where the pin play left it
    (:attr:`~bridge.sim.truth.TrueMachine.play_offset`; NaN where refused)."""


class _TwinGotos:
    """A :class:`SimRig` on ``truth`` driven by real gotos of ``model``'s planner (with the profile's final
    approach, if any) through the unit loops' feed-forward, each held until the valves rested ``hold_s``."""

    def __init__(self, model: HitchModel, truth: MachineTruth, start: np.ndarray, s: AccuracyRunSettings) -> None:
        self.tp = TrajectoryPlanner(model)
        self.s = s
        self.rig = SimRig(
            model,
            SimSettings(tick_s=s.tick_s, seed=s.seed),
            initial_actuators=self.tp.inverse.solve(start)[0],
            truth=truth,
        )
        loops = build_unit_loops(model.profile, self.rig.ecu.config.a)
        self.shaper = FeedforwardShaper(loops, self.tp.inverse.solve_full, self.rig.link.check_reference)
        #: the last goto's count approach (None: the profile has none, or not at that goal)
        self.last_tail: CountTail | None = None
        self.guard = Guard(self.tp)  # the count approach's via and final poses pass it, as in the service
        self.scaling = SensorScaling(model.profile)

    def counts_estimate(self) -> np.ndarray:
        """The pistons' positions as the planner knows them at rest [counts, float]: where the last goto's count
        approach stops each piston inside its count when the reading is on that count, else the reading."""
        read = np.asarray(self.state().counts, float)
        tail = self.last_tail
        if tail is None:
            return read
        a = tail.approach
        # the lift's reading comes from the hitch status, fractional when its span exceeds 250 counts
        return np.where(np.abs(read - a.final_counts) < 0.5, a.stop_counts, read)

    def __enter__(self) -> _TwinGotos:
        self.rig.__enter__()
        self.rig.start()
        self.rig.run_until(self.s.warmup_s)
        return self

    def __exit__(self, *exc: object) -> None:
        self.rig.__exit__(*exc)

    def state(self) -> LinkState:
        """The link's latest state (SimError without a measurement)."""
        state = self.rig.link.latest_state()
        if state is None:
            raise SimError(
                f"no measurement from the simulated ECU (faults: {', '.join(self.rig.link.faults.reasons) or 'none'})"
            )
        return state

    def goto(self, goal: dict[str, float], what: str) -> np.ndarray:
        """One real goto over the CAN path; the commanded pose (4,) once the valves rested ``hold_s``."""
        rig, tp, s = self.rig, self.tp, self.s
        p0 = self.state().pose.controlled()
        p1 = tp.goal_vector(p0, goal)
        tp.check_in_workspace(p1, what)
        plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(_DOF, map(float, p1), strict=True)))
        sp = tp.sample(plan)
        refs = [
            self.shaper.for_plan(plan.state_at, float(t), q, qd)
            for t, q, qd in zip(sp.t, sp.actuators, sp.actuator_velocity, strict=True)
        ]
        # the profile's count approach after the plan, as the service streams it (bridge.link.count_tail)
        tail = plan_count_tail(tp, plan, rig.link.check_reference, self.guard)
        self.last_tail = tail
        end = float(sp.t[-1])
        t0, k, sent_phase = rig.now_s, 0, -1
        quiet_since: float | None = None
        try:
            while True:
                while k < len(refs) and rig.next_tick_s >= t0 + float(sp.t[k]) - 1e-9:
                    rig.link.send_reference(refs[k], rig.next_tick_s)
                    k += 1
                in_tail = False
                if tail is not None and k == len(refs):
                    after = rig.next_tick_s - t0 - end
                    in_tail = after < tail.approach.duration_s
                    phase = 0 if after < tail.approach.via_hold_s else 1
                    if phase != sent_phase:  # the link streams the last reference on
                        rig.link.send_reference(tail.actuators_at(after), rig.next_tick_s)
                        sent_phase = phase
                t = rig.tick()
                quiet_since = self._quiet_since(t, quiet_since, busy=k < len(refs) or in_tail)
                if quiet_since is not None and t - quiet_since >= s.hold_s - 1e-9:
                    return p1
                if t - t0 >= s.max_move_s:
                    return p1  # measured as it stands (a cylinder still hunting): the error shows it
        except (ReferenceRefused, LinkFaultError) as exc:  # a refused reference or a link fault
            raise SimError(f"t = {rig.now_s:.2f} s: {exc}") from None

    def hold_counts(self, counts: ArrayLike) -> bool:
        """Stream the whole ``counts`` (5) until every valve stayed closed ``hold_s``: True, or False after
        ``max_move_s`` with a valve still open. SimError when the link refuses them (a hard limit)."""
        rig, s = self.rig, self.s
        try:
            rig.link.send_reference(self.scaling.to_si(counts), rig.next_tick_s)
        except (ReferenceRefused, LinkFaultError) as exc:
            raise SimError(f"t = {rig.now_s:.2f} s: {exc}") from None
        t0, quiet_since = rig.now_s, None
        while True:
            t = rig.tick()
            quiet_since = self._quiet_since(t, quiet_since)
            if quiet_since is not None and t - quiet_since >= s.hold_s - 1e-9:
                return True
            if t - t0 >= s.max_move_s:
                return False

    def _quiet_since(self, t: float, since: float | None, *, busy: bool = False) -> float | None:
        """Since when every valve has been closed at tick ``t`` (None: one is open, or the caller is ``busy``
        streaming)."""
        if busy or self.rig.ecu.valve_commands().any():
            return None
        return t if since is None else since


@dataclass(frozen=True)
class StopOffsets:
    """Where the twin's ECU leaves each piston inside its reference count, piston − count [counts], rising
    into the count (``from_below``) and falling into it (``from_above``) after a back-off of 1, 2, … counts:
    per actuator the mean offsets (one per back-off kept) and their sd, over ``n`` poses.

    A back-off is kept while its stop lies further into the count than the one before, on the side it came
    from, and repeats within :data:`STOP_SD_MAX_COUNTS`: from further away the piston comes faster and coasts
    further, until it coasts a count over and the ECU drives it back (from the other side)."""

    from_below: tuple[tuple[float, ...], ...]
    from_above: tuple[tuple[float, ...], ...]
    sd_below: tuple[tuple[float, ...], ...]
    sd_above: tuple[tuple[float, ...], ...]
    n: int

    def table(self) -> dict[str, dict[str, list[float]]]:
        """``from_below_counts`` and ``from_above_counts`` of a ``motion.count_approach`` section."""
        return {
            "from_below_counts": {k: list(v) for k, v in zip(ACTUATOR_NAMES, self.from_below, strict=True)},
            "from_above_counts": {k: list(v) for k, v in zip(ACTUATOR_NAMES, self.from_above, strict=True)},
        }

    def toml(self) -> str:
        """The profile section ``[motion.count_approach]`` with these offsets (3 decimals)."""

        def row(v: tuple[tuple[float, ...], ...]) -> str:
            items = (f"{k} = [{', '.join(f'{x:.3f}' for x in xs)}]" for k, xs in zip(ACTUATOR_NAMES, v, strict=True))
            return "{ " + ", ".join(items) + " }"

        return (
            "[motion.count_approach]\n"
            f"from_below_counts = {row(self.from_below)}\n"
            f"from_above_counts = {row(self.from_above)}\n"
        )


#: a back-off whose stop spreads more than this over the poses measured is not kept [counts]
STOP_SD_MAX_COUNTS = 0.05


def _kept(name: str, mean: np.ndarray, sd: np.ndarray, sign: float) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The leading back-offs whose stops move monotonically further along ``sign`` and repeat (one actuator);
    SimError when even a back-off of one count does not repeat or stops a count or more away."""
    if not (sd[0] <= STOP_SD_MAX_COUNTS and abs(mean[0]) < 1.0):
        raise SimError(
            f"{name}: its stop after a one-count step does not repeat (mean {mean[0]:+.3f}, sd {sd[0]:.3f} counts; "
            f"allowed sd <= {STOP_SD_MAX_COUNTS}, |mean| < 1): no count approach for this ECU"
        )
    m, s = [float(mean[0])], [float(sd[0])]
    for k in range(1, len(mean)):
        if sign * (mean[k] - m[-1]) <= 0.0 or sd[k] > STOP_SD_MAX_COUNTS or abs(mean[k]) >= 1.0:
            break
        m.append(float(mean[k]))
        s.append(float(sd[k]))
    return tuple(m), tuple(s)


def measure_stop_offsets(
    model: HitchModel,
    poses: ArrayLike,
    truth: MachineTruth | None = None,
    settings: AccuracyRunSettings | None = None,
    *,
    max_back_off_counts: int = 3,
) -> StopOffsets:
    """Measure on the twin where its ECU stops each piston inside a count: at each pose (N, 4; reached by a
    real goto of ``model``'s planner; refused poses are skipped), for k = 1 … ``max_back_off_counts`` every
    actuator's reference goes k counts below its count and back up, then k above and back down, each held
    until the valves rested; the twin's true pistons give the offsets (:class:`StopOffsets` says which
    back-offs are kept). On a real machine the pistons inside a count are not observable from the readings:
    there the offsets come from the machine's twin (docs/commissioning.md)."""
    s = settings or AccuracyRunSettings(instrument="none")
    tr = truth if truth is not None else MachineTruth(model.profile)
    ps = np.asarray(poses, float).reshape(-1, 4)
    if not isinstance(max_back_off_counts, int) or not 1 <= max_back_off_counts <= 5:
        raise SimError(f"max_back_off_counts must be a whole number in [1, 5], got {max_back_off_counts!r}")
    ks = range(1, max_back_off_counts + 1)
    below: list[list[np.ndarray]] = []
    above: list[list[np.ndarray]] = []
    skipped = 0
    with _TwinGotos(model, tr, model.neutral_pose.controlled(), s) as tw:
        for k_pose, p in enumerate(ps):
            try:
                tw.goto(dict(zip(_DOF, map(float, p), strict=True)), f"poses[{k_pose}]")
            except PlanError:
                continue
            c = tw.rig.ecu.reference_counts()
            if c is None:
                continue
            b_row: list[np.ndarray] = []
            a_row: list[np.ndarray] = []
            try:
                for k in ks:
                    for d, row in ((1, b_row), (-1, a_row)):
                        settled = tw.hold_counts(c - d * k) and tw.hold_counts(c)
                        if not settled:
                            raise SimError(f"poses[{k_pose}]: a valve still open after {s.max_move_s} s")
                        row.append(tw.rig.ecu.piston_counts() - c)
            except SimError:  # a count beyond a hard limit, or no rest: this pose is not measured
                skipped += 1
                continue
            below.append(b_row)
            above.append(a_row)
    if not below:
        raise SimError(f"no stop measured: {skipped} poses skipped, the rest refused by the planner")
    b, a = np.array(below), np.array(above)  # (poses, back-offs, actuators)
    names = [f"{n} from below" for n in ACTUATOR_NAMES], [f"{n} from above" for n in ACTUATOR_NAMES]
    out_b = [_kept(names[0][i], b.mean(axis=0)[:, i], b.std(axis=0)[:, i], 1.0) for i in range(len(ACTUATOR_NAMES))]
    out_a = [_kept(names[1][i], a.mean(axis=0)[:, i], a.std(axis=0)[:, i], -1.0) for i in range(len(ACTUATOR_NAMES))]
    return StopOffsets(
        tuple(m for m, _ in out_b),
        tuple(m for m, _ in out_a),
        tuple(sd for _, sd in out_b),
        tuple(sd for _, sd in out_a),
        len(b),
    )


def visit_poses(
    model: HitchModel,
    poses: ArrayLike,
    truth: MachineTruth | None = None,
    settings: AccuracyRunSettings | None = None,
    *,
    skip_refused: bool = False,
    instrument: Instrument | None = None,
    points: Sequence[str] = (),
) -> PoseVisits:
    """Drive the twin with ``truth`` (default: nominal) to each pose (N, 4; x, z, roll, pitch [m, rad]) in
    order by a real goto of ``model``'s planner (from the profile's neutral pose), as the operator does
    before measuring a pose; record where the implement truly is and what the link reads, and (with an
    ``instrument``) what the instrument reads of the pose and the named ``points``.

    Raises :class:`SimError` (no measurement, a refused reference) or a
    :class:`~planner.trajectory.plan.PlanError` (a pose out of the workspace or no plan within the
    limits; with ``skip_refused`` such a pose is left out instead, its rows NaN, named in ``refused``).
    """
    s = settings if settings is not None else AccuracyRunSettings()
    p = np.asarray(poses, dtype=float)
    if p.ndim != 2 or p.shape[1] != 4 or p.shape[0] < 1 or not np.all(np.isfinite(p)):
        raise SimError("poses must be a non-empty (N, 4) array of finite x, z, roll, pitch [m, rad]")
    truth = truth if truth is not None else MachineTruth.nominal(model.profile)
    n = p.shape[0]
    cmd, true, planner, counts, play = (
        np.full((n, 4), np.nan),
        np.full((n, 4), np.nan),
        np.full((n, 4), np.nan),
        np.full((n, 5), np.nan),
        np.full((n, 4), np.nan),
    )
    refused: list[tuple[int, str]] = []
    readings: list[Measurement | None] = []
    marked: list[dict[str, np.ndarray]] = []
    with _TwinGotos(model, truth, model.neutral_pose.controlled(), s) as tw:
        for k, pose in enumerate(p):
            try:
                cmd[k] = tw.goto(dict(zip(_DOF, map(float, pose), strict=True)), f"poses[{k}]")
            except PlanError as exc:
                if not skip_refused:
                    raise
                refused.append((k, str(exc)))
                readings.append(None)
                marked.append({})
                continue
            true[k] = tw.rig.true_pose().controlled()
            machine = tw.rig.true_machine
            play[k] = machine.play_offset
            marked.append(machine.points(tuple(points)) if points else {})
            readings.append(instrument.measure(machine, tuple(points)) if instrument is not None else None)
            state = tw.state()
            counts[k] = tw.counts_estimate()  # with a count approach: its stop inside the count
            planner[k] = state.pose.controlled()
        simulated = tw.rig.now_s
    return PoseVisits(
        cmd,
        true,
        counts,
        planner,
        simulated,
        tuple(refused),
        tuple(readings) if instrument else (),
        tuple(marked),
        play,
    )


def run_accuracy_test(
    model: HitchModel,
    truth: MachineTruth | None = None,
    settings: AccuracyRunSettings | None = None,
    sequence: Sequence[AccuracyPose] | None = None,
) -> AccuracyRun:
    """Run the test (module docstring) on the twin with ``truth`` (default: the nominal twin).

    Home is the profile's neutral pose. Raises :class:`SimError` (no measurement, a refused
    reference) or a :class:`~planner.trajectory.plan.PlanError` (a pose out of the workspace).
    """
    s = settings if settings is not None else AccuracyRunSettings()
    seq = tuple(sequence) if sequence is not None else thesis_sequence()
    if not any(p.measure for p in seq):
        raise SimError("the sequence has no pose to measure")
    truth = truth if truth is not None else MachineTruth.nominal(model.profile)
    home = model.neutral_pose.controlled()
    noise = InstrumentNoise.preset(INSTRUMENTS[s.instrument])
    rng = np.random.default_rng(s.seed)
    labels: list[str] = []
    cmd: list[np.ndarray] = []
    meas: list[tuple[float, float, float, float]] = []
    true: list[np.ndarray] = []
    planner: list[np.ndarray] = []
    with _TwinGotos(model, truth, home, s) as tw:
        pts = model.forward(tw.tp.inverse.solve(home)[0]).points
        rear = 1.0 if float(pts["T"][1] - pts["H"][1]) >= 0.0 else -1.0  # the frame extends away from the tractor
        for step in seq:
            p1 = tw.goto(step.goal(home), "accuracy-test pose")
            if not step.measure:
                continue
            tpose = tw.rig.true_pose().controlled()
            state = tw.rig.link.latest_state()
            labels.append(step.label)
            cmd.append(p1)
            true.append(tpose)
            planner.append(state.pose.controlled() if state is not None else np.full(4, np.nan))
            meas.append(read_frame(tpose, noise, rng, rear_sign=rear).pose)
        simulated = tw.rig.now_s
    c, m, t = np.array(cmd), np.array(meas), np.array(true)
    return AccuracyRun(
        truth=truth.profile.name,
        instrument=s.instrument,
        labels=tuple(labels),
        commanded=c,
        measured=m,
        true=t,
        planner=np.array(planner),
        statistics=accuracy_statistics(c, m, labels),
        true_statistics=accuracy_statistics(c, t, labels),
        simulated_s=simulated,
    )
