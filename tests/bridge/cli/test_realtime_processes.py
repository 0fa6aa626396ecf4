"""The twin's own processes run under SCHED_FIFO where permitted: ``hitch can-hub`` and ``hitch ecu-sim``.

A new user's commissioning on the shared 2-core machine (load 4): ``hitch calibrate sensors`` over a hub
needed 6 runs, stopped by stale measurements and the ECU's reference watchdog; the hub and the ECU ran at
ordinary priority while the service's own control path runs real-time. Measured with 4 busy processes: 3 of 3
runs stopped at ordinary priority, 2 of 2 finished under ``chrt -f 20``.

Truth: the kernel's own report of each thread's policy and priority (``/proc/<pid>/task/<tid>/stat``).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bench._common import free_port
from bridge.service.scheduling import TWIN_RT_PRIORITY, thread_schedule
from tests.helpers import wait_until

HITCH = [sys.executable, "-m", "bridge.cli"]


def _fifo_permitted() -> bool:
    code = "import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True).returncode == 0


def _start(args: list[str], tmp_path: Path, name: str) -> tuple[subprocess.Popen, Path]:
    err = tmp_path / f"{name}.err"
    p = subprocess.Popen([*HITCH, *args], stdout=subprocess.DEVNULL, stderr=err.open("w"), cwd=tmp_path)
    return p, err


@pytest.mark.parametrize("no_realtime", [False, True])
def test_the_hub_and_the_ecu_process_run_real_time_where_permitted(tmp_path, no_realtime):
    port = free_port()
    url = f"ws://127.0.0.1:{port}/"
    extra = ["--no-realtime"] if no_realtime else []
    hub, hub_err = _start(["can-hub", "--port", str(port), *extra], tmp_path, "hub")
    ecu = None
    try:
        assert wait_until(lambda: url in hub_err.read_text(), 20.0), hub_err.read_text()
        ecu, ecu_err = _start(
            ["ecu-sim", "--interface", "remote", "--channel", url, "--duration", "20", *extra], tmp_path, "ecu"
        )
        assert wait_until(lambda: "valve commands" in ecu_err.read_text(), 20.0), ecu_err.read_text()  # running
        permitted = _fifo_permitted()
        for proc, err, who in ((hub, hub_err, "can-hub"), (ecu, ecu_err, "ecu-sim")):
            threads = thread_schedule(proc.pid)
            assert threads, who
            if no_realtime:
                assert all(t.policy == "other" for t in threads), (who, threads)
                assert "ordinary priority" not in err.read_text()
            elif permitted:
                main = next(t for t in threads if t.tid == proc.pid)
                assert (main.policy, main.rt_priority) == ("fifo", TWIN_RT_PRIORITY), (who, main)
                # the threads started after (the node's runner): inherited; only library pools
                # started at numpy's import (OpenBLAS) keep the ordinary policy
                fifo = [t for t in threads if (t.policy, t.rt_priority) == ("fifo", TWIN_RT_PRIORITY)]
                assert len(fifo) >= (2 if who == "ecu-sim" else 1), (who, threads)  # ecu-sim: main + runner
            else:
                assert f"{who}: runs at ordinary priority (real-time SCHED_FIFO not permitted" in err.read_text()
    finally:
        for p in (ecu, hub):
            if p is not None:
                p.terminate()
                try:
                    p.wait(10)
                except subprocess.TimeoutExpired:
                    p.kill()


def test_a_command_run_in_process_gives_the_caller_its_own_policy_back():
    """A test's ``main(["ecu-sim", …])`` left the test process's main thread under SCHED_FIFO for good (every
    later thread inheriting it): the command is real-time for its own run only."""
    import os
    import uuid

    from bridge.cli.main import main

    before = (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority)
    argv = ["ecu-sim", "--interface", "virtual", "--channel", f"t-{uuid.uuid4().hex}", "--duration", "0.2", "--json"]
    assert main(argv) == 0
    assert (os.sched_getscheduler(0), os.sched_getparam(0).sched_priority) == before
