"""The control core as its own process: CAN, the twin, the motion controller, ``stop``, state and events.

``python -m bridge.service.core.process FD CONFIG_JSON ENDPOINTS_JSON`` (started by
:class:`~bridge.service.core.client.CoreProcess`, never by hand) runs :class:`ControlCore`:

* the machine side (:func:`bridge.service.machine.start_can`, :func:`~bridge.service.machine.build_controller`):
  the link, the simulated ECU and tractor when configured, the motion controller and its control
  thread — every thread of this process at nice :data:`CORE_NICE`, and once started every Python and
  Zenoh thread under the real-time policy ``SCHED_FIFO`` (:func:`raise_core_to_realtime`; both need
  root or CAP_SYS_NICE; otherwise it runs at normal priority and the ``ready`` message says why);
* its own Zenoh session (a client of the service's session on its private link — a Unix socket, or with a
  users file a loopback listener with a made-up login — or
  of the routers the service connects to in client mode: ``ENDPOINTS_JSON``): the
  ``<prefix>/stop`` queryable (any payload stops) and subscriber (a put or delete stops too: a small ring
  a thread of its own empties, one stop per burst), the ``<prefix>/track/setpoint`` subscriber (a ring
  that a thread of its own empties at most :data:`SETPOINT_MAX_HZ` a second: a flood of puts never
  holds up the session that answers ``stop``),
  and the ``<prefix>/state`` and ``<prefix>/events`` publishers. Nothing the service's request
  handling does (thousands of requests, storage, validation, the terminal) runs under this
  process's interpreter lock: the control cycle only shares it with the CAN threads, the outbox
  and the motion commands below;
* a watch of the service (:meth:`ControlCore._watch_service`): the service sends a keep-alive over the
  socket every 0.25 s; silent for :data:`SERVICE_SILENCE_S` (a frozen or hung service: nobody can reach
  this core's ``stop`` through it) the core brakes the hitch to rest and posts ``service_lost``; heard
  again, ``service_restored`` — nothing stopped resumes;
* calls from the service over the socket ``FD`` (:mod:`bridge.service.core.client`): ``(id,
  method, args)`` in, ``(id, "ok", value)`` or ``(id, "error", code, message)`` out; and notes
  ``(0, "note", {...})`` about what the core answered on its own (each ``stop`` it served, for the
  service's black box), each change of its mode (the service's ``mode`` and ``config`` answer from
  it) and each event it publishes (its JSON: the service's event listeners hear it from here); sent
  by a thread of their own through a bounded queue, never in the way of the stop. O(1) methods
  are answered on the reading thread at once (``stop`` first of all); ``goto`` and
  ``run_maneuver`` (they plan) on two threads of their own. Values travel as plain data (JSON-ready
  dicts, numbers, states); errors as the API's codes and texts.

The process ends when the socket closes (the service ended, however) or on ``close``: the motion
is braked for up to 0.4 s, then the stream ends and the ECU's watchdog holds the valves at zero.
"""

from __future__ import annotations

import gc
import json
import multiprocessing.connection
import os
import queue
import select
import signal
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import zenoh

from bridge.service.config import ServiceConfig
from bridge.service.gnss import start_twin_gnss
from bridge.service.machine import CanParts, build_controller, service_info, start_can
from bridge.service.motion.controller import LIVE_SESSION, MotionController
from bridge.service.scheduling import (
    CONTROL_RT_PRIORITY,
    CORE_RT_PRIORITY,
    TWIN_RT_PRIORITY,
    pin_to_one_cpu,
    raise_to_fifo,
    zenoh_thread_ids,
)
from bridge.service.schemas import RequestError, parse_request, setpoint_session, setpoint_too_large
from bridge.service.security import connect_sections
from bridge.service.wire import to_json_bytes
from bridge.service.workers import error_code
from planner.errors import HitchError

#: period of the core's check of its CAN threads [s]
RUNNER_WATCH_S = 0.2
#: a service silent this long over the private socket counts as lost: the core brakes the hitch to rest
#: the ring of puts on ``<prefix>/stop`` (the oldest dropped when full: they all mean the same)
STOP_PUT_RING = 8
#: a put on stop is taken at most this often [s] (one stop per burst; a flood of them stops the hitch continually)
STOP_PUT_INTERVAL_S = 0.05
#: (``service_lost``). The service sends a keep-alive every
#: :data:`~bridge.service.core.client.KEEPALIVE_S` (0.25 s) from a thread of its own, so this is 8 of them
#: missed in a row: a Python thread of a loaded computer is delayed tens of milliseconds, a full garbage
#: collection of the service ~0.1 s, never seconds; a frozen (SIGSTOP), hung or swapped-out service is
#: braked within this plus :data:`SERVICE_WATCH_S` [s]
SERVICE_SILENCE_S = 2.0
#: period of the core's watch of its service [s]
SERVICE_WATCH_S = 0.1
#: setpoint puts the core's ring holds for its setpoint thread (``core-setpoints``); beyond it the oldest is
#: dropped, in Zenoh
SETPOINT_RING = 256
#: the most setpoint puts a second the setpoint thread takes after a burst of :data:`SETPOINT_BURST` [Hz]: 20 times
#: the documented 100 Hz maximum of a stream; a flood beyond it waits in (and falls out of) the ring
SETPOINT_MAX_HZ = 2000.0
#: setpoints taken at once before :data:`SETPOINT_MAX_HZ` applies (a stream's burst after a hiccup)
SETPOINT_BURST = 64

__all__ = ["CORE_NICE", "TWIN_NICE", "ControlCore", "freeze_startup_objects", "lock_memory", "raise_core_to_realtime"]

#: nice value of every thread of the core process (the control cycle, CAN, its Zenoh session)
CORE_NICE = -10
#: nice value of the machine twin's runner (the simulated ECU and tractor): it stands in for computers of
#: their own, whose timing the planner host's load does not touch, so it runs above the core's threads
TWIN_NICE = -15
#: the twin runner's thread name (:func:`bridge.service.machine.start_can`)
TWIN_THREAD = "EcuCanNode-rt"
#: the core interpreter's switch interval [s] (Python's default 5 ms)
SWITCH_INTERVAL_S = 0.001
#: methods answered on the reading thread (O(1), no planning)
_INLINE = frozenset(
    {
        "stop",
        "stop_report",
        "jog",
        "set_mode",
        "mode",
        "ack_faults",
        "faults",
        "current_state",
        "preview_start",
        "track_start",
        "track_setpoint",
        "track_setpoint_refused",
        "track_stop",
        "sim_fault",
        "sim_switch",
        "post_event",
        "want_state",
        "ping",
    }
)
#: methods that plan (on the core's motion threads)
_PLANNING = frozenset({"goto", "run_maneuver", "select_implement"})  # (select waits for a running plan)


def _set_nice(nice: int) -> str | None:
    """Every thread of this process to ``nice`` (the ones libraries started at import too; threads
    started later inherit it); None when done, else why not."""
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:
        tids = [threading.get_native_id()]
    try:
        for tid in tids:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
    except PermissionError:
        return "not permitted"
    except (OSError, AttributeError) as exc:
        return str(exc)
    return None


class ControlCore:
    """The core's parts and its two faces (Zenoh and the service's socket); see the module docstring."""

    def __init__(
        self,
        cfg: ServiceConfig,
        conn: multiprocessing.connection.Connection,
        endpoints: list[str],
        *,
        nice_failed: str | None = None,
        login: tuple[str, str] | None = None,
        zid: str | None = None,
    ):
        self.cfg, self.conn, self.endpoints = cfg, conn, list(endpoints)
        self._login = login  # (user, password) of a secured service's link for this core (never printed)
        self._zid = zid  # the Zenoh id a secured service without users allows on its private socket
        self.nice_failed = nice_failed  # why the process could not be raised to CORE_NICE (None: it was)
        self._send_lock = threading.Lock()
        self.parts: CanParts | None = None
        self.motion: MotionController | None = None
        self.session: zenoh.Session | None = None
        self._state_pub: zenoh.Publisher | None = None
        self._event_pub: zenoh.Publisher | None = None
        self._decls: list[Any] = []
        self._setpoints: Any = None  # the setpoint subscriber's ring (_take_setpoints)
        self._stop_puts: Any = None  # the stop puts' ring (_take_stop_puts)
        self._pool = ThreadPoolExecutor(2, thread_name_prefix="core-motion")
        self._closed = threading.Event()
        self._state_listened = threading.Event()  # a subscriber matches the state publisher
        # the service's own listeners (terminal, latest_state) want the state over the private socket: a router
        # outage froze it there, and anyone allowed to put on the public key could draw a false one
        self._state_to_service = threading.Event()
        self._state_slot: bytes | None = None  # the newest state not sent to the service yet (older: replaced)
        self._state_ready = threading.Event()
        self.recorder: Any = None
        self._table: dict[str, Callable[..., Any]] = {}
        self._notes: queue.Queue[dict[str, Any]] = queue.Queue(maxsize=256)
        self.notes_dropped = 0
        #: ``track/setpoint`` puts dropped unread (beyond MAX_SETPOINT_BYTES)
        self.setpoints_too_large = 0
        #: when the last message from the service arrived (``time.monotonic()``; the watch of the service)
        self._heard = time.monotonic()
        self._heard_gap = 0.0  # the longest time between two messages from the service since the watch reset it [s]

    def send_ready(self, ready: dict[str, Any]) -> None:
        """Answer the start (``(0, "ok", ready)``), then begin sending notes. Notes queued while starting (an ECU
        heartbeat fault of a loaded machine, the ``realtime`` warning) wait behind the answer: one sent first
        was read as the answer and the service refused to start ("the control core could not start: {'event':
        …}", a run under load 28)."""
        with self._send_lock:
            self.conn.send((0, "ok", ready))
        threading.Thread(target=self._send_notes, name="core-notes", daemon=True).start()
        threading.Thread(target=self._send_states, name="core-state-notes", daemon=True).start()

    # ------------------------------------------------------------------ life cycle
    def start(self) -> dict[str, Any]:
        """Build and start everything; the ``ready`` message for the service."""
        cfg = self.cfg
        nice_failed = self.nice_failed
        if cfg.can_log is not None:
            from bridge.service.blackbox import CanRecorder, announce_can_log_stop

            self.recorder = CanRecorder.of_config(cfg)
        runners: list[Any] = []
        self.parts = parts = start_can(cfg, runners_out=runners)
        self._runners = runners
        self._open_zenoh()
        self.motion, guard = build_controller(cfg, parts, on_state=self._publish_state, on_event=self._publish_event)
        self.motion.state_wanted = lambda: self._state_listened.is_set() or self._state_to_service.is_set()
        if self.recorder is not None:
            announce_can_log_stop(self.recorder, self.motion.outbox)
        self._table = self._methods()
        gnss = self.motion.gnss  # the tractor's GNSS position (maneuver wait_for line steps)
        assert self.session is not None
        self._decls.append(
            self.session.declare_subscriber(cfg.key("tractor/gnss"), lambda s: gnss.take_payload(s.payload.to_bytes()))
        )
        twin_gnss = start_twin_gnss(cfg, parts, self.session)  # the simulated tractor's receiver (None: a real one)
        if twin_gnss is not None:
            self._decls.append(twin_gnss)
        self.motion.start()
        threading.Thread(target=self._watch_runners, name="core-can-watch", daemon=True).start()
        if nice_failed is None:
            for t in threading.enumerate():
                if t.name == TWIN_THREAD and t.native_id is not None:
                    try:
                        os.setpriority(os.PRIO_PROCESS, t.native_id, TWIN_NICE)
                    except OSError:  # the thread ended, or not permitted: it keeps the core's priority
                        pass
        warnings = []
        fifo_failed = raise_core_to_realtime() if cfg.realtime else "switched off (realtime = false)"
        threading.Thread(target=self._take_setpoints, name="core-setpoints", daemon=True).start()
        threading.Thread(target=self._take_stop_puts, name="core-stop-puts", daemon=True).start()
        if fifo_failed is not None and cfg.realtime:
            warnings.append(
                f"control core: real-time scheduling (SCHED_FIFO) not possible ({fifo_failed}); its threads run at "
                f"nice {CORE_NICE} and a CPU-bound program may delay them"
            )
        if nice_failed is not None:
            text = (
                f"cannot raise the control core to nice {CORE_NICE} ({nice_failed}); running at normal priority "
                "(run as root or with CAP_SYS_NICE for a steadier control period)"
            )
            warnings.append(text)
            self.motion.outbox.put_event({"event": "realtime", "priority_raised": False, "message": text})
            self.motion.outbox.flush()
        clock = parts.clock
        info = service_info(cfg, guard)
        frozen = freeze_startup_objects()
        locked = lock_memory()
        if locked is not None:
            warnings.append(f"control core: memory not locked ({locked}); its pages may be evicted and fault back in")
        return {
            "realtime": fifo_failed is None,
            "gc_frozen": frozen,
            "memory_locked": locked is None,
            "t0_monotonic": time.monotonic() - clock(),
            "info": info,
            "simulated_ecu": parts.ecu_node is not None,
            "warnings": warnings,
            "pid": os.getpid(),
        }

    def _open_zenoh(self) -> None:
        cfg = self.cfg
        z = zenoh.Config()
        for path, value in (
            ("mode", "client"),
            ("connect/endpoints", self.endpoints),
            ("scouting/multicast/enabled", False),
        ):
            z.insert_json5(path, json.dumps(value))
        if self._zid is not None:  # a secured service's private Unix socket: the id its ACL allows there
            z.insert_json5("id", json.dumps(self._zid))
        if self._login is not None:  # a secured service's private listener: the user it made up for this core
            z.insert_json5("transport/auth/usrpwd/user", json.dumps(self._login[0]))
            z.insert_json5("transport/auth/usrpwd/password", json.dumps(self._login[1]))
        elif cfg.security is not None and cfg.mode == "client":  # the routers: logged in as the service is
            for path, value in connect_sections(cfg.security).items():
                z.insert_json5(path, value)
        self.session = s = zenoh.open(z)
        self._state_pub = s.declare_publisher(
            cfg.key("state"),
            encoding=zenoh.Encoding.APPLICATION_JSON,
            express=True,
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.DATA_HIGH,
        )
        self._event_pub = s.declare_publisher(cfg.key("events"), encoding=zenoh.Encoding.APPLICATION_JSON, express=True)
        # the state is built and sent only while a subscriber matches it (a viewer, the service's terminal …)
        self._decls.append(self._state_pub.declare_matching_listener(self._on_state_matching))
        status: Any = self._state_pub.matching_status  # a MatchingStatus (zenoh's stub says bool)
        if bool(getattr(status, "matching", status)):
            self._state_listened.set()
        exact = cfg.key("stop")

        def on_stop(query: zenoh.Query) -> None:
            taken = time.time()  # when the core took it (the reply's "t": the way to the core vs the stop itself)
            with query:
                if str(query.key_expr) != exact:
                    return  # a wildcard query reaches every queryable: only the exact key stops
                ok, reply = self._call_safely("stop_report", ())
                answer = {"stopped": True, **reply, "t": taken} if ok else reply
                data = to_json_bytes(answer)
                try:
                    if ok:  # the reply as urgent as the stop itself
                        query.reply(
                            query.key_expr,
                            data,
                            encoding=zenoh.Encoding.APPLICATION_JSON,
                            priority=zenoh.Priority.REAL_TIME,
                            express=True,
                        )
                    else:
                        query.reply_err(data, encoding=zenoh.Encoding.APPLICATION_JSON)
                except Exception:  # noqa: BLE001 — the session is closing
                    pass
                payload = b"" if query.payload is None else query.payload.to_bytes()
                self._note({"request": "stop", "ok": ok, "reply": answer, "payload": payload[:1024]})

        self._decls.append(s.declare_queryable(exact, on_stop, complete=True))

        # a put (or delete) on stop stops as the query does: into a small ring Zenoh fills without running Python,
        # taken by core-stop-puts (_take_stop_puts), one stop per burst — a flood of them costs that thread only
        self._stop_puts = s.declare_subscriber(exact, zenoh.handlers.RingChannel(STOP_PUT_RING))
        self._decls.append(self._stop_puts)
        # the setpoint puts into a ring that Zenoh fills without running Python (the oldest dropped when full): this
        # session's threads never wait for the interpreter lock for them (core-setpoints takes them, start)
        self._setpoints = s.declare_subscriber(cfg.key("track/setpoint"), zenoh.handlers.RingChannel(SETPOINT_RING))
        self._decls.append(self._setpoints)

    def _watch_runners(self) -> None:
        """Every :data:`RUNNER_WATCH_S`: a CAN thread that stopped (its transport failed: a remote CAN hub killed,
        a Broken pipe) ends the core, as it ends the service whose control cycle runs in its own threads
        (``bridge.service.server.serve``): the motion is stopped, the service told why (the ``core_ended`` note:
        its ``serve`` then ends with that reason) and the core closes. It stayed up with a dead CAN thread
        before, and after a ``faults/ack`` said "no fault held" while no frame went out (a safety trial)."""
        while not self._closed.wait(RUNNER_WATCH_S):
            failed = [r.error for r in self._runners if r.error is not None]
            if not failed:
                continue
            reason = "a CAN thread stopped: " + "; ".join(f"{type(e).__name__}: {e}" for e in failed)
            if self.motion is not None:
                try:
                    self.motion.stop(reason)
                except Exception:  # noqa: BLE001 — the bus is gone: the ECU's watchdog holds the valves at zero
                    pass
            self._note({"core_ended": reason})
            end = time.monotonic() + 1.0
            while not self._notes.empty() and time.monotonic() < end:  # the reason reaches the service first
                time.sleep(0.01)
            signal.raise_signal(signal.SIGINT)  # the main thread's serve() ends and closes the core (main)
            return

    def _watch_service(self) -> None:
        """Every :data:`SERVICE_WATCH_S`: has the service said anything (a call, its keep-alive) within
        :data:`SERVICE_SILENCE_S`? A service frozen (SIGSTOP), hung or swapped out no longer routes anyone's
        ``stop`` to this core (a peer's clients reach the core through its session): the core then brakes
        whatever runs — a goto, a maneuver, a track stream, a work session — as a lost router does with
        ``on_link_loss = stop``, and posts ``service_lost`` (the service's black box gets it over the socket once
        it reads again). When the service is heard again, ``service_restored``; nothing stopped resumes. Before,
        a work session ran on for as long as the service stayed frozen (a safety trial: 15.6 s, and on after
        SIGCONT). A message waiting unread on the socket counts as heard (this core's reader busy, not the
        service silent)."""
        lost = False
        while not self._closed.wait(SERVICE_WATCH_S):
            silent = time.monotonic() - self._heard
            if not lost:
                if silent < SERVICE_SILENCE_S or self._service_waiting():
                    continue
                lost = True
                self._heard_gap = 0.0  # the whole silence, measured by the reader when the service speaks again
                self._on_service_lost(silent)
            elif silent < SERVICE_SILENCE_S:
                lost = False
                gap = self._heard_gap
                self._post(
                    {
                        "event": "service_restored",
                        "silent_s": round(gap, 2),
                        "message": f"the service is heard again after {gap:.1f} s of silence; nothing stopped resumes",
                    }
                )

    def _on_service_lost(self, silent: float) -> None:
        motion = self.motion
        if motion is None:
            return
        try:  # first: the announcement must not delay it
            motion.stop(f"service lost: no word from the service for {silent:.1f} s")
        except Exception:  # noqa: BLE001 — the bus is gone: the ECU's watchdog holds the valves at zero
            pass
        self._post(
            {
                "event": "service_lost",
                "silent_s": round(silent, 2),
                "message": f"the service has said nothing for {silent:.1f} s (frozen, hung or overloaded): nobody "
                f"can reach this control core's stop through it; braking the hitch to rest (bound "
                f"{SERVICE_SILENCE_S:g} s)",
            }
        )

    def _post(self, event: dict[str, Any]) -> None:
        motion = self.motion
        if motion is not None:
            try:
                motion.post_event(event)
            except Exception:  # noqa: BLE001 — closing
                pass

    def _service_waiting(self) -> bool:
        """Whether a message from the service waits unread on the socket (poll, no wait)."""
        try:
            p = select.poll()
            p.register(self.conn.fileno(), select.POLLIN)
            return any(ev & select.POLLIN for _, ev in p.poll(0))
        except (OSError, ValueError):
            return False

    def _note(self, note: dict[str, Any]) -> None:
        """Tell the service what the core answered on its own (its black box records it); never blocks."""
        try:
            self._notes.put_nowait(note)
        except queue.Full:
            self.notes_dropped += 1

    def _writable(self, timeout_s: float) -> bool:
        """Whether the socket to the service takes a message now (poll: any descriptor number), waited for at most
        ``timeout_s`` without holding the lock the replies need."""
        try:
            p = select.poll()
            p.register(self.conn.fileno(), select.POLLOUT)
            return bool(p.poll(1000.0 * timeout_s))
        except (OSError, ValueError):
            return True  # let the send itself fail and end the thread

    def _send_notes(self) -> None:
        while not self._closed.is_set():
            try:
                note = self._notes.get(timeout=0.2)
            except queue.Empty:
                continue
            while not self._writable(0.2):  # a service that reads slowly: wait here, not under the lock
                if self._closed.is_set():
                    return
            with self._send_lock:
                try:
                    self.conn.send((0, "note", note))
                except (OSError, ValueError):
                    return

    def _take_stop_puts(self) -> None:
        """The puts and deletes on ``<prefix>/stop`` (:meth:`_open_zenoh`): each that names this key — exactly or
        by a wildcard that includes it (``fleet/*/hitch/stop``: a fleet's broadcast) — stops as the query does,
        and what waits in the ring behind it is taken with it (one stop, one note per burst). A fleet trial: a put
        was ignored and the hitch moved on. Under the normal policy (``SCHED_OTHER``) at the core's nice, as
        :meth:`_take_setpoints`: a flood costs this thread its share, never the real-time threads theirs."""
        _ordinary_policy()
        sub = self._stop_puts
        if sub is None:
            return
        exact = zenoh.KeyExpr(self.cfg.key("stop"))
        for sample in sub:  # ends when the subscriber is undeclared or the session closes
            if not zenoh.KeyExpr(str(sample.key_expr)).includes(exact):
                continue
            burst = 1
            while sub.try_recv() is not None:  # the rest of the burst, taken first: one stop for all of them (a put
                burst += 1  # arriving after the stop is taken by the next pass, a review: drained after, it was lost)
            ok, reply = self._call_safely("stop_report", ())
            answer = {"stopped": True, **reply} if ok else reply
            payload = sample.payload.to_bytes()[:1024]
            kind = "delete" if sample.kind == zenoh.SampleKind.DELETE else "put"
            self._note({"request": "stop", "ok": ok, "reply": answer, "payload": payload, "via": kind, "burst": burst})
            # a flood of them is a flood of stops: at most one every STOP_PUT_INTERVAL_S (the ring keeps the newest
            # meanwhile), which bounds this thread's work. What a flood on this key still costs the stop query is
            # Zenoh's delivery of the puts to this subscriber (5 threads, ~1 M puts/s: stop query median 15-18 ms,
            # max 98-119 ms, as without the interval, 19 / 75-166 ms; 2-3 / 4-7 ms with the flood on another key)
            time.sleep(STOP_PUT_INTERVAL_S)

    def _take_setpoints(self) -> None:
        """The setpoint puts from their ring (:meth:`_open_zenoh`), at most :data:`SETPOINT_MAX_HZ` a second after a
        burst of :data:`SETPOINT_BURST` (a token bucket): beyond that this thread sleeps and the ring keeps the
        newest :data:`SETPOINT_RING`, the older ones dropped in Zenoh. A stream of the documented 100 Hz, bursts
        after a network hiccup included, never waits. Under the normal policy (``SCHED_OTHER``) at the core's
        nice: a flood (a safety trial: ~350 000 puts a second from one client) costs this thread its CPU share,
        never the real-time threads theirs, and never delays the ``stop`` this session answers (before, each put
        ran this callback on the session's own thread: another client's ``stop`` waited 0.8–1.9 s behind them)."""
        _ordinary_policy()
        sub = self._setpoints
        if sub is None:
            return
        tokens, last = float(SETPOINT_BURST), time.monotonic()
        for sample in sub:  # ends when the subscriber is undeclared or the session closes
            now = time.monotonic()
            tokens = min(float(SETPOINT_BURST), tokens + (now - last) * SETPOINT_MAX_HZ)
            last = now
            if tokens < 1.0:
                time.sleep((1.0 - tokens) / SETPOINT_MAX_HZ)
                now = time.monotonic()
                tokens, last = min(float(SETPOINT_BURST), tokens + (now - last) * SETPOINT_MAX_HZ), now
            tokens -= 1.0
            try:
                self._on_setpoint(sample)
            except Exception:  # noqa: BLE001 — one bad put must not end the stream
                pass

    def _on_setpoint(self, sample: zenoh.Sample) -> None:
        """A streamed ``track/setpoint`` put (O(1)): refusals are counted and announced by the controller. A put
        beyond :data:`~bridge.service.schemas.MAX_SETPOINT_BYTES` is dropped before it is copied or parsed, counted in
        :attr:`setpoints_too_large`; on ``core-setpoints`` (:meth:`_take_setpoints`), never in the session's threads."""
        too_large = setpoint_too_large(len(sample.payload))
        if too_large is not None:  # whose it is cannot be known unread: counted against the live session, if any
            self.setpoints_too_large += 1
            self._call_safely("track_setpoint_refused", (LIVE_SESSION, too_large))
            return
        raw = sample.payload.to_bytes()
        try:
            r = parse_request("track/setpoint", raw)
        except RequestError as exc:  # nobody to answer: counted as a rejection of its session, if it names one
            self._call_safely("track_setpoint_refused", (setpoint_session(raw), str(exc)))
            return
        velocity = None if r.velocity is None else r.velocity.as_dict()  # type: ignore[attr-defined]
        self._call_safely("track_setpoint", (r.session, r.seq, r.pose.as_dict(), velocity))  # type: ignore[attr-defined]

    def _on_state_matching(self, status: zenoh.MatchingStatus) -> None:
        if status.matching:
            self._state_listened.set()
        else:
            self._state_listened.clear()

    def _publish_state(self, msg: dict[str, Any]) -> None:
        pub = self._state_pub
        try:
            data = to_json_bytes(msg)
        except Exception:  # noqa: BLE001 — as a put that fails
            return
        if self._state_to_service.is_set():  # the newest only: a slow reader skips states, never queues them
            self._state_slot = data
            self._state_ready.set()
        if pub is not None and not self._closed.is_set():
            try:
                pub.put(data)
            except Exception:  # noqa: BLE001 — the session is closing
                pass

    def _send_states(self) -> None:
        """The newest state to the service as a note, once it asked (``want_state``)."""
        while not self._closed.is_set():
            if not self._state_ready.wait(0.2):
                continue
            self._state_ready.clear()
            data, self._state_slot = self._state_slot, None
            if data is None:
                continue
            with self._send_lock:
                try:  # never waits under the lock the replies need: a service that reads slowly skips states
                    if not self._writable(0.0):
                        continue
                    self.conn.send((0, "note", {"state": data}))
                except (OSError, ValueError):
                    return

    def _publish_event(self, event: dict[str, Any]) -> None:
        if event.get("event") == "mode_changed":  # the service keeps the mode from this note, not the public key
            self._note({"mode": event.get("mode")})
        try:
            data = to_json_bytes(event)
        except Exception:  # noqa: BLE001 — as a put that fails: the outbox goes on
            return
        # the service's listeners (black box, terminal, the raise / lower switch) hear the core's events from
        # this note, never from the public key (anyone allowed to put there could forge one; a router cuts it)
        self._note({"event": data})
        pub = self._event_pub
        if pub is not None and not self._closed.is_set():
            try:
                pub.put(data)
            except Exception:  # noqa: BLE001
                pass

    def close(self, why: str = "service shutting down") -> None:
        """Brake and end everything (idempotent); ``why``: the running motion's abort reason."""
        if self._closed.is_set():
            return
        if self.motion is not None:
            self.motion.close(why=why)
        self._closed.set()
        for d in reversed(self._decls):
            _quiet(d.undeclare)
        for p in (self._state_pub, self._event_pub):
            if p is not None:
                _quiet(p.undeclare)
        if self.session is not None:
            _quiet(self.session.close)
        self._pool.shutdown(wait=False, cancel_futures=True)
        if self.parts is not None:
            self.parts.close()
        if self.recorder is not None:
            _quiet(self.recorder.close)

    # ------------------------------------------------------------------ calls
    def _methods(self) -> dict[str, Callable[..., Any]]:
        m = self.motion
        assert m is not None
        parts = self.parts
        ecu = None if parts is None else parts.ecu_node

        def sim_fault(settings: dict[str, Any]) -> Any:
            if ecu is None:
                raise RequestError(
                    "unavailable",
                    "no simulated ECU runs in this service (a real ECU is connected, or the twin runs in another "
                    "process); fault injection is only for the twin",
                )
            applied = ecu.apply_fault(settings)
            to_json = getattr(applied, "to_json", None)
            return to_json() if callable(to_json) else dict(settings)

        def sim_switch(position: str) -> list[str]:  # the twin's operator switch (docs/implements.md)
            tractor = None if parts is None else parts.tractor_node
            if tractor is None:
                raise RequestError(
                    "unavailable",
                    "sim/switch: no simulated tractor runs in this service (a real machine is connected); the "
                    "switch can only be pressed on the twin",
                )
            from bridge.link.hitch_switch import press_switch

            return press_switch(tractor.bus, position)  # type: ignore[arg-type]

        return {
            "stop": m.stop,
            "stop_report": m.stop_report,
            "jog": lambda *a, **k: m.jog(*a, **k).to_json(),
            "goto": lambda *a, **k: m.goto(*a, **k).to_json(),
            "run_maneuver": m.run_maneuver,
            "set_mode": m.set_mode,
            "mode": lambda: m.mode,
            "ack_faults": lambda: m.ack_faults().to_json(),
            "faults": lambda: [f.to_json() for f in m.faults],
            "current_state": m.current_state,
            "preview_start": m.preview_start,
            "track_start": lambda *a, **k: m.track_start(*a, **k).to_json(),
            "track_setpoint": m.track_setpoint,
            "track_setpoint_refused": m.track_setpoint_refused,
            "track_stop": m.track_stop,
            "select_implement": m.select_implement,
            "maneuver_control": m.maneuver_control,
            "lines_request": m.lines_request,
            "distance_travelled": m.distance_travelled,
            "sim_fault": sim_fault,
            "sim_switch": sim_switch,
            "post_event": m.post_event,
            "want_state": self._state_to_service.set,
            "work": lambda op, *a: m.work.dispatch(op, *a),  # work/… (bridge.service.work.WorkControl)
            "ping": lambda: os.getpid(),
        }

    def _call_safely(
        self, method: str, args: tuple[Any, ...], kwargs: dict[str, Any] | None = None
    ) -> tuple[bool, Any]:
        fn = self._table.get(method)
        if fn is None:
            return False, {"error": "internal", "message": f"unknown core method {method!r}"}
        try:
            return True, fn(*args, **(kwargs or {}))
        except Exception as exc:  # noqa: BLE001 — every failure goes back as the API's code and text
            code = error_code(exc)
            text = str(exc) if code != "internal" else f"internal error {type(exc).__name__}: {exc}"
            return False, {"error": code, "message": text[:500]}

    def _answer(self, call_id: int, method: str, args: tuple[Any, ...], kwargs: dict[str, Any]) -> None:
        ok, value = self._call_safely(method, args, kwargs)
        reply = (call_id, "ok", value) if ok else (call_id, "error", value["error"], value["message"])
        with self._send_lock:
            try:
                self.conn.send(reply)
            except (OSError, ValueError):
                pass

    def serve(self) -> None:
        """Answer the service's calls until its socket closes or it sends ``close``; its keep-alives
        (``alive``, no answer) and every call feed the watch of the service (:meth:`_watch_service`)."""
        self._heard = time.monotonic()
        threading.Thread(target=self._watch_service, name="core-service-watch", daemon=True).start()
        while True:
            try:
                msg = self.conn.recv()
            except (EOFError, OSError):  # the service went without a close: killed or crashed (a fleet trial read
                # "service shutting down" after a kill -9 of the service)
                self.close(why="the service ended without closing the core (killed or crashed)")
                return
            now = time.monotonic()
            self._heard_gap, self._heard = max(self._heard_gap, now - self._heard), now
            call_id, method, args, kwargs = msg
            if method == "alive":
                continue
            if method == "close":
                self.close()
                with self._send_lock:
                    try:
                        self.conn.send((call_id, "ok", None))
                    except (OSError, ValueError):
                        pass
                return
            if method in _PLANNING:
                try:
                    self._pool.submit(self._answer, call_id, method, args, kwargs)
                except RuntimeError:  # shutting down
                    return
            else:
                self._answer(call_id, method, args, kwargs)


#: mlockall(2) flags (Linux): what is mapped now, what is mapped later, each page locked when first touched
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4


def raise_core_to_realtime() -> str | None:
    """Every Python and Zenoh thread of this process under ``SCHED_FIFO`` (:mod:`bridge.service.scheduling`):
    the twin's runner at :data:`TWIN_RT_PRIORITY`, the control cycle and the planner's CAN thread at
    :data:`CONTROL_RT_PRIORITY`, the rest at :data:`CORE_RT_PRIORITY` — the calling thread too, so the
    threads it starts later (the motion threads) inherit it — and all of them on one CPU
    (:func:`~bridge.service.scheduling.pin_to_one_cpu`). None when done, else why not (the threads
    keep their nice values)."""
    named = {TWIN_THREAD: TWIN_RT_PRIORITY, "hitch-control": CONTROL_RT_PRIORITY, "CanLink-rt": CONTROL_RT_PRIORITY}
    failed: list[str] = []
    tids = []
    for t in threading.enumerate():
        if t.native_id is not None:
            tids.append(t.native_id)
            failed += raise_to_fifo([t.native_id], named.get(t.name, CORE_RT_PRIORITY))
    zenoh_tids = zenoh_thread_ids()
    failed += raise_to_fifo(zenoh_tids, CORE_RT_PRIORITY)
    if not failed:  # one CPU for them all (bridge.service.scheduling: fewer cross-CPU wake-ups)
        failed += pin_to_one_cpu([*tids, *zenoh_tids])[1]
    return "; ".join(sorted(set(failed))) if failed else None


def lock_memory() -> str | None:
    """Lock the process's pages in RAM (``mlockall(MCL_CURRENT | MCL_FUTURE | MCL_ONFAULT)``); None when
    done, else why not.

    A real-time process must not page-fault on its control path. Even with free memory and no swap, a
    kernel may evict *file-backed* pages it sees as cold (the code of the interpreter and of the
    numeric libraries; proactive reclaim such as DAMON's ``pageout`` does exactly that), and a thread
    that next runs such code waits for the disk — holding the interpreter lock, so every thread of the
    core waits with it. Locked pages are never evicted. ``MCL_ONFAULT`` locks pages as they are first
    touched instead of reading in every mapped library at once. Needs CAP_IPC_LOCK (root) or a large
    enough ``RLIMIT_MEMLOCK``."""
    import ctypes
    import ctypes.util

    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.mlockall(_MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT) != 0:
            return os.strerror(ctypes.get_errno())
    except (OSError, AttributeError) as exc:  # no libc / no mlockall here
        return str(exc)
    return None


def freeze_startup_objects() -> int:
    """Collect once, then exclude everything built so far (models, CasADi functions, planners, the
    twin) from the garbage collector's later passes (``gc.freeze``); returns how many were frozen.

    A full (generation 2) collection walks every tracked object while holding the interpreter lock:
    about 21–37 ms for the ~80 000 objects of a started service on a quiet machine, several times that
    on a loaded one — a pause of every thread of the process at once, the control cycle and the CAN
    threads included (a ~120 ms stall of the whole core was seen under the reliability bench's load).
    The start-up objects live as long as the process, so scanning them finds nothing; after the
    freeze a full collection walks only what came later (well under 1 ms)."""
    gc.collect()
    gc.freeze()
    return gc.get_freeze_count()


def _quiet(fn: Callable[[], Any]) -> None:
    try:
        fn()
    except Exception:  # noqa: BLE001
        pass


def main(argv: list[str]) -> int:
    """``python -m bridge.service.core.process FD CONFIG_JSON ENDPOINTS_JSON [login]``; with ``login`` the
    first message on the socket is ``("login", user, password, zid)`` for the core's Zenoh link (user and
    password None without a users file; zid None with one)."""
    fd, cfg_json, endpoints = int(argv[0]), argv[1], list(json.loads(argv[2]))
    nice_failed = _set_nice(CORE_NICE)  # first: every thread started from here on inherits it
    sys.setswitchinterval(SWITCH_INTERVAL_S)  # a thread that plans hands the GIL over within ~1 ms
    conn = multiprocessing.connection.Connection(fd)
    core: ControlCore | None = None
    try:
        login, zid = None, None
        if argv[3:4] == ["login"]:
            tag, user, password, zid = conn.recv()
            if tag != "login":
                raise RuntimeError(f"the control core expected its login first, got {tag!r}")
            login = None if user is None else (str(user), str(password))
        cfg = ServiceConfig.model_validate_json(cfg_json)
        core = ControlCore(cfg, conn, endpoints, nice_failed=nice_failed, login=login, zid=zid)
        try:
            ready = core.start()
        except (HitchError, OSError, zenoh.ZError) as exc:
            conn.send((0, "error", "start", f"{type(exc).__name__}: {exc}"))
            return 1
        core.send_ready(ready)
        core.serve()
    except KeyboardInterrupt:  # a SIGINT sent to the core itself (a terminal's Ctrl-C reaches only the service:
        pass  # the core runs in a process group of its own, CoreProcess.start)
    finally:
        # closing (a Zenoh client's session takes tens of ms to close): a second Ctrl-C, or the service's own
        # stop, must not cut it short — it did, and the interpreter's finalisation then reported every Ruckig
        # object of the daemon threads as "nanobind: leaked" (45 lines on a fleet operator's terminal)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if core is not None:
            core.close()
        conn.close()
    return 0


if __name__ == "__main__":  # run the module's canonical copy
    from bridge.service.core.process import main as _canonical_main

    code = _canonical_main(sys.argv[1:])
    # everything was closed explicitly; the daemon threads' objects (Ruckig's among them) would only be
    # reported as leaked by the interpreter's finalisation, so the process ends here
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _ordinary_policy() -> None:
    """This thread under the normal policy (``SCHED_OTHER``), its nice staying the core's: a thread started by the
    main thread after it went real-time, which a flood must cost its own share only."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except (OSError, AttributeError):
        pass
