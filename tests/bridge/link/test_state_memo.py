"""The assembler reuses the last solved readings only when they repeat: every state is still the
forward kinematics of its own quantised readings, and a failing reading fails every time."""

import random

import numpy as np

from bridge.isobus.codec import PositionMeasurement, RearHitchStatus
from bridge.link.state import LinkConfig, MeasurementAssembler, lift_counts_from_fraction
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import HitchState, KinematicsError


class _PickyModel:
    """The model, except that a tilt above ``limit_m`` "does not close the mechanism" (a pure function)."""

    def __init__(self, model: HitchModel, limit_m: float) -> None:
        self._model, self._limit_m = model, limit_m
        self.profile = model.profile  # the valve gains: how fast a reading can move

    def forward(self, q: np.ndarray) -> HitchState:
        if q[1] > self._limit_m:
            raise KinematicsError(f"tilt {q[1]:.4f} m above {self._limit_m:.4f} m")
        return self._model.forward(q)


def test_every_state_is_the_kinematics_of_its_readings_with_repeats_and_failures(model):
    scaling = SensorScaling(model.profile)
    neutral_si = scaling.to_si(scaling.to_counts(model.neutral))
    picky = _PickyModel(model, float(neutral_si[1]) + 0.002)
    cfg = LinkConfig(reading_rate_factor=0.0)  # readings jump anywhere at once: their motion's plausibility is
    bumps: dict[str, int] = {}  # tests/bridge/link/test_reading_plausibility.py's
    rx = MeasurementAssembler(
        picky,  # type: ignore[arg-type]  # duck-typed: forward and the profile
        scaling,
        cfg,
        lambda **d: [bumps.__setitem__(k, bumps.get(k, 0) + v) for k, v in d.items()],
    )
    rnd = random.Random(5)
    neutral = [int(c) for c in scaling.to_counts(model.neutral)]
    lo, hi = [int(np.ceil(c)) for c in scaling.counts_min], [int(np.floor(c)) for c in scaling.counts_max]

    def reading() -> list[int]:
        if rnd.random() < 0.3:  # anywhere in the span: some of these do not close the mechanism
            return [rnd.randint(lo[i], hi[i]) for i in range(5)]
        return [min(max(c + rnd.randint(-3, 3), lo[i]), hi[i]) for i, c in enumerate(neutral)]

    failures = solved = 0
    current = reading()
    meas: tuple[int, int, int, int] | None = None
    frac: float | None = None
    for k in range(600):
        if rnd.random() < 0.3:  # otherwise repeat the last readings, as at rest
            current = reading()
        t = k * 0.01
        before, fails_before = rx.state, bumps.get("kinematics_failures", 0)
        if k % 2:
            f = (current[0] - scaling.counts_min[0]) / (scaling.counts_max[0] - scaling.counts_min[0])
            frac = round(min(max(f, 0.0), 1.0) / 0.004) * 0.004
            rx.on_hitch_status(RearHitchStatus(position=frac), t)
        else:
            tilt, top, left, right = current[1:]
            meas = (tilt, top, left, right)
            rx.on_measurement(PositionMeasurement(tilt, top, right, left, system_state=1), t)
        if meas is None or frac is None:
            assert rx.state is None
            continue
        lift = lift_counts_from_fraction(
            frac, scaling.counts_min[0], scaling.counts_max[0], on_count_grid=cfg.lift_count_grid
        )
        expected = (lift, *(float(c) for c in meas))
        try:
            truth = picky.forward(scaling.to_si(expected, tolerance_counts=cfg.reading_tolerance_counts))
        except KinematicsError:
            assert rx.state is before  # kept the last good state ...
            assert bumps["kinematics_failures"] == fails_before + 1  # ... and counted this failure
            failures += 1
            continue
        assert rx.state is not None and rx.state.t_s == t and rx.state.counts == expected
        assert rx.state.actuators == truth.actuators and rx.state.pose == truth.pose  # exact, not close
        solved += 1
    assert solved > 200 and failures > 50
