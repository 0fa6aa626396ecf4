"""Deep nesting and aliased collections in a maneuver script are refused from one pass over the text,
before the YAML parser reads it (a trial: ``steps: [[[…`` 30 000 deep cost the service 1.1-1.8 s of CPU
before it was refused, 1000 deep 0.7 s: PyYAML's scanner and composer grow with the square of the nesting).

Truth used: the language's own limit (6 levels, ``_MAX_DEPTH``) and PyYAML itself — for scripts
PyYAML reads, the depth of what it builds decides whether the pre-pass may refuse (it must never refuse
a script within the limit) and must (deeper ones are refused, by the pre-pass or the composer's limit).
No timing here: the figures are in the commit message.
"""

from __future__ import annotations

import random

import pytest
import yaml

from bridge.service.maneuvers import language
from bridge.service.maneuvers.language import ManeuverError, parse_maneuver

LIMIT = language._MAX_DEPTH
TOO_DEEP = f"the script nests deeper than {LIMIT} levels"
ALIASED = "YAML anchors/aliases of mappings or lists are not allowed"


def _laughs() -> str:
    text = "a0: &a0 [x, x, x, x, x, x, x, x, x]\n"
    text += "".join(f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]\n" for i in range(1, 9))
    return text + "steps: *a8\n"


def _merge_bomb() -> str:
    text = "a0: &a0 {" + ", ".join(f"k{i}: {i}" for i in range(10)) + "}\n"
    text += "".join(f"a{i}: &a{i} {{<<: [{', '.join([f'*a{i - 1}'] * 9)}]}}\n" for i in range(1, 9))
    return text + "steps: [{wait: 1}]\n"


DEEP = {
    "flow [ 30000 (the trial's)": "steps: " + "[" * 30000 + "]" * 30000,
    "flow [ 1000": "steps: " + "[" * 1000 + "]" * 1000,
    "flow [ unclosed": "steps: " + "[" * 30000,
    "flow {": "steps: " + "{a: " * 12000 + "}" * 12000,
    "mixed [{": "steps: " + "[{a: " * 6000 + "}]" * 6000,
    "flow over lines": "steps:\n" + "".join(" " * 2 + "[\n" for _ in range(5000)),
    "compact block sequences": "steps:\n" + "- " * 30000 + "x",
    "complex keys": "steps:\n" + "? " * 30000 + "x",
    "block sequences by indentation": "steps:\n" + "".join(" " * i + "-\n" for i in range(1, 300)),
    "block mappings by indentation": "steps:\n" + "".join(" " * i + f"k{i}:\n" for i in range(1, 300)),
    "anchored, tagged, quoted keys": "steps:\n" + "".join(" " * i + f"&a{i} !!str 'k{i}':\n" for i in range(1, 300)),
    "flow in block in flow": "steps:\n  - a:\n      - [{b: [\n          {c: [[d]]}]}]",
}
ALIASES = {"billion laughs": _laughs(), "merge-key bomb": _merge_bomb()}


@pytest.fixture
def no_parser(monkeypatch):
    """The YAML parser must not be reached."""

    def refuse(text):
        raise AssertionError("the YAML parser was called")

    monkeypatch.setattr(language, "_load_yaml", refuse)


@pytest.mark.parametrize("name", list(DEEP))
def test_deep_nesting_is_refused_naming_the_limit_before_the_parser(name, no_parser):
    with pytest.raises(ManeuverError) as ei:
        parse_maneuver(DEEP[name])
    assert [(e.step, e.message) for e in ei.value.errors] == [(None, TOO_DEEP)]


@pytest.mark.parametrize("name", list(ALIASES))
def test_aliases_of_collections_are_refused_before_the_parser(name, no_parser):
    """The merge-key bomb: PyYAML copies merged mappings (an older PyYAML, 9^8 of them); before, the copies
    hid the aliases from the check after parsing and the script reached the schema."""
    with pytest.raises(ManeuverError) as ei:
        parse_maneuver(ALIASES[name])
    assert [(e.step, e.message) for e in ei.value.errors] == [(None, ALIASED)]


def _nest(style: str, levels: int) -> str:
    """A script ``levels`` collections deep in total (the top mapping is one)."""
    inner = levels - 1
    if style == "flow":
        return "steps: " + "[" * inner + "1" + "]" * inner + "\n"
    if style == "flow mappings":
        return "steps: " + "{a: " * inner + "1" + "}" * inner + "\n"
    if style == "block":
        return "steps:\n" + "".join(" " * (2 * i) + "-\n" for i in range(1, inner)) + " " * (2 * inner) + "- 1\n"
    if style == "compact":
        return "steps:\n" + "- " * inner + "1\n"
    assert style == "indentless"  # each list at its mapping keys' column
    lines, pad = ["steps:"], ""
    while inner > 0:
        lines.append(pad + ("- 1" if inner == 1 else "- k: 1" if inner == 2 else "- k:"))
        pad, inner = pad + "  ", inner - 2
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("style", ["flow", "flow mappings", "block", "compact", "indentless"])
def test_the_limit_itself_is_not_refused_one_more_level_is(style):
    within, beyond = _nest(style, LIMIT), _nest(style, LIMIT + 1)
    assert _depth(yaml.safe_load(within)) == LIMIT and _depth(yaml.safe_load(beyond)) == LIMIT + 1
    assert language._NestingScan(within).problem() is None
    assert language._NestingScan(beyond).problem() == TOO_DEEP


LEGIT = [
    # brackets in text: quoted (over lines, with escapes), block scalars, plain scalars over lines, comments
    "description: '[[[[[[[[ {{{{{{{{ it''s'\nsteps: [{wait: 1}]  # [[[[[[[[[[[[\n",
    'description: "[[[[[[[[\\" {{{{{{{{\n  [[[[[[[[["\nsteps: [{wait: 1}]\n',
    "description: |\n  [[[[[[[[[[\n    {{{{{{{{{{\nsteps:\n  - wait: 1\n",
    "description: >-\n    [[[[[[[[\n      [[[[[[[[\nsteps:\n- wait: 1\n",
    "description: lift and\n  [[[[[[[[ centre\n  {{{{{{{{\nsteps:\n- wait: 1\n",
    "description: a [[[[[[[[ b # {{{{{{{{\nsteps: [{wait: 1}, {wait: 2}]\n",
    "steps: [{wait: 1}, # [[[[[[[[\n  {wait: 2}]\n",
    "{name: x, description: 'x[[[[[[[[x', steps: [{goto: {z: 0.1}}, {wait: 1}]}\n",
    '{\n  description: "{{{{{{{{",\n  steps: [{wait: 1}],  # ]]]]]]]]\n}\n',
    # flow plain scalars: ':' and '#' inside them, quotes that do not start a token
    "{description: a:b c#d don't &e *f, steps: [{wait: 1}]}\n",
    # scalar anchors and aliases are allowed
    "steps:\n  - goto: {z: &z 0.25}\n  - wait: 1\n  - goto: {z: *z}\n",
    "timeout: &t 30\nsteps:\n  - wait: *t\n",
    # a tag, an indentless list, a document start
    "--- !!map\nname: !!str tagged\nsteps:\n- wait: 1\n- goto:\n    z: 0.1\n",
]


@pytest.mark.parametrize("text", LEGIT)
def test_scripts_within_the_limit_parse(text):
    assert parse_maneuver(text).steps


def _depth(d: object) -> int:
    """Collections nested (a scalar 0, ``[]`` 1); shared ones are counted where they are first met."""
    seen: set[int] = set()
    stack, deepest = [(d, 1)], 0
    while stack:
        node, k = stack.pop()
        if isinstance(node, (dict, list)) and id(node) not in seen:
            seen.add(id(node))
            deepest = max(deepest, k)
            items = [*node.keys(), *node.values()] if isinstance(node, dict) else node
            stack.extend((v, k + 1) for v in items)
    return deepest


_TEXT = ["a", "[", "]", "{", "}", "[[[[[[[", "'", '"', "#", " #", ": ", ":", "- ", "? ", "&x", "*x", "|", "\n", ","]


def _data(rng: random.Random, levels: int) -> object:
    if levels == 0 or rng.random() < 0.15:
        return rng.choice(["".join(rng.choices(_TEXT, k=rng.randint(0, 6))), rng.randint(-5, 5), None, True])
    if rng.random() < 0.5:
        return [_data(rng, levels - 1) for _ in range(rng.randint(0, 2))]
    return {f"k{i}" + "".join(rng.choices(_TEXT, k=rng.randint(0, 3))): _data(rng, levels - 1) for i in range(2)}


def test_the_pre_pass_agrees_with_pyyaml_on_dumped_documents():
    """PyYAML writes random documents in every style (flow, block, mixed; quoted or plain text holding
    brackets, comment and key marks; lines folded): one within the limit is never refused by the pre-pass,
    a deeper one is refused as too deep (by the pre-pass, or where it counts fewer levels by the composer)."""
    rng = random.Random(7)
    within = beyond = 0
    for _ in range(400):
        data = _data(rng, rng.randint(1, 9))
        text = yaml.safe_dump(
            data,
            default_flow_style=rng.choice([True, False, None]),
            width=rng.choice([10, 40, 1000]),
            default_style=rng.choice([None, None, '"', "'"]),
            indent=rng.choice([2, 4]),
        )
        if rng.random() < 0.2:
            text = text.replace("\n", "\r\n")
        levels = _depth(yaml.safe_load(text))
        problem = language._NestingScan(text).problem()
        if levels <= LIMIT:
            within += 1
            assert problem is None, text
        else:
            beyond += 1
            if problem is None:
                with pytest.raises(ManeuverError, match=TOO_DEEP):
                    yaml.load(text, Loader=language._UniqueKeyLoader)  # noqa: S506 — a SafeLoader subclass
            else:
                assert problem == TOO_DEEP
    assert within > 100 and beyond > 50


def test_what_the_pre_pass_counts_short_the_composer_refuses():
    """A single-pair mapping in a flow sequence (``[a: b]``) is a level the pre-pass does not count."""
    text = "steps: " + "[a: " * 4 + "1" + "]" * 4
    assert language._NestingScan(text).problem() is None
    with pytest.raises(ManeuverError) as ei:
        parse_maneuver(text)
    assert [e.message for e in ei.value.errors] == [TOO_DEEP]
