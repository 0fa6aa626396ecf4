"""The control core's private link is a Unix socket in a private directory, not a TCP port of its own.

A fleet trial: with ``listen = ["tcp/127.0.0.1:47910"]`` the service also listened on a random loopback TCP port
(the core's link) that no setting named or could move: a port policy could not be met, and without a security
file any local process could join that session.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from bridge.service.client import HitchClient
from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.integration.service_process import free_port

pytestmark = pytest.mark.slow  # a service with its control core's process


def _listening_tcp_ports(pid: int) -> set[int]:
    """The TCP ports process ``pid`` listens on (its socket inodes in LISTEN state in /proc/net/tcp{,6})."""
    inodes = set()
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            m = re.fullmatch(r"socket:\[(\d+)\]", os.readlink(fd))
        except OSError:
            continue
        if m:
            inodes.add(m.group(1))
    ports = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            f = line.split()
            if f[3] == "0A" and f[9] in inodes:  # LISTEN
                ports.add(int(f[1].rsplit(":", 1)[1], 16))
    return ports


def test_a_service_listens_only_where_it_is_told(tmp_path):
    before = _listening_tcp_ports(os.getpid())
    port = free_port()
    svc = HitchService(
        ServiceConfig(listen=[f"tcp/127.0.0.1:{port}"], data_dir=tmp_path, control_core="process")
    ).start()
    try:
        assert svc.core is not None  # the control core runs in its own process
        assert _listening_tcp_ports(os.getpid()) - before == {port}
        with HitchClient([f"tcp/127.0.0.1:{port}"], timeout_s=10.0) as c:  # the core's state and stop, over its link
            assert c.state(timeout_s=10.0)["seq"] >= 0
            assert c.stop()["stopped"] is True
    finally:
        svc.close()


def test_a_long_temporary_directory_does_not_keep_the_service_from_starting(tmp_path, monkeypatch):
    """A review: with a TMPDIR longer than about 72 characters the core's socket path passed a Unix socket's 107
    bytes and a default `hitch serve` failed to start ("path must be shorter than SUN_LEN")."""
    import tempfile

    from bridge.service.server import private_link_dir

    long_dir = tmp_path / ("t" * 60) / ("m" * 60)
    long_dir.mkdir(parents=True)
    monkeypatch.setattr(tempfile, "tempdir", str(long_dir))
    d = private_link_dir()
    try:
        assert len(os.fsencode(d / "core.sock")) <= 107 and oct(d.stat().st_mode & 0o777) == "0o700"
    finally:
        d.rmdir()
    port = free_port()
    svc = HitchService(
        ServiceConfig(listen=[f"tcp/127.0.0.1:{port}"], data_dir=tmp_path / "data", control_core="process")
    ).start()
    try:
        with HitchClient([f"tcp/127.0.0.1:{port}"], timeout_s=10.0) as c:
            assert c.stop()["stopped"] is True  # answered by the core, over its link
    finally:
        svc.close()
    assert list(long_dir.iterdir()) == []
