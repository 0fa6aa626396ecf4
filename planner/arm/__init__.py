"""Serial arms: rotations and transforms, Denavit-Hartenberg chains, arm profiles, the closed-form
inverse of a 6R arm with a spherical wrist, and the arm as a mechanism of the SQP IK core.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from planner.arm.analytic import (
        ArmIKResult,
        ArmIKSolution,
        ArmStructureError,
        NoAdmissibleSolutionError,
        SphericalWristArm,
        UnreachableTargetError,
        build_spherical_wrist_arm,
        select_nearest_solution,
        solve_arm_ik,
    )
    from planner.arm.dh import (
        CasadiChain,
        ChainFrames,
        DHChain,
        DHLink,
        JointLimitError,
        build_casadi_chain,
        build_dh_chain,
        check_joint_vector,
        forward_kinematics,
        geometric_jacobian,
        limit_violations,
    )
    from planner.arm.mechanism import arm_target, arm_weights, build_arm_mechanism
    from planner.arm.profile import (
        DEFAULT_ARM_PROFILE,
        ArmProfile,
        ArmProfileError,
        arm_profile_from_dict,
        available_arm_profiles,
        load_arm_profile,
    )
    from planner.arm.transforms import (
        ArmInputError,
        EulerZYZ,
        RotationMatrixError,
        ZYZSolution,
        check_rotation,
        check_transform,
        euler_zyz_matrix,
        homogeneous,
        invert_transform,
        rotx,
        roty,
        rotz,
        solve_euler_zyz,
    )

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "ArmInputError",
            "RotationMatrixError",
            "EulerZYZ",
            "ZYZSolution",
            "rotx",
            "roty",
            "rotz",
            "homogeneous",
            "invert_transform",
            "check_rotation",
            "check_transform",
            "euler_zyz_matrix",
            "solve_euler_zyz",
        ),
        "planner.arm.transforms",
    ),
    **dict.fromkeys(
        (
            "JointLimitError",
            "DHLink",
            "DHChain",
            "ChainFrames",
            "CasadiChain",
            "build_dh_chain",
            "build_casadi_chain",
            "forward_kinematics",
            "geometric_jacobian",
            "check_joint_vector",
            "limit_violations",
        ),
        "planner.arm.dh",
    ),
    **dict.fromkeys(
        (
            "ArmProfileError",
            "ArmProfile",
            "DEFAULT_ARM_PROFILE",
            "load_arm_profile",
            "arm_profile_from_dict",
            "available_arm_profiles",
        ),
        "planner.arm.profile",
    ),
    **dict.fromkeys(
        (
            "ArmStructureError",
            "UnreachableTargetError",
            "NoAdmissibleSolutionError",
            "SphericalWristArm",
            "ArmIKSolution",
            "ArmIKResult",
            "build_spherical_wrist_arm",
            "solve_arm_ik",
            "select_nearest_solution",
        ),
        "planner.arm.analytic",
    ),
    **dict.fromkeys(("build_arm_mechanism", "arm_target", "arm_weights"), "planner.arm.mechanism"),
}

__all__ = [
    "ArmInputError",
    "RotationMatrixError",
    "EulerZYZ",
    "ZYZSolution",
    "rotx",
    "roty",
    "rotz",
    "homogeneous",
    "invert_transform",
    "check_rotation",
    "check_transform",
    "euler_zyz_matrix",
    "solve_euler_zyz",
    "JointLimitError",
    "DHLink",
    "DHChain",
    "ChainFrames",
    "CasadiChain",
    "build_dh_chain",
    "build_casadi_chain",
    "forward_kinematics",
    "geometric_jacobian",
    "check_joint_vector",
    "limit_violations",
    "ArmProfileError",
    "ArmProfile",
    "DEFAULT_ARM_PROFILE",
    "load_arm_profile",
    "arm_profile_from_dict",
    "available_arm_profiles",
    "ArmStructureError",
    "UnreachableTargetError",
    "NoAdmissibleSolutionError",
    "SphericalWristArm",
    "ArmIKSolution",
    "ArmIKResult",
    "build_spherical_wrist_arm",
    "solve_arm_ik",
    "select_nearest_solution",
    "build_arm_mechanism",
    "arm_target",
    "arm_weights",
]

if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports("planner.arm", globals(), _SOURCES)
