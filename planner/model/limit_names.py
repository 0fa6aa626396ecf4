"""Names of limits as values: ``stroke:lift:min``, ``workspace:x:max``, ``top_link_yaw_min``, ...

Every limit the planner reports (IK ``active`` and ``at_bound`` lists, plan violations,
kinematic margins, jog flags, guard reasons) is named by one scheme, and :class:`LimitName`
is that scheme as a value. Two spellings exist:

* ``<kind>:<member>:<side>``, parts left out when empty: ``stroke:<actuator>:min|max``,
  ``workspace:<dof>:min|max`` (any task-bound label in place of ``workspace``),
  ``velocity:<actuator>``, ``acceleration:<actuator>``, ``jerk:<actuator>``, ``end_stop:<actuator>``,
  ``keep_out:<sphere name>``;
* the hitch's feature limits, joined with ``_`` as the profile names them (``flat``):
  ``top_link_yaw_min|max``, ``top_link_pitch_min|max``, ``ground_clearance_left|right``
  (and ``z_left_end_max``, ``z_right_end_max``, the unbounded upper sides of the clearance rows).

``str(name)`` is the string; :meth:`LimitName.parse` reads it back, and
``str(LimitName.parse(s)) == s`` for every name the planner produces. Whatever leaves the
planner (IK results, :class:`~planner.trajectory.plan.Violation`, guard reasons, JSON) stays a
plain ``str``; the value type is for building and taking names apart.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from planner.errors import HitchInputError

__all__ = ["FEATURE_KINDS", "SIDELESS_KINDS", "LimitName", "LimitNameError", "Side", "beyond_words"]

Side = Literal["", "min", "max"]
_SIDES: tuple[str, ...] = ("min", "max")

#: Kinds spelled with ``_`` (``flat``): the hitch's feature-limit rows, longest first for parsing.
FEATURE_KINDS: tuple[str, ...] = ("top_link_pitch", "top_link_yaw", "ground_clearance", "z_right_end", "z_left_end")
#: Kinds named ``<kind>:<member>`` without a side; the member is everything after the first ``:``
#: (a keep-out sphere's name may itself contain ``:``).
SIDELESS_KINDS: tuple[str, ...] = ("velocity", "acceleration", "jerk", "end_stop", "keep_out")


class LimitNameError(HitchInputError):
    """A string or field values that do not form a limit name; the message says which part."""


@dataclass(frozen=True)
class LimitName:
    """One limit's name.

    Attributes:
        kind: What is limited: ``"stroke"``, a task-bound label (``"workspace"``), ``"velocity"``,
            ``"acceleration"``, ``"jerk"``, ``"end_stop"``, ``"keep_out"`` or a feature kind (:data:`FEATURE_KINDS`).
        member: Which one: an actuator, a DOF, a side of the hitch (``"left"``), a keep-out name;
            ``""`` when the kind has only one.
        side: ``"min"`` or ``"max"`` for the bound reached, ``""`` when the limit has one side only.
        flat: Spelled with ``_`` (feature limits: ``top_link_yaw_min``); else with ``:``.
    """

    kind: str
    member: str = ""
    side: Side = ""
    flat: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.kind, str) or not self.kind or ":" in self.kind:
            raise LimitNameError(f"limit name: kind must be a non-empty string without ':', got {self.kind!r}")
        if not isinstance(self.member, str):
            raise LimitNameError(f"limit name: member must be a string, got {self.member!r}")
        if self.side not in ("", *_SIDES):
            raise LimitNameError(f"limit name: side must be 'min', 'max' or '', got {self.side!r}")
        if self.flat:
            if self.kind not in FEATURE_KINDS:
                raise LimitNameError(
                    f"limit name: only the feature kinds ({', '.join(FEATURE_KINDS)}) are spelled with '_', "
                    f"got {self.kind!r}"
                )
            if self.member and self.side:
                raise LimitNameError("limit name: a feature limit has a member or a side, not both")
            if ":" in self.member:
                raise LimitNameError(f"limit name: a feature limit's member cannot contain ':', got {self.member!r}")

    def __str__(self) -> str:
        parts = [p for p in (self.kind, self.member, self.side) if p]
        return ("_" if self.flat else ":").join(parts)

    @classmethod
    def parse(cls, text: str) -> LimitName:
        """The :class:`LimitName` whose ``str()`` is ``text``; :class:`LimitNameError` if none is."""
        if not isinstance(text, str) or not text:
            raise LimitNameError(f"limit name: expected a non-empty string, got {text!r}")
        name = cls._split(text)
        if str(name) != text:  # empty parts ("stroke::min", "top_link_yaw_") spell no name
            raise LimitNameError(f"limit name: {text!r} is not of the form kind[:member][:min|max]")
        return name

    @classmethod
    def _split(cls, text: str) -> LimitName:
        if ":" in text:
            kind, _, rest = text.partition(":")
            if not kind:
                raise LimitNameError(f"limit name: {text!r} has no kind before ':'")
            if kind in SIDELESS_KINDS:
                return cls(kind, rest)
            member, sep, side = rest.rpartition(":")
            if sep and side in _SIDES:
                return cls(kind, member, "min" if side == "min" else "max")
            if rest in _SIDES:
                return cls(kind, "", "min" if rest == "min" else "max")
            return cls(kind, rest)
        for kind in FEATURE_KINDS:
            if text == kind:
                return cls(kind, flat=True)
            if text.startswith(kind + "_"):
                rest = text[len(kind) + 1 :]
                if rest in _SIDES:
                    return cls(kind, side="min" if rest == "min" else "max", flat=True)
                return cls(kind, rest, flat=True)
        return cls(text)


def beyond_words(dof: str, high: bool) -> str:
    """How a value of pose DOF ``dof`` beyond its workspace range is said: x lies **left of** (``high``: +x is
    the driver's left) or **right of** the workspace — "goal.x = 0.1 m is above the workspace" read as a
    height — and z, roll, pitch lie **above** or **below** it."""
    if dof == "x":
        return "left of" if high else "right of"
    return "above" if high else "below"
