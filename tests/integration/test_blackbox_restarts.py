"""The black box across an unclean end: a service killed (or its computer's power lost) leaves no stop record
and may leave a torn last line; a control core that dies ends the service with a reason.

An incident investigator's report: after a kill -9 the restarted service's log went from the killed run's
``motion_started`` straight to ``started``, nothing said that run had ended without a stop; a torn last line
swallowed the next ``started`` record (both unreadable); a control core killed mid-motion was logged as a plain
``stopped`` and said "exit code None". Truth: the log's records as ``read_events`` reads them.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import pytest

from bridge.cli.records import format_record
from bridge.service.blackbox import EventLog, ended_cleanly, event_log_path, last_record, read_events
from tests.integration.service_process import ServiceProcess, free_port

pytestmark = pytest.mark.slow  # a service in its own process


def _torn_log(data_dir: Path) -> Path:
    path = event_log_path(data_dir)
    path.parent.mkdir(parents=True)
    whole = {"t": time.time() - 60, "seq": 7, "kind": "event", "event": "motion_started", "motion_id": 3}
    path.write_text(json.dumps(whole) + "\n" + '{"t": 1, "seq": 8, "kind": "event", "event": "motion_ab', "utf-8")
    return path


def test_a_torn_last_line_is_ended_and_the_next_record_is_readable(tmp_path):
    path = _torn_log(tmp_path)
    assert last_record(path)["seq"] == 7 and not ended_cleanly(last_record(path))
    with EventLog(path) as log:
        log.record("service", what="started")
    recs = read_events(path)
    assert [r["kind"] for r in recs] == ["event", "unreadable", "service"], recs
    assert recs[-1]["what"] == "started" and recs[-1]["seq"] == 8


def _core_pid(parent: int) -> int | None:
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
            cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ")
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        if ppid == parent and b"bridge.service.core.process" in cmd:
            return int(d.name)
    return None


def test_a_restart_after_an_unclean_end_says_so_and_a_dead_core_is_the_stop_s_reason(tmp_path):
    path = _torn_log(tmp_path)
    svc = ServiceProcess(["--listen", f"tcp/127.0.0.1:{free_port()}", "--data-dir", str(tmp_path)])
    try:
        core = None
        deadline = time.monotonic() + 20.0
        while core is None and time.monotonic() < deadline:
            core = _core_pid(svc.proc.pid)
            time.sleep(0.1)
        assert core is not None, "no control core process"
        os.kill(core, signal.SIGKILL)
        assert svc.proc.wait(timeout=30) == 2, "".join(svc.output)
    finally:
        svc.kill()
    recs = [r for r in read_events(path) if r["kind"] == "service"]
    unclean, started, stopped = recs[0], recs[1], recs[-1]
    assert unclean["what"] == "previous_run_unclean" and unclean["last_seq"] == 7, recs
    assert "ended without a stop record" in format_record(unclean)
    assert started["what"] == "started"
    assert stopped["what"] == "stopped" and "the control core ended (killed by signal 9)" in stopped["reason"], stopped
    assert "killed by signal 9" in "".join(svc.output)


def test_a_record_with_a_time_out_of_range_is_printed_not_a_traceback():
    line = format_record({"t": 1e300, "seq": 3, "kind": "event", "event": "fault"})
    assert line.startswith("t=1e+300 #3 event fault"), line
