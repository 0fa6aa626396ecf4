"""Constrained inverse kinematics: the nearest pose the hitch can reach within every limit.

:class:`IKSolver` solves a small QP per SQP iteration over the five actuators: strokes as
bounds, the implement span as an equality, top-link angles and ground clearance as
inequalities. A reachable target comes back with status "ok"; one out of reach comes back
"limited", with the nearest reachable pose and the limits that stop it.
"""

from planner import ACTUATOR_UNITS, HitchModel, IKSolver, Target

model = HitchModel.from_profile()
solver = IKSolver(model)
solver.solve(Target(0.0, model.neutral_pose.z, 0.0, 0.0))  # the first solve builds the QP; later ones reuse it


def show(label: str, target: Target) -> None:
    res = solver.solve(target)
    print(f"{label}: status {res.status}, {res.iterations} iterations, {res.solve_time_s * 1e6:.0f} µs")
    if res.actuators is not None and res.pose is not None:
        q = res.actuators.as_dict()
        print("  actuators: " + ", ".join(f"{k} = {v:.4f} {ACTUATOR_UNITS[k]}" for k, v in q.items()))
        p = {k: round(v, 4) + 0.0 for k, v in res.pose.as_dict().items()}  # +0.0000, never -0.0000
        print(f"  pose: x = {p['x']:+.4f} m, z = {p['z']:+.4f} m, roll = {p['roll']:+.4f} rad, ", end="")
        print(f"pitch = {p['pitch']:+.4f} rad")
    if res.active:
        print("  active limits: " + ", ".join(res.active))


show("within reach", Target(x=0.02, z=0.20, roll=0.01, pitch=0.0))
# 0.3 m to the side is far beyond the sway limiters: the nearest reachable pose is returned.
show("out of reach", Target(x=0.30, z=0.20, roll=0.0, pitch=0.0))
# Weights say which DOF to keep when the target is out of reach (x, z, roll, pitch).
show("out of reach, height first", Target(x=0.30, z=0.20, roll=0.0, pitch=0.0, weights=(0.1, 10.0, 1.0, 1.0)))
