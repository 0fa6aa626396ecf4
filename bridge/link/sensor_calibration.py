"""Sensor calibration over the link: drive each cylinder slowly to both end stops, fit the AD map.

The AD map of a cylinder (profile ``[actuators.*] counts_min / counts_max`` over the physical
stroke ``min / max`` in SI) is what this procedure measures. It runs over a
:class:`~bridge.link.can_link.CanLink` and nothing else: references out, readings and the ECU's
system state in.

**The calibration link.** Before calibration the nominal map is only approximately right, so a
reference at a nominal stroke end may stop short of the true end. The link is therefore built on
:func:`calibration_profile`: the nominal profile with every stroke extended *on the same linear
map* by ``reach`` counts at each end (offset 3 + 2.5 % of the span + 1, inside 0…1023; for the
lift at most so far that its travel spans 250 counts, the finest the rear hitch status resolves
to a whole count). Its hard limits (strokes, top-link angles, ground clearance) stay in force.
The ECU's lift position (a fraction of its configured travel) must be configured with the same
calibration profile.

**End stops.** The ECU protects each cylinder with its end-stop relay (thesis §2.3.1): a reading
at or beyond a limit ``m`` counts inside a stroke end blocks commands further out, and its system
state reports the relay (bit 2, any cylinder). The relay sits ``m = max(2, ceil(1 % of the
span))`` counts inside the stroke ends (the ECU's firmware rule; :class:`RelayRule`).

**The procedure**, per actuator in profile order, each end in turn (low, then high), the other
four held at the neutral pose: a step reference to ``approach`` counts inside the nominal end (the
largest possible calibration error plus the relay margin, so the relay is not reached at speed),
then a creep: every control period the reference is set ``lead`` counts (1) beyond the latest
reading, so the piston moves at the unit controller's one-count speed (a few counts per second)
and coasts less than a count when the relay blocks. The end is found when the reading has not
changed for ``stall_s`` while the relay is reported; that reading is the relay limit, and the
stroke end is it ∓ ``m`` (``m`` solved with the span it implies). Then the actuator returns to
neutral. A stall without the relay, or reaching the calibration link's reach, is an error.

**Safety.** Before an actuator moves, its full calibration stroke (the others at neutral) is
checked against the hard limits and, through a :class:`~planner.limits.guard.Guard` with the
implement, the tractor's stability (hard thresholds), the keep-out spheres and the implement's
upper height; any violation refuses the calibration of that actuator, naming the limit.

**Detached.** The top-link angle limits (``top_link_yaw_*``, ``top_link_pitch_*``) exist because the
top link is pinned to the implement's mast. ``detached=True`` is the operator's declaration that no
implement is attached and the top link is unpinned at the mast (hanging in its rest, or removed):
then those angles do not bind, and :func:`calibration_profile` releases them to the widest the
profile schema allows (:data:`DETACHED_RELEASED_LIMITS`, π/2 rad each way, beyond any stroke of
the thesis profile) — for the safety check and for the link's own reference check alike, so the two
agree. Every other limit stays: each cylinder's stroke (the calibration reach, the ECU's end-stop
relay), the lower links' ground clearance (they still swing on the lift arms), the keep-out spheres,
the tractor's stability (without an implement) and the upper height. A detached calibration with an
implement is refused.

**Resumable.** ``progress`` (a JSON file) records each end as it is found, and the machine it was
found on (``machine``: the ECU's ISO 11783 NAME, or the twin's truth); a new run with the same file
skips what is recorded, says what it kept, and refuses a file recorded on another machine (its ends
are not this machine's). :func:`sensor_profile_toml` writes the result: the source
profile's TOML text with the fitted ``counts_min / counts_max`` put in (everything else as it
was), which loads with :func:`~planner.profiles.hitch.load_profile`.
"""

from __future__ import annotations

import datetime as _dt
import importlib.resources
import json
import math
import os
import re
import tomllib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

from bridge.link.can_link import CanLink
from bridge.link.realtime import RealtimeRunner
from bridge.link.state import LinkFaultError, ReferenceRefused
from planner.errors import HitchInputError
from planner.filelock import LockHeldError, take_lock
from planner.limits.guard import Guard
from planner.limits.tractor import ImplementRecord
from planner.model.hard_limits import HardLimits
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES, KinematicsError
from planner.profiles.hitch import Profile, profile_from_dict, tractor_profile_for
from planner.trajectory import TrajectoryPlanner

__all__ = [
    "DETACHED_RELEASED_LIMITS",
    "EndReading",
    "LinkDriver",
    "RealtimeDriver",
    "RelayRule",
    "SensorCalibration",
    "SensorCalibrationError",
    "SensorCalibrationSettings",
    "SensorFit",
    "calibration_profile",
    "check_full_stroke",
    "fit_sensor",
    "full_stroke_hold",
    "sensor_profile_toml",
    "SENSOR_PROVENANCE_MARKER",
]

_AD_MAX = 1023
_LIFT_MAX_SPAN = 250  # the rear hitch status resolves a whole count up to this travel
_PROGRESS_VERSION = 1
#: The profile limits a detached calibration (no implement, top link unpinned at the mast) releases:
#: the top-link angles, which only the implement's mast imposes.
DETACHED_RELEASED_LIMITS: tuple[str, ...] = ("top_link_yaw_max", "top_link_pitch_up_max", "top_link_pitch_down_max")
_RELEASED_ANGLE_RAD = math.pi / 2  # the widest the profile schema allows


class SensorCalibrationError(HitchInputError):
    """A sensor calibration that cannot run or was refused; the message names the actuator and the limit."""


class LinkDriver(Protocol):
    """What advances the link's time: a simulated rig (``bridge.sim.rig.SimRig``) or a real-time runner."""

    @property
    def now_s(self) -> float: ...

    def tick(self) -> float:
        """Advance time by one tick, polling the link; returns the new time [s]."""
        ...


class RealtimeDriver:
    """A :class:`LinkDriver` on the wall clock, for a real ECU: the link runs in its
    :class:`~bridge.link.realtime.RealtimeRunner`'s thread; a tick waits ``tick_s`` of real time."""

    def __init__(self, runner: RealtimeRunner, tick_s: float = 0.01) -> None:
        if not 0.001 <= tick_s <= 0.1:
            raise SensorCalibrationError(f"tick_s must lie in [0.001, 0.1] s, got {tick_s!r}")
        self._runner = runner
        self._tick_s = float(tick_s)

    @property
    def now_s(self) -> float:
        return self._runner.now()

    def tick(self) -> float:
        """Wait one tick; :class:`SensorCalibrationError` when the link's loop has ended (its error named)."""
        if self._runner.wait(self._tick_s):
            err = self._runner.error
            raise SensorCalibrationError(f"the CAN link stopped{'' if err is None else f': {err!r}'}")
        return self.now_s


@dataclass(frozen=True)
class RelayRule:
    """Where the ECU's end-stop relay sits inside the stroke ends: ``max(min_counts, ceil(fraction · span))``."""

    fraction: float = 0.01
    min_counts: int = 2

    def margin(self, span_counts: int) -> int:
        return max(self.min_counts, math.ceil(self.fraction * span_counts - 1e-12))


@dataclass(frozen=True)
class SensorCalibrationSettings:
    """Settings of the procedure (module docstring).

    Attributes:
        offset_counts: largest AD offset the nominal map may have [counts].
        gain: largest relative AD gain error the nominal map may have.
        lead_counts: how far the creeping reference leads the reading [counts].
        stall_s: a reading unchanged this long (with the relay reported) is an end stop [s].
        settle_s: a step reference is reached once the reading stayed within a count this long [s].
        max_end_s: longest time for one end (approach and creep) [s].
        relay: the ECU's relay rule.
    """

    offset_counts: int = 3
    gain: float = 0.02
    lead_counts: int = 1
    stall_s: float = 1.0
    settle_s: float = 0.4
    max_end_s: float = 120.0
    relay: RelayRule = RelayRule()

    def __post_init__(self) -> None:
        for name, ilo, ihi in (("offset_counts", 0, 50), ("lead_counts", 1, 10)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not ilo <= v <= ihi:
                raise SensorCalibrationError(f"{name} must be an integer in [{ilo}, {ihi}], got {v!r}")
        for name, lo, hi in (
            ("gain", 0.0, 0.2),
            ("stall_s", 0.1, 30.0),
            ("settle_s", 0.05, 10.0),
            ("max_end_s", 1.0, 3600.0),
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and lo <= v <= hi):
                raise SensorCalibrationError(f"{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")

    def band_counts(self, span: int) -> int:
        """How far a true stroke end may lie from the nominal one [counts]."""
        return self.offset_counts + math.ceil(self.gain * span)

    def reach_counts(self, name: str, counts_min: int, counts_max: int) -> tuple[int, int]:
        """How far the calibration link reaches beyond the nominal (low, high) ends [counts]."""
        span = counts_max - counts_min
        ext = self.offset_counts + math.ceil(1.25 * self.gain * span) + 1
        lo, hi = min(ext, counts_min), min(ext, _AD_MAX - counts_max)
        if name == "lift":
            room = max(0, _LIFT_MAX_SPAN - 1 - span)
            lo, hi = min(lo, room // 2), min(hi, room - room // 2)
        return lo, hi


def calibration_profile(
    nominal: Profile, settings: SensorCalibrationSettings | None = None, *, detached: bool = False
) -> Profile:
    """The nominal profile with every stroke extended on its own AD map by the reach (module docstring);
    ``detached``: also with the top-link angle limits released (:data:`DETACHED_RELEASED_LIMITS`)."""
    if not isinstance(detached, bool):
        raise SensorCalibrationError(f"detached must be true or false, got {detached!r}")
    s = settings if settings is not None else SensorCalibrationSettings()
    data = nominal.model_dump(mode="python")
    data["name"] = f"{nominal.name}-calibration{'-detached' if detached else ''}"[:80]
    if detached:
        for name in DETACHED_RELEASED_LIMITS:
            data["limits"][name] = _RELEASED_ANGLE_RAD
    for name in ACTUATOR_NAMES:
        spec = data["actuators"][name]
        cmin, cmax = int(spec["counts_min"]), int(spec["counts_max"])
        res = (float(spec["max"]) - float(spec["min"])) / (cmax - cmin)
        lo, hi = s.reach_counts(name, cmin, cmax)
        spec["counts_min"], spec["counts_max"] = cmin - lo, cmax + hi
        spec["min"], spec["max"] = float(spec["min"]) - lo * res, float(spec["max"]) + hi * res
    return profile_from_dict(data, source=f"calibration profile of {nominal.name}")


def check_full_stroke(
    actuator: str,
    model: HitchModel,
    hold: ArrayLike,
    guard: Guard,
    *,
    stroke: tuple[float, float] | None = None,
    samples: int = 41,
) -> None:
    """Refuse (:class:`SensorCalibrationError`, naming the limit) if a full-stroke motion of ``actuator``
    of ``model`` (the calibration model) over ``stroke`` (SI; default its whole stroke), the others at
    ``hold`` (SI), violates a hard limit, the
    guard's stability (hard thresholds), a keep-out sphere or the implement's upper height."""
    i = ACTUATOR_NAMES.index(actuator)
    hard = HardLimits.from_model(model)
    lo, hi = (float(model.lower[i]), float(model.upper[i])) if stroke is None else stroke
    upper = guard.implement_limits.upper_height_m
    for v in np.linspace(lo, hi, samples):
        q = np.array(hold, dtype=float)
        q[i] = v
        where = f"{actuator} = {v:.4f} {'rad' if actuator == 'lift' else 'm'}"
        try:
            feats, _ = model.features(q)
            state = model.forward(q)
        except KinematicsError as exc:
            raise SensorCalibrationError(
                f"sensor calibration of {actuator} refused: the mechanism cannot close at {where} ({exc})"
            ) from None
        bad = [n for n in hard.violations(q, feats, tol=1e-9) if not n.startswith("stroke:")]
        if bad:
            detach = (
                "; with no implement attached and the top link unpinned at the mast, --detached releases the "
                "top-link angle limits (docs/commissioning.md)"
                if any(n.startswith("top_link_") for n in bad)
                else ""
            )
            raise SensorCalibrationError(
                f"sensor calibration of {actuator} refused: {', '.join(bad)} at {where}{detach}"
            )
        rep = guard.stability_at(q, state.points)
        for viol in rep.violations:
            if viol.level == "hard":
                raise SensorCalibrationError(
                    f"sensor calibration of {actuator} refused: stability {viol.measure} = {viol.value:.4g} "
                    f"below its threshold {viol.threshold:.4g} at {where}"
                )
        for name, dist, radius in guard.keep_out_clearance(q, state.points):
            if dist < radius:
                raise SensorCalibrationError(
                    f"sensor calibration of {actuator} refused: keep_out:{name} "
                    f"({dist:.3f} m < {radius:.3f} m) at {where}"
                )
        if upper is not None and float(state.pose.z) > float(upper):
            raise SensorCalibrationError(
                f"sensor calibration of {actuator} refused: implement upper height {float(state.pose.z):.3f} m "
                f"above {float(upper):.3f} m at {where}"
            )


def full_stroke_hold(
    actuator: str,
    model: HitchModel,
    neutral: ArrayLike,
    guard: Guard,
    stroke: tuple[float, float] | None = None,
) -> np.ndarray:
    """Where to hold the other four actuators while ``actuator`` travels its full stroke: ``neutral`` if
    :func:`check_full_stroke` passes there, else the first safe hold that moves one other actuator to one of
    nine points inside its stroke (nearest to neutral first). Refuses with the reason at ``neutral`` if none is safe."""
    base = np.asarray(neutral, dtype=float).reshape(5)
    i = ACTUATOR_NAMES.index(actuator)
    try:
        check_full_stroke(actuator, model, base, guard, stroke=stroke)
        return base
    except SensorCalibrationError as exc:
        first = exc
    candidates: list[tuple[float, np.ndarray]] = []
    for j in range(5):
        if j == i:
            continue
        lo, hi = float(model.lower[j]), float(model.upper[j])
        for v in np.linspace(lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo), 9):
            q = base.copy()
            q[j] = v
            candidates.append((abs(v - base[j]) / (hi - lo), q))
    for _, q in sorted(candidates, key=lambda c: c[0]):
        try:
            check_full_stroke(actuator, model, q, guard, stroke=stroke)
        except SensorCalibrationError:
            continue
        return q
    raise first


@dataclass(frozen=True)
class EndReading:
    """The reading [counts] at which one end stopped, and what stopped it ("relay")."""

    counts: int
    stopped_by: str


@dataclass(frozen=True)
class SensorFit:
    """The fitted AD map of one actuator: counts at the stroke's ``min`` and ``max`` and the relay margin used."""

    actuator: str
    counts_min: int
    counts_max: int
    relay_margin_counts: int
    low: EndReading
    high: EndReading

    def as_dict(self) -> dict[str, Any]:
        return {
            "counts_min": self.counts_min,
            "counts_max": self.counts_max,
            "relay_margin_counts": self.relay_margin_counts,
            "low": {"counts": self.low.counts, "stopped_by": self.low.stopped_by},
            "high": {"counts": self.high.counts, "stopped_by": self.high.stopped_by},
        }


def fit_sensor(actuator: str, low: EndReading, high: EndReading, relay: RelayRule = RelayRule()) -> SensorFit:
    """The AD map from the two relay readings: the stroke ends lie the relay margin ``m`` outside them,
    with ``m`` the relay rule of the span they imply (the smallest consistent ``m``)."""
    inner = high.counts - low.counts
    if inner <= 0:
        raise SensorCalibrationError(f"{actuator}: high end reading {high.counts} is not above the low {low.counts}")
    for m in range(relay.min_counts, 200):
        if relay.margin(inner + 2 * m) == m:
            cmin, cmax = low.counts - m, high.counts + m
            if not 0 <= cmin < cmax <= _AD_MAX:
                raise SensorCalibrationError(f"{actuator}: fitted map [{cmin}, {cmax}] leaves the 10-bit range 0…1023")
            return SensorFit(actuator, cmin, cmax, m, low, high)
    raise SensorCalibrationError(
        f"{actuator}: no relay margin is consistent with the readings {low.counts}, {high.counts}"
    )


class SensorCalibration:
    """The procedure (module docstring) over ``link`` (built on :func:`calibration_profile` of
    ``nominal``, with the same ``detached``), advanced by ``driver``; ``progress``: JSON file to resume
    from and record to. ``detached``: the operator's declaration that no implement is attached and the
    top link is unpinned at the mast (module docstring); refused together with an ``implement``."""

    def __init__(
        self,
        link: CanLink,
        driver: LinkDriver,
        nominal: Profile,
        *,
        settings: SensorCalibrationSettings | None = None,
        implement: ImplementRecord | None = None,
        progress: str | Path | None = None,
        log: Callable[[str], None] | None = None,
        detached: bool = False,
        machine: str | None = None,
    ) -> None:
        if not isinstance(detached, bool):
            raise SensorCalibrationError(f"detached must be true or false, got {detached!r}")
        if detached and implement is not None:
            raise SensorCalibrationError(
                f"detached declares that no implement is attached: it cannot go with the implement {implement.name!r}"
            )
        self.settings = s = settings if settings is not None else SensorCalibrationSettings()
        self.detached = detached
        expected = calibration_profile(nominal, s, detached=detached)
        if link.model.profile != expected:
            raise SensorCalibrationError(
                f"the link must be built on calibration_profile(nominal, detached={detached}): its strokes reach "
                "beyond the nominal ends" + (" and its top-link angle limits are released" if detached else "")
            )
        self.link, self.driver, self.nominal = link, driver, nominal
        self.model = link.model
        self._scaling = SensorScaling(expected)
        self._nominal_scaling = SensorScaling(nominal)
        nominal_model = HitchModel(nominal, link.model.category)
        tp = TrajectoryPlanner(nominal_model)
        self.hold = np.asarray(tp.inverse.solve(nominal_model.neutral_pose.controlled())[0], dtype=float)
        self.guard = Guard(tp, implement=implement)
        self.progress_path = Path(progress) if progress is not None else None
        self._log = log if log is not None else (lambda _msg: None)
        self._lock_fd = _lock_progress(self.progress_path) if self.progress_path is not None else None
        self.progress: dict[str, Any] = {"version": _PROGRESS_VERSION, "profile": nominal.name, "actuators": {}}
        if self.progress_path is not None and self.progress_path.is_file():
            try:
                self._load_progress()
                self._check_machine(machine)
            except BaseException:  # refused: the file is not held on
                self.close()
                raise
        if machine is not None:
            self.progress["machine"] = machine
        self.progress["detached"] = detached  # the state the operator declared for this run (a record only)

    # -- progress ---------------------------------------------------------------------
    def _load_progress(self) -> None:
        assert self.progress_path is not None
        try:
            data = json.loads(self.progress_path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as exc:
            raise SensorCalibrationError(f"progress file {self.progress_path}: cannot read it ({exc})") from None
        if (
            not isinstance(data, dict)
            or data.get("version") != _PROGRESS_VERSION
            or not isinstance(data.get("actuators"), dict)
        ):
            raise SensorCalibrationError(
                f"progress file {self.progress_path}: not a version-{_PROGRESS_VERSION} sensor calibration"
            )
        if data.get("profile") != self.nominal.name:
            raise SensorCalibrationError(
                f"progress file {self.progress_path} is for profile {data.get('profile')!r}, not {self.nominal.name!r}"
            )
        for name, ends in data["actuators"].items():
            if name not in ACTUATOR_NAMES or not isinstance(ends, dict):
                raise SensorCalibrationError(f"progress file {self.progress_path}: unknown actuator {name!r}")
            for end, rec in ends.items():
                if end == "fit":  # the fit a run wrote after both ends (refitted from the ends on resume)
                    ok = isinstance(rec, dict) and all(
                        isinstance(rec.get(k), int) and not isinstance(rec.get(k), bool) and 0 <= rec[k] <= _AD_MAX
                        for k in ("counts_min", "counts_max")
                    )
                else:
                    ok = (
                        end in ("low", "high")
                        and isinstance(rec, dict)
                        and isinstance(rec.get("counts"), int)
                        and not isinstance(rec.get("counts"), bool)
                        and 0 <= rec["counts"] <= _AD_MAX
                    )
                if not ok:
                    raise SensorCalibrationError(f"progress file {self.progress_path}: bad record {name}.{end}")
        self.progress = data

    def _check_machine(self, machine: str | None) -> None:
        """A loaded progress file's ends are this machine's (or refused), and the operator is told what is kept."""
        recorded, kept = self.progress.get("machine"), self.progress["actuators"]
        if kept and recorded != machine:  # also when either is unknown: the ends may be another machine's
            this = (
                f"not on {machine}"
                if machine
                else "and this machine is not named (the ECU did not answer with its ISO 11783 NAME)"
            )
            raise SensorCalibrationError(
                f"progress file {self.progress_path} was recorded on {recorded or 'a machine not named'}, {this}: "
                "its end readings may be another machine's (delete the file or give another --progress to start "
                "afresh)"
            )
        if kept:
            ends = ", ".join(f"{a} {e}" for a, rec in kept.items() for e in ("low", "high") if e in rec)
            self._log(
                f"resuming from {self.progress_path} (recorded {self.progress.get('saved', 'at an unknown time')} "
                f"on {recorded or 'an unnamed machine'}): keeping {ends or 'nothing'}"
            )

    def _save_progress(self) -> None:
        if self.progress_path is None:
            return
        self.progress["saved"] = _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
        tmp = self.progress_path.with_suffix(self.progress_path.suffix + ".tmp")
        try:
            tmp.write_text(json.dumps(self.progress, indent=1), encoding="utf-8")
            tmp.replace(self.progress_path)
        except OSError as exc:
            raise SensorCalibrationError(
                f"progress file {self.progress_path}: cannot write it ({exc.strerror})"
            ) from None

    # -- motion -----------------------------------------------------------------------
    def _si(self, counts: np.ndarray) -> np.ndarray:
        sc = self._scaling
        return sc.si_min + (np.asarray(counts, dtype=float) - sc.counts_min) * sc.resolution

    def _counts_of(self, q: np.ndarray) -> np.ndarray:
        sc = self._scaling
        return np.round(sc.counts_min + (np.asarray(q, dtype=float) - sc.si_min) / sc.resolution)

    def _reading(self) -> tuple[np.ndarray, bool]:
        st = self.link.latest_state()
        if st is None:
            raise SensorCalibrationError("no measurement from the ECU")
        return np.rint(np.asarray(st.counts, dtype=float)), bool(st.system.end_stop_relay)

    def _send(self, counts: np.ndarray) -> None:
        try:
            self.link.send_reference(self._si(counts), self.driver.now_s)
        except (ReferenceRefused, LinkFaultError) as exc:
            raise SensorCalibrationError(f"sensor calibration stopped: {exc}") from None

    def _check_streaming(self, what: str) -> None:
        """Stop at once when the link no longer streams the references (a latched link fault: the ECU's watchdog
        has zeroed the valves and nothing moves): the wait would run to ``max_end_s`` and blame the reading (a
        remote bus's fault: "the approach to 242 counts not reached within 120 s … the calibration link's lift
        travel"). Names the fault's reason and how to resume; the ends found so far stay recorded."""
        faults = self.link.faults
        if self.link.streaming and not faults.any:
            return
        reason = "; ".join(dict.fromkeys(faults.reasons)) if faults.any else ""
        if not reason:
            reason = ", ".join(faults.active()) if faults.any else "the stream was stopped"
        if self.progress_path is None:
            resume = "without --progress the ends found so far are not kept (with --progress FILE a calibration "
            resume += "resumes where it stopped)"
        elif self.progress["actuators"] and any(self.progress["actuators"].values()):
            resume = f"the ends found so far are kept in {self.progress_path}: resume with the same command"
        else:
            resume = f"no end was found yet; resume with the same command (--progress {self.progress_path})"
        raise SensorCalibrationError(
            f"sensor calibration stopped during {what}: the link stopped streaming references: {reason}; "
            f"{resume} once the link is sound"
        )

    def _step_to(self, ref: np.ndarray, what: str) -> bool:
        """Step reference ``ref`` (counts); True once reached (within a count, still), False if the relay stopped it;
        a :class:`SensorCalibrationError` at once when the link stops streaming (:meth:`_check_streaming`)."""
        s = self.settings
        self._send(ref)
        t0 = self.driver.now_s
        still_since, last = t0, self._reading()[0]
        while self.driver.now_s - t0 < s.max_end_s:
            self.driver.tick()
            self._check_streaming(what)
            r, relay = self._reading()
            if not np.array_equal(r, last):
                still_since, last = self.driver.now_s, r
            elif self.driver.now_s - still_since >= s.settle_s:
                if np.all(np.abs(r - ref) <= 1):
                    return True
                if relay:
                    return False
        apart = [
            f"{name} reads {int(r)} counts, reference {int(q)}"
            for name, r, q in zip(ACTUATOR_NAMES, last, ref, strict=True)
            if abs(r - q) > 1
        ]
        hint = ""
        if any(a.startswith("lift ") for a in apart):
            lift = self.model.profile.actuator("lift")
            hint = (
                "; the lift's reading is the rear hitch position, a fraction of the travel the ECU is configured "
                f"with: for this calibration that must be the calibration link's lift travel, counts "
                f"{lift.counts_min} … {lift.counts_max} (hitch ecu-sim --sensor-calibration), not the nominal one"
            )
        raise SensorCalibrationError(
            f"sensor calibration: {what} not reached within {s.max_end_s:g} s ({'; '.join(apart) or 'still moving'})"
            + hint
        )

    def _find_end(self, i: int, direction: int, hold_counts: np.ndarray) -> EndReading:
        s, name = self.settings, ACTUATOR_NAMES[i]
        cal = self._scaling
        nmin, nmax = int(self._nominal_scaling.counts_min[i]), int(self._nominal_scaling.counts_max[i])
        span = nmax - nmin
        inside = s.band_counts(span) + s.relay.margin(span + s.band_counts(span)) + 2
        ref = hold_counts.copy()
        ref[i] = (nmin + inside) if direction < 0 else (nmax - inside)
        if not self._step_to(ref, f"{name}: the approach to {int(ref[i])} counts"):
            raise SensorCalibrationError(
                f"{name}: the end-stop relay stopped the approach at {int(self._reading()[0][i])} counts: the stroke "
                f"end is further than {s.band_counts(span)} counts from the nominal map"
            )
        limit = float(cal.counts_min[i]) if direction < 0 else float(cal.counts_max[i])
        period = self.link.config.control_period_s
        t0 = self.driver.now_s
        last, changed_s = self._reading()[0][i], t0
        next_send = t0
        while self.driver.now_s - t0 < s.max_end_s:
            if self.driver.now_s >= next_send - 1e-9:
                r_all = self._reading()[0]
                ref = hold_counts.copy()
                ref[i] = min(max(r_all[i] + direction * s.lead_counts, cal.counts_min[i]), cal.counts_max[i])
                self._send(ref)
                next_send = self.driver.now_s + period
            self.driver.tick()
            self._check_streaming(f"{name}: the creep to its {'low' if direction < 0 else 'high'} end")
            r_all, relay = self._reading()
            if r_all[i] != last:
                last, changed_s = r_all[i], self.driver.now_s
            elif self.driver.now_s - changed_s >= s.stall_s:
                if relay:
                    return EndReading(int(last), "relay")
                if abs(last - limit) <= 0.5:
                    raise SensorCalibrationError(
                        f"{name}: reached the calibration reach ({int(limit)} counts) without an end stop"
                    )
                raise SensorCalibrationError(
                    f"{name}: stalled at {int(last)} counts without the end-stop relay (blocked cylinder, valve?)"
                )
        raise SensorCalibrationError(f"{name}: no end stop within {s.max_end_s:g} s")

    # -- the procedure ----------------------------------------------------------------
    def stroke(self, actuator: str) -> tuple[float, float]:
        """The nominal stroke of ``actuator`` (SI): the full-stroke motion the safety check covers."""
        spec = self.nominal.actuator(actuator)
        return float(spec.min), float(spec.max)

    def run(self, actuators: Sequence[str] = ACTUATOR_NAMES) -> dict[str, SensorFit]:
        """Calibrate ``actuators`` (default all five); returns their fits (recorded ends are reused). The progress
        file is this calibration's until it returns or raises (:meth:`close`)."""
        try:
            return self._run(actuators)
        finally:
            self.close()

    def close(self) -> None:
        """Give the progress file up to another calibration (idempotent; the process's exit does it too)."""
        fd, self._lock_fd = self._lock_fd, None
        if fd is not None:
            os.close(fd)

    def _run(self, actuators: Sequence[str]) -> dict[str, SensorFit]:
        unknown = [a for a in actuators if a not in ACTUATOR_NAMES]
        if unknown or not actuators:
            raise SensorCalibrationError(
                f"actuators: unknown or none {list(actuators)!r}; allowed {', '.join(ACTUATOR_NAMES)}"
            )
        holds = {a: full_stroke_hold(a, self.model, self.hold, self.guard, self.stroke(a)) for a in actuators}
        fits: dict[str, SensorFit] = {}
        for a in actuators:
            i = ACTUATOR_NAMES.index(a)
            hold_counts = self._counts_of(holds[a])
            rec = self.progress["actuators"].setdefault(a, {})
            for end, direction in (("low", -1), ("high", 1)):
                if end in rec:
                    self._log(f"{a} {end}: recorded {rec[end]['counts']} counts (resumed)")
                    continue
                self._step_to(hold_counts, f"{a}: the hold")
                found = self._find_end(i, direction, hold_counts)
                rec[end] = {"counts": found.counts, "stopped_by": found.stopped_by}
                self._save_progress()
                self._log(f"{a} {end}: {found.stopped_by} at {found.counts} counts")
            self._step_to(self._counts_of(self.hold), "neutral")
            fit = fit_sensor(
                a,
                EndReading(rec["low"]["counts"], rec["low"]["stopped_by"]),
                EndReading(rec["high"]["counts"], rec["high"]["stopped_by"]),
                self.settings.relay,
            )
            rec["fit"] = {"counts_min": fit.counts_min, "counts_max": fit.counts_max}
            self._save_progress()
            fits[a] = fit
        return fits


# -- output -----------------------------------------------------------------------------------
def _profile_text(profile: str | Path) -> str:
    p = Path(profile)
    if p.suffix == ".toml" or p.exists():
        return p.read_text(encoding="utf-8")
    return (importlib.resources.files("planner.profiles") / f"{profile}.toml").read_text(encoding="utf-8")


def _lock_progress(progress: Path) -> int:
    """Take ``<progress>.lock`` for this process (an flock, released when its descriptor closes): two calibrations
    on one progress file wrote each other's ends (a commissioning trial: a resume ran while the first run still
    wrote); :class:`SensorCalibrationError` naming the holder while another holds it."""
    lock = progress.with_name(progress.name + ".lock")
    try:
        return take_lock(lock)
    except LockHeldError as exc:
        raise SensorCalibrationError(
            f"progress file {progress} is in use by another sensor calibration ({exc.holder}): let it end (or stop "
            "it) before resuming, or give another --progress"
        ) from None
    except OSError as exc:
        raise SensorCalibrationError(
            f"progress file {progress}: cannot open its lock {lock} ({exc.strerror})"
        ) from None


#: start of the comment line that carries a sensor calibration's provenance (the loader ignores comments)
SENSOR_PROVENANCE_MARKER = "#! sensor_calibration ="


def sensor_profile_toml(
    source: str | Path,
    counts: Mapping[str, tuple[int, int]],
    *,
    provenance: Mapping[str, Any] | None = None,
    out_folder: str | Path | None = None,
) -> str:
    """The TOML text of profile ``source`` (built-in name or path) with ``counts_min / counts_max`` of the
    actuators in ``counts`` ({name: (counts_min, counts_max)}) replaced; the result is validated. A tractor
    profile the source names by a relative path is rewritten for ``out_folder``, the folder the text goes to
    (None: absolute): copied as it was, it pointed next to the output, not to the source.

    ``provenance`` (date, the machine it was calibrated on, the end readings …) is written as a comment line
    ``#! sensor_calibration = { … }`` at the top (an earlier one replaced): a commissioning record, and what
    tells a later geometry calibration that the AD maps were measured."""
    text = _profile_text(source)
    if provenance is not None:
        from planner.calibration.profile_out import toml_value

        kept = [ln for ln in text.splitlines(keepends=True) if not ln.startswith(SENSOR_PROVENANCE_MARKER)]
        text = f"{SENSOR_PROVENANCE_MARKER} {toml_value(dict(provenance))}\n" + "".join(kept)
    lines = text.splitlines(keepends=True)
    section = ""
    done: set[tuple[str, str]] = set()
    for k, line in enumerate(lines):
        head = re.match(r"\s*\[([^\]]+)\]", line)
        if head:
            section = head.group(1).strip()
            continue
        tp = re.match(r"(\s*tractor_profile\s*=\s*)(\"[^\"]*\"|'[^']*')(.*)", line, re.DOTALL)
        if tp and section == "stability":
            from planner.calibration.profile_out import toml_value

            given = tomllib.loads(f"v = {tp.group(2)}")["v"]
            folder = Path(source).parent if Path(source).suffix == ".toml" or Path(source).exists() else None
            new = tractor_profile_for(given, out_folder, relative_to=folder)
            lines[k] = f"{tp.group(1)}{toml_value(new)}{tp.group(3)}" if new != given else line
            continue
        m = re.match(r"(\s*)(counts_min|counts_max)(\s*=\s*)(\d+)(.*)", line, re.DOTALL)
        if m and section.startswith("actuators."):
            name = section.split(".", 1)[1]
            if name in counts:
                v = counts[name][0 if m.group(2) == "counts_min" else 1]
                lines[k] = f"{m.group(1)}{m.group(2)}{m.group(3)}{int(v)}{m.group(5)}"
                done.add((name, m.group(2)))
    missing = [f"{n}.{f}" for n in counts for f in ("counts_min", "counts_max") if (n, f) not in done]
    if missing:
        raise SensorCalibrationError(f"profile {source}: no line for {', '.join(missing)} to write")
    out = "".join(lines)
    try:
        profile_from_dict(tomllib.loads(out), source=f"calibrated {source}")
    except (HitchInputError, tomllib.TOMLDecodeError) as exc:
        raise SensorCalibrationError(f"the calibrated profile does not validate: {exc}") from None
    return out
