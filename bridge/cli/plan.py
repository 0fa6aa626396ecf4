"""CLI command ``hitch plan``: a jerk-limited move between poses, as a table, JSON or a plot."""

from __future__ import annotations

import argparse

import numpy as np

from bridge.cli.model import add_model_options, bounded_float, model_from_args, plain_number
from bridge.cli.output import console, esc, plot_path, pose_text
from bridge.cli.ranges import check_pose_ranges
from bridge.link.count_tail import plan_count_tail
from bridge.link.reference_check import ReferenceCheck
from bridge.service.maneuvers.language import MIN_SPEED_SCALE
from bridge.service.wire import to_json_text
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES
from planner.trajectory import MotionState, TrajectoryPlanner

__all__ = ["add_commands", "parse_pose_arg"]


def parse_pose_arg(text: str) -> dict[str, float]:
    """'x=0.05,z=0.2' → {"x": 0.05, "z": 0.2} (any of x, z, roll, pitch)."""
    out: dict[str, float] = {}
    for part in filter(None, (p.strip() for p in text.split(","))):
        if "=" not in part:
            raise argparse.ArgumentTypeError(f"expected key=value pairs (x, z, roll, pitch), got {part!r}")
        k, v = (s.strip() for s in part.split("=", 1))
        if k not in CONTROLLED_POSE_NAMES:
            raise argparse.ArgumentTypeError(f"unknown pose field {k!r}; allowed: x, z, roll, pitch")
        if k in out:
            raise argparse.ArgumentTypeError(f"pose field {k!r} given twice; give each of x, z, roll, pitch once")
        out[k] = plain_number(k, v)
        if not np.isfinite(out[k]):
            raise argparse.ArgumentTypeError(f"{k} must be finite, got {v!r}")
    if not out:
        raise argparse.ArgumentTypeError("no pose fields given")
    return out


def plot_plan(path: str, sp, tp: TrajectoryPlanner) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 10), sharex=True, constrained_layout=True)
    names6 = ("x", "y", "z", "roll", "pitch", "yaw")
    for i in (0, 2, 3, 4):
        axes[0].plot(sp.t, sp.pose[:, i], label=f"{names6[i]} [{'m' if i < 3 else 'rad'}]")
    axes[0].set_title("pose (x, z, roll, pitch)")
    axes[0].legend(loc="best")
    span = tp.model.upper - tp.model.lower
    for i, n in enumerate(ACTUATOR_NAMES):
        axes[1].plot(sp.t, (sp.actuators[:, i] - tp.model.lower[i]) / span[i], label=n)
    axes[1].axhline(0, color="k", lw=0.8)
    axes[1].axhline(1, color="k", lw=0.8)
    axes[1].set_title("actuator positions, fraction of stroke (strokes at 0 and 1)")
    axes[1].legend(loc="best")
    for i, n in enumerate(ACTUATOR_NAMES):
        (line,) = axes[2].plot(sp.t, sp.actuator_velocity[:, i] / tp.limits.velocity[i], label=n)
    axes[2].axhline(1, color="r", ls="--", lw=1)
    axes[2].axhline(-1, color="r", ls="--", lw=1, label="limit")
    axes[2].set_title("actuator velocities, fraction of their limits")
    axes[2].set_xlabel("t [s]")
    axes[2].legend(loc="best")
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _cmd_plan(args) -> int:
    model = model_from_args(args)
    tp = TrajectoryPlanner(model, rate=args.rate)
    start = model.neutral_pose.controlled()
    # every DOF of --from and --to outside the workspace, with its range and the mm hint (the service's wording)
    check_pose_ranges((args.start, "--from", "from"), (args.to, "--to", "goal"), workspace=tp.workspace)
    if args.start:
        start = tp.goal_vector(start, args.start)
        tp.check_in_workspace(start, "from")
    plan = tp.plan_move(MotionState.at_rest(start), args.to, speed_scale=args.speed_scale)
    sp = plan.setpoints  # verified at the planner's rate (--rate)
    if sp is None:  # a move is always sampled by plan_move; only stop plans come without samples
        sp = tp.sample(plan)
    if args.plot:
        plot_plan(args.plot, sp, tp)
    # the profile's count approach a goto of this plan ends with (the link's checks; no guard here)
    tail = plan_count_tail(tp, plan, ReferenceCheck(model))
    approach = (
        None
        if tail is None
        else {
            "duration_s": tail.approach.duration_s,
            "via_counts": [int(c) for c in tail.approach.via_counts],
            "final_counts": [int(c) for c in tail.approach.final_counts],
        }
    )
    if args.json:
        print(
            to_json_text(
                {
                    "duration": plan.duration,
                    "lower_bound": plan.lower_bound,
                    "rate": tp.rate,
                    "actuator_velocity_max": dict(zip(ACTUATOR_NAMES, map(float, tp.limits.velocity), strict=True)),
                    "actuator_acceleration_max": dict(
                        zip(ACTUATOR_NAMES, map(float, tp.limits.acceleration), strict=True)
                    ),
                    "final_approach": plan.info.get("final_approach"),
                    "count_approach": approach,
                    "samples": sp.to_json(),
                }
            )
        )
        return 0
    c = console()
    ratio = f"ratio {plan.duration / plan.lower_bound:.3f}" if plan.lower_bound > 0.0 else "the start is the goal"
    c.print(
        f"duration {plan.duration:.3f} s (lower bound {plan.lower_bound:.3f} s, {ratio}), "
        f"{len(sp.t)} samples at {tp.rate:g} Hz"
    )
    c.print("end pose: " + pose_text(sp.pose[-1]))
    c.print(
        "peak |actuator velocity| / limit: "
        + "  ".join(
            f"{n}={np.max(np.abs(sp.actuator_velocity[:, i])) / tp.limits.velocity[i]:.3f}"
            for i, n in enumerate(ACTUATOR_NAMES)
        )
    )
    fa = plan.info.get("final_approach")
    if fa is not None:  # the profile's motion.final_approach: the goto ends rising (or falling) from a via pose
        side = tp.model.profile.motion.final_approach.side  # type: ignore[union-attr]  # fa: it has one
        via = (
            f"none needed (the move {'rises' if side == 'below' else 'falls'} by the offsets)"
            if fa["via"] is None
            else "  ".join(f"{k}={v:+.4f}" for k, v in zip(("x", "z", "roll", "pitch"), fa["via"], strict=True))
        )
        face = "lower" if side == "below" else "upper"
        short = f"; cut short at the {face} face: {', '.join(fa['short'])}" if fa["short"] else ""
        c.print(f"final approach via: {via}{short}")
        if "aim" in fa:  # motion.final_approach.lag: the mechanism aimed beyond the goal, the implement lags onto it
            aim = "  ".join(f"{k}={v:+.4f}" for k, v in zip(("x", "z", "roll", "pitch"), fa["aim"], strict=True))
            cut = (
                f"; cut at the workspace face or the upper height in {', '.join(fa['aim_short'])}: the implement "
                "rests short of the goal there"
                if fa.get("aim_short")
                else ""
            )
            c.print(
                f"mechanism aimed at: {aim} (beyond the goal by the profile's lag of the pin play, on the "
                f"approach's side{cut})"
            )
    if tail is None and tp.model.profile.motion.count_approach is not None:
        c.print(
            "count approach: none at this goal (a via or final count would leave the workspace box or a limit, or "
            "the link would refuse it): the goto ends as its plan does"
        )
    if tail is not None and approach is not None:  # the profile's motion.count_approach: after the plan, whole counts
        c.print(
            f"count approach after the plan: +{tail.approach.duration_s:.2f} s (a goto lasts "
            f"{plan.duration + tail.approach.duration_s:.3f} s), via counts {approach['via_counts']}, final counts "
            f"{approach['final_counts']} ({', '.join(ACTUATOR_NAMES)})"
        )
    if args.plot:
        c.print(f"plot written to {esc(args.plot)}")
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("plan", help="plan a jerk-limited move between poses (no motion)")
    p.add_argument(
        "--to", type=parse_pose_arg, required=True, help="goal, e.g. x=0.05,z=0.25 (unspecified DOF keep their value)"
    )
    p.add_argument("--from", dest="start", type=parse_pose_arg, default=None, help="start pose (default: neutral)")
    p.add_argument(
        "--rate",
        type=bounded_float("--rate", 1.0, 200.0, unit="Hz", lo_open=False),
        default=None,
        help="sampling rate [Hz], 1..200 (default: the profile's, 50)",
    )
    p.add_argument(
        "--speed-scale",
        type=bounded_float("--speed-scale", MIN_SPEED_SCALE, 1.0, lo_open=False),
        default=1.0,
        help=f"fraction of full speed, [{MIN_SPEED_SCALE:g}, 1] (the service's range), default 1",
    )
    p.add_argument(
        "--plot", default=None, type=plot_path, help="write a PNG of pose, actuators and velocities with limits"
    )
    add_model_options(p)
    p.set_defaults(handler=_cmd_plan)
