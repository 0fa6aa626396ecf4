"""The service's motion controller streams the unit loops' feed-forward reference (in the product
path, not only in the closed-loop bench): a goto through the real CAN path (link + simulated ECU,
simulated time, cycles at 50 Hz) keeps to the straight pose line and ends within the closed loop's
steady-state targets.

Truth used: the straight segment start → goal in (x, z); the goal; the same run with the
plan's actuators streamed unshaped (the cylinders' different lags bend the path).
"""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.motion.controller import MotionController
from bridge.sim.move import SimRig
from planner.limits.guard import Guard
from planner.model.exact_inverse import ExactInverse
from planner.trajectory import TrajectoryPlanner

POSE = ("x", "z", "roll", "pitch")


def _goto_path(model, feedforward: bool):
    """Measured and true poses every 20 ms of a 200 mm diagonal goto (x 100 mm, z 173 mm)."""
    start = ExactInverse(model)(-0.05, 0.0, 0.0, 0.0)
    states: list[dict] = []
    with SimRig(model, initial_actuators=start) as rig:
        rig.start()
        rig.run_until(0.5)
        mc = MotionController(
            Guard(TrajectoryPlanner(model)),
            Guard(TrajectoryPlanner(model)),
            rig.link,
            lambda: rig.now_s,
            on_state=states.append,
            spawn=lambda fn: fn(),
            feedforward=feedforward,
        )
        mc.cycle()
        p0 = np.array([states[-1]["pose"][k] for k in POSE])
        acc = mc.goto({"x": 0.05, "z": 0.1732})
        measured, truth = [], []
        params = rig.ecu.params
        end = rig.now_s + acc.duration + 2.0
        while rig.now_s < end - 1e-9:
            rig.run_until(rig.now_s + 0.02)
            mc.cycle()
            measured.append([states[-1]["pose"][k] for k in POSE])
            q = [p.counts_to_si(c) for p, c in zip(params, rig.ecu.piston_counts(), strict=True)]
            truth.append(model.forward(np.array(q)).pose.controlled())
        assert not states[-1]["moving"] and rig.link.status(rig.now_s).counters.references_refused == 0
        assert states[-1]["ecu"]["feedforward"] == {"enabled": feedforward, "pulled_back": 0}
        return p0, np.array([0.05, 0.1732, p0[2], p0[3]]), np.array(measured), np.array(truth), mc


def _deviation_m(p0, p1, path) -> float:
    d = (p1 - p0)[:2]
    s = np.clip((path[:, :2] - p0[:2]) @ d / (d @ d), 0.0, 1.0)
    return float(np.max(np.linalg.norm(path[:, :2] - (p0[:2] + s[:, None] * d), axis=1)))


@pytest.fixture(scope="module")
def runs(model):
    return {ff: _goto_path(model, ff) for ff in (True, False)}


def test_goto_keeps_to_the_straight_line_through_the_can_path(runs):
    p0, p1, measured, truth, mc = runs[True]
    dev_ff = _deviation_m(p0, p1, truth)
    dev_plain = _deviation_m(*runs[False][:2], runs[False][3])
    assert dev_ff <= 0.010 and _deviation_m(p0, p1, measured) <= 0.010
    assert dev_plain > 3 * dev_ff  # unshaped: each cylinder lags by its own loop
    assert mc.shaper.enabled and not runs[False][4].shaper.enabled
    assert mc.shaper.pulled_back == 0  # nothing near a hard limit on this move


def test_goto_ends_within_the_steady_state_targets(runs):
    p0, p1, measured, truth, _ = runs[True]
    err = measured[-1] - p1
    assert np.hypot(err[0], err[1]) <= 0.002 and np.max(np.abs(err[2:])) <= 0.002, err
    # the true pose: within half an AD step of every sensor of the measured one (lift: 3.7 mm of z)
    assert np.hypot(*(truth[-1] - p1)[:2]) <= 0.004 and np.max(np.abs((truth[-1] - p1)[2:])) <= 0.003


def test_a_jog_into_the_workspace_face_does_not_carry_the_hitch_past_it(model):
    """A jog is known only now: the feed-forward extrapolates its rates with its acceleration and
    stops at zero, so braking at the z face does not lead the pistons past it (with the rates
    alone the true z went 2.5 mm beyond the face)."""
    z_max = model.workspace["z"][1]
    peaks = {}
    for ff in (True, False):
        states: list[dict] = []
        with SimRig(model) as rig:
            rig.start()
            rig.run_until(0.5)
            mc = MotionController(
                Guard(TrajectoryPlanner(model)),
                Guard(TrajectoryPlanner(model)),
                rig.link,
                lambda: rig.now_s,
                on_state=states.append,
                spawn=lambda fn: fn(),
                feedforward=ff,
            )
            mc.cycle()
            params, z_true = rig.ecu.params, []
            for _ in range(450):  # 9 s of z+ at 50 mm/s: into the face and held there
                mc.jog({"vz": 0.05}, 0.3)
                rig.run_until(rig.now_s + 0.02)
                mc.cycle()
                q = [p.counts_to_si(c) for p, c in zip(params, rig.ecu.piston_counts(), strict=True)]
                z_true.append(model.forward(np.array(q)).pose.z)
            assert states[-1]["limited"], "the jog should be limited at the face"
            assert states[-1]["reference"]["pose"]["z"] <= z_max + 1e-9
            peaks[ff] = max(z_true) - z_max
    # never past the face, and no further towards it than without feed-forward beyond the face itself (with the
    # jerk in the extrapolation the pistons stop 0.24 mm short of the face, without feed-forward 0.87 mm short)
    assert peaks[True] <= 0.0 and max(peaks[True], 0.0) <= max(peaks[False], 0.0) + 0.5e-3, peaks
