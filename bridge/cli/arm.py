"""Command-line layer of the serial-arm kinematics: ``arm fk`` and ``arm ik``.

Two pure functions build the JSON-ready answers, :func:`add_arm_parser` registers the
commands on an argparse sub-parser set (the ``hitch`` CLI plugs it in)::

    hitch arm fk --joints=q1,...,q6 [--profile P] [--json]
    hitch arm ik --position=x,y,z --rotation=r11,r12,...,r33 [--all] [--reference=q1,...,q6]
                 [--profile P] [--json]

Units: positions in metres, joints in radians, the rotation matrix row by row. Write values
that start with a minus sign as ``--rotation=-0.12,...`` (argparse would take ``-0.12,...``
for an option). Each command's handler prints JSON with ``--json`` and a table otherwise and
returns the exit status; errors are raised as :class:`~planner.errors.HitchInputError`
subclasses (bad input, also ``ValueError``) for the CLI to report.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bridge.service.wire import to_json_text
from planner.arm.analytic import (
    ArmStructureError,
    UnreachableTargetError,
    build_spherical_wrist_arm,
    select_nearest_solution,
    solve_arm_ik,
)
from planner.arm.dh import check_joint_vector, forward_kinematics, limit_violations
from planner.arm.profile import DEFAULT_ARM_PROFILE, load_arm_profile

__all__ = ["arm_fk_command", "arm_ik_command", "add_arm_parser", "parse_floats"]


def _list(v) -> list[float]:
    return [float(x) for x in np.asarray(v, dtype=float).reshape(-1)]


def arm_fk_command(joints: Sequence[float], profile: str | Path = DEFAULT_ARM_PROFILE) -> dict:
    """Forward kinematics of an arm profile at ``joints`` [rad or m per joint type].

    Returns ``{"profile", "joints", "position" [m], "rotation" (3x3 rows), "origins" (name ->
    frame origin [m]), "wrist_centre" [m] (only for a 6R spherical-wrist arm), "within_limits",
    "limit_violations"}``.
    """
    prof = load_arm_profile(profile)
    chain = prof.chain()
    q = check_joint_vector(chain, joints, "joints")
    frames = forward_kinematics(chain, q)
    names = ("base",) + chain.names + ("tool",)
    violations = limit_violations(chain, q)
    out = {
        "profile": prof.name,
        "joints": _list(q),
        "position": _list(frames.position),
        "rotation": [_list(row) for row in frames.rotation],
        "origins": {name: _list(frames.origin(i)) for i, name in enumerate(names)},
        "within_limits": not violations,
        "limit_violations": list(violations),
    }
    try:
        build_spherical_wrist_arm(chain)
    except ArmStructureError:
        return out
    out["wrist_centre"] = _list(frames.origin(4))  # origin of frames 4 and 5: the wrist centre
    return out


def arm_ik_command(
    position: Sequence[float],
    rotation: Sequence[float],
    all_solutions: bool = False,
    profile: str | Path = DEFAULT_ARM_PROFILE,
    reference: Sequence[float] | None = None,
) -> dict:
    """Closed-form IK of a 6R spherical-wrist arm profile.

    ``position`` (3,) [m]; ``rotation`` 9 values row-major (or 3x3), projected onto SO(3)
    when slightly non-orthonormal (defect up to 1e-3). Returns::

        {"solutions": [{"joints": [q1..q6 rad], "fk_error": e}], "wrist_centre": [x, y, z]}

    with every solution when ``all_solutions``, else only the admissible one nearest
    ``reference`` (default zeros). ``fk_error = hypot(|Δp| [m], rotation angle [rad])`` of
    the solution's forward kinematics against the solved target. Raises
    :class:`~planner.arm.analytic.UnreachableTargetError` with the reason when no solution
    exists and ``NoAdmissibleSolutionError`` when none is within the joint limits.
    """
    prof = load_arm_profile(profile)
    arm = build_spherical_wrist_arm(prof.chain())
    ref = np.zeros(6) if reference is None else check_joint_vector(arm.chain, reference, "reference")
    result = solve_arm_ik(arm, position, rotation, reference=ref)
    if not result.reachable:
        raise UnreachableTargetError(result.reason)
    chosen = result.solutions if all_solutions else (select_nearest_solution(arm, result, ref),)
    return {
        "solutions": [{"joints": list(s.joints), "fk_error": s.fk_error} for s in chosen],
        "wrist_centre": _list(result.wrist_centre),
    }


def parse_floats(option: str, count: int | None = None):
    """argparse ``type``: comma-separated finite numbers (exactly ``count`` when given)."""

    def parse(text: str) -> list[float]:
        parts = [p for p in text.replace(" ", "").split(",") if p != ""]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise argparse.ArgumentTypeError(f"{option} must be comma-separated numbers, got {text!r}") from None
        if count is not None and len(values) != count:
            raise argparse.ArgumentTypeError(f"{option} needs {count} comma-separated values, got {len(values)}")
        if not values or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{option} values must be finite numbers, got {text!r}")
        return values

    return parse


def _fmt(values: Sequence[float]) -> str:
    return ", ".join(f"{v:+.6f}" for v in values)


def _run_fk(args) -> int:
    out = arm_fk_command(args.joints, args.profile)
    if args.json:
        print(to_json_text(out))
        return 0
    print(f"profile {out['profile']}: joints [{_fmt(out['joints'])}] rad")
    print(f"tool position [{_fmt(out['position'])}] m")
    print("tool rotation " + "; ".join(f"[{_fmt(r)}]" for r in out["rotation"]))
    if "wrist_centre" in out:
        print(f"wrist centre [{_fmt(out['wrist_centre'])}] m")
    print(
        "within joint limits" if out["within_limits"] else "OUTSIDE joint limits: " + "; ".join(out["limit_violations"])
    )
    return 0


def _run_ik(args) -> int:
    out = arm_ik_command(args.position, args.rotation, args.all_solutions, args.profile, args.reference)
    if args.json:
        print(to_json_text(out))
        return 0
    print(f"wrist centre [{_fmt(out['wrist_centre'])}] m")
    for i, s in enumerate(out["solutions"], start=1):
        deg = ", ".join(f"{math.degrees(q):+.4f}" for q in s["joints"])
        print(f"{i}: q = [{_fmt(s['joints'])}] rad = [{deg}] deg, fk error {s['fk_error']:.2e}")
    return 0


def add_arm_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``arm fk`` and ``arm ik`` on an argparse sub-parser set.

    Each leaf parser sets ``handler`` (``handler(args) -> exit status``), the convention of
    ``bridge/cli/main.py``. Returns the ``arm`` parser.
    """
    arm = subparsers.add_parser("arm", help="serial-arm kinematics: DH forward kinematics, closed-form 6R IK")
    sub = arm.add_subparsers(dest="arm_command", required=True)

    p = sub.add_parser("fk", help="forward kinematics of an arm profile: joints [rad] -> tool pose [m]")
    p.add_argument("--joints", type=parse_floats("--joints"), required=True, help="q1,...,qn [rad; m for prismatic]")
    p.add_argument(
        "--profile", default=DEFAULT_ARM_PROFILE, help=f"arm profile name or .toml path (default {DEFAULT_ARM_PROFILE})"
    )
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=_run_fk)

    p = sub.add_parser("ik", help="closed-form IK of a 6R spherical-wrist arm: tool pose -> joints")
    p.add_argument("--position", type=parse_floats("--position", 3), required=True, help="x,y,z [m]")
    p.add_argument("--rotation", type=parse_floats("--rotation", 9), required=True, help="r11,r12,...,r33 row-major")
    p.add_argument("--all", dest="all_solutions", action="store_true", help="all (up to eight) solutions")
    p.add_argument(
        "--reference",
        type=parse_floats("--reference", 6),
        default=None,
        help="q1,...,q6 [rad]: pick the admissible solution nearest this posture (default zeros)",
    )
    p.add_argument(
        "--profile", default=DEFAULT_ARM_PROFILE, help=f"arm profile name or .toml path (default {DEFAULT_ARM_PROFILE})"
    )
    p.add_argument("--json", action="store_true", help="print JSON")
    p.set_defaults(handler=_run_ik)
    return arm
