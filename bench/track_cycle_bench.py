"""Track-mode cycle cost: one control cycle of the online follower (Ruckig re-targeted from the current
state, the exact inverse, the workspace stop check) on a 100 Hz noisy setpoint stream, with and
without the guard's stability check 1 s ahead (``Guard.check_jog`` along the follower's heading),
and the ideal follower's gain and bandwidth per DOF for comparison.

Sessions: all four DOFs (any-direction limits), and one DOF alone (roll, as levelling: its subset
limits, a sine beyond the roll workspace so that it brakes at the faces). "track cycle" is what the
controller runs (:meth:`TrackMotion.step` and :meth:`TrackMotion.look_ahead`): the step every cycle, the guard every
``TRACK_GUARD_EVERY``-th; target p99 ≤ 1 ms, the worst cycle reported beside it.

Run: .venv/bin/python bench/track_cycle_bench.py [--cycles 5000] [--json out.json]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, percentiles_us, write_json  # noqa: E402

from bridge.service.motion.types import TRACK_GUARD_EVERY  # noqa: E402
from planner.limits.guard import Guard  # noqa: E402
from planner.limits.tractor import load_tractor_profile  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.trajectory import MotionState, TrajectoryPlanner  # noqa: E402
from planner.trajectory.ideal_follower import ideal_bandwidth_hz, ideal_sine_gain  # noqa: E402
from planner.trajectory.track import TrackFollower  # noqa: E402

DOFS = ("x", "z", "roll", "pitch")


def stream_cycles(
    tp: TrajectoryPlanner,
    cycles: int,
    guard: Guard | None,
    seed: int,
    dofs: tuple[str, ...] = DOFS,
    guard_every: int = 1,
) -> dict:
    """Times [s] of ``step`` (and of the guard check every ``guard_every``-th cycle) per cycle; two noisy
    setpoints per cycle (only ``dofs``: one DOF alone swings 1.6 × beyond its faces at 0.2 Hz)."""
    rng = np.random.default_rng(seed)
    c = (tp.lo + tp.hi) / 2
    half = (tp.hi - tp.lo) / 2
    amp, f = 0.8 * half, np.array([0.05, 0.03, 0.07, 0.04])  # slow sines over most of the workspace
    if len(dofs) == 1:
        amp, f = 1.6 * half, np.full(4, 0.2)
    tracked = [DOFS.index(k) for k in dofs]
    tr = TrackFollower(tp, MotionState.at_rest(c), dofs, 0.1)
    cycle_s, cycle_cpu = [], []  # the track cycle (step + guard when it runs): wall clock, thread CPU time
    step_s, guard_s, set_s, braking, limited = [], [], [], 0, 0
    step_cpu, guard_cpu = [], []  # thread CPU time: what the cycle costs, without the waits of a loaded machine
    h = guard.settings.jog_horizon if guard is not None else 1.0
    for n in range(cycles):
        for i in (1, 2):  # 100 Hz setpoints, noise 1 mm / 1 mrad, sometimes beyond a face
            ts = tr.t + tr.dt * i / 2
            w = 2 * math.pi * f
            p = c + amp * np.sin(w * ts) + rng.normal(0, 1e-3, 4)
            if rng.random() < 0.01:
                p = p + rng.choice([-1, 1], 4) * half
            v = amp * w * np.cos(w * ts)
            t0 = time.perf_counter()
            tr.set_setpoint({DOFS[d]: float(p[d]) for d in tracked}, {DOFS[d]: float(v[d]) for d in tracked}, ts)
            set_s.append(time.perf_counter() - t0)
        c0, t0 = time.thread_time(), time.perf_counter()
        out = tr.step()
        c1, t1 = time.thread_time(), time.perf_counter()
        g = gc = 0.0
        if guard is not None and n % guard_every == 0:
            guard.check_jog(out.state, tr.guard_rates(h), along_path=False)  # as TrackMotion.look_ahead
            g = time.perf_counter() - t1
            gc = time.thread_time() - c1
            guard_s.append(g)
            guard_cpu.append(gc)
        cycle_s.append(t1 - t0 + g)
        cycle_cpu.append(c1 - c0 + gc)
        step_s.append(t1 - t0)
        step_cpu.append(c1 - c0)
        braking += out.braking
        limited += bool(out.limited)
    res = {
        "step": percentiles_us(step_s),
        "step_cpu": percentiles_us(step_cpu),
        "set_setpoint": percentiles_us(set_s),
        "braking_cycles": braking,
        "limited_cycles": limited,
        "fallbacks": tr.fallbacks,
        "cycle": percentiles_us(cycle_s),
        "cycle_cpu": percentiles_us(cycle_cpu),
        "worst_cycle_index": int(np.argmax(cycle_s)),
        "limits_velocity": tr.limits.velocity.tolist(),
    }
    if guard_s and guard_every == 1:
        res["guard"] = percentiles_us(guard_s)
        res["guard_cpu"] = percentiles_us(guard_cpu)
        res["step_plus_guard"] = percentiles_us(np.array(step_s) + np.array(guard_s))
        res["step_plus_guard_cpu"] = percentiles_us(np.array(step_cpu) + np.array(guard_cpu))
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--cycles", type=int, default=5000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    model = HitchModel.from_profile()
    tp = TrajectoryPlanner(model)
    guard = Guard(tp, implement=load_tractor_profile().implement("cat2-power-harrow-1500"))
    guard.set_slope(0.1, 0.0)
    stream_cycles(tp, 200, None, 0)  # warm-up
    plain = stream_cycles(tp, args.cycles, None, 1)
    guarded = stream_cycles(tp, args.cycles, guard, 1)
    every = TRACK_GUARD_EVERY
    stream_cycles(tp, 200, guard, 0, ("roll",), every)  # warm-up
    ctrl4 = stream_cycles(tp, args.cycles, guard, 2, DOFS, every)
    ctrl1 = stream_cycles(tp, args.cycles, guard, 3, ("roll",), every)
    plain1 = stream_cycles(tp, args.cycles, None, 3, ("roll",))
    ideal = {
        dof: {
            "bandwidth_hz_A10mm": ideal_bandwidth_hz(tp, dof, 0.01),
            "gain_1hz_A10mm": ideal_sine_gain(tp, dof, 0.01, 1.0).gain,
            "binding_1hz": ideal_sine_gain(tp, dof, 0.01, 1.0).limit,
        }
        for dof in DOFS
    }
    load = os.getloadavg()
    print(f"track cycle, {args.cycles} cycles at {tp.rate:g} Hz, setpoints at 100 Hz (load {load[0]:.2f})")
    print(f"{'':24s} {'p50 us':>9s} {'p99 us':>9s} {'max us':>9s}   (wall clock; cpu = thread CPU time)")
    rows = [
        ("step", plain["step"]),
        ("step cpu", plain["step_cpu"]),
        ("set_setpoint", plain["set_setpoint"]),
        ("step (guarded run)", guarded["step"]),
        ("guard.check_jog 1 s", guarded["guard"]),
        ("guard.check_jog cpu", guarded["guard_cpu"]),
        ("step + guard", guarded["step_plus_guard"]),
        ("step + guard cpu", guarded["step_plus_guard_cpu"]),
        ("step, roll alone", plain1["step"]),
        (f"track cycle 4 DOF (guard 1/{every})", ctrl4["cycle"]),
        (f"track cycle roll (guard 1/{every})", ctrl1["cycle"]),
        (f"track cycle 4 DOF cpu (1/{every})", ctrl4["cycle_cpu"]),
        (f"track cycle roll cpu (1/{every})", ctrl1["cycle_cpu"]),
    ]
    for name, r in rows:
        print(f"{name:24s} {r['p50_us']:9.1f} {r['p99_us']:9.1f} {r['max_us']:9.1f}")
    for name, r in (("4 DOF", plain), ("roll alone", plain1)):
        print(
            f"{name}: braking cycles {r['braking_cycles']}, limited cycles {r['limited_cycles']}, "
            f"fallbacks {r['fallbacks']}, velocity limits {np.round(r['limits_velocity'], 4).tolist()}"
        )
    for name, r in (("4 DOF", ctrl4), ("roll", ctrl1)):
        ok = "met" if r["cycle"]["p99_us"] <= 1000.0 else "MISSED"
        ok_cpu = "met" if r["cycle_cpu"]["p99_us"] <= 1000.0 else "MISSED"
        print(
            f"track cycle {name}: p99 {r['cycle']['p99_us']:.0f} us wall ({ok}: <= 1000), "
            f"worst {r['cycle']['max_us']:.0f} us; thread CPU p99 {r['cycle_cpu']['p99_us']:.0f} us ({ok_cpu})"
        )
    for dof, r in ideal.items():
        print(
            f"ideal {dof:5s}: bandwidth {r['bandwidth_hz_A10mm']:.3f} Hz (A = 0.01), "
            f"gain at 1 Hz {r['gain_1hz_A10mm']:.3f} ({r['binding_1hz'] or '-'})"
        )
    write_json(
        args.json,
        {
            "machine": machine_note(),
            "load": load,
            "cycles": args.cycles,
            "plain": plain,
            "guarded": guarded,
            "track_cycle_4dof": ctrl4,
            "track_cycle_roll": ctrl1,
            "plain_roll": plain1,
            "ideal": ideal,
        },
    )


if __name__ == "__main__":
    main()
