"""Operator words of the implement's limits and of the guard's speed factors (:mod:`bridge.web.wording`).

A new user's trial: ``hitch track --sine z=0.02@0.5Hz`` with an implement that has a lowering speed limit
printed ``control limited: lifting speed: implement lowering speed limit (vz), implement lowering speed limit:
speed: implement lowering speed limit would be 0.06001 m/s …`` — "lifting" for a lowering limit, the limit
twice, its numbers as the guard's sentence. Truth: the expected strings below are written by hand from the
numbers given (0.06001 m/s → 0.060 m/s; a factor 0.5084 → 51 %).
"""

from __future__ import annotations

import bridge.web.wording as wording
from bridge.web.wording import highlight, limited_words, words
from planner.limits import implement_limits
from planner.limits.guard import GuardReason
from planner.limits.implement_limits import LOWERING_SPEED_LIMIT, UPPER_HEIGHT_LIMIT

_LOWERING_SENTENCE = "speed: implement lowering speed limit would be 0.06001 m/s (threshold 0.05 m/s) at t = 0.00 s"


def test_vz_is_the_vertical_speed_not_lifting():
    """``vz`` is the vertical speed, up or down: a lowering limit must not read "lifting"."""
    text = limited_words("vz", "z_descent")
    assert text == "vertical speed: z_descent"
    assert "lifting" not in text


def test_every_implement_limit_name_has_words():
    names = [
        implement_limits.UPPER_HEIGHT_LIMIT,
        implement_limits.LOWERING_SPEED_LIMIT,
        implement_limits.TRANSPORT_LOCK,
    ]
    assert words(LOWERING_SPEED_LIMIT) == "lowering faster than the implement allows"
    assert words(UPPER_HEIGHT_LIMIT) == "implement at its upper height limit"
    assert all(words(n) for n in names), [n for n in names if not words(n)]
    assert highlight(LOWERING_SPEED_LIMIT) == ("implement",)


def test_the_lowering_speed_limit_in_m_s_beside_its_limit():
    reason = GuardReason(LOWERING_SPEED_LIMIT, 0.06001, 0.05, 0.0, "speed", "m/s")
    assert f"speed: {reason.sentence()}" == _LOWERING_SENTENCE  # the service's sentence, as the user saw it
    assert limited_words(LOWERING_SPEED_LIMIT, _LOWERING_SENTENCE) == (
        "lowering faster than the implement allows: 0.060 m/s (limit 0.050 m/s): slowed"
    )


def test_the_upper_height_limit_refused_in_m():
    reason = GuardReason(UPPER_HEIGHT_LIMIT, 0.65, 0.6, 1.0, "hard", "m")
    assert limited_words(UPPER_HEIGHT_LIMIT, f"hard: {reason.sentence()}") == (
        "implement at its upper height limit: 0.650 m (limit 0.600 m): refused"
    )


def test_a_speed_factor_reads_as_a_share_of_full_speed():
    """A guard "speed" reason without a unit is a speed factor (threshold 1): said in %, not dropped."""
    assert limited_words("velocity:tilt", "speed: velocity:tilt would be 0.5084 (threshold 1)") == (
        "tilt cylinder (right lift rod) at its speed limit: slowed to 51 %"
    )
    assert limited_words("end_stop:lift", "speed: end_stop:lift would be 0.8086 (threshold 1) at t = 0.00 s") == (
        "lift arm slowing before its stroke end: slowed to 81 %"
    )
    lowering = GuardReason(LOWERING_SPEED_LIMIT, 0.8, 1.0, 1.2, "speed")  # a plan slowed as a whole
    assert limited_words(LOWERING_SPEED_LIMIT, f"speed: {lowering.sentence()}") == (
        "lowering faster than the implement allows: slowed to 80 %"
    )
    assert (wording.percent(0.004), wording.percent(0.5), wording.percent(0.0)) == ("0.4 %", "50 %", "0 %")


def test_a_limit_flagged_on_a_track_dof_and_the_guards_reason_on_it_are_one_entry():
    limited = {"vz": LOWERING_SPEED_LIMIT, LOWERING_SPEED_LIMIT: _LOWERING_SENTENCE, "z": "workspace:z:max"}
    assert wording.limited_entries(limited) == [
        ("vz", "lowering faster than the implement allows: 0.060 m/s (limit 0.050 m/s): slowed"),
        ("z", "height limit reached (top)"),
    ]
    # the flag alone: its words; the guard's reason alone: under its own code
    assert wording.limited_entries({"vz": LOWERING_SPEED_LIMIT}) == [
        ("vz", "lowering faster than the implement allows")
    ]
    assert wording.limited_entries({LOWERING_SPEED_LIMIT: _LOWERING_SENTENCE}) == [
        (LOWERING_SPEED_LIMIT, "lowering faster than the implement allows: 0.060 m/s (limit 0.050 m/s): slowed")
    ]
