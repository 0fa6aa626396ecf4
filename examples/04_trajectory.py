"""A jerk-limited move between two poses, planned with Ruckig and sampled at the control rate.

The plan follows a straight line in pose space (x, z, roll, pitch) with every DOF starting
and stopping together; actuator velocity, acceleration and jerk limits come from the valves
and ramp times of the profile. Every sample is checked against every limit before the plan
is returned (a PlanError names the limit otherwise).
"""

import numpy as np

from planner import ACTUATOR_NAMES, HitchModel, MotionState, TrajectoryPlanner

model = HitchModel.from_profile()
planner = TrajectoryPlanner(model)  # samples at the profile's control rate (50 Hz)

start = MotionState.at_rest(model.neutral_pose.controlled())
plan = planner.plan_move(start, {"x": 0.04, "z": 0.25, "roll": 0.03})  # pitch keeps its value
print(f"duration {plan.duration:.3f} s (time-optimal lower bound {plan.lower_bound:.3f} s)")

for t in np.linspace(0.0, plan.duration, 5):
    s = plan.state_at(t)
    x, z, roll, pitch = s.position
    print(
        f"t = {t:5.3f} s: x = {x:+.4f} m, z = {z:+.4f} m, roll = {roll:+.4f} rad, pitch = {pitch:+.4f} rad, "
        f"dz/dt = {s.velocity[1]:+.4f} m/s"
    )

sp = plan.setpoints if plan.setpoints is not None else planner.sample(plan)
print(f"{len(sp.t)} samples at {sp.rate:g} Hz; peak |actuator velocity| / limit:")
peak = np.abs(sp.actuator_velocity).max(axis=0) / planner.limits.velocity
print("  " + ", ".join(f"{n} {r:.2f}" for n, r in zip(ACTUATOR_NAMES, peak, strict=True)))
