"""IK benchmark: QP (OSQP, DAQP), the thesis baselines and an IPOPT reference.

Target sets: random poses inside the thesis's table 3-7 box (default interpretation), random
poses outside it, and a continuous path of N steps. Ground truth for reachability: the hitch
IK has one solution per pose (the closed-form inverse, planner.model.exact_inverse); a pose is
reachable iff that solution lies within every hard limit. The claim is cross-checked by an
independent global search: multi-start IPOPT from random seeds inside the strokes on targets
the closed form calls unreachable.

Run: .venv/bin/python bench/ik_bench.py [--n 1000] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import casadi as ca
import numpy as np
from rich.progress import Progress

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from planner.ik_qp.baselines import DLSIK, GeometricIK, HybridIK  # noqa: E402
from planner.ik_qp.hitch_ik import IKSolver, default_weights  # noqa: E402
from planner.ik_qp.hitch_mechanism import TASK_ROWS  # noqa: E402
from planner.model.exact_inverse import ExactInverse  # noqa: E402
from planner.model.hard_limits import HardLimits  # noqa: E402
from planner.model.kinematics import FEATURE_NAMES, HitchModel  # noqa: E402
from planner.model.types import KinematicsError  # noqa: E402


class IpoptIK:
    """Reference: the same problem (weighted task error, rigidity equality, limits) with CasADi nlpsol + IPOPT."""

    method = "ipopt"

    def __init__(self, model: HitchModel, closed_form_seed: bool = False):
        self.model, self.hard = model, HardLimits.from_model(model)
        self.inverse = ExactInverse(model) if closed_form_seed else None
        sym = model.symbolic
        q, f = sym.q, sym.features
        p = ca.SX.sym("target", 4)
        w = ca.DM(default_weights(model))
        err = ca.vertcat(*[f[i] for i in TASK_ROWS]) - p
        g = ca.vertcat(f[FEATURE_NAMES.index("lower_span")] - model.span, f[list(self.hard.feature_index)])
        self.lbg = np.r_[0.0, self.hard.feature_lower]
        self.ubg = np.r_[0.0, self.hard.feature_upper]
        opts = {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.tol": 1e-12,
            "ipopt.acceptable_tol": 1e-10,
            "ipopt.max_iter": 200,
            "ipopt.sb": "yes",
        }
        self.solver = ca.nlpsol("ik", "ipopt", {"x": q, "p": p, "f": 0.5 * ca.sumsqr(w * err), "g": g}, opts)
        self.last = model.neutral.copy()

    def solve(self, target, seed=None):
        if seed is None and self.inverse is not None:  # same closed-form seed as the QP's default
            try:
                seed = np.clip(
                    self.inverse.solve(np.asarray(target, float))[0], self.hard.actuator_lower, self.hard.actuator_upper
                )
            except KinematicsError:
                seed = None
        x0 = self.last if seed is None else seed
        t0 = time.perf_counter()
        sol = self.solver(
            x0=x0,
            p=np.asarray(target, float),
            lbx=self.hard.actuator_lower,
            ubx=self.hard.actuator_upper,
            lbg=self.lbg,
            ubg=self.ubg,
        )
        dt = time.perf_counter() - t0
        st = self.solver.stats()
        q = np.array(sol["x"]).ravel()
        ok = st["success"] and np.all(np.isfinite(q))
        if ok:
            self.last = q
        return q if ok else None, dt, st.get("iter_count", 0)


def run_method(name, solver, targets, model, hard, truth, cold_seed, progress, task):
    rt, times, iters, ok_flags, in_limits, pos_err, ang_err = [], [], [], [], [], [], []
    for t in targets:
        if name.startswith("ipopt"):
            q, dt, it = solver.solve(t, seed=cold_seed)
            status = "ok" if q is not None else "failed"
        else:
            kw = {"seed": cold_seed} if cold_seed is not None and name.startswith("qp") else {}
            if cold_seed is not None and name.startswith("qp") and name != "qp-osqp-last":
                kw = {}  # closed-form seeding does not depend on history: warm = cold
            if cold_seed is not None and not name.startswith("qp"):
                solver.reset()
            r = solver.solve(t, **kw)
            dt, it, status = r.solve_time_s, r.iterations, r.status
            q = None if r.actuators is None else r.actuators.as_array()
        times.append(dt)
        iters.append(it)
        err, lim_ok, pe, ae = np.inf, False, np.inf, np.inf
        if q is not None:
            try:
                f, _ = model.features(q)
                d = np.abs(f[list(TASK_ROWS)] - t)
                err, pe, ae = float(np.max(d)), float(max(d[0], d[1])), float(max(d[2], d[3]))
                lim_ok = not hard.violations(q, f, tol=1e-8) and abs(f[6] - model.span) < 1e-8
            except KinematicsError:
                pass
        rt.append(err)
        pos_err.append(pe)
        ang_err.append(ae)
        ok_flags.append(status == "ok")
        in_limits.append(lim_ok)
        progress.advance(task)
    rt, times = np.array(rt), np.array(times)
    reach = np.array(truth)
    reached = np.array(ok_flags) & (rt <= 1e-6) & np.array(in_limits)
    good = rt[reach & np.isfinite(rt)]
    pe, ae = np.array(pos_err)[reach & np.isfinite(rt)], np.array(ang_err)[reach & np.isfinite(rt)]
    return {
        "pos_err_mm": {"max": float(pe.max() * 1e3), "mean": float(pe.mean() * 1e3)} if pe.size else None,
        "ang_err_mrad": {"max": float(ae.max() * 1e3), "mean": float(ae.mean() * 1e3)} if ae.size else None,
        "success_on_reachable": float(np.mean(reached[reach])) if reach.any() else None,
        "n_reachable": int(reach.sum()),
        "false_ok_on_unreachable": int(np.sum(np.array(ok_flags)[~reach] & (rt[~reach] <= 1e-6))),
        "roundtrip_err_max": float(good.max()) if good.size else None,
        "roundtrip_err_p99": float(np.percentile(good, 99)) if good.size else None,
        "solutions_within_limits": float(np.mean(np.array(in_limits)[np.isfinite(rt)]))
        if np.isfinite(rt).any()
        else None,
        "time_p50_us": float(np.percentile(times, 50) * 1e6),
        "time_p99_us": float(np.percentile(times, 99) * 1e6),
        "iterations_mean": float(np.mean(iters)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--n", type=int, default=1000)
    ap.add_argument(
        "--global-check", type=int, default=40, help="unreachable targets cross-checked by multi-start IPOPT"
    )
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    model = HitchModel.from_profile()
    hard = HardLimits.from_model(model)
    inv = ExactInverse(model)
    box = model.thesis_box()
    lo = np.array([box[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([box[k][1] for k in ("x", "z", "roll", "pitch")])
    rng = np.random.default_rng(2026)
    inside = lo + (hi - lo) * rng.random((args.n, 4))
    outside = []
    while len(outside) < args.n:
        t = lo - 0.5 * (hi - lo) + 2.0 * (hi - lo) * rng.random(4)
        if np.any(t < lo) or np.any(t > hi):
            outside.append(t)
    outside = np.array(outside)
    ws = model.workspace
    wlo = np.array([ws[k][0] for k in ("x", "z", "roll", "pitch")])
    whi = np.array([ws[k][1] for k in ("x", "z", "roll", "pitch")])
    s = np.linspace(0, 1, args.n)
    path = wlo + (whi - wlo) * (
        0.5
        + 0.45
        * np.column_stack(
            [np.sin(2 * np.pi * s), np.sin(4 * np.pi * s + 1), np.sin(6 * np.pi * s + 2), np.sin(2 * np.pi * s + 3)]
        )
    )
    in_workspace = np.all((inside >= wlo) & (inside <= whi), axis=1)

    def reachable(t):
        try:
            q = inv(*t)
            f, _ = model.features(q)
        except KinematicsError:
            return False
        return not hard.violations(q, f)

    sets = {"inside_box": inside, "outside_box": outside, "path": path}
    truth = {k: [reachable(t) for t in v] for k, v in sets.items()}
    makers = {
        "qp-osqp": lambda: IKSolver(model, backend="osqp"),
        "qp-daqp": lambda: IKSolver(model, backend="daqp"),
        "qp-osqp-last": lambda: IKSolver(model, backend="osqp", seed_strategy="last"),
        "ipopt-cf": lambda: IpoptIK(model, closed_form_seed=True),
        "dls": lambda: DLSIK(model),
        "hybrid": lambda: HybridIK(model),
        "geometric": lambda: GeometricIK(model),
        "ipopt": lambda: IpoptIK(model),
    }
    results: dict = {}
    total = sum(len(v) for v in sets.values()) * len(makers) * 2
    with Progress() as progress:
        task = progress.add_task("IK", total=total)
        for mname, make in makers.items():
            for sname, targets in sets.items():
                for mode, seed in (("warm", None), ("cold", model.neutral.copy())):
                    solver = make()
                    results[(mname, sname, mode)] = run_method(
                        mname, solver, targets, model, hard, truth[sname], seed, progress, task
                    )
    # independent global search on targets the closed form calls unreachable
    ip = IpoptIK(model)
    unreachable = [t for t, r in zip(outside, truth["outside_box"], strict=True) if not r][: args.global_check]
    found = 0
    for t in unreachable:
        for _ in range(20):
            seed = model.lower + (model.upper - model.lower) * rng.random(5)
            q, _, _ = ip.solve(t, seed=seed)
            if q is not None:
                f, _ = model.features(q)
                if np.max(np.abs(f[list(TASK_ROWS)] - t)) <= 1e-6 and not hard.violations(q, f, tol=1e-8):
                    found += 1
                    break
    ws_mask = np.array(in_workspace, bool)
    qp_ws = results[("qp-osqp", "inside_box", "warm")]
    print(f"machine: {machine_note()}")
    print(
        f"reachable by the closed form + limits: inside box {sum(truth['inside_box'])}/{args.n}, "
        f"outside {sum(truth['outside_box'])}/{args.n}, path {sum(truth['path'])}/{args.n}; "
        f"inside the restricted workspace: {int(ws_mask.sum())}"
    )
    print(
        f"global search (multi-start IPOPT, 20 random seeds each) on {len(unreachable)} targets called unreachable: "
        f"{found} found reachable"
    )
    hdr = (
        f"{'method':10s} {'set':12s} {'mode':5s} {'success':>8s} {'rt max':>9s} {'rt p99':>9s} {'in lim':>6s} "
        f"{'p50 µs':>9s} {'p99 µs':>9s} {'iter':>5s}"
    )
    print(hdr)
    for (m, sname, mode), r in results.items():
        succ = "-" if r["success_on_reachable"] is None else f"{100 * r['success_on_reachable']:.1f}%"
        rtm = "-" if r["roundtrip_err_max"] is None else f"{r['roundtrip_err_max']:.1e}"
        rtp = "-" if r["roundtrip_err_p99"] is None else f"{r['roundtrip_err_p99']:.1e}"
        il = "-" if r["solutions_within_limits"] is None else f"{100 * r['solutions_within_limits']:.0f}%"
        print(
            f"{m:10s} {sname:12s} {mode:5s} {succ:>8s} {rtm:>9s} {rtp:>9s} {il:>6s} {r['time_p50_us']:9.0f} "
            f"{r['time_p99_us']:9.0f} {r['iterations_mean']:5.1f}"
        )
    for sname in ("path", "inside_box"):
        ip_w = results[("ipopt", sname, "warm")]["time_p50_us"]
        ip_cf = results[("ipopt-cf", sname, "warm")]["time_p50_us"]
        qp_w = results[("qp-osqp", sname, "warm")]["time_p50_us"]
        qp_l = results[("qp-osqp-last", sname, "warm")]["time_p50_us"]
        print(
            f"{sname}: QP-OSQP (closed-form seed) p50 {qp_w:.0f} µs vs IPOPT warm {ip_w:.0f} µs: {ip_w / qp_w:.1f}x, "
            f"vs IPOPT with the same closed-form seed {ip_cf:.0f} µs: {ip_cf / qp_w:.1f}x; "
            f"QP warm from the last solution {qp_l:.0f} µs vs IPOPT warm: {ip_w / qp_l:.1f}x"
        )
    # model errors of the thesis baselines over the box (reachable targets)
    for m in ("geometric", "dls", "hybrid"):
        r = results[(m, "inside_box", "warm")]
        print(
            f"{m} model error over the box (reachable targets): position max {r['pos_err_mm']['max']:.3f} mm "
            f"(mean {r['pos_err_mm']['mean']:.3f}), angle max {r['ang_err_mrad']['max']:.3f} mrad "
            f"(mean {r['ang_err_mrad']['mean']:.3f})"
        )
    write_json(
        args.json,
        {
            "machine": machine_note(),
            "global_check": {"targets": len(unreachable), "found": found},
            "results": {"|".join(k): v for k, v in results.items()},
            "qp_inside_box": qp_ws,
        },
    )


if __name__ == "__main__":
    main()
