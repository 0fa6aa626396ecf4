"""``hitch router`` and its protection: a security file that authenticates no link and enables no access
control (a client's file given by mistake) is refused, not run wide open; a listener beyond loopback without
protection is warned about, as ``hitch serve`` does (a fleet trial: both ran silently)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
import zenoh

from bridge.cli.main import main
from bridge.cli.router import router_config, router_warnings
from bridge.service.security import (
    AccessPolicy,
    Credentials,
    SecurityError,
    SecuritySettings,
    security_json5,
    write_users_file,
)
from tests.integration.service_process import ROOT, free_port


@pytest.fixture
def files(tmp_path):
    users = write_users_file(tmp_path / "users.txt", {"alice": "alice-pw", "t01": "t01-pw"})
    out = {}
    for name, settings in {
        "client": SecuritySettings(credentials=Credentials("t01", "t01-pw")),
        "router": SecuritySettings(users_file=users, access=AccessPolicy("fleet/*/hitch", operators=("alice",))),
        "no_acl": SecuritySettings(users_file=users),
    }.items():
        out[name] = tmp_path / f"{name}.json5"
        out[name].write_text(security_json5(settings))
    empty = tmp_path / "empty-users.txt"
    empty.write_text("")
    out["empty_users"] = tmp_path / "empty_users.json5"  # Zenoh checks no password against an empty dictionary
    out["empty_users"].write_text(json.dumps({"transport": {"auth": {"usrpwd": {"dictionary_file": str(empty)}}}}))
    return out


def _router(ep: str, security) -> subprocess.Popen:
    """``hitch router --listen ep --security FILE`` in its own process (its output piped)."""
    return subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "router", "--listen", ep, "--security", str(security)],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_hitch_router_refuses_a_client_security_file(files):
    ep = f"tcp/127.0.0.1:{free_port()}"
    proc = _router(ep, files["client"])
    try:
        out, err = proc.communicate(timeout=30)
    except subprocess.TimeoutExpired:  # it runs: unprotected
        proc.kill()
        out, err = proc.communicate(timeout=10)
        pytest.fail(f"the router ran with a client's security file: {out!r} {err!r}")
    assert proc.returncode == 2, (out, err)
    assert "ready" not in out
    assert "authenticates no link and enables no access control" in err
    assert "it looks like a client's file (it logs in as 't01')" in err
    assert "dictionary_file" in err and "access_control" in err  # what a router's file needs


def test_security_files_that_protect_nothing_are_refused_the_others_warned_about(files):
    for name in ("client", "empty_users"):
        with pytest.raises(SecurityError) as exc:
            router_config(["tcp/127.0.0.1:7447"], str(files[name]))
        assert exc.value.field == "security", name
    assert router_warnings(["tcp/127.0.0.1:7447"], str(files["router"])) == []
    assert router_warnings(["tcp/127.0.0.1:7447"], str(files["no_acl"])) == [
        "the security file enables no access_control: every user it authenticates may use every key of every "
        "service behind the router, motion included"
    ]
    assert router_warnings(["tcp/192.168.10.2:7447"], str(files["router"])) == [
        "tcp/192.168.10.2:7447 accepts unencrypted links from the network; use tls/… with a certificate"
    ]
    with pytest.raises(SecurityError) as exc:  # a TLS listener needs the router's certificate
        router_warnings(["tls/192.168.10.2:7447"], str(files["router"]))
    assert exc.value.field == "tls.certificate"


def test_hitch_router_warns_about_an_exposed_listener_without_security(monkeypatch, capsys):
    opened = []

    def no_open(config):  # nothing listens on 0.0.0.0 in a test: the warnings come before the session opens
        opened.append(json.loads(config.get_json("listen/endpoints")))
        raise zenoh.ZError("not opened by the test")

    monkeypatch.setattr(zenoh, "open", no_open)
    assert main(["router", "--listen", "tcp/0.0.0.0:7447"]) == 2
    err = capsys.readouterr().err
    assert opened == [["tcp/0.0.0.0:7447"]]
    assert "hitch router: warning: tcp/0.0.0.0:7447 accepts unencrypted links from the network" in err
    assert "hitch router: warning: tcp/0.0.0.0:7447 accepts links from the network without user/password" in err
    assert "hitch router: warning: tcp/0.0.0.0:7447 exposes the motion keys to every connected node" in err
    assert main(["router", "--listen", "tcp/127.0.0.1:7447"]) == 2  # loopback: nothing to warn about
    assert "warning" not in capsys.readouterr().err


def test_hitch_router_runs_with_a_router_security_file(files):
    ep = f"tcp/127.0.0.1:{free_port()}"
    proc = _router(ep, files["router"])
    try:
        assert proc.stdout is not None
        line = proc.stdout.readline()
        assert f"hitch router: ready on {ep}" in line and "lease 2 s)" in line, line  # the lease it announces
    finally:
        proc.terminate()
        out, err = proc.communicate(timeout=20)
    assert proc.returncode == 0, err
    assert "warning" not in err


def test_serve_behind_a_secured_router_says_how_to_check_the_fleet_sees_it(files):
    """A fleet trial: a service whose prefix the router's policy did not give its login said ready, and nobody
    could list or stop it; the service cannot see that itself. With ``security`` and ``connect`` the start names
    the check, a command the CLI takes; without either it says nothing."""
    import shlex

    from bridge.cli.main import build_parser
    from bridge.cli.service import access_check_hint
    from bridge.service.config import ServiceConfig

    cfg = ServiceConfig(
        mode="client", connect=["tcp/127.0.0.1:48999"], prefix="fleet/t03/hitch", security=files["client"]
    )
    hint = access_check_hint(cfg)
    assert hint is not None
    command = hint.split("check the fleet sees this service: ", 1)[1].split(" must list it")[0]
    argv = shlex.split(command)
    assert argv[0] == "hitch"
    args = build_parser().parse_args(argv[1:])
    assert args.connect == ["tcp/127.0.0.1:48999"] and args.prefix == "fleet/t03/hitch" and args.security
    assert access_check_hint(ServiceConfig(connect=["tcp/127.0.0.1:48999"])) is None
    assert access_check_hint(ServiceConfig(security=files["client"])) is None
