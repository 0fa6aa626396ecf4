"""Forward kinematics: five actuator positions -> the implement pose and the linkage points.

The model is built from the default hitch profile (``planner/profiles/thesis-t132.toml``) with
an ISO 730 category-2 implement attached. Actuators are always in the order lift [rad], tilt,
top, left, right [m]; the pose is x, y, z [m], roll, pitch, yaw [rad] in the tractor frame
(+x to the driver's left, y rearward, z up).
"""

from planner import ACTUATOR_UNITS, Actuators, HitchModel

model = HitchModel.from_profile("thesis-t132", category="2")

# The neutral posture: mid lift stroke, implement centred and level.
neutral = Actuators.from_array(model.neutral)
print("neutral actuators: " + ", ".join(f"{k} = {v:.4f} {ACTUATOR_UNITS[k]}" for k, v in neutral.as_dict().items()))

# Raise the lift arms by 0.1 rad and lengthen the tilt cylinder (right lift rod) by 10 mm.
q = Actuators(neutral.lift + 0.1, neutral.tilt + 0.010, neutral.top, neutral.left, neutral.right)
state = model.forward(q)  # exact: raises KinematicsError if the linkage cannot close
p = state.pose

print(f"pose after lift +0.1 rad, tilt +10 mm: x = {p.x:+.4f} m, y = {p.y:+.4f} m, z = {p.z:+.4f} m")
print(f"  roll = {p.roll:+.4f} rad (the longer right lift rod), pitch = {p.pitch:+.4f} rad, yaw = {p.yaw:+.4f} rad")
print(f"lower-link span |L - R| = {state.lower_span:.4f} m (implement span {model.span:.4f} m)")
print(
    f"top-link angles from the neutral direction: yaw {state.top_link_angles[0]:+.4f} rad, "
    f"pitch {state.top_link_angles[1]:+.4f} rad"
)
for name in ("L", "R", "T", "U"):  # lower hitch points, tool point T, mast top U
    x, y, z = state.points[name]
    print(f"point {name}: ({x:+.4f}, {y:+.4f}, {z:+.4f}) m")
