"""Operator words for the service's limit codes: what the terminal writes instead of ``workspace:roll:max``.

The service names every limit by one scheme (:class:`planner.model.limit_names.LimitName`:
``stroke:top:max``, ``workspace:x:min``, ``velocity:lift``, ``top_link_yaw_max``,
``ground_clearance_left``, ``end_stop:tilt``, ``keep_out:<sphere>``) and its stability guard by
the measures ``front_axle_load``, ``ssm``, ``lsm``, ``esm``. Those codes reach the page in
``state.limited`` (keys: jog directions ``x+``/``x-`` …, track DOFs ``roll``/``vroll`` …, guard
measures; values: a limit name or the guard's ``"<level>: <sentence>"``), in the kinematic
margin's ``limit`` and in refusals. This module is the table from code to words, pure (no
model, no I/O):

* :data:`MEMBER_WORDS` — actuators and DOFs as the operator calls them;
* :data:`KIND_WORDS` — ``(kind, side)`` → a sentence with ``{m}`` for the member;
* :data:`WORKSPACE_WORDS` — the workspace faces, ``(dof, side)`` → words (``+x`` is the driver's
  left, roll ``+`` the left side down, pitch ``+`` the mast top towards the tractor);
* :data:`MEASURE_WORDS` — the guard's stability measures;
* :data:`IMPLEMENT_WORDS` — the implement's own limits (:mod:`planner.limits.implement_limits`: their names
  have spaces, ``implement lowering speed limit``);
* :data:`KEY_WORDS` — the keys of ``state.limited`` that are not limit names (what was being
  commanded when the limit bit);
* :data:`HIGHLIGHT` — which drawn member of the hitch picture a code lights up.

:func:`words` gives the operator sentence of one code (None when the table has none — the tests
check that every code the service can emit has one); :func:`limited_words` the sentence of one
``state.limited`` entry, with the guard's numbers in the operator's units when it knows the
tractor's weight; :func:`limited_entries` all entries of one ``state.limited``, each limit once (a
track DOF flagged by a limit and the guard's reason on that limit are one entry).
"""

from __future__ import annotations

import re
from collections.abc import Mapping

from planner.model.limit_names import LimitName, LimitNameError

__all__ = [
    "MEMBER_WORDS",
    "KIND_WORDS",
    "WORKSPACE_WORDS",
    "MEASURE_WORDS",
    "IMPLEMENT_WORDS",
    "KEY_WORDS",
    "HIGHLIGHT",
    "words",
    "highlight",
    "limited_words",
    "limited_entries",
]

#: actuators (``ACTUATOR_NAMES``), controlled DOFs and hitch sides as the operator calls them
MEMBER_WORDS: dict[str, str] = {
    "lift": "lift arm",
    "tilt": "tilt cylinder (right lift rod)",
    "top": "top link",
    "left": "left sway limiter",
    "right": "right sway limiter",
    "x": "lateral position",
    "z": "height",
    "roll": "roll",
    "pitch": "pitch",
}
#: the member of a ``ground_clearance_<side>`` / ``z_<side>_end`` limit
SIDE_WORDS: dict[str, str] = {"left": "left", "right": "right"}

#: ``(kind, side)`` → words; ``{m}`` is the member in words (:data:`MEMBER_WORDS`, a keep-out name)
KIND_WORDS: dict[tuple[str, str], str] = {
    ("stroke", "min"): "{m} at its stroke end (shortest)",
    ("stroke", "max"): "{m} at its stroke end (longest)",
    ("velocity", ""): "{m} at its speed limit",
    ("acceleration", ""): "{m} at its acceleration limit",
    ("jerk", ""): "{m} at its jerk limit",
    ("end_stop", ""): "{m} slowing before its stroke end",
    ("keep_out", ""): "top link close to the {m}",
    ("top_link_yaw", "min"): "top link at its sideways limit (swung left)",
    ("top_link_yaw", "max"): "top link at its sideways limit (swung right)",
    ("top_link_pitch", "min"): "top link at its downward angle limit",
    ("top_link_pitch", "max"): "top link at its upward angle limit",
    ("ground_clearance", ""): "{m} lower hitch point at its ground clearance",
    ("z_left_end", "max"): "left lower hitch point at its highest",
    ("z_right_end", "max"): "right lower hitch point at its highest",
}
#: the lift arms' stroke is an angle: their ends in words
LIFT_STROKE_WORDS: dict[str, str] = {
    "min": "lift arm at its lowest (stroke end)",
    "max": "lift arm at its highest (stroke end)",
}

#: ``workspace:<dof>:<side>`` → words
WORKSPACE_WORDS: dict[tuple[str, str], str] = {
    ("x", "max"): "left limit reached (lateral position)",
    ("x", "min"): "right limit reached (lateral position)",
    ("z", "max"): "height limit reached (top)",
    ("z", "min"): "height limit reached (bottom)",
    ("roll", "max"): "roll limit reached (left side down)",
    ("roll", "min"): "roll limit reached (right side down)",
    ("pitch", "max"): "pitch limit reached (mast tilted forward)",
    ("pitch", "min"): "pitch limit reached (mast tilted back)",
}

#: the stability guard's measures (:data:`planner.limits.stability.Measure`)
MEASURE_WORDS: dict[str, str] = {
    "front_axle_load": "front axle load too low",
    "ssm": "side stability margin too low",
    "lsm": "longitudinal stability margin too low",
    "esm": "tip-over energy margin too low",
}

#: the implement's own limits, by the names the guard and the track follower give them
#: (:data:`planner.limits.implement_limits.UPPER_HEIGHT_LIMIT` … — the tests check the names match)
IMPLEMENT_WORDS: dict[str, str] = {
    "implement upper height limit": "implement at its upper height limit",
    "implement lowering speed limit": "lowering faster than the implement allows",
    "implement transport lock": "implement locked for transport",
}

#: keys of ``state.limited`` that are not limit names: the jog directions and the track DOFs
KEY_WORDS: dict[str, str] = {
    "x+": "moving left",
    "x-": "moving right",
    "z+": "raising",
    "z-": "lowering",
    "roll+": "rolling the left side down",
    "roll-": "rolling the right side down",
    "pitch+": "tilting the mast forward",
    "pitch-": "tilting the mast back",
    "x": "lateral position",
    "z": "height",
    "roll": "roll",
    "pitch": "pitch",
    "vx": "lateral speed",
    "vz": "vertical speed",
    "vroll": "roll speed",
    "vpitch": "pitch speed",
}

#: member of the hitch picture a limit lights up (the page's ``data-member`` names): per actuator,
#: per DOF and per kind
HIGHLIGHT: dict[str, tuple[str, ...]] = {
    "lift": ("lift_arm",),
    "tilt": ("lift_rod_right",),
    "top": ("top_link",),
    "left": ("limiter_left",),
    "right": ("limiter_right",),
    "x": ("implement",),
    "z": ("implement",),
    "roll": ("implement",),
    "pitch": ("mast",),
    "top_link_yaw": ("top_link",),
    "top_link_pitch": ("top_link",),
    "keep_out": ("top_link",),
    "ground_clearance": ("lower_link",),
    "z_left_end": ("lower_link_left",),
    "z_right_end": ("lower_link_right",),
    "stability": ("implement",),
    "implement_limit": ("implement",),
}

#: SSM, LSM [m] and ESM [J] as shown: (factor, unit, digits)
_MEASURE_UNITS: Mapping[str, tuple[float, str, int]] = {
    "ssm": (1.0, "m", 2),
    "lsm": (1.0, "m", 2),
    "esm": (1e-3, "kJ", 1),
}
#: a limit of the implement (:data:`IMPLEMENT_WORDS`) as shown, by its SI unit: (factor, unit, decimals)
_LIMIT_UNITS: Mapping[str, tuple[float, str, int]] = {
    "m/s": (1.0, "m/s", 3),
    "m": (1.0, "m", 3),
}
#: what the guard's level does to the motion
_TAIL: Mapping[str, str] = {"hard": "refused", "caution": "slowed", "speed": "slowed"}
_GUARD = re.compile(  # GuardReason.sentence: the numbers may carry their SI unit ("1.2e+04 N", "0.3 m/s");
    # a measure may have spaces ("implement lowering speed limit"); no unit: a speed factor (threshold 1)
    r"^(?P<level>hard|caution|speed):\s*(?P<measure>\S.*?) would be (?P<value>[-+0-9.eE]+|nan|inf)"
    r"(?: (?P<unit>[^\s()]+))? \(threshold (?P<threshold>[-+0-9.eE]+|nan|inf)(?: [^\s()]+)?\)"
)


def _parse(code: str) -> LimitName | None:
    try:
        return LimitName.parse(code)
    except LimitNameError:
        return None


def words(code: str) -> str | None:
    """The operator sentence for one limit code or guard measure; None when the table has none."""
    if not isinstance(code, str) or not code:
        return None
    if code in MEASURE_WORDS:
        return MEASURE_WORDS[code]
    if code in IMPLEMENT_WORDS:
        return IMPLEMENT_WORDS[code]
    name = _parse(code)
    if name is None:
        return None
    if name.kind == "workspace":
        return WORKSPACE_WORDS.get((name.member, name.side))
    if name.kind == "stroke" and name.member == "lift" and name.side:
        return LIFT_STROKE_WORDS[name.side]
    template = KIND_WORDS.get((name.kind, name.side))
    if template is None:
        return None
    if "{m}" not in template:
        return template if not name.member else None
    if name.kind == "keep_out":
        member = name.member.replace("_", " ")
    elif name.kind == "ground_clearance":
        member = SIDE_WORDS.get(name.member, "")
    else:
        member = MEMBER_WORDS.get(name.member, "")
    if not member:
        return None
    return template.format(m=member)


def highlight(code: str) -> tuple[str, ...]:
    """The drawn members one code lights up in the hitch picture (empty: none)."""
    if code in MEASURE_WORDS:
        return HIGHLIGHT["stability"]
    if code in IMPLEMENT_WORDS:
        return HIGHLIGHT["implement_limit"]
    name = _parse(code) if isinstance(code, str) and code else None
    if name is None:
        return ()
    if name.kind == "ground_clearance":
        return (f"lower_link_{name.member}",) if name.member in SIDE_WORDS else HIGHLIGHT["ground_clearance"]
    if name.kind in HIGHLIGHT:
        return HIGHLIGHT[name.kind]
    return HIGHLIGHT.get(name.member, ())


def percent(factor: float) -> str:
    """A speed factor [1] as a share of full speed: ``51 %``; a share below 1 % with one significant digit
    (``0.4 %``), never a ``0 %`` that is not zero."""
    pct = 100.0 * float(factor)
    return f"{pct:.1g} %" if 0.0 < pct < 0.95 else f"{pct:.0f} %"


def _guard_words(m: re.Match[str], tractor_weight_n: float | None) -> str:
    """The words of one parsed guard sentence (:data:`_GUARD`); the numbers in the operator's units."""
    measure, level, unit = m.group("measure"), m.group("level"), m.group("unit") or ""
    v, th = float(m.group("value")), float(m.group("threshold"))
    base = words(measure) or measure
    tail = _TAIL[level]
    bound = "minimum" if level == "hard" else "slows below"
    if measure == "front_axle_load" and tractor_weight_n:
        share, limit = 100.0 * v / tractor_weight_n, 100.0 * th / tractor_weight_n
        return f"front axle load {share:.0f} % of the tractor's weight ({bound} {limit:.0f} %): {tail}"
    if measure in _MEASURE_UNITS:
        k, shown, digits = _MEASURE_UNITS[measure]
        return f"{base}: {v * k:.{digits}f} {shown} ({bound} {th * k:.{digits}f} {shown}): {tail}"
    if measure in MEASURE_WORDS:
        return f"{base}: {tail}"
    if level == "speed" and not unit:  # GuardReason: no unit is a speed factor (threshold 1)
        return f"{base}: slowed to {percent(v)}"
    if measure in IMPLEMENT_WORDS and unit in _LIMIT_UNITS:
        k, shown, digits = _LIMIT_UNITS[unit]
        return f"{base}: {v * k:.{digits}f} {shown} (limit {th * k:.{digits}f} {shown}): {tail}"
    return base  # keep-outs say it themselves


def limited_words(key: str, value: str, tractor_weight_n: float | None = None) -> str:
    """One ``state.limited`` entry in words.

    ``value`` is a limit name (``workspace:x:max``) or the guard's ``"<level>: <measure> would be
    <value> (threshold <threshold>) …"``; the guard's numbers come out in the operator's units:
    the front-axle load as a share of the empty tractor's weight ``tractor_weight_n`` [N] (when
    given), SSM and LSM in m, ESM in kJ, a speed factor (no unit) as a share of full speed [%], the
    implement's lowering speed [m/s] and height [m] beside their limit. Anything the table does not
    know stays as it came (``key: value``), never dropped.
    """
    text = str(value)
    w = words(text)
    if w is not None:
        return w
    m = _GUARD.match(text)
    if m is not None:
        return _guard_words(m, tractor_weight_n)
    kw = KEY_WORDS.get(key)
    return f"{kw}: {text}" if kw is not None else f"{key}: {text}"


def _guard_measure(value: str) -> str | None:
    """The measure of a guard sentence (``"speed: <measure> would be …"``); None for anything else."""
    m = _GUARD.match(value)
    return None if m is None else m.group("measure")


def limited_entries(limited: Mapping[str, object], tractor_weight_n: float | None = None) -> list[tuple[str, str]]:
    """The entries of one ``state.limited`` (or a track session's ``control_limited``) as ``(key, words)``,
    in their order, each limit once: a key flagged by a limit (``"vz": "implement lowering speed limit"``)
    beside the guard's reason on that limit (``"implement lowering speed limit": "speed: … would be 0.06 m/s
    (threshold 0.05 m/s) …"``) is one entry, the flagged key with the guard's words and numbers.
    ``tractor_weight_n`` [N] as for :func:`limited_words`."""
    items = {str(k): str(v) for k, v in limited.items()}
    said_by = {v: k for k, v in items.items() if v != k and v in items and _guard_measure(items[v]) == v}
    out: list[tuple[str, str]] = []
    for k, v in items.items():
        if k in said_by:
            continue  # said under the key its limit flags
        if said_by.get(v) == k:
            out.append((k, limited_words(v, items[v], tractor_weight_n)))
        else:
            out.append((k, limited_words(k, v, tractor_weight_n)))
    return out
