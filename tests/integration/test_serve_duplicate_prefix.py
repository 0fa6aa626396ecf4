"""A second ``hitch serve`` on a prefix a running service already serves refuses to start.

A fleet trial's report: a second service on ``fleet/t01/hitch`` started silently and printed "ready"; both
answered, the state stream interleaved (seq 839, 1, 840, 2 …) and which machine took a goto or a stop was up
to Zenoh. At start the service now asks for the liveliness token ``<prefix>/alive`` (bounded,
server.PREFIX_CHECK_S) and refuses with one line naming the prefix when another service holds it. A service on
another prefix of the same router starts, and so does one on the prefix of a service killed with SIGKILL (its
token goes with its connection).

Truth: the processes' exit status and output; the ``config`` of the service that keeps the prefix. A Zenoh
router in the test process (loopback only) carries the services, as a fleet router does.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
import zenoh

from bridge.service.client import HitchClient
from tests.helpers import loopback_zenoh_config
from tests.integration.service_process import ROOT, ServiceProcess, free_port

pytestmark = pytest.mark.slow  # services in their own processes

PREFIX = "fleet/t01/hitch"


def _serve(ep: str, prefix: str, data_dir, *, timeout_s: float = 90.0) -> tuple[int | None, str]:
    """Run ``hitch serve`` as a client of ``ep`` until it exits or says it is ready: (exit status or None when it
    became ready — then it was killed —, its output)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "serve", "--mode", "client", "--connect", ep, "--prefix", prefix]
        + ["--data-dir", str(data_dir)],
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        text=True,
    )
    out: list[str] = []
    end = time.monotonic() + timeout_s
    try:
        assert proc.stdout is not None
        for line in proc.stdout:  # ends when the process exits
            out.append(line)
            if "ready on" in line:
                return None, "".join(out)
            if time.monotonic() > end:
                break
        return proc.wait(timeout=max(1.0, end - time.monotonic())), "".join(out)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


@pytest.fixture
def router():
    ep = f"tcp/127.0.0.1:{free_port()}"
    s = zenoh.open(loopback_zenoh_config("router", ep))
    try:
        yield ep
    finally:
        s.close()


def test_a_second_service_on_a_served_prefix_refuses_to_start(router, tmp_path):
    first = ServiceProcess(
        ["--mode", "client", "--connect", router, "--prefix", PREFIX, "--data-dir", str(tmp_path / "a")]
    )
    try:
        code, out = _serve(router, PREFIX, tmp_path / "b")
        assert code == 2, out  # before: it started and said "ready"
        lines = out.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("hitch: error: "), out
        assert f"prefix {PREFIX!r} is served already" in lines[0] and f"{PREFIX}/alive" in lines[0], out
        assert "Traceback" not in out
        # the first one serves on, alone: one answer to config, one token
        with HitchClient([router], prefix=PREFIX, timeout_s=10.0) as c:
            assert c.config()["prefix"] == PREFIX
            assert c.fleet() == [PREFIX]
        assert first.proc.poll() is None
        # another prefix on the same router starts
        code, out = _serve(router, "fleet/t02/hitch", tmp_path / "c")
        assert code is None, out
    finally:
        first.kill()


def test_the_prefix_of_a_killed_service_can_be_served_again(router, tmp_path):
    """SIGKILL closes the killed service's connection: the router drops its token at once, so a restart (a
    supervisor's, at once) is not refused."""
    first = ServiceProcess(
        ["--mode", "client", "--connect", router, "--prefix", PREFIX, "--data-dir", str(tmp_path / "a")]
    )
    first.kill()
    code, out = _serve(router, PREFIX, tmp_path / "a")
    assert code is None, out


def test_two_services_that_meet_on_one_prefix_stop_and_the_later_one_ends(tmp_path):
    """A fleet trial: with the router down, a second service on t01's prefix started (its check saw nobody);
    once the router was back both served, and one goto moved both tractors (both black boxes accepted it 2 ms
    apart). Now they meet through their instance tokens: both brake (``prefix_conflict``), the later one ends
    (exit 2, one line naming the prefix), the earlier one serves on alone."""
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(loopback_zenoh_config("router", router_ep))
    first = ServiceProcess(
        ["--mode", "client", "--connect", router_ep, "--prefix", PREFIX, "--data-dir", str(tmp_path / "a")]
    )
    second = None
    try:
        router.close()  # the router is down: the second one's start-up check reaches nobody
        own = f"tcp/127.0.0.1:{free_port()}"
        second = ServiceProcess(
            ["--mode", "peer", "--listen", own, "--connect", router_ep, "--prefix", PREFIX]
            + ["--data-dir", str(tmp_path / "b")]
        )
        router = zenoh.open(loopback_zenoh_config("router", router_ep))  # back: the two meet
        assert second.proc.wait(timeout=60) == 2, "".join(second.output)
        last = second.output[-1]
        assert last.startswith("hitch: error: another service serves prefix 'fleet/t01/hitch'"), second.output
        assert "this service, the later one, ends itself" in last, last
        assert first.proc.poll() is None  # the earlier one serves on, alone
        with HitchClient([router_ep], prefix=PREFIX, timeout_s=20.0) as c:
            assert c.fleet() == [PREFIX]
            assert c.config()["prefix"] == PREFIX
        log = (tmp_path / "a" / "log" / "events.jsonl").read_text(encoding="utf-8")
        assert '"event":"prefix_conflict"' in log.replace(" ", "") and "the later one ends itself" in log, log[-2000:]
    finally:
        for p in (first, second):
            if p is not None:
                p.kill()
        router.close()


def test_the_later_of_two_services_refuses_every_request_but_stop_at_once_and_junk_names_are_ignored(tmp_path):
    """A review: the service that must end went on answering (a goto could still move both tractors) until
    serve()'s 0.5 s poll ended it, and an embedded service never acted on it; and any token under
    <prefix>/instance/ (e.g. "0", which sorts first) made the real service end itself."""
    import json
    import types

    from bridge.service.config import ServiceConfig
    from bridge.service.server import HitchService

    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{free_port()}"], data_dir=tmp_path, planning_processes=0, prefix="conflict/hitch"
    )
    svc = HitchService(cfg).start()
    try:
        events: list[dict] = []
        svc.add_listener("event", events.append)

        def meet(name: str) -> None:
            key = f"conflict/hitch/instance/{name}"
            svc._on_instance(types.SimpleNamespace(key_expr=key, kind=zenoh.SampleKind.PUT))

        def ask(key: str, body: dict) -> tuple[bool, dict]:
            out: list = []
            svc.dispatch(key, json.dumps(body).encode(), lambda ok, data: out.append((ok, json.loads(data))))
            deadline = time.monotonic() + 10.0
            while not out and time.monotonic() < deadline:
                time.sleep(0.01)
            return out[0]

        for junk in ("0", "00000000000000000001", "notes-ab", "0000000000000000000x-ab"):
            meet(junk)
        assert svc.conflict is None and ask("config", {})[0]
        meet("00000000000000000001-0a")  # started long before this one
        assert svc.conflict is not None and "this service, the later one, ends itself" in svc.conflict
        ok, reply = ask("goto", {"goal": {"z": 0.1}})
        assert not ok and reply["error"] == "unavailable" and "refused, the service ends" in reply["message"], reply
        assert not ask("config", {})[0]
        assert ask("stop", {})[0]  # stop always
        wait_until = time.monotonic() + 5.0
        while time.monotonic() < wait_until and not any(e.get("event") == "prefix_conflict" for e in events):
            time.sleep(0.02)
        conflict = [e for e in events if e.get("event") == "prefix_conflict"]
        assert conflict and conflict[0]["ends"] is True and conflict[0]["other"] == "00000000000000000001-0a", events
    finally:
        svc.close()
