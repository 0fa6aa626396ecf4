"""``hitch goto`` names what slowed the motion, from the reply's ``limited``.

An operator's trial: ``motion 11 accepted, 4.96 s (slowed x0.80)`` while the reply named front_axle_load.
Truth: the reply a service gives for a goto the guard slowed (its ``limited`` as the service builds it).
"""

from __future__ import annotations

from bridge.cli import service as cli_service
from bridge.cli.main import main
from bridge.service.motion.types import guard_limits
from planner.limits.guard import GuardDecision, GuardReason


class _Client:
    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def goto(self, to, speed_scale=None, **kw):
        reason = GuardReason("front_axle_load", 11200.0, 11800.0, 1.2, "caution", "N")
        decision = GuardDecision("scaled", 0.8, (reason,))
        return {
            "motion_id": 11,
            "duration": 4.96,
            "speed_factor": 0.8,
            "guard": "scaled",
            "limited": guard_limits(decision),
        }


def test_a_slowed_goto_names_what_slowed_it(monkeypatch, capsys):
    monkeypatch.setattr(cli_service, "_client", lambda args: _Client())
    assert main(["goto", "--to", "z=0.2"]) == 0
    out = capsys.readouterr().out
    sentence = GuardReason("front_axle_load", 11200.0, 11800.0, 1.2, "caution", "N").sentence()
    assert out.strip() == f"motion 11 accepted, 4.96 s (slowed x0.80 by {sentence})", out
