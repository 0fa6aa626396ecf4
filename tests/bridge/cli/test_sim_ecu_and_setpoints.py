"""``hitch ecu-sim`` when its CAN bus goes away and its status line; ``hitch sim field --draft-setpoint``'s range
and its hint for a value meant in kN."""

import errno
import threading
import uuid

import pytest

import bridge.cli.sim as cli_sim
from bridge.cli.main import main
from bridge.link.virtual import InProcessBus


class _HubGoneBus(InProcessBus):
    """A bus on a CAN hub that is killed once ``gone`` is set: reads and sends fail, and so does the shutdown (as
    python-can-remote's does on its dead socket: ``OSError`` [Errno 107])."""

    gone = threading.Event()

    def _recv_internal(self, timeout):
        if self.gone.is_set():
            raise ConnectionResetError(errno.ECONNRESET, "Connection reset by peer")
        return super()._recv_internal(timeout)

    def send(self, msg, timeout=None):
        if self.gone.is_set():
            raise BrokenPipeError(errno.EPIPE, "Broken pipe")
        super().send(msg, timeout)

    def shutdown(self):
        if self.gone.is_set():
            raise OSError(errno.ENOTCONN, "Transport endpoint is not connected")
        super().shutdown()


def test_ecu_sim_says_in_one_line_that_the_can_hub_went_away_and_exits_non_zero(monkeypatch, capsys):
    """Safety tester: ``hitch ecu-sim`` ended with an uncaught ``OSError: [Errno 107]`` traceback from
    ``bus.shutdown()`` when the CAN hub went away."""
    _HubGoneBus.gone.clear()
    monkeypatch.setattr(cli_sim, "open_bus", lambda interface, channel: _HubGoneBus(channel=channel))
    timer = threading.Timer(0.3, _HubGoneBus.gone.set)
    timer.start()
    try:
        rc = main(["ecu-sim", "--interface", "virtual", "--channel", uuid.uuid4().hex, "--duration", "5", "--json"])
    finally:
        timer.cancel()
        _HubGoneBus.gone.clear()
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith("hitch: error: ECU node stopped: the CAN bus"), err
    assert "Connection reset" in err[0] or "Broken pipe" in err[0] or "not connected" in err[0]


def test_ecu_sim_status_line_shows_the_valve_commands_as_plain_numbers(capsys):
    """The status line printed ``valves `` and nothing after it: numpy's repr in brackets was swallowed as rich
    markup."""
    rc = main(
        ["ecu-sim", "--interface", "virtual", "--channel", uuid.uuid4().hex, "--duration", "0.35"]
        + ["--status-every", "0.1"]
    )
    assert rc == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("t=")]
    want = "valve commands [±254 = full]: lift 0  tilt 0  top 0  left 0  right 0"
    assert lines and all(line.rstrip().endswith(want) for line in lines), lines


@pytest.mark.parametrize(
    "value, says",
    [
        ("20", "did you mean kN? 20 kN = 20000 N"),
        ("999.5", "did you mean kN? 999.5 kN = 999500 N"),
        ("0", "(0, 300000] N"),
        ("-5000", "(0, 300000] N"),
        ("300001", "(0, 300000] N"),
        ("nan", "finite"),
    ],
)
def test_sim_field_draft_setpoint_in_newtons_is_range_checked_with_a_kn_hint(capsys, value, says):
    """Safety tester: ``--draft-setpoint 20`` (newtons, easily mistaken for kN) was accepted silently."""
    rc = main(["sim", "field", "chisel", "--mode", "draft", "--draft-setpoint", value, "--duration", "20"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--draft-setpoint" in err[0] and says in err[0], err


def test_draft_setpoint_newtons_takes_working_drafts():
    assert cli_sim.draft_setpoint_newtons("1000") == 1000.0
    assert cli_sim.draft_setpoint_newtons("21000") == 21000.0
    assert cli_sim.draft_setpoint_newtons("300000") == 300000.0
