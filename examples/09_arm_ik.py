"""The serial arm: closed-form inverse kinematics of a 6R arm with a spherical wrist.

The worked example of the arm source (``planner/profiles/arms/arm-source-example.toml``,
lengths in metres): a tool pose has up to eight solutions (shoulder right/left × elbow
up/down × two wrist branches), each checked by forward kinematics.
"""

import math

import numpy as np

from planner.arm import (
    build_spherical_wrist_arm,
    forward_kinematics,
    load_arm_profile,
    select_nearest_solution,
    solve_arm_ik,
)

arm = build_spherical_wrist_arm(load_arm_profile("arm-source-example").chain())

position = [0.100, 0.050, 0.120]  # m
rotation = [[-0.1219, -0.9917, 0.0406], [-0.1241, -0.0253, -0.9919], [0.9847, -0.1260, -0.1200]]  # 4 decimals

result = solve_arm_ik(arm, position, rotation)  # the rotation is projected onto SO(3) first
wx, wy, wz = result.wrist_centre
print(f"wrist centre ({wx:.4f}, {wy:.4f}, {wz:.4f}) m; {len(result.solutions)} solutions")
for s in result.solutions:  # label: shoulder/elbow/wrist branch
    rad = ", ".join(f"{q:+.5f}" for q in s.joints)
    print(f"  {s.label:<14} q = [{rad}] rad, fk error {s.fk_error:.1e}")
first = result.solutions[0]
print("first solution [deg]: " + ", ".join(f"{math.degrees(q):.4f}" for q in first.joints))
# The source applies its formulas to the 4-decimal matrix as given: orthonormalize=False gives its numbers (docs/arm.md,
# "All eight solutions", θ6 = -147.4508 of the fig. 3.4 erratum); the projection above moves them by about 1e-3°.
as_given = solve_arm_ik(arm, position, rotation, orthonormalize=False).solutions[0]
print("the matrix as given [deg]: " + ", ".join(f"{math.degrees(q):.4f}" for q in as_given.joints))

# The admissible solution nearest a reference posture, checked by forward kinematics.
best = select_nearest_solution(arm, result, np.zeros(6))
tool = forward_kinematics(arm.chain, best.joints)
print(f"nearest zero posture: {best.label}; tool at {np.round(tool.position, 6).tolist()} m")
