"""The operator terminal in a real browser: headless Chromium driven by Playwright against
``hitch serve --http`` running in its own process with the simulated ECU.

Set-up installs what is missing and never skips: Debian's ``chromium`` through apt-get (root), the
``playwright`` Python package must be installed (the ``test`` extra); its bundled browser is not
used (``playwright install`` downloads one and fails here) — we launch ``/usr/bin/chromium``.

Screenshots go to ``$HITCH_SCREENSHOT_DIR`` when set (``docs/screenshots`` to refresh the docs),
otherwise to a temporary folder.

Truths the page is checked against: the service's own ``/api/state`` and ``presets/list`` answers,
the goal typed in (settling within the closed loop's steady-state target: 2 mm, 2 mrad), the workspace
limit's name, and the service process being gone.
"""

from __future__ import annotations

import contextlib
import http.cookiejar
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from bench._common import free_port
from bridge.service.motion.controller import STOP_GRACE_S

pytestmark = pytest.mark.slow  # a real browser against the service in its own process

CHROMIUM = "/usr/bin/chromium"
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]
STEADY_STATE_TARGET = {"x": 2e-3, "z": 2e-3, "roll": 2e-3, "pitch": 2e-3}  # |(dx, dz)| <= 2 mm, angles <= 2 mrad
ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------- set-up
def _install_chromium() -> str:
    if Path(CHROMIUM).is_file():
        return CHROMIUM
    if shutil.which("apt-get") is None or os.geteuid() != 0:
        pytest.fail(
            f"{CHROMIUM} is missing and cannot be installed here (needs root and apt-get): "
            "run `apt-get update && apt-get install -y chromium` first"
        )
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd, timeout in ((["apt-get", "update"], 300), (["apt-get", "install", "-y", "chromium"], 900)):
        try:
            r = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f"`{' '.join(cmd)}` did not finish within {timeout} s")
        if r.returncode != 0:
            pytest.fail(f"`{' '.join(cmd)}` failed ({r.returncode}): {r.stderr.strip()[-500:]}")
    if not Path(CHROMIUM).is_file():
        pytest.fail(f"apt-get installed chromium but {CHROMIUM} does not exist")
    return CHROMIUM


@pytest.fixture(scope="module")
def chromium() -> str:
    return _install_chromium()


@pytest.fixture(scope="module")
def shots(tmp_path_factory) -> Path:
    d = Path(os.environ.get("HITCH_SCREENSHOT_DIR") or tmp_path_factory.mktemp("screenshots"))
    d.mkdir(parents=True, exist_ok=True)
    return d


class Service:
    """``hitch serve --http`` in its own process (own process group, killed in teardown).

    ``login``: (user, password) the test's own requests log in with (a service with access control)."""

    def __init__(self, data_dir: Path, *extra: str, login: tuple[str, str] | None = None):
        self.data_dir, self.extra = data_dir, list(extra)
        self.http_port, self.zenoh_port = free_port(), free_port()
        self.url = f"http://127.0.0.1:{self.http_port}/"
        self.proc: subprocess.Popen | None = None
        self.login = login
        self.csrf: str | None = None
        self._opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(http.cookiejar.CookieJar()))

    def _log_in(self) -> None:
        if self.login is None or self.csrf is not None:
            return
        user, password = self.login
        req = urllib.request.Request(
            self.url + "api/login",
            data=json.dumps({"user": user, "password": password}).encode(),
            headers={"Content-Type": "application/json"},
            method="POST",
        )
        with self._opener.open(req, timeout=10) as r:
            self.csrf = json.loads(r.read())["csrf"]

    def start(self, timeout_s: float = 30.0) -> Service:
        cmd = [
            sys.executable,
            "-m",
            "bridge.cli.main",
            "serve",
            "--listen",
            f"tcp/127.0.0.1:{self.zenoh_port}",
            "--http",
            f"127.0.0.1:{self.http_port}",
            "--data-dir",
            str(self.data_dir),
            "--can-channel",
            f"web-browser-{os.getpid()}-{self.http_port}",
            *self.extra,
        ]
        self.log = open(self.data_dir / "serve.log", "ab")
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                pytest.fail(f"hitch serve exited with {self.proc.returncode}: {self.log_text()[-2000:]}")
            try:
                st = self.state()
                if st["ecu"]["online"]:
                    return self
            except (OSError, ValueError, KeyError):
                pass
            time.sleep(0.2)
        self.kill()
        pytest.fail(f"hitch serve did not come up within {timeout_s} s: {self.log_text()[-2000:]}")

    def log_text(self) -> str:
        return (self.data_dir / "serve.log").read_text(errors="replace")

    def api(self, name: str, payload: dict | None = None) -> tuple[int, dict]:
        self._log_in()
        headers = {"Content-Type": "application/json"}
        if self.csrf is not None:
            headers["X-CSRF-Token"] = self.csrf
        req = urllib.request.Request(
            self.url + f"api/{name}", data=json.dumps(payload or {}).encode(), headers=headers, method="POST"
        )
        try:
            with self._opener.open(req, timeout=10) as r:
                return r.status, json.loads(r.read())
        except urllib.error.HTTPError as exc:
            return exc.code, json.loads(exc.read())

    def state(self) -> dict:
        self._log_in()
        with self._opener.open(self.url + "api/state", timeout=2) as r:
            return json.loads(r.read())

    def kill(self, sig: int = signal.SIGKILL) -> None:
        if self.proc is not None and self.proc.poll() is None:
            os.killpg(self.proc.pid, sig)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(5)
        if getattr(self, "log", None) is not None:
            self.log.close()
            self.log = None
        self.csrf = None  # a new service process knows no session


@contextlib.contextmanager
def running_service(data_dir: Path, *args: str) -> Iterator[Service]:
    """``hitch serve`` in its own process on ``data_dir`` (``args``: more options) until the block ends: then a
    SIGTERM (its clean stop), and a kill if that did not end it."""
    svc = Service(data_dir, *args).start()
    try:
        yield svc
    finally:
        svc.kill(signal.SIGTERM)
        svc.kill()


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    with running_service(tmp_path_factory.mktemp("hitch-serve")) as svc:
        yield svc


@contextlib.contextmanager
def chromium_context(chromium: str, profile_dir: Path) -> Iterator[Any]:
    """A headless chromium (``chromium``: its executable) with a persistent profile in ``profile_dir``, the cab
    display's 1024×600 viewport and touch; closed on exit."""
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.fail(
            "the playwright package is missing: pip install 'playwright>=1.45' (test extra); "
            "its browser download is not needed, the test uses Debian's chromium"
        )
    pw = sync_playwright().start()
    ctx = None
    try:
        ctx = pw.chromium.launch_persistent_context(
            str(profile_dir),
            executable_path=chromium,
            headless=True,
            args=FLAGS,
            viewport={"width": 1024, "height": 600},
            has_touch=True,
        )  # the cab display
        yield ctx
    finally:
        if ctx is not None:
            ctx.close()
        pw.stop()


def open_page(ctx: Any, url: str, *, first: bool = False) -> Any:
    """A page of ``ctx`` at ``url`` (``first``: the context's first page) whose script errors and console errors
    collect in its ``errors`` list."""
    pg = ctx.pages[0] if first and ctx.pages else ctx.new_page()
    pg.set_default_timeout(10_000)
    errors: list[str] = []
    pg.on("pageerror", lambda e: errors.append(str(e)))
    pg.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    pg.goto(url)
    pg.errors = errors
    return pg


@pytest.fixture(scope="module")
def page(chromium, service, tmp_path_factory):
    with chromium_context(chromium, tmp_path_factory.mktemp("chromium-profile")) as ctx:
        yield open_page(ctx, service.url, first=True)


# ---------------------------------------------------------------------------------------------- helpers
def within_steady_state_target(pose: dict, goal: dict, display_round_m: float = 0.0) -> bool:
    """The closed loop's steady state: |(Δx, Δz)| ≤ 2 mm and |Δroll|, |Δpitch| ≤ 2 mrad ("quantisation-
    limited"); ``display_round_m``: half the last digit of a readout (0.05 mm / 0.05 mrad) when
    ``pose`` comes from the page's text."""
    import math

    pos = math.hypot(pose["x"] - goal["x"], pose["z"] - goal["z"])
    ang = max(abs(pose["roll"] - goal["roll"]), abs(pose["pitch"] - goal["pitch"]))
    return (
        pos <= STEADY_STATE_TARGET["x"] + math.sqrt(2) * display_round_m
        and ang <= STEADY_STATE_TARGET["roll"] + display_round_m
    )


def _num(text: str) -> float:
    m = re.search(r"-?\d+(\.\d+)?", text.replace("−", "-"))
    assert m, f"no number in {text!r}"
    return float(m.group())


def _lateral(text: str) -> float:
    """The x readout ("left 12.5 mm", "right 3.0 mm", "centre 0.0 mm") in m: +x is the driver's left."""
    m = re.fullmatch(r"(left|right|centre) (\d+(?:\.\d+)?) mm", text.strip())
    assert m, f"x readout {text!r} is not 'left/right n mm'"
    return (-1.0 if m.group(1) == "right" else 1.0) * float(m.group(2)) / 1000


def shown_pose(pg) -> dict:
    """The pose the page shows, in SI (the readouts are mm and mrad; x as "left/right n mm")."""
    out = {k: _num(pg.text_content(f"#r-{k}")) / 1000 for k in ("z", "roll", "pitch")}
    out["x"] = _lateral(pg.text_content("#r-x"))
    return out


def wait_for(cond, timeout_s: float, what: str, period_s: float = 0.05):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        v = cond()
        if v:
            return v
        time.sleep(period_s)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def _ended(service, motion_id: int) -> bool:
    """Motion ``motion_id`` (or a later one) ended: "not moving" alone is also read from a state the service
    published before the motion began (its reply comes first), before the motion has run at all."""
    s = service.state()
    return (s.get("motion_id") or 0) >= motion_id and not s["moving"]


def _at(state: dict, z: float) -> bool:
    """At rest with the held reference at ``z`` [m] (the goto's goal; the measured pose is off by up to a count)."""
    ref = ((state.get("reference") or {}).get("pose") or {}).get("z")
    return not state["moving"] and ref is not None and abs(ref - z) < 1e-4


def at_rest(service, pg):
    service.api("stop")
    wait_for(lambda: not service.state()["moving"], 10, "the hitch to come to rest")
    time.sleep(STOP_GRACE_S + 0.02)  # a motion request just after a stop may have been sent before it: refused
    if service.state()["mode"] != "auto":
        assert service.api("mode", {"mode": "auto"})[0] == 200
    wait_js(pg, "!document.getElementById('motion').textContent.startsWith('Moving')")


def record_log(pg) -> None:
    """Keep every line the terminal's one-line log shows in ``window.__hitchLog`` (an automatic event can
    replace a reply within milliseconds, before a poll of the footer sees it: the fresh-data event of a
    restarted ECU overwrote the acknowledgement's reply in one CI run)."""
    pg.evaluate(
        """() => { const f = document.getElementById('log'); window.__hitchLog = [f.textContent];
        new MutationObserver((records) => { for (const r of records) {  // each text set, even two in one task
          if (r.type === 'characterData') window.__hitchLog.push(r.target.textContent);
          for (const n of r.addedNodes) window.__hitchLog.push(n.textContent); } })
          .observe(f, { childList: true, characterData: true, subtree: true }); }"""
    )


def wait_log(pg, pattern: str, timeout: float = 10_000):
    """Wait until a line the log showed since :func:`record_log` matches the JavaScript regex ``pattern``."""
    return wait_js(pg, f"(window.__hitchLog || []).some((t) => /{pattern}/.test(t))", timeout)


def wait_js(pg, expression: str, timeout: float = 10_000):
    """Poll a JavaScript expression until truthy (evaluated through DevTools, so the page keeps its
    Content-Security-Policy: Playwright's own wait_for_function needs 'unsafe-eval'). A time-out says
    what the terminal's log showed last (what the operator read instead)."""
    try:
        return wait_for(lambda: pg.evaluate(expression), timeout / 1000, expression)
    except AssertionError as exc:
        shown = pg.evaluate("(document.getElementById('log') || {}).textContent || ''")
        raise AssertionError(f"{exc}; the terminal's log ends: {shown[-600:]!r}") from None


def set_jog_speed(pg, percent: int):
    pg.evaluate(
        "(p) => { const s = document.getElementById('jog-speed'); s.value = p; s.dispatchEvent(new Event('input')); }",
        percent,
    )
    assert pg.text_content("#jog-speed-out") == f"{percent} %"


def tab(pg, name: str):
    pg.click(f".tabs button[data-tab='{name}']")


def goto_target(service, pg, goal: dict, speed: int = 100):
    tab(pg, "goto")
    for k in ("x", "z", "roll", "pitch"):
        pg.fill(f"#goto-form input[name={k}]", "" if k not in goal else f"{goal[k] * 1000:.1f}")
    pg.fill("#goto-form input[name=speed]", str(speed))
    pg.evaluate("document.getElementById('goto-result').textContent = ''")  # the last goto's answer is not this one's
    pg.click("#goto-go")
    # a goal under 1 mm (a rest pose read back) is asked about as metres typed into mm: it is meant as typed
    wait_js(
        pg,
        "document.getElementById('goto-result').textContent.length > 0 || "
        "!document.getElementById('confirm').classList.contains('hidden')",
    )
    if not pg.is_hidden("#confirm"):
        assert pg.text_content("#confirm-title") == "Millimetres?"
        pg.click("#confirm-ok")
        wait_js(pg, "document.getElementById('goto-result').textContent.length > 0")
    text = pg.text_content("#goto-result")
    # accepted: "moving: motion #N, …", or its outcome when the motion ended before the reply was shown (a
    # short move on a loaded machine; a CI-style run read "motion #8 finished" for a 10 mm goto)
    assert text.startswith("moving: motion #") or re.fullmatch(r"motion #\d+ finished", text), text
    return text


# ---------------------------------------------------------------------------------------------- scenarios
def test_page_loads_and_shows_the_published_state(service, page, shots):
    wait_js(page, "document.getElementById('conn').textContent.startsWith('Service: connected')")
    wait_js(page, "document.getElementById('ecu').textContent.includes('online')")
    wait_js(page, "Number(document.body.dataset.fps) > 0")
    time.sleep(1.2)  # one full rate-meter window
    fps = float(page.evaluate("document.body.dataset.fps"))
    assert fps >= 20, f"gauges refresh at {fps} Hz (required: at least 20 Hz)"
    st, shown = service.state(), shown_pose(page)
    for k in shown:  # at rest: the page shows the service's pose
        assert shown[k] == pytest.approx(st["pose"][k], abs=1e-4), k
    assert page.is_visible("#limited") is False
    # everything fits the 1024×600 cab display: no scrolling
    assert page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]") == [1024, 600]
    assert page.text_content("#modes button.active") == "Auto"
    strokes = page.text_content("#act-top")
    assert "655.0 mm" in strokes and "905.0 mm" in strokes  # the top link's stroke limits (thesis table 3-1)
    page.screenshot(path=str(shots / "01-main.png"))
    assert page.errors == []


def test_save_a_preset_from_the_page(service, page, shots):
    at_rest(service, page)
    tab(page, "presets")
    page.fill("#preset-form input[name=name]", "start")
    page.click("#preset-save")
    page.wait_for_selector("#preset-list li[data-name='start']")
    status, listing = service.api("presets/list")
    (p,) = [p for p in listing["presets"] if p["name"] == "start"]
    st = service.state()
    for k in ("x", "z", "roll", "pitch"):  # saved at the current pose
        assert p["pose"][k] == pytest.approx(st["pose"][k], abs=3e-3), k
    # the list says x as the gauges do, left/right of centre, not a signed number (a terminal trial)
    sub = page.text_content("#preset-list li[data-name='start']")
    assert re.search(r"x (centre|left \d+|right \d+) ·", sub), sub
    page.screenshot(path=str(shots / "02-presets.png"))


def test_goto_moves_the_gauges_and_they_settle_at_the_target(service, page, shots):
    at_rest(service, page)
    goal = {"x": -0.03, "z": 0.20, "roll": 0.03, "pitch": 0.02}
    start = shown_pose(page)
    goto_target(service, page, goal)
    wait_js(page, "document.getElementById('motion').textContent.startsWith('Moving')")
    # sampled while the page says Moving, until 5 distinct z readings (a loaded host slows every
    # browser call: a fixed 0.8 s window saw only 3 samples in CI, all different)
    seen, activity, moving = [], set(), True
    deadline = time.monotonic() + 10.0
    while moving and len(set(seen)) < 5 and time.monotonic() < deadline:
        z_text, ecu, motion = page.evaluate(
            "['r-z', 'ecu', 'motion'].map((id) => id === 'ecu' ? "
            "document.getElementById(id).dataset.activity : document.getElementById(id).textContent)"
        )
        seen.append(_num(z_text) / 1000)
        activity.add(ecu)
        moving = motion.startswith("Moving")
        time.sleep(0.05)
    assert "driving" in activity, activity  # valve activity: the reference moves, the ECU drives
    page.screenshot(path=str(shots / "03-goto-moving.png"))
    assert len(set(seen)) >= 5, f"the z gauge did not move: {seen}"  # live, not a frozen snapshot
    assert abs(seen[-1] - goal["z"]) < abs(start["z"] - goal["z"])

    last: dict = {}

    def settled():
        last.update(shown_pose(page))
        return within_steady_state_target(last, goal, display_round_m=0.5e-4)

    try:
        wait_for(settled, 15, f"the gauges to settle within 2 mm / 2 mrad of {goal}")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; last shown {last}") from None
    wait_js(page, "document.getElementById('motion').textContent === 'Idle'")
    wait_js(page, "/^motion #\\d+ finished$/.test(document.getElementById('goto-result').textContent)")
    wait_js(page, "document.getElementById('ecu').dataset.activity === 'holding'")  # settled: valves at rest

    # the pose the page shows is the service's measured one (to the readouts' last digit), which meets the
    # target unrounded. The page draws a state some tens of ms after the service published it, and at rest
    # the measurement may still step by a count: compare a shown pose with a state read on both sides of it
    # that did not change in between, and read again (bounded) until they agree.
    def shown_equals_measured():
        before = service.state()["pose"]
        shown = shown_pose(page)
        after = service.state()["pose"]
        if before != after:
            return None
        return after if all(abs(shown[k] - after[k]) <= 0.5e-4 + 1e-9 for k in goal) else None

    measured = wait_for(shown_equals_measured, 5, "the page to show the service's measured pose")
    assert within_steady_state_target(measured, goal), (measured, goal)
    page.screenshot(path=str(shots / "04-goto-settled.png"))
    # the target markers sit where the gauges settled
    assert page.evaluate("getComputedStyle(document.querySelector('#g-z .target')).display") != "none"
    ref = service.state()["reference"]["pose"]
    assert all(ref[k] == pytest.approx(goal[k], abs=1e-6) for k in goal)  # the service's target is exact
    _needles_turn_as_the_pictures(service, page)


def _needles_turn_as_the_pictures(service, page) -> None:
    """The roll and pitch needles and the jog buttons' arrows turn the way the hitch pictures beside them do (an
    operator's trial: with roll and pitch +0.05 rad the rear view's bar rose to the right and the side view's mast
    leaned to the front, both counter-clockwise, while both needles turned clockwise and the arrows said ↷ ⤻; ⤻ is
    an anticlockwise arrow by its Unicode name, a review: the arrows are ↺ and ↻).
    The pictures: the rear view draws +x (L) on the left, the side view the front on the left (``buildView``)."""
    p = _view(service)["measured"]["points"]
    # counter-clockwise on the screen: the bar from L (left) to R rises; the mast from T to U leans to the front (−y)
    roll_ccw = p["R"][2] > p["L"][2]
    pitch_ccw = p["U"][1] < p["T"][1]

    def needle_deg(dof: str) -> float:  # rotate(deg cx cy): SVG angles are clockwise on the screen
        t = page.get_attribute(f"#g-{dof} .needle", "transform") or ""
        return float(t.split("(")[1].split()[0])

    assert (needle_deg("roll") < 0) == roll_ccw and abs(needle_deg("roll")) > 1.0, (needle_deg("roll"), p)
    assert (needle_deg("pitch") < 0) == pitch_ccw and abs(needle_deg("pitch")) > 1.0, (needle_deg("pitch"), p)
    for sign, ccw in (("1", True), ("-1", False)):  # ↺ anticlockwise, ↻ clockwise (U+21BA, U+21BB)
        arrows = {
            d: page.text_content(f"button.jog[data-dof={d}][data-sign='{sign}']") or "" for d in ("roll", "pitch")
        }
        assert ("↺" in arrows["roll"]) == (roll_ccw == ccw) and ("↻" in arrows["roll"]) == (roll_ccw != ccw), arrows
        assert ("↺" in arrows["pitch"]) == (pitch_ccw == ccw) and ("↻" in arrows["pitch"]) == (pitch_ccw != ccw), arrows


def _view(service) -> dict:
    with urllib.request.urlopen(service.url + "api/view", timeout=5) as r:
        return json.loads(r.read())


def test_the_hitch_picture_shows_the_model_live_in_operator_units(service, page, shots):
    """Rear and side views from the model's points, lift in %, heights above ground, the target ghosted
    during a motion; angles in mrad or degrees (a setting kept by the browser)."""
    from planner.profiles.hitch import load_profile

    at_rest(service, page)
    page.wait_for_selector("#v-rear circle[data-point=L]", state="attached", timeout=15_000)
    pivot_height = load_profile("thesis-t132").geometry.pivot_height
    # the tool point's height above ground: the service's own z + the pivots' height above ground (profile)
    st, view = service.state(), _view(service)
    assert view["measured"]["above_ground"]["T"] == pytest.approx(st["pose"]["z"] + pivot_height, abs=2e-4)
    ground = page.text_content("#r-ground")
    shown = [float(v) / 1000 for v in re.findall(r"\b[LR] (\d+)", ground)]
    assert shown == [pytest.approx(view["measured"]["above_ground"][n], abs=1.5e-3) for n in ("L", "R")], ground
    # rear view: the left lower hitch point (x > 0, the driver's left) is drawn on the left
    lx, rx = (float(page.get_attribute(f"#v-rear circle[data-point={n}]", "cx")) for n in ("L", "R"))
    assert view["measured"]["points"]["L"][0] > 0 > view["measured"]["points"]["R"][0] and lx < rx
    # lift in % of its stroke (config strokes, the state's lift angle)
    lo, hi = service.api("config")[1]["limits"]["strokes"]["lift"]
    lift_percent = 100 * (st["actuators"]["lift"] - lo) / (hi - lo)
    assert _num(page.text_content("#act-lift .val")) == pytest.approx(lift_percent, abs=0.3)
    assert page.evaluate("window.hitchTerminal.inWords('refused: stroke:top:max active')").endswith(
        "— top link at its stroke end (longest)"
    )
    # the service's unit hints are for SI callers (this page's fields take mm and the angle unit): not shown
    hinted = "goal.roll = 3 rad is out; did you mean degrees? 3 deg = 0.0523599 rad; or mrad? 3 mrad = 0.003 rad"
    assert "did you mean" not in page.evaluate(f"window.hitchTerminal.displayUnits({hinted!r})")
    # during a motion the target (the reference's points) is drawn dashed over the measured hitch
    z0 = st["pose"]["z"]
    assert service.api("goto", {"goal": {"z": -0.1 if z0 > 0.05 else 0.2, "x": 0.03}, "speed_scale": 0.3})[0] == 200
    wait_js(page, "getComputedStyle(document.querySelector('#v-rear .ghost')).display !== 'none'")
    time.sleep(0.6)
    page.screenshot(path=str(shots / "19-hitch-moving.png"))
    wait_for(lambda: not service.state()["moving"], 20, "the motion to end")
    wait_js(page, "getComputedStyle(document.querySelector('#v-rear .ghost')).display === 'none'")
    # angles in degrees: a setting of this browser, kept over a reload
    assert page.text_content("#angle-unit") == "Angles: mrad"
    page.click("#angle-unit")
    assert page.text_content("#angle-unit") == "Angles: deg"
    page.reload()
    wait_js(page, "document.getElementById('conn').textContent.startsWith('Service: connected')")
    assert page.text_content("#angle-unit") == "Angles: deg"
    wait_js(page, "document.getElementById('r-roll').textContent.endsWith(' deg')")
    import math

    roll = service.state()["pose"]["roll"]
    assert _num(page.text_content("#r-roll")) == pytest.approx(math.degrees(roll), abs=0.02)
    tab(page, "goto")
    assert page.text_content("#goto-form label:has(input[name=roll]) .unit").startswith("deg")
    # the levelling line in the chosen unit too (a field operator's report: it said "roll 0 mrad" in degrees)
    assert page.text_content("#level-status") == "off · roll 0.00 deg to gravity when on"
    page.screenshot(path=str(shots / "20-angles-in-degrees.png"))
    page.click("#angle-unit")
    assert page.text_content("#level-status") == "off · roll 0.0 mrad to gravity when on"
    assert page.text_content("#angle-unit") == "Angles: mrad"
    wait_js(page, "document.getElementById('r-roll').textContent.endsWith(' mrad')")
    assert page.errors == []


def test_metres_typed_into_a_mm_field_are_asked_about_before_the_goto(service, page):
    """A field operator's report: z = 0.25 typed into the mm field moved the hitch down to 0.25 mm."""
    at_rest(service, page)
    tab(page, "goto")
    for k in ("x", "roll", "pitch"):
        page.fill(f"#goto-form input[name={k}]", "")
    page.fill("#goto-form input[name=z]", "0.25")
    page.click("#goto-go")
    page.wait_for_selector("#confirm:not(.hidden)", timeout=5_000)
    assert "z = 0.25 mm (did you mean 250 mm?)" in page.text_content("#confirm-text")
    page.click("#confirm-cancel")
    wait_js(page, "document.getElementById('goto-result').textContent.startsWith('not sent')")
    # an operator's trial: 0.0001 (0.1 mm meant) was asked as "z = 0.000 mm (did you mean 0 mm?)", and the last
    # "not sent" stood under the dialog
    page.fill("#goto-form input[name=z]", "0.0001")
    page.click("#goto-go")
    page.wait_for_selector("#confirm:not(.hidden)", timeout=5_000)
    assert "z = 0.0001 mm (did you mean 0.1 mm?)" in page.text_content("#confirm-text")
    assert page.text_content("#goto-result") == ""
    page.click("#confirm-cancel")
    wait_js(page, "document.getElementById('goto-result').textContent.startsWith('not sent')")
    time.sleep(0.3)
    assert not service.state()["moving"]
    page.fill("#goto-form input[name=z]", "100.5")  # a length in mm: no question
    page.click("#goto-go")
    wait_js(page, "document.getElementById('goto-result').textContent.length > 0")
    assert page.is_hidden("#confirm")
    answer = page.text_content("#goto-result")
    started = re.search(r"motion #(\d+)", answer)
    assert started, answer
    wait_for(lambda: _ended(service, int(started.group(1))), 20, "the motion to end")


def test_preset_go_returns_to_the_saved_pose(service, page):
    at_rest(service, page)
    tab(page, "presets")
    _, listing = service.api("presets/list")
    (p,) = [p for p in listing["presets"] if p["name"] == "start"]
    page.click("#preset-list li[data-name='start'] button.primary")
    wait_for(lambda: service.state()["moving"], 5, "the preset motion to start")
    wait_for(lambda: not service.state()["moving"], 15, "the preset motion to end")
    ref = service.state()["reference"]["pose"]
    for k in ("x", "z", "roll", "pitch"):
        assert ref[k] == pytest.approx(p["pose"][k], abs=1e-6), k


def test_jog_moves_only_while_the_button_is_held(service, page, shots):
    at_rest(service, page)
    tab(page, "jog")
    set_jog_speed(page, 50)
    z0 = shown_pose(page)["z"]
    box = page.locator("button.jog[data-dof='z'][data-sign='1']").bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    try:
        wait_for(lambda: service.state()["motion"] == "jog", 3, "the jog to start")
        time.sleep(1.0)
        assert "held" in page.get_attribute("button.jog[data-dof='z'][data-sign='1']", "class")
        page.screenshot(path=str(shots / "05-jog-held.png"))
        z_held = shown_pose(page)["z"]
        assert z_held > z0 + 0.01, (z0, z_held)  # moved up while held
    finally:
        page.mouse.up()
    t_release = time.monotonic()
    wait_for(lambda: not service.state()["moving"], 2.0, "the jog to stop after release (TTL + braking)")
    assert time.monotonic() - t_release < 2.0
    ref = service.state()["reference"]["pose"]["z"]
    # the cylinders catch up with the held reference: a second as before, and on a loaded machine until the
    # measured z is within the closed loop's steady-state target of it (CI: waiting for the page's "holding"
    # alone read the gauge 3.7 mm short, still rising)
    time.sleep(1.0)
    wait_for(
        lambda: abs(service.state()["pose"]["z"] - ref) <= STEADY_STATE_TARGET["z"], 10, "z to settle at the reference"
    )
    wait_js(page, "document.getElementById('motion').textContent === 'Idle'")
    z1 = shown_pose(page)["z"]
    time.sleep(0.5)
    assert service.state()["reference"]["pose"]["z"] == ref  # … and nothing is commanded any more
    assert shown_pose(page)["z"] == pytest.approx(z1, abs=1e-3)  # the gauge stays where it stopped


def test_keyboard_jog_is_the_same_dead_man(service, page):
    at_rest(service, page)
    z0 = shown_pose(page)["z"]
    page.keyboard.down("ArrowDown")
    try:
        wait_for(lambda: service.state()["motion"] == "jog", 3, "the keyboard jog to start")
        time.sleep(0.8)
    finally:
        page.keyboard.up("ArrowDown")
    wait_for(lambda: not service.state()["moving"], 2.0, "the keyboard jog to stop after key-up")
    assert shown_pose(page)["z"] < z0 - 0.005


def test_keys_typed_in_a_script_box_or_a_list_never_jog_or_stop(service, page):
    """An operator's trial: holding W in the maneuver script box jogged the hitch (pitch), a Space typed there
    sent STOP and was swallowed, and ArrowUp on the work mode list raised the hitch at 23 mm/s: only text inputs
    counted as typing. Text areas and drop-down lists do now; Escape still stops from anywhere."""
    at_rest(service, page)
    tab(page, "maneuvers")
    page.evaluate("document.getElementById('maneuver-editor').open = true")  # "New maneuver script"
    box = page.locator("textarea[name='script']")
    box.click()
    page.keyboard.down("KeyW")
    time.sleep(0.6)
    page.keyboard.up("KeyW")
    page.keyboard.type("name: a b")
    assert service.state()["motion"] is None and not service.state()["moving"], service.state()["motion"]
    assert box.input_value().endswith("name: a b"), box.input_value()
    box.fill("")
    page.evaluate("document.getElementById('maneuver-editor').open = false")
    tab(page, "work")
    page.focus("#work-mode")
    page.keyboard.down("ArrowUp")
    time.sleep(0.6)
    page.keyboard.up("ArrowUp")
    assert service.state()["motion"] is None and not service.state()["moving"], service.state()["motion"]


def test_stop_mid_motion(service, page, shots):
    at_rest(service, page)
    z0 = service.state()["pose"]["z"]
    goal = {"z": -0.15 if z0 > 0.05 else 0.25}
    goto_target(service, page, goal, speed=30)
    wait_for(lambda: service.state()["moving"], 3, "the motion to start")
    time.sleep(0.6)
    t_stop = time.monotonic()
    page.click("#stop")
    wait_for(lambda: not service.state()["moving"], 3, "STOP to bring the hitch to rest")
    assert time.monotonic() - t_stop < 3
    wait_js(page, "document.getElementById('log').textContent.includes('stop')")
    time.sleep(0.5)
    st = service.state()
    assert abs(st["pose"]["z"] - goal["z"]) > 0.05  # stopped well short of the goal
    page.screenshot(path=str(shots / "06-stopped.png"))


def test_forcing_a_limit_shows_control_limited_with_its_name(service, page, shots):
    at_rest(service, page)
    tab(page, "jog")
    set_jog_speed(page, 100)
    sel = "button.jog[data-dof='x'][data-sign='1']"
    box = page.locator(sel).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    try:
        page.wait_for_selector("#limited:not(.hidden)", timeout=15_000)
        text = page.text_content("#limited")
        assert text.startswith("Control limited") and "workspace:x:max" in text, text
        assert "left limit reached" in text, text  # in words: +x is the driver's left
        # 100 % is the service's jog speed limit (config limits.jog_velocity), never above it
        assert "velocity:" not in text, text
        # the picture lights up the limited member (the implement at its lateral face)
        wait_js(page, "document.querySelector('#v-rear line[data-member=implement]').classList.contains('hl')")
        time.sleep(0.5)
        page.screenshot(path=str(shots / "07-control-limited.png"))
    finally:
        page.mouse.up()
    x_max = service.api("config")[1]["limits"]["workspace"]["x"][1]
    assert service.state()["reference"]["pose"]["x"] <= x_max + 1e-9  # never past the face
    page.wait_for_selector("#limited.hidden", state="attached", timeout=5_000)


def test_mode_selector_confirms_manual_and_attach_and_stop_works_over_the_dialog(service, page, shots):
    at_rest(service, page)
    z0 = service.state()["pose"]["z"]
    assert service.api("goto", {"goal": {"z": -0.15 if z0 > 0.05 else 0.25}, "speed_scale": 0.3})[0] == 200
    # moving: its reply comes before a state that says so (read once, a state published before it said "at rest")
    wait_for(lambda: service.state()["moving"], 5, "the goto to start")
    page.click("#modes button[data-mode='manual']")
    page.wait_for_selector("#confirm:not(.hidden)")
    assert "Manual" in page.text_content("#confirm-title")
    page.screenshot(path=str(shots / "08-confirm-manual.png"))
    assert service.state()["moving"]
    page.click("#stop")  # STOP stays on top of the dialog
    wait_for(lambda: not service.state()["moving"], 3, "STOP pressed over the dialog to stop the motion")
    page.click("#confirm-cancel")
    time.sleep(0.3)
    assert service.state()["mode"] == "auto"  # cancelled: nothing changed
    page.click("#modes button[data-mode='attach']")
    page.click("#confirm-ok")
    wait_js(page, "document.querySelector('#modes button.active').dataset.mode === 'attach'")
    assert service.state()["mode"] == "attach"
    tab(page, "help")
    assert page.text_content("#help-title") == "Implement attach mode"
    assert "slow jog only" in page.text_content("#help-text")
    page.screenshot(path=str(shots / "09-help-attach.png"))
    status, reply = service.api("goto", {"goal": {"z": 0.1}})
    assert status == 409 and reply["error"] == "mode"  # the service's rule, not the page's
    page.click("#modes button[data-mode='auto']")  # no confirmation back to automatic
    wait_js(page, "document.querySelector('#modes button.active').dataset.mode === 'auto'")
    assert page.text_content("#help-title") == "Automatic mode"


def test_touch_hold_jogs_and_lifting_the_finger_stops(service, page):
    at_rest(service, page)
    tab(page, "jog")
    set_jog_speed(page, 50)
    z0 = service.state()["pose"]["z"]
    sign = "-1" if z0 > 0.0 else "1"
    box = page.locator(f"button.jog[data-dof='z'][data-sign='{sign}']").bounding_box()
    point = {"x": box["x"] + box["width"] / 2, "y": box["y"] + box["height"] / 2}
    cdp = page.context.new_cdp_session(page)
    cdp.send("Input.dispatchTouchEvent", {"type": "touchStart", "touchPoints": [point]})
    try:
        wait_for(lambda: service.state()["motion"] == "jog", 3, "the touch jog to start")
        time.sleep(0.8)
    finally:
        cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})
    wait_for(lambda: not service.state()["moving"], 2.0, "the touch jog to stop when the finger lifts")
    assert (service.state()["pose"]["z"] - z0) * float(sign) > 0.005
    cdp.detach()


def test_maneuver_validate_run_and_live_progress(service, page, shots):
    at_rest(service, page)
    z = service.state()["pose"]["z"]
    script = (
        f"name: headland\ndescription: lift, wait, lower\nsteps:\n  - goto: {{z: {min(z + 0.12, 0.28):.3f}}}\n"
        f"  - wait: 1.0\n  - goto: {{z: {z:.3f}}}\n"
    )
    assert service.api("maneuvers/save", {"name": "headland", "script": script})[0] == 200
    tab(page, "maneuvers")
    page.wait_for_selector("#maneuver-list li[data-name='headland']")
    page.evaluate("document.getElementById('maneuver-editor').open = true")  # "New maneuver script"
    page.fill("#maneuver-form input[name=name]", "headland")
    page.fill("#maneuver-form textarea", script)
    page.click("#maneuver-validate")
    wait_js(page, "document.getElementById('maneuver-result').textContent.startsWith('valid')")
    page.click("#maneuver-list li[data-name='headland'] button.primary")
    page.wait_for_selector("#maneuver-progress:not(.hidden)")
    wait_js(page, "document.querySelector('#maneuver-progress .text').textContent.includes('step 2 of 3')")
    page.screenshot(path=str(shots / "10-maneuver-progress.png"))
    wait_js(page, "document.getElementById('maneuver-result').textContent.includes('finished')", timeout=20_000)
    page.wait_for_selector("#maneuver-progress", state="hidden", timeout=3_000)


def test_saving_a_maneuver_over_one_saved_already_asks_and_replaces_only_when_told(service, page):
    """maneuvers/save refuses a name saved already unless sent with replace (a teach-in recording had replaced a
    6-step maneuver without a word): the page asks, Cancel keeps the saved one, Replace replaces it."""
    one, two = "steps:\n  - wait: 1.0\n", "steps:\n  - wait: 1.0\n  - wait: 2.0\n"
    assert service.api("maneuvers/save", {"name": "twice", "script": one})[0] == 200
    tab(page, "maneuvers")
    page.evaluate("document.getElementById('maneuver-editor').open = true")  # whatever an earlier test left
    page.fill("#maneuver-form input[name=name]", "twice")
    page.fill("#maneuver-form textarea", two)
    page.click("#maneuver-save")
    page.wait_for_selector("#confirm:not(.hidden)")
    assert "Replace maneuver twice?" in page.text_content("#confirm-title")
    page.click("#confirm-cancel")
    wait_js(page, "document.getElementById('maneuver-result').textContent.includes('kept as it was')")
    listed = {m["name"]: m for m in service.api("maneuvers/list")[1]["maneuvers"]}
    assert listed["twice"]["steps"] == 1
    page.click("#maneuver-save")
    page.wait_for_selector("#confirm:not(.hidden)")
    page.click("#confirm-ok")
    wait_js(page, "document.getElementById('maneuver-result').textContent.includes('twice saved (2 steps)')")
    listed = {m["name"]: m for m in service.api("maneuvers/list")[1]["maneuvers"]}
    assert listed["twice"]["steps"] == 2
    page.evaluate("document.getElementById('maneuver-editor').open = false")


def test_killing_the_service_is_shown_and_the_page_reconnects(service, page, shots):
    record_log(page)  # the page stays loaded over the reconnect: its footer's lines are kept from here
    service.kill(signal.SIGKILL)
    page.wait_for_selector("#banner:not(.hidden)", timeout=5_000)
    assert "Service not reachable" in page.text_content("#banner")
    assert page.text_content("#conn") == "Service: disconnected"
    page.screenshot(path=str(shots / "11-service-down.png"))
    tab(page, "goto")
    page.fill("#goto-form input[name=z]", "100")
    page.click("#goto-go")  # refused while disconnected: said under the form
    try:
        wait_js(page, "document.getElementById('goto-result').textContent.includes('not connected to the service')")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; goto-result: {page.text_content('#goto-result')!r}") from None
    service.start()  # same ports and data: the page comes back by itself
    wait_js(page, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
    assert page.is_hidden("#banner")
    # an operator's trial: "goto: not connected to the service" stayed under the form and in the footer after the
    # page had reconnected
    wait_js(page, "document.getElementById('goto-result').textContent === ''")
    # the footer says so, and no "not connected" after it (its lines as recorded: read once, the footer may
    # already show what the restarted service posted next, its ECU coming online or a fault clearing)
    wait_log(page, "connected to the service again$")
    since = page.evaluate(
        "(() => { const l = window.__hitchLog, i = l.findIndex((t) => /connected to the service again$/.test(t));"
        " return l.slice(i); })()"
    )
    assert not [t for t in since if "not connected" in t], since
    tab(page, "presets")
    page.wait_for_selector("#preset-list li[data-name='start']")  # acknowledged preset survived kill -9


def test_stability_margins_take_the_services_caution_colours(page, shots, tmp_path_factory):
    # a 1500 kg power harrow (tractor profile, assumed data) unloads the front axle below the caution share
    heavy = Service(tmp_path_factory.mktemp("hitch-serve-harrow"), "--implement", "cat2-power-harrow-1500").start()
    try:
        page.goto(heavy.url)
        wait_js(page, "document.getElementById('conn').textContent.startsWith('Service: connected')")
        st = heavy.state()["stability"]
        levels = {v["measure"]: v["level"] for v in st["violations"]}
        assert levels.get("front_axle_load") == "caution", st
        wait_js(page, "document.getElementById('m-front_axle_load').classList.contains('caution')")
        for m in ("ssm", "lsm", "esm"):  # the measures the service does not flag stay "ok"
            expected = {"caution": "caution", "hard": "danger"}.get(levels.get(m), "ok")
            assert expected in page.get_attribute(f"#m-{m}", "class"), m
        # shown as a share of the empty tractor's weight: share of the total × (tractor + ballast + harrow) / tractor
        from planner.limits.tractor import load_tractor_profile
        from planner.profiles.hitch import load_profile

        stab = load_profile("thesis-t132").stability
        tp = load_tractor_profile(stab.tractor_profile)
        factor = (tp.spec.mass + stab.front_ballast + tp.implement("cat2-power-harrow-1500").mass) / tp.spec.mass
        wait_js(page, "document.getElementById('m-front_axle_load').title.includes('of the tractor')")
        shown = _num(page.text_content("#m-front_axle_load .v")) / 100
        assert shown == pytest.approx(heavy.state()["stability"]["front_axle_share"] * factor, abs=0.006)
        note = page.text_content("#m-front_axle_load .n")
        assert note == "of the tractor's weight (minimum 20 %)", note
        assert "minimum 0.10 m" in page.text_content("#m-ssm .n")
        page.screenshot(path=str(shots / "12-stability-caution.png"))
    finally:
        heavy.kill(signal.SIGTERM)
        heavy.kill()


# ---------------------------------------------------------------------------------------------- units, faults, header
def _connected(pg, url: str) -> None:
    if pg.url != url:
        pg.errors.clear()  # what the page logged while it showed another service (now gone) is not this page's
        pg.goto(url)
    wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)


def test_inputs_say_their_unit_and_range_and_refusals_come_in_display_units(service, page):
    _connected(page, service.url)
    at_rest(service, page)
    workspace = service.api("config")[1]["limits"]["workspace"]
    tab(page, "goto")
    for k, unit in (("x", "mm"), ("z", "mm"), ("roll", "mrad"), ("pitch", "mrad")):
        lo, hi = (1000 * v for v in workspace[k])
        shown = page.text_content(f"#range-{k}")
        assert [_num(t) for t in shown.split("…")] == [pytest.approx(lo, abs=0.05), pytest.approx(hi, abs=0.05)], k
        field = f"#goto-form input[name={k}]"
        assert shown in page.get_attribute(field, "placeholder")
        title = page.get_attribute(field, "title")
        assert f" in {unit}," in title and shown in title, title
        assert page.text_content(f"#goto-form label:has(input[name={k}]) .unit").startswith(unit)
    # every input of the page names its unit or range (title or placeholder)
    untitled = page.evaluate(
        "Array.from(document.querySelectorAll('input, textarea')).filter(e => !(e.title || e.placeholder))"
        ".map(e => e.name || e.id)"
    )
    assert untitled == []
    assert "10–100 %" in page.get_attribute("#jog-speed", "title")
    assert "5–100 %" in page.get_attribute("#goto-form input[name=speed]", "title")
    assert "m and rad" in page.get_attribute("#maneuver-form textarea", "title")
    # a goal 100 mm above the workspace: the service refuses in SI, the page shows mm
    z_mm = round(1000 * workspace["z"][1]) + 100
    status, reply = service.api("goto", {"goal": {"z": z_mm / 1000}})
    assert status == 422 and re.search(r"\d m\b", reply["message"]), reply  # the service's own words are SI
    for button in ("#goto-plan", "#goto-go"):
        for k in ("x", "roll", "pitch"):
            page.fill(f"#goto-form input[name={k}]", "")
        page.fill("#goto-form input[name=z]", str(z_mm))
        page.evaluate("document.getElementById('goto-result').textContent = ''")
        page.click(button)
        wait_js(page, "document.getElementById('goto-result').textContent.length > 0")
        text = page.text_content("#goto-result")
        assert f"{z_mm} mm" in text, text
        face = re.search(r"(?:workspace:z:max = |to )(-?\d+(?:\.\d+)?) mm", text)
        assert face and float(face.group(1)) == pytest.approx(1000 * workspace["z"][1], abs=0.05), text
        assert not re.search(r"\d\s*(m|rad)\b", text), f"SI units left in {text!r}"
        assert "err" in page.get_attribute("#goto-result", "class")
    assert not service.state()["moving"]


def test_latched_faults_are_acknowledged_from_the_header(service, page, shots):
    _connected(page, service.url)
    at_rest(service, page)
    status, reply = service.api("sim/fault", {"restart_ecu": True})  # the twin restarts: an event fault latches
    assert status == 200, reply
    page.wait_for_selector("#faults-ack:not(.hidden)", timeout=5_000)
    # a restart first shows the gap it leaves (stale measurement, heartbeat), then the latched restart
    wait_js(page, "document.getElementById('ecu').textContent.includes('ecu_restart')")
    assert "fault" in page.text_content("#ecu") and "ecu_restart" in page.text_content("#ecu")
    page.screenshot(path=str(shots / "13-fault-acknowledge.png"))
    # the button stays where it is when the fault text changes (a cleared fault shortens it): before, it sat
    # after the ECU pill and moved left as the stale/heartbeat faults cleared, and a click aimed at it missed
    xs = page.evaluate(
        """() => { const ecu = document.getElementById('ecu'), b = document.getElementById('faults-ack');
        const keep = ecu.textContent, xs = [];
        for (const t of ['ECU fault: stale_measurement, ecu_heartbeat, ecu_restart · holding', 'ECU fault: x']) {
          ecu.textContent = t; xs.push(b.getBoundingClientRect().x); }
        ecu.textContent = keep; return xs; }"""
    )
    assert xs[0] == xs[1], xs
    record_log(page)
    page.click("#faults-ack")
    # the reply ("faults acknowledged: …") or the service's event that follows it ("… cleared: … (ack)")
    wait_log(page, "faults acknowledged: ecu_restart|fault cleared: ecu_restart \\(ack\\)")
    page.wait_for_selector("#faults-ack", state="hidden", timeout=5_000)
    # the ack cleared the latched restart; the gap's self-clearing faults (stale measurement, heartbeat) may
    # still be held when the click comes early (a loaded CI machine): they clear themselves on fresh data
    assert "ecu_restart" not in service.state()["ecu"]["faults"]
    wait_for(lambda: service.state()["ecu"]["faults"] == [], 10.0, "the restart gap's faults to clear themselves")
    # with nothing latched the service's answer is shown as it is: no error, nothing moves
    page.evaluate("document.getElementById('faults-ack').click()")
    wait_log(page, "none latched")
    assert not service.state()["moving"]


def _fault_names() -> list[str]:
    """Every fault the link can latch (the longest fault text is all of them at once)."""
    from dataclasses import fields

    from bridge.link.state import LinkFaults

    return [f.name for f in fields(LinkFaults) if f.name != "reasons"]


@pytest.mark.parametrize("size", [(1024, 600), (800, 480)])
def test_the_longest_fault_text_never_pushes_stop_off_screen(service, page, shots, size):
    """A terminal fed the service's own state with every fault latched (a WebServer in this process,
    its commands forwarded to the service): STOP stays whole inside the viewport."""
    import threading

    from bridge.web.server import WebServer
    from bridge.web.settings import WebSettings

    base = service.state()
    names = _fault_names()
    reasons = [
        f"{n}: " + "the cylinder ECU reported a condition that needs the operator's attention " * 2 for n in names
    ]
    state = {**base, "ecu": {**base["ecu"], "faults": names, "ack_required": names, "fault_reasons": reasons}}
    web = WebServer(lambda name, body, user, **_: _forward(service, name, body), WebSettings(port=0)).start()
    done = threading.Event()

    def feed() -> None:
        seq = state["seq"]
        while not done.wait(0.05):
            seq += 1
            web.publish_state({**state, "seq": seq})

    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    width, height = size
    try:
        page.set_viewport_size({"width": width, "height": height})
        _connected(page, web.url)
        wait_js(page, f"document.getElementById('ecu').textContent.includes('{names[-1]}')")
        for sel in ("#stop", "#faults-ack", "#modes"):
            box = page.locator(sel).bounding_box()
            assert box is not None, sel
            assert box["x"] >= 0 and box["y"] >= 0, (sel, box)
            assert box["x"] + box["width"] <= width + 0.5 and box["y"] + box["height"] <= height + 0.5, (sel, box, size)
        stop, ecu = page.locator("#stop").bounding_box(), page.locator("#ecu").bounding_box()
        assert ecu["x"] + ecu["width"] <= stop["x"], (ecu, stop)  # the pill shortens, it does not run under STOP
        assert stop["width"] >= 100 and stop["height"] >= 48  # still a big target
        hit = page.evaluate(
            "([x, y]) => document.elementFromPoint(x, y).id", [stop["x"] + stop["width"] / 2, stop["y"] + 5]
        )
        assert hit == "stop"
        assert names[-1] in page.get_attribute("#ecu", "title")  # the full text stays available
        page.screenshot(path=str(shots / f"14-faults-{width}x{height}.png"))
    finally:
        done.set()
        feeder.join(2)
        page.set_viewport_size({"width": 1024, "height": 600})
        page.goto(service.url)
        web.close()


def _forward(service, name: str, body: bytes) -> tuple[bool, dict]:
    status, reply = service.api(name, json.loads(body or b"{}"))
    return status == 200, reply


# ---------------------------------------------------------------------------------------------- login
@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """``hitch serve`` with a security file (olga operates, victor views) and ``--http-user olga``."""
    from bridge.service.security import AccessPolicy, SecuritySettings, security_json5, write_users_file

    d = tmp_path_factory.mktemp("hitch-serve-secured")
    users = write_users_file(d / "users.txt", {"olga": "o-secret", "victor": "v-secret"})
    sec = d / "security.json5"
    sec.write_text(
        security_json5(
            SecuritySettings(
                users_file=users, access=AccessPolicy(prefix="hitch", operators=("olga",), viewers=("victor",))
            )
        )
    )
    svc = Service(d, "--security", str(sec), "--http-user", "olga", login=("olga", "o-secret")).start()
    yield svc
    svc.kill(signal.SIGTERM)
    svc.kill()


def test_with_access_control_the_page_asks_for_a_login(secured, page, shots):
    pg = page.context.new_page()
    pg.set_default_timeout(10_000)
    try:
        pg.goto(secured.url)
        pg.wait_for_selector("#login:not(.hidden)")
        assert pg.is_hidden("main") and pg.is_visible("#stop")  # nothing to see or move, STOP stays
        pg.screenshot(path=str(shots / "15-login.png"))
        pg.fill("#login-form input[name=user]", "victor")
        pg.fill("#login-form input[name=password]", "wrong")
        pg.click("#login-go")
        wait_js(pg, "document.getElementById('login-result').textContent.includes('wrong user name or password')")
        pg.fill("#login-form input[name=password]", "v-secret")
        pg.click("#login-go")
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
        assert pg.text_content("#user") == "victor · viewer"
        assert "hitch_session" not in pg.evaluate("document.cookie")  # HttpOnly: no script reads the session
        tab(pg, "jog")
        assert pg.is_disabled("button.jog[data-dof='z'][data-sign='1']")
        tab(pg, "goto")
        assert pg.is_disabled("#goto-go")
        for sel in ACTION_BUTTONS:  # the quick row and the tabs' commands too: a viewer watches and stops
            show(pg, sel)
            assert pg.is_disabled(sel), sel
        tab(pg, "goto")
        # the viewer's own command through the page: refused by the service as victor, not run as --http-user olga
        pg.evaluate("document.getElementById('goto-go').disabled = false")
        pg.fill("#goto-form input[name=z]", "100")
        pg.click("#goto-go")
        wait_js(pg, "document.getElementById('goto-result').textContent.includes('victor')")
        assert not secured.state()["moving"]
        record_log(pg)
        pg.click("#stop")  # a viewer may stop
        wait_log(pg, "STOP: motion stopped")
        tab(pg, "help")
        pg.click("#logout")
        pg.wait_for_selector("#login:not(.hidden)")
        pg.fill("#login-form input[name=user]", "olga")
        pg.fill("#login-form input[name=password]", "o-secret")
        pg.click("#login-go")
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
        assert pg.text_content("#user") == "olga · operator"
        z0 = secured.state()["pose"]["z"]
        goal = {"z": 0.1 if z0 < 0.05 else 0.0}
        goto_target(secured, pg, goal, speed=50)  # an operator's goto through the page (with the CSRF token)
        wait_for(lambda: secured.state()["moving"], 5, "the logged-in operator's goto to start")
        pg.click("#stop")
        wait_for(lambda: not secured.state()["moving"], 5, "STOP")
    finally:
        pg.close()


# ---------------------------------------------------------------------------------------------- the command row
# the quick row (under the tab area, whatever tab is open) and the commands that live in a tab
QUICK_BUTTONS = ("#act-raise", "#act-return", "#act-pause", "#act-resume", "#act-skip")
WORK_CONTROLS = ("#work-mode", "#work-settings", "#work-toggle", "#work-resume", "#work-status")
CONTROL_TAB = {"#act-implement": "implement", "#act-lock": "implement", "#act-record": "maneuvers"}
CONTROL_TAB.update({sel: "work" for sel in WORK_CONTROLS})
ACTION_BUTTONS = QUICK_BUTTONS + ("#act-lock", "#act-implement", "#act-record")


def show(pg, sel: str) -> None:
    """Open the tab that holds ``sel`` (the quick row's controls need none)."""
    if sel in CONTROL_TAB:
        tab(pg, CONTROL_TAB[sel])


def _settle(service, goal: dict, timeout_s: float = 20.0) -> dict:
    """Wait for the motion to end and the measured pose to settle within the closed loop's target of ``goal``."""
    wait_for(lambda: not service.state()["moving"], timeout_s, "the motion to end")
    last: dict = {}

    def settled():
        last.clear()
        last.update(service.state()["pose"])
        return within_steady_state_target(last, goal)

    try:
        wait_for(settled, 5, f"the hitch to settle within 2 mm / 2 mrad of {goal}")
    except AssertionError as exc:
        raise AssertionError(f"{exc}; last {last}") from None
    return last


def test_action_row_raise_return_lock_and_the_implement_chooser(service, page, shots):
    """Raise goes to the implement's headland pose and Return back to where the raise started; the
    transport lock refuses a goto with the service's words; the chooser shows a refusal while moving."""
    _connected(page, service.url)
    at_rest(service, page)
    headland = {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.0}
    status, reply = service.api(
        "implements/define",
        {
            "name": "plough",
            "category": "2",
            "mass_kg": 300.0,
            "com_m": [0.0, 0.5, 0.3],
            "headland": headland,
            "upper_height_m": 0.30,
            "lowering_speed_m_s": 0.2,
        },
    )
    assert status == 200, reply
    page.reload()  # the chooser lists the implements when the page connects
    _connected(page, service.url)
    for sel in ACTION_BUTTONS:  # every control present (in its tab), inside the cab display
        show(page, sel)
        box = page.locator(sel).bounding_box()
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 1024.5, (sel, box)
        assert box["y"] + box["height"] <= 600.5, (sel, box)
    assert page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]") == [1024, 600]
    page.wait_for_selector("#act-implement option[value='plough']", state="attached")
    tab(page, "implement")
    # an implement without a headland pose and no preset "headland": said so, and Raise has nowhere to go (an
    # operator's trial: the tab showed 'the preset “headland”', which did not exist, and Raise stayed enabled)
    page.select_option("#act-implement", "cat2-spreader-400")
    wait_js(page, "document.getElementById('act-result').textContent === 'implement: cat2-spreader-400'")
    wait_js(page, "document.getElementById('imp-limits').textContent.includes('none: define one, or save a preset')")
    wait_js(page, "document.getElementById('act-raise').disabled === true")
    page.select_option("#act-implement", "plough")
    wait_js(page, "document.getElementById('act-result').textContent === 'implement: plough'")
    assert service.api("implements/list")[1]["selected"] == "plough"
    wait_js(page, "document.getElementById('act-lock').textContent === 'Lock: off'")
    # the Implement tab names it in full with its record and limits (upper height 300 mm, lowering 200 mm/s)
    assert page.evaluate("document.getElementById('act-implement').selectedOptions[0].textContent") == "plough"
    wait_js(page, "document.getElementById('imp-limits').textContent.includes('300.0 mm (tool point z)')")
    assert "200 mm/s" in page.text_content("#imp-limits")
    # work pose → Raise (headland) → Return (the work pose again)
    work = {"x": 0.02, "z": 0.0, "roll": 0.0, "pitch": 0.0}
    assert service.api("goto", {"goal": work})[0] == 200
    _settle(service, work)
    page.click("#act-raise")
    wait_js(page, "document.getElementById('act-result').textContent.startsWith('raise: moving')")
    _settle(service, headland)
    # the last work pose is where the hitch measured at rest when Raise was pressed (within the settling
    # target of the work pose), shown as the service recorded it; the test expected exactly 'left 20.0 mm'
    # and failed now and then (CI-style run, 2026-12-06): a measured x at rest need not round to 20.0 mm
    plough = next(i for i in service.api("implements/list")[1]["implements"] if i["name"] == "plough")
    x_mm = plough["last_work"]["x"] * 1000
    assert abs(x_mm - 20.0) <= 2.0, plough["last_work"]
    wait_js(  # 'left NN.N mm', to the tenth shown (either way of rounding a tie)
        page,
        "(() => { const m = document.getElementById('imp-limits').textContent.match(/left (\\d+\\.\\d) mm/);"
        f" return m !== null && Math.abs(parseFloat(m[1]) - {x_mm!r}) <= 0.051; }})()",
    )
    page.screenshot(path=str(shots / "21-actions-row.png"))
    page.click("#act-return")
    wait_js(page, "document.getElementById('act-result').textContent.startsWith('return: moving')")
    _settle(service, work)
    # the chooser while moving: the service's refusal is shown, the selection stays
    assert service.api("goto", {"goal": headland, "speed_scale": 0.2})[0] == 200
    wait_for(lambda: service.state()["moving"], 5, "the goto to start")
    other = [
        n for n in page.eval_on_selector_all("#act-implement option", "os => os.map(o => o.value)") if n != "plough"
    ]
    assert other, "the chooser lists the tractor profile's implements too"
    page.select_option("#act-implement", other[0])
    # the refusal of the selection (the return's abort by the goto may be shown first: also an error, a CI-style run)
    wait_js(
        page,
        "(e => e.classList.contains('err') && e.textContent.startsWith('implements/select'))"
        "(document.getElementById('act-result'))",
    )
    refusal = page.text_content("#act-result")
    assert refusal.startswith("implements/select") and "stop" in refusal, refusal
    wait_js(page, "document.getElementById('act-implement').value === 'plough'")
    at_rest(service, page)
    # the transport lock: shown, and a goto from the page refused with the service's words
    page.click("#act-lock")
    wait_js(page, "document.getElementById('act-lock').textContent === 'Lock: on'")
    assert page.get_attribute("#act-lock", "aria-pressed") == "true"
    assert page.text_content("#imp-lock-text").startswith("transport lock on")
    page.screenshot(path=str(shots / "26-implement-tab.png"))
    goal = {"z": 0.1}
    tab(page, "goto")
    for k in ("x", "z", "roll", "pitch"):
        page.fill(f"#goto-form input[name={k}]", "" if k not in goal else f"{goal[k] * 1000:.1f}")
    page.click("#goto-go")
    wait_js(page, "document.getElementById('goto-result').textContent.includes('transport-locked')")
    assert "goto refused: the implement is transport-locked" in page.text_content("#goto-result")
    assert not service.state()["moving"]
    tab(page, "implement")
    page.click("#act-lock")
    wait_js(page, "document.getElementById('act-lock').textContent === 'Lock: off'")
    assert page.errors == []


def test_record_review_save_and_pause_resume_of_a_running_maneuver(service, page, shots):
    _connected(page, service.url)
    at_rest(service, page)
    z0 = service.state()["pose"]["z"]
    tab(page, "maneuvers")  # teach-in lives with the maneuvers
    page.click("#act-record")
    wait_js(page, "document.getElementById('act-record').getAttribute('aria-pressed') === 'true'")
    for z in (0.12 if z0 < 0.05 else -0.05, z0):
        goto_target(service, page, {"z": z})
        # at the goal and at rest: "not moving" alone can be read before the motion starts (the reply comes
        # first, the motion ~80 ms later), and the next goto then reverses a hitch at full speed, whose
        # braking overshoots the workspace (CI: 'z reaches 380.8 mm … workspace:z:max')
        wait_for(lambda z=z: _at(service.state(), z), 15, "the recorded goto to end at its goal")
    tab(page, "maneuvers")
    page.click("#act-record")
    page.wait_for_selector("#review:not(.hidden)")
    script = page.input_value("#review-script")
    assert script.count("goto") == 2, script
    page.fill("#review-name", "taught")
    page.screenshot(path=str(shots / "22-record-review.png"))
    page.click("#review-save")
    page.wait_for_selector("#review", state="hidden")
    tab(page, "maneuvers")
    page.wait_for_selector("#maneuver-list li[data-name='taught']")
    assert "taught" in [m["name"] for m in service.api("maneuvers/list")[1]["maneuvers"]]
    # Cancel discards: nothing saved
    page.click("#act-record")
    wait_js(page, "document.getElementById('act-record').getAttribute('aria-pressed') === 'true'")
    goto_target(service, page, {"z": z0 + 0.01})
    wait_for(lambda: _at(service.state(), z0 + 0.01), 15, "the goto to end at its goal")
    tab(page, "maneuvers")
    page.click("#act-record")
    page.wait_for_selector("#review:not(.hidden)")
    page.click("#review-cancel")
    page.wait_for_selector("#review", state="hidden")
    assert len(service.api("maneuvers/list")[1]["maneuvers"]) == len(page.query_selector_all("#maneuver-list li"))
    # pause / resume / skip of a running maneuver, its progress from the state
    # the second step lasts 3 s: long enough to be read in the state after the skip (polled over HTTP, which a
    # loaded machine slows: a poll that misses a 1 s step finds no maneuver and waits its 5 s out), short enough
    # for the maneuver's end to be waited for
    script = "name: waits\nsteps:\n  - wait: 20\n  - wait: 3\n"
    assert service.api("maneuvers/save", {"name": "waits", "script": script})[0] == 200
    assert service.api("maneuvers/run", {"name": "waits"})[0] == 200
    wait_js(page, "!document.getElementById('act-pause').disabled")
    try:
        wait_js(
            page,
            "/^waits: step 1 of 2 · wait · \\d+\\.\\d s left$/"
            ".test(document.getElementById('act-progress').textContent)",
        )
    except AssertionError as exc:
        raise AssertionError(f"{exc}; shown {page.text_content('#act-progress')!r}") from None
    page.click("#act-pause")
    wait_for(lambda: (service.state()["maneuver"] or {}).get("paused") is True, 5, "the maneuver to pause")
    wait_js(page, "document.getElementById('act-progress').textContent.endsWith('· paused')")
    assert page.is_visible("#act-progress")  # while a maneuver runs the quick row's line is its progress
    assert page.is_disabled("#act-pause") and not page.is_disabled("#act-resume")
    left = service.state()["maneuver"]["time_left"]
    time.sleep(0.5)
    assert service.state()["maneuver"]["time_left"] == pytest.approx(left, abs=1e-6)  # paused: the time stands
    page.screenshot(path=str(shots / "23-maneuver-paused.png"))
    page.click("#act-resume")
    wait_for(lambda: (service.state()["maneuver"] or {}).get("paused") is False, 5, "the maneuver to resume")
    wait_js(page, "!document.getElementById('act-progress').textContent.includes('paused')")
    page.click("#act-skip")
    wait_for(lambda: (service.state()["maneuver"] or {}).get("step") == 1, 5, "the skip to the second step")
    wait_for(lambda: service.state()["maneuver"] is None, 10, "the maneuver to end")
    wait_js(page, "document.getElementById('act-progress').textContent === 'no maneuver running'")
    assert page.is_disabled("#act-pause") and page.is_disabled("#act-skip")
    assert page.is_hidden("#act-progress") and page.is_visible("#act-result")  # idle: the line shows the answers
    assert page.errors == []


# the last control of each tab (what an operator must reach without scrolling)
TAB_LAST = {
    "jog": "#jog-speed",
    "goto": "#goto-go",
    "presets": "#preset-list li:last-child button:last-child",
    "maneuvers": "#maneuver-editor summary",
    "implement": "#imp-limits dd:last-of-type",
    "work": "#work-summary",
    "help": "#config dd:last-of-type",
}


def test_every_tab_fits_the_cab_display(service, page, shots):
    """At 1024×600 every tab's content is whole without scrolling — its last control inside the viewport
    and inside the tab, the tab needing no scrolling, the page neither — while the quick row stays in view
    under it and the tab bar shows every label whole. Run after the maneuver tests: several stored
    maneuvers and a preset in the lists."""
    _connected(page, service.url)
    at_rest(service, page)
    if not service.api("presets/list")[1]["presets"]:  # run alone: one of each to list
        assert service.api("presets/save", {"name": "start"})[0] == 200
    if not service.api("maneuvers/list")[1]["maneuvers"]:
        assert (
            service.api("maneuvers/save", {"name": "waits", "script": "name: waits\nsteps:\n  - wait: 1\n"})[0] == 200
        )
    page.reload()  # the lists as the page reads them on connecting
    _connected(page, service.url)
    assert page.eval_on_selector_all(".tabs button", "bs => bs.map(b => b.dataset.tab)") == list(TAB_LAST)
    for name, last in TAB_LAST.items():
        tab(page, name)
        if name in ("presets", "maneuvers"):
            page.wait_for_selector(f"#{'preset' if name == 'presets' else 'maneuver'}-list li")
        if name == "help":
            wait_js(page, "document.querySelectorAll('#config dd').length > 0")
        pane = page.locator(f"#tab-{name}").bounding_box()
        # a list drawn again meanwhile (a refresh after connecting) detaches its old items for a moment: the box of
        # the one asked for is None then (a CI-style run); asked again once it is there
        box = None
        for _ in range(20):
            page.locator(last).wait_for(state="visible")
            if (box := page.locator(last).bounding_box()) is not None:
                break
            time.sleep(0.05)
        assert pane is not None and box is not None, (name, last)
        assert box["y"] >= pane["y"] - 0.5 and box["y"] + box["height"] <= pane["y"] + pane["height"] + 0.5, (
            name,
            last,
            box,
            pane,
        )
        assert box["y"] + box["height"] <= 600, (name, last, box)  # inside the cab display
        assert box["x"] >= 0 and box["x"] + box["width"] <= 1024.5, (name, last, box)
        scroll = page.evaluate(f"(e => [e.scrollHeight, e.clientHeight])(document.getElementById('tab-{name}'))")
        assert scroll[0] <= scroll[1] + 1, (name, scroll)  # no scrolling needed inside the tab
        assert page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]") == [
            1024,
            600,
        ], name
        for sel in QUICK_BUTTONS + ("#stop", "#level-toggle"):  # the quick row, STOP and levelling stay in view
            q = page.locator(sel).bounding_box()
            assert q is not None and q["y"] >= 0 and q["y"] + q["height"] <= 600, (name, sel, q)
            assert q["y"] >= pane["y"] + pane["height"] or q["y"] + q["height"] <= pane["y"], (name, sel, q, pane)
    labels = page.eval_on_selector_all(
        ".tabs button", "bs => bs.map(b => [b.textContent, b.scrollWidth, b.clientWidth])"
    )
    assert all(sw <= cw for _, sw, cw in labels), labels  # no label cut short
    assert min(cw for _, _, cw in labels) >= 34, labels  # still a touch target
    tab(page, "maneuvers")
    page.screenshot(path=str(shots / "27-maneuvers-tab.png"))
    tab(page, "jog")
    assert page.errors == []


def test_the_action_row_fits_800x480(service, page, shots):
    page.set_viewport_size({"width": 800, "height": 480})
    try:
        _connected(page, service.url)
        assert page.evaluate("document.documentElement.scrollWidth") == 800  # no sideways overflow
        row = page.locator("#actions").bounding_box()
        assert row is not None and row["x"] >= 0 and row["x"] + row["width"] <= 800.5, row
        for sel in ACTION_BUTTONS + WORK_CONTROLS[:-1]:
            show(page, sel)
            box = page.locator(sel).bounding_box()
            assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 800.5, (sel, box)
            assert box["width"] >= 60 and box["height"] >= 40, (sel, box)  # still a touch target
            assert page.evaluate("document.documentElement.scrollWidth") == 800, sel
        tab(page, "jog")
        page.locator("#actions").scroll_into_view_if_needed()  # at 800×480 the panels below the header scroll
        page.screenshot(path=str(shots / "24-actions-800x480.png"))
    finally:
        page.set_viewport_size({"width": 1024, "height": 600})


# ---------------------------------------------------------------------------------------------- work control


def test_work_control_settings_start_stop_and_the_fallback_without_a_field(service, page, shots):
    """The Work tab at 1024×600: the mode and the settings (kN, cm) put through the
    page reach the service's stored settings in SI; Start opens a work session which — this service has
    no sim field, so no draft on the bus — falls back to position control at once, shown in words with
    the setpoint in kN; Resume is offered; Stop ends it. Still no overflow at 800×480."""
    _connected(page, service.url)
    at_rest(service, page)
    # draft work needs an implement selected (work/start refuses it without one): a light tine, none again after
    tine = {"name": "tine", "category": "2", "mass_kg": 150.0, "com_m": [0.0, 0.3, 0.2]}
    assert service.api("implements/define", tine)[0] == 200
    assert service.api("implements/select", {"name": "tine"})[0] == 200
    tab(page, "work")
    for sel in WORK_CONTROLS:  # inside the cab display, no scrolling
        box = page.locator(sel).bounding_box()
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 1024.5, (sel, box)
        assert box["y"] + box["height"] <= 600.5, (sel, box)
    assert page.evaluate("[document.documentElement.scrollWidth, document.documentElement.scrollHeight]") == [1024, 600]
    implement = service.api("work/settings")[1]["implement"]
    page.select_option("#work-mode", "draft")
    wait_for(lambda: service.api("work/settings")[1]["settings"]["mode"] == "draft", 5, "mode draft stored")
    page.click("#work-settings")
    page.wait_for_selector("#work-dialog:not(.hidden)")
    page.fill("#work-form input[name=depth_max_cm]", "70")  # out of range: the service's words, nothing stored
    page.click("#work-save")
    wait_js(page, "document.getElementById('work-form-result').classList.contains('err')")
    assert "depth_max" in page.text_content("#work-form-result")
    for name, value in (("draft_kn", "20"), ("blend", "0.4"), ("depth_min_cm", "5"), ("depth_max_cm", "30")):
        page.fill(f"#work-form input[name={name}]", value)
    page.click("#work-save")
    page.wait_for_selector("#work-dialog", state="hidden")
    stored = service.api("work/settings")[1]
    assert stored["implement"] == implement
    assert stored["settings"]["draft_setpoint_n"] == pytest.approx(20_000.0)
    assert stored["settings"]["blend"] == pytest.approx(0.4)
    assert stored["settings"]["depth_min_m"] == pytest.approx(0.05)
    assert stored["settings"]["depth_max_m"] == pytest.approx(0.30)
    wait_js(
        page, "document.getElementById('work-status').textContent === 'work control: off · draft (setpoint 20.0 kN)'"
    )
    # Start: no draft on the bus (no sim field) → one fallback, position control, shown in words
    page.click("#work-toggle")
    wait_for(lambda: (service.state().get("work") or {}).get("running"), 5, "the work session to start")
    wait_for(lambda: service.state()["work"]["fallback"] == "draft signal stale: no reading", 5, "the fallback")
    try:
        wait_js(
            page,
            "document.getElementById('work-status').textContent.startsWith("
            "'fallback: draft signal stale (no reading) — position control · draft — (setpoint 20.0 kN)')",
        )
    except AssertionError as exc:
        raise AssertionError(f"{exc}; shown {page.text_content('#work-status')!r}") from None
    assert page.get_attribute("#work-toggle", "aria-pressed") == "true"
    assert not page.is_disabled("#work-resume")
    assert service.state()["work"]["active"] == "position" and service.state()["motion"] is not None
    page.screenshot(path=str(shots / "25-work-fallback.png"))
    page.click("#work-toggle")  # Stop
    wait_for(lambda: not service.state()["work"]["running"], 5, "the work session to end")
    wait_js(page, "document.getElementById('work-status').textContent.startsWith('work control: off')")
    assert page.get_attribute("#work-toggle", "aria-pressed") == "false" and page.is_disabled("#work-resume")
    at_rest(service, page)
    assert service.api("work/settings", {"mode": "position"})[0] == 200  # leave the shared service as found
    assert service.api("implements/select", {"name": "default"})[0] == 200  # no implement, as the other tests expect
    page.set_viewport_size({"width": 800, "height": 480})
    try:
        assert page.evaluate("document.documentElement.scrollWidth") == 800  # no sideways overflow
        for sel in WORK_CONTROLS:
            box = page.locator(sel).bounding_box()
            assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= 800.5, (sel, box)
    finally:
        page.set_viewport_size({"width": 1024, "height": 600})
    assert page.errors == []


# ---------------------------------------------------------------------------------------------- operator's trial
def type_into(pg, sel: str, text: str) -> None:
    """Clear a field and type ``text`` key by key, as an operator does (``fill`` bypasses what a browser's
    number input makes of a decimal comma)."""
    pg.fill(sel, "")
    pg.locator(sel).press_sequentially(text)


def _goto_answer(pg, button: str) -> str:
    pg.evaluate("document.getElementById('goto-result').textContent = ''")
    pg.click(button)
    wait_js(pg, "document.getElementById('goto-result').textContent.length > 0", timeout=5_000)
    return pg.text_content("#goto-result")


def test_a_decimal_comma_is_a_decimal_point_in_every_number_field(service, page):
    """The operator typed ``12,5`` mm into z: the browser's number input dropped the comma, the field held
    125 and the hitch went to 125 mm. Now 12,5 is 12.5 (goto, and the work settings' kN and blend)."""
    _connected(page, service.url)
    at_rest(service, page)
    tab(page, "goto")
    for k in ("x", "roll", "pitch"):
        page.fill(f"#goto-form input[name={k}]", "")
    type_into(page, "#goto-form input[name=z]", "12,5")
    type_into(page, "#goto-form input[name=speed]", "100")
    text = _goto_answer(page, "#goto-go")
    assert text.startswith("moving: motion #") or re.fullmatch(r"motion #\d+ finished", text), text
    mid = int(re.search(r"motion #(\d+)", text).group(1))

    def ended() -> bool:  # its own end: a state from before it started also says "not moving" (a CI-style run
        s = service.state()  # read the start pose's reference, 9.8 mm)
        return (s.get("motion_id") or 0) >= mid and not s["moving"]

    wait_for(ended, 20, "the goto to end")
    ref_z = service.state()["reference"]["pose"]["z"]
    assert ref_z == pytest.approx(0.0125, abs=1e-4), f"the hitch went to z = {ref_z * 1000:.1f} mm for 12,5 mm"
    assert page.input_value("#goto-form input[name=z]") == "12,5"  # the field keeps what was typed
    # an invalid number is refused in the form, nothing is sent
    type_into(page, "#goto-form input[name=z]", "1e")
    text = _goto_answer(page, "#goto-go")
    assert "z:" in text and "not a number" in text and "mm" in text, text
    assert "err" in page.get_attribute("#goto-result", "class")
    time.sleep(0.3)
    assert not service.state()["moving"]
    assert service.state()["reference"]["pose"]["z"] == pytest.approx(0.0125, abs=1e-4)
    page.fill("#goto-form input[name=z]", "")
    # Work ⚙ Settings: blend 0,4 and draft 2,5 kN (not 4 and 25 kN)
    before = service.api("work/settings")[1]["settings"]
    tab(page, "work")
    page.click("#work-settings")
    page.wait_for_selector("#work-dialog:not(.hidden)")
    try:
        type_into(page, "#work-form input[name=draft_kn]", "2,5")
        type_into(page, "#work-form input[name=blend]", "0,4")
        page.click("#work-save")
        page.wait_for_selector("#work-dialog", state="hidden", timeout=5_000)
        stored = service.api("work/settings")[1]["settings"]
        assert stored["draft_setpoint_n"] == pytest.approx(2_500.0), stored
        assert stored["blend"] == pytest.approx(0.4), stored
    finally:
        if not page.is_hidden("#work-dialog"):
            page.click("#work-cancel")
        keep = {k: before[k] for k in ("draft_setpoint_n", "blend", "depth_min_m", "depth_max_m")}
        assert service.api("work/settings", keep)[0] == 200
    assert page.errors == []


def test_check_refuses_exactly_what_go_refuses(service, page):
    """Check (hitch/plan) ignored what Go refused: speed 0, 2.5 and 500 % were checked at 5 % and 100 %,
    an invalid x was dropped. Both now give the same refusal, in the field's unit, and nothing is sent."""
    _connected(page, service.url)
    at_rest(service, page)
    tab(page, "goto")
    cases = [
        ({"z": "50", "speed": "0"}, "speed", "5–100 %"),
        ({"z": "50", "speed": "2.5"}, "speed", "5–100 %"),
        ({"z": "50", "speed": "500"}, "speed", "5–100 %"),
        ({"x": "1e", "z": "50", "speed": "100"}, "x:", "mm"),
    ]
    for fields, names, unit in cases:
        for k in ("x", "z", "roll", "pitch", "speed"):
            type_into(page, f"#goto-form input[name={k}]", fields.get(k, ""))
        check = _goto_answer(page, "#goto-plan")
        assert "err" in page.get_attribute("#goto-result", "class"), (fields, check)
        go = _goto_answer(page, "#goto-go")
        assert "err" in page.get_attribute("#goto-result", "class"), (fields, go)
        assert check == go, (fields, check, go)
        assert names in check and unit in check, (fields, check)
        time.sleep(0.2)
        assert not service.state()["moving"], fields
    type_into(page, "#goto-form input[name=speed]", "100")
    page.fill("#goto-form input[name=x]", "")
    assert page.errors == []


def test_work_settings_are_checked_in_the_dialogs_units_and_refusals_come_back_in_them(service, page):
    """An empty or "abc" draft closed the dialog as if saved; the service's refusals came in N and m for the
    kN and cm fields. Now the dialog refuses in kN and cm before sending, and converts the service's words."""
    _connected(page, service.url)
    at_rest(service, page)
    before = service.api("work/settings")[1]["settings"]
    tab(page, "work")
    page.click("#work-settings")
    page.wait_for_selector("#work-dialog:not(.hidden)")
    try:
        for draft in ("", "abc"):
            page.evaluate("document.getElementById('work-form-result').textContent = ''")
            type_into(page, "#work-form input[name=draft_kn]", draft)
            page.click("#work-save")
            wait_js(page, "document.getElementById('work-form-result').textContent.length > 0", timeout=5_000)
            text = page.text_content("#work-form-result")
            assert not page.is_hidden("#work-dialog"), f"draft {draft!r} closed the dialog"
            assert text.startswith("draft") and "kN" in text, text
        type_into(page, "#work-form input[name=draft_kn]", "20000")
        page.click("#work-save")
        wait_js(page, "document.getElementById('work-form-result').textContent.includes('20000 kN')", timeout=5_000)
        assert "300] kN" in page.text_content("#work-form-result")
        type_into(page, "#work-form input[name=draft_kn]", "20")
        type_into(page, "#work-form input[name=depth_min_cm]", "40")
        type_into(page, "#work-form input[name=depth_max_cm]", "30")
        page.click("#work-save")
        wait_js(
            page, "document.getElementById('work-form-result').textContent.includes('must be below')", timeout=5_000
        )
        text = page.text_content("#work-form-result")
        assert "depth min = 40 cm" in text and "depth max = 30 cm" in text, text
        assert not page.is_hidden("#work-dialog")
    finally:
        if not page.is_hidden("#work-dialog"):
            page.click("#work-cancel")
    assert service.api("work/settings")[1]["settings"] == before  # nothing was stored
    # the service's own refusals (SI, its field names) in the dialog's units and labels
    for body, want in (
        ({"draft_setpoint_n": 2e7}, ["draft = 20000 kN", "(0, 300] kN"]),
        ({"depth_max_m": 3.0}, ["depth max = 300 cm", "[0, 60] cm"]),
        ({"depth_min_m": 0.4, "depth_max_m": 0.3}, ["depth min = 40 cm", "depth max = 30 cm"]),
    ):
        status, reply = service.api("work/settings", body)
        assert status >= 400, reply
        shown = page.evaluate("(t) => window.hitchTerminal.workUnits(t)", reply["message"])
        for w in want:
            assert w in shown, (reply["message"], shown)
        assert not re.search(r"\d\]?\s*(N|m)\b|_n\b|_m\b", shown), shown
    assert service.api("work/settings")[1]["settings"] == before
    assert page.errors == []


def test_gauges_turn_stale_when_the_ecu_stops_reporting(service, page):
    """``hitch sim fault --cut ecu_to_planner``: the gauges kept the last values in normal colours; now they
    are greyed and the banner says the measurement's age, as when the service is down."""
    _connected(page, service.url)
    at_rest(service, page)
    wait_js(page, "!document.body.classList.contains('stale')")
    status, reply = service.api("sim/fault", {"cut": "ecu_to_planner"})
    assert status == 200, reply
    try:
        wait_for(lambda: not service.state()["ecu"]["online"], 5, "the ECU to go offline")
        wait_js(page, "document.body.classList.contains('stale')", timeout=5_000)
        assert page.evaluate("getComputedStyle(document.getElementById('gauges')).opacity") != "1"
        banner = page.text_content("#banner")
        assert page.is_visible("#banner") and re.search(r"\d+(\.\d)? s old", banner), banner
        assert page.text_content("#conn").startswith("Service: connected")  # the service itself is live
        # self-clearing faults only: nothing to acknowledge, and the valves' state is not claimed (a terminal
        # trial: Acknowledge showed and answered "none latched" in red; the tooltip said "holding")
        ecu = service.state()["ecu"]
        if not ecu["ack_required"]:
            assert ecu["faults"] and page.is_hidden("#faults-ack"), ecu
        assert "holding" not in (page.get_attribute("#ecu", "title") or "")
    finally:
        _reconnect_ecu(service)
    wait_js(page, "!document.body.classList.contains('stale')", timeout=5_000)
    assert page.is_hidden("#banner")
    assert page.errors == []


def _reconnect_ecu(service) -> None:
    """Undo a cut link: fresh measurements again and the faults it latched acknowledged (the other tests
    expect none)."""
    assert service.api("sim/fault", {"cut": "none"})[0] == 200

    def fresh() -> bool:
        age = service.state()["ecu"]["measurement_age_s"]
        return age is not None and age < 0.1

    wait_for(fresh, 10, "fresh measurements")
    for _ in range(40):
        if not service.state()["ecu"]["faults"]:
            return
        service.api("faults/ack")
        time.sleep(0.25)
    raise AssertionError(f"faults still latched: {service.state()['ecu']['faults']}")


def _select_headland_implement(service, name: str) -> None:
    """Define (category 2, 100 kg, a headland pose at z = 0.12 m) and select the implement ``name``."""
    headland = {"x": 0.0, "z": 0.12, "roll": 0.0, "pitch": 0.0}
    spec = {"name": name, "category": "2", "mass_kg": 100.0, "com_m": [0.0, 0.3, 0.2], "headland": headland}
    assert service.api("implements/define", spec)[0] == 200
    assert service.api("implements/select", {"name": name})[0] == 200


def _definition_js(dl_id: str, term: str) -> str:
    """A JavaScript expression: the text the definition list ``dl_id`` shows for ``term`` ('' if none)."""
    return (
        f"(() => {{ const dt = [...document.getElementById({dl_id!r}).querySelectorAll('dt')]"
        f".find((d) => d.textContent === {term!r}); return dt ? dt.nextElementSibling.textContent : ''; }})()"
    )


def test_the_quick_row_follows_the_raise_to_its_end(service, page):
    """The quick row kept saying ``raise: moving, motion #4, 3.0 s`` after the motion finished."""
    _connected(page, service.url)
    at_rest(service, page)
    _select_headland_implement(service, "rake")
    try:
        work = {"x": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0}  # raise from a work pose (return needs one)
        assert service.api("goto", {"goal": work})[0] == 200
        _settle(service, work)
        wait_js(page, "!document.getElementById('act-raise').disabled")
        page.click("#act-raise")
        wait_js(page, "document.getElementById('act-result').textContent.startsWith('raise: moving')")
        motion = re.search(r"motion #(\d+)", page.text_content("#act-result")).group(1)
        wait_for(lambda: _ended(service, int(motion)), 20, "the raise to end")
        wait_js(
            page,
            f"document.getElementById('act-result').textContent === 'raise: motion #{motion} finished'",
            timeout=5_000,
        )
        assert "ok" in page.get_attribute("#act-result", "class")
        page.click("#act-return")
        wait_js(page, "document.getElementById('act-result').textContent.startsWith('return: moving')")
        motion = re.search(r"motion #(\d+)", page.text_content("#act-result")).group(1)
        service.api("stop")  # stopped mid-way: the row says aborted
        wait_js(
            page,
            f"/^return: motion aborted #{motion}/.test(document.getElementById('act-result').textContent)",
            timeout=5_000,
        )
        assert "err" in page.get_attribute("#act-result", "class")
    finally:
        at_rest(service, page)
        assert service.api("implements/select", {"name": "default"})[0] == 200
    assert page.errors == []


def test_the_help_tab_names_the_implement_selected_since_connecting(service, page):
    """Help's configuration kept the implement of the connect-time ``config`` answer ("none" after a select: an
    audit): it follows every ``implement_selected`` event."""
    _connected(page, service.url)
    spec = {"name": "rake", "category": "2", "mass_kg": 100.0, "com_m": [0.0, 0.3, 0.2]}
    assert service.api("implements/define", spec)[0] == 200
    shown = _definition_js("config", "implement")
    try:
        for name, words in (("rake", "rake"), ("default", "none")):
            assert service.api("implements/select", {"name": name})[0] == 200
            wait_js(page, f"{shown} === {words!r}")
    finally:
        assert service.api("implements/select", {"name": "default"})[0] == 200
    assert page.errors == []


def test_the_implement_tab_follows_a_raise_from_another_client(service, page):
    """A raise from the cab's switch or another client recorded a new last work pose; the Implement tab kept
    "none yet (set by a raise)" (an audit): it follows ``last_work_recorded``."""
    _connected(page, service.url)
    at_rest(service, page)
    _select_headland_implement(service, "tedder")
    row = _definition_js("imp-limits", "last work pose")
    try:
        wait_js(page, f"{row} === 'none yet (set by a raise)'")
        work = {"x": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0}
        assert service.api("goto", {"goal": work})[0] == 200
        _settle(service, work)
        assert service.api("hitch/raise")[0] == 200  # not this page's raise
        wait_js(page, f"/^centre|^left|^right/.test({row})")
        wait_for(lambda: not service.state()["moving"], 20, "the raise to end")
    finally:
        at_rest(service, page)
        assert service.api("implements/select", {"name": "default"})[0] == 200
    assert page.errors == []


def test_an_older_list_answered_after_a_newer_one_is_not_drawn_over_it(service, page):
    """The server runs each command as its own task, so replies can come back out of order. The chooser's
    list asked for on connecting (no implement selected) was drawn over the one asked for on the
    ``implement_selected`` event when its answer came last: the chooser said "no implement" and Raise stayed
    disabled. Here the connect-time answers of ``implements/list`` and ``presets/list`` are held back until the
    event's answers are shown."""
    import json

    headland = {"x": 0.0, "z": 0.12, "roll": 0.0, "pitch": 0.0}
    spec = {"name": "rake", "category": "2", "mass_kg": 100.0, "com_m": [0.0, 0.3, 0.2], "headland": headland}
    assert service.api("implements/define", spec)[0] == 200
    assert service.api("implements/select", {"name": "default"})[0] == 200
    keys = {"implements/list", "presets/list"}
    BARRIER = {"type": "event", "data": {"event": "test_barrier"}}  # logged by the page as "test barrier"
    asked: dict[int, str] = {}  # request id → key, of the lists the page asked for
    held: list[str] = []  # the first answer of each list (asked on connecting), sent to the page later
    pg = page.context.new_page()
    pg.set_default_timeout(10_000)
    pg.errors = []
    pg.on("pageerror", lambda e: pg.errors.append(str(e)))

    def route(ws):
        server = ws.connect_to_server()

        def to_server(msg):
            cmd = json.loads(msg)
            if cmd.get("key") in keys:
                asked[cmd["id"]] = cmd["key"]
            server.send(msg)

        def to_page(msg):
            reply = json.loads(msg)
            key = asked.get(reply.get("id")) if reply.get("type") == "reply" else None
            if key is not None and sum(1 for k in asked.values() if k == key) == 1:
                held.append(msg)  # the only one of its key asked so far: the connect-time answer
            else:
                ws.send(msg)

        ws.on_message(to_server)
        server.on_message(to_page)
        # the older answers, then an event of the test's own: the page handles its messages in order and draws a
        # list's answer before it handles the next message, so once it logged that event it had the older answers
        pg.release = lambda: [ws.send(m) for m in [*held, json.dumps(BARRIER)]]

    try:
        pg.route_web_socket("**/ws", route)
        pg.goto(service.url)
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
        # (the route's handlers run while this thread is in a Playwright call: the evaluate)
        wait_for(lambda: pg.evaluate("true") and len(held) == 2, 10, "the connect-time answers of both lists")
        assert service.api("implements/select", {"name": "rake"})[0] == 200
        wait_js(pg, "document.getElementById('act-implement').value === 'rake'")
        wait_js(pg, "!document.getElementById('act-raise').disabled")
        record_log(pg)
        pg.release()  # the older answers (no implement) come last
        # handled by the page (a fixed 300 ms could pass on a loaded machine before it had drawn them)
        wait_log(pg, "test barrier")
        assert pg.evaluate("document.getElementById('act-implement').value") == "rake"
        assert pg.evaluate("!document.getElementById('act-raise').disabled")
        assert pg.errors == []
    finally:
        pg.close()
        assert service.api("implements/select", {"name": "default"})[0] == 200


@pytest.mark.parametrize("size", [(375, 667), (360, 640)])
def test_stop_is_whole_and_nothing_scrolls_sideways_on_a_phone(service, page, size):
    """At 375×667 STOP was cut to "ST" and the page scrolled sideways (scrollWidth 430)."""
    width, height = size
    page.set_viewport_size({"width": width, "height": height})
    try:
        _connected(page, service.url)
        for name in ("jog", "goto", "presets", "maneuvers", "implement", "work", "help"):
            tab(page, name)
            box = page.locator("#stop").bounding_box()
            assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= width + 0.5, (name, box)
            assert box["y"] >= 0 and box["height"] >= 44 and box["width"] >= 90, (name, box)
            # the whole word: the button's text is not clipped
            assert page.evaluate(
                "(() => { const b = document.getElementById('stop'); return b.scrollWidth <= b.clientWidth; })()"
            ), name
            hit = page.evaluate(
                "([x, y]) => document.elementFromPoint(x, y).id", [box["x"] + box["width"] / 2, box["y"] + 8]
            )
            assert hit == "stop", name
            widths = page.evaluate(
                "[document.documentElement.scrollWidth, document.body.scrollWidth,"
                " document.querySelector('main').scrollWidth, document.querySelector('main').clientWidth,"
                " document.querySelector('header').scrollWidth]"
            )
            assert widths[0] == width and widths[1] == width and widths[2] <= widths[3] and widths[4] <= width, (
                name,
                widths,
            )
            for sel in ("#modes", "#panel", "#goto-go", "#act-skip"):
                b = page.locator(sel).bounding_box()
                if b is not None:
                    assert b["x"] >= 0 and b["x"] + b["width"] <= width + 0.5, (name, sel, b)
    finally:
        page.set_viewport_size({"width": 1024, "height": 600})
        tab(page, "jog")
    assert page.errors == []


def test_saving_a_preset_under_an_existing_name_asks_first(service, page):
    """Saving under an existing name overwrote it silently; now the page asks (Cancel keeps it)."""
    _connected(page, service.url)
    at_rest(service, page)
    z_now = service.state()["pose"]["z"]
    stored_z = 0.2 if z_now < 0.1 else -0.1
    pose = {"x": 0.0, "z": stored_z, "roll": 0.0, "pitch": 0.0}
    assert service.api("presets/save", {"name": "dup", "pose": pose})[0] == 200

    def dup_z() -> float:
        return next(p for p in service.api("presets/list")[1]["presets"] if p["name"] == "dup")["pose"]["z"]

    try:
        tab(page, "presets")
        page.fill("#preset-form input[name=name]", "dup")
        page.click("#preset-save")
        page.wait_for_selector("#confirm:not(.hidden)", timeout=5_000)
        assert "dup" in page.text_content("#confirm-title") and page.text_content("#confirm-ok") == "Overwrite"
        page.click("#confirm-cancel")
        wait_js(page, "document.getElementById('log').textContent.includes('not saved')")
        assert dup_z() == pytest.approx(stored_z, abs=1e-6)
        page.fill("#preset-form input[name=name]", "dup")
        page.click("#preset-save")
        page.wait_for_selector("#confirm:not(.hidden)", timeout=5_000)
        page.click("#confirm-ok")
        wait_for(lambda: abs(dup_z() - stored_z) > 0.01, 5, "the preset to be overwritten")
        # a new name: no question
        page.fill("#preset-form input[name=name]", "dup2")
        page.click("#preset-save")
        wait_js(page, "document.getElementById('log').textContent.includes('preset dup2 saved')")
        assert page.is_hidden("#confirm")
    finally:
        if not page.is_hidden("#confirm"):
            page.click("#confirm-cancel")
        for n in ("dup", "dup2"):
            service.api("presets/delete", {"name": n})
    assert page.errors == []


def _fresh_login(page, url: str, user: str, password: str):
    """A new page of ``page``'s browser logged in to ``url`` as ``user`` (an earlier test's login cleared first)."""
    page.context.clear_cookies()
    pg = page.context.new_page()
    pg.set_default_timeout(10_000)
    pg.goto(url)
    pg.wait_for_selector("#login:not(.hidden)")
    pg.fill("#login-form input[name=user]", user)
    pg.fill("#login-form input[name=password]", password)
    pg.click("#login-go")
    wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
    return pg


def test_a_viewer_sees_saving_deleting_and_acknowledging_disabled(secured, page):
    """A trial: a viewer's page had *Save current*, each preset's *Delete*, the maneuver editor's *Save* and the
    header's *Acknowledge* enabled (the service refused each with 403) while the other commands were disabled;
    saving, deleting and acknowledging are an operator's (docs/security.md §1)."""
    pose = {"x": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0}
    assert secured.api("presets/save", {"name": "kept", "pose": pose, "replace": True})[0] == 200
    assert secured.api("sim/fault", {"restart_ecu": True})[0] == 200  # ecu_restart latches: Acknowledge shows
    pg = _fresh_login(page, secured.url, "victor", "v-secret")
    try:
        wait_js(pg, "!document.getElementById('faults-ack').classList.contains('hidden')")
        assert pg.is_disabled("#faults-ack")
        tab(pg, "presets")
        pg.wait_for_selector("#preset-list li[data-name='kept']")
        assert pg.is_disabled("#preset-save")
        assert pg.is_disabled("#preset-list li[data-name='kept'] button.danger")
        tab(pg, "maneuvers")
        pg.click("#maneuver-editor summary")
        assert pg.is_disabled("#maneuver-save")
        assert not pg.is_disabled("#maneuver-validate")  # a reading key: a viewer may check a script
    finally:
        pg.close()
        secured.api("sim/fault", {})
        secured.api("faults/ack", {})
        secured.api("presets/delete", {"name": "kept"})


def test_the_footer_names_the_mode_and_the_implement_another_client_chose(service, page):
    """A trial: another client's mode change and implement choice showed as "mode changed" and "implement
    selected" alone in the footer: the operator could not tell which mode or implement."""
    _connected(page, service.url)
    at_rest(service, page)
    record_log(page)
    try:
        assert service.api("mode", {"mode": "attach"})[0] == 200
        wait_log(page, "mode changed: Implement attach \\(was Automatic\\)")
        assert service.api("mode", {"mode": "auto"})[0] == 200
        assert service.api("implements/select", {"name": "cat2-spreader-400"})[0] == 200
        wait_log(page, "implement selected: cat2-spreader-400")
        assert service.api("implements/select", {"name": "default"})[0] == 200
        wait_log(page, "implement selected: none \\(the hitch alone\\)")
    finally:
        service.api("mode", {"mode": "auto"})
        service.api("implements/select", {"name": "default"})
    assert page.errors == []


def test_after_a_service_restart_the_login_form_says_why(secured, page):
    """A trial: the service restarted while an operator's page was open; the page came back with a blank login form
    (the service keeps no sessions over a restart) and nothing said why the operator was logged out."""
    pg = _fresh_login(page, secured.url, "olga", "o-secret")
    try:
        secured.kill(signal.SIGTERM)
        wait_js(pg, "document.getElementById('conn').textContent.includes('disconnected')")
        secured.start()
        pg.wait_for_selector("#login:not(.hidden)", timeout=30_000)
        wait_js(pg, "document.getElementById('login-result').textContent.includes('log in again')")
        assert "the service restarted" in pg.text_content("#login-result")
    finally:
        pg.close()


def test_a_refused_maneuver_step_is_named_by_one_number(service, page):
    """A trial: validating a script whose second step was out of range read "step 2: steps[1].goto.z = 250 m …" —
    the page's 1-based step and the service's 0-based YAML index for the same step."""
    _connected(page, service.url)
    tab(page, "maneuvers")
    if page.is_hidden("#maneuver-form"):
        page.click("#maneuver-editor summary")
    script = "steps:\n  - goto: {z: 0.1}\n  - goto: {z: 250}\n  - got: {x: 0}\n"
    page.fill("#maneuver-form textarea[name=script]", script)
    page.click("#maneuver-validate")
    wait_js(page, "document.getElementById('maneuver-result').textContent.includes('step 2')")
    shown = page.text_content("#maneuver-result")
    assert "step 2: goto.z = 250 m" in shown and "step 3: unknown step 'got'" in shown, shown
    assert "steps[" not in shown, shown
    assert page.errors == []


def test_control_limited_words_the_implement_s_upper_height_in_mm(service, page):
    """A trial: z+ held against an implement's upper height showed "Control limited: implement upper height limit:
    speed: implement upper height limit would be 218.9 mm (threshold 200 mm) at t = 1.00 s" — the guard's raw
    sentence (the page read a measure without spaces only), not the words the server sends (which are in SI)."""
    _connected(page, service.url)
    at_rest(service, page)
    limits = {"upper_height_m": 0.2, "lowering_speed_m_s": 0.05}
    body = {"name": "low-roof", "category": "2", "mass_kg": 500, "com_m": [0, 0.6, 0.3], **limits}
    assert service.api("implements/define", body)[0] == 200
    try:
        assert service.api("implements/select", {"name": "low-roof"})[0] == 200
        status, reply = service.api("goto", {"goal": {"z": 0.12}})
        assert status == 200, reply
        wait_for(lambda: _ended(service, reply["motion_id"]), 15, "the goto below the upper height")
        tab(page, "jog")
        set_jog_speed(page, 100)
        box = page.locator("button.jog[data-dof='z'][data-sign='1']").bounding_box()
        page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
        page.mouse.down()
        try:
            # the flag comes first, the guard's reason with its numbers a cycle later: wait for the words in mm
            wait_js(page, "document.getElementById('limited').textContent.includes('limit 200 mm')", timeout=8_000)
            shown = page.text_content("#limited")
        finally:
            page.mouse.up()
        assert "implement at its upper height limit" in shown and "limit 200 mm" in shown, shown
        assert "would be" not in shown and " m " not in shown, shown
    finally:
        at_rest(service, page)
        service.api("implements/select", {"name": "default"})
        service.api("implements/delete", {"name": "low-roof"})
    assert page.errors == []


def test_the_kinematic_margin_names_the_limit_ahead_without_reached(service, page):
    """While moving, the margin row read "1.73 s to height limit reached (top)" (a terminal trial): the words of a
    reached limit, for one still ahead."""
    _connected(page, service.url)
    at_rest(service, page)
    z0 = service.state()["pose"]["z"]
    assert service.api("goto", {"goal": {"z": -0.15 if z0 > 0.05 else 0.25}, "speed_scale": 0.3})[0] == 200
    try:
        wait_js(page, "document.querySelector('#m-kin .n').textContent.startsWith('to ')")
        text = page.text_content("#m-kin .n")
        assert "reached" not in text and "limit" in text, text
    finally:
        at_rest(service, page)


def test_a_refused_jog_is_said_once_and_releases_the_button(service, page):
    """A held jog button the service refuses (here the mode; another operator's live jog or a stop that ended this
    jog alike) went on sending 12 refusals a second, each a footer line, and stayed "held" (a review): now the
    refusal is said once and the page stops sending until the button is pressed again."""
    _connected(page, service.url)
    at_rest(service, page)
    tab(page, "jog")
    assert service.api("mode", {"mode": "manual"})[0] == 200
    wait_js(page, "document.querySelector('#modes button.active').dataset.mode === 'manual'")
    record_log(page)
    # the jog commands the page sends (its WebSocket), counted in the page: the truth for "stops sending" (the
    # footer's own record may see one line set twice: the page re-renders it)
    page.evaluate(
        """() => { window.__jogSent = 0; const send = WebSocket.prototype.send;
        WebSocket.prototype.send = function (d) { if (String(d).includes('"key":"jog"')) window.__jogSent += 1;
          return send.call(this, d); }; }"""
    )
    sel = "button.jog[data-dof='z'][data-sign='1']"
    box = page.locator(sel).bounding_box()
    page.mouse.move(box["x"] + box["width"] / 2, box["y"] + box["height"] / 2)
    page.mouse.down()
    try:
        wait_log(page, "jog is refused in mode 'manual'")
        time.sleep(0.6)  # 7 more periods of the page's jog (80 ms)
        # the first command's refusal arrives within a period or two: at most those in flight are sent
        assert page.evaluate("window.__jogSent") <= 2, page.evaluate("window.__jogSent")
        assert "held" not in (page.get_attribute(sel, "class") or "")
    finally:
        page.mouse.up()
        assert service.api("mode", {"mode": "auto"})[0] == 200
    assert not service.state()["moving"]


def test_a_maneuver_run_over_a_running_one_says_the_new_one_runs(service, page):
    """maneuvers/run replaces a running maneuver: the replaced one's ``maneuver_aborted`` ("replaced by another
    maneuver") is posted before the run's reply. The page counted every maneuver end between its Run and the
    reply as this run's own, so it never said that the new one runs: "slowpoke aborted: interrupted" stood under
    the list while "crawl" moved the hitch."""
    _connected(page, service.url)
    at_rest(service, page)
    z = service.state()["pose"]["z"]
    up = min(z + 0.12, 0.28)
    for name in ("slowpoke", "crawl"):
        script = f"name: {name}\nsteps:\n  - goto: {{z: {up:.3f}}}\n  - wait: 8.0\n  - goto: {{z: {z:.3f}}}\n"
        status, reply = service.api("maneuvers/save", {"name": name, "script": script, "replace": True})
        assert status == 200, reply
    tab(page, "maneuvers")
    page.wait_for_selector("#maneuver-list li[data-name='crawl']")
    try:
        page.click("#maneuver-list li[data-name='slowpoke'] button.primary")
        wait_js(page, "document.getElementById('maneuver-result').textContent.startsWith('slowpoke: running')")
        page.click("#maneuver-list li[data-name='crawl'] button.primary")
        wait_for(lambda: (service.state().get("maneuver") or {}).get("name") == "crawl", 5, "crawl to run")
        wait_js(page, "document.querySelector('#maneuver-progress .text').textContent.startsWith('crawl')")
        page.wait_for_timeout(300)  # the run's reply and the replaced one's end have both come by now
        shown = page.evaluate("document.getElementById('maneuver-result').textContent")
        assert shown.startswith("crawl: running"), shown
        assert page.errors == []
    finally:
        at_rest(service, page)


def test_a_run_s_reply_come_after_a_newer_run_s_does_not_cover_it(service, page):
    """Two Runs in a row: the replies can come back out of order (each command is a task of its own) and the
    replaced maneuver's end after both. The older run's reply set the maneuver shown back to the replaced one:
    "slowpoke: running" and then its "aborted: interrupted" stood under the list while "crawl" moved the hitch."""
    at_rest(service, page)
    z = service.state()["pose"]["z"]
    up = min(z + 0.12, 0.28)
    for name in ("slowpoke", "crawl"):
        script = f"name: {name}\nsteps:\n  - goto: {{z: {up:.3f}}}\n  - wait: 8.0\n  - goto: {{z: {z:.3f}}}\n"
        status, reply = service.api("maneuvers/save", {"name": name, "script": script, "replace": True})
        assert status == 200, reply
    held: list[str] = []  # the first run's reply, then its end: sent to the page in that order, late
    first: dict[str, Any] = {}  # the first maneuvers/run's request id, then its maneuver id
    to_the_page: list[Any] = []
    pg = page.context.new_page()
    pg.set_default_timeout(10_000)
    pg.errors = []
    pg.on("pageerror", lambda e: pg.errors.append(str(e)))

    def route(ws):
        server = ws.connect_to_server()
        to_the_page.append(ws)

        def to_server(msg):
            cmd = json.loads(msg)
            if cmd.get("key") == "maneuvers/run" and "request" not in first:
                first["request"] = cmd["id"]
            server.send(msg)

        def to_page(msg):
            m = json.loads(msg)
            if m.get("type") == "reply" and "request" in first and m.get("id") == first["request"]:
                first["maneuver"] = (m.get("data") or {}).get("maneuver_id")
                held.append(msg)
            elif (
                m.get("type") == "event"
                and (m.get("data") or {}).get("event") in ("maneuver_aborted", "maneuver_finished")
                and first.get("maneuver") is not None
                and (m.get("data") or {}).get("maneuver_id") == first["maneuver"]
            ):
                held.append(msg)
            else:
                ws.send(msg)

        ws.on_message(to_server)
        server.on_message(to_page)

    try:
        pg.route_web_socket("**/ws", route)
        pg.goto(service.url)
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
        tab(pg, "maneuvers")
        pg.wait_for_selector("#maneuver-list li[data-name='crawl']")
        pg.click("#maneuver-list li[data-name='slowpoke'] button.primary")
        # (the route's handlers run while this thread is in a Playwright call: the evaluate)
        wait_for(lambda: pg.evaluate("true") and len(held) == 1, 10, "slowpoke's run reply held")
        pg.click("#maneuver-list li[data-name='crawl'] button.primary")
        wait_js(pg, "document.getElementById('maneuver-result').textContent.startsWith('crawl: running')")
        wait_for(lambda: pg.evaluate("true") and len(held) == 2, 10, "slowpoke's end held")
        record_log(pg)
        for m in held:  # slowpoke's reply, then its end
            to_the_page[-1].send(m)
        wait_log(pg, "maneuver slowpoke: aborted")
        shown = pg.evaluate("document.getElementById('maneuver-result').textContent")
        assert shown.startswith("crawl: running"), shown
        assert pg.errors == []
    finally:
        pg.close()
        at_rest(service, page)


@contextlib.contextmanager
def first_answers_held(page, service, keys: set[str], *, at_connect: bool = True) -> Iterator[Any]:
    """A new page of ``page``'s browser on ``service`` whose first answer of each of ``keys`` is held back until
    ``pg.release()``: the server answers commands as parallel tasks, so such an answer can come after the answer
    of a later request of the same key, or after an event the request caused. ``at_connect``: the keys are asked
    on connecting (the page is yielded once their answers are held)."""
    asked: dict[int, str] = {}  # request id → key, of the requests of ``keys`` the page sent
    held: dict[str, str] = {}  # key → its first answer
    to_the_page: list[Any] = []  # the page's side of the routed WebSocket
    pg = page.context.new_page()
    pg.set_default_timeout(10_000)
    pg.errors = []
    pg.on("pageerror", lambda e: pg.errors.append(str(e)))

    def route(ws):
        server = ws.connect_to_server()
        to_the_page.append(ws)

        def to_server(msg):
            cmd = json.loads(msg)
            if cmd.get("key") in keys:
                asked[cmd["id"]] = cmd["key"]
            server.send(msg)

        def to_page(msg):
            reply = json.loads(msg)
            key = asked.get(reply.get("id")) if reply.get("type") == "reply" else None
            if key is not None and key not in held:
                held[key] = msg  # the first answer of its key: the connect-time one
            else:
                ws.send(msg)

        ws.on_message(to_server)
        server.on_message(to_page)

    def release() -> None:
        """Send the held answers, then an event of the test's own, and wait until the page logged it: it handles
        its messages in order and draws an answer before the next message, so it has drawn the held ones."""
        record_log(pg)
        for m in [*held.values(), json.dumps({"type": "event", "data": {"event": "test_barrier"}})]:
            to_the_page[-1].send(m)
        wait_log(pg, "test barrier")

    def hold_again(key: str) -> None:
        """Hold the next answer of ``key`` (one of ``keys``; its earlier held answer is sent first)."""
        if key in held:
            to_the_page[-1].send(held.pop(key))

    pg.release = release
    pg.hold_again = hold_again
    try:
        pg.route_web_socket("**/ws", route)
        pg.goto(service.url)
        wait_js(pg, "document.getElementById('conn').textContent.startsWith('Service: connected')", timeout=15_000)
        # (the route's handlers run while this thread is in a Playwright call: the evaluate)
        if at_connect:
            wait_for(lambda: pg.evaluate("true") and set(held) == keys, 10, f"the connect-time answers of {keys}")
        pg.held = lambda: set(held)
        yield pg
    finally:
        pg.close()


def test_a_config_answer_older_than_a_selection_does_not_name_the_old_implement(service, page):
    """Help's implement came from the connect-time ``config`` answer: one computed before an ``implement_selected``
    event but answered after it named the implement selected before (a review)."""
    _select_headland_implement(service, "rake")
    assert service.api("implements/select", {"name": "default"})[0] == 200
    try:
        with first_answers_held(page, service, {"config"}) as pg:
            record_log(pg)
            assert service.api("implements/select", {"name": "rake"})[0] == 200
            wait_log(pg, "implement selected: rake")
            pg.release()  # the config answer (no implement) comes after the event
            assert pg.evaluate(_definition_js("config", "implement")) == "rake"
            assert pg.errors == []
    finally:
        assert service.api("implements/select", {"name": "default"})[0] == 200


def test_a_list_answer_older_than_a_recorded_work_pose_does_not_put_the_old_one_back(service, page):
    """``last_work_recorded`` set the Implement tab's last work pose, but a list asked before the raise and answered
    after the event put the old one back (a review): the event asks for the list again."""
    at_rest(service, page)
    _select_headland_implement(service, "baler")
    row = _definition_js("imp-limits", "last work pose")
    try:
        work = {"x": 0.0, "z": 0.0, "roll": 0.0, "pitch": 0.0}
        assert service.api("goto", {"goal": work})[0] == 200
        _settle(service, work)
        with first_answers_held(page, service, {"implements/list"}) as pg:
            pg.hold_again("implements/list")  # the connect-time list is drawn: no work pose yet
            wait_js(pg, f"{row} === 'none yet (set by a raise)'")
            record_log(pg)
            assert service.api("implements/select", {"name": "baler"})[0] == 200  # the page asks for the list
            wait_log(pg, "implement selected: baler")
            wait_for(lambda: pg.evaluate("true") and pg.held() == {"implements/list"}, 5, "the list's answer held")
            status, reply = service.api("hitch/raise")  # not this page's raise: the list was answered before it
            assert status == 200, reply
            wait_js(pg, f"/^centre|^left|^right/.test({row})")
            pg.release()  # that list (no work pose yet) comes after the event
            shown = pg.evaluate(row)
            assert re.match(r"centre|left|right", shown), shown
            assert pg.errors == []
        wait_for(lambda: not service.state()["moving"], 20, "the raise to end")
    finally:
        at_rest(service, page)
        assert service.api("implements/select", {"name": "default"})[0] == 200


def test_an_older_maneuver_list_answered_after_a_newer_one_is_not_drawn_over_it(service, page):
    """The maneuver list asked for on connecting, answered after the one asked for on opening the tab, was drawn
    over it: a maneuver saved in between (here by another client; on the page, its own save) vanished from the
    list until the tab was opened again."""
    service.api("maneuvers/delete", {"name": "latecomer"})
    with first_answers_held(page, service, {"maneuvers/list"}) as pg:
        script = "name: latecomer\nsteps:\n  - wait: 0.5\n"
        assert service.api("maneuvers/save", {"name": "latecomer", "script": script})[0] == 200
        tab(pg, "maneuvers")  # asks for the list again: it has the new one
        pg.wait_for_selector("#maneuver-list li[data-name='latecomer']")
        pg.release()  # the connect-time answer (without it) comes last
        assert pg.evaluate("Boolean(document.querySelector(\"#maneuver-list li[data-name='latecomer']\"))")
        assert pg.errors == []
    assert service.api("maneuvers/delete", {"name": "latecomer"})[0] == 200


def test_an_older_work_settings_answer_is_not_drawn_over_a_newer_one(service, page):
    """The Work tab reads the selected implement's settings on connecting; that answer, come after the answer of
    a mode the operator chose meanwhile (work/settings {"mode"}), put the old mode back in the selector while
    the service had stored the new one (work/start then ran in a mode the page did not show)."""
    assert service.api("work/settings", {"mode": "position"})[0] == 200
    try:
        with first_answers_held(page, service, {"work/settings"}) as pg:
            tab(pg, "work")
            pg.select_option("#work-mode", "draft")
            wait_for(lambda: service.api("work/settings")[1]["settings"]["mode"] == "draft", 5, "mode draft stored")
            # the summary says the mode ("includes('draft')" matched the "draft setpoint" of any mode)
            wait_js(pg, "/: draft ·/.test(document.getElementById('work-summary').textContent)")
            pg.release()  # the connect-time answer (position) comes last
            assert pg.evaluate("document.getElementById('work-mode').value") == "draft"
            assert "position" not in pg.evaluate("document.getElementById('work-summary').textContent")
            assert pg.errors == []
    finally:
        assert service.api("work/settings", {"mode": "position"})[0] == 200


def test_a_preset_go_over_before_its_reply_came_is_not_said_to_be_moving(service, page):
    """A preset at the pose the hitch is at ends within a cycle: its ``motion_finished`` can reach the page
    before the ``presets/go`` reply (the same socket, other threads). The page then logged "preset …: moving"
    last, over the motion's end, and the footer said the hitch moved while it stood (goto and the quick row's
    raise keep such an outcome; the preset's Go did not)."""
    at_rest(service, page)
    assert service.api("presets/save", {"name": "here", "replace": True})[0] == 200
    try:
        with first_answers_held(page, service, {"presets/go"}, at_connect=False) as pg:
            record_log(pg)
            tab(pg, "presets")
            pg.click("#preset-list li[data-name='here'] button.primary")
            wait_for(lambda: pg.evaluate("true") and pg.held() == {"presets/go"}, 5, "the presets/go answer")
            wait_log(pg, "motion finished #\\d+")  # its end came first
            pg.release()
            shown = pg.evaluate("window.__hitchLog.filter((t) => !/test barrier/.test(t)).pop()")  # before the barrier
            assert "moving" not in shown and "finished" in shown, shown
            assert pg.errors == []
    finally:
        assert service.api("presets/delete", {"name": "here"})[0] == 200
