"""Planning workers: the expensive requests that need no motion state run in processes of their own.

Plan previews (``plan``), maneuver validation (``maneuvers/validate`` and the check before
``maneuvers/run``) and ``ik`` are pure computations on a model of the hitch: given the start
state (read from the controller in O(1)), they need nothing of the running service. Computed on
threads of the service they would hold the interpreter lock for tens to hundreds of
milliseconds, and a thread holding it that the operating system puts aside for CPU-bound work
delays the control thread behind it (priority inversion through the lock). Here each runs in a
:class:`PlanningWorkers` process with its own model, guard and IK solver, at a lower OS
priority (nice :data:`WORKER_NICE`): the service's process keeps only the control loop,
the CAN threads and O(1) request handling (``docs/faults.md``, *Threads or processes*).

Protocol: a worker is a fresh interpreter (``python -m bridge.service.workers``) with one pipe. It builds its context
from a :class:`WorkerSpec` (profile, category, control rate, implement), then answers one task at a
time: ``(kind, args, implement)`` in, ``("ok", value)`` or ``("error", code, message)`` out — errors travel as
the API's error codes and texts, never as pickled exceptions. A spec that does not build (a profile, category or
implement that does not exist) is refused by :meth:`PlanningWorkers.start` before any process is spawned
(:func:`check_spec`); a worker whose context fails to build nonetheless prints no traceback: it answers every
task with ``("error", "unavailable", "the planning process could not start: …")``. A caller takes an idle worker
(waiting at most its timeout, else ``busy``), sends, and waits for the answer up to its timeout;
a worker that did not answer in time is terminated and replaced, so a task that timed out never
finishes later, and a worker that died is replaced the same way. Bounded: at most ``processes``
tasks run at once, and callers that find no idle worker in time are refused.

The selected implement (``implements/select``, :meth:`PlanningWorkers.set_implement`) travels with
every task — its stability record and limits, or None for the spec's — and the worker's guard takes
it before the task runs: no task is planned with a half-applied selection, and a worker replaced
meanwhile needs nothing but the next task.
"""

from __future__ import annotations

import json
import math
import multiprocessing.connection
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

from bridge.service.maneuvers.language import (
    ManeuverScript,
    PlanningContext,
    PresetLike,
    PresetStep,
    ValidationResult,
    validate,
)
from bridge.service.motion.types import PlanPreview
from planner.errors import HitchError, HitchInputError

__all__ = [
    "PresetPose",
    "PlanningWorkers",
    "WorkerError",
    "WorkerSpec",
    "WORKER_NICE",
    "WORKER_TIMEOUT_S",
    "check_spec",
    "error_code",
    "referenced_presets",
]

#: the workers' nice value (lower priority than the service and than ordinary programs; needs no privilege)
WORKER_NICE = 5
#: the longest a task may take, including the wait for an idle worker [s]
WORKER_TIMEOUT_S = 30.0


class WorkerError(HitchError, RuntimeError):
    """A task the workers could not answer; ``code`` is the API's error code (``busy``,
    ``unavailable``, ``refused``, ``unreachable``, ``bad_request``, ``ik_failed``, ``internal``)."""

    def __init__(self, code: str, message: str):
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class WorkerSpec:
    """What a worker builds its hitch from (the service's own settings)."""

    profile: str
    category: str | None
    control_rate: float
    implement: str | None


@dataclass(frozen=True)
class PresetPose:
    """A preset as validation reads it (:class:`~bridge.service.maneuvers.language.PresetLike`),
    as plain data for the pipe: x, z [m]; roll, pitch [rad]."""

    pose: Mapping[str, float]
    speed_scale: float | None = None


def check_spec(spec: WorkerSpec) -> None:
    """Raise the error a worker would meet building ``spec`` — :class:`~planner.profiles.loader.ProfileError`
    (profile not found or invalid, category not in it) or :class:`~planner.limits.tractor.TractorProfileError`
    (implement not in the profile's tractor profile) — without building a model (a fraction of a second)."""
    from planner.limits.tractor import load_tractor_profile
    from planner.profiles.hitch import load_profile

    profile = load_profile(spec.profile)
    profile.category(spec.category if spec.category is not None else profile.implement.default_category)
    if spec.implement is not None:
        load_tractor_profile(profile.stability.tractor_profile).implement(spec.implement)


# ---------------------------------------------------------------------- inside a worker process
class _WorkerContext:
    """The worker's own model, guard and IK solver (built once, used by this process only)."""

    def __init__(self, spec: WorkerSpec):
        from planner.ik_qp.hitch_ik import IKSolver
        from planner.limits.guard import Guard
        from planner.limits.tractor import load_tractor_profile
        from planner.model.kinematics import HitchModel
        from planner.trajectory import TrajectoryPlanner

        model = HitchModel.from_profile(spec.profile, spec.category)
        implement = None
        if spec.implement is not None:
            implement = load_tractor_profile(model.profile.stability.tractor_profile).implement(spec.implement)
        self.guard = Guard(TrajectoryPlanner(model, rate=spec.control_rate), implement=implement)
        from bridge.link.reference_check import ReferenceCheck

        self.reference_check = ReferenceCheck(model)  # the link's check, for a preview's count approach
        self.ik = IKSolver(HitchModel.from_profile(spec.profile, spec.category))
        from bridge.service.maneuvers.language import guarded_plan_step

        self.plan_step = guarded_plan_step(self.guard)
        self._selected: tuple[Any, Any] | None = None  # the implement (record, limits) the guard has

    def select(self, implement: tuple[Any, Any] | None) -> None:
        """Give the guard the selected implement's record and limits (None: keep what it has)."""
        if implement is None or implement == self._selected:
            return
        record, limits = implement
        self.guard.set_implement(record)
        self.guard.set_implement_limits(limits)
        self._selected = implement

    def run(self, kind: str, args: tuple[Any, ...]) -> Any:
        if kind == "preview":
            start, goal, scale = args
            from bridge.link.count_tail import plan_count_tail
            from planner.trajectory.plan import PlanError

            try:
                gp = self.guard.plan(start, goal, speed_scale=scale)
                tail = plan_count_tail(self.guard.planner, gp.plan, self.reference_check, self.guard)
                return PlanPreview.planned(gp, tail).to_json()
            except PlanError as exc:  # the planner's or the guard's (GuardRefusal) refusal
                return PlanPreview.refusal(exc).to_json()
        if kind == "validate":
            script, start, presets = args
            ctx = PlanningContext(start, self.plan_step, presets.get)
            return validate(script, ctx)
        if kind == "ik":
            from planner.ik_qp.result import Target

            res = self.ik.solve(Target(*args[0]))
            if res.status == "failed":
                raise WorkerError("ik_failed", f"no solution ({res.reason})")
            return res.to_json()
        if kind == "ping":
            return os.getpid()
        raise WorkerError("internal", f"unknown worker task {kind!r}")


def error_code(exc: BaseException) -> str:
    """The API's error code of an exception from planning or the controller (the code it carries —
    :class:`WorkerError`, ``MotionError``, ``RequestError`` —, else by its kind)."""
    from planner.limits.guard import GuardRefusal
    from planner.trajectory.plan import PlanError

    code = getattr(exc, "code", None)
    if isinstance(exc, HitchError) and isinstance(code, str):
        return code
    if isinstance(exc, GuardRefusal):
        return "refused"
    if isinstance(exc, PlanError):
        return "unreachable"
    if isinstance(exc, ValueError):
        return "bad_request"
    return "internal"


def _worker_main(conn: multiprocessing.connection.Connection, spec: WorkerSpec, nice: int) -> None:
    """A worker's life: its priority to nice ``nice`` (absolute: the service's own threads may run
    raised; lowering needs no privilege), build the context, answer tasks until the pipe closes."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, max(nice, os.getpriority(os.PRIO_PROCESS, 0)))
    except (OSError, AttributeError):
        pass
    ctx: _WorkerContext | None = None
    failed: tuple[str, str, str] | None = None
    try:
        ctx = _WorkerContext(spec)
    except HitchError as exc:  # the user's settings (check_spec refuses most before a worker starts): no traceback
        failed = ("error", "unavailable", f"the planning process could not start: {type(exc).__name__}: {exc}"[:500])
    while True:
        try:
            kind, args, implement = conn.recv()
        except (EOFError, OSError):
            return
        reply: tuple[Any, ...]
        if ctx is None:  # every task, the ping of warm() included, is told why
            assert failed is not None
            reply = failed
        else:
            try:
                ctx.select(implement)
                reply = ("ok", ctx.run(kind, args))
            except Exception as exc:  # noqa: BLE001 — every failure goes back as a code and a text
                text = str(exc) if error_code(exc) != "internal" else f"internal error {type(exc).__name__}: {exc}"
                reply = ("error", error_code(exc), text[:500])
        try:
            conn.send(reply)
        except (OSError, ValueError):
            return


# ---------------------------------------------------------------------- in the service
class _Worker:
    """One worker: ``python -m bridge.service.workers FD SPEC NICE`` on one end of a socket pair.

    A fresh interpreter, not a fork or a ``multiprocessing`` spawn: it imports nothing of the
    program that embeds the service (a script without a ``__main__`` guard stays safe), and it
    ends when its pipe closes (the service ended, however)."""

    def __init__(self, spec: WorkerSpec, nice: int):
        mine, theirs = socket.socketpair()
        try:
            fd = theirs.fileno()
            self.process = subprocess.Popen(
                [sys.executable, "-m", "bridge.service.workers", str(fd), json.dumps(asdict(spec)), str(int(nice))],
                pass_fds=(fd,),
                stdin=subprocess.DEVNULL,
                process_group=0,  # as the control core's: the service ends its workers, a Ctrl-C does not
            )
        finally:
            theirs.close()
        self.conn = multiprocessing.connection.Connection(mine.detach())

    @property
    def pid(self) -> int:
        return self.process.pid

    def kill(self) -> None:
        try:
            self.conn.close()
        except OSError:
            pass
        if self.process.poll() is None:
            self.process.kill()
        try:
            self.process.wait(0.5)
        except subprocess.TimeoutExpired:
            pass


class PlanningWorkers:
    """A fixed set of worker processes for :data:`preview`, validation and IK (module docstring).

    Args:
        spec: what each worker builds.
        processes: how many run (each takes one task at a time).
        nice: the workers' nice value (:data:`WORKER_NICE`; a worker never raises its priority).
    """

    def __init__(self, spec: WorkerSpec, processes: int = 2, *, nice: int = WORKER_NICE):
        if isinstance(processes, bool) or not isinstance(processes, int) or not 1 <= processes <= 32:
            raise HitchInputError(f"planning processes must be an integer in 1..32, got {processes!r}")
        self.spec, self.processes, self.nice = spec, processes, int(nice)
        self._idle: queue.SimpleQueue[_Worker] = queue.SimpleQueue()
        self._all: set[_Worker] = set()
        self._lock = threading.Lock()
        self._closed = False
        self._implement: tuple[Any, Any] | None = None  # the selected implement, sent with every task
        self.replaced = 0
        """Workers terminated and replaced (timed out or died) since start."""

    def start(self) -> PlanningWorkers:
        """Spawn the workers (they build their models in the background; the first task waits).

        Raises:
            ProfileError / TractorProfileError: the spec's profile, category or implement does not exist
                (:func:`check_spec`; nothing spawned).
        """
        check_spec(self.spec)
        for _ in range(self.processes):
            self._idle.put(self._spawn())
        return self

    def _spawn(self) -> _Worker:
        w = _Worker(self.spec, self.nice)
        with self._lock:
            self._all.add(w)
        return w

    def _replace(self, w: _Worker) -> None:
        with self._lock:
            self._all.discard(w)
            closed = self._closed
        w.kill()
        if not closed:
            self.replaced += 1
            self._idle.put(self._spawn())

    def set_implement(self, implement: Any, limits: Any) -> None:
        """The selected implement (an ``ImplementRecord`` or None, its ``ImplementLimits``) for every
        later task (``implements/select``; see the module docstring)."""
        self._implement = (implement, limits)

    @property
    def pids(self) -> tuple[int, ...]:
        with self._lock:
            return tuple(w.pid for w in self._all)

    def call(self, kind: str, *args: Any, timeout_s: float = WORKER_TIMEOUT_S) -> Any:
        """Run one task; its value, or :class:`WorkerError` with the API's code."""
        if self._closed:
            raise WorkerError("unavailable", "the service is shutting down")
        if not (isinstance(timeout_s, (int, float)) and math.isfinite(timeout_s) and timeout_s > 0):
            raise WorkerError("internal", f"timeout_s must be a positive number of seconds, got {timeout_s!r}")
        t_end = time.monotonic() + float(timeout_s)
        try:
            w = self._idle.get(timeout=float(timeout_s))
        except queue.Empty:
            raise WorkerError(
                "busy", f"all {self.processes} planning processes stayed busy for {timeout_s:.1f} s; not run later"
            ) from None
        try:
            w.conn.send((kind, args, self._implement))
            if not w.conn.poll(max(0.0, t_end - time.monotonic())):
                self._replace(w)
                raise WorkerError(
                    "busy", f"the planning process did not answer within {timeout_s:.1f} s; not run later"
                )
            reply = w.conn.recv()
        except (EOFError, OSError, BrokenPipeError):
            self._replace(w)
            if self._closed:
                raise WorkerError("unavailable", "the service is shutting down") from None
            raise WorkerError("internal", "a planning process ended unexpectedly; it was restarted") from None
        self._idle.put(w)
        if reply[0] == "ok":
            return reply[1]
        raise WorkerError(str(reply[1]), str(reply[2]))

    # ------------------------------------------------------------------ the tasks
    def preview(self, start: Any, goal: Mapping[str, float], speed_scale: float) -> dict[str, Any]:
        """The ``plan`` reply: the guarded plan from ``start`` (a MotionState) or its refusal."""
        return dict(self.call("preview", start, dict(goal), float(speed_scale)))

    def validate(self, script: ManeuverScript, start: Any, presets: Mapping[str, PresetLike]) -> ValidationResult:
        """:func:`~bridge.service.maneuvers.language.validate` of a parsed script from ``start``;
        ``presets``: every preset the script names that exists (by name)."""
        plain = {n: PresetPose(dict(p.pose), p.speed_scale) for n, p in presets.items()}
        res = self.call("validate", script, start, plain)
        if not isinstance(res, ValidationResult):
            raise WorkerError("internal", f"validation returned {type(res).__name__}")
        return res

    def ik(self, target: tuple[float, float, float, float]) -> dict[str, Any]:
        """The IK solution's JSON for ``(x, z, roll, pitch)`` [m, rad]; ``ik_failed`` when there is none."""
        return dict(self.call("ik", tuple(float(v) for v in target)))

    def warm(self, timeout_s: float = 60.0) -> None:
        """Wait until every worker has built its context (one ``ping`` each).

        Raises:
            WorkerError: ``unavailable`` when a worker did not start in time, could not build its context
                (its message) or ended while starting; ``unavailable`` too when the workers are busy.
        """
        taken: list[_Worker] = []
        t_end = time.monotonic() + timeout_s
        try:
            for _ in range(self.processes):
                w = self._idle.get(timeout=max(0.01, t_end - time.monotonic()))
                taken.append(w)
                w.conn.send(("ping", (), None))
            for w in list(taken):
                if not w.conn.poll(max(0.0, t_end - time.monotonic())):
                    taken.remove(w)
                    self._replace(w)  # its ping is still unanswered: never reuse its pipe
                    raise WorkerError("unavailable", f"a planning process did not start within {timeout_s:.0f} s")
                try:
                    reply = w.conn.recv()
                except (EOFError, OSError):  # it died building its context (a bug: its traceback is on stderr)
                    taken.remove(w)
                    try:
                        code: int | None = w.process.wait(2.0)
                    except subprocess.TimeoutExpired:
                        code = None
                    self._replace(w)
                    raise WorkerError(
                        "unavailable", f"a planning process ended while starting (exit code {code})"
                    ) from None
                if reply[0] != "ok":
                    raise WorkerError(str(reply[1]), str(reply[2]))
        except queue.Empty:
            raise WorkerError("unavailable", "the planning processes are busy") from None
        finally:
            for w in taken:
                self._idle.put(w)

    def close(self) -> None:
        """Terminate every worker (a running task is abandoned: nothing is run later)."""
        with self._lock:
            self._closed = True
            workers = list(self._all)
            self._all.clear()
        for w in workers:
            w.kill()


def referenced_presets(script: ManeuverScript) -> tuple[str, ...]:
    """The preset names a script's steps use (in order, once each)."""
    return tuple(dict.fromkeys(s.name for s in script.steps if isinstance(s, PresetStep)))


def _main(argv: list[str]) -> int:
    """``python -m bridge.service.workers FD SPEC_JSON NICE``: serve tasks on the socket FD."""
    fd, spec, nice = int(argv[0]), WorkerSpec(**json.loads(argv[1])), int(argv[2])
    conn = multiprocessing.connection.Connection(fd)
    try:
        _worker_main(conn, spec, nice)
    except KeyboardInterrupt:  # a SIGINT sent to the worker itself (its own process group: Ctrl-C is the service's)
        pass
    finally:
        signal.signal(signal.SIGINT, signal.SIG_IGN)  # a second Ctrl-C must not interrupt the ending (as the core)
        conn.close()
    return 0


if __name__ == "__main__":  # run the module's canonical copy (its classes are the ones the service pickles)
    from bridge.service.workers import _main as _canonical_main

    code = _canonical_main(sys.argv[1:])
    # everything it owns is closed; the interpreter's finalisation would only report the planner's Ruckig
    # objects as "nanobind: leaked" (a worker killed by the service never gets here; one that ends does)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
