"""The exact inverse: a pose (x, z, roll, pitch) -> the five actuators, in closed form.

:class:`ExactInverse` ignores every limit (strokes, top-link angles): it is the geometric
truth the constrained IK is checked against. Its Jacobian d actuators / d pose comes with it.
"""

import numpy as np

from planner import ExactInverse, HitchModel, KinematicsError

model = HitchModel.from_profile()
inverse = ExactInverse(model)

x, z, roll, pitch = 0.03, 0.20, 0.02, -0.03  # m, m, rad, rad
q = inverse.actuators(x, z, roll, pitch)
print("actuators: " + ", ".join(f"{k} = {v:.5f}" for k, v in q.as_dict().items()) + "  (lift rad, others m)")

# Round trip through the forward kinematics.
p = model.forward(q).pose
error = np.abs(p.controlled() - [x, z, roll, pitch]).max()
print(
    f"forward kinematics gives x = {p.x:+.5f} m, z = {p.z:+.5f} m, roll = {p.roll:+.5f} rad, "
    f"pitch = {p.pitch:+.5f} rad; largest error {error:.1e}"
)

# The Jacobian: how far each actuator moves per metre / radian of each pose coordinate.
_, jac = inverse.solve([x, z, roll, pitch])
print(f"d lift / d z = {jac[0, 1]:.3f} rad/m, d top / d pitch = {jac[2, 3]:.3f} m/rad")

# A pose the linkage cannot take at all.
try:
    inverse(0.0, 2.0, 0.0, 0.0)
except KinematicsError as exc:
    print(f"z = 2 m: {exc}")
