"""Closed-loop work control over a field in simulated time: position, draft, mixed or float control.

:func:`run_field_loop` drives the tractor over a field (:mod:`bridge.sim.field`: a terrain scenario,
soil patches, a D497 implement, draft pins) with the twin of :mod:`bridge.service.track_loop`
(:class:`~bridge.service.track_loop.SimLoop`: the real motion controller on the simulated rig,
identified hydraulics, the real codec and CAN path, the tractor's sensors on the bus). Every control
cycle (20 ms) the :class:`~planner.work_control.WorkController` turns the operator's position
setpoint into the z setpoint of one track session (tractor frame, DOF z), which the controller's
:class:`~planner.trajectory.track.TrackFollower` follows within the workspace and the guard.

The draft travels the bus: the simulated ECU node's rear hitch status (PGN 65093) carries the
draft pins' reading (RearDraft, the nominal lower-link force) from a :class:`FieldDraft` source,
which steps the :class:`~bridge.sim.field.FieldRun` with the tool tip's *true* height (forward
kinematics of the simulated pistons), so the draft comes from the true working depth. The planner
side reads it with :class:`~bridge.link.tractor_sensors.TractorSensors` (``read_draft``).

Geometry (an assumption of the twin). The tool tip is ``tool_drop_m`` below the hitch's tool point
T, calibrated so that the operator's position setpoint ``z_m`` puts the tip ``working_depth_m``
(the field file's) below the tractor's contact plane: ``tool_drop_m = pivot_height + z_m +
working_depth_m``. The ground reference of the work controller (the z at which the tip touches
the ground) is ``z_measured - ground_distance + tool_drop_m`` from the measured pose and the ground
sensor at T.

Slip (an assumption): the work controller gets the twin's true slip (the tractor's own estimate
from radar and wheel speed is not modelled on the bus).

Figures (:class:`FieldLoopResult`, after ``settle_s``): the true draft's mean and standard deviation,
the true working depth's min/max, the slip's max overall and in the heavy patches (soil factor
≥ 1 + variation/2; all samples, and those at least 3 s into the patch), fallbacks, and the work
controller's cycle cost (wall and thread CPU time per step).
"""

from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bridge.link.tractor_sensors import TractorSensorsConfig
from bridge.service.motion.types import MotionError
from bridge.service.track_loop import SimLoop, TrackLoopError, _note
from bridge.service.work import WindowSlope, draft_rate_limit
from bridge.sim.field import FieldDraft, FieldRun, FieldSetup, load_field
from bridge.sim.move import SimSettings
from bridge.sim.preview_sensor import PreviewSensor, PreviewSensorConfig
from bridge.sim.truth import MachineTruth
from planner.model.kinematics import HitchModel
from planner.work_control import WorkController, WorkSettings
from planner.work_control.ground_preview import GroundPreview, PreviewGeometry

__all__ = ["FieldDraft", "FieldLoopError", "FieldLoopResult", "FieldLoopSettings", "run_field_loop"]


HEAVY_SETTLE_S = 3.0
"""The slip figure ``slip_max_heavy_settled`` leaves out the first seconds in a heavy patch (the entry
transient: the limiter acts on the slip, so it cannot prevent the rise it reacts to)."""


class FieldLoopError(TrackLoopError):
    """A field loop that cannot run as asked; the message names the field and the allowed range."""


def _number(name: str, v: object, lo: float, hi: float, *, optional: bool = False) -> None:
    if optional and v is None:
        return
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise FieldLoopError(f"{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")


@dataclass(frozen=True)
class FieldLoopSettings:
    """One field run.

    Attributes:
        work: the operator's work-control settings (mode, setpoint, blend, limits …).
        z_m: the operator's position setpoint, hitch z in the tractor frame [m], [-0.2, 0.3].
        duration_s: scenario time to run [s] (None: the terrain scenario's), [2, 3600].
        warmup_s: rig time before the loop starts [s]; settle_s: the figures leave out the first
            ``settle_s`` of the loop [s].
        ttl_s: the track session's time-to-live [s].
        draft_lost_at_s: from this loop time on the draft pins send "not available" (a broken
            sensor: the fallback), None: never.
        rate_window_s: the least-squares window of the setpoint's rate sent with it [s].
        rate_limit: the work controller knows the hitch's z speed (the follower's z-only limit, see
            :data:`bridge.service.work.Z_RATE_SHARE`) and never asks for more (False: unlimited, the old behaviour).
        preview: the preview ground sensor on the tractor's front (:mod:`bridge.sim.preview_sensor`) whose
            readings, with the slope sensor's pitch, the implement's ground sensor and the odometer, feed a
            :class:`~planner.work_control.ground_preview.GroundPreview`; None: no preview (the old regulator).
        preview_lead_s: how far ahead the work controller's ground is taken: the hitch's lag from setpoint
            to position [s], [0, 1] (the preview reaches (F − L)/v, 0.45 s at 8 km/h).
        sim: the simulated machine and bus.
        truth: the twin's own true machine (:mod:`bridge.sim.truth`, ``hitch sim perturb``); None: exactly
            the planner's profile. The planner, the link and the figures' demand stay on the model.
    """

    work: WorkSettings = field(default_factory=WorkSettings)
    z_m: float = 0.0
    duration_s: float | None = None
    warmup_s: float = 0.5
    settle_s: float = 3.0
    ttl_s: float = 0.3
    draft_lost_at_s: float | None = None
    rate_window_s: float = 0.1
    rate_limit: bool = True
    preview: PreviewSensorConfig | None = field(default_factory=PreviewSensorConfig)
    preview_lead_s: float = 0.3
    sim: SimSettings = field(default_factory=SimSettings)
    truth: MachineTruth | None = None

    def __post_init__(self) -> None:
        if self.truth is not None and not isinstance(self.truth, MachineTruth):
            raise FieldLoopError(f"truth must be a MachineTruth or None, got {type(self.truth).__name__}")
        if not isinstance(self.work, WorkSettings):
            raise FieldLoopError(f"work must be a WorkSettings, got {type(self.work).__name__}")
        _number("z_m", self.z_m, -0.2, 0.3)
        _number("warmup_s", self.warmup_s, 0.3, 10.0)
        _number("settle_s", self.settle_s, 0.0, 600.0)
        _number("duration_s", self.duration_s, 0.0, 3600.0, optional=True)
        least = self.warmup_s + self.settle_s  # the one range a duration has
        if self.duration_s is not None and self.duration_s <= least:
            raise FieldLoopError(
                f"duration_s = {self.duration_s:g} s must exceed warmup_s + settle_s = {least:g} s "
                f"(allowed: ({least:g}, 3600] s)"
            )
        _number("ttl_s", self.ttl_s, 0.05, 1.0)
        _number("draft_lost_at_s", self.draft_lost_at_s, 0.0, 3600.0, optional=True)
        _number("rate_window_s", self.rate_window_s, 0.02, 2.0)
        if not isinstance(self.rate_limit, bool):
            raise FieldLoopError(f"rate_limit must be true or false, got {self.rate_limit!r}")
        if self.preview is not None and not isinstance(self.preview, PreviewSensorConfig):
            raise FieldLoopError(f"preview must be a PreviewSensorConfig or None, got {type(self.preview).__name__}")
        _number("preview_lead_s", self.preview_lead_s, 0.0, 1.0)


@dataclass(frozen=True)
class FieldLoopResult:
    """One field run sampled every control cycle (t = loop time [s], SI).

    Arrays (N,): ``t``, ``z_operator``, ``z_setpoint`` (the work controller's), ``z_reference`` (the
    motion controller's reference, NaN when none), ``z_true`` (simulated pistons), ``ground_z`` (the
    controller's ground reference, NaN when none), ``depth`` (true working depth), ``draft`` (true),
    ``draft_measured`` (over CAN, NaN when none), ``resistance`` (soil factor), ``slip`` (true),
    ``active`` (the mode in effect), ``evaluated`` (after ``settle_s``), ``heavy`` (resistance ≥
    1 + variation/2), ``ground_ahead_z`` (the previewed ground reference handed to the controller, NaN
    when none). ``cycle_s``, ``cycle_cpu_s``: the work controller's step times, wall and thread CPU [s];
    ``preview_cpu_s``: the ground preview's update and estimate per cycle, thread CPU [s] (empty without).
    """

    field: str
    mode: str
    settings: WorkSettings
    t: np.ndarray
    z_operator: np.ndarray
    z_setpoint: np.ndarray
    z_true: np.ndarray
    ground_z: np.ndarray
    depth: np.ndarray
    draft: np.ndarray
    draft_measured: np.ndarray
    resistance: np.ndarray
    slip: np.ndarray
    active: tuple[str, ...]
    z_reference: np.ndarray
    evaluated: np.ndarray
    heavy: np.ndarray
    cycle_s: np.ndarray
    cycle_cpu_s: np.ndarray
    events: tuple[str, ...]
    counts: dict[str, int]
    faults: tuple[str, ...]
    notes: tuple[str, ...] = ()
    ground_ahead_z: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))
    preview_cpu_s: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0))

    def heavy_settled(self, after_s: float = HEAVY_SETTLE_S) -> np.ndarray:
        """Heavy-patch samples at least ``after_s`` after the implement entered the patch."""
        out = np.zeros(len(self.t), bool)
        since: float | None = None
        for i, (t, h) in enumerate(zip(self.t, self.heavy, strict=True)):
            since = (since if since is not None else float(t)) if h else None
            out[i] = since is not None and t - since >= after_s
        return out

    def figures(self) -> dict[str, Any]:
        """Draft, depth and slip figures over the evaluated samples, the work controller's cycle cost
        (wall and thread CPU) [µs]."""
        ev = self.evaluated
        hv = ev & self.heavy
        hs = ev & self.heavy_settled()
        d = self.draft[ev]
        cyc, cpu, pre = self.cycle_s * 1e6, self.cycle_cpu_s * 1e6, self.preview_cpu_s * 1e6
        return {
            "draft_mean_n": float(np.mean(d)) if d.size else math.nan,
            "draft_sd_n": float(np.std(d)) if d.size else math.nan,
            "depth_min_m": float(np.min(self.depth[ev])) if d.size else math.nan,
            "depth_max_m": float(np.max(self.depth[ev])) if d.size else math.nan,
            "slip_max": float(np.max(self.slip[ev])) if d.size else math.nan,
            "slip_max_heavy": float(np.max(self.slip[hv])) if hv.any() else math.nan,
            "slip_p95_heavy": float(np.percentile(self.slip[hv], 95)) if hv.any() else math.nan,
            "slip_max_heavy_settled": float(np.max(self.slip[hs])) if hs.any() else math.nan,
            "heavy_samples": int(hv.sum()),
            "cycle_median_us": float(np.median(cyc)) if cyc.size else math.nan,
            "cycle_p99_us": float(np.percentile(cyc, 99)) if cyc.size else math.nan,
            "cycle_cpu_median_us": float(np.median(cpu)) if cpu.size else math.nan,
            "cycle_cpu_p99_us": float(np.percentile(cpu, 99)) if cpu.size else math.nan,
            "preview_cpu_median_us": float(np.median(pre)) if pre.size else math.nan,
            "preview_cpu_p99_us": float(np.percentile(pre, 99)) if pre.size else math.nan,
            "n": int(d.size),
        }

    def summary(self) -> dict[str, Any]:
        """JSON-ready settings, figures, counts and events."""
        s = self.settings
        return {
            "field": self.field,
            "mode": self.mode,
            "settings": {
                "mode": s.mode,
                "draft_setpoint_n": s.draft_setpoint_n,
                "blend": s.blend,
                "sensitivity": s.sensitivity,
                "depth_min_m": s.depth_min_m,
                "depth_max_m": s.depth_max_m,
                "slip_limit": s.slip_limit,
            },
            "duration_s": float(self.t[-1] - self.t[0]) if len(self.t) else 0.0,
            "figures": self.figures(),
            "counts": dict(self.counts),
            "events": list(self.events),
            "faults": list(self.faults),
            "notes": list(self.notes),
        }


def run_field_loop(
    model: HitchModel,
    field_setup: FieldSetup | str,
    settings: FieldLoopSettings | None = None,
) -> FieldLoopResult:
    """Run the field with the work controller closing the loop through a track session (module docstring).

    Raises:
        FieldLoopError / TrackLoopError: bad settings, no ECU measurement, the session could not start.
        FieldError: the field cannot be loaded.
    """
    s = settings if settings is not None else FieldLoopSettings()
    fs = field_setup if isinstance(field_setup, FieldSetup) else load_field(field_setup)
    sc = fs.scenario
    duration = sc.duration_s if s.duration_s is None else s.duration_s
    if duration <= s.warmup_s + s.settle_s:
        raise FieldLoopError(
            f"duration_s = {duration:g} s must exceed warmup_s + settle_s = {s.warmup_s + s.settle_s:g} s"
        )
    pivot = float(model.profile.geometry.pivot_height)
    drop = pivot + s.z_m + fs.working_depth_m
    heavy_at = 1.0 + 0.5 * fs.soil.variation
    cfg = TractorSensorsConfig(read_draft=True)
    with SimLoop(
        model, sc, sim=s.sim, start={"z": s.z_m}, warmup_s=s.warmup_s, sensors_config=cfg, truth=s.truth
    ) as loop:
        mc = loop.mc
        t0 = loop.now_s
        lost = None if s.draft_lost_at_s is None else t0 + s.draft_lost_at_s
        source = FieldDraft(FieldRun(fs), lambda: pivot + float(loop.truth_pose()[1]) - drop, lost_at_s=lost)
        loop.rig.node.draft_source = source
        p0 = mc.planner.implement_pose(loop.measured_pose())  # held where it is (with a lag: aimed at p0)
        mc.goto({"x": float(p0[0]), "z": s.z_m, "roll": float(p0[2]), "pitch": float(p0[3])})
        loop.cycle()
        try:
            session = mc.track_start("tractor", ("z",), s.ttl_s).session
        except MotionError as exc:
            raise FieldLoopError(f"the track session could not start: {exc}") from None
        work = WorkController(s.work, z_rate_max_m_s=draft_rate_limit(mc.planner, p0) if s.rate_limit else None)
        # the z the session can reach (the workspace: no implement bounds here), as the live service passes it
        # (bridge.service.work): the regulator clips its demand and integrator there (a review: the loop did
        # not, so its draft could wind up below the workspace floor where the service's cannot)
        z_range = (float(mc.planner.lo[1]), float(mc.planner.hi[1]))
        front = None if s.preview is None else PreviewSensor(sc.twin, s.preview)
        preview = None
        if front is not None:
            geometry = PreviewGeometry(
                wheelbase_m=sc.twin.tractor.wheelbase_m,
                sensor_ahead_m=front.ahead_of_rear_axle_m,
                tool_behind_m=sc.twin.implement_behind_m,
                sensor_sigma_m=max(1e-4, s.preview.noise_rms_m) if s.preview is not None else 0.003,
            )
            preview = GroundPreview(geometry)
        odometer = 0.0  # travelled distance [m]: the measured wheel-based speed integrated per cycle
        last_now: float | None = None
        preview_cpu_s: list[float] = []
        slope = WindowSlope(s.rate_window_s)
        t_loop = loop.now_s
        seq = 0
        counts = {"references_outside_strokes": 0, "refused": 0, "setpoints_rejected": 0, "fallbacks": 0}
        notes: list[str] = []
        events: list[str] = []
        cycle_s: list[float] = []
        cycle_cpu_s: list[float] = []
        rows: list[tuple[Any, ...]] = []
        n_events = len(loop.events)
        while loop.now_s < duration - 1e-9:
            now = loop.now_s
            dist = loop.sensors.ground_distance(now)
            ls = loop.rig.link.latest_state()
            ground = z_meas = None
            if ls is not None:
                z_meas = float(ls.pose.controlled()[1])
            if dist is not None and z_meas is not None:
                ground = z_meas - dist + drop
            ground_ahead = None
            if preview is not None and front is not None:
                readings = loop.decoder.readings(now)
                v = readings.speed.value if not readings.speed.stale else None
                att = loop.sensors.attitude(now)
                c0 = time.thread_time()
                if v is None or att is None:
                    preview.reset()  # no odometer or no pitch: the buffer cannot be placed
                else:
                    odometer += float(v) * (0.0 if last_now is None else now - last_now)
                    tool = None if ground is None else ground - drop + pivot  # ρ at the tool, from the T sensor
                    preview.add(odometer, att[1], front.config.height_m - front.read(now), tool)
                    at = odometer + float(v) * s.preview_lead_s
                    if ground is not None and preview.ready(at):
                        ground_ahead = preview.ground_at_tool(at) + drop - pivot
                preview_cpu_s.append(time.thread_time() - c0)
            last_now = now
            dr = loop.decoder.draft(now)
            sample = source.last
            slip = None if sample is None else sample.slip
            w0, c0 = time.perf_counter(), time.thread_time()
            st = work.step(
                now,
                s.z_m,
                draft_n=dr.value,
                draft_t=dr.received_s,
                slip=slip,
                ground_z=ground,
                ground_ahead_z=ground_ahead,
                z_measured=z_meas,
                z_range=z_range,
            )
            cycle_s.append(time.perf_counter() - w0)
            cycle_cpu_s.append(time.thread_time() - c0)
            if st.event is not None:
                counts["fallbacks"] += 1
                events.append(f"t = {now - t_loop:.2f} s: {st.event}")
                loop.events.append({"event": "work_fallback", "reason": st.fallback, "t": now})
            seq += 1
            try:
                mc.track_setpoint(session, seq, {"z": st.z}, {"z": slope.add(now, st.z)})
            except MotionError as exc:
                counts["setpoints_rejected"] += 1
                _note(notes, f"setpoint rejected: {exc}")
            loop.cycle()
            q = loop.streamed_actuators()
            if q is not None and (np.any(q < model.lower - 1e-9) or np.any(q > model.upper + 1e-9)):
                counts["references_outside_strokes"] += 1
            last = source.last
            if last is None:
                continue
            rows.append(
                (
                    loop.now_s - t_loop,
                    st.z,
                    float(loop.truth_pose()[1]),
                    math.nan if ground is None else ground,
                    last.depth_m,
                    last.draft_n,
                    math.nan if dr.value is None else dr.value,
                    last.resistance,
                    last.slip,
                    st.active,
                    _reference_z(loop.state),
                    math.nan if ground_ahead is None else ground_ahead,
                )
            )
        for e in loop.events[n_events:]:
            if e.get("event") == "limit_reached" and "limits" not in e:
                counts["refused"] += 1
                _note(notes, f"reference refused: {e.get('message')}")
        faults = tuple(loop.rig.link.faults.reasons)
    ts = np.array([r[0] for r in rows])
    res = np.array([r[7] for r in rows])
    return FieldLoopResult(
        field=fs.name,
        mode=s.work.mode,
        settings=s.work,
        t=ts,
        z_operator=np.full(len(rows), s.z_m),
        z_setpoint=np.array([r[1] for r in rows]),
        z_true=np.array([r[2] for r in rows]),
        ground_z=np.array([r[3] for r in rows]),
        depth=np.array([r[4] for r in rows]),
        draft=np.array([r[5] for r in rows]),
        draft_measured=np.array([r[6] for r in rows]),
        resistance=res,
        slip=np.array([r[8] for r in rows]),
        active=tuple(r[9] for r in rows),
        z_reference=np.array([r[10] for r in rows]),
        evaluated=ts >= s.settle_s - 1e-9,
        heavy=res >= heavy_at,
        cycle_s=np.array(cycle_s),
        cycle_cpu_s=np.array(cycle_cpu_s),
        events=tuple(events),
        counts=counts,
        faults=faults,
        notes=tuple(notes),
        ground_ahead_z=np.array([r[11] for r in rows]),
        preview_cpu_s=np.array(preview_cpu_s),
    )


def _reference_z(state: dict[str, Any] | None) -> float:
    ref = (state or {}).get("reference")
    return float(ref["pose"]["z"]) if ref else math.nan


def plot_field(path: str, results: list[FieldLoopResult], title: str | None = None) -> None:
    """Depth, draft and slip over time of one or more runs (same field) into a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(4, 1, figsize=(10, 9), sharex=True)
    for r in results:
        label = r.mode if r.settings.slip_limit is None else f"{r.mode} + slip ≤ {r.settings.slip_limit:g}"
        if r.mode == "mixed":
            label += f" {r.settings.blend:g}"
        ax[0].plot(r.t, r.depth * 100, lw=0.9, label=label)
        ax[1].plot(r.t, r.draft / 1e3, lw=0.9, label=label)
        ax[2].plot(r.t, r.slip * 100, lw=0.9, label=label)
    r0 = results[0]
    ax[3].plot(r0.t, r0.resistance, color="k", lw=0.9, label="soil factor")
    ax[3].fill_between(r0.t, 0.0, 1.0, where=r0.heavy, color="tab:red", alpha=0.15, label="heavy patch")
    lim = r0.settings
    for a in (ax[0],):
        a.axhline(lim.depth_min_m * 100, color="grey", ls=":", lw=0.8)
        a.axhline(lim.depth_max_m * 100, color="grey", ls=":", lw=0.8)
    for r in results:
        if r.settings.slip_limit is not None:
            ax[2].axhline(r.settings.slip_limit * 100, color="tab:red", ls="--", lw=0.8)
    ax[0].set_ylabel("true depth [cm]")
    ax[1].set_ylabel("true draft [kN]")
    ax[2].set_ylabel("slip [%]")
    ax[3].set_ylabel("soil factor")
    ax[3].set_ylim(min(0.6, float(np.min(r0.resistance)) - 0.05), max(1.4, float(np.max(r0.resistance)) + 0.05))
    ax[3].set_xlabel("t [s]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(loc="upper right", fontsize=7)
    ax[0].set_title(title or f"field {r0.field}: work control")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
