"""Guard.check_jog and Guard.stability_at, old tree against this one: identical outputs and the cost.

Each round runs a worker per tree (a subprocess with that tree first on ``PYTHONPATH``) over the same
random states and rates (seeded; 1 s ahead as the controller asks, within and beyond the workspace,
slopes 0 / 0.1 / 0.3 rad, with and without the heavy implement). The workers pickle every output —
allowed rates, decision (action, factor, reasons), the full stability report ahead, and the report of
``stability_at`` at each state's actuators (the state message's evaluation) — and their thread CPU and
wall time per call; the parent compares the outputs exactly and prints p50 / p99 per tree and round.

Run: .venv/bin/python bench/check_jog_compare.py --old /tmp/cj_old [--states 2000] [--rounds 2]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import pickle
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent.parent


def _bits(v):
    """Floats by their IEEE bits, arrays by their bytes, dataclasses field by field."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return (type(v).__name__, tuple((f.name, _bits(getattr(v, f.name))) for f in dataclasses.fields(v)))
    if isinstance(v, np.ndarray):
        return (v.dtype.str, v.shape, v.tobytes())
    if isinstance(v, (float, np.floating)):
        return struct.pack("<d", float(v))
    if isinstance(v, (tuple, list)):
        return tuple(_bits(x) for x in v)
    return v


def worker(out: str, states: int) -> None:
    import planner
    from planner.limits.guard import Guard
    from planner.limits.tractor import load_tractor_profile
    from planner.model.kinematics import HitchModel
    from planner.trajectory import MotionState, TrajectoryPlanner

    print(f"  worker: planner from {Path(planner.__file__).parent.parent}", file=sys.stderr)
    model = HitchModel.from_profile()
    tp = TrajectoryPlanner(model)
    heavy = load_tractor_profile().implement("cat2-power-harrow-1500")
    rng = np.random.default_rng(15)
    results, cpu, wall, cpu_st = [], [], [], []
    for k in range(states):
        guard = None
        if k % 250 == 0:
            guard = Guard(tp, implement=None if k % 500 else heavy)
            guard.set_slope(*[(0.0, 0.0), (0.1, 0.0), (0.3, 0.2), (-0.25, -0.3)][(k // 250) % 4])
            g = guard
        p = tp.lo + rng.random(4) * (tp.hi - tp.lo)
        rates = rng.normal(0, 0.08, 4) * (rng.random(4) < 0.8)
        state = MotionState.at_rest(p)
        try:
            g.check_jog(state, rates)  # warm, as a controller's repeated checks are
        except Exception:  # noqa: BLE001 - reported by the timed call below
            pass
        res: tuple
        c0, w0 = time.thread_time(), time.perf_counter()
        try:
            allowed, dec = g.check_jog(state, rates)
            res = ("ok", allowed, dec)
        except Exception as exc:  # noqa: BLE001 - an error is an output too
            res = ("error", type(exc).__name__, str(exc))
        w1, c1 = time.perf_counter(), time.thread_time()
        cpu.append(c1 - c0)
        wall.append(w1 - w0)
        q = tp.inverse(*p)
        c2 = time.thread_time()
        rep = g.stability_at(q)
        cpu_st.append(time.thread_time() - c2)
        results.append(_bits((res, rep)))
    with open(out, "wb") as f:
        pickle.dump({"results": results, "cpu": cpu, "wall": wall, "cpu_stability": cpu_st}, f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--old", required=True, help="work tree of the old code (git worktree add --detach)")
    ap.add_argument("--states", type=int, default=2000)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(args.worker, args.states)
        return
    pct = lambda a, q: float(np.percentile(a, q)) * 1e6  # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        for rnd in range(args.rounds):
            outs = {}
            for name, tree in (("old", Path(args.old).resolve()), ("new", HERE)):
                out = str(Path(tmp) / f"{name}{rnd}.pkl")
                env = dict(os.environ, PYTHONPATH=str(tree))
                load = os.getloadavg()[0]
                subprocess.run(
                    [
                        sys.executable,
                        str(HERE / "bench/check_jog_compare.py"),
                        "--old",
                        ".",
                        "--worker",
                        out,
                        "--states",
                        str(args.states),
                    ],
                    check=True,
                    env=env,
                    cwd=str(tree),
                )
                with open(out, "rb") as f:
                    outs[name] = pickle.load(f)
                d = outs[name]
                c, w, st = d["cpu"], d["wall"], d["cpu_stability"]
                print(
                    f"round {rnd + 1} {name}: load {load:.2f}; check_jog CPU p50 / p99 {pct(c, 50):.0f} / "
                    f"{pct(c, 99):.0f} us, wall p50 / p99 {pct(w, 50):.0f} / {pct(w, 99):.0f} us; "
                    f"stability_at CPU p50 / p99 {pct(st, 50):.0f} / {pct(st, 99):.0f} us"
                )
            a, b = outs["old"]["results"], outs["new"]["results"]
            diff = sum(x != y for x, y in zip(a, b, strict=True))
            refused = sum(1 for x in a if x[0][0] == "ok" and x[0][2][1][0][1] == "refused")
            print(f"round {rnd + 1}: {len(a)} states, outputs differing bit for bit: {diff} ({refused} refused)")


if __name__ == "__main__":
    main()
