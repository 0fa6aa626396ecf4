"""Trajectory planning benchmark: planning time for ~5 s moves with IK at every
sample, duration ratio to the per-actuator lower bound, straight-line deviation, limit checks.

Run: .venv/bin/python bench/trajectory_bench.py [--moves 200] [--json out.json]

``--compare-with DIR`` measures instead a whole guarded goto plan (``Guard.plan``: the
planner, sampling through the exact inverse, verification of every sample, the guard's
checks with a 1500 kg implement on a 0.1 rad side slope, the caution re-plan) of ~5 s moves,
for the code in DIR (e.g. a ``git worktree add --detach /tmp/hp-old HEAD`` of an earlier
commit) and for this tree side by side: two worker processes, one per tree, plan the same
moves alternately (old, new, old, new, ...) under the same load, and the setpoints and
decisions of both are compared.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
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


def _goto_setup():
    model = HitchModel.from_profile()
    tp = TrajectoryPlanner(model)
    guard = Guard(tp, implement=load_tractor_profile().implement("cat2-power-harrow-1500"))
    guard.set_slope(0.1, 0.0)
    return tp, guard


def _worker() -> None:
    """One tree's side of ``--compare-with``: commands on stdin, one JSON line per answer."""
    tp, guard = _goto_setup()
    out = sys.stdout
    for line in sys.stdin:
        cmd = json.loads(line)
        if cmd["op"] == "cases":  # pick moves of the wanted duration (deterministic for a seed)
            rng = np.random.default_rng(cmd["seed"])
            cases: list[list[float]] = []
            while len(cases) < cmd["n"]:
                p0 = tp.lo + (tp.hi - tp.lo) * rng.choice([0.02, 0.98], 4) + rng.normal(0, 0.01, 4) * (tp.hi - tp.lo)
                p1 = tp.lo + (tp.hi - tp.lo) * rng.random(4)
                p0, p1 = np.clip(p0, tp.lo, tp.hi), np.clip(p1, tp.lo, tp.hi)
                try:
                    gp = guard.plan(MotionState.at_rest(p0), dict(zip(DOFS, p1, strict=True)))
                except Exception:  # noqa: BLE001 - a refused or unplannable move is simply not a case
                    continue
                if cmd["lo"] <= gp.plan.duration <= cmd["hi"]:
                    cases.append([*p0.tolist(), *p1.tolist()])
            out.write(json.dumps({"cases": cases}) + "\n")
        elif cmd["op"] == "plan":
            c = np.asarray(cmd["case"], float)
            start, goal = MotionState.at_rest(c[:4]), dict(zip(DOFS, c[4:], strict=True))
            c0, t0 = time.thread_time(), time.perf_counter()
            gp = guard.plan(start, goal)
            dt, cpu = time.perf_counter() - t0, time.thread_time() - c0
            res: dict = {"dt": dt, "cpu": cpu, "duration": gp.plan.duration, "samples": len(gp.setpoints.t)}
            if cmd.get("result"):
                res |= {
                    "q": gp.setpoints.actuators.tolist(),
                    "qd": gp.setpoints.actuator_velocity.tolist(),
                    "pose": gp.setpoints.pose.tolist(),
                    "decision": gp.decision.to_json(),
                }
            out.write(json.dumps(res) + "\n")
        out.flush()


def _max_diff(a, b) -> float:
    """Largest |a - b| over equal nested JSON values (inf where the structure or a string differs)."""
    if isinstance(a, dict):
        return max((_max_diff(a[k], b[k]) for k in a), default=0.0) if a.keys() == b.keys() else float("inf")
    if isinstance(a, list):
        return max((_max_diff(x, y) for x, y in zip(a, b, strict=True)), default=0.0) if len(a) == len(b) else 1e300
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return 0.0 if a == b else abs(float(a) - float(b)) / max(1.0, abs(float(a)))
    return 0.0 if a == b else float("inf")


def compare(args) -> None:
    """Guarded goto plans of the code in ``args.compare_with`` and of this tree, alternately."""
    here = Path(__file__).resolve().parent.parent
    trees = {"old": Path(args.compare_with).resolve(), "new": here}
    procs = {}
    for name, root in trees.items():
        env = {**os.environ, "PYTHONPATH": str(root)}
        procs[name] = subprocess.Popen(
            [sys.executable, __file__, "--worker"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env
        )

    def ask(name: str, cmd: dict) -> dict:
        p = procs[name]
        assert p.stdin is not None and p.stdout is not None
        p.stdin.write(json.dumps(cmd) + "\n")
        p.stdin.flush()
        line = p.stdout.readline()
        if not line:
            raise RuntimeError(f"the {name} worker ended")
        return json.loads(line)

    try:
        sel = {"op": "cases", "seed": 1, "n": args.goto_moves, "lo": 4.5, "hi": 5.5}
        cases = ask("new", sel)["cases"]
        times: dict[str, list[float]] = {"old": [], "new": []}
        cpus: dict[str, list[float]] = {"old": [], "new": []}  # thread CPU time: without a loaded machine's waits
        worst, durations, samples = 0.0, [], []
        for c in cases:  # results once (outside the timing), then alternating timed repetitions
            r = {n: ask(n, {"op": "plan", "case": c, "result": True}) for n in ("old", "new")}
            for res in r.values():  # a reason's unit is a label (added 2026-12-05), not a result
                for reason in res["decision"]["reasons"]:
                    reason.pop("unit", None)
            worst = max(
                worst,
                _max_diff(
                    {k: r["old"][k] for k in ("q", "qd", "pose", "decision")},
                    {k: r["new"][k] for k in ("q", "qd", "pose", "decision")},
                ),
            )
            durations.append(r["new"]["duration"])
            samples.append(r["new"]["samples"])
        load0 = os.getloadavg()
        for _ in range(args.repeat):
            for c in cases:
                for n in ("old", "new"):
                    r1 = ask(n, {"op": "plan", "case": c})
                    times[n].append(r1["dt"])
                    cpus[n].append(r1["cpu"])
        load1 = os.getloadavg()
    finally:
        for p in procs.values():
            if p.stdin is not None:
                p.stdin.close()
            p.wait(10)
    res = {
        "machine": machine_note(),
        "load_average_1_5_15": {"before": list(load0), "after": list(load1)},
        "old_tree": str(trees["old"]),
        "moves": len(cases),
        "repeat": args.repeat,
        "duration_s": {"min": min(durations), "median": float(np.median(durations)), "max": max(durations)},
        "samples_median": float(np.median(samples)),
        "guard_plan_ms": {
            n: {k.replace("_us", "_ms"): v / 1e3 for k, v in percentiles_us(t).items() if k != "n"}
            for n, t in times.items()
        },
        "guard_plan_cpu_ms": {
            n: {k.replace("_us", "_ms"): v / 1e3 for k, v in percentiles_us(t).items() if k != "n"}
            for n, t in cpus.items()
        },
        "max_rel_diff_old_new": worst,
    }
    old, new = res["guard_plan_ms"]["old"], res["guard_plan_ms"]["new"]
    print(f"machine: {res['machine']}; load average before {load0[0]:.2f} {load0[1]:.2f}, after {load1[0]:.2f}")
    print(
        f"{len(cases)} guarded goto plans x {args.repeat}, duration {res['duration_s']['min']:.2f}.."
        f"{res['duration_s']['max']:.2f} s (median {res['duration_s']['median']:.2f} s, "
        f"{res['samples_median']:.0f} samples of the returned plan), alternating old/new"
    )
    for n, v in (("old", old), ("new", new)):
        print(f"Guard.plan {n}: p50 {v['p50_ms']:.2f} ms   p99 {v['p99_ms']:.2f} ms   max {v['max_ms']:.2f} ms")
    print(f"ratio old/new: p50 {old['p50_ms'] / new['p50_ms']:.2f}x   p99 {old['p99_ms'] / new['p99_ms']:.2f}x")
    for n in ("old", "new"):
        v = res["guard_plan_cpu_ms"][n]
        print(f"Guard.plan {n}, thread CPU time: p50 {v['p50_ms']:.2f} ms   p99 {v['p99_ms']:.2f} ms")
    print(f"setpoints and decisions old vs new: largest difference {worst:.3g} (relative above 1)")
    write_json(args.json, res)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--moves", type=int, default=200)
    ap.add_argument("--min-duration", type=float, default=4.0, help="keep moves at least this long [s]")
    ap.add_argument("--json", default=None)
    ap.add_argument("--compare-with", default=None, help="a checkout of older code: Guard.plan old vs new")
    ap.add_argument("--goto-moves", type=int, default=40, help="--compare-with: moves of 4.5..5.5 s")
    ap.add_argument("--repeat", type=int, default=5, help="--compare-with: timed plans of each move per tree")
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        return _worker()
    if args.compare_with:
        return compare(args)
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
