"""One service per data folder (bridge.service.data_lock): a newcomer's trial ran ``make run`` in two clones on the
default folder; the second service ran beside the first, wrote a false ``previous_run_unclean`` record about it
and interleaved the event log's record numbers."""

from __future__ import annotations

import subprocess
import sys
import tempfile
import uuid

import pytest

from bridge.service.config import ServiceConfig
from bridge.service.data_lock import LOCK_FILE, DataDirInUseError, DataDirLock
from bridge.service.server import HitchService
from tests.integration.service_process import free_port


def test_a_second_holder_is_refused_naming_the_folder_and_the_first_and_takes_it_once_released(tmp_path):
    first = DataDirLock(tmp_path).acquire()
    with pytest.raises(DataDirInUseError, match=rf"data folder {tmp_path} is in use by another hitch service \(pid "):
        DataDirLock(tmp_path).acquire()
    first.release()
    first.release()  # idempotent
    with DataDirLock(tmp_path):
        pass
    assert (tmp_path / LOCK_FILE).exists()


def test_the_lock_goes_with_a_killed_holder(tmp_path):
    code = (
        f"from bridge.service.data_lock import DataDirLock; DataDirLock({str(tmp_path)!r}).acquire(); "
        "print(1, flush=True); input()"
    )
    holder = subprocess.Popen([sys.executable, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "1"
        with pytest.raises(DataDirInUseError, match=rf"pid {holder.pid}\)"):
            DataDirLock(tmp_path).acquire()
    finally:
        holder.kill()
        holder.wait(5.0)
    DataDirLock(tmp_path).acquire().release()  # nothing stale left


def test_a_second_service_on_the_same_data_folder_is_refused_before_it_touches_anything():
    data = tempfile.mkdtemp()

    def config() -> ServiceConfig:
        return ServiceConfig(
            data_dir=data,
            listen=(f"tcp/127.0.0.1:{free_port()}",),
            can_channel=f"lock-{uuid.uuid4().hex}",
            control_core="thread",
            planning_processes=0,
        )

    with HitchService(config()):
        with pytest.raises(DataDirInUseError, match="is in use by another hitch service"):
            HitchService(config()).start()
    with HitchService(config()):  # the first closed: the folder is free again
        pass


def test_config_names_the_run_and_a_restart_on_the_same_folder_is_another():
    """A fleet trial: after a restart the motion ids began at 1 again and a client waiting on "motion 18" could
    match another; `config` now says which run answers (`instance`, as the liveliness token)."""
    from bridge.service.client import HitchClient

    data, port = tempfile.mkdtemp(), free_port()
    cfg = ServiceConfig(
        data_dir=data,
        listen=(f"tcp/127.0.0.1:{port}",),
        can_channel=f"run-{uuid.uuid4().hex}",
        control_core="thread",
        planning_processes=0,
    )
    runs = []
    for _ in range(2):
        with HitchService(cfg) as svc, HitchClient([f"tcp/127.0.0.1:{port}"], timeout_s=10) as c:
            got = c.config()["instance"]
            assert got == svc.instance and got.split("-")[0].isdigit(), got
            runs.append(got)
    assert runs[0] != runs[1]


def test_hitch_serve_holds_the_folder_until_its_event_log_is_closed(tmp_path, monkeypatch):
    """A review: the service gave the lock up in its close, before `hitch serve` wrote the stop record; a second
    service could take the folder then, find no stop record and call the first's run unclean."""
    import bridge.service.server as server
    from bridge.cli.main import main
    from bridge.service.blackbox import EventLog

    seen: list[str] = []
    real_close = EventLog.close

    def close(self):  # the event log's last write: the folder must still be this service's
        try:
            DataDirLock(tmp_path).acquire().release()
            seen.append("free")
        except DataDirInUseError:
            seen.append("held")
        real_close(self)

    class Stand:
        warnings: list[str] = []
        api = None

        def nodes_reached(self):
            return None

        def add_listener(self, kind, callback):
            pass

        def remove_listener(self, kind, callback):
            pass

    def fake_serve(cfg, ready, data_lock=None):
        assert data_lock is not None  # the CLI's, handed to the service
        ready(Stand())
        return 0.01

    monkeypatch.setattr(EventLog, "close", close)
    monkeypatch.setattr(server, "serve", fake_serve)
    assert main(["serve", "--data-dir", str(tmp_path)]) == 0
    assert seen == ["held"]
    DataDirLock(tmp_path).acquire().release()  # and given up after it
