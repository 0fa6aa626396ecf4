"""The twin's fault injector: settings and their errors, what each fault does to frames in each
direction (on a virtual bus, simulated clock), run-time changes from another thread, the CLI."""

import threading
import time
import uuid

import can
import pytest

from bridge.cli.main import main
from bridge.sim import CylinderECU, EcuCanNode
from bridge.sim.fault_injector import FaultError, FaultInjector, FaultSettings
from planner.errors import HitchInputError


@pytest.fixture
def pair():
    channel = f"fault-{uuid.uuid4().hex}"
    ecu_side, planner = (can.Bus(interface="virtual", channel=channel) for _ in range(2))
    clock = {"t": 0.0}
    inj = FaultInjector(ecu_side, clock=lambda: clock["t"], seed=3)
    yield inj, planner, clock
    inj.shutdown()
    ecu_side.shutdown()
    planner.shutdown()


def frame(i: int) -> can.Message:
    return can.Message(arbitration_id=0x0CFF21A6, data=bytes([i % 256] * 8), is_extended_id=True)


def drain(bus):
    out = []
    while (f := bus.recv(timeout=0.0)) is not None:
        out.append(f.data[0])
    return out


@pytest.mark.parametrize(
    "kwargs, field, allowed",
    [
        ({"cut": "sideways"}, "cut", "none, planner_to_ecu, ecu_to_planner, both"),
        ({"cut": None}, "cut", "none"),
        ({"loss": -0.1}, "loss", "[0, 1]"),
        ({"loss": 1.5}, "loss", "[0, 1]"),
        ({"loss": float("nan")}, "loss", "[0, 1]"),
        ({"loss": True}, "loss", "[0, 1]"),
        ({"loss": "0.1"}, "loss", "[0, 1]"),
        ({"delay_ms": -1}, "delay_ms", "[0, 5000] ms"),
        ({"delay_ms": 5000.5}, "delay_ms", "[0, 5000] ms"),
        ({"delay_ms": float("inf")}, "delay_ms", "[0, 5000] ms"),
        ({"restart_ecu": "yes"}, "restart_ecu", "true or false"),
        ({"restart_ecu": 1}, "restart_ecu", "true or false"),
    ],
)
def test_bad_settings_name_the_field_and_the_allowed_range(kwargs, field, allowed):
    with pytest.raises(FaultError) as err:
        FaultSettings(**kwargs)
    assert str(err.value).startswith(field) and allowed in str(err.value)
    assert isinstance(err.value, HitchInputError) and isinstance(err.value, ValueError)
    with pytest.raises(FaultError, match=field):
        FaultSettings.from_mapping(kwargs)


def test_settings_from_and_to_json():
    s = FaultSettings.from_mapping({"cut": "both", "loss": 1, "delay_ms": 5000, "restart_ecu": True})
    assert s == FaultSettings("both", 1.0, 5000.0, True)
    assert s.to_json() == {"cut": "both", "loss": 1.0, "delay_ms": 5000.0, "restart_ecu": True}
    assert FaultSettings.from_mapping({}) == FaultSettings()
    with pytest.raises(FaultError, match=r"unknown fault setting\(s\) \['delay'\]"):
        FaultSettings.from_mapping({"delay": 10})
    with pytest.raises(FaultError, match="must be an object"):
        FaultSettings.from_mapping(["cut"])  # type: ignore[arg-type]
    node = EcuCanNode(CylinderECU(), can.Bus(interface="virtual", channel=uuid.uuid4().hex))
    with pytest.raises(FaultError, match="loss"):
        node.apply_fault({"loss": 2})
    assert node.fault_settings == FaultSettings()  # a refused setting changes nothing
    node.bus.inner.shutdown()


def test_no_fault_passes_every_frame_at_once_both_ways(pair):
    inj, planner, _ = pair
    for i in range(5):
        planner.send(frame(i))
        inj.send(frame(10 + i))
    assert drain(inj) == [0, 1, 2, 3, 4] and drain(planner) == [10, 11, 12, 13, 14]
    assert inj.counters.as_dict() == {
        "rx_passed": 5,
        "rx_dropped": 0,
        "rx_delayed": 0,
        "tx_passed": 5,
        "tx_dropped": 0,
        "tx_delayed": 0,
    }


@pytest.mark.parametrize(
    "cut, rx_ok, tx_ok",
    [("planner_to_ecu", False, True), ("ecu_to_planner", True, False), ("both", False, False), ("none", True, True)],
)
def test_each_cut_drops_its_direction_only(pair, cut, rx_ok, tx_ok):
    inj, planner, _ = pair
    inj.apply(FaultSettings(cut=cut))
    planner.send(frame(1))
    inj.send(frame(2))
    assert drain(inj) == ([1] if rx_ok else [])
    assert drain(planner) == ([2] if tx_ok else [])


def test_loss_is_a_seeded_fraction_each_way(pair):
    inj, planner, _ = pair
    inj.apply(FaultSettings(loss=0.2))
    n = 2000
    for i in range(n):
        planner.send(frame(i))
        inj.send(frame(i))
        if i % 100 == 99:
            drain(inj)
            drain(planner)
    c = inj.counters
    assert 0.16 < c.rx_dropped / n < 0.24 and 0.16 < c.tx_dropped / n < 0.24
    assert c.rx_dropped + c.rx_passed == n and c.tx_dropped + c.tx_passed == n
    inj.apply(FaultSettings(loss=1.0))
    planner.send(frame(1))
    inj.send(frame(1))
    assert drain(inj) == [] and drain(planner) == []


def test_delay_holds_frames_in_order_on_the_given_clock(pair):
    inj, planner, clock = pair
    inj.apply(FaultSettings(delay_ms=400))
    for i in range(3):
        clock["t"] = 0.1 * i
        planner.send(frame(i))
        inj.send(frame(10 + i))
        assert drain(inj) == []  # read from the bus and held
    inj.flush()
    assert drain(planner) == []
    clock["t"] = 0.4
    inj.flush()
    assert drain(inj) == [0] and drain(planner) == [10]
    clock["t"] = 0.55
    inj.flush()
    assert drain(inj) == [1] and drain(planner) == [11]
    # a cut set while frames are held catches them when they leave
    inj.apply(FaultSettings(cut="both", delay_ms=400))
    clock["t"] = 1.0
    inj.flush()
    assert drain(inj) == [] and drain(planner) == []
    # delay off: what is still held is due at once, new frames pass at once
    inj.apply(FaultSettings(delay_ms=400))
    planner.send(frame(7))
    assert drain(inj) == []
    inj.apply(FaultSettings())
    planner.send(frame(8))
    assert drain(inj) == [7, 8]
    assert inj.counters.rx_delayed == 4 and inj.counters.tx_delayed == 3


def test_real_time_delay_and_settings_changed_from_another_thread():
    channel = f"fault-{uuid.uuid4().hex}"
    inner, planner = (can.Bus(interface="virtual", channel=channel) for _ in range(2))
    inj = FaultInjector(inner)  # time.monotonic
    try:
        inj.apply(FaultSettings(delay_ms=150))
        t0 = time.monotonic()
        planner.send(frame(1))
        got = inj.recv(timeout=5.0)  # blocks until the held frame is due
        assert got is not None and got.data[0] == 1 and time.monotonic() - t0 >= 0.149
        stop = threading.Event()

        def toggle():
            while not stop.is_set():
                for s in (FaultSettings(cut="both"), FaultSettings(loss=0.5), FaultSettings()):
                    inj.apply(s)

        th = threading.Thread(target=toggle)
        th.start()
        try:
            for i in range(300):
                planner.send(frame(i))
                inj.send(frame(i))
                inj.recv(timeout=0.0)
        finally:
            stop.set()
            th.join(5.0)
        inj.apply(FaultSettings())
        while inj.recv(timeout=0.05) is not None:
            pass
        c = inj.counters
        assert c.rx_passed + c.rx_dropped == 301 and c.tx_passed + c.tx_dropped == 300
    finally:
        inj.shutdown()
        inner.shutdown()
        planner.shutdown()


def test_cli_sim_fault_refuses_bad_settings_before_connecting(capsys):
    assert main(["sim", "fault", "--loss", "1.5"]) != 0
    assert "--loss must lie in [0, 1]" in capsys.readouterr().err  # the option, named
    assert main(["sim", "fault", "--cut", "sideways"]) != 0
    assert "--cut" in capsys.readouterr().err


def test_cli_sim_fault_sends_the_four_keys_to_the_service_key(capsys):
    """A stand-in service on loopback answers ``hitch/sim/fault`` with what it received."""
    import json

    import zenoh

    from tests.integration.service_process import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps([endpoint]))
    c.insert_json5("scouting/multicast/enabled", "false")
    received = []

    def answer(q):
        body = json.loads(q.payload.to_bytes()) if q.payload is not None else None
        received.append(body)
        q.reply(q.key_expr, json.dumps({"applied": body}))

    session = zenoh.open(c)
    try:
        queryable = session.declare_queryable("hitch/sim/fault", answer)
        argv = ["sim", "fault", "--cut", "planner_to_ecu", "--loss", "0.05", "--delay-ms", "40", "--restart-ecu"]
        assert main([*argv, "--connect", endpoint, "--json", "--timeout", "10"]) == 0
        json_out = capsys.readouterr().out
        assert main([*argv, "--connect", endpoint, "--timeout", "10"]) == 0  # text without --json
        queryable.undeclare()
    finally:
        session.close()
    sent = {"cut": "planner_to_ecu", "loss": 0.05, "delay_ms": 40.0, "restart_ecu": True}
    assert received == [sent, sent]
    assert json.loads(json_out.strip().splitlines()[-1]) == {"applied": sent}
    assert capsys.readouterr().out.strip().splitlines()[-1] == (
        "twin fault injection: link cut: planner → ECU, frame loss 5 %, delay 40 ms, ECU restarted"
    )
