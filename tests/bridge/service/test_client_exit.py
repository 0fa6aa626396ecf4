"""A script that uses :class:`~bridge.service.client.HitchClient` and never closes it exits.

A fleet trial's report: a client that subscribed (``subscribe``, ``follow``, ``state``; not real-time) and was
not closed hung at interpreter exit forever (Zenoh ran the callback on a non-daemon thread of its own, which the
interpreter joins before any exit hook could close the subscription); with ``close()`` it exited in 0.65 s.
Every subscription now has a daemon callback thread of its own, closed at exit like the real-time ones, and a
client left open is closed at exit.

Truth: the child process's exit status and its output, under a generous timeout (a normal exit takes well
under a second; the timeout only turns the old hang into a failure). Loopback Zenoh only: a router in the test
process publishes ``hitch/state`` and ``hitch/events`` at 50 Hz.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from bench._common import free_port
from tests.helpers import loopback_zenoh_config

ROOT = Path(__file__).resolve().parents[3]

#: seconds a child may take to exit: far above the 0.1..3 s it needs, far below the hang
EXIT_TIMEOUT_S = 40.0


@pytest.fixture(scope="module")
def publisher():
    """A Zenoh router on loopback publishing ``hitch/state`` and ``hitch/events`` every 20 ms."""
    port = free_port()
    s = zenoh.open(loopback_zenoh_config("router", f"tcp/127.0.0.1:{port}"))
    pubs = [s.declare_publisher("hitch/state"), s.declare_publisher("hitch/events")]
    done = threading.Event()

    def publish() -> None:
        seq = 0
        while not done.wait(0.02):
            seq += 1
            for p in pubs:
                p.put(json.dumps({"seq": seq, "motion_id": 1, "moving": False}).encode())

    th = threading.Thread(target=publish, daemon=True)
    th.start()
    try:
        yield f"tcp/127.0.0.1:{port}"
    finally:
        done.set()
        th.join(2)
        for p in pubs:
            p.undeclare()
        s.close()


HEAD = """
import sys, threading, time
from bridge.service.client import HitchClient
c = HitchClient([sys.argv[1]], timeout_s=10.0)
"""

#: what each child does before it exits, never calling close()
SCRIPTS = {
    "subscribe": """
got = threading.Event()
c.subscribe("state", lambda s: got.set())
c.subscribe("events", lambda s: None)
assert got.wait(10.0)
""",
    "follow-left-open": """
samples = c.follow("state")
assert next(samples)["seq"] >= 1
keep = samples  # the generator is neither exhausted nor closed
""",
    "state": """
assert c.state()["seq"] >= 1
""",
    "blocked-callback": """
got, never = threading.Event(), threading.Event()
def cb(s):
    got.set()
    never.wait()  # a callback that never returns: the exit waits for it a bounded time only
c.subscribe("state", cb)
assert got.wait(10.0)
""",
}


@pytest.mark.parametrize("what", sorted(SCRIPTS))
def test_a_script_that_never_closes_its_client_exits(publisher, what):
    try:
        out = subprocess.run(
            [sys.executable, "-c", HEAD + SCRIPTS[what] + "print('done', flush=True)\n", publisher],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=EXIT_TIMEOUT_S,
        )
    except subprocess.TimeoutExpired as exc:
        raise AssertionError(f"{what}: the process did not exit within {EXIT_TIMEOUT_S:g} s: {exc.stderr!r}") from None
    assert (out.returncode, out.stdout.strip()) == (0, "done"), out.stderr
    assert "FATAL" not in out.stderr and "Traceback" not in out.stderr, out.stderr
    if what == "blocked-callback":  # said, not silently waited for
        assert "has not returned 2 s after close; the process exits without it" in out.stderr, out.stderr


def test_the_exit_hook_closes_the_clients_left_open(publisher):
    """What runs at exit (``_close_open_clients``): every client still open is closed with its subscriptions and
    their callback threads; one closed before is left as it is (no second close, no error)."""
    from bridge.service import client as client_module

    closed = client_module.HitchClient([publisher], timeout_s=10.0)
    closed.close()
    left = client_module.HitchClient([publisher], timeout_s=10.0)
    try:
        got = threading.Event()
        left.subscribe("state", lambda s: got.set())
        assert got.wait(10.0)
        assert closed not in client_module._OPEN_CLIENTS and left in client_module._OPEN_CLIENTS
        client_module._close_open_clients()
        assert left.session.is_closed() and left._subs == []
        assert left not in client_module._OPEN_CLIENTS
        assert not [t for t in threading.enumerate() if t.name.startswith(client_module.DISPATCH_THREAD_PREFIX)]
    finally:
        left.close()  # idempotent
