"""The hitch picture's numbers (:mod:`bridge.web.view`) and the operator words (:mod:`bridge.web.wording`).

Independent truths: a separately built :class:`HitchModel` (its ``forward`` points), the hitch
profile's ``pivot_height`` and strokes, the planner's own limit-name constants and sentence
format (``GuardReason.sentence``), and a scan of the source tree for every limit kind that is
constructed anywhere (so a new kind without operator words fails here).
"""

from __future__ import annotations

import base64
import json
import os
import re
import socket
import threading
import time
import typing
from pathlib import Path

import numpy as np
import pytest

from bridge.web.server import WebServer
from bridge.web.settings import WebSettings
from bridge.web.view import VIEW_RATE_HZ, HitchView, limit_codes
from bridge.web.websocket import OP_CLOSE, OP_TEXT, decode_frame, encode_frame
from bridge.web.wording import KEY_WORDS, KIND_WORDS, WORKSPACE_WORDS, highlight, limited_words, words
from planner.model.kinematics import POINT_NAMES, HitchModel
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES
from planner.profiles.hitch import load_profile

ROOT = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def view() -> HitchView:
    return HitchView.build("thesis-t132", "2", "cat2-power-harrow-1500")


@pytest.fixture(scope="module")
def model() -> HitchModel:
    return HitchModel.from_profile("thesis-t132", "2")  # a model of its own: the truth


def _state(seq: int, q: np.ndarray, qr: np.ndarray | None = None, limited: dict | None = None) -> dict:
    return {
        "seq": seq,
        "t": 1000.0 + seq,
        "actuators": dict(zip(ACTUATOR_NAMES, map(float, q), strict=True)),
        "reference": None if qr is None else {"actuators": dict(zip(ACTUATOR_NAMES, map(float, qr), strict=True))},
        "limited": limited or {},
        "stability": {"front_axle_share": 0.2},
    }


def _check_points(got: dict, model: HitchModel, q: np.ndarray) -> None:
    truth = model.forward(q)
    assert set(got["points"]) == set(POINT_NAMES)
    for n in POINT_NAMES:
        assert np.allclose(got["points"][n], truth.points[n], atol=1e-6), n
    ph = load_profile("thesis-t132").geometry.pivot_height
    for n in ("L", "R", "T"):
        assert got["above_ground"][n] == pytest.approx(truth.points[n][2] + ph, abs=1e-6)
    spec = load_profile("thesis-t132").actuators.lift
    assert got["lift_fraction"] == pytest.approx((q[0] - spec.min) / (spec.max - spec.min))


# ---------------------------------------------------------------------------------------------- numbers
def test_view_points_equal_forward_kinematics_for_measured_and_target(view, model):
    rng = np.random.default_rng(3)
    for k in range(5):
        q = model.neutral + rng.uniform(-0.3, 0.3, 5) * (model.upper - model.lower) * 0.2
        qr = model.neutral + rng.uniform(-0.3, 0.3, 5) * (model.upper - model.lower) * 0.2
        msg = view.message(_state(k, q, qr))
        assert msg["seq"] == k
        _check_points(msg["measured"], model, q)
        _check_points(msg["reference"], model, qr)
    # no reference (nothing streamed), missing or non-finite actuators: no points, no crash
    assert view.message(_state(9, model.neutral))["reference"] is None
    assert view.message({"seq": 1, "actuators": None})["measured"] is None
    assert view.message({"seq": 1, "actuators": {"lift": float("nan")}})["measured"] is None
    # a configuration the mechanism cannot close: no points
    far = model.upper + 1.0
    assert view.message(_state(2, far))["measured"] is None


def test_the_ghost_is_the_forward_kinematics_of_the_goal_actuators(view, model):
    """The picture's ``goal``: the model's points at ``state.goal.actuators`` (the plan's end), not at
    the reference; None when the state carries no goal (no plan running) or a malformed one."""
    q = model.neutral
    qr = model.neutral + 0.05 * (model.upper - model.lower)
    qg = model.neutral + 0.15 * (model.upper - model.lower)
    st = {**_state(1, q, qr), "goal": {"pose": {}, "actuators": dict(zip(ACTUATOR_NAMES, map(float, qg), strict=True))}}
    msg = view.message(st)
    _check_points(msg["goal"], model, qg)
    _check_points(msg["reference"], model, qr)
    assert msg["goal"]["points"]["T"] != msg["reference"]["points"]["T"]
    assert view.message(_state(2, q, qr))["goal"] is None
    assert view.message({**_state(3, q, qr), "goal": None})["goal"] is None
    assert view.message({**_state(4, q, qr), "goal": {"actuators": {"lift": float("nan")}}})["goal"] is None


def test_at_rest_nothing_is_recomputed(view, model):
    before = view.computed
    for seq in range(20):
        view.message(_state(seq, model.neutral, model.neutral))
    assert view.computed - before <= 1


def test_terminal_info_from_the_profiles(view, model):
    t = view.terminal()
    prof = load_profile("thesis-t132")
    assert t["ground_z"] == -prof.geometry.pivot_height
    assert t["workspace"] == {k: list(v) for k, v in model.workspace.items()}
    assert t["strokes"]["top"] == [prof.actuators.top.min, prof.actuators.top.max]
    # tractor-6t: 6000 kg empty; the harrow 1500 kg; no front ballast → 7.5 t / 6 t
    assert t["tractor_weight_n"] == pytest.approx(6000 * 9.80665)
    assert t["weight_factor"] == pytest.approx(7500 / 6000)
    assert t["rear_wheel"]["radius"] == pytest.approx(0.85)
    assert all(t["words"][c] for c in t["words"])
    json.dumps(t, allow_nan=False)


# ---------------------------------------------------------------------------------------------- words
def _kinds_constructed_in_the_source() -> set[str]:
    """Every ``LimitName("<kind>", …)`` written anywhere in planner/ and bridge/."""
    kinds: set[str] = set()
    for pkg in ("planner", "bridge"):
        for path in (ROOT / pkg).rglob("*.py"):
            kinds.update(re.findall(r'LimitName\(\s*"(\w+)"', path.read_text()))
    return kinds


def _service_codes(model: HitchModel) -> set[str]:
    """The limit codes the service can emit, from the planner's own constants and objects."""
    from planner.limits import guard, stability
    from planner.limits.guard import Guard
    from planner.model.hard_limits import HardLimits
    from planner.trajectory import plan, track
    from planner.trajectory.planner import TrajectoryPlanner

    hard = HardLimits.from_model(model)
    codes = {n for n in hard.names_lower + hard.names_upper if n}
    from planner.model.hard_limits import STROKE_NAMES, WORKSPACE_NAMES

    codes |= {n for pair in STROKE_NAMES + WORKSPACE_NAMES for n in pair}
    codes |= set(plan._VELOCITY_NAMES) | set(plan._ACCELERATION_NAMES) | set(plan._JERK_NAMES)
    codes |= set(track._VELOCITY_NAMES)
    codes |= set(guard._END_STOP_NAMES) | set(guard._MEASURES) | set(typing.get_args(stability.Measure))
    codes |= set(Guard(TrajectoryPlanner(model))._keep_out_names)
    return codes


def test_every_limit_code_the_service_can_emit_has_operator_words(model):
    codes = _service_codes(model)
    assert len(codes) > 40
    missing = sorted(c for c in codes if not words(c))
    assert not missing, missing
    assert codes <= set(limit_codes(model))  # the terminal's table sends all of them to the page
    # every kind any code constructs is in the table (a new kind fails here until it has words)
    known = {k for k, _ in KIND_WORDS} | {"workspace", "stroke"}
    assert _kinds_constructed_in_the_source() <= known, _kinds_constructed_in_the_source() - known
    # the keys of state.limited: jog directions and track DOFs (planner.trajectory.jog / track)
    from planner.trajectory.track import TRACK_DOFS

    keys = {f"{k}{s}" for k in CONTROLLED_POSE_NAMES for s in "+-"} | set(TRACK_DOFS) | {f"v{k}" for k in TRACK_DOFS}
    assert keys <= set(KEY_WORDS)


def test_the_issue_examples_and_directions():
    assert words("workspace:roll:max") == "roll limit reached (left side down)"
    assert words("stroke:top:max") == "top link at its stroke end (longest)"
    assert words("workspace:x:max").startswith("left")  # +x is the driver's left
    assert words("keep_out:remote_hydraulics_couplers") == "top link close to the remote hydraulics couplers"
    assert words("stroke:lift:min") == "lift arm at its lowest (stroke end)"
    assert words("nonsense") is None and words("stroke:wing:max") is None and words("") is None
    assert highlight("stroke:top:max") == ("top_link",)
    assert highlight("ground_clearance_left") == ("lower_link_left",)
    assert highlight("workspace:pitch:min") == ("mast",)


def test_directions_match_the_model(model):
    """roll + is the left side down, pitch + the mast top towards the tractor, top-link yaw + swings right."""
    q = model.neutral.copy()
    q[1] += 0.02  # a longer tilt cylinder lowers the right lower link
    st = model.forward(q)
    assert st.pose.roll < 0 and st.points["R"][2] < st.points["L"][2]
    assert "right side down" in WORKSPACE_WORDS[("roll", "min")]
    q = model.neutral.copy()
    q[2] += 0.02  # a longer top link pushes the mast top rearward (+y)
    st = model.forward(q)
    assert st.pose.pitch < 0 and st.points["U"][1] > model.forward(model.neutral).points["U"][1]
    assert "back" in WORKSPACE_WORDS[("pitch", "min")]


def test_guard_entries_in_words_with_units():
    from planner.limits.guard import GuardReason

    w = 6000 * 9.80665
    fa = GuardReason("front_axle_load", 0.16 * w, 0.25 * w, 0.5, "caution")
    text = limited_words("front_axle_load", f"caution: {fa.sentence()}", w)
    assert text == "front axle load 16 % of the tractor's weight (slows below 25 %): slowed"
    hard = GuardReason("front_axle_load", 0.16 * w, 0.20 * w, 0.5, "hard")
    assert "(minimum 20 %)" in limited_words("front_axle_load", f"hard: {hard.sentence()}", w)
    ssm = GuardReason("ssm", 0.15, 0.2, 0.5, "caution")
    assert limited_words("ssm", f"caution: {ssm.sentence()}") == (
        "side stability margin too low: 0.15 m (slows below 0.20 m): slowed"
    )
    es = GuardReason("end_stop:tilt", 0.01, 0.02, 0.0, "speed")
    expected = "tilt cylinder (right lift rod) slowing before its stroke end: slowed to 1 %"  # the factor, in %
    assert limited_words("end_stop:tilt", f"speed: {es.sentence()}") == expected
    assert limited_words("x+", "workspace:x:max") == "left limit reached (lateral position)"
    assert limited_words("what", "ever") == "what: ever"  # unknown: shown as it came, never dropped
    # the guard's reasons carry their SI units (since 2026-12-05): the words are the same
    ssm_m = GuardReason("ssm", 0.15, 0.2, 0.5, "caution", "m")
    assert "0.15 m (threshold 0.2 m)" in ssm_m.sentence()
    assert limited_words("ssm", f"caution: {ssm_m.sentence()}") == (
        "side stability margin too low: 0.15 m (slows below 0.20 m): slowed"
    )
    fa = GuardReason("front_axle_load", 9000.0, 12000.0, 0.5, "hard", "N")
    assert limited_words("front_axle_load", f"hard: {fa.sentence()}", 60000.0) == (
        "front axle load 15 % of the tractor's weight (minimum 20 %): refused"
    )
    esm = GuardReason("esm", 1569.0, 2000.0, 0.5, "hard", "J")
    assert limited_words("esm", f"hard: {esm.sentence()}").endswith("1.6 kJ (minimum 2.0 kJ): refused")


def test_limited_entries_carry_words_and_the_members_to_highlight(view, model):
    w = view.tractor_weight_n
    msg = view.message(
        _state(
            1,
            model.neutral,
            limited={
                "x+": "workspace:x:max",
                "front_axle_load": f"caution: front_axle_load would be {0.18 * w:.4g} "
                f"(threshold {0.25 * w:.4g}) at t = 0.50 s",
            },
        )
    )
    by_key = {e["key"]: e for e in msg["limited"]}
    assert by_key["x+"]["words"] == "left limit reached (lateral position)"
    assert by_key["x+"]["highlight"] == ["implement"]
    assert by_key["front_axle_load"]["code"] == "front_axle_load"
    assert by_key["front_axle_load"]["words"].startswith("front axle load 18 % of the tractor's weight")
    assert msg["highlight"] == ["implement"]
    assert msg["front_axle_of_tractor_weight"] == pytest.approx(0.2 * 7500 / 6000)


# ---------------------------------------------------------------------------------------------- the stream
class _WS:
    def __init__(self, web):
        host, port = web.address
        self.sock = socket.create_connection((host, port), timeout=5)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            (
                f"GET /ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
            ).encode()
        )
        self.buf = b""
        while b"\r\n\r\n" not in self.buf:
            self.buf += self.sock.recv(4096)
        self.buf = self.buf.partition(b"\r\n\r\n")[2]

    def messages(self, duration_s: float) -> list[dict]:
        out, deadline = [], time.monotonic() + duration_s
        self.sock.settimeout(0.05)
        while time.monotonic() < deadline:
            got = decode_frame(self.buf, require_mask=False, max_bytes=1 << 22)
            if got is not None:
                frame, used = got
                self.buf = self.buf[used:]
                if frame.opcode == OP_TEXT:
                    out.append(json.loads(frame.payload))
                elif frame.opcode == OP_CLOSE:
                    break
                continue
            try:
                chunk = self.sock.recv(65536)
            except TimeoutError:
                continue
            if not chunk:
                break
            self.buf += chunk
        return out

    def close(self):
        try:
            self.sock.sendall(encode_frame(OP_CLOSE, b"\x03\xe8", mask=os.urandom(4)))
        finally:
            self.sock.close()


def _feed(web, model, stop: threading.Event, states: dict, period_s: float = 0.01) -> threading.Thread:
    def run() -> None:
        seq = 0
        while not stop.wait(period_s):
            seq += 1
            q = model.neutral + 0.002 * np.sin(seq / 7.0) * (model.upper - model.lower)
            states[seq] = q
            web.publish_state(_state(seq, q, model.neutral))

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_view_stream_is_rate_bounded_and_only_while_a_page_is_connected(view, model):
    web = WebServer(lambda n, b, u, **_: (True, {}), WebSettings(port=0), view=view).start()
    stop, states = threading.Event(), {}
    feeder = _feed(web, model, stop, states)
    try:
        time.sleep(0.5)
        assert web.counts["state"] > 10 and web.counts["views"] == 0  # nobody looks: nothing computed
        ws = _WS(web)
        try:
            msgs = ws.messages(1.5)
        finally:
            ws.close()
        kinds = [m["type"] for m in msgs]
        assert kinds[0] == "hello" and kinds.count("terminal") == 1
        views = [m["data"] for m in msgs if m["type"] == "view"]
        assert kinds.count("state") > 2 * len(views)  # the states are not slowed down to the picture's rate
        assert 5 <= len(views) <= VIEW_RATE_HZ * 1.5 + 3, len(views)
        for v in views[-3:]:  # the numbers are the model's for that state's actuators
            _check_points(v["measured"], model, states[v["seq"]])
            _check_points(v["reference"], model, model.neutral)
    finally:
        stop.set()
        feeder.join(2)
        web.close()


def _get(web, path: str) -> tuple[int, dict]:
    import http.client

    host, port = web.address
    conn = http.client.HTTPConnection(host, port, timeout=10)
    conn.request("GET", path)
    r = conn.getresponse()
    data = json.loads(r.read())
    conn.close()
    return r.status, data


def test_api_view_is_built_lazily_and_answers_the_latest_state(view, model):
    release = threading.Event()
    calls = []

    def factory() -> HitchView:
        calls.append(1)
        assert release.wait(10)
        return view

    web = WebServer(lambda n, b, u, **_: (True, {}), WebSettings(port=0), view=factory).start()
    try:
        assert calls == []  # nothing built before it is needed
        status, reply = _get(web, "/api/view")
        assert status == 503 and "being built" in reply["message"]
        release.set()
        deadline = time.monotonic() + 10
        while _get(web, "/api/terminal")[0] != 200 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert _get(web, "/api/terminal")[1]["words"]["stroke:top:max"] == "top link at its stroke end (longest)"
        assert _get(web, "/api/view")[0] == 503  # no state yet
        q = model.neutral + 0.01 * (model.upper - model.lower)
        web.publish_state(_state(7, q))
        deadline = time.monotonic() + 5
        while web.counts["state"] == 0 and time.monotonic() < deadline:
            time.sleep(0.01)
        status, msg = _get(web, "/api/view")
        assert status == 200 and msg["seq"] == 7
        _check_points(msg["measured"], model, q)
        assert len(calls) == 1
    finally:
        release.set()
        web.close()


def test_without_a_model_there_is_no_picture():
    web = WebServer(lambda n, b, u, **_: (True, {}), WebSettings(port=0)).start()
    try:
        assert _get(web, "/api/view")[0] == 404
    finally:
        web.close()


def test_a_limit_flagged_on_a_track_dof_and_its_guard_reason_are_one_entry_on_the_page(view, model):
    """The page said the lowering limit twice ("vertical speed: implement lowering speed limit" and the guard's
    "implement lowering speed limit: speed: … would be 0.06001 m/s …"), as the CLI did."""
    state = _state(3, model.neutral)
    state["limited"] = {
        "vz": "implement lowering speed limit",
        "implement lowering speed limit": "speed: implement lowering speed limit would be 0.06001 m/s "
        "(threshold 0.05 m/s) at t = 0.00 s",
    }
    entries = view.message(state)["limited"]
    assert [e["key"] for e in entries] == ["vz"], entries
    assert entries[0]["words"] == "lowering faster than the implement allows: 0.060 m/s (limit 0.050 m/s): slowed"


def test_the_terminal_has_words_for_the_implement_s_own_limits(view):
    """A trial: with an upper height the page's *Check* said "slowed to 49 %: implement lowering speed limit" and
    the limit codes of the implement had no words in the terminal's table, as every other code has."""
    from bridge.web.wording import IMPLEMENT_WORDS

    table = view.terminal()["words"]
    for code, said in IMPLEMENT_WORDS.items():
        assert table.get(code) == said, code


def test_attach_mode_s_quarter_speed_has_words():
    """The state names attach mode's cap on a jog (``{"z+": "mode:attach"}``); the terminal says it in words (it
    showed nothing before: a terminal trial), and the code is among the hitch's limit codes."""
    from bridge.web.wording import limited_words

    assert limited_words("z+", "mode:attach") == "attach mode: a quarter of full speed"
    assert "mode:attach" in limit_codes(HitchModel.from_profile("thesis-t132", "2"))
