"""The pure helpers of bench/reliability_bench.py and bench/_common.py (no service, fast)."""

from __future__ import annotations

import os
import socket

import numpy as np
import pytest

from bench._common import _ephemeral_low, _PortPicker, free_port, percentiles_ms, proc_cpu_seconds
from bench.reliability_bench import (
    MEASUREMENT_PGN,
    REFERENCE_PGN,
    WATCHDOG_BIT,
    max_displacement,
    outward_excess,
    period_figures,
    pgn_of,
    rising_edges,
    secured_files,
    still_time,
    stop_effect_time,
    stop_latency,
    verdict,
    window,
)


def test_pgn_of_the_hitch_frames_from_their_dbc_identifiers():
    # hitch.dbc: BO_ 2365530534 PositionReference (0xFF21 from 166), BO_ 2365530793 PositionMeasurement (0xFF22)
    assert pgn_of(2365530534 & 0x1FFFFFFF) == REFERENCE_PGN
    assert pgn_of(2365530793 & 0x1FFFFFFF) == MEASUREMENT_PGN
    assert pgn_of((6 << 26) | (0xEA << 16) | (0x80 << 8) | 0x26) == 0xEA00  # PDU1: the destination is not in the PGN


def test_percentiles_ms_and_periods():
    s = percentiles_ms([0.001, 0.002, 0.003])
    assert s == {"p50_ms": pytest.approx(2.0), "p99_ms": pytest.approx(2.98), "max_ms": pytest.approx(3.0), "n": 3}
    assert percentiles_ms([]) == {"p50_ms": None, "p99_ms": None, "max_ms": None, "n": 0}
    t = np.concatenate([np.arange(0, 1.0, 0.02), [1.07, 1.09]])  # one 70 ms gap, unsorted input is fine
    f = period_figures(list(np.random.default_rng(1).permutation(t)))
    assert f["n"] == t.size - 1 and f["max_ms"] == pytest.approx(90.0)
    assert (f["over_25_ms"], f["over_60_ms"], f["over_100_ms"]) == (1, 1, 0)
    assert f["p50_ms"] == pytest.approx(20.0)
    assert list(window([3.0, 1.0, 2.0, 5.0], 1.5, 3.0)) == [2.0, 3.0]


def test_watchdog_rising_edges_count_only_inside_the_window():
    samples = [(0.0, 0x03), (1.0, 0x01), (2.0, 0x03), (3.0, 0x03), (4.0, 0x01), (5.0, 0x03), (6.0, 0x01), (7.0, 0x03)]
    assert rising_edges(samples, WATCHDOG_BIT, 0.0, 10.0) == 3
    assert rising_edges(samples, WATCHDOG_BIT, 1.5, 5.5) == 2  # the clear sample before the window counts as previous
    assert rising_edges(samples, WATCHDOG_BIT, 2.5, 4.5) == 0


def test_stop_latency_takes_the_first_reference_after_the_earliest_report_of_the_stop():
    refs = [10.0 + 0.02 * k for k in range(100)]  # 50 Hz from t = 10 s
    t_cmd = 10.105
    states = [
        {"t": 10.100, "motion_id": 4, "motion": "goto"},  # before the command: ignored
        {"t": 10.1201, "motion_id": 4, "motion": "goto"},
        {"t": 10.1401, "motion_id": 5, "motion": "stop"},  # the state reports the stop
    ]
    events = [{"t": 10.1102, "event": "motion_started", "motion_id": 5, "kind": "stop"}]
    eff = stop_effect_time(t_cmd, 5, states, events)
    assert eff == pytest.approx(10.1102)  # the event came first
    assert stop_latency(t_cmd, eff, refs) == pytest.approx(10.12 - t_cmd)  # next reference after it
    assert stop_effect_time(t_cmd, 5, states, []) == pytest.approx(10.1401)
    assert stop_latency(t_cmd, 10.1401, refs) == pytest.approx(10.16 - t_cmd)
    # without a stop id the first state with motion "stop" is used; an effect before the command is clamped
    assert stop_effect_time(t_cmd, None, states, []) == pytest.approx(10.1401)
    assert stop_latency(t_cmd, 10.0, refs) == pytest.approx(10.12 - t_cmd)
    assert stop_effect_time(t_cmd, 9, states, events) is None and stop_latency(t_cmd, None, refs) is None
    assert stop_latency(t_cmd, 20.0, refs) is None  # no reference after it


def test_still_time_is_the_change_after_which_the_counts_rest():
    # braking ends at 0.06; the counts rest; the next command moves them again from 0.60: the rest
    # is at 0.06 (reading the window to its end gave 0.62, the next motion: the old mis-measurement)
    rest = [(0.06 + 0.02 * k, (3, 3)) for k in range(1, 27)]
    refs = [(0.0, (1, 2)), (0.02, (2, 2)), (0.04, (3, 2)), (0.06, (3, 3)), *rest, (0.60, (4, 3)), (0.62, (5, 3))]
    assert still_time(refs, 0.0, 1.0) == pytest.approx(0.06)
    assert still_time(refs, 0.07, 0.5) is None  # no change in the window
    assert still_time(refs[:6], 0.0, 1.0) is None  # the data ends before 0.3 s of rest: not known


def test_overshoot_displacement_and_verdict():
    assert outward_excess([0.29, 0.3125, 0.31], 0.3117, +1) == pytest.approx(0.0008)
    assert outward_excess([-0.20, -0.2170], -0.21627, -1) == pytest.approx(0.00073)
    assert outward_excess([0.1], 0.3, +1) == pytest.approx(-0.2) and outward_excess([], 0.3, 1) is None
    poses = [{"x": 0.0, "z": 0.1, "roll": 0.0, "pitch": 0.0}, {"x": 0.003, "z": 0.104, "roll": -0.002, "pitch": 0.001}]
    pos, ang = max_displacement(poses)
    assert (pos, ang) == (pytest.approx(0.005), pytest.approx(0.002))
    assert max_displacement([]) is None
    assert (verdict(25.0, 25.0), verdict(25.1, 25.0), verdict(None, 1.0)) == ("ok", "FAIL", "-")


def test_proc_cpu_seconds_grows_with_work():
    before = proc_cpu_seconds(os.getpid())
    x = 0
    for i in range(3_000_000):
        x += i
    assert proc_cpu_seconds(os.getpid()) > before


def test_free_ports_lie_below_the_ephemeral_range_are_distinct_and_bindable():
    """A port from bind(0) lies in the kernel's ephemeral range, where an outgoing connection can take
    it before the service binds it (a CI run failed so): test ports come from below that range, each
    once, so two asked for in a row never coincide."""
    low = _ephemeral_low()
    ports = [free_port() for _ in range(200)]
    assert len(set(ports)) == len(ports)
    assert all(1024 < p < low for p in ports), (min(ports), max(ports), low)
    with socket.socket() as s:
        s.bind(("127.0.0.1", ports[-1]))  # still free


def test_a_port_in_use_is_never_handed_out_and_none_twice():
    with socket.socket() as held:
        held.bind(("127.0.0.1", free_port()))
        held.listen()
        taken = held.getsockname()[1]
        picker = _PortPicker(taken, taken + 2)  # two ports: one in use, one free
        assert picker.pick() == taken + 1
        with pytest.raises(RuntimeError, match="no free loopback port"):
            picker.pick()  # the free one was handed out already


@pytest.mark.parametrize("kind", ["users", "certificates"])
def test_the_secured_benchs_files_are_ones_the_service_and_its_clients_accept(tmp_path, kind):
    from bridge.service.client import client_config
    from bridge.service.security import access_policy_from_file

    server, client, scheme = secured_files(str(tmp_path), kind)
    assert scheme == {"users": "tcp", "certificates": "tls"}[kind]
    policy = access_policy_from_file(server, "hitch")
    assert policy is not None and "operator" in policy.operators + policy.operator_cert_names
    client_config([f"{scheme}/127.0.0.1:7447"], security=client)  # Zenoh parses and takes it
    if kind == "certificates":  # the openssl-made chain verifies: the operator's certificate is the CA's
        import subprocess

        out = subprocess.run(
            ["openssl", "verify", "-CAfile", str(tmp_path / "ca.pem"), str(tmp_path / "operator.pem")],
            capture_output=True,
            text=True,
        )
        assert out.returncode == 0, out.stderr
