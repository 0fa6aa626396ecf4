"""OS scheduling of threads (bridge.service.scheduling): what the module reads from /proc agrees with what
the kernel answers through os.sched_getscheduler / os.getpriority, and a thread put under SCHED_FIFO is
reported so (root only: raising a policy needs CAP_SYS_NICE)."""

from __future__ import annotations

import os
import threading

import pytest

from bridge.service.scheduling import (
    pin_to_one_cpu,
    python_thread_ids,
    raise_to_fifo,
    set_thread_fifo,
    set_thread_nice,
    thread_nice,
    thread_schedule,
)

ROOT = os.geteuid() == 0


def _parked_thread() -> tuple[threading.Thread, threading.Event]:
    release = threading.Event()
    t = threading.Thread(target=release.wait, name="sched-test-parked", daemon=True)
    t.start()
    return t, release


def test_the_schedule_read_from_proc_agrees_with_the_kernel_calls():
    me = threading.get_native_id()
    mine = {s.tid: s for s in thread_schedule()}[me]
    policy = os.sched_getscheduler(me)
    assert mine.policy == {os.SCHED_OTHER: "other", os.SCHED_FIFO: "fifo", os.SCHED_RR: "rr"}.get(policy, mine.policy)
    assert mine.rt_priority == os.sched_getparam(me).sched_priority
    assert mine.nice == thread_nice(me) == os.getpriority(os.PRIO_PROCESS, me)
    assert me in python_thread_ids() and python_thread_ids(["no such thread"]) == []


def test_a_priority_outside_1_to_99_is_refused():
    for bad in (0, 100, -3):
        with pytest.raises(ValueError, match="1…99"):
            set_thread_fifo(threading.get_native_id(), bad)


def test_a_thread_that_ended_is_no_failure():
    t, release = _parked_thread()
    tid = t.native_id
    release.set()
    t.join()
    assert tid is not None and raise_to_fifo([tid], 3) == []


@pytest.mark.skipif(not ROOT, reason="a real-time policy needs root or CAP_SYS_NICE")
def test_a_thread_put_under_fifo_is_reported_fifo_at_its_priority_and_its_nice_kept():
    t, release = _parked_thread()
    try:
        tid = t.native_id
        assert tid is not None
        assert set_thread_nice(tid, -3) is None
        assert set_thread_fifo(tid, 7) is None
        s = {x.tid: x for x in thread_schedule()}[tid]
        assert (s.policy, s.rt_priority, s.nice) == ("fifo", 7, -3)
        assert os.sched_getscheduler(tid) == os.SCHED_FIFO
    finally:
        release.set()
        t.join()


@pytest.mark.skipif(ROOT, reason="as root the policy is permitted")
def test_without_privilege_the_reason_is_given():
    t, release = _parked_thread()
    try:
        assert t.native_id is not None and set_thread_fifo(t.native_id, 7) == "not permitted"
    finally:
        release.set()
        t.join()


@pytest.mark.skipif(len(os.sched_getaffinity(0)) < 2, reason="needs two CPUs")
def test_pinned_threads_run_on_the_last_cpu_the_process_may_use_and_others_keep_theirs():
    t, release = _parked_thread()
    try:
        assert t.native_id is not None
        before = os.sched_getaffinity(0)
        cpu, failed = pin_to_one_cpu([t.native_id])
        assert failed == [] and cpu == max(before)
        assert os.sched_getaffinity(t.native_id) == {cpu}
        assert os.sched_getaffinity(0) == before  # the caller is untouched
    finally:
        release.set()
        t.join()
