"""Forward-kinematics call cost and the kinematically feasible fraction of the stroke box.

Run: .venv/bin/python bench/model_bench.py [--samples 200000] [--json out.json]
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

from planner.model.hard_limits import HardLimits  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.model.types import KinematicsError  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--samples", type=int, default=100_000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    m = HitchModel.from_profile()
    rng = np.random.default_rng(0)
    q = m.neutral.copy()
    timings = {}
    for name, fn in (
        ("features+jacobian", lambda: m.features(q)),
        ("forward (all points)", lambda: m.forward(q)),
        ("raw buffer eval", m._features._eval),
    ):
        for _ in range(1000):
            fn()
        t = []
        for _ in range(20000):
            t0 = time.perf_counter()
            fn()
            t.append(time.perf_counter() - t0)
        timings[name] = percentiles_us(t)
    limits = HardLimits.from_model(m)
    closes = within = 0
    for _ in track(range(args.samples), description="stroke box"):
        q = m.lower + (m.upper - m.lower) * rng.random(5)
        try:
            f, _ = m.features(q)
        except KinematicsError:
            continue
        closes += 1
        within += not limits.violations(q, f)
    res = {
        "machine": machine_note(),
        "fk_cost": timings,
        "stroke_box_samples": args.samples,
        "fraction_mechanism_closes": closes / args.samples,
        "fraction_closes_and_within_angle_and_ground_limits": within / args.samples,
    }
    print(f"machine: {res['machine']}")
    for k, v in timings.items():
        print(f"{k:24s} p50 {v['p50_us']:7.2f} µs   p99 {v['p99_us']:7.2f} µs")
    print(
        f"stroke box (5-D uniform, {args.samples} samples): mechanism closes {100 * closes / args.samples:.2f} %, "
        f"closes and within top-link/ground limits {100 * within / args.samples:.2f} %"
    )
    write_json(args.json, res)


if __name__ == "__main__":
    main()
