"""CLI command ``hitch ik``: pose → actuators with the QP solver or a thesis baseline."""

from __future__ import annotations

import math

from bridge.cli.model import add_model_options, finite_float, model_from_args
from bridge.cli.output import POSE_UNITS, console, esc, milli_text, signed
from bridge.service.wire import to_json_text
from planner.ik_qp.baselines import DLSIK, GeometricIK, HybridIK
from planner.ik_qp.hitch_ik import IKSolver
from planner.ik_qp.result import Target, check_target
from planner.model.types import ACTUATOR_UNITS

__all__ = ["add_commands"]

METHODS = {"qp": IKSolver, "dls": DLSIK, "hybrid": HybridIK, "geometric": GeometricIK}


def _cmd_ik(args) -> int:
    model = model_from_args(args)
    target = Target(args.x, args.z, args.roll, args.pitch)
    solver = METHODS[args.method](model)
    res = solver.solve(target)
    if args.json:
        print(to_json_text(res.to_json()))
    else:
        c = console()
        c.print(f"status: [bold]{res.status}[/bold]" + (f" — {esc(res.reason)}" if res.reason else ""))
        if res.actuators is not None:
            q = res.actuators.as_dict()
            c.print("actuators: " + "  ".join(f"{k}={v:.5f} {ACTUATOR_UNITS[k]}" for k, v in q.items()))
            c.print(
                "pose:      " + "  ".join(f"{k}={signed(v, 5)} {POSE_UNITS[k]}" for k, v in res.pose.as_dict().items())
            )
        if res.active:  # a baseline's are the limits its actuators break (it enforces none), the QP's those it met
            label = "limits broken" if res.extra.get("violated") else "active limits"
            c.print(f"{label}: " + esc(", ".join(res.active)))
        # no solution, no error ("residual inf": a fuzz trial; --json says null). Per DOF with its unit, apart from
        # the solver's "weighted residual" in the status line (a newcomer read two residuals, unnamed and unitless)
        if res.pose is not None and math.isfinite(res.residual):
            got = res.pose.as_dict()
            errs = ", ".join(
                milli_text(k, got[k] - t)
                for k, t in zip(("x", "z", "roll", "pitch"), check_target(target), strict=True)
            )
        else:
            errs = "none (no solution)"
        c.print(f"iterations {res.iterations}, pose - target: {errs}, {res.solve_time_s * 1e6:.0f} µs")
    return 0 if res.status != "failed" else 1


def add_commands(sub) -> None:
    p = sub.add_parser("ik", help="inverse kinematics: pose (x, z, roll, pitch) -> actuators")
    p.add_argument("--x", type=finite_float("--x"), required=True, help="lateral position of T [m] (+ = driver's left)")
    p.add_argument("--z", type=finite_float("--z"), required=True, help="height of T above pivot height [m]")
    p.add_argument("--roll", type=finite_float("--roll"), required=True, help="roll [rad] (+ = right side higher)")
    p.add_argument("--pitch", type=finite_float("--pitch"), required=True, help="pitch [rad] (+ = mast top forward)")
    p.add_argument("--method", choices=sorted(METHODS), default="qp", help="solver (default qp)")
    add_model_options(p)
    p.set_defaults(handler=_cmd_ik)
