"""Trajectory planning benchmark: planning time for ~5 s moves with IK at every
sample, duration ratio to the per-actuator lower bound, straight-line deviation, limit checks.

Run: .venv/bin/python bench/trajectory_bench.py [--moves 200] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from rich.progress import track

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, percentiles_us, write_json  # noqa: E402

from planner.limits.guard import Guard  # noqa: E402
from planner.limits.tractor import load_tractor_profile  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.trajectory import MotionState, TrajectoryPlanner, verify_setpoints  # noqa: E402

DOFS = ("x", "z", "roll", "pitch")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--moves", type=int, default=200)
    ap.add_argument("--min-duration", type=float, default=4.0, help="keep moves at least this long [s]")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    model = HitchModel.from_profile()
    tp = TrajectoryPlanner(model)
    # the guard's check of every sample (FK, end stops, keep-outs, stability) with a heavy implement on a side slope
    guard = Guard(tp, implement=load_tractor_profile().implement("cat2-power-harrow-1500"))
    guard.set_slope(0.1, 0.0)
    guard_times = []
    rng = np.random.default_rng(1)
    times, ratios, dev_pos, dev_ang, durations, violations = [], [], [], [], [], 0
    pbar = track(range(args.moves), description="plans")
    for _ in pbar:
        while True:  # long moves: pick far-apart corners-ish poses
            p0 = tp.lo + (tp.hi - tp.lo) * rng.choice([0.02, 0.98], 4) + rng.normal(0, 0.01, 4) * (tp.hi - tp.lo)
            p1 = tp.lo + (tp.hi - tp.lo) * rng.random(4)
            p0, p1 = np.clip(p0, tp.lo, tp.hi), np.clip(p1, tp.lo, tp.hi)
            t0 = time.perf_counter()
            plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(DOFS, p1, strict=True)))
            dt = time.perf_counter() - t0
            if plan.duration >= args.min_duration:
                break
        sp = plan.setpoints
        times.append(dt)
        t0 = time.perf_counter()
        guard.check_setpoints(sp)
        guard_times.append(time.perf_counter() - t0)
        durations.append(plan.duration)
        ratios.append(plan.duration / plan.lower_bound)
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        rel = sp.pose[:, [0, 2, 3, 4]] - p0
        dev = rel - np.outer(rel @ u, u)
        dev_pos.append(float(np.max(np.abs(dev[:, :2]))))
        dev_ang.append(float(np.max(np.abs(dev[:, 2:]))))
        violations += len(verify_setpoints(sp, model, tp.hard, tp.limits))
    res = {
        "machine": machine_note(),
        "moves": args.moves,
        "duration_s": {
            "min": float(np.min(durations)),
            "median": float(np.median(durations)),
            "max": float(np.max(durations)),
        },
        "plan_time_incl_ik_and_verification": {
            k.replace("_us", "_ms"): v / 1e3 for k, v in percentiles_us(times).items() if k != "n"
        },
        "guard_check_time": {
            k.replace("_us", "_ms"): v / 1e3 for k, v in percentiles_us(guard_times).items() if k != "n"
        },
        "duration_over_lower_bound": {"median": float(np.median(ratios)), "max": float(np.max(ratios))},
        "straight_line_deviation": {"position_m_max": float(np.max(dev_pos)), "angle_rad_max": float(np.max(dev_ang))},
        "samples_over_a_limit": violations,
    }
    print(f"machine: {res['machine']}")
    print(
        f"{args.moves} moves, duration {res['duration_s']['min']:.2f}..{res['duration_s']['max']:.2f} s "
        f"(median {res['duration_s']['median']:.2f} s), 50 Hz samples, "
        "IK (closed form) + full limit check at every sample"
    )
    pt = res["plan_time_incl_ik_and_verification"]
    print(f"planning time: p50 {pt['p50_ms']:.2f} ms   p99 {pt['p99_ms']:.2f} ms   max {pt['max_ms']:.2f} ms")
    gt = res["guard_check_time"]
    print(
        f"guard check (1500 kg implement, 0.1 rad side slope): p50 {gt['p50_ms']:.2f} ms   p99 {gt['p99_ms']:.2f} ms   "
        f"max {gt['max_ms']:.2f} ms"
    )
    print(
        f"duration / lower bound: median {res['duration_over_lower_bound']['median']:.3f}   "
        f"max {res['duration_over_lower_bound']['max']:.3f}"
    )
    print(
        f"straight-line deviation: {res['straight_line_deviation']['position_m_max']:.2e} m, "
        f"{res['straight_line_deviation']['angle_rad_max']:.2e} rad; samples over a limit: {violations}"
    )
    write_json(args.json, res)


if __name__ == "__main__":
    main()
