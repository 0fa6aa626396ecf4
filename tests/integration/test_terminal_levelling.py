"""The terminal's Levelling toggle in a real browser (headless Chromium, 1024×600 and 800×480) against
``hitch serve --http`` in its own process (simulated ECU, the tractor twin on flat ground).

Truths: the service's own ``/api/state`` (``motion``, the ``track`` entry), its ``track/stop`` and
TTL outcomes, the measured roll (flat ground: the slope sensor reads 0, so roll_level = 0 means
roll_tractor = 0 within the closed loop's 2 mrad) and the workspace from ``config``.
"""

from __future__ import annotations

import time

import pytest

from bridge.service.motion.controller import STOP_GRACE_S
from tests.integration.test_web_browser import (
    _install_chromium,
    chromium_context,
    open_page,
    running_service,
    wait_for,
    wait_js,
)

pytestmark = pytest.mark.slow  # a real browser against the service in its own process

ROLL_TOL = 2e-3  # rad: the closed loop's steady state (README, "Closed loop over CAN")


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    with running_service(tmp_path_factory.mktemp("hitch-serve-levelling")) as svc:
        yield svc


@pytest.fixture(scope="module")
def page(service, tmp_path_factory):
    with chromium_context(_install_chromium(), tmp_path_factory.mktemp("chromium-profile-levelling")) as ctx:
        pg = open_page(ctx, service.url, first=True)
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", 20_000)
        yield pg


@pytest.fixture
def shots(tmp_path_factory):
    import os
    from pathlib import Path

    d = Path(os.environ.get("HITCH_SCREENSHOT_DIR") or tmp_path_factory.mktemp("screenshots-levelling"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _rest(service) -> None:
    """Stop; wait for rest, no track session and no fault held (a self-clearing fault after a host
    stall refuses motion for about a second: see ``tests/bridge/web/test_web_api.py`` ``_rest``)."""
    service.api("stop")

    def ready() -> bool:
        st = service.state()
        return not st["moving"] and st.get("track") is None and not st["ecu"]["faults"]

    wait_for(ready, 15, "rest, no session, no fault held")
    time.sleep(STOP_GRACE_S + 0.02)  # a motion request just after a stop may have been sent before it: refused


def _pressed(pg) -> str:
    return pg.get_attribute("#level-toggle", "aria-pressed") or ""


def _stop_fully_visible(pg, width: int, height: int) -> None:
    box = pg.locator("#stop").bounding_box()
    assert box is not None and box["x"] >= 0 and box["y"] >= 0
    assert box["x"] + box["width"] <= width and box["y"] + box["height"] <= height, box
    hit = pg.evaluate("([x, y]) => document.elementFromPoint(x, y).id", [box["x"] + box["width"] / 2, box["y"] + 8])
    assert hit == "stop"


def test_levelling_toggle_streams_roll_zero_and_track_stop_ends_it(service, page, shots):
    _rest(service)
    status, reply = service.api("goto", {"goal": {"roll": 0.03}})
    assert status == 200, reply
    wait_for(
        lambda: abs(service.state()["pose"]["roll"] - 0.03) < ROLL_TOL and not service.state()["moving"], 20, "roll 30"
    )

    page.click("#level-toggle")
    wait_js(page, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'true'")
    st = wait_for(lambda: (s := service.state()).get("track") and s, 5, "a track session in the state")
    assert st["motion"] == "track"
    assert st["track"]["frame"] == "level" and st["track"]["dof"] == ["roll"]
    # the page's setpoints {roll: 0} in frame level: on flat ground the hitch rolls back to 0 (tractor frame)
    wait_for(lambda: abs(service.state()["pose"]["roll"]) < ROLL_TOL, 20, "roll levelled to 0 ± 2 mrad")
    n0, t0 = service.state()["track"]["setpoints"], time.monotonic()
    time.sleep(2.0)
    tr = service.state()["track"]
    rate = (tr["setpoints"] - n0) / (time.monotonic() - t0)
    assert 5.0 <= rate <= 12.0, f"{rate:.1f} setpoints/s (the page sends every 100 ms)"
    assert tr["rejected"] == 0 and tr["ignored_seq"] == 0 and not tr["stale"]
    counts = page.text_content("#level-counts")
    assert "setpoints" in counts and "rejected 0" in counts, counts
    assert "on · session" in page.text_content("#level-status")
    assert page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]") == [1024, 600]
    _stop_fully_visible(page, 1024, 600)
    page.screenshot(path=str(shots / "16-levelling-on.png"))

    page.click("#level-toggle")  # off: track/stop, braking smoothly to rest
    wait_js(page, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'false'")
    wait_for(lambda: service.state().get("track") is None, 10, "the session to end")
    wait_js(page, "document.getElementById('level-status').textContent.includes('off: track/stop')")
    assert abs(service.state()["pose"]["roll"]) < ROLL_TOL
    assert page.errors == []


def test_hiding_the_page_stops_the_stream_and_the_service_brakes_at_the_ttl(service, page, shots):
    _rest(service)
    page.click("#level-toggle")
    wait_for(lambda: (service.state().get("track") or {}).get("setpoints", 0) >= 3, 5, "setpoints arriving")
    # the tab goes to the background (simulated: document.hidden and its event, as a browser does)
    page.evaluate(
        "Object.defineProperty(document, 'hidden', {configurable: true, get: () => true});"
        "document.dispatchEvent(new Event('visibilitychange'))"
    )
    try:
        assert _pressed(page) == "false"
        n = service.state()["track"]["setpoints"]
        wait_for(lambda: service.state().get("track") is None, 5, "the service to end the stale session")
        wait_js(page, "document.getElementById('level-status').textContent.includes('stale')")
        status = page.text_content("#level-status")
        assert "500 ms" in status, status  # the service's reason: no setpoint within the TTL
    finally:
        page.evaluate("delete document.hidden; document.dispatchEvent(new Event('visibilitychange'))")
    assert n >= 3
    page.screenshot(path=str(shots / "17-levelling-stale.png"))


def test_stop_ends_levelling_and_the_limit_is_named_in_words(service, page):
    _rest(service)
    page.click("#level-toggle")
    wait_for(lambda: service.state().get("track") is not None, 5, "a session")
    page.click("#stop")
    wait_js(page, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'false'")
    wait_for(lambda: service.state().get("track") is None and not service.state()["moving"], 10, "rest after STOP")
    _, cfg = service.api("config")
    hi = cfg["limits"]["workspace"]["roll"][1]
    words = page.evaluate("window.hitchTerminal.limitWords('roll', 'workspace:roll:max')")
    assert words == f"roll at its upper workspace limit ({hi * 1000:.1f} mrad)"
    assert page.evaluate("window.hitchTerminal.limitWords('vroll', 'velocity:roll')") == "roll at its speed limit"


def test_at_800x480_stop_and_the_toggle_stay_visible(service, page, shots):
    _rest(service)
    page.set_viewport_size({"width": 800, "height": 480})
    try:
        page.click("#level-toggle")
        wait_js(page, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'true'")
        assert page.is_visible("#level-toggle") and page.is_visible("#level-status")
        _stop_fully_visible(page, 800, 480)
        page.screenshot(path=str(shots / "18-levelling-800x480.png"))
        page.click("#level-toggle")
        wait_for(lambda: service.state().get("track") is None, 10, "the session to end")
    finally:
        page.set_viewport_size({"width": 1024, "height": 600})


class _RepliesAfterOutcome:
    """A page whose websocket to the service holds back the reply to ``key`` until the event ``outcome``
    (a predicate on the event's data) has been delivered: the order a loaded service can produce, every time.
    Playwright runs the route's callbacks while the test thread calls into it (``pump``)."""

    def __init__(self, page, key: str, outcome):
        import json
        import threading

        self.page = page.context.new_page()
        self.page.set_default_timeout(10_000)
        self.ids: set[int] = set()
        self.held: list[str] = []
        self.delivered = threading.Event()

        def route(ws):
            server = ws.connect_to_server()

            def to_server(m):
                try:
                    cmd = json.loads(m)
                except (TypeError, ValueError):
                    cmd = None
                if isinstance(cmd, dict) and cmd.get("key") == key:
                    self.ids.add(cmd.get("id"))
                server.send(m)

            def to_page(m):
                try:
                    msg = json.loads(m)
                except (TypeError, ValueError):
                    msg = {}
                if msg.get("type") == "reply" and msg.get("id") in self.ids and not self.delivered.is_set():
                    self.held.append(m)  # the reply waits for the outcome
                    return
                ws.send(m)
                if msg.get("type") == "event" and outcome(msg.get("data") or {}):
                    self.delivered.set()
                    while self.held:
                        ws.send(self.held.pop(0))

            ws.on_message(to_server)
            server.on_message(to_page)

        self.page.route_web_socket("**", route)

    def open(self, url: str) -> None:
        self.page.goto(url)
        wait_js(self.page, "document.getElementById('conn').textContent.startsWith('Service: connected')", 20_000)

    def wait_outcome_then_reply(self, timeout_s: float = 15.0) -> None:
        wait_for(
            lambda: self.page.evaluate("1") and self.delivered.is_set() and not self.held,
            timeout_s,
            "the outcome, then the held reply",
        )
        self.page.wait_for_timeout(300)  # the page has handled the reply


def test_the_outcome_stays_shown_when_it_arrives_before_the_stops_reply(service, page):
    """CI saw the status end as 'off: braking to rest': the motion_finished event (reason track/stop) reached
    the page before the reply to track/stop, and the reply overwrote it."""
    _rest(service)
    held = _RepliesAfterOutcome(
        page, "track/stop", lambda e: e.get("event") == "motion_finished" and e.get("reason") == "track/stop"
    )
    pg = held.page
    try:
        held.open(service.url)
        pg.click("#level-toggle")
        wait_js(pg, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'true'")
        wait_for(lambda: service.state().get("track"), 5, "a track session in the state")
        pg.click("#level-toggle")
        held.wait_outcome_then_reply()
        assert "off: track/stop" in pg.text_content("#level-status")
    finally:
        pg.close()


def test_a_goto_that_ends_before_its_reply_shows_its_outcome(service, page):
    """The same order for a goto: on the old page the outcome was dropped (the goto's id was not known yet)
    and 'moving: motion #N' stayed forever."""
    from tests.integration.test_web_browser import tab

    _rest(service)
    held = _RepliesAfterOutcome(page, "goto", lambda e: e.get("event") == "motion_finished" and e.get("kind") == "goto")
    pg = held.page
    try:
        held.open(service.url)
        tab(pg, "goto")
        for k, v in (("x", ""), ("z", "150.0"), ("roll", ""), ("pitch", "")):
            pg.fill(f"#goto-form input[name={k}]", v)
        pg.click("#goto-go")
        held.wait_outcome_then_reply(30.0)
        text = pg.text_content("#goto-result")
        assert text.endswith("finished") and text.startswith("motion #"), text
    finally:
        pg.close()
