"""CLI command ``hitch stability``: axle loads, stability margins and ballast advice for a pose and slope."""

from __future__ import annotations

from bridge.cli.errors import CLIError
from bridge.cli.model import add_model_options, bounded_float, model_from_args
from bridge.cli.output import console, esc
from bridge.cli.plan import parse_pose_arg
from bridge.cli.ranges import check_pose_ranges
from bridge.service.wire import to_json_text
from planner.limits.guard import Guard
from planner.limits.stability import MEASURE_UNITS
from planner.limits.tractor import load_tractor_profile
from planner.trajectory import TrajectoryPlanner

__all__ = ["add_commands"]

#: the largest |slope| [rad] the option takes: below π/2 (the guard refuses ±π/2 and beyond), 4 decimals
_SLOPE_MAX_RAD = 1.5707


def _cmd_stability(args) -> int:
    model = model_from_args(args)
    tprof = load_tractor_profile(model.profile.stability.tractor_profile)
    implement = None if args.implement in (None, "none") else tprof.implement(args.implement)
    if implement is not None and implement.category != model.category:  # as implements/select refuses it
        raise CLIError(
            f"--implement {implement.name} is an ISO 730 category {implement.category} implement; the hitch is set "
            f"up for category {model.category} (--category {implement.category} for it)"
        )
    guard = Guard(TrajectoryPlanner(model), implement=implement)
    guard.set_slope(args.slope_roll, args.slope_pitch)
    # every DOF outside the workspace, with its range and the mm hint, before the IK tries it
    check_pose_ranges((args.pose, "--pose", "pose"), workspace=guard.planner.workspace)
    pose = guard.planner.goal_vector(model.neutral_pose.controlled(), args.pose or {})
    q = guard.planner.inverse(*pose)
    rep = guard.stability_at(q)
    d = rep.as_dict()
    out = {
        "axle_loads": d["axle_loads"],
        "front_axle_share": d["front_axle_share"],
        "ssm": d["ssm"],
        "lsm": d["lsm"],
        "esm": d["esm"],
        "min_front_ballast": d["min_front_ballast"],
        "ok": d["ok"],
        "violations": [
            {"measure": v["measure"], "value": v["value"], "threshold": v["threshold"], "level": v["level"]}
            for v in d["violations"]
        ],
        "weakest_edge": d["weakest_edge"],
        "implement": None if implement is None else implement.name,
        "pose": dict(zip(("x", "z", "roll", "pitch"), map(float, pose), strict=True)),
        "slope": {"roll": args.slope_roll, "pitch": args.slope_pitch},
    }
    verdict = 0 if out["ok"] else 1  # scripts can test it, as `goto --wait` exits 1 when aborted
    if args.json:
        print(to_json_text(out))
        return verdict
    c = console()
    c.print(
        f"implement: {esc(out['implement'] or 'none')}; "
        f"slope roll {args.slope_roll:+.3f} rad, pitch {args.slope_pitch:+.3f} rad"
    )
    c.print(
        f"axle loads: front {out['axle_loads']['front']:.0f} N, rear {out['axle_loads']['rear']:.0f} N "
        f"(front share {out['front_axle_share'] * 100:.1f} %)"
    )
    c.print(
        f"SSM {out['ssm']:.3f} m   LSM {out['lsm']:.3f} m   ESM {out['esm']:.0f} J   "
        f"(weakest edge: {esc(out['weakest_edge'])})"
    )
    c.print(
        f"minimum front ballast (the manuals' formula, level ground: front axle load at least "
        f"{guard.thresholds.front_axle_fraction_hard * 100:.0f} % of the empty tractor's weight, not a share of "
        f"the total; the slope is in the margins below): {out['min_front_ballast']:.0f} kg"
    )
    for v in out["violations"]:
        u = MEASURE_UNITS.get(v["measure"], "")
        c.print(
            f"[red]{esc(v['level'])}[/red]: {esc(v['measure'])} = {v['value']:.4g} {u} below {v['threshold']:.4g} {u}"
        )
    c.print("[green]ok[/green]" if out["ok"] else "[red]NOT OK[/red]")
    return verdict


def add_commands(sub) -> None:
    p = sub.add_parser("stability", help="tractor + implement stability for a hitch pose and a slope")
    p.add_argument("--pose", type=parse_pose_arg, default=None, help="x=..,z=..,roll=..,pitch=.. (default: neutral)")
    p.add_argument(
        "--slope-roll",
        type=bounded_float("--slope-roll", -_SLOPE_MAX_RAD, _SLOPE_MAX_RAD, unit="rad", lo_open=False),
        default=0.0,
        help=f"tractor roll [rad], + = left side up, [-{_SLOPE_MAX_RAD:g}, {_SLOPE_MAX_RAD:g}] (default 0)",
    )
    p.add_argument(
        "--slope-pitch",
        type=bounded_float("--slope-pitch", -_SLOPE_MAX_RAD, _SLOPE_MAX_RAD, unit="rad", lo_open=False),
        default=0.0,
        help=f"tractor pitch [rad], + = nose up, [-{_SLOPE_MAX_RAD:g}, {_SLOPE_MAX_RAD:g}] (default 0)",
    )
    p.add_argument("--implement", default=None, help="implement record of the tractor profile (default: none)")
    add_model_options(p)
    p.set_defaults(handler=_cmd_stability)
