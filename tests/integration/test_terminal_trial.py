"""Defects an operator trial found in the browser terminal, each checked in headless Chromium against
``hitch serve --http`` in its own process (simulated ECU), as ``test_web_browser.py`` drives it.

Truths: the service's own ``/api/state`` (the pose, ``motion_id``, ``track``), its API replies (``plan``'s
``speed_factor`` and reasons), the slider's own value, the service process's exit status (a prefix conflict
ends the later service with status 2) and the workspace from ``config``.
"""

from __future__ import annotations

import contextlib
import json
import re
import signal
import threading
import time
from collections.abc import Iterator

import pytest

from tests.integration.test_web_browser import (
    Service,
    _install_chromium,
    at_rest,
    chromium_context,
    open_page,
    record_log,
    running_service,
    set_jog_speed,
    tab,
    wait_for,
    wait_js,
    wait_log,
)

pytestmark = pytest.mark.slow  # a real browser against the service in its own process


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    with chromium_context(_install_chromium(), tmp_path_factory.mktemp("chromium-profile-trial")) as ctx:
        yield ctx


def _open(ctx, url: str):
    pg = open_page(ctx, url)
    _wait_connected(pg)
    return pg


def _wait_connected(pg, timeout: float = 30_000) -> None:
    wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout)


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    with running_service(tmp_path_factory.mktemp("hitch-serve-trial")) as svc:
        yield svc


@pytest.fixture(scope="module")
def page(browser, service):
    pg = _open(browser, service.url)
    yield pg
    pg.close()


@pytest.fixture
def shots(tmp_path_factory):
    import os
    from pathlib import Path

    d = Path(os.environ.get("HITCH_SCREENSHOT_DIR") or tmp_path_factory.mktemp("screenshots-trial"))
    d.mkdir(parents=True, exist_ok=True)
    return d


def _level_status(pg) -> tuple[str, bool]:
    return pg.evaluate(
        "(() => { const e = document.getElementById('level-status');"
        " return [e.textContent, e.classList.contains('err')]; })()"
    )


# ------------------------------------------------------------------------------------------- 1. the slider
def test_arrow_keys_on_the_jog_speed_slider_change_the_speed_and_never_jog(service, page):
    """Trial: clicked the Jog speed slider, held ↑: a jog raised the hitch 239 → 264 mm, the slider stayed at 40 %."""
    at_rest(service, page)
    tab(page, "jog")
    set_jog_speed(page, 40)
    before = service.state()
    page.focus("#jog-speed")
    page.keyboard.down("ArrowUp")
    time.sleep(0.8)  # a jog would have started and moved by now
    after = service.state()
    page.keyboard.up("ArrowUp")
    assert page.evaluate("document.getElementById('jog-speed').value") == "50"  # the slider took the key (step 10)
    assert page.text_content("#jog-speed-out") == "50 %"
    assert after["motion_id"] == before["motion_id"] and not after["moving"], (before["motion_id"], after)
    assert abs(after["pose"]["z"] - before["pose"]["z"]) < 1e-3
    page.keyboard.down("ArrowLeft")  # left/right too: the slider, never x
    time.sleep(0.5)
    page.keyboard.up("ArrowLeft")
    assert page.evaluate("document.getElementById('jog-speed').value") == "40"
    assert service.state()["motion_id"] == before["motion_id"]
    # off the slider the arrow keys still jog (the keyboard dead-man)
    page.evaluate("document.activeElement.blur()")
    page.keyboard.down("ArrowUp")
    try:
        wait_for(lambda: service.state()["motion_id"] != before["motion_id"], 5, "a keyboard jog")
    finally:
        page.keyboard.up("ArrowUp")
    at_rest(service, page)


# ---------------------------------------------------------------------------------- 3. the levelling box
def test_the_levelling_control_limited_box_words_a_guard_sentence_like_the_main_box(page):
    """Trial: the levelling box showed "front_axle_load: caution: front_axle_load would be 1.212e+04 N
    (threshold 1.471e+04 N)" while the main box said it in words."""
    guard = "caution: front_axle_load would be 1.212e+04 N (threshold 1.471e+04 N)"
    words = page.evaluate(f"window.hitchTerminal.limitWords('front_axle_load', {json.dumps(guard)})")
    main = page.evaluate(f"window.hitchTerminal.limitedEntryWords('front_axle_load', {json.dumps(guard)})")
    assert "e+04" not in words and "would be" not in words, words
    assert words.startswith(main[0]) and "front axle" in words, (words, main)
    stroke = page.evaluate("window.hitchTerminal.limitWords('z', 'stroke:lift:max')")
    assert "stroke:lift:max" in stroke and not stroke.startswith("z: stroke"), stroke  # words, the code in brackets


# ------------------------------------------------------------------- 4./5. levelling refusals and take-over
def _stream_elsewhere(service, stop: threading.Event, out: dict) -> None:
    """Another client (hitch track) streaming z setpoints, until ``stop``."""
    status, reply = service.api("track/start", {"frame": "tractor", "dof": ["z"], "ttl_ms": 1000})
    assert status == 200, reply
    out["session"] = session = reply["session"]
    z = service.state()["pose"]["z"]
    seq = 0
    while not stop.is_set():
        service.api("track/setpoint", {"session": session, "seq": seq, "pose": {"z": z}})
        seq += 1
        time.sleep(0.1)
    service.api("track/stop", {"session": session})


@contextlib.contextmanager
def _streaming_elsewhere(service) -> Iterator[dict]:
    """Another client streams z setpoints (:func:`_stream_elsewhere`) while the block runs, its session in the
    yielded dict's ``session`` once its stream has sent two; it stops at the end of the block."""
    stop, out = threading.Event(), {}
    t = threading.Thread(target=_stream_elsewhere, args=(service, stop, out), daemon=True)
    t.start()
    try:
        wait_for(lambda: (service.state().get("track") or {}).get("setpoints", 0) >= 2, 10, "the other stream")
        yield out
    finally:
        stop.set()
        t.join(10)


def test_a_busy_levelling_toggle_says_who_streams_offers_a_take_over_and_forgets_the_refusal(service, page, shots):
    """Trial: the refusal said "track/stop ends it; track/start with replace: true (hitch track --replace)" —
    neither of which the terminal has — and stayed red long after the other session had ended."""
    at_rest(service, page)
    with _streaming_elsewhere(service) as out:
        page.click("#level-toggle")
        page.wait_for_selector("#confirm:not(.hidden)")
        text = page.text_content("#confirm-text")
        assert "Another client is streaming setpoints" in text and f"track session {out['session']}" in text, text
        page.screenshot(path=str(shots / "trial-level-take-over.png"))
        page.click("#confirm-cancel")
        wait_js(page, "document.getElementById('level-status').classList.contains('err')")
        status, _ = _level_status(page)
        assert "another client is streaming setpoints" in status and "STOP ends it" in status, status
        assert "replace" not in status and "hitch track" not in status and "track/stop" not in status, status
    wait_for(lambda: service.state().get("track") is None, 10, "the other session to end")
    # the other session ended: the refusal is no longer news
    wait_js(page, "!document.getElementById('level-status').classList.contains('err')")
    assert "another client" not in _level_status(page)[0]

    # take-over: the terminal sends replace: true when the operator confirms
    at_rest(service, page)
    with _streaming_elsewhere(service) as out:
        page.click("#level-toggle")
        page.wait_for_selector("#confirm:not(.hidden)")
        page.click("#confirm-ok")
        wait_js(page, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'true'")
        track = wait_for(
            lambda: (lambda tr: tr if tr and tr.get("session") != out["session"] else None)(
                service.state().get("track")
            ),
            5,
            "the terminal's own session",
        )
        assert track["frame"] == "level" and track["dof"] == ["roll"], track
    page.click("#level-toggle")
    wait_js(page, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'false'")
    at_rest(service, page)


# ------------------------------------------------------------------------------- 7. the limit in the footer
def test_the_limit_reached_line_names_the_limit_in_words(service, page):
    """Trial: the footer said "limit reached #18" without naming the limit (the event carries ``limits``)."""
    at_rest(service, page)
    tab(page, "jog")
    set_jog_speed(page, 100)
    record_log(page)
    sel = "button.jog[data-dof='x'][data-sign='1']"
    box = page.locator(sel).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    try:
        wait_log(page, r"limit reached #\d+: .*left limit reached.*\[workspace:x:max\]", 15_000)
    finally:
        page.mouse.up()
    at_rest(service, page)


# ------------------------------------------------------------------------------------ 8. Check's "(scaled)"
def test_check_says_how_much_the_guard_slows_a_goto_and_why(service, page):
    """Trial: Check showed "(scaled)" alone; the plan reply has speed_factor 0.8 and the front axle as reason.
    A 1200 kg implement 0.8 m behind the hitch, lowered to z = 0: the guard slows it (front axle load)."""
    at_rest(service, page)
    heavy = {"name": "heavy", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.8, 0.3]}
    assert service.api("implements/define", heavy)[0] == 200
    assert service.api("implements/select", {"name": "heavy"})[0] == 200
    try:
        status, plan = service.api("plan", {"goal": {"z": 0.0}, "speed_scale": 1.0})
        assert status == 200 and plan["ok"] and plan["speed_factor"] < 1, plan
        tab(page, "goto")
        for k in ("x", "roll", "pitch"):
            page.fill(f"#goto-form input[name={k}]", "")
        page.fill("#goto-form input[name=z]", "0")
        page.fill("#goto-form input[name=speed]", "100")
        page.evaluate("document.getElementById('goto-result').textContent = ''")
        page.click("#goto-plan")
        wait_js(page, "document.getElementById('goto-result').textContent.startsWith('reachable')")
        text = page.text_content("#goto-result")
        assert f"slowed to {round(100 * plan['speed_factor'])} %" in text, text
        assert "front axle load" in text and "% of the tractor's weight" in text, text
        assert "scaled" not in text and "e+0" not in text, text
    finally:
        service.api("implements/select", {"name": "default"})


# ----------------------------------------------------------------------------- minor: depth, x bar ticks
def test_work_depth_below_a_tenth_of_a_cm_is_refused_in_the_dialog(service, page):
    """Trial: depth 0.001–0.002 cm was taken and summarised as "depth 0–0 cm"."""
    tab(page, "work")
    wait_js(page, "window.hitchTerminal.work.settings !== null")
    page.click("#work-settings")
    page.wait_for_selector("#work-dialog:not(.hidden)")
    for name, value in (("draft_kn", "20"), ("blend", "0.5"), ("depth_min_cm", "0.001"), ("depth_max_cm", "0.002")):
        page.fill(f"#work-form input[name={name}]", value)
    before = service.api("work/settings")[1]["settings"]
    page.click("#work-save")
    wait_js(page, "document.getElementById('work-form-result').classList.contains('err')")
    assert "steps of 0.1 cm" in page.text_content("#work-form-result")
    assert service.api("work/settings")[1]["settings"] == before  # nothing saved
    page.click("#work-cancel")


def test_the_x_bar_ticks_are_unsigned_like_the_left_right_readout(page):
    ticks = page.evaluate("Array.from(document.querySelectorAll('#g-x text.dim')).map((t) => t.textContent)")
    assert ticks and not any(re.search(r"[-−]", t) for t in ticks), ticks


# ---------------------------------------------------- 4. levelling over a service restart; jog disconnected
def test_over_a_service_restart_the_levelling_line_forgets_old_refusals_and_motion_numbers(browser, tmp_path_factory):
    """Trial: "not connected" stayed red after the reconnect, and after a service restart (motion numbers start
    again) an unrelated motion with the levelling's number ending made the line say "off: replaced by …".
    A jog while disconnected was dropped silently (goto said "not connected")."""
    svc = Service(tmp_path_factory.mktemp("hitch-serve-restart")).start()
    pg = None
    try:
        pg = _open(browser, svc.url)
        pg.click("#level-toggle")
        wait_js(pg, "document.getElementById('level-toggle').getAttribute('aria-pressed') === 'true'")
        level_motion = wait_for(lambda: (svc.state().get("track") or {}) and svc.state()["motion_id"], 5, "levelling")
        svc.kill()  # the service dies while levelling
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: disconnected')")
        record_log(pg)
        tab(pg, "jog")
        b = pg.locator("button.jog[data-dof='z'][data-sign='1']").bounding_box()
        pg.mouse.move(b["x"] + b["width"] / 2, b["y"] + b["height"] / 2)
        pg.mouse.down()
        try:
            wait_log(pg, "jog: not connected", 3_000)
        finally:
            pg.mouse.up()
        pg.click("#level-toggle")  # refused: not connected
        wait_js(pg, "document.getElementById('level-status').textContent.includes('not connected')")
        assert _level_status(pg)[1]
        svc.start()
        _wait_connected(pg)
        wait_js(pg, "!document.getElementById('level-status').classList.contains('err')")
        assert "not connected" not in _level_status(pg)[0]
        # motions on the new service until one has the levelling's old number; it ends replaced by a goto
        z = svc.state()["pose"]["z"]
        while True:
            status, r = svc.api("goto", {"goal": {"z": z - 0.05}, "speed_scale": 0.2})
            assert status == 200, r
            if r["motion_id"] >= level_motion:  # the same goal again otherwise: each goto is a motion of its own
                break
        assert r["motion_id"] == level_motion, (r, level_motion)
        time.sleep(0.3)
        status, r2 = svc.api("goto", {"goal": {"z": z + 0.02}, "speed_scale": 0.5})  # replaces it
        assert status == 200, r2
        wait_for(lambda: not svc.state()["moving"], 20, "rest")
        time.sleep(0.3)
        text, err = _level_status(pg)
        assert "replaced" not in text and not err, text
        assert not [e for e in pg.errors if "ERR_CONNECTION_REFUSED" not in e], pg.errors  # refused while it was down
    finally:
        if pg is not None:
            pg.close()
        svc.kill(signal.SIGTERM)
        svc.kill()


# --------------------------------------------------------------------------------- 2. a prefix conflict
def test_a_prefix_conflict_is_a_lasting_red_banner_naming_what_to_do(browser, tmp_path_factory, shots):
    """Trial: the service announced ``prefix_conflict`` and ended itself; the terminal showed a grey footer line,
    overwritten by the next event, then "connection lost — retrying…" for ever. Here a Zenoh client declares
    the instance token of a service that started earlier on the same prefix: this service is the later one."""
    import zenoh

    svc = Service(tmp_path_factory.mktemp("hitch-serve-conflict")).start()
    pg = session = None
    try:
        pg = _open(browser, svc.url)
        assert pg.is_hidden("#conflict")
        cfg = zenoh.Config()
        cfg.insert_json5("mode", json.dumps("client"))
        cfg.insert_json5("connect/endpoints", json.dumps([f"tcp/127.0.0.1:{svc.zenoh_port}"]))
        cfg.insert_json5("scouting/multicast/enabled", "false")
        session = zenoh.open(cfg)
        token = session.liveliness().declare_token("hitch/instance/00000000000000000001-0a")
        wait_js(pg, "!document.getElementById('conflict').classList.contains('hidden')")
        text = pg.text_content("#conflict-text")
        assert "Prefix conflict" in text and "another hitch service" in text and "hitch" in text, text
        assert "00000000000000000001-0a" in text, text  # the other instance
        assert "ends itself" in text and "Stop one of the two services" in text, text
        assert svc.proc.wait(30) == 2  # the later service ends (hitch serve exits with status 2)
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: disconnected')")
        time.sleep(1.0)
        assert pg.is_visible("#conflict") and "Prefix conflict" in pg.text_content("#conflict-text")  # it lasts
        bg = pg.evaluate("getComputedStyle(document.getElementById('conflict')).backgroundColor")
        r, g, b = (int(v) for v in re.findall(r"\d+", bg)[:3])
        assert r > 150 and g < 100 and b < 100, bg  # red
        pg.screenshot(path=str(shots / "trial-prefix-conflict.png"))
        pg.click("#conflict-dismiss")
        assert pg.is_hidden("#conflict")
        token.undeclare()
    finally:
        if session is not None:
            session.close()
        if pg is not None:
            pg.close()
        svc.kill(signal.SIGTERM)
        svc.kill()


# ------------------------------------------------------------------------------------- 6. nothing cut off
# every visible element inside the viewport's width; a leaf whose text is wider than its box where the box does not
# show the rest; an SVG text outside its drawing (the x bar's, the dials', the hitch picture's labels)
CLIPPED_JS = """() => {
  const vw = document.documentElement.clientWidth, bad = [];
  const name = (e) => e.id || (e.className && (e.className.baseVal ?? e.className)) || e.tagName;
  for (const e of document.querySelectorAll('body *')) {
    if (e.closest('.hidden') || e.getClientRects().length === 0) continue;
    const r = e.getBoundingClientRect();
    if (!r.width) continue;
    if (r.right > vw + 0.5 || r.left < -0.5) bad.push(['outside', name(e), e.textContent.slice(0, 30)]);
    if (!(e instanceof SVGElement) && e.children.length === 0 && e.clientWidth > 0
        && e.scrollWidth > e.clientWidth + 1 && getComputedStyle(e).overflowX !== 'visible')
      bad.push(['cut', name(e), e.textContent.slice(0, 40)]);
  }
  for (const t of document.querySelectorAll('svg text')) {
    if (t.closest('.hidden') || !t.textContent) continue;
    const s = t.ownerSVGElement.getBoundingClientRect(), r = t.getBoundingClientRect();
    if (!r.width) continue;
    if (r.left < s.left - 0.5 || r.right > s.right + 0.5 || r.top < s.top - 1 || r.bottom > s.bottom + 1)
      bad.push(['svg', t.ownerSVGElement.id, t.textContent]);
  }
  // texts of the hitch picture that overlap each other ("↑624 mm" ran into "right ▶")
  for (const v of document.querySelectorAll('svg.view')) {
    const ts = Array.from(v.querySelectorAll('text')).filter((t) => t.textContent)
      .map((t) => [t, t.getBoundingClientRect()]);
    for (let i = 0; i < ts.length; i++) for (let j = i + 1; j < ts.length; j++) {
      const [a, ra] = ts[i], [b, rb] = ts[j];
      if (ra.width && rb.width && ra.left < rb.right - 1 && rb.left < ra.right - 1
          && ra.top < rb.bottom - 1 && rb.top < ra.bottom - 1)
        bad.push(['overlap', v.id, a.textContent + ' / ' + b.textContent]);
    }
  }
  return bad;
}"""


@pytest.mark.parametrize("size", [(360, 740), (1024, 768)], ids=["360x740", "1024x768"])
def test_nothing_is_cut_off_on_a_phone_and_at_1024x768(service, page, shots, size):
    """Trial at 360 px: the Go to ranges ran past the panel (285–377 px, panel ends at 354), the Work settings
    dialog cut "0–300" to "0–30", the rear view's "↑624 mm" overlapped "right ▶", the side view's label was cut;
    at 1024 px the header pill "Moving: goto …" lost its motion number."""
    w, h = size
    page.set_viewport_size({"width": w, "height": h})
    try:
        page.reload()
        _wait_connected(page)
        wait_js(page, "document.querySelectorAll('#v-rear text.hgt').length === 2")
        time.sleep(0.5)
        problems = {}
        for t in ("jog", "goto", "presets", "maneuvers", "implement", "work", "help"):
            tab(page, t)
            if t == "maneuvers":
                page.evaluate("document.querySelectorAll('#tab-maneuvers details').forEach((d) => { d.open = true; })")
            time.sleep(0.2)
            problems[t] = page.evaluate(CLIPPED_JS)
            if t == "goto":
                page.screenshot(path=str(shots / f"trial-goto-{w}x{h}.png"))
        tab(page, "work")
        page.click("#work-settings")
        page.wait_for_selector("#work-dialog:not(.hidden)")
        problems["work dialog"] = page.evaluate(CLIPPED_JS)
        page.screenshot(path=str(shots / f"trial-work-settings-{w}x{h}.png"))
        page.click("#work-cancel")
        page.evaluate("document.querySelector('main').scrollTop = 1e6")
        time.sleep(0.3)
        page.screenshot(path=str(shots / f"trial-views-{w}x{h}.png"))
        assert not any(problems.values()), {k: v for k, v in problems.items() if v}
        # a running goto's pill keeps its number
        at_rest(service, page)
        z = service.state()["pose"]["z"]
        status, r = service.api("goto", {"goal": {"z": z - 0.06}, "speed_scale": 0.1})
        assert status == 200, r
        wait_js(page, "document.getElementById('motion').textContent.startsWith('Moving')")
        pill = page.evaluate(
            "(() => { const m = document.getElementById('motion');"
            " return [m.textContent, m.scrollWidth, m.clientWidth]; })()"
        )
        assert pill[0].endswith(f"#{r['motion_id']}") and pill[1] <= pill[2], pill
        assert page.evaluate("document.documentElement.scrollWidth") <= w
        page.screenshot(path=str(shots / f"trial-moving-{w}x{h}.png"))
    finally:
        service.api("stop")
        page.set_viewport_size({"width": 1024, "height": 600})
        page.reload()
        _wait_connected(page)


# ---------------------------------------------------------------------- minor: the maneuver editor's units
def test_the_maneuver_editor_answers_in_the_scripts_units(service, page):
    """Trial: the editor takes metres (``goto: {z: 0.5}``) but its refusal said "goal.z = 500 mm"."""
    tab(page, "maneuvers")
    page.evaluate("document.getElementById('maneuver-editor').open = true")
    page.fill("#maneuver-form input[name=name]", "high")
    page.fill("#maneuver-form textarea[name=script]", "name: high\nsteps:\n  - goto: {z: 0.5}\n")
    page.evaluate("document.getElementById('maneuver-result').textContent = ''")
    page.click("#maneuver-validate")
    wait_js(page, "document.getElementById('maneuver-result').textContent.length > 0")
    text = page.text_content("#maneuver-result")
    assert "0.5" in text and not re.search(r"\d mm", text), text  # metres, as typed
