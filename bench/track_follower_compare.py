"""Track follower, old vs new, side by side in one process: the same setpoint streams through the
:class:`~planner.trajectory.track.TrackFollower` of another checkout (``--old``: e.g. a
``git worktree add --detach`` of the commit before a change) and of this tree, the old and new step of
every cycle interleaved so that the machine's load hits both alike.

Printed per stream: the largest |difference| of the state (position, velocity, acceleration) and the
actuators, the cycles whose flags (``limited``, ``braking``, ``stale``) differ, thread CPU time per step
(``time.thread_time``) p50/p99 old and new [µs], and the new follower's rendezvous counters.

Streams (100 Hz setpoints, 50 Hz cycles): those of ``bench/track_cycle_bench.py`` (4 DOFs with 1 mm
noise and jumps beyond the faces; roll alone swinging 1.6 × beyond its faces), the same 4 DOFs with a
z descent bound, and clean sines with their acceleration and jerk (4 DOFs; x alone), where the
rendezvous meets the stream.

Run: .venv/bin/python bench/track_follower_compare.py --old /path/to/old/checkout [--cycles 1000]
"""

from __future__ import annotations

import argparse
import importlib.util
import math
import os
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np

from planner.model.kinematics import HitchModel
from planner.trajectory import MotionState, TrajectoryPlanner
from planner.trajectory import track as new_track
from planner.trajectory.track import TrackBounds

DOFS = ("x", "z", "roll", "pitch")


def load_old(root: Path) -> ModuleType:
    """The old checkout's ``planner/trajectory/track.py`` as a module of its own (its imports from this tree)."""
    spec = importlib.util.spec_from_file_location("track_old", root / "planner" / "trajectory" / "track.py")
    if spec is None or spec.loader is None:
        raise SystemExit(f"no planner/trajectory/track.py under {root}")
    mod = importlib.util.module_from_spec(spec)
    sys.modules["track_old"] = mod
    spec.loader.exec_module(mod)
    return mod


def compare(
    old: ModuleType,
    tp: TrajectoryPlanner,
    cycles: int,
    seed: int,
    dofs: tuple[str, ...],
    clean: bool,
    bounds: TrackBounds | None = None,
) -> dict:
    """One stream through both followers; the differences and the CPU times [s] per step."""
    rng = np.random.default_rng(seed)
    c, half = (tp.lo + tp.hi) / 2, (tp.hi - tp.lo) / 2
    amp, w = 0.8 * half, 2 * math.pi * np.array([0.05, 0.03, 0.07, 0.04])
    if len(dofs) == 1 and not clean:
        amp, w = 1.6 * half, np.full(4, 2 * math.pi * 0.2)
    tracked = [DOFS.index(k) for k in dofs]
    fo = old.TrackFollower(tp, MotionState.at_rest(c), dofs, 0.1, bounds=bounds)
    fn = new_track.TrackFollower(tp, MotionState.at_rest(c), dofs, 0.1, bounds=bounds)
    cpu_o, cpu_n, diff, flags = [], [], 0.0, 0
    for _ in range(cycles):
        for i in (1, 2):
            ts = fo.t + fo.dt * i / 2
            p = c + amp * np.sin(w * ts)
            if not clean:
                p = p + rng.normal(0, 1e-3, 4)
                if rng.random() < 0.01:
                    p = p + rng.choice([-1, 1], 4) * half
            v, a, j = amp * w * np.cos(w * ts), -amp * w**2 * np.sin(w * ts), -amp * w**3 * np.cos(w * ts)
            pick = [{DOFS[d]: float(x[d]) for d in tracked} for x in (p, v, a, j)]
            extra = {"acceleration": pick[2], "jerk": pick[3]} if clean else {}
            fo.set_setpoint(pick[0], pick[1], ts, **extra)
            fn.set_setpoint(pick[0], pick[1], ts, **extra)
        c0 = time.thread_time()
        oo = fo.step()
        c1 = time.thread_time()
        on = fn.step()
        c2 = time.thread_time()
        cpu_o.append(c1 - c0)
        cpu_n.append(c2 - c1)
        for x, y in (
            (oo.state.position, on.state.position),
            (oo.state.velocity, on.state.velocity),
            (oo.state.acceleration, on.state.acceleration),
            (oo.actuators, on.actuators),
        ):
            diff = max(diff, float(np.max(np.abs(x - y))))
        flags += (oo.limited != on.limited) or (oo.braking != on.braking) or (oo.stale != on.stale)
    return {
        "max_diff": diff,
        "flag_diffs": flags,
        "old_us": (np.percentile(cpu_o, 50) * 1e6, np.percentile(cpu_o, 99) * 1e6),
        "new_us": (np.percentile(cpu_n, 50) * 1e6, np.percentile(cpu_n, 99) * 1e6),
        "rendezvous": (fo.rendezvous, fn.rendezvous),
        "tries": getattr(fn, "rendezvous_tries", -1),
        "skips": getattr(fn, "rendezvous_skips", -1),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--old", required=True, type=Path, help="the old checkout's root")
    ap.add_argument("--cycles", type=int, default=1000)
    args = ap.parse_args()
    old = load_old(args.old)
    tp = TrajectoryPlanner(HitchModel.from_profile())
    compare(old, tp, 100, 0, DOFS, False)  # warm-up
    streams = (
        ("4 DOF noisy (track_cycle_bench)", 1, DOFS, False, None),
        ("roll beyond faces (track_cycle_bench)", 3, ("roll",), False, None),
        ("4 DOF noisy, z descent bound", 7, DOFS, False, TrackBounds(z_descent_m_s=0.02)),
        ("4 DOF clean with a, j", 5, DOFS, True, None),
        ("x clean with a, j", 6, ("x",), True, None),
    )
    print(f"load {os.getloadavg()[0]:.2f}; {args.cycles} cycles per stream; thread CPU per step [us]")
    worst = 0.0
    for name, seed, dofs, clean, bounds in streams:
        r = compare(old, tp, args.cycles, seed, dofs, clean, bounds)
        worst = max(worst, r["max_diff"])
        (o50, o99), (n50, n99) = r["old_us"], r["new_us"]
        print(
            f"{name:38s} max|diff| {r['max_diff']:.3g}, flag diffs {r['flag_diffs']}; old p50 {o50:5.0f} p99 "
            f"{o99:5.0f}; new p50 {n50:5.0f} p99 {n99:5.0f}; rendezvous old/new {r['rendezvous']}, "
            f"Ruckig tries {r['tries']}, skipped {r['skips']}"
        )
    print(f"largest difference over all streams: {worst:.3g}")


if __name__ == "__main__":
    main()
