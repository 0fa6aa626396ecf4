"""``control limited`` in the terminal (:func:`bridge.cli.output.limited_text`): each limit once, in words.

Truth: the strings a new user saw (``hitch track --sine z=0.02@0.5Hz --duration 2``, an implement with a
lowering speed limit of 0.05 m/s) and the words written by hand."""

from __future__ import annotations

from bridge.cli.output import limited_text


def test_the_lowering_speed_limit_of_a_track_session_is_said_once_in_words_with_units():
    control_limited = {
        "vz": "implement lowering speed limit",
        "implement lowering speed limit": (
            "speed: implement lowering speed limit would be 0.06001 m/s (threshold 0.05 m/s) at t = 0.00 s"
        ),
    }
    assert limited_text(control_limited) == (
        "lowering faster than the implement allows: 0.060 m/s (limit 0.050 m/s): slowed (vz)"
    )


def test_a_speed_factor_is_a_share_of_full_speed():
    lim = {"velocity:tilt": "speed: velocity:tilt would be 0.5084 (threshold 1) at t = 0.00 s"}
    assert limited_text(lim) == "tilt cylinder (right lift rod) at its speed limit: slowed to 51 % (velocity:tilt)"
