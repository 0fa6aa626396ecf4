"""Serial arm: analytic 6R solutions vs the QP IK on the same core, 1000 random poses.

Run: .venv/bin/python bench/arm_bench.py [--n 1000] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from rich.progress import track

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from planner.arm.analytic import build_spherical_wrist_arm, solve_arm_ik  # noqa: E402
from planner.arm.dh import forward_kinematics  # noqa: E402
from planner.arm.mechanism import arm_target, arm_weights, build_arm_mechanism  # noqa: E402
from planner.arm.profile import load_arm_profile  # noqa: E402
from planner.ik_qp.problem import build_ik_problem  # noqa: E402
from planner.ik_qp.sqp import SQPSolver  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    chain = load_arm_profile().chain()
    arm, mech = build_spherical_wrist_arm(chain), build_arm_mechanism(chain)
    solver = SQPSolver(mech)
    rng = np.random.default_rng(8)
    fk_err, near_hits, neutral_ok, t_an, t_near, t_neu = [], 0, 0, [], [], []
    for _ in track(range(args.n), description="arm poses"):
        q = rng.uniform(-2.5, 2.5, 6)
        T = forward_kinematics(chain, q).end
        p, R = T[:3, 3], T[:3, :3]
        t0 = time.perf_counter()
        res = solve_arm_ik(arm, p, R)
        t_an.append(time.perf_counter() - t0)
        for s in res.solutions:
            Ts = forward_kinematics(chain, s.joints).end
            fk_err.append(max(np.max(np.abs(Ts[:3, 3] - p)), np.max(np.abs(Ts[:3, :3] - R))))
        s0 = res.solutions[0]
        prob = build_ik_problem(mech, arm_target(p, R), arm_weights())
        t0 = time.perf_counter()
        r = solver.solve(prob, seed=np.asarray(s0.joints) + rng.normal(0, 0.01, 6))
        t_near.append(time.perf_counter() - t0)
        near_hits += r.status == "ok" and np.max(np.abs(r.q - s0.joints)) < 1e-6
        t0 = time.perf_counter()
        r = solver.solve(prob, seed=np.zeros(6))
        t_neu.append(time.perf_counter() - t0)
        neutral_ok += r.status == "ok"
    res = {
        "machine": machine_note(),
        "n": args.n,
        "analytic_fk_error_max": float(np.max(fk_err)),
        "analytic_solutions_checked": len(fk_err),
        "qp_seeded_near_solution_converges_to_it": near_hits / args.n,
        "qp_from_neutral_success": neutral_ok / args.n,
        "time_ms_p50": {
            "analytic_all_8": 1e3 * float(np.median(t_an)),
            "qp_seeded": 1e3 * float(np.median(t_near)),
            "qp_neutral": 1e3 * float(np.median(t_neu)),
        },
    }
    print(f"machine: {res['machine']}")
    print(
        f"{args.n} poses: all {len(fk_err)} analytic solutions match the target to {res['analytic_fk_error_max']:.1e}"
    )
    print(
        "QP seeded near an analytic solution converges to it: "
        f"{100 * res['qp_seeded_near_solution_converges_to_it']:.1f} %"
    )
    print(f"QP from the neutral seed reaches the target: {100 * res['qp_from_neutral_success']:.1f} %")
    print(
        "median time: analytic (all 8 + FK checks) {analytic_all_8:.3f} ms, QP seeded {qp_seeded:.3f} ms, "
        "QP neutral {qp_neutral:.3f} ms".format(**res["time_ms_p50"])
    )
    write_json(args.json, res)


if __name__ == "__main__":
    main()
