"""A service that holds its liveliness token but does not answer (hung: ``kill -STOP``; busy), as ``hitch fleet ls``,
``hitch goto`` and :class:`HitchClient` tell it; and ``fleet ls`` of a login that sees no service.

A fleet trial's report: ``fleet ls`` called a hung service ``REFUSED (bad_reply): the reply is not JSON`` — the
reply was Zenoh's own timeout (an error reply whose payload is ``Timeout``), decoded as the service's; ``goto`` to
it said the same. Now: ``NO ANSWER within X s (the service is up — its liveliness token is there — but did not
answer: busy or hung)``, and ``goto`` says the timeout and that the service holds its token. A login whose role
may see no service read ``(no services)``, as if none ran.

Truth: a stand-in service on loopback (its own Zenoh peer) that declares the token and a queryable on its prefix
and never replies; a stand-in client (no Zenoh) for the empty fleet.
"""

from __future__ import annotations

import json

import pytest
import zenoh

from bridge.cli import service as cli_service
from bridge.cli.main import main
from bridge.service.client import HitchClient, ServiceTimeout
from tests.helpers import loopback_zenoh_config
from tests.integration.service_process import free_port

PREFIX = "fleet/t01/hitch"
HUNG = (
    f"{PREFIX}: NO ANSWER within 1 s (the service is up — its liveliness token is there — but did not answer: "
    "busy or hung); no state within 1 s"
)


@pytest.fixture
def hung():
    """The endpoint of a stand-in hung service: token ``fleet/t01/hitch/alive``, every query held unanswered."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    s = zenoh.open(loopback_zenoh_config("peer", ep))
    held: list = []  # the queries, never answered (dropping one would end it at once)
    q = s.declare_queryable(f"{PREFIX}/**", held.append)
    token = s.liveliness().declare_token(f"{PREFIX}/alive")
    try:
        yield ep
    finally:
        held.clear()
        token.undeclare()
        q.undeclare()
        s.close()


def test_the_client_says_timeout_not_bad_reply(hung):
    with HitchClient([hung], prefix=PREFIX, timeout_s=1.0) as c:
        with pytest.raises(ServiceTimeout) as info:
            c.config()
    assert info.value.code == "timeout" and info.value.timeout_s == 1.0
    assert "not JSON" not in str(info.value) and "within 1 s" in str(info.value), info.value


def test_fleet_ls_says_no_answer_within_the_timeout(hung, capsys):
    assert main(["fleet", "ls", "--connect", hung, "--timeout", "1"]) == 2  # none answered (docs/api.md)
    out = capsys.readouterr()
    assert out.out.splitlines() == [HUNG], out.out
    assert "1 of 1 services gave no configuration: fleet/t01/hitch" in out.err
    assert main(["fleet", "ls", "--connect", hung, "--timeout", "1", "--json"]) == 2
    (row,) = json.loads(capsys.readouterr().out)["fleet"]
    assert (row["prefix"], row["code"], row["timeout_s"]) == (PREFIX, "timeout", 1.0), row


def test_goto_to_a_hung_service_says_it_holds_its_token_but_did_not_answer(hung, capsys):
    rc = main(["goto", "--to", "z=0.2", "--connect", hung, "--prefix", PREFIX, "--timeout", "1"])
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "within 1 s" in err and f"holds its liveliness token {PREFIX}/alive" in err and "busy or hung" in err, err
    assert "not JSON" not in err and "start one with" not in err and "nothing answered" not in err, err


class _EmptyFleet:
    """A stand-in client that sees no service (``fleet()`` empty)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        pass

    def fleet(self, *, timeout_s: float = 2.0, under: str | None = None) -> list[str]:
        return []


def test_a_login_that_sees_no_service_is_told_access_control_may_hide_them(monkeypatch, capsys, tmp_path):
    monkeypatch.setattr(cli_service, "_client", lambda args: _EmptyFleet())
    login = tmp_path / "bob.json5"  # not read: the stand-in client takes its place
    assert main(["fleet", "ls", "--security", str(login)]) == 0  # none is live: 0 (docs/api.md)
    assert capsys.readouterr().out.strip() == (
        "(no services visible: none runs, or this login may see none — access control)"
    )
    assert main(["fleet", "ls"]) == 0  # without a login: none runs
    assert capsys.readouterr().out.strip() == "(no services)"
