"""``hitch ecu-sim`` / ``hitch can-hub`` as a new user met them: ecu-sim on ``--interface remote`` without a hub
(the error must say to start ``hitch can-hub --port P`` first), its closing summary (printed as a Python dict)
and its status line's unlabelled ``valves 0 -132 0 0 0``; can-hub's banner naming the next steps in order.

The expected texts are written by hand (ports 18500-18549 on 127.0.0.1 only)."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
import uuid
from types import SimpleNamespace

import pytest

import bridge.cli.sim as cli_sim
from bridge.cli.main import main
from bridge.link.loopback import LoopbackHub

#: nothing listens here during the test (a port of this test's range not bound by any other of its tests)
_NO_HUB_PORT = 18541
_HUB_PORT = 18542
_HUB_CLI_PORT = 18543


def test_ecu_sim_remote_without_a_hub_says_to_start_can_hub_on_that_port_first(capsys):
    url = f"ws://127.0.0.1:{_NO_HUB_PORT}/"
    rc = main(["ecu-sim", "--interface", "remote", "--channel", url, "--duration", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert err[0].startswith(f"hitch: error: cannot open remote channel '{url}': no CAN hub runs there"), err
    assert f"start `hitch can-hub --port {_NO_HUB_PORT}` first" in err[0], err
    assert f"then ecu-sim with --channel {url}" in err[0], err


def test_ecu_sim_status_line_names_each_valve_command_and_its_scale():
    node = SimpleNamespace(
        counters=SimpleNamespace(references=3, frames_tx=40, malformed=0), claim_state=SimpleNamespace(value="claimed")
    )
    ecu = SimpleNamespace(valve_commands=lambda: [0, -132, 0, 0, 254])
    line = cli_sim._ecu_status_line(2.0, node, ecu)
    assert line == (
        "t=    2.0 s  claimed  refs 3  tx 40  malformed 0  "
        "valve commands [±254 = full]: lift 0  tilt -132  top 0  left 0  right 254"
    )


def test_ecu_sim_summary_is_labelled_text_not_a_python_dict(capsys):
    argv = ["ecu-sim", "--interface", "virtual", "--channel", f"t-{uuid.uuid4().hex}", "--duration", "0.3"]
    assert main(argv) == 0
    out = capsys.readouterr().out.strip().splitlines()
    assert not any(line.lstrip().startswith("{") or "'interface'" in line for line in out), out
    assert len(out) == 3, out
    assert re.fullmatch(
        r"ecu-sim ran \d+\.\d{3} s on interface virtual; address claim: claimed; watchdog trips: 0", out[0]
    ), out
    assert out[1].startswith("frames: received 0, sent ") and ", references 0, " in out[1], out
    assert out[1].endswith(", send errors 0, ECU restarts 0"), out
    assert re.fullmatch(r"measurement \[AD counts\]: lift \d+, tilt \d+, top \d+, left \d+, right \d+", out[2]), out
    # --json: the same summary as JSON, nothing else on stdout
    assert main([*argv, "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["interface"] == "virtual" and doc["claim"] == "claimed"


def test_ecu_sim_joins_a_running_hub_and_prints_its_summary(capsys):
    with LoopbackHub(_HUB_PORT) as hub:
        assert hub.url == f"ws://127.0.0.1:{_HUB_PORT}/"
        rc = main(["ecu-sim", "--interface", "remote", "--channel", hub.url, "--duration", "0.5"])
    out = capsys.readouterr().out
    assert rc == 0
    assert out.startswith("ecu-sim ran ") and "on interface remote; address claim: claimed" in out, out


@pytest.mark.slow
def test_can_hub_says_where_it_listens_and_what_to_start_next_in_order():
    proc = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "can-hub", "--port", str(_HUB_CLI_PORT)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        first = proc.stderr.readline()
    finally:
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=15)
    url = f"ws://127.0.0.1:{_HUB_CLI_PORT}/"
    assert first.startswith(f"CAN hub on {url} "), first
    ecu = f"hitch ecu-sim --interface remote --channel {url}"
    serve = f"hitch serve --can-interface remote --can-channel {url} --no-sim-ecu"
    assert ecu in first and serve in first and first.index(ecu) < first.index(serve), first
