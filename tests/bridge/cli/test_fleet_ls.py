"""``hitch fleet ls`` against a stand-in client (no Zenoh): what it asks each live service and its exit status.

A fleet trial's report: for a viewer every row read ``no reply from fleet/t01/hitch/user/bob/mode: nothing
answered that key …`` and the command exited 0 anyway. It asked ``mode``, an operator's key, though the
``config`` reply (which any role that may read may ask) carries the mode. Now: the mode comes from ``config``
and the ``mode`` key is never asked; a service that does not answer is shown as such, and the exit status is 0
when every listed service answered, 1 when some did not, 2 when none did.

Truth: the replies and errors the stand-in gives (the keys it was asked are recorded).
"""

from __future__ import annotations

import json

import pytest

from bridge.cli import service as cli_service
from bridge.cli.main import main
from bridge.service.client import ClientError, ServiceError, ServiceTimeout

CONFIG = {"profile": "thesis-t132", "category": "2", "implement": None, "mode": "manual", "user_keys": True}
#: a state message's parts fleet ls reads (bridge.service.state_message), of a service at rest with its ECU online
AT_REST = {"ecu": {"online": True, "faults": [], "ack_required": []}, "moving": False, "motion": None, "seq": 7}


class _Fleet:
    """A stand-in HitchClient for ``fleet ls``: ``services`` maps each live prefix to its config reply or the
    error its config raises; the ``mode`` key (an operator's) never answers, as for a viewer."""

    def __init__(self, services: dict[str, dict | ServiceError], states: dict[str, dict] | None = None):
        self.services = services
        self.states = {p: AT_REST for p in services} if states is None else states
        self.asked: list[tuple[str, str | None]] = []
        self.unsubscribable: set[str] = set()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def fleet(self, *, timeout_s: float = 2.0, under: str | None = None) -> list[str]:
        return sorted(p for p in self.services if under is None or f"{p}/".startswith(f"{under}/"))

    def request(self, key, payload=None, *, prefix=None, timeout_s=None):
        self.asked.append((key, prefix))
        if key == "mode":
            raise ServiceTimeout(f"no reply from {prefix}/user/bob/mode: nothing answered that key (0.01 s)")
        if key != "config":
            raise AssertionError(f"fleet ls asked {key}")
        got = self.services[prefix]
        if isinstance(got, ServiceError):
            raise got
        return dict(got)

    def config(self, prefix=None):
        return self.request("config", {}, prefix=prefix)

    def subscribe(self, what, callback, *, prefix=None):
        assert what == "state", what
        if prefix in self.unsubscribable:  # a token whose key this client cannot subscribe to
            raise ClientError(f"prefix {prefix!r}: not a key prefix")
        if prefix in self.states:  # its control core publishes: the first sample comes at once
            callback(self.states[prefix])
        return _Closed()


class _Closed:
    def close(self):
        pass


def _run(monkeypatch, capsys, services, *flags, states=None):
    client = _Fleet(services, states)
    monkeypatch.setattr(cli_service, "_client", lambda args: client)
    code = main(["fleet", "ls", *flags])
    out = capsys.readouterr()
    return code, out.out, out.err, client.asked


def test_the_mode_comes_from_the_config_any_reader_may_ask(monkeypatch, capsys):
    services: dict = {"fleet/t01/hitch": CONFIG, "fleet/t02/hitch": {**CONFIG, "mode": "auto"}}
    code, out, err, asked = _run(monkeypatch, capsys, services, "--json")
    assert code == 0, err
    rows = json.loads(out)["fleet"]
    assert [(r["prefix"], r["mode"], r["profile"]) for r in rows] == [
        ("fleet/t01/hitch", "manual", "thesis-t132"),
        ("fleet/t02/hitch", "auto", "thesis-t132"),
    ]
    assert all("error" not in r for r in rows)
    assert asked == [("config", "fleet/t01/hitch"), ("config", "fleet/t02/hitch")]  # never the operators' mode key
    code, out, err, _ = _run(monkeypatch, capsys, services)
    assert code == 0 and err == ""
    assert out.splitlines() == [
        "fleet/t01/hitch: thesis-t132 cat 2, implement -, mode manual; ECU online, at rest",
        "fleet/t02/hitch: thesis-t132 cat 2, implement -, mode auto; ECU online, at rest",
    ]


@pytest.mark.parametrize("json_out", [False, True], ids=["text", "json"])
def test_a_service_that_does_not_answer_is_shown_and_sets_the_exit_status(monkeypatch, capsys, json_out):
    silent = ServiceTimeout("no reply from fleet/t02/hitch/config: nothing answered that key (0.01 s)")
    flags = ["--json"] if json_out else []
    # some answered: 1; the one that did not is shown as such
    code, out, err, _ = _run(monkeypatch, capsys, {"fleet/t01/hitch": CONFIG, "fleet/t02/hitch": silent}, *flags)
    assert code == 1
    if json_out:
        rows = json.loads(out)["fleet"]
        assert rows[0]["mode"] == "manual" and "error" not in rows[0]
        assert rows[1] == {"prefix": "fleet/t02/hitch", "code": "timeout", "error": str(silent), "state": STATE_JSON}
    else:
        assert out.splitlines() == [
            "fleet/t01/hitch: thesis-t132 cat 2, implement -, mode manual; ECU online, at rest",
            f"fleet/t02/hitch: NO ANSWER: {silent}; ECU online, at rest",
        ]
        assert "1 of 2 services gave no configuration: fleet/t02/hitch" in err
    # none answered (one silent, one refusing): 2
    refused = ServiceError("forbidden", "config: not for this user")
    code, out, err, _ = _run(monkeypatch, capsys, {"fleet/t01/hitch": refused, "fleet/t02/hitch": silent}, *flags)
    assert code == 2
    if json_out:
        assert [r["code"] for r in json.loads(out)["fleet"]] == ["forbidden", "timeout"]
    else:
        assert (
            out.splitlines()[0]
            == "fleet/t01/hitch: REFUSED (forbidden): config: not for this user; ECU online, at rest"
        )
        assert "2 of 2 services gave no configuration" in err


STATE_JSON = {"ecu_online": True, "faults": [], "ack_required": [], "moving": False, "motion": None}


def test_each_row_says_the_machine_now_ecu_link_faults_and_motion(monkeypatch, capsys):
    """A fleet trial: ``fleet ls --json`` had no ECU online or fault fields; a fleet had to subscribe to every
    state itself. Truth: the state each stand-in service publishes (a frozen service's core still does; one
    whose core is silent has none)."""
    services: dict = {"fleet/t01/hitch": CONFIG, "fleet/t02/hitch": CONFIG, "fleet/t03/hitch": CONFIG}
    states = {
        "fleet/t01/hitch": {
            "ecu": {"online": False, "faults": ["stale_measurement", "ecu_restart"], "ack_required": ["ecu_restart"]},
            "moving": False,
            "motion": None,
        },
        "fleet/t02/hitch": {**AT_REST, "moving": True, "motion": "goto"},
    }
    code, out, err, _ = _run(monkeypatch, capsys, services, states=states)
    assert code == 0, err
    assert out.splitlines() == [
        "fleet/t01/hitch: thesis-t132 cat 2, implement -, mode manual; ECU OFFLINE, faults stale_measurement, "
        "ecu_restart (acknowledge: hitch faults ack --prefix fleet/t01/hitch), at rest",
        "fleet/t02/hitch: thesis-t132 cat 2, implement -, mode manual; ECU online, moving (goto)",
        "fleet/t03/hitch: thesis-t132 cat 2, implement -, mode manual; no state within 1 s",
    ]
    code, out, _, _ = _run(monkeypatch, capsys, services, "--json", states=states)
    rows = {r["prefix"]: r["state"] for r in json.loads(out)["fleet"]}
    assert rows == {
        "fleet/t01/hitch": {
            "ecu_online": False,
            "faults": ["stale_measurement", "ecu_restart"],
            "ack_required": ["ecu_restart"],
            "moving": False,
            "motion": None,
        },
        "fleet/t02/hitch": {**STATE_JSON, "moving": True, "motion": "goto"},
        "fleet/t03/hitch": None,
    }


def test_a_service_whose_state_cannot_be_subscribed_does_not_hold_the_listing(monkeypatch, capsys):
    """A review: one subscription that failed left the wait for every state unfinished, so each listing took the
    whole second. Truth: the wall time of the listing against the 1 s wait."""
    import time

    client = _Fleet({"fleet/t01/hitch": CONFIG, "fleet/t02/hitch": CONFIG})
    client.unsubscribable = {"fleet/t02/hitch"}
    monkeypatch.setattr(cli_service, "_client", lambda args: client)
    t0 = time.monotonic()
    assert main(["fleet", "ls"]) == 0
    took = time.monotonic() - t0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith("; ECU online, at rest") and lines[1].endswith("; no state within 1 s"), lines
    assert took < 0.5, took


def test_an_empty_fleet_is_no_error(monkeypatch, capsys):
    code, out, err, _ = _run(monkeypatch, capsys, {})
    assert (code, out.strip(), err) == (0, "(no services)", "")


def test_an_empty_filtered_fleet_names_the_filter(monkeypatch, capsys):
    code, out, err, _ = _run(monkeypatch, capsys, {"fleet/t01/hitch": CONFIG}, "--prefix", "farm")
    assert (code, out.strip(), err) == (0, "(no services under farm)", "")


def test_a_fleet_listing_that_reaches_no_service_says_no_python_none():
    """A fleet trial: `hitch fleet ls` reaching nothing said "no hitch service with prefix None answers"."""
    import argparse

    err = cli_service._service_down(argparse.Namespace(connect=["tcp/127.0.0.1:1"], prefix=None), OSError("x"))
    assert "no hitch service answers at tcp/127.0.0.1:1" in str(err) and "None" not in str(err), err
    one = cli_service._service_down(argparse.Namespace(connect=None, prefix="fleet/t01/hitch"), OSError("x"))
    assert "no hitch service with prefix 'fleet/t01/hitch' answers" in str(one)
