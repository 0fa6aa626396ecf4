"""The operator's rear hitch raise / lower switch: ISO 11783-7 PGN 65090 through the codec (bytes as the
standard lays them out), the edges the link node turns into commands, and the round trip through a
service with the core in its threads (a frame sent on the CAN bus raises the hitch to the headland pose
and a lower edge returns it to the work pose) and with the core in its own process (the default: the
simulated tractor in the core sends the press, ``sim/switch``)."""

from __future__ import annotations

import json
import time
import uuid

import can
import pytest

from bridge.isobus.codec import decode_frame, encode
from bridge.isobus.j1939 import decode_id
from bridge.isobus.messages import OPERATOR_SWITCH_ADDRESS, PGN_HITCH_PTO_COMMANDS, CodecError, HitchCommand
from bridge.link.hitch_switch import (
    MAX_EDGE_AGE_S,
    HitchSwitchNode,
    SwitchEdges,
    press_frames,
    press_switch,
    switch_frame,
    switch_position,
)
from tests.helpers import wait_until


def test_the_switch_frame_is_pgn_65090_with_the_rear_hitch_command_in_byte_2():
    msg = switch_frame("raise")
    ident = decode_id(msg.arbitration_id)
    assert ident.pgn == PGN_HITCH_PTO_COMMANDS == 0xFE42 and ident.source_address == OPERATOR_SWITCH_ADDRESS
    assert ident.priority == 3
    assert bytes(msg.data) == bytes([0xFF, 250, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF])  # 100 % = 250 × 0.4 %
    assert bytes(switch_frame("lower").data)[1] == 0 and bytes(switch_frame("released").data)[1] == 0xFF
    d = decode_frame(switch_frame("released"))
    assert d.payload == HitchCommand(None) and d.unavailable == ("RearHitchPositionCommand",)
    assert decode_frame(encode(HitchCommand(0.5))).payload.rear_position == pytest.approx(0.5)
    with pytest.raises(CodecError):
        switch_frame("up")  # type: ignore[arg-type]


def test_positions_and_edges():
    assert [switch_position(v) for v in (1.0, 0.9, 0.5, 0.1, 0.0, None)] == [
        "raise",
        "raise",
        "released",
        "lower",
        "lower",
        "released",
    ]
    e = SwitchEdges()
    seq = ["lower", "lower", "raise", "raise", "released", "raise", "lower", "released", "lower"]
    assert [e.update(p) for p in seq] == [None, None, "raise", None, None, "raise", "return", None, "return"]


def test_the_node_decodes_frames_and_ignores_other_senders():
    got: list[str] = []
    node = HitchSwitchNode(can.Bus(interface="virtual", channel=f"sw-{uuid.uuid4().hex}"), got.append)
    try:
        assert node.take(switch_frame("released"), 0.0) is None  # the first frame sets the position
        assert node.take(switch_frame("raise", source=0x30), 0.1) is None  # another sender: not the switch
        assert node.take(switch_frame("raise"), 0.2) == "raise"
        assert node.take(switch_frame("raise"), 0.3) is None  # held: nothing repeated
        assert node.take(switch_frame("lower"), 0.4) == "return"
        assert node.take(can.Message(arbitration_id=0x123, is_extended_id=False, data=b"\0"), 0.5) is None
        assert got == ["raise", "return"] and node.commands == 2
    finally:
        node.bus.shutdown()


def test_an_edge_read_long_after_its_frame_was_stamped_gives_no_command():
    """A safety trial: the service stalled 2 s (SIGSTOP) while the operator pressed "lower"; when it ran again
    it read the waiting frames, returned the hitch and resumed the paused work. An edge whose frame's bus
    stamp is older than MAX_EDGE_AGE_S when it is read gives no command now; ``on_stale`` hears of it, and
    the position is taken (holding the switch later repeats nothing)."""
    channel = f"stale-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    got: list[str] = []
    stale: list[tuple[str, float]] = []
    node = HitchSwitchNode(can.Bus(interface="virtual", channel=channel), got.append)
    node.on_stale = lambda cmd, age: stale.append((cmd, age))
    try:
        press_switch(bus, "lower")
        time.sleep(MAX_EDGE_AGE_S + 0.2)  # the service stalls; the frames wait on the bus
        node.poll(0.0)
        assert got == [] and node.commands == 0 and node.stale == 1
        assert [c for c, _ in stale] == ["return"] and stale[0][1] > MAX_EDGE_AGE_S
        press_switch(bus, "raise")  # a fresh press is taken at once
        node.poll(1.0)
        assert got == ["raise"] and node.commands == 1
    finally:
        bus.shutdown()
        node.bus.shutdown()


def test_a_stale_edge_is_announced_by_the_service_as_ignored():
    """The machine as the service builds it: a switch edge read 2 s after its frame was stamped is the event
    ``hitch_switch_ignored`` (the black box and the terminal say why the press did nothing), no ``hitch_switch``."""
    from tests.helpers import running_machine

    with running_machine("switch-stale") as (_, parts, _mc, events):
        assert parts.switch is not None
        old = switch_frame("lower")
        old.timestamp = time.time() - 2.0  # stamped 2 s ago: it waited while the service stalled
        parts.switch.take(switch_frame("released"), 0.0)
        parts.switch.take(old, 0.0)
        assert wait_until(lambda: any(e.get("event") == "hitch_switch_ignored" for e in events), 5.0), events
        e = next(e for e in events if e.get("event") == "hitch_switch_ignored")
        assert e["command"] == "return" and e["age_s"] >= 1.9 and "not acted on" in e["message"], e
        assert not any(e.get("event") == "hitch_switch" for e in events)


def test_a_press_gives_exactly_one_edge_whatever_the_switch_did_before():
    assert [bytes(f.data)[1] for f in press_frames("raise")] == [0xFF, 250, 0xFF]
    assert [bytes(f.data)[1] for f in press_frames("released")] == [0xFF]
    with pytest.raises(CodecError):
        press_frames("up")  # type: ignore[arg-type]
    for before in (None, "raise", "lower", "released"):
        for position, command in (("raise", "raise"), ("lower", "return"), ("released", None)):
            edges = SwitchEdges()
            if before is not None:
                edges.update(before)  # type: ignore[arg-type]
            got = [c for f in press_frames(position) if (c := edges.update(switch_position(_rear(f)))) is not None]
            assert got == ([] if command is None else [command]), (before, position)
    channel = f"press-{uuid.uuid4().hex}"
    bus = can.Bus(interface="virtual", channel=channel)
    node = HitchSwitchNode(can.Bus(interface="virtual", channel=channel))
    try:
        assert press_switch(bus, "lower") == ["released", "lower", "released"]
        node.poll(0.0)
        assert node.frames == 3 and node.commands == 1
    finally:
        bus.shutdown()
        node.bus.shutdown()


@pytest.mark.parametrize(("position", "command"), [("raise", "raise"), ("lower", "return"), ("released", None)])
def test_hitch_switch_on_the_bus_is_one_press_that_a_fresh_node_takes(position, command, capsys):
    """``hitch switch POSITION`` (no ``--service``) sends one momentary press, so a switch node that has
    seen no frame yet (a service just started) still gets exactly one command. Fails on the old code
    (it sent the position then released: the first frame only set the position, no command)."""
    from bridge.cli.main import main

    channel = f"cli-{uuid.uuid4().hex}"
    node = HitchSwitchNode(can.Bus(interface="virtual", channel=channel))
    try:
        assert main(["switch", position, "--interface", "virtual", "--channel", channel]) == 0
        assert f"sent {position}" in capsys.readouterr().out
        got: list[str] = []
        node.on_command = got.append
        node.poll(0.0)
        assert got == ([] if command is None else [command]) and node.frames == len(press_frames(position))
    finally:
        node.bus.shutdown()


def _rear(frame: can.Message) -> float | None:
    payload = decode_frame(frame).payload
    assert isinstance(payload, HitchCommand)
    return payload.rear_position


@pytest.mark.slow
def test_a_switch_on_the_can_bus_raises_and_returns_the_hitch(tmp_path):
    from bridge.service.config import ServiceConfig
    from bridge.service.server import HitchService
    from tests.integration.service_process import free_port

    channel = f"hitch-{uuid.uuid4().hex}"
    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{free_port()}"],
        data_dir=tmp_path,
        planning_processes=0,
        control_core="thread",
        can_channel=channel,
    )
    svc = HitchService(cfg).start()
    switch = can.Bus(interface="virtual", channel=channel)
    events: list[dict] = []
    try:
        svc.add_listener("event", events.append)

        def call(key, payload=None):
            ok, r = svc.api.handle(key, json.dumps(payload or {}))
            assert ok, (key, r)
            return r

        def z_now():
            return ((svc.latest_state or {}).get("pose") or {}).get("z")

        def at_rest(z):
            st = svc.latest_state or {}
            return st.get("motion") is None and z_now() is not None and abs(z_now() - z) < 3e-3

        assert wait_until(lambda: z_now() is not None)
        call("implements/define", {"name": "harrow", "category": "2", "mass_kg": 800.0, "com_m": [0.0, 0.6, 0.3]})
        call("implements/select", {"name": "harrow"})
        call("presets/save", {"name": "headland", "pose": {"x": 0.0, "z": 0.24, "roll": 0.0, "pitch": 0.0}})
        assert wait_until(lambda: svc.api.handle("goto", json.dumps({"goal": {"z": -0.05}}))[0])  # once the link is up
        assert wait_until(lambda: at_rest(-0.05))
        switch.send(switch_frame("released"))
        time.sleep(0.1)
        switch.send(switch_frame("raise"))
        assert wait_until(lambda: at_rest(0.24)), "the switch did not raise the hitch"
        assert any(e.get("event") == "hitch_switch" and e.get("command") == "raise" for e in events)
        switch.send(switch_frame("lower"))
        node = svc.parts.switch
        assert wait_until(lambda: at_rest(-0.05)), (  # a string: pytest shortens a tuple's repr (CI, 7c1e287)
            "the switch did not return the hitch to work\n"
            f"switch log: {list(svc.api.implements.switch_log)}\n"
            f"switch node: frames {node.frames}, commands {node.commands}, position {node.edges.position}\n"
            f"events: {[e for e in events if e.get('event') != 'state'][-8:]}\n"
            f"state: { {k: (svc.latest_state or {}).get(k) for k in ('motion', 'pose', 'ecu')} }"
        )
    finally:
        switch.shutdown()
        svc.close()


@pytest.mark.slow
def test_the_switch_raises_and_returns_with_the_core_in_its_own_process(tmp_path):
    """The default mode: the switch node runs in the core process; ``sim/switch`` makes the core's simulated
    tractor send the press on the core's bus, the node's event reaches the service over Zenoh, and the
    service raises / returns."""
    from bridge.service.config import ServiceConfig
    from bridge.service.server import HitchService
    from tests.integration.service_process import free_port

    cfg = ServiceConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], data_dir=tmp_path, planning_processes=0)
    svc = HitchService(cfg).start()
    events: list[dict] = []
    try:
        assert svc.core is not None  # the core has its own process
        svc.add_listener("event", events.append)

        def call(key, payload=None):
            ok, r = svc.api.handle(key, json.dumps(payload or {}))
            assert ok, (key, r)
            return r

        def z_now():
            return ((svc.latest_state or {}).get("pose") or {}).get("z")

        def at_rest(z):
            st = svc.latest_state or {}
            return st.get("motion") is None and z_now() is not None and abs(z_now() - z) < 3e-3

        assert wait_until(lambda: z_now() is not None)
        ok, r = svc.api.handle("sim/switch", json.dumps({"position": "up"}))
        assert not ok and r["error"] == "bad_request" and "position" in r["message"], r
        call("implements/define", {"name": "harrow", "category": "2", "mass_kg": 800.0, "com_m": [0.0, 0.6, 0.3]})
        call("implements/select", {"name": "harrow"})
        call("presets/save", {"name": "headland", "pose": {"x": 0.0, "z": 0.24, "roll": 0.0, "pitch": 0.0}})
        assert wait_until(lambda: svc.api.handle("goto", json.dumps({"goal": {"z": -0.05}}))[0])  # once the link is up
        assert wait_until(lambda: at_rest(-0.05))
        assert call("sim/switch", {"position": "raise"})["sent"] == ["released", "raise", "released"]
        assert wait_until(lambda: at_rest(0.24)), "the switch did not raise the hitch"
        assert any(e.get("event") == "hitch_switch" and e.get("command") == "raise" for e in events)
        call("sim/switch", {"position": "lower"})
        assert wait_until(lambda: at_rest(-0.05)), "the switch did not return the hitch to work"
        assert any(e.get("event") == "hitch_switch" and e.get("command") == "return" for e in events)
    finally:
        svc.close()
