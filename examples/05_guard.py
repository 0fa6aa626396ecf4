"""The guard: every plan is checked for limits and tractor stability before anything moves.

:class:`Guard` evaluates all samples of a plan (axle loads and the 20 % front-axle rule,
static, longitudinal and energy stability margins, keep-out volumes, end-stop zone). It
returns the plan unchanged or slowed, or refuses it naming the measure, the value, the
threshold and the time in the plan.
"""

from planner import Guard, GuardRefusal, HitchModel, MotionState, TrajectoryPlanner, load_tractor_profile

model = HitchModel.from_profile()
planner = TrajectoryPlanner(model)

# No implement, level ground: an ordinary move is accepted as planned.
guard = Guard(planner)
start = MotionState.at_rest(model.neutral_pose.controlled())
checked = guard.plan(start, {"x": 0.03, "z": 0.25})
print(
    f"level ground, no implement: {checked.decision.action}, {checked.plan.duration:.2f} s, "
    f"speed factor {checked.decision.speed_factor:.2f}"
)
rep = guard.stability_at(checked.setpoints.actuators[-1])
print(
    f"  at the goal: front axle {rep.axle_loads.front:.0f} N, rear axle {rep.axle_loads.rear:.0f} N, "
    f"static stability margin (SSM) {rep.ssm:.3f} m, energy stability margin (ESM) {rep.esm:.0f} J"
)

# Lifting an implement from the bottom to the top of the workspace, on level ground and on a
# 0.35 rad side slope (left side up): a light spreader, then a 1500 kg power harrow.
implements = load_tractor_profile(model.profile.stability.tractor_profile)
low, high = planner.lo[1], planner.hi[1]  # the workspace's z range [m]
for name, slope in (("cat2-spreader-400", 0.0), ("cat2-spreader-400", 0.35), ("cat2-power-harrow-1500", 0.35)):
    g = Guard(planner, implement=implements.implement(name))
    g.set_slope(slope, 0.0)  # tractor roll, pitch [rad]
    try:
        checked = g.plan(MotionState.at_rest([0.0, low, 0.0, 0.0]), {"z": high})
    except GuardRefusal as refusal:  # nothing moves; the reasons say why
        print(f"{name}, slope {slope:.2f} rad: {refusal}")
        continue
    why = "; ".join(f"{r.level}: {r.sentence()}" for r in checked.decision.reasons)
    print(
        f"{name}, slope {slope:.2f} rad: {checked.decision.action}, speed factor "
        f"{checked.decision.speed_factor:.2f}, {checked.plan.duration:.2f} s" + (f" ({why})" if why else "")
    )
