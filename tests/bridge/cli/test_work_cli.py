"""``hitch work`` against the live service's replies (bridge.cli.work).

A field trial: ``hitch work stop`` at the headland while work was paused (``work start --z 0``, ``raise
--wait``, ``work stop``) crashed with ``KeyError: 'session'`` and exit 1, though the service had cleared the
pause as documented (its reply ``{"stopping": false, "work_paused_cleared": …}``); ``hitch work resume``
printed "resumed:" while its reply showed the fallback still latched (it engages on the next cycle and,
without a draft, falls back again at once).

Truth: the service's own replies — a work service on the simulated rig in simulated time (the API and the
controller of the live service, no Zenoh), reached through a client stand-in that hands each request to
``ServiceAPI.handle`` — and the events it announces.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from bridge.cli import service as cli_service
from bridge.cli.main import main
from bridge.service.client import ServiceError
from bridge.service.work import WorkControl
from tests.helpers import SimService

#: a light tine implement with a headland pose (docs/implements.md)
TINE = {
    "name": "tine",
    "category": "2",
    "mass_kg": 150.0,
    "com_m": [0.0, 0.3, 0.2],
    "headland": {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0},
}


class _Inputs:
    """Work control's inputs: a draft reading (None: the draft pins send nothing) and a fixed ground."""

    def __init__(self) -> None:
        self.value: float | None = 1_000.0

    def draft(self, now):
        return (None if self.value is None else self.value + 10.0 * np.sin(37.0 * now)), now

    def slip(self, now):
        return None

    def ground_z(self, now):
        return 0.3


class _Service(SimService):
    def __init__(self, model, path, inputs):
        super().__init__(model, path, prepare=lambda mc: setattr(mc, "work", WorkControl(mc, inputs)))

    def ok(self, key, payload=None):
        ok, r = self.call(key, payload)
        assert ok, (key, r)
        return r

    def run_forwarding(self, seconds: float) -> None:
        """``run`` with the controller's events handed to the implements logic (as the service's listener does)."""
        seen = len(self.events)

        def each() -> None:
            nonlocal seen
            new, seen = self.events[seen:], len(self.events)
            for e in new:
                self.api.implements.on_event(e)

        self.run(seconds, each)


class _Client:
    """The CLI's client: each request to the service's API, its reply (or ServiceError, as the real client)."""

    def __init__(self, svc: _Service, replies: list):
        self.svc, self.replies = svc, replies

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def request(self, key, payload=None, **kw):
        ok, r = self.svc.call(key, payload)
        self.replies.append((key, r))
        if not ok:
            raise ServiceError(r["error"], r["message"])
        return r


@pytest.fixture
def work(model, tmp_path, monkeypatch):
    inputs = _Inputs()
    svc = _Service(model, tmp_path / "hitch.sqlite3", inputs)
    svc.inputs = inputs
    svc.replies = []
    monkeypatch.setattr(cli_service, "_client", lambda args: _Client(svc, svc.replies))
    yield svc
    svc.close()


def test_work_stop_at_the_headland_says_the_paused_work_is_cleared_and_exits_0(work, capsys, monkeypatch):
    """``work start --z 0.1``, the quick raise to the headland, ``work stop``: no session runs, the service clears
    the pause and says so; the CLI prints it in words (before: ``KeyError: 'session'``, exit 1), and ``--json``
    prints the reply."""
    work.ok("implements/define", TINE)
    work.ok("implements/select", {"name": "tine"})
    work.ok("work/settings", {"mode": "position"})
    assert main(["work", "start", "--z", "0.1"]) == 0
    session = work.replies[-1][1]["session"]
    assert f"work session {session} started" in capsys.readouterr().out
    work.run_forwarding(3.0)
    r = work.ok("hitch/raise")
    assert r["work_paused"]["session"] == session
    work.run_forwarding(r["duration"] + 1.0)
    assert main(["work", "stop"]) == 0
    reply = work.replies[-1][1]
    assert reply["stopping"] is False and reply["work_paused_cleared"]["session"] == session, reply
    out = capsys.readouterr().out.strip()
    assert out == (
        f"no work session was running; paused work cleared (session {session}, position mode, operator's z "
        "0.100 m): it will not restart on return (hitch return only goes back)"
    ), out
    assert work.api.implements.paused_work is None
    r = work.ok("hitch/return")
    assert "resumes_work" not in r  # the service agrees: the return only goes back

    class Same(_Client):  # the same reply again, for --json (a second stop finds nothing to clear)
        def request(self, key, payload=None, **kw):
            assert key == "work/stop"
            return reply

    monkeypatch.setattr(cli_service, "_client", lambda args: Same(work, []))
    assert main(["work", "stop", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == json.loads(json.dumps(reply))


def test_work_stop_of_a_running_session_names_it(work, capsys):
    work.ok("work/settings", {"mode": "position"})
    session = work.ok("work/start", {"z": 0.05})["session"]
    work.run(0.5)
    assert main(["work", "stop"]) == 0
    motion = work.replies[-1][1]["motion_id"]
    assert capsys.readouterr().out.strip() == f"work session {session} stopping (motion {motion})"


def test_work_resume_says_the_fallback_it_clears_and_that_it_falls_back_again_without_its_cause_gone(work, capsys):
    """A draft session without a draft reading falls back to position; ``work resume`` while the draft is still
    missing: the reply's block still holds the fallback (the resume engages on the next cycle) and the session
    falls back again at once. Before, the CLI printed "resumed:" (and the fallback line telling to resume)."""
    work.ok("implements/define", TINE)
    work.ok("implements/select", {"name": "tine"})
    work.ok("work/settings", {"mode": "draft"})
    work.inputs.value = None
    session = work.ok("work/start", {"z": 0.1})["session"]
    work.run(1.0)
    assert len([e for e in work.events if e["event"] == "work_fallback"]) == 1
    assert main(["work", "resume"]) == 0
    reply = work.replies[-1][1]
    assert reply["fallback"] and "no reading" in reply["fallback"], reply
    out = capsys.readouterr().out
    assert not out.startswith("resumed"), out
    head = out.splitlines()[0]
    assert head.startswith(f"work session {session}: resume asked: draft control engages again"), head
    assert reply["fallback"] in head and "falls back again at once" in head, head
    assert "(hitch work resume)" not in out  # the line that asks for a resume is not printed after one
    work.run(1.0)
    assert len([e for e in work.events if e["event"] == "work_fallback"]) == 2  # it did fall back again
    # with the draft back: the resume engages and stays; a second resume has nothing to clear
    work.inputs.value = 20_000.0
    assert main(["work", "resume"]) == 0
    capsys.readouterr()
    work.run(0.5)
    assert work.states[-1]["work"]["fallback"] is None
    assert main(["work", "resume"]) == 0
    head = capsys.readouterr().out.splitlines()[0]
    assert head == f"work session {session}: nothing to resume: no fallback latched, draft control in effect", head
