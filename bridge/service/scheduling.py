"""How the operating system schedules the service's threads: nice values and real-time priorities.

The control path (the control cycle, the CAN threads, the twin standing in for the ECU's computer,
and the Zenoh threads that carry ``stop``) must not wait for CPU-bound programs on the same computer.
A raised nice value only weighs the fair scheduler in its favour: a busy program still runs for its
slice before a waking control thread, and a whole-process stall of 58–68 ms remained under the
reliability bench's load with every core thread at nice −10 (``docs/faults.md``). Under the
real-time policy ``SCHED_FIFO`` a thread that becomes runnable preempts every ordinary thread at once
(higher real-time priority first); the kernel still keeps 5 % of every second for ordinary threads
(``/proc/sys/kernel/sched_rt_runtime_us``), so a runaway real-time thread cannot freeze the computer.

Which threads, and why (numbers: higher runs first):

* :data:`TWIN_RT_PRIORITY` — the simulated ECU and tractor (``EcuCanNode-rt``): computers of their own
  in the field, whose timing the planner host's load does not touch;
* :data:`CONTROL_RT_PRIORITY` — the control cycle (``hitch-control``) and the planner's CAN thread
  (``CanLink-rt``);
* :data:`CORE_RT_PRIORITY` — every other thread of the control core (its Zenoh session, which answers
  ``stop``; the reading, notes and outbox threads; the motion threads that plan a goto — bounded
  work, and they hold the interpreter lock the control cycle needs, so they must not be put aside
  for an ordinary program while holding it);
* :data:`ROUTER_RT_PRIORITY` — the Zenoh threads of the service's own process when the control core
  runs elsewhere (they route ``stop`` from the clients to the core; they never take the interpreter
  lock: the service's queryables hand queries over through ring channels).

The control core's real-time threads share one CPU (:func:`pin_to_one_cpu`, the last the process may
use): a frame one of them sends then wakes the receiving thread on the same CPU after the sender
blocks, with the frames of a burst handled in one wake-up, instead of on another CPU at once for
every frame with the interpreter lock handed across CPUs each time (measured: the planner's CAN
thread woke 284 times a second at rest instead of 159, and the core took 24 % of a core instead of
17 % under the same load). Real-time threads still preempt every ordinary thread on that CPU.

A thread created later inherits its creator's policy and CPUs (Linux ``clone``), so threads a real-time
thread starts (a motion thread's helpers) are real-time too. The library threads that are neither
Python's nor Zenoh's (e.g. a BLAS pool) keep the ordinary policy. Setting a real-time policy needs
root or CAP_SYS_NICE; without it every function here says why and the caller falls back to nice
values.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass

__all__ = [
    "CLIENT_RT_PRIORITY",
    "CONTROL_RT_PRIORITY",
    "CORE_RT_PRIORITY",
    "ROUTER_RT_PRIORITY",
    "TWIN_RT_PRIORITY",
    "ZENOH_THREAD_PREFIXES",
    "ThreadSchedule",
    "pin_to_one_cpu",
    "process_to_fifo",
    "caller_to_fifo",
    "caller_to_ordinary",
    "python_thread_ids",
    "raise_to_fifo",
    "set_thread_fifo",
    "set_thread_nice",
    "thread_nice",
    "thread_schedule",
    "zenoh_thread_ids",
]

#: real-time priority (SCHED_FIFO, 1…99) of the machine twin's runner thread
TWIN_RT_PRIORITY = 30
#: real-time priority of the control cycle and the planner's CAN thread
CONTROL_RT_PRIORITY = 20
#: real-time priority of every other thread of the control core (its Zenoh session included)
CORE_RT_PRIORITY = 10
#: real-time priority of the service process's Zenoh threads (they route ``stop`` to the core)
ROUTER_RT_PRIORITY = 5
#: real-time priority of a :class:`~bridge.service.client.HitchClient` asked to be real-time (its process's
#: Zenoh threads send its ``stop``): as the service's router, below the control core
CLIENT_RT_PRIORITY = 5
#: name prefixes (``/proc/<pid>/task/<tid>/comm``) of the threads of Zenoh's runtime (zenoh 1.x:
#: ``rx-0``, ``tx-0``, ``net-0``, ``app-0``, ``acc-0``)
ZENOH_THREAD_PREFIXES = ("rx-", "tx-", "net-", "app-", "acc-")

_SCHED_FIFO = 1  # Linux policy numbers as /proc/<pid>/task/<tid>/stat reports them
_POLICY_NAMES = {0: "other", 1: "fifo", 2: "rr", 3: "batch", 5: "idle", 6: "deadline"}


@dataclass(frozen=True)
class ThreadSchedule:
    """One thread's scheduling as the kernel reports it: its name, policy and priorities."""

    tid: int
    name: str
    policy: str  #: "other", "fifo", "rr", "batch", "idle" or "deadline"
    rt_priority: int  #: 1…99 under a real-time policy, 0 otherwise
    nice: int


def thread_nice(native_id: int) -> int | None:
    """The nice value of one thread (None where the system cannot tell)."""
    getpriority = getattr(os, "getpriority", None)
    if getpriority is None:
        return None
    try:
        return int(getpriority(os.PRIO_PROCESS, native_id))
    except OSError:
        return None


def set_thread_nice(native_id: int, nice: int) -> str | None:
    """Set the nice value of one thread (Linux: a thread is a schedulable task with its own id);
    None when done, else why not (not permitted, not supported)."""
    setpriority = getattr(os, "setpriority", None)
    if setpriority is None:
        return "os.setpriority is not available on this system"
    try:
        setpriority(os.PRIO_PROCESS, native_id, nice)
    except PermissionError:
        return "not permitted"
    except OSError as exc:
        return str(exc)
    return None


def set_thread_fifo(native_id: int, priority: int) -> str | None:
    """Put one thread under ``SCHED_FIFO`` at real-time ``priority`` (1…99); None when done, else why
    not (not permitted, not supported, the thread ended)."""
    if not 1 <= priority <= 99:
        raise ValueError(f"priority must be within 1…99, got {priority}")
    setscheduler = getattr(os, "sched_setscheduler", None)
    if setscheduler is None:
        return "os.sched_setscheduler is not available on this system"
    try:
        setscheduler(native_id, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return "not permitted"
    except OSError as exc:
        return str(exc)
    return None


def _base_policy() -> int:
    """The calling thread's policy without the ``SCHED_RESET_ON_FORK`` flag (rtkit sets it)."""
    return os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)


def caller_to_fifo(priority: int) -> Callable[[], None] | None:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` for a while; the function that gives it
    its own policy back, or None when nothing was changed: not permitted, not supported, or the thread
    runs under a real-time or deadline policy already (left as it is, never lowered)."""
    try:
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
        if _base_policy() not in (os.SCHED_OTHER, os.SCHED_BATCH, os.SCHED_IDLE):
            return None
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError):
        return None

    def restore() -> None:
        try:
            os.sched_setscheduler(0, policy, param)
        except OSError:  # not permitted back (cannot happen for a lower policy): leave it
            pass

    return restore


def process_to_fifo(priority: int) -> str | None:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` for good, before it starts the process's
    other threads: they inherit its policy (Linux ``clone``). For a command that stands for a computer of its
    own in the field — ``hitch ecu-sim``, ``hitch can-hub`` (the bus between them) — or that is a control path
    of its own (``hitch calibrate sensors`` on a bus). None when done (or the thread runs under a real-time or
    deadline policy already, e.g. started with ``chrt``: left as it is), else why not.

    Measured (4 busy processes on the 2-core machine, the top link's calibration over a hub, all three
    processes at ordinary priority): 3 of 3 runs stopped by a stale measurement or the ECU's reference
    watchdog; under ``chrt -f 20``: 2 of 2 finished in 29 s, as unloaded.
    """
    if not 1 <= priority <= 99:
        raise ValueError(f"priority must be within 1…99, got {priority}")
    try:
        if _base_policy() not in (os.SCHED_OTHER, os.SCHED_BATCH, os.SCHED_IDLE):
            return None
    except (AttributeError, OSError):
        return "os.sched_getscheduler is not available on this system"
    return set_thread_fifo(0, priority)


def caller_to_ordinary() -> None:
    """Put the calling thread under the ordinary policy if it runs under another (lowering is always
    permitted; a thread inherits its creator's policy)."""
    try:
        if _base_policy() != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (AttributeError, OSError):
        pass


def _task_ids(pid: int | str) -> list[int]:
    try:
        return [int(t) for t in os.listdir(f"/proc/{pid}/task")]
    except OSError:
        return []


def _comm(pid: int | str, tid: int) -> str:
    try:
        with open(f"/proc/{pid}/task/{tid}/comm") as f:
            return f.read().strip()
    except OSError:
        return ""


def zenoh_thread_ids(pid: int | str = "self") -> list[int]:
    """The ids of the threads of Zenoh's runtime in process ``pid`` (by name, :data:`ZENOH_THREAD_PREFIXES`)."""
    return [t for t in _task_ids(pid) if _comm(pid, t).startswith(ZENOH_THREAD_PREFIXES)]


def python_thread_ids(names: Iterable[str] | None = None) -> list[int]:
    """The native ids of this interpreter's threads (only those named in ``names`` when given)."""
    wanted = None if names is None else frozenset(names)
    return [
        t.native_id for t in threading.enumerate() if t.native_id is not None and (wanted is None or t.name in wanted)
    ]


def thread_schedule(pid: int | str = "self") -> list[ThreadSchedule]:
    """Every thread of process ``pid`` with its policy, real-time priority and nice value
    (``/proc/<pid>/task/<tid>/stat`` fields 19, 40 and 41); threads that end meanwhile are left out."""
    out = []
    for tid in _task_ids(pid):
        try:
            with open(f"/proc/{pid}/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        # fields[0] is field 3 (state): field n is fields[n - 3]
        nice, rt_priority, policy = int(fields[16]), int(fields[37]), int(fields[38])
        out.append(ThreadSchedule(tid, _comm(pid, tid), _POLICY_NAMES.get(policy, str(policy)), rt_priority, nice))
    return out


def raise_to_fifo(tids: Iterable[int], priority: int) -> list[str]:
    """:func:`set_thread_fifo` for each thread id; the reasons of those that failed (a thread that
    ended meanwhile is not a failure)."""
    failed = []
    for tid in tids:
        why = set_thread_fifo(tid, priority)
        if why is not None and os.path.exists(f"/proc/self/task/{tid}"):
            failed.append(why)
    return failed


def pin_to_one_cpu(tids: Iterable[int]) -> tuple[int | None, list[str]]:
    """Restrict each thread to the last CPU this process may run on (``sched_setaffinity``); returns
    that CPU (None when there is only one, or the call is not available: nothing is changed) and the
    reasons of the threads that failed (one that ended meanwhile is not a failure)."""
    getaffinity = getattr(os, "sched_getaffinity", None)
    setaffinity = getattr(os, "sched_setaffinity", None)
    if getaffinity is None or setaffinity is None:
        return None, []
    cpus = sorted(getaffinity(0))
    if len(cpus) < 2:
        return None, []
    cpu, failed = cpus[-1], []
    for tid in tids:
        try:
            setaffinity(tid, {cpu})
        except OSError as exc:
            if os.path.exists(f"/proc/self/task/{tid}"):
                failed.append(str(exc))
    return cpu, failed
