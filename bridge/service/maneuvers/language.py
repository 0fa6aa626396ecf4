"""The maneuver language: YAML scripts of ordered hitch steps, parsed strictly and validated by planning.

A maneuver is the headland-sequence idea of commercial hitch systems, written in pose space
(SI: x, z [m]; roll, pitch [rad]; times [s]; distances [m])::

    name: headland-lift                # optional; letters, digits, '-', '_', '.'
    description: lift and centre at the headland
    timeout: 45                        # optional, (0, 3600] s, default 60 s
    steps:
      - speed: 0.6                     # scale (0, 1] for the following motion steps
      - goto: {z: 0.25, pitch: 0.05}   # partial pose: unspecified DOF keep their value
      - wait_for: {distance: 12.0}     # metres travelled (wheel-based speed on the CAN bus)
      - wait_for: {line: headland, complete: true}  # the next step is complete at the line
      - preset: work                   # or {name: work, speed_scale: 0.5}
      - wait: 1.5                      # seconds
      - goto: {x: 0.0, speed_scale: 1.0}

Rules: :func:`parse_maneuver` reads the text with PyYAML's safe loader only, at most
:data:`MAX_SCRIPT_BYTES` and :data:`MAX_STEPS`; anchors/aliases of mappings or lists are refused
(no "billion laughs") and so is nesting deeper than 6 levels, both from one linear pass over the text
before the parser reads it (:class:`_NestingScan`; PyYAML's time grows with the square of the nesting); a
key written twice in one mapping is an error naming the key and its line (plain YAML keeps the last one
silently); every step is a mapping with exactly one step key;
speed scales are at least :data:`MIN_SPEED_SCALE` (0.05: plan time grows as 1/scale); unknown keys, wrong
types, NaN/inf and out-of-range values are errors ``{"step": index, "message": ...}`` naming the
field and the allowed range (``step`` is the 0-based index in ``steps``, ``None`` for the
top level). Nothing raises but :class:`ManeuverError` (a :class:`~planner.errors.HitchInputError`,
hence a ``ValueError``).

Speed scale of a motion step: its own ``speed_scale`` if given; else, for a preset, the
preset's stored speed scale; else the scale set by the last ``speed`` step (1.0 at the start).

The step schema (one pydantic model per step kind, :class:`ManeuverScript`, the bounds and
:func:`check_name`) is in :mod:`bridge.service.maneuvers.steps` and re-exported here.

:func:`validate` plans every motion step from the given start state through a ``plan_step``
callable (the service passes :func:`guarded_plan_step`, i.e. the trajectory planner and the
stability guard) before anything moves, and checks that the planned time fits the timeout.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import yaml
from pydantic import BaseModel, ValidationError

from bridge.service.maneuvers.steps import (  # the step schema; re-exported (see __all__)
    _KINDS,
    DEFAULT_TIMEOUT_S,
    MAX_TIMEOUT_S,
    MIN_SPEED_SCALE,
    NAME_PATTERN,
    POSE_BOUNDS,
    GotoStep,
    ManeuverSchemaError,
    ManeuverScript,
    PresetStep,
    SpeedStep,
    Step,
    WaitForStep,
    WaitStep,
    _Header,
    _show,
    check_name,
    step_words,
)
from planner.errors import HitchInputError, unit_hint_within
from planner.model.types import CONTROLLED_POSE_UNITS
from planner.trajectory import MotionState

if TYPE_CHECKING:
    from planner.limits.guard import Guard

__all__ = [
    "MAX_SCRIPT_BYTES",
    "MAX_STEPS",
    "DEFAULT_TIMEOUT_S",
    "MIN_SPEED_SCALE",
    "POSE_BOUNDS",
    "NAME_PATTERN",
    "ManeuverError",
    "ManeuverSchemaError",
    "StepError",
    "GotoStep",
    "PresetStep",
    "WaitStep",
    "WaitForStep",
    "SpeedStep",
    "ManeuverScript",
    "PlannedStep",
    "ValidationResult",
    "PlanningContext",
    "PlanStep",
    "PresetLike",
    "parse_maneuver",
    "validate",
    "guarded_plan_step",
    "goto_workspace_errors",
    "StepPlan",
    "pose_tolerance",
    "within_tolerance_s",
    "check_name",
]

MAX_SCRIPT_BYTES = 64 * 1024
MAX_STEPS = 500
_MAX_DEPTH = 6
_MAX_NODES = 20_000
_TOO_DEEP = f"the script nests deeper than {_MAX_DEPTH} levels"
_ALIASED = "YAML anchors/aliases of mappings or lists are not allowed"
_UNITS = {**CONTROLLED_POSE_UNITS, "seconds": "s", "distance": "m", "timeout": "s"}


class ManeuverError(HitchInputError):
    """A maneuver script that cannot be used; ``errors`` lists ``StepError`` values (step index + message)."""

    def __init__(self, errors: Iterable[StepError]):
        self.errors = tuple(errors)
        super().__init__("; ".join(e.sentence() for e in self.errors[:5]))


@dataclass(frozen=True)
class StepError:
    step: int | None  # 0-based index into ``steps``; None: the script as a whole
    message: str

    def to_json(self) -> dict:
        return {"step": self.step, "message": self.message}

    def sentence(self) -> str:
        return self.message if self.step is None else f"{step_words(self.step)}: {self.message}"


# ---------------------------------------------------------------------------------------- parsing
def _range(model: type[BaseModel], name: str) -> str:
    info = model.model_fields.get(name)
    if info is None:
        return ""
    parts = [
        f"{sym} {getattr(m, a):.6g}"
        for m in info.metadata
        for a, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="))
        if getattr(m, a, None) is not None
    ]
    unit = _UNITS.get(name, "")
    return f" (allowed: {name} {' and '.join(parts)}{' ' + unit if unit else ''})" if parts else ""


def _errors(exc: ValidationError, model: type[BaseModel], where: str, step: int | None) -> list[StepError]:
    out = []
    for e in exc.errors(include_url=False):
        loc = [str(p) for p in e["loc"]]
        fld = loc[0] if loc else ""
        path = ".".join([where] + loc) if where else ".".join(loc) or "script"
        if e["type"] == "extra_forbidden":
            allowed = ", ".join(model.model_fields)
            out.append(StepError(step, f"{path}: unknown key (allowed: {allowed})"))
            continue
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "missing":
            msg = "is required"
        elif e["type"] in ("greater_than", "greater_than_equal", "less_than", "less_than_equal"):
            msg = "out of range"
        elif e["type"] == "finite_number":
            msg = "must be a finite number (NaN and infinity are not allowed)"
        elif e["type"] == "string_type":  # pydantic's "Input should be a valid string" said in the script's words
            msg = "must be text (a name such as headland-lift)"
        elif e["type"] in ("float_type", "float_parsing", "int_type", "int_parsing"):
            msg = "must be a number"
        elif e["type"] in ("model_type", "dict_type"):
            msg = "must be a mapping ({key: value, …})"
        shown = "" if e["type"] == "missing" or not loc else f" = {_show(e.get('input'))}"
        hint = _unit_hint(model, fld, e.get("input")) if msg == "out of range" else ""
        out.append(StepError(step, f"{path}{shown}: {msg}{_range(model, fld)}{hint}"))
    return out


def _unit_hint(model: type[BaseModel], name: str, value: object) -> str:
    """``; did you mean mm? …`` (or degrees) for a pose value out of range that fits read so (`goto: {z: 250}`
    named only the ±2 m, where the CLI's goto hinted at mm)."""
    info = model.model_fields.get(name)
    if info is None or isinstance(value, bool) or not isinstance(value, (int, float)):
        return ""
    return unit_hint_within(float(value), info.metadata, _UNITS.get(name, ""))


class _UniqueKeyLoader(yaml.SafeLoader):
    """PyYAML's safe loader, but a key written twice in one mapping is an error (naming the key and line), and
    a collection nested deeper than :data:`_MAX_DEPTH` is refused as it starts (:class:`ManeuverError`): the
    exact limit behind :class:`_NestingScan`'s cheap one (which may count fewer levels: ``[a: [b: …]]``)."""

    _open = 0  # collections being composed around the next node

    def compose_node(self, parent: yaml.Node | None, index: int) -> yaml.Node | None:
        if not self.check_event(yaml.SequenceStartEvent, yaml.MappingStartEvent):
            return super().compose_node(parent, index)
        if self._open >= _MAX_DEPTH:
            raise ManeuverError([StepError(None, _TOO_DEEP)])
        self._open += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._open -= 1

    def construct_mapping(self, node: yaml.MappingNode, deep: bool = False) -> dict[Any, Any]:
        seen: dict[Any, Any] = {}
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge" or not isinstance(key_node, yaml.ScalarNode):
                continue  # '<<' merges may override; non-scalar keys are refused later
            key = self.construct_object(key_node, deep=False)
            try:
                first = seen.setdefault(key, key_node)
            except TypeError:  # an unhashable key: the base constructor reports it
                continue
            if first is not key_node:
                raise yaml.constructor.ConstructorError(
                    f"while constructing a mapping (first {key!r} at line {first.start_mark.line + 1})",
                    node.start_mark,
                    f"duplicate key {_show(key)} (each key may appear once in a mapping)",
                    key_node.start_mark,
                )
        return super().construct_mapping(node, deep=deep)


# YAML 1.2 core-schema numbers instead of PyYAML's YAML 1.1 ones: ``1e-3`` and ``-.0`` are numbers (1.1
# read them as strings, refused as "not a valid number"), ``0x10``, ``1_0`` and ``1:30`` are not (1.1 read
# 16, 10 and 90: sexagesimal); .inf / .nan stay numbers for the finite check to refuse by name.
_INT, _FLOAT = "tag:yaml.org,2002:int", "tag:yaml.org,2002:float"
_UniqueKeyLoader.yaml_implicit_resolvers = {
    first: [(tag, rx) for tag, rx in resolvers if tag not in (_INT, _FLOAT)]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_UniqueKeyLoader.add_implicit_resolver(_INT, re.compile(r"^[-+]?[0-9]+$"), list("-+0123456789"))


def _decimal_int(loader: yaml.SafeLoader, node: yaml.Node) -> int:
    """An integer scalar in base 10 (YAML 1.1's constructor reads a leading 0 as octal: 010 was 8)."""
    assert isinstance(node, yaml.ScalarNode)
    return int(loader.construct_scalar(node))


_UniqueKeyLoader.add_constructor(_INT, _decimal_int)
_UniqueKeyLoader.add_implicit_resolver(
    _FLOAT,
    re.compile(
        r"^(?:[-+]?(?:\.[0-9]+|[0-9]+(?:\.[0-9]*)?)(?:[eE][-+]?[0-9]+)?|[-+]?\.(?:inf|Inf|INF)|\.(?:nan|NaN|NAN))$"
    ),
    list("-+.0123456789"),
)


def _load_yaml(text: str) -> Any:
    return yaml.load(text, Loader=_UniqueKeyLoader)  # noqa: S506 — a SafeLoader subclass


_BREAKS = str.maketrans({"\r": "\n", "\x85": "\n", "\u2028": "\n", "\u2029": "\n"})
#: a plain scalar's text in a flow collection, up to a blank or an indicator (PyYAML's scan_plain)
_FLOW_PLAIN = re.compile(r"(?:[^ \t\n,?\[\]{}:]|:(?![ \t\n,\[\]{}]|\Z))*")
#: what ends a plain scalar after a ':' in a flow collection (and the text's end)
_FLOW_ENDS = frozenset(("", " ", "\t", "\n", ",", "[", "]", "{", "}"))
_BLANKS = re.compile(r"[ \t\n]*")
#: a plain scalar in block context ends at a key's ':', a comment or the line's end
_PLAIN_STOP = re.compile(r":(?=[ \t\n]|\Z)|(?<=[ \t])#|\n")
_DOUBLE_QUOTED_REST = re.compile(r'(?:[^"\\]|\\.)*"?', re.S)
_COMMENT = re.compile(r"[ \t]#")
_SPACES = re.compile(r"[ \t]*")
_TOKEN = re.compile(r"[^ \t\n]*")
_ANCHOR_NAME = re.compile(r"[0-9A-Za-z_-]*")
_BLANK = frozenset(" \t\n")


class _Refused(HitchInputError):
    """Internal: a refusal found by the scan, caught by :meth:`_NestingScan.problem` (under the root error as every
    class here)."""


class _NestingScan:
    """One linear pass over a script's text, before the YAML parser sees it: how deep its collections nest
    (block mappings and sequences by their indentation, as PyYAML's scanner opens them, and flow ``[`` ``{``),
    and whether an alias names an anchored mapping or list. PyYAML's scanner is quadratic in the nesting of
    flow collections (30 000 ``[`` took 0.8 s to be refused as too deep, 1000 half a second), so nesting
    deeper than the language allows (:data:`_MAX_DEPTH`) is refused here, in time linear in the text.

    Quotes, comments, block scalars (``|``, ``>``) and plain scalars over several lines are skipped as
    PyYAML reads them, so brackets in text never count. Where this reading is unsure it counts fewer levels,
    never more: a flow collection as a mapping key or a single-pair mapping in a flow sequence (``[a: b]``)
    adds no level here; the composer's own limit (:meth:`_UniqueKeyLoader.compose_node`) and
    :func:`_check_structure` after parsing are exact. An anchor is of a collection when ``[`` or ``{``
    follows it, or when it ends its line and the next line opens a block collection."""

    def __init__(self, text: str):
        self.t = text.translate(_BREAKS)  # PyYAML's line breaks; "\r\n" becomes an extra blank line
        self.n = len(self.t)
        self.block: list[list[Any]] = []  # open block collections: [column, is a mapping, its indentless sequence]
        self.flow = 0
        self.line_start = 0
        self.collections: set[str] = set()  # anchors of mappings or lists
        self.anchor: str | None = None  # an anchor whose node has not started yet
        self.anchor_line = -1  # the line (its start) of that anchor
        self.literal_above: int | None = None  # a block scalar: lines indented more than this are its text
        self.plain_above: int | None = None  # a plain scalar may go on on lines indented more than this

    def problem(self) -> str | None:
        try:
            self._run()
        except _Refused as exc:
            return str(exc)
        return None

    # ------------------------------------------------------------------ state
    def _top(self) -> int:
        return self.block[-1][0] if self.block else -1

    def _check(self) -> None:
        if len(self.block) + sum(b[2] for b in self.block) + self.flow > _MAX_DEPTH:
            raise _Refused(_TOO_DEEP)

    def _push(self, column: int, mapping: bool) -> None:
        """A block entry ('- ', or '? ', ': ') or a key at ``column``: a new collection if it is indented further
        (PyYAML's ``add_indent``); a '- ' at the column of a mapping's keys is its value, an indentless sequence.
        An anchor on an earlier line is the new collection's (else its node was empty)."""
        earlier = self.anchor is not None and self.anchor_line != self.line_start
        opened = False
        if column > self._top():
            self.block.append([column, mapping, False])
            opened = True
        elif not mapping and column == self._top() and self.block[-1][1] and not self.block[-1][2]:
            self.block[-1][2] = opened = True
        self._node(earlier and opened)
        self._check()

    def _node(self, collection: bool) -> None:
        """The node an anchor waits for has started: a collection or not."""
        if self.anchor is not None:
            if collection:
                self.collections.add(self.anchor)
            self.anchor = None

    def _anchor(self, q: int) -> int:
        end = _ANCHOR_NAME.match(self.t, q + 1).end()  # type: ignore[union-attr]
        self.anchor, self.anchor_line = self.t[q + 1 : end], self.line_start
        return end

    def _alias(self, q: int) -> int:
        end = _ANCHOR_NAME.match(self.t, q + 1).end()  # type: ignore[union-attr]
        if self.t[q + 1 : end] in self.collections:
            raise _Refused(_ALIASED)
        return end

    def _eol(self, q: int) -> int:
        e = self.t.find("\n", q)
        return self.n if e < 0 else e

    def _quoted(self, q: int) -> int:
        """The position after the quoted scalar that starts at ``q`` (it may span lines)."""
        t = self.t
        if t[q] == "'":
            end = q + 1
            while True:
                e = t.find("'", end)
                if e < 0:
                    end = self.n
                    break
                if t.startswith("''", e):
                    end = e + 2
                    continue
                end = e + 1
                break
        else:
            end = _DOUBLE_QUOTED_REST.match(t, q + 1).end()  # type: ignore[union-attr]
        nl = t.rfind("\n", q, end)
        if nl >= 0:
            self.line_start = nl + 1
        return end

    # ------------------------------------------------------------------ the pass
    def _run(self) -> None:
        t, n = self.t, self.n
        p = 1 if t.startswith("\ufeff") else 0
        while p < n:  # one line in block context per pass
            self.line_start = p
            eol = self._eol(p)
            q = _SPACES.match(t, p).end()  # type: ignore[union-attr]
            col = q - p
            if q == eol or t[q] == "#":  # a blank line, a comment line
                if q < eol:
                    self.plain_above = None
                p = eol + 1
                continue
            if col == 0 and t.startswith(("---", "..."), q) and (q + 3 >= n or t[q + 3] in _BLANK):
                self.block.clear()  # a document starts or ends (more than one is an error of the parser's)
                self.literal_above = self.plain_above = None
                p = self._line(q + 3) if t[q] == "-" else eol + 1
                continue
            if self.literal_above is not None:
                if col > self.literal_above:
                    p = eol + 1
                    continue
                self.literal_above = None
            if self.plain_above is not None:
                if col > self.plain_above:  # the plain scalar goes on: its text, up to a comment
                    if _COMMENT.search(t, q, eol) is not None:
                        self.plain_above = None
                    p = eol + 1
                    continue
                self.plain_above = None
            if col == 0 and t[q] == "%":  # a directive
                p = eol + 1
                continue
            while self.block and self.block[-1][0] > col:
                self.block.pop()
            if (
                self.block
                and self.block[-1][0] == col
                and not (t[q] == "-" and t[q + 1 : q + 2] in ("", " ", "\t", "\n"))
            ):
                self.block[-1][2] = False  # the indentless sequence ended
            p = self._line(q)

    def _line(self, q: int) -> int:
        """The rest of a line from ``q``, where a node may start (block context); returns where the next
        line starts."""
        t, n = self.t, self.n
        props: int | None = None  # the column of the node's first tag or anchor on this line: a key's column
        while True:
            q = _SPACES.match(t, q).end()  # type: ignore[union-attr]
            if q >= n or t[q] == "\n":
                return q + 1
            c, col = t[q], q - self.line_start
            key_col = col if props is None else props
            follows = t[q + 1] if q + 1 < n else "\n"
            if c == "#":
                return self._eol(q) + 1
            if c in "-?:" and follows in _BLANK:  # a block entry, a complex key or its value
                self._push(key_col if c == ":" else col, c != "-")  # (':' after a property: an empty key)
                q, props = q + 1, None
                continue
            if c in "&!":  # an anchor, a tag (PyYAML's tags end at a blank)
                q = self._anchor(q) if c == "&" else _TOKEN.match(t, q).end()  # type: ignore[union-attr]
                props = key_col
                continue
            if c in "[{":
                self._node(True)
                line = self.line_start
                q = self._flow(q)
                if self._key_follows(q) and self.line_start == line:  # a flow collection as a key
                    self._push(key_col, True)
                    q, props = self._key_end(q), None
                    continue
                return self._eol(q) + 1
            if c in "|>":
                self._node(False)
                self.literal_above = self._top()
                return self._eol(q) + 1
            if c in "\"'" or c == "*":
                line = self.line_start
                end = self._quoted(q) if c != "*" else self._alias(q)
                if self._key_follows(end) and self.line_start == line:
                    self._push(key_col, True)
                    q, props = self._key_end(end), None
                    continue
                self._node(False)
                return self._eol(end) + 1
            m = _PLAIN_STOP.search(t, q)  # a plain scalar: a key if ':' ends it
            if m is None:
                self._node(False)
                return n
            if m.group() == ":":
                self._push(key_col, True)
                q, props = m.end(), None
                continue
            self._node(False)
            if m.group() == "\n":
                self.plain_above = self._top()
                return m.end()
            return self._eol(m.end()) + 1

    def _key_follows(self, q: int) -> bool:
        q = _SPACES.match(self.t, q).end()  # type: ignore[union-attr]
        return q < self.n and self.t[q] == ":" and (q + 1 >= self.n or self.t[q + 1] in _BLANK)

    def _key_end(self, q: int) -> int:
        return _SPACES.match(self.t, q).end() + 1  # type: ignore[union-attr]

    def _flow(self, q: int) -> int:
        """A flow collection from its '[' or '{' at ``q``, token by token as PyYAML's scanner reads the flow
        context: the position after its closing bracket."""
        t, n = self.t, self.n
        plain = False  # in a plain scalar: after blanks it goes on (quotes, '&', '*', '!' are its text)
        while q < n:
            c = t[q]
            if c in " \t":
                q += 1
            elif c == "\n":
                self.line_start = q = q + 1
            elif c == "#":  # at a token's start, or after a blank in a plain scalar: a comment
                q, plain = self._eol(q), False
            elif c in "[{":
                self._node(True)
                self.flow += 1
                self._check()
                q, plain = q + 1, False
            elif c in "]}":
                self.flow -= 1
                q, plain = q + 1, False
                if self.flow == 0:
                    return q
            elif c in ",?" or (c == ":" and (not plain or t[q + 1 : q + 2] in _FLOW_ENDS)):
                q, plain = q + 1, False  # an indicator (':' inside a plain scalar only before a blank or , [ ] { })
            elif plain:
                q = _FLOW_PLAIN.match(t, q).end() or q + 1  # type: ignore[union-attr]
            elif c in "\"'":
                self._node(False)
                q = self._quoted(q)
            elif c == "&":
                q = self._anchor(q)
                nxt = _BLANKS.match(t, q).end()  # type: ignore[union-attr]
                self._node(nxt < n and t[nxt] in "[{")
            elif c == "*":
                self._node(False)
                q = self._alias(q)
            elif c == "!":  # a tag: up to a blank (its URI may hold brackets and commas)
                q = _TOKEN.match(t, q).end()  # type: ignore[union-attr]
            else:
                self._node(False)
                q, plain = _FLOW_PLAIN.match(t, q).end() or q + 1, True  # type: ignore[union-attr]
        return n


def _check_structure(data: Any) -> str | None:
    """Refuse shared containers (YAML aliases), deep nesting and huge node counts; non-string keys."""
    seen: set[int] = set()
    stack = [(data, 0)]
    nodes = 0
    while stack:
        node, depth = stack.pop()
        nodes += 1
        if nodes > _MAX_NODES:
            return f"the script has more than {_MAX_NODES} YAML nodes"
        if isinstance(node, (dict, list)):
            if id(node) in seen:
                return _ALIASED
            seen.add(id(node))
            if depth >= _MAX_DEPTH:
                return _TOO_DEEP
            if isinstance(node, dict):
                for k in node:
                    if not isinstance(k, str):
                        return f"mapping keys must be strings, got {_show(k)}"
                stack.extend((v, depth + 1) for v in node.values())
            else:
                stack.extend((v, depth + 1) for v in node)
    return None


def _parse_step(i: int, raw: Any) -> tuple[Step | None, list[StepError]]:
    kinds = ", ".join(_KINDS)
    if not isinstance(raw, dict) or len(raw) != 1:
        return None, [
            StepError(
                i,
                f"steps[{i}] must be a mapping with exactly one step key ({kinds}), "
                f"got {_show(raw) if not isinstance(raw, dict) else ', '.join(map(str, raw)) or 'an empty mapping'}",
            )
        ]
    ((kind, value),) = raw.items()
    if kind not in _KINDS:
        return None, [StepError(i, f"steps[{i}]: unknown step {_show(kind)} (allowed: {kinds})")]
    model, scalar = _KINDS[kind]
    if not isinstance(value, dict):
        if scalar is None:
            return None, [
                StepError(
                    i,
                    f"steps[{i}].{kind} must be a mapping, got {_show(value)}"
                    f" (fields: {', '.join(model.model_fields)})",
                )
            ]
        value = {scalar: value}
    try:
        return model.model_validate(value), []
    except ValidationError as exc:
        return None, _errors(exc, model, f"steps[{i}].{kind}", i)


def parse_maneuver(text: Any) -> ManeuverScript:
    """Parse and schema-check a maneuver script; :class:`ManeuverError` lists every problem."""
    if not isinstance(text, str):
        raise ManeuverError([StepError(None, f"script must be YAML text, got {_show(text)}")])
    size = len(text.encode("utf-8", "surrogatepass"))
    if size > MAX_SCRIPT_BYTES:
        raise ManeuverError([StepError(None, f"script is {size} bytes (allowed: at most {MAX_SCRIPT_BYTES} bytes)")])
    problem = _NestingScan(text).problem()  # before the parser: its cost grows with the square of the nesting
    if problem:
        raise ManeuverError([StepError(None, problem)])
    try:
        data = _load_yaml(text)
    except ManeuverError:
        raise
    except Exception as exc:  # noqa: BLE001 — PyYAML's constructors also raise IndexError, AttributeError, …
        where = getattr(exc, "problem_mark", None) or getattr(exc, "context_mark", None)
        at = f" at line {where.line + 1}, column {where.column + 1}" if where is not None else ""
        problem = (
            "nesting too deep"
            if isinstance(exc, RecursionError)
            else getattr(exc, "problem", None)
            or (
                str(exc)[:200] if isinstance(exc, (yaml.YAMLError, ValueError)) else f"bad value ({type(exc).__name__})"
            )
        )
        if isinstance(exc, yaml.reader.ReaderError):
            # a character YAML does not allow: the reader's error has no mark, and said 'in "<unicode string>",
            # position 0' (a fuzz trial); its position is an index into the text, said as line and column here
            pos = int(exc.position)
            line, column = text.count("\n", 0, pos) + 1, pos - (text.rfind("\n", 0, pos) + 1) + 1
            char = exc.character
            shown = f"U+{char:04X}" if isinstance(char, int) else repr(char)
            at, problem = f" at line {line}, column {column}", f"character {shown} is not allowed ({exc.reason})"
        raise ManeuverError([StepError(None, f"script is not valid YAML{at}: {problem}")]) from None
    if not isinstance(data, dict):
        raise ManeuverError(
            [
                StepError(
                    None,
                    f"script must be a mapping with 'steps' (and optional name, "
                    f"description, timeout), got {_show(data)}",
                )
            ]
        )
    problem = _check_structure(data)
    if problem:
        raise ManeuverError([StepError(None, problem)])
    errors: list[StepError] = []
    steps_raw = data.pop("steps", None)
    try:
        header = _Header.model_validate(data)
    except ValidationError as exc:
        header = None
        errors.extend(_errors(exc, _Header, "", None))
    if not isinstance(steps_raw, list) or not steps_raw:
        errors.append(
            StepError(
                None,
                f"steps must be a non-empty list of steps (at most {MAX_STEPS}), "
                f"got {'an empty list' if steps_raw == [] else _show(steps_raw)}",
            )
        )
        raise ManeuverError(errors)
    if len(steps_raw) > MAX_STEPS:
        errors.append(StepError(None, f"steps has {len(steps_raw)} entries (allowed: at most {MAX_STEPS})"))
        raise ManeuverError(errors)
    steps: list[Step] = []
    for i, raw in enumerate(steps_raw):
        step, errs = _parse_step(i, raw)
        errors.extend(errs)
        if step is not None:
            steps.append(step)
    errors.extend(_check_leads(steps_raw, steps))
    if errors or header is None:  # a step or the header that did not parse has its errors listed
        raise ManeuverError(errors)
    return ManeuverScript(header.name, header.description, header.timeout, tuple(steps))


# ---------------------------------------------------------------------------------------- validation
class PlanStep(Protocol):
    """Plan a move from ``start`` to a (partial) goal at ``speed_scale``: (duration [s], end state).

    Raises ``ValueError`` (``PlanError``, ``GuardRefusal``) with a message naming the limit.
    """

    def __call__(
        self, start: MotionState, goal: Mapping[str, float], speed_scale: float
    ) -> tuple[float, MotionState]: ...


class PresetLike(Protocol):
    """What validation reads of a preset (e.g. a :class:`bridge.service.store.Preset`)."""

    @property
    def pose(self) -> Mapping[str, float]:
        """x, z [m]; roll, pitch [rad]."""
        ...

    @property
    def speed_scale(self) -> float | None:
        """The preset's own speed scale (0, 1], or None."""
        ...


@dataclass(frozen=True)
class PlanningContext:
    """What :func:`validate` needs from the service: the start state, the planner and the presets."""

    start: MotionState
    plan_step: PlanStep
    #: the preset of the current implement by name, or None if there is none
    preset: Callable[[str], PresetLike | None]


@dataclass(frozen=True)
class PlannedStep:
    """One step as it will run: full goal (motion steps), speed scale, planned start and duration [s]."""

    index: int
    kind: str
    goal: Mapping[str, float] | None = None
    speed_scale: float = 1.0
    seconds: float = 0.0  # wait
    distance_m: float = 0.0  # wait_for
    start_s: float = 0.0  # planned start, excluding the time of earlier wait_for steps
    duration_s: float = 0.0
    line: str | None = None  # wait_for a line
    #: wait_for a line with ``complete``: the time [s] the next motion step's plan takes to come within
    #: the pose tolerance of its goal (:func:`within_tolerance_s`), so that step starts that time (plus
    #: the start latency) × the ground speed before the line (lead compensation); 0: at the line
    lead_s: float = 0.0
    #: motion steps: when the plan comes within the pose tolerance of its goal [s] (<= ``duration_s``)
    within_s: float = 0.0


@dataclass(frozen=True)
class ValidationResult:
    """``duration``: planned time [s] of motions and waits (wait_for time depends on the tractor)."""

    ok: bool
    duration: float
    errors: tuple[StepError, ...] = ()
    script: ManeuverScript | None = None
    steps: tuple[PlannedStep, ...] = ()
    distance_m: float = 0.0  # total wait_for distance

    def to_json(self) -> dict:
        return {"ok": self.ok, "duration": self.duration, "errors": [e.to_json() for e in self.errors]}


class StepPlan(tuple[float, MotionState]):
    """What :func:`guarded_plan_step` returns: ``(duration [s], end state)`` as every :class:`PlanStep`,
    plus ``within_s``, when the plan comes within the pose tolerance of its goal [s] (lead compensation)."""

    within_s: float

    def __new__(cls, duration: float, end: MotionState, within_s: float | None = None) -> StepPlan:
        self = super().__new__(cls, (float(duration), end))
        self.within_s = float(duration) if within_s is None else float(within_s)
        return self

    def __getnewargs__(self) -> tuple[float, MotionState, float]:
        return (self[0], self[1], self.within_s)


def pose_tolerance(guard: Guard, pose: Any) -> np.ndarray:
    """The pose tolerance at ``pose`` (x, z [m], roll, pitch [rad]): one AD count on every cylinder
    sensor mapped to the pose (|J⁺|·resolution, J = d actuators / d pose). The cylinder ECU's
    position controllers call a cylinder settled within one count of its reference
    (``ControllerTuning.cutoff_counts`` = 1, :mod:`bridge.sim.controller`), so a hitch within this
    tolerance of its goal is where the ECU holds it: the motion is done."""
    from planner.model.sensors import SensorScaling

    jac = guard.planner.inverse.solve(np.asarray(pose, float))[1]
    res = SensorScaling(guard.model.profile).resolution
    return np.asarray(np.abs(np.linalg.pinv(jac)) @ res, float)


def within_tolerance_s(plan: Any, tolerance: np.ndarray, dt: float = 1e-3) -> float:
    """The earliest time [s] from which ``plan`` (``duration``, ``state_at``) stays within ``tolerance``
    of its end pose (every DOF), to ``dt``: searched back from the end (the plan settles monotonically
    onto its goal in its last jerk-limited phase)."""
    duration = float(plan.duration)
    goal = np.asarray(plan.state_at(duration).position, float)
    t = duration
    while t > 0.0:
        tt = max(0.0, t - dt)
        if np.any(np.abs(np.asarray(plan.state_at(tt).position, float) - goal) > tolerance):
            return t
        t = tt
    return 0.0


def guarded_plan_step(guard: Guard) -> PlanStep:
    """A :class:`PlanStep` through :meth:`planner.limits.guard.Guard.plan`: limits and stability. Returns a
    :class:`StepPlan` (with the time the plan comes within :func:`pose_tolerance` of its goal)."""

    def plan_step(start: MotionState, goal: Mapping[str, float], speed_scale: float) -> tuple[float, MotionState]:
        gp = guard.plan(start, goal, speed_scale=speed_scale)
        end = gp.plan.state_at(gp.plan.duration)
        within = within_tolerance_s(gp.plan, pose_tolerance(guard, end.position))
        return StepPlan(gp.plan.duration, MotionState.at_rest(end.position), within)

    return plan_step


@dataclass(frozen=True)
class _Resolved:
    """A step with its partial goal (motion steps; presets looked up) and the speed scale it runs at."""

    index: int
    step: Step
    goal: Mapping[str, float] | None
    speed_scale: float


def _resolve(script: ManeuverScript, ctx: PlanningContext) -> tuple[list[_Resolved], list[StepError]]:
    """Every step but ``speed`` with its goal and scale; preset lookups first, so every unknown name is reported."""
    out: list[_Resolved] = []
    errors: list[StepError] = []
    speed = 1.0
    for i, s in enumerate(script.steps):
        if isinstance(s, SpeedStep):
            speed = s.scale
        elif isinstance(s, GotoStep):
            out.append(_Resolved(i, s, s.goal, s.speed_scale or speed))
        elif isinstance(s, PresetStep):
            p = ctx.preset(s.name)
            if p is None:
                errors.append(StepError(i, f"preset {s.name!r} does not exist for this implement"))
                continue
            out.append(_Resolved(i, s, dict(p.pose), s.speed_scale or p.speed_scale or speed))
        else:
            out.append(_Resolved(i, s, None, speed))
    return out, errors


def validate(script: str | ManeuverScript, ctx: PlanningContext) -> ValidationResult:
    """Parse (if text), resolve presets, plan every motion step and check the timeout; never raises on bad input.

    With a preset that does not exist, the steps before it are still planned (their errors are reported beside
    it: a missing preset hid that the goto before it could not be planned); those after it cannot be, as
    where the hitch would start them is unknown."""
    if not isinstance(script, ManeuverScript):
        try:
            script = parse_maneuver(script)
        except ManeuverError as exc:
            return ValidationResult(False, 0.0, exc.errors)
    resolved, unresolved = _resolve(script, ctx)
    first_unresolved = min((e.step for e in unresolved if e.step is not None), default=None)
    errors: list[StepError] = []
    planned: list[PlannedStep] = []
    t, dist, state = 0.0, 0.0, ctx.start
    for r in resolved:
        i, step, goal, scale = r.index, r.step, r.goal, r.speed_scale
        if first_unresolved is not None and i > first_unresolved:
            break
        if isinstance(step, WaitStep):
            planned.append(PlannedStep(i, "wait", seconds=step.seconds, start_s=t, duration_s=step.seconds))
            t += step.seconds
        elif isinstance(step, WaitForStep) and step.line is not None:
            planned.append(PlannedStep(i, "wait_for", line=step.line, start_s=t))
        elif isinstance(step, WaitForStep) and step.distance is not None:
            planned.append(PlannedStep(i, "wait_for", distance_m=step.distance, start_s=t))
            dist += step.distance
        elif goal is not None:  # goto, preset: a motion
            try:
                res = ctx.plan_step(state, goal, scale)
            except ValueError as exc:
                errors.append(StepError(i, f"{step.kind} cannot be planned: {exc}"))
                break
            duration, end = res
            within = res.within_s if isinstance(res, StepPlan) else float(duration)  # (another planner: its end)
            full = dict(zip(POSE_BOUNDS, map(float, np.asarray(end.position, float)), strict=True))
            planned.append(
                PlannedStep(i, step.kind, full, scale, start_s=t, duration_s=float(duration), within_s=within)
            )
            t += float(duration)
            state = MotionState.at_rest(end.position)
        if t > script.timeout_s:
            errors.append(
                StepError(
                    i,
                    f"the maneuver would still run at {t:.2f} s, beyond its timeout "
                    f"(timeout = {script.timeout_s:g} s; allowed: timeout <= {MAX_TIMEOUT_S:g} s)",
                )
            )
            break
    if unresolved:
        errors = sorted([*errors, *unresolved], key=lambda e: -1 if e.step is None else e.step)
        return ValidationResult(False, 0.0, tuple(errors), script)
    return ValidationResult(not errors, t, tuple(errors), script, _with_leads(script, planned), dist)


def goto_workspace_errors(script: ManeuverScript, planner: Any) -> list[StepError]:
    """Every ``goto`` step whose own goal lies outside the workspace of ``planner`` (a
    :class:`~planner.trajectory.TrajectoryPlanner`: ``lo``, ``hi``, ``check_in_workspace``) — known
    without planning from the step before: a DOF the step gives out of ``[lo, hi]``. The message is the
    planner's own (``goal.x = … m is left of the workspace (x_min = … m)``, with its unit hint), as
    planning the step would give it; steps indexed 0-based."""
    lo, hi = np.asarray(planner.lo, float), np.asarray(planner.hi, float)
    out = []
    for i, step in enumerate(script.steps):
        if not isinstance(step, GotoStep):
            continue
        pose = (lo + hi) / 2.0  # the DOF it does not give keep a value inside the workspace
        for j, k in enumerate(POSE_BOUNDS):
            v = getattr(step, k)
            if v is not None:
                pose[j] = float(v)
        try:
            planner.check_in_workspace(pose, "goal")
        except ValueError as exc:  # PlanError
            out.append(StepError(i, str(exc)))
    return out


def _check_leads(raw: list[Any], steps: list[Step]) -> list[StepError]:
    """A ``wait_for`` line step with ``complete: true`` must be followed by a motion step
    (``goto`` or ``preset``; ``speed`` steps in between are fine): the step that is complete at the line."""
    if len(steps) != len(raw):  # some step did not parse: its errors are reported already
        return []
    out = []
    for i, s in enumerate(steps):
        if isinstance(s, WaitForStep) and s.complete:
            nxt = next((n for n in steps[i + 1 :] if not isinstance(n, SpeedStep)), None)
            if not isinstance(nxt, (GotoStep, PresetStep)):
                out.append(
                    StepError(
                        i,
                        f"steps[{i}].wait_for.complete = True needs a motion step (goto or preset) after it: "
                        "the step that must be complete at the line",
                    )
                )
    return out


def _with_leads(script: ManeuverScript, planned: list[PlannedStep]) -> tuple[PlannedStep, ...]:
    """Give each ``wait_for`` line step with ``complete`` the time the motion step after it takes to come
    within the pose tolerance of its goal (its ``within_s``)."""
    out = list(planned)
    for k, ps in enumerate(out):
        step = script.steps[ps.index]
        if isinstance(step, WaitForStep) and step.complete:
            nxt = next((n for n in out[k + 1 :] if n.goal is not None), None)
            if nxt is not None:
                out[k] = replace(ps, lead_s=nxt.within_s)
    return tuple(out)
