"""Stability margins of the default tractor with a light and a heavy category-2 implement over
the hitch's height range, on level ground and on slopes.

Run: .venv/bin/python bench/stability_table.py [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from planner.limits.guard import Guard  # noqa: E402
from planner.limits.tractor import load_tractor_profile  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402
from planner.trajectory import TrajectoryPlanner  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    model = HitchModel.from_profile()
    tp = TrajectoryPlanner(model)
    tprof = load_tractor_profile(model.profile.stability.tractor_profile)
    rows = []
    heights = np.linspace(tp.lo[1], tp.hi[1], 5)
    slopes = [("level", 0.0, 0.0), ("10° side (left up)", np.radians(10), 0.0), ("10° nose up", 0.0, np.radians(10))]
    for imp_name in ("cat2-spreader-400", "cat2-power-harrow-1500"):
        g = Guard(tp, implement=tprof.implement(imp_name))
        for label, sr, sp in slopes:
            g.set_slope(sr, sp)
            for z in heights:
                q = tp.inverse(0.0, float(z), 0.0, 0.0)
                r = g.stability_at(q)
                rows.append(
                    {
                        "implement": imp_name,
                        "slope": label,
                        "z_m": float(z),
                        "front_axle_share": r.front_axle_share,
                        "front_over_empty_weight": r.axle_loads.front / g.tractor.empty_weight,
                        "ssm_m": r.ssm,
                        "lsm_m": r.lsm,
                        "esm_J": r.esm,
                        "min_front_ballast_kg": r.min_front_ballast_kg,
                        "ok": r.ok,
                        "violations": [f"{v.measure}:{v.level}" for v in r.violations],
                    }
                )
    print(f"machine: {machine_note()}")
    print(
        f"{'implement':24s} {'slope':20s} {'z [m]':>7s} {'front %':>8s} {'front/empty':>11s} {'SSM m':>6s} "
        f"{'LSM m':>6s} {'ESM J':>7s} {'ballast':>7s}  flags"
    )
    for r in rows:
        print(
            f"{r['implement']:24s} {r['slope']:20s} {r['z_m']:7.3f} {100 * r['front_axle_share']:8.1f} "
            f"{r['front_over_empty_weight']:11.3f} {r['ssm_m']:6.3f} {r['lsm_m']:6.3f} {r['esm_J']:7.0f} "
            f"{r['min_front_ballast_kg']:7.0f}  {'ok' if r['ok'] else 'REFUSE'} {' '.join(r['violations'])}"
        )
    write_json(args.json, {"machine": machine_note(), "rows": rows})


if __name__ == "__main__":
    main()
