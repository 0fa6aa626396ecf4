"""Every YAML example of docs/maneuvers.md is what the language says it is.

Truth: the language's own parser and validator (bridge.service.maneuvers.language) with the real
trajectory planner and stability guard — the page's scripts parse and plan from the neutral pose
within their timeout; each refused example fails with the message quoted in its first line.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from bridge.service.maneuvers.language import (
    ManeuverError,
    PlanningContext,
    guarded_plan_step,
    parse_maneuver,
    validate,
)
from planner.limits.guard import Guard
from planner.model.kinematics import HitchModel
from planner.trajectory import MotionState, TrajectoryPlanner

DOC = Path(__file__).resolve().parents[3] / "docs" / "maneuvers.md"
BLOCKS = re.findall(r"```yaml\n(.*?)```", DOC.read_text(encoding="utf-8"), re.S)
REFUSED = [b for b in BLOCKS if b.startswith("# refused: ")]
SCRIPTS = [b for b in BLOCKS if not b.startswith("# refused: ")]


class _Preset:
    pose = {"x": 0.0, "z": 0.05, "roll": 0.0, "pitch": 0.0}
    speed_scale = 0.7


def test_the_page_has_examples_of_both_kinds():
    assert len(SCRIPTS) >= 3 and len(REFUSED) >= 5
    assert len(BLOCKS) == DOC.read_text(encoding="utf-8").count("```yaml")


@pytest.fixture(scope="module")
def context() -> PlanningContext:
    model = HitchModel.from_profile("thesis-t132")
    guard = Guard(TrajectoryPlanner(model))
    start = MotionState.at_rest(model.neutral_pose.controlled())
    return PlanningContext(start, guarded_plan_step(guard), lambda name: _Preset() if name == "work" else None)


@pytest.mark.parametrize("block", SCRIPTS, ids=lambda b: b.splitlines()[0][:40])
def test_every_script_on_the_page_parses_and_plans(block, context):
    script = parse_maneuver(block)
    assert script.steps
    res = validate(script, context)
    assert res.ok, [e.sentence() for e in res.errors]
    assert 0 < res.duration <= script.timeout_s


@pytest.mark.parametrize("block", REFUSED, ids=lambda b: b.splitlines()[0][11:50])
def test_every_refused_example_fails_with_the_quoted_message(block):
    quoted = block.splitlines()[0].removeprefix("# refused: ").strip()
    with pytest.raises(ManeuverError) as info:
        parse_maneuver(block)
    assert quoted in str(info.value)
