"""The operator switch's edges and what became of them (``ImplementService.switch_log``): a press that did not
move the hitch says why (refused by the API: also a ``hitch_switch_refused`` event; or dropped while the
previous press still ran)."""

import threading
import time

import pytest

from bridge.service.implements import SWITCH_EVENT_MAX_DELAY_S, SWITCH_HISTORY, ImplementService
from bridge.service.store import HitchStore
from tests.helpers import wait_until


@pytest.fixture
def switch(tmp_path):
    """``(svc, posted)``: an ImplementService on a fresh store whose motion collects the events it posts."""
    store = HitchStore(tmp_path / "hitch.sqlite3")
    posted: list[dict] = []

    class Motion:
        def post_event(self, event):
            posted.append(dict(event))

    try:
        yield ImplementService(store, motion=Motion()), posted
    finally:
        store.close()


def test_each_switch_edge_is_logged_with_its_answer_or_why_it_was_dropped(switch):
    svc, posted = switch
    release = threading.Event()
    refused = (False, {"error": "busy", "message": "refused: the planner stayed busy"})
    answers = iter([refused, (True, {"ok": 1})])

    def dispatch(key, payload):
        assert payload == b"{}"
        release.wait(5.0)
        return next(answers)

    svc.dispatch = dispatch
    svc.on_event({"event": "hitch_switch", "command": "raise"})
    svc.on_event({"event": "hitch_switch", "command": "return"})  # the raise still runs: dropped
    svc.on_event({"event": "hitch_switch", "command": "sideways"})  # not a command: nothing
    svc.on_event({"event": "state"})
    release.set()
    assert wait_until(lambda: len(svc.switch_log) == 2, 5.0)
    assert svc.switch_log[0] == ("hitch/return", "dropped: the previous switch request still runs")
    assert svc.switch_log[1] == ("hitch/raise", refused)
    assert posted == [
        {
            "event": "hitch_switch_refused",
            "command": "raise",
            "error": "busy",
            "message": "refused: the planner stayed busy",
        }
    ]
    svc.on_event({"event": "hitch_switch", "command": "return"})
    assert wait_until(lambda: len(svc.switch_log) == 3, 5.0)
    assert svc.switch_log[2] == ("hitch/return", (True, {"ok": 1}))
    assert len(posted) == 1  # an accepted press announces nothing more
    for _ in range(SWITCH_HISTORY + 3):  # bounded
        svc.switch_log.append(("hitch/raise", None))
    assert len(svc.switch_log) == SWITCH_HISTORY


def test_a_switch_event_that_reaches_the_service_late_is_not_acted_on(switch):
    """A safety trial: a stalled process acted on a switch press seconds later (a return, then the paused work
    resumed). An event delivered more than SWITCH_EVENT_MAX_DELAY_S after it was posted (its ``t``) is refused
    and announced; one delivered at once runs."""
    svc, posted = switch
    asked: list[str] = []
    svc.dispatch = lambda key, payload: (asked.append(key), (True, {}))[1]
    svc.on_event({"event": "hitch_switch", "command": "return", "t": time.time() - SWITCH_EVENT_MAX_DELAY_S - 1.0})
    assert wait_until(lambda: len(svc.switch_log) == 1, 5.0)
    key, (ok, reply) = svc.switch_log[0]
    assert key == "hitch/return" and not ok and "s after it happened" in reply["message"], reply
    assert asked == [] and posted[0]["event"] == "hitch_switch_refused" and posted[0]["command"] == "return"
    svc.on_event({"event": "hitch_switch", "command": "return", "t": time.time()})
    assert wait_until(lambda: asked == ["hitch/return"], 5.0)
