"""The running service: CAN link (+ simulated ECU), motion control, Zenoh session.

:class:`HitchService` wires the pieces and owns their life cycle:

* CAN — a :class:`~bridge.link.can_link.CanLink` on the configured python-can bus, run in real time
  by a :class:`~bridge.link.realtime.RealtimeRunner`; by default the simulated cylinder ECU
  (:class:`~bridge.sim.can_node.EcuCanNode`) runs in the same process on the same
  ``virtual`` channel, so every reference takes the real path: limits check, AD scaling, codec,
  bus, ECU watchdog — and every measurement comes back the same way. A
  :class:`~.odometer.WheelOdometer` reads the tractor's wheel-based distance (PGN 65096) for
  maneuver ``wait_for`` steps; with the simulated ECU a :class:`~.odometer.SimulatedTractor`
  sends it at ``sim_ground_speed``.
* motion — a :class:`~bridge.service.motion.controller.MotionController` whose control thread streams references and
  publishes ``<prefix>/state`` (50 Hz, ``express``: no batching, so the period stays regular);
* Zenoh — one session (peer or client), one queryable per API key answering through
  :meth:`~bridge.service.api.ServiceAPI.handle` in one of three lanes (:data:`INLINE_KEYS`: O(1) keys,
  ``stop`` first of all, answered in the Zenoh callback; :data:`MOTION_KEYS_LANE`: goto, preset,
  maneuver run on their own small pool, so no planning or storage request queues ahead of them;
  everything else — planning, validation, storage, IK — on the worker pool, whose queue is bounded:
  beyond it a request is refused ``busy`` at once), each request stamped with its arrival time
  (its ``deadline_ms`` counts from then). Where the name is checked (``user_keys``: by default when this
  service's access control gives each user their own keys) every key but ``stop`` also answers as
  ``<prefix>/user/<name>/<key>``, a queryable of its own: the request of user ``<name>``, so admission, store
  owners and the black box know who asked;
  ``<prefix>/events`` and the liveliness token ``<prefix>/alive``;
* storage — :class:`~bridge.service.store.HitchStore` under the data directory;
* the operator terminal (``http``) — :func:`bridge.web.server.start_http`, loaded only when asked for.

Real time: the control thread and the CAN threads run at a raised OS priority (nice
:data:`REALTIME_NICE` and the real-time policy ``SCHED_FIFO``, :mod:`bridge.service.scheduling`; the
service's Zenoh threads under ``SCHED_FIFO`` too; needs root or CAP_SYS_NICE; otherwise a warning and
an event say so and the service runs on), and the interpreter's switch interval is set to :data:`SWITCH_INTERVAL_S` so a
thread that computes (a plan) hands the GIL to the control thread within about a millisecond
(``docs/faults.md``, *Threads or processes*).

Every HitchModel instance is used by one thread only (their CasADi buffers are shared state):
the control thread, the planning lock, the IK lock and the link each get their own.

:meth:`close` is idempotent and fast (< 1 s): motion stopped and the reference stream ended,
queryables and token undeclared, the session closed, the CAN threads stopped and the buses
shut down, the database checkpointed and closed. :func:`serve` runs a service until SIGINT or
SIGTERM.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from concurrent.futures import Executor, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any

import zenoh

from bridge.link.can_link import CanLink
from bridge.link.realtime import RealtimeRunner
from bridge.service.api import API_KEYS, ServiceAPI
from bridge.service.client import zenoh_reason
from bridge.service.config import ServiceConfig
from bridge.service.core.client import CoreProcess, MotionProxy
from bridge.service.core.process import STOP_PUT_INTERVAL_S, STOP_PUT_RING, freeze_startup_objects, lock_memory
from bridge.service.data_lock import DataDirLock
from bridge.service.gnss import restore_lines, start_twin_gnss
from bridge.service.machine import CanParts, build_controller, build_guard, build_model, service_info, start_can
from bridge.service.motion.controller import LIVE_SESSION, MotionController
from bridge.service.planning import GuardPlanning, InProcessPlanning, Planning
from bridge.service.scheduling import (
    CONTROL_RT_PRIORITY,
    ROUTER_RT_PRIORITY,
    TWIN_RT_PRIORITY,
    raise_to_fifo,
    set_thread_nice,
    thread_nice,
    zenoh_thread_ids,
)
from bridge.service.schemas import setpoint_too_large
from bridge.service.security import (
    INTERNAL_SOCKET_NAME,
    USER_SCOPE,
    InternalLink,
    access_policy_from_file,
    acl_scopes_users,
    apply_security,
    exposure_warnings,
    grant_internal_socket,
    grant_internal_user,
    read_users,
    scopable_user,
)
from bridge.service.signals import StopSignals
from bridge.service.stall_watch import StallWatch
from bridge.service.store import HitchStore
from bridge.service.wire import to_json_bytes
from bridge.service.work import unused_sim_terrain
from bridge.service.workers import PlanningWorkers, WorkerSpec, check_spec
from bridge.sim.can_node import EcuCanNode
from planner.errors import HitchError, HitchInputError
from planner.ik_qp.hitch_ik import IKSolver
from planner.trajectory import TrajectoryPlanner

if TYPE_CHECKING:
    from bridge.web.server import WebServer

__all__ = [
    "HitchService",
    "HitchServiceError",
    "ServiceStartError",
    "ServiceStopped",
    "serve",
    "INLINE_KEYS",
    "MOTION_KEYS_LANE",
    "to_json_bytes",
    "build_zenoh_config",
]

#: keys answered inside the Zenoh callback: O(1), no planning, no storage (``stop`` never waits for a pool)
INLINE_KEYS = frozenset(
    {"jog", "stop", "mode", "config", "faults/ack", "sim/fault", "track/start", "track/setpoint", "track/stop"}
)
#: motion requests: their own pool, so planning, validation and storage requests never queue ahead of them
MOTION_KEYS_LANE = frozenset({"goto", "presets/go", "maneuvers/run"})
#: threads of the motion lane
MOTION_WORKERS = 2
#: requests the worker pool takes per worker before further ones are refused ``busy`` at once
QUEUE_PER_WORKER = 2
#: nice value of the control and CAN threads (lower runs first; needs root or CAP_SYS_NICE)
REALTIME_NICE = -10
#: the interpreter's switch interval while a service runs [s] (Python's default: 0.005)
SWITCH_INTERVAL_S = 0.001
#: nice value of every other thread the service starts (request handling, Zenoh, outbox): above CPU-bound
#: programs (0), below the control and CAN threads; their work is O(1) (the expensive requests run in the
#: planning processes at nice +5), so a thread holding the interpreter lock is rarely put aside
SERVICE_NICE = -5
#: threads raised to :data:`REALTIME_NICE` (by name)
REALTIME_THREADS = frozenset({"hitch-control", "CanLink-rt", "EcuCanNode-rt"})


#: the longest path of a Unix socket Linux takes (sun_path is 108 bytes with its terminating NUL)
_UNIX_PATH_MAX = 107


def private_link_dir() -> Path:
    """A fresh 0700 directory for the control core's Unix socket (``core.sock``): under the temporary directory
    (``TMPDIR``), or — when the socket's path there would be longer than a Unix socket's (a long ``TMPDIR``: a
    review; the service failed to start with Zenoh's "path must be shorter than SUN_LEN") — under
    ``XDG_RUNTIME_DIR`` or ``/tmp``; :class:`ServiceStartError` naming ``TMPDIR`` when none is short enough."""
    tried = []
    for base in (None, os.environ.get("XDG_RUNTIME_DIR"), "/tmp"):
        if base is not None and not os.path.isdir(base):
            continue
        try:
            d = Path(tempfile.mkdtemp(prefix="hitch-core-link-", dir=base))
        except OSError as exc:  # not ours to write (an inherited XDG_RUNTIME_DIR of another user: a review)
            tried.append(f"{base or tempfile.gettempdir()} ({exc.strerror})")
            continue
        if len(os.fsencode(d / INTERNAL_SOCKET_NAME)) <= _UNIX_PATH_MAX:
            return d
        shutil.rmtree(d, ignore_errors=True)
        tried.append(str(d.parent))
    raise ServiceStartError(
        f"no directory for the control core's socket: under each of {', '.join(tried)} its path would be longer than "
        f"a Unix socket's {_UNIX_PATH_MAX} bytes or the directory could not be made: give TMPDIR a short directory "
        "this user may write"
    )


class HitchServiceError(HitchInputError):
    """The service asked for something it cannot do (e.g. an unknown listener kind)."""


class ServiceStartError(HitchServiceError):
    """The service cannot start (a port in use, a bus that cannot be opened …); says which and why."""


class ServiceStopped(HitchError, RuntimeError):
    """The running service lost a part it cannot run without (a CAN thread stopped)."""


def build_zenoh_config(cfg: ServiceConfig) -> zenoh.Config:
    """The session config: mode, endpoints, scouting, the link lease (``lease_s``), then the security
    file (if any)."""
    z = zenoh.Config()
    for path, value in (
        ("mode", cfg.mode),
        ("listen/endpoints", list(cfg.listen or ())),
        ("connect/endpoints", list(cfg.connect)),
        ("scouting/multicast/enabled", cfg.scouting),
        ("transport/link/tx/lease", round(cfg.lease_s * 1000.0)),
    ):
        z.insert_json5(path, json.dumps(value))
    if cfg.security is not None:
        apply_security(z, cfg.security)
    return z


class HitchService:
    """One service instance (see the module docstring). ``start()`` then ``close()``.

    Embedding it with ``control_core = "thread"`` (the control cycle in the caller's process): call
    :func:`bridge.service.core.process.freeze_startup_objects` after :meth:`start`, as :func:`serve`
    and the core process do. Without it a full garbage collection walks every start-up object while
    holding the interpreter lock: a pause of 75–84 ms of every thread was measured 8.6 s into a
    track stream, long enough for the ECU's 100 ms watchdog to trip (``references_lost``)."""

    def __init__(self, config: ServiceConfig, *, data_lock: DataDirLock | None = None):
        """``data_lock``: the data folder's lock, held by the caller already (``hitch serve`` holds it until its
        event log is closed, after the service's close); None: the service takes it and gives it up itself."""
        self.config = config
        self._lock_held_for_us = data_lock
        self.api: ServiceAPI | None = None
        self.motion: MotionController | None = None  # the controller when the core runs in this process
        self.core: CoreProcess | None = None  # the control core's process (``control_core = "process"``)
        self.link: CanLink | None = None
        self.ecu_node: EcuCanNode | None = None
        self.parts: CanParts | None = None
        self.store: HitchStore | None = None
        self._data_lock: DataDirLock | None = None  # the data folder, this service's alone while it runs
        self.planning: PlanningWorkers | None = None  # the planning processes (None: in-process planning)
        self.session: zenoh.Session | None = None
        self.warnings: list[str] = []
        #: whether each user's own keys are served (``<prefix>/user/<name>/<key>``; _serves_user_keys)
        self.user_keys = False
        self.http: WebServer | None = None
        self._runners: list[RealtimeRunner] = []
        self._decls: list[Any] = []  # zenoh queryables, subscribers and the liveliness token
        self._pool: ThreadPoolExecutor | None = None
        #: the earliest a request taken now may have arrived (this process's stalls: bridge.service.stall_watch);
        #: ticking from :meth:`start`, once this process's threads have their scheduling
        self._stall = StallWatch()
        self._motion_pool: ThreadPoolExecutor | None = None
        self._queued = 0  # requests waiting in or running on the worker pool
        self._queued_lock = threading.Lock()
        self._switch_interval: float | None = None  # the interpreter's, restored at close
        self._state_pub: zenoh.Publisher | None = None
        self._event_pub: zenoh.Publisher | None = None
        self._listeners: dict[str, list[Callable[[dict[str, Any]], None]]] = {"state": [], "event": []}
        self._latest_state: dict[str, Any] | None = None
        self._closed = False
        self._closed_event = threading.Event()  # set by close: ends the link watch
        self._routers_seen = False  # the link watch saw a router (a peer is watched from then on)
        self._close_lock = threading.Lock()
        self.close_duration_s: float | None = None
        self._service_nice_failed: str | None = None  # why the service threads could not be raised
        self._recorder: Any = None  # the CAN recorder when the core runs here
        self._state_asked = False  # the core sends its state over the private socket (asked when first wanted)
        self._sub_lock = threading.Lock()
        self._proxy: MotionProxy | None = None  # the controller's proxy when the core has its own process
        self._core_link: InternalLink | None = None  # the core's made-up login (a secured service, own process)
        self._core_link_dir: Path | None = None  # where its users file lies (removed at close)
        #: this service's instance on its prefix: "<start time, ns, 20 digits>-<Zenoh id>" (_watch_instances)
        self.instance = f"{time.time_ns():020d}"
        self._instances_met: set[str] = set()
        #: why this service must end (another, earlier service serves its prefix): :func:`serve` ends on it
        self.conflict: str | None = None

    @property
    def core_in_process(self) -> bool:
        """Whether the control core runs as threads of this process (else in :attr:`core`'s process)."""
        return self.core is None

    def start(self) -> HitchService:
        # every thread started from here on (ours, Zenoh's, the pools') inherits this thread's nice value
        me = threading.get_native_id()
        # only when the control core runs here: its process then needs its request threads raised; with the
        # core in its own process the service's threads stay at the caller's priority (they must not take
        # CPU from the core)
        in_process = self.config.control_core != "process"
        caller_nice = thread_nice(me) if in_process else None
        self._service_nice_failed = set_thread_nice(me, SERVICE_NICE) if caller_nice is not None else None
        try:
            return self._start()
        finally:
            if caller_nice is not None:
                set_thread_nice(me, caller_nice)  # the caller's own thread as it was (lowering is permitted)

    def _start(self) -> HitchService:
        cfg = self.config
        self._stall.start()  # at this thread's nice value, as the request threads it watches (close() ends it)
        try:
            # a new data dir is the service user's alone (the event log and the store name users and their
            # actions); one that exists keeps the permissions its owner gave it
            cfg.data_dir.mkdir(parents=True, exist_ok=True, mode=0o700)
            if self._lock_held_for_us is None:  # before the store or the event log is touched
                self._data_lock = DataDirLock(cfg.data_dir).acquire()
            self.store = HitchStore(cfg.database_path, limits=cfg.store_limits())
            ik: IKSolver | None = None
            planning: Planning | None = None
            # the profile, category and implement exist (an implement not in the tractor profile: refused here); the
            # implement itself goes to no guard as it is built (theirs, the core's, the planning's) but through the
            # implement service's restore, which checks its category and the persisted selection (docs/implements.md)
            check_spec(WorkerSpec(cfg.profile, cfg.category, cfg.control_rate, cfg.implement))
            if cfg.planning_processes > 0:  # they build their models while the rest starts
                spec = WorkerSpec(cfg.profile, cfg.category, cfg.control_rate, None)
                planning = self.planning = PlanningWorkers(spec, cfg.planning_processes).start()
            else:
                ik = IKSolver(build_model(cfg))
                ik.solve((0.0, float(build_model(cfg).neutral_pose.z), 0.0, 0.0))  # warm the solver before serving
            # with a security file too: a client's file (no logins checked, no access control) protects nothing
            self.warnings = exposure_warnings(cfg.listen or (), cfg.security)
            self.warnings.extend(unused_sim_terrain(cfg))  # a twin's terrain with no twin: said, not ignored
            policy = access_policy_from_file(cfg.security, cfg.prefix) if cfg.security is not None else None
            if cfg.security is not None:  # a missing or malformed users file named here, not by Zenoh's Rust error
                read_users(cfg.security)
            own_process = cfg.control_core == "process"
            private = self._open_zenoh(private_link=own_process and cfg.mode != "client")
            self._refuse_a_served_prefix()  # before the core, the CAN bus or any key is taken
            motion: Any
            if own_process:
                endpoints = [private] if private is not None else list(cfg.connect)
                link = self._core_link
                self.core = core = CoreProcess(
                    cfg,
                    endpoints,
                    on_note=self._core_note,
                    credentials=None if link is None else link.credentials,
                    zid=None if link is None else link.zid,
                ).start()
                self.warnings.extend(core.ready.get("warnings", []))
                motion = self._proxy = MotionProxy(core, TrajectoryPlanner(build_model(cfg), rate=cfg.control_rate))
                if planning is None:  # no planning processes: plan here, on a guard of the service's own
                    planning = InProcessPlanning(GuardPlanning(build_guard(cfg, build_model(cfg))), ik)
                info = dict(core.ready["info"])
                sim_fault = motion.sim_fault if core.ready.get("simulated_ecu") else None
            else:
                if cfg.can_log is not None:  # records the in-process bus (the core process records its own)
                    from bridge.service.blackbox import CanRecorder, announce_can_log_stop

                    self._recorder = CanRecorder.of_config(cfg)
                self.parts = parts = start_can(cfg, runners_out=self._runners)
                self.link, self.ecu_node = parts.link, parts.ecu_node
                self.motion, guard = build_controller(cfg, parts, on_state=self._on_state, on_event=self._on_event)
                if self._recorder is not None:
                    announce_can_log_stop(self._recorder, self.motion.outbox)
                motion, info = self.motion, service_info(cfg, guard)
                ecu_node = parts.ecu_node
                sim_fault = None if ecu_node is None else ecu_node.apply_fault
            self.user_keys = _serves_user_keys(cfg)
            info["user_keys"] = self.user_keys  # clients send on their user's keys only when this says so
            self.api = ServiceAPI(
                motion,
                ik,
                self.store,
                info,
                implement=cfg.implement,
                implement_source=cfg.implement_source,
                policy=policy,
                sim_fault=sim_fault,
                planning=planning,
            )
            # an implement named at start-up and not taken, or dropped (another category, not defined): said at start
            self.warnings.extend(self.api.implements.warnings)
            self.add_listener("event", self.api.implements.on_event)  # the operator's raise / lower switch
            self.add_listener("event", self.api.events.take)  # kept for events/recent
            if self.parts is not None:  # sim/switch on the in-process twin (the core process has its own)
                self.api.implements.use_twin(self.parts.tractor_node)
            self.warnings.extend(restore_lines(self.api, cfg.lines_file))  # the field's lines (store, file)
            self._pool = ThreadPoolExecutor(cfg.workers, thread_name_prefix="hitch-api")
            self._motion_pool = ThreadPoolExecutor(MOTION_WORKERS, thread_name_prefix="hitch-motion")
            self._declare_api()
            self._switch_interval = sys.getswitchinterval()
            sys.setswitchinterval(SWITCH_INTERVAL_S)
            if self.motion is not None:
                self.motion.start()
                self._raise_priorities()
            self._raise_router()
            if cfg.http is not None:
                self._start_http(cfg.http)
            if self.planning is not None:  # built their models meanwhile: ready before the service says so
                self.planning.warm(60.0)
            if cfg.connect:  # its routers are its way to the fleet
                threading.Thread(target=self._watch_links, name="hitch-link-watch", daemon=True).start()
        except BaseException:
            self.close()
            raise
        return self

    def nodes_reached(self) -> int | None:
        """How many routers and peers the service's session reaches now (None: no session, or it cannot be read)."""
        session = self.session
        if session is None:
            return None
        try:
            return len(list(session.info.routers_zid())) + len(list(session.info.peers_zid()))
        except Exception:  # noqa: BLE001 — the session is closing
            return None

    def _watch_links(self) -> None:
        """The routers of ``connect``: every :data:`LINK_WATCH_S`, how many routers the session reaches. When the
        last is lost, a ``link_lost`` event (in the black box) and, by ``on_link_loss`` (default ``stop``), the
        hitch braked to rest: nobody in the fleet can stop it now. ``link_restored`` when one is back; nothing
        stopped resumes. A client reached its router when its session opened; a peer is watched from the first
        router it reaches (one that connects to peers only has no router to lose). A session that cannot be
        read :data:`LINK_READ_FAILURES` times in a row counts as one that reaches none (said once)."""
        reached = self.config.mode == "client"
        failures = 0
        while not self._closed_event.wait(LINK_WATCH_S):
            session, api = self.session, self.api
            if session is None or api is None:
                return
            try:
                n = len(list(session.info.routers_zid()))
                failures = 0
            except Exception as exc:  # noqa: BLE001 — the session is closing, or Zenoh failed
                if self._closed:
                    return
                failures += 1
                if failures < LINK_READ_FAILURES:
                    continue
                if failures == LINK_READ_FAILURES:
                    print(f"hitch serve: warning: the link watch cannot read the session ({exc})", file=sys.stderr)
                n = 0
            if reached and n == 0:
                self._on_link_lost(api)
            elif not reached and n > 0 and (self.config.mode == "client" or self._routers_seen):
                self._announce(
                    api, {"event": "link_restored", "message": f"{n} router(s) reached again; nothing resumes"}
                )
            self._routers_seen = self._routers_seen or n > 0
            reached = n > 0

    def _on_link_lost(self, api: ServiceAPI) -> None:
        stop = self.config.on_link_loss == "stop"
        if stop:  # first: the announcement (a call to the core) must not delay it
            try:
                api.motion.stop("link lost: no node of connect reached")
            except Exception:  # noqa: BLE001 — the core is closing
                pass
        then = "braking it to rest (on_link_loss = stop)" if stop else "its motion runs on (on_link_loss = continue)"
        self._announce(
            api,
            {
                "event": "link_lost",
                "message": f"no node of connect ({', '.join(self.config.connect)}) is reached: the fleet can "
                f"neither see nor stop the hitch; {then}",
                "action": self.config.on_link_loss,
            },
        )

    @staticmethod
    def _announce(api: ServiceAPI, event: dict[str, Any]) -> None:
        try:
            api.motion.post_event(event)
        except Exception:  # noqa: BLE001 — the core is closing
            pass

    def _raise_priorities(self) -> None:
        """The control and CAN threads at :data:`REALTIME_NICE` and under ``SCHED_FIFO``
        (:data:`~bridge.service.scheduling.CONTROL_RT_PRIORITY`, the twin's runner
        :data:`~bridge.service.scheduling.TWIN_RT_PRIORITY`); when not permitted a warning and a
        ``realtime`` event say so, and the service runs on at normal priority."""
        failed: list[str] = []
        if self._service_nice_failed is not None:
            failed.append(f"service threads (nice {SERVICE_NICE}): {self._service_nice_failed}")
        for t in threading.enumerate():
            if t.name in REALTIME_THREADS and t.native_id is not None:
                why = set_thread_nice(t.native_id, REALTIME_NICE)
                if why is not None:
                    failed.append(f"{t.name}: {why}")
                rt = TWIN_RT_PRIORITY if t.name == "EcuCanNode-rt" else CONTROL_RT_PRIORITY
                if self.config.realtime:
                    failed += [f"{t.name} (SCHED_FIFO): {w}" for w in raise_to_fifo([t.native_id], rt)]
        if failed and self.motion is not None:
            text = (
                f"cannot raise the control and CAN threads to nice {REALTIME_NICE} ({'; '.join(sorted(set(failed)))}); "
                "running at normal priority (run as root or with CAP_SYS_NICE for a steadier control period)"
            )
            self.warnings.append(text)
            self.motion.outbox.put_event({"event": "realtime", "priority_raised": False, "message": text})
            self.motion.outbox.flush()

    def _raise_router(self) -> None:
        """This process's Zenoh threads under ``SCHED_FIFO`` at
        :data:`~bridge.service.scheduling.ROUTER_RT_PRIORITY`: they route ``stop`` to the control core
        (its own process) or hand it to the inline path (threads), and never take the interpreter lock
        (the queryables read ring channels). Not permitted: a warning, and they keep their nice value."""
        if not self.config.realtime:
            return
        failed = raise_to_fifo(zenoh_thread_ids(), ROUTER_RT_PRIORITY)
        if failed:
            self.warnings.append(
                f"the service's Zenoh threads could not be given real-time priority ({'; '.join(sorted(set(failed)))})"
            )

    def _refuse_a_served_prefix(self) -> None:
        """:class:`ServiceStartError` when another service already holds this prefix's liveliness token
        ``<prefix>/alive`` where this session reaches (asked for at most :data:`PREFIX_CHECK_S`). Two services
        on one prefix both answered every request — which machine took a ``goto`` or a ``stop`` was Zenoh's
        choice — and their state streams interleaved. A token Zenoh does not let this session see (an access
        list without ``liveliness_query`` on the prefix) is not found: the start goes on."""
        cfg, s = self.config, self.session
        assert s is not None
        key = cfg.key("alive")
        try:
            held = [str(r.ok.key_expr) for r in s.liveliness().get(key, timeout=PREFIX_CHECK_S) if r.ok is not None]
        except zenoh.ZError:  # the query could not be sent: nothing is known, as without the check
            return
        if held:
            where = ", ".join([*(cfg.connect or ()), *(cfg.listen or ())]) or "this network"
            raise ServiceStartError(
                f"prefix {cfg.prefix!r} is served already: another service holds its liveliness token {key} "
                f"(seen through {where}); two services on one prefix would both answer every request, a goto or "
                "stop reaching either machine. Stop that service, or give this one another prefix (--prefix)"
            )

    def _open_zenoh(self, *, private_link: bool) -> str | None:
        """Open the service's session; with ``private_link`` it also listens on an endpoint of its own for
        the core process, and returns that endpoint, the link :mod:`bridge.service.security` makes up: a Unix
        socket in a private directory (:func:`~bridge.service.security.grant_internal_socket`; no TCP port
        beside the configured ones: a fleet trial could not meet a port policy), or with a security file whose
        users file authenticates every link a loopback port and a user of its own
        (:func:`~bridge.service.security.grant_internal_user`).

        The private port is found free and then bound by Zenoh; if another socket took it in between
        (any outgoing connection on the machine may be given it as its local port), another port is
        tried, up to ``PRIVATE_PORT_TRIES`` times. A port the operator chose is never replaced."""
        cfg = self.config
        link_dir, users = None, False
        if private_link:  # the core's link: made up for it (docs/security.md), never a TCP port of its own
            link_dir = self._core_link_dir = private_link_dir()  # 0700; removed at close
            users = cfg.security is not None and bool(read_users(cfg.security))  # {}: no users file, or empty
        for _ in range(PRIVATE_PORT_TRIES if private_link else 1):
            private = f"tcp/127.0.0.1:{_free_port()}" if private_link else None
            z = build_zenoh_config(cfg)
            if link_dir is not None:
                self._core_link = link = (
                    grant_internal_user(z, cfg.prefix, link_dir)
                    if users
                    else grant_internal_socket(z, cfg.prefix, link_dir)
                )
                private = link.endpoint if link is not None and link.endpoint is not None else private
            if private is not None:
                z.insert_json5("listen/endpoints", json.dumps([*list(cfg.listen or ()), private]))
            try:
                self.session = zenoh.open(z)
                if link_dir is not None and users:  # Zenoh read the users when the session opened: the copy goes
                    shutil.rmtree(link_dir, ignore_errors=True)
                return private
            except zenoh.ZError as exc:  # e.g. the port is taken, a TLS file is unreadable
                error = exc
                if private is None or not private.startswith("tcp/") or private.removeprefix("tcp/") not in str(exc):
                    break  # not the private port's fault: retrying cannot help
        reason = zenoh_reason(error) if error is not None else "unknown"
        hint = ""
        if cfg.connect and "Unable to connect" in reason:  # (a fleet trial: a wrong password said only this)
            hint = "; check that a router listens there" + (
                ", and the login (transport.auth.usrpwd) and TLS files of --security: a router refuses a wrong "
                "password or certificate this way"
                if cfg.security is not None
                else ", and whether it requires a login or TLS (--security)"
            )
        raise ServiceStartError(
            f"cannot open the Zenoh session (listen {', '.join(cfg.listen or ()) or '-'}, connect "
            f"{', '.join(cfg.connect) or '-'}): {reason}{hint}"
        ) from None

    def _declare_api(self) -> None:
        """Queryables of the API keys (``stop`` and the setpoint stream: the core's own when it has a
        process), the state and event publishers or subscriptions, the liveliness token."""
        cfg, s = self.config, self.session
        assert s is not None
        if self.core is None:
            self._state_pub = s.declare_publisher(
                cfg.key("state"),
                encoding=zenoh.Encoding.APPLICATION_JSON,
                express=True,
                congestion_control=zenoh.CongestionControl.DROP,
                priority=zenoh.Priority.DATA_HIGH,
            )
            self._event_pub = s.declare_publisher(
                cfg.key("events"), encoding=zenoh.Encoding.APPLICATION_JSON, express=True
            )
            # the setpoint stream is put, not queried: refusals are counted and announced as events
            self._serve(s.declare_subscriber(cfg.key("track/setpoint"), _ring()), self._on_setpoint, "setpoints")
            gnss = getattr(self.motion, "gnss", None)  # the tractor's GNSS position (maneuver wait_for line)
            if gnss is not None:
                sub = s.declare_subscriber(cfg.key("tractor/gnss"), _ring())
                self._serve(sub, lambda m: gnss.take_payload(m.payload.to_bytes()), "gnss")
            twin_gnss = start_twin_gnss(cfg, self.parts, s)  # the simulated tractor's receiver (None: a real one)
            if twin_gnss is not None:
                self._decls.append(twin_gnss)
        # else the core publishes; this process's event listeners (terminal, black box, the raise / lower switch)
        # hear its events from its notes (_core_note), never from the public events key, where anyone allowed
        # to put could forge one and which a router outage cuts; its 50 Hz state is subscribed to only once
        # something here listens to it (_ensure_state_subscription)
        if self.core is None:  # a put on stop stops too (the core process takes its own); a small ring: they are alike
            stop_put = s.declare_subscriber(cfg.key("stop"), zenoh.handlers.RingChannel(STOP_PUT_RING))
            self._serve(stop_put, self._on_stop_put, "stop-put")
        for key in API_KEYS:
            if key == "stop" and self.core is not None:
                continue  # answered by the core process itself: no request here can delay it
            q = s.declare_queryable(cfg.key(key), _ring(), complete=True)
            self._serve(q, self._query_callback(key), key)
            if key != "stop" and self.user_keys:  # the request of a named user (security.USER_SCOPE): own lane too
                q = s.declare_queryable(cfg.key(f"{USER_SCOPE}/*/{key}"), _ring(), complete=True)
                self._serve(q, self._query_callback(key, scoped=True), f"{key}@user")
        self._decls.append(s.liveliness().declare_token(cfg.key("alive")))
        self._watch_instances()
        if self.api is not None:  # config says which run answers: motion ids, event and state seq restart with it
            self.api.info["instance"] = self.instance

    def _watch_instances(self) -> None:
        """Two services on one prefix that :meth:`_refuse_a_served_prefix` could not see — both started within
        its wait, or one started while the router between them was down — are found when they meet: each holds
        a second token ``<prefix>/instance/<start ns>-<zid>`` and watches ``<prefix>/instance/*``. Meeting
        another, both brake to rest and announce ``prefix_conflict``; the one that started later (the larger
        instance name) refuses every request but ``stop`` at once and ends itself (:attr:`conflict`,
        :func:`serve` exits on it), the earlier one serves on. Before, both answered every request: one ``goto``
        moved two tractors (a fleet trial). "Later" is by the computers' clocks (the start time in the name; the
        Zenoh id breaks a tie): with a clock far off the earlier service may be the one that ends — either way
        both have braked and one serves the prefix."""
        cfg, s = self.config, self.session
        assert s is not None
        self.instance = f"{self.instance}-{s.info.zid()}"
        self._decls.append(s.liveliness().declare_token(cfg.key(f"instance/{self.instance}")))
        watch = s.liveliness().declare_subscriber(cfg.key("instance/*"), _ring(), history=True)
        self._serve(watch, self._on_instance, "instances")

    def _on_instance(self, sample: zenoh.Sample) -> None:
        """A token on ``<prefix>/instance/*`` appeared (:meth:`_watch_instances`)."""
        other = str(sample.key_expr).rsplit("/", 1)[-1]
        if sample.kind != zenoh.SampleKind.PUT or other == self.instance or other in self._instances_met:
            return
        if not _INSTANCE_NAME.fullmatch(other):  # not a service's (it would sort first and end this one)
            return
        self._instances_met.add(other)
        later = other < self.instance  # the other started first: this one is the later
        text = (
            f"another service serves prefix {self.config.prefix!r} (instance {other}; this one {self.instance}): "
            "two services on one prefix both answer every request, a goto or stop reaching either machine; "
            "motion stopped; "
            + ("this service, the later one, ends itself" if later else "the later one ends itself, this one serves on")
        )
        if later:
            self.conflict = text  # from now on every request but stop is refused (_answer); serve() ends on it
        api = self.api
        if api is None:
            return
        try:
            api.motion.stop(f"prefix conflict: another service serves {self.config.prefix!r}")
        except Exception:  # noqa: BLE001 — the core is closing
            pass
        self._announce(api, {"event": "prefix_conflict", "message": text, "other": other, "ends": later})

    def _ensure_state_subscription(self) -> None:
        """With the core in its own process: ask it for its state over the private socket once a listener or a
        reader wants it (until then this process does not decode 50 messages a second that nobody uses). Never
        from the public ``state`` key: a router outage froze it there (the terminal showed a hitch "moving"
        that had braked), and anyone allowed to put there could draw a false one."""
        if self.core is None or self._closed:
            return
        with self._sub_lock:
            if self._state_asked or self._closed:
                return
            self._state_asked = True
        core = self.core

        def ask() -> None:  # on a thread of its own: a reader may be the thread that reads the core's answers
            while not self._closed:  # asked again until the core answers (a failed ask left the terminal blank)
                try:
                    core.call("want_state")
                    return
                except Exception:  # noqa: BLE001 — a slow or closing core: again in a second, unless closed
                    self._closed_event.wait(1.0)

        threading.Thread(target=ask, name="hitch-want-state", daemon=True).start()

    def _core_note(self, note: dict[str, Any]) -> None:
        """A note from the core over the private socket: an event it published (its JSON), handed to this
        process's ``event`` listeners; a request it answered itself (``stop``), given to the API's request
        hook (the black box); or its new mode (kept by the proxy). Never taken from the public ``events``
        key, where anyone may put a ``mode_changed`` or a forged fault."""
        for kind in ("state", "event"):  # the JSON the core published, to this process's listeners of that kind
            raw = note.get(kind)
            if not isinstance(raw, (bytes, bytearray)):
                continue
            try:
                msg = json.loads(raw)
            except ValueError:
                return
            if isinstance(msg, dict):
                if kind == "state":
                    self._latest_state = msg
                for cb in list(self._listeners[kind]):
                    _call(cb, msg)
            return
        if "mode" in note and isinstance(self._proxy, MotionProxy):
            self._proxy.on_mode_note(note["mode"])
            return
        api = self.api
        hook = None if api is None else api.on_request
        if hook is not None and note.get("request"):
            hook(str(note["request"]), None, bytes(note.get("payload") or b""), bool(note.get("ok")), note.get("reply"))

    def _start_http(self, addr: str) -> None:
        try:
            from bridge.web.server import start_http  # the operator terminal, loaded only when asked for
        except ImportError as exc:
            raise ServiceStartError(f"--http {addr}: the operator terminal is not available ({exc})") from None
        try:
            users = read_users(self.config.security) if self.config.security is not None else None
            self.http = start_http(
                self, addr, user=self.config.http_user, users=users, extra_hosts=self.config.http_hosts
            )
        except OSError as exc:  # the port is taken, the address is not local …
            raise ServiceStartError(f"--http {addr}: cannot listen ({exc})") from None

    # ------------------------------------------------------------------ Zenoh callbacks
    def _serve(self, source: Any, handle: Callable[[Any], None], name: str) -> None:
        """Take what a queryable or subscriber receives from its channel on a thread of its own.

        Zenoh puts each query or sample into the channel (:func:`_ring`) without running Python: its
        runtime threads never wait for this interpreter's lock, so routing — the control core's
        ``stop`` and its replies, the core's state — goes on however busy the request handlers are."""
        self._decls.append(source)

        def run() -> None:
            for item in source:  # ends when the queryable/subscriber is undeclared or the session closes
                try:
                    handle(item)
                except Exception:  # noqa: BLE001 — a bug in one request must not end the lane
                    pass

        threading.Thread(target=run, name=f"hitch-z-{name}", daemon=True).start()

    def _query_callback(self, key: str, *, scoped: bool = False) -> Callable[[zenoh.Query], None]:
        """``scoped``: the queryable of ``<prefix>/user/*/<key>``; the user is the key's chunk (with access
        control on, Zenoh lets only that user send it: security.scope_acl_users)."""
        exact = self.config.key(key)
        head, tail = self.config.key(USER_SCOPE) + "/", "/" + key

        def on_query(query: zenoh.Query) -> None:
            got = str(query.key_expr)
            user = got[len(head) : -len(tail)] if scoped and got.startswith(head) and got.endswith(tail) else None
            if (got != exact and not scoped) or (scoped and not scopable_user(user)):
                # a wildcard query (e.g. 'hitch/**') reaches every queryable; answering it would run
                # motion commands nobody asked for by name, so only exact keys are served
                query.drop()
                return
            received = self._stall.arrival()  # now, or after a stall of this process the tick before it
            payload = b"" if query.payload is None else query.payload.to_bytes()
            self.dispatch(key, payload, lambda ok, data: _reply(query, ok, data), received=received, user=user)

        return on_query

    def _on_stop_put(self, sample: zenoh.Sample) -> None:
        """A put or delete on ``<prefix>/stop`` — exactly, or by a wildcard that includes it (a fleet's broadcast
        ``fleet/*/hitch/stop``): a stop as the query's (any payload; nothing to answer). Before, a put was ignored
        and the hitch moved on (a fleet trial)."""
        if not zenoh.KeyExpr(str(sample.key_expr)).includes(zenoh.KeyExpr(self.config.key("stop"))):
            return
        self.dispatch("stop", sample.payload.to_bytes(), lambda ok, data: None, received=time.monotonic())
        time.sleep(STOP_PUT_INTERVAL_S)  # a flood of them: one stop per interval, the ring keeping the newest

    def _on_setpoint(self, sample: zenoh.Sample) -> None:
        """A ``track/setpoint`` put: handled at once (O(1)); its reply goes nowhere (rejections are
        counted in the state's ``track`` entry and announced by a ``track_setpoint_rejected`` event)."""
        api = self.api
        if api is None or self._closed:
            return
        too_large = setpoint_too_large(len(sample.payload))
        if too_large is not None:  # dropped before it is copied or parsed (as the core process does)
            refused = getattr(api.motion, "track_setpoint_refused", None)
            if callable(refused):
                refused(LIVE_SESSION, too_large)
            return
        api.handle("track/setpoint", sample.payload.to_bytes(), None, received=time.monotonic())

    def dispatch(
        self,
        key: str,
        payload: bytes,
        respond: Callable[[bool, bytes], None],
        *,
        received: float | None = None,
        user: str | None = None,
        inline: Executor | None = None,
    ) -> None:
        """Answer one request in its lane (see the module docstring): ``respond(ok, json_bytes)``
        is called exactly once, from the lane's thread. ``received``: its arrival
        (``time.monotonic()``, default now); ``user``: who sent it (None: not named; ServiceAPI.handle);
        ``inline``: where the O(1) keys (:data:`INLINE_KEYS`) run (default: the caller's thread, as Zenoh's
        callback; the operator terminal gives its own threads, so its event loop never waits). Never blocks
        otherwise: the lanes' pools take the rest."""
        t = self._stall.arrival() if received is None else received
        pool = self._motion_pool if key in MOTION_KEYS_LANE else None if key in INLINE_KEYS else self._pool
        if pool is None:
            if inline is not None:
                try:
                    inline.submit(self._answer, respond, key, payload, t, False, user)
                    return
                except RuntimeError:  # that executor shut down: answer here
                    pass
            self._answer(respond, key, payload, t, user=user)
            return
        if pool is self._pool:
            with self._queued_lock:
                full = self._queued >= QUEUE_PER_WORKER * self.config.workers
                if not full:
                    self._queued += 1
            if full:
                respond(
                    False,
                    to_json_bytes(
                        {
                            "error": "busy",
                            "message": f"{key}: {self._queued} requests are waiting for the service's workers "
                            f"(allowed: {QUEUE_PER_WORKER * self.config.workers}); send it again later",
                        }
                    ),
                )
                return
        try:
            pool.submit(self._answer, respond, key, payload, t, pool is self._pool, user)
        except RuntimeError:  # pool shut down: the service is closing
            self._answer(respond, key, payload, t, pool is self._pool, user)

    def _answer(
        self,
        respond: Callable[[bool, bytes], None],
        key: str,
        payload: bytes,
        received: float,
        queued: bool = False,
        user: str | None = None,
    ) -> None:
        try:
            if self.api is None or self._closed:
                ok, reply = False, {"error": "unavailable", "message": f"{key}: the service is shutting down"}
            elif self.conflict is not None and key != "stop":  # it ends: a goto here could move a second tractor
                why = f"{key}: refused, the service ends: {self.conflict}"
                ok, reply = False, {"error": "unavailable", "message": why}
            else:
                ok, reply = self.api.handle(key, payload, user, received=received)
            data = to_json_bytes(reply)
        except Exception as exc:  # noqa: BLE001 — the query is answered whatever happened
            ok, data = False, to_json_bytes({"error": "internal", "message": f"{key}: {type(exc).__name__}"})
        finally:
            if queued:
                with self._queued_lock:
                    self._queued -= 1
        respond(ok, data)

    # ------------------------------------------------------------------ state and events
    def add_listener(self, kind: str, callback: Callable[[dict[str, Any]], None]) -> None:
        """In-process subscription to ``"state"`` or ``"event"`` dicts (e.g. the web terminal)."""
        if kind not in self._listeners:
            raise HitchServiceError(f"kind must be 'state' or 'event', got {kind!r}")
        self._listeners[kind].append(callback)
        if kind == "state":
            self._ensure_state_subscription()

    def remove_listener(self, kind: str, callback: Callable[[dict[str, Any]], None]) -> None:
        if callback in self._listeners.get(kind, []):
            self._listeners[kind].remove(callback)

    @property
    def latest_state(self) -> dict[str, Any] | None:
        """The newest state message (with the core in its own process the first read subscribes to it)."""
        self._ensure_state_subscription()
        return self._latest_state

    def _on_state(self, msg: dict[str, Any]) -> None:
        self._latest_state = msg
        pub = self._state_pub
        if pub is not None and not self._closed:
            try:
                pub.put(to_json_bytes(msg))
            except Exception:  # the session is closing
                pass
        for cb in list(self._listeners["state"]):
            _call(cb, msg)

    def _on_event(self, event: dict[str, Any]) -> None:
        pub = self._event_pub
        if pub is not None and not self._closed:
            try:
                pub.put(to_json_bytes(event))
            except Exception:
                pass
        for cb in list(self._listeners["event"]):
            _call(cb, event)

    # ------------------------------------------------------------------ shutdown
    def close(self) -> float:
        """Stop motion, close Zenoh, CAN and the database; returns the time it took [s]."""
        with self._close_lock:
            if self._closed:
                return self.close_duration_s or 0.0
            t0 = time.monotonic()
            self._stall.close()
            if self.motion is not None:
                self.motion.close()
            if self.core is not None:
                _quiet(self.core.close)  # it brakes, ends its stream and its session
            self._closed = True
            self._closed_event.set()
            if self.http is not None:
                _quiet(self.http.close)
            for d in reversed(self._decls):
                _quiet(d.undeclare)
            self._decls.clear()
            for p in (self._state_pub, self._event_pub):
                if p is not None:
                    _quiet(p.undeclare)
            if self.session is not None:
                _quiet(self.session.close)
            if self._core_link_dir is not None:  # the made-up user's file or the core's socket: gone with the session
                shutil.rmtree(self._core_link_dir, ignore_errors=True)
            for pool in (self._pool, self._motion_pool):
                if pool is not None:
                    pool.shutdown(wait=False, cancel_futures=True)
            if self.planning is not None:
                _quiet(self.planning.close)
            if self._switch_interval is not None:
                sys.setswitchinterval(self._switch_interval)
            if self.parts is not None:
                self.parts.close()
            else:  # a start that failed half-way: the runners it started
                for r in reversed(self._runners):
                    r.stop(0.5)
            if self._recorder is not None:
                _quiet(self._recorder.close)
            if self.store is not None:
                _quiet(self.store.close)
            if self._data_lock is not None:
                self._data_lock.release()
            self.close_duration_s = time.monotonic() - t0
            return self.close_duration_s

    def __enter__(self) -> HitchService:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()


#: period of the link watch (HitchService._watch_links) [s]
LINK_WATCH_S = 0.1
#: reads of the session that fail in a row before the link watch counts it as reaching no router
LINK_READ_FAILURES = 5

#: queries (or samples) a key's channel holds while its thread is busy; beyond it the oldest is dropped
#: (its querier gets no reply, as from a busy service) — Zenoh never waits for Python
CHANNEL_CAPACITY = 256


def _serves_user_keys(cfg: ServiceConfig) -> bool:
    """Serve ``<prefix>/user/<name>/<key>`` (``user_keys``; ``"auto"``: only where the name is checked: this
    service's own access control gives each user their own keys, security.acl_scopes_users). Behind a
    router whose access control does that, the operator says so with ``user_keys = true``; without a check
    anyone could claim any name (another user's admission allowance and store limits)."""
    if cfg.user_keys != "auto":
        return bool(cfg.user_keys)
    return cfg.security is not None and cfg.mode != "client" and acl_scopes_users(cfg.security)


#: a service's instance name on its prefix (_watch_instances): start time [ns] in 20 digits, '-', its Zenoh id
_INSTANCE_NAME = re.compile(r"\d{20}-[0-9a-f]{1,32}")


def _ring() -> Any:
    return zenoh.handlers.RingChannel(CHANNEL_CAPACITY)


#: how many loopback ports the service tries for the core process's private link (see _open_zenoh)
PRIVATE_PORT_TRIES = 5
#: how long the start waits for another service's liveliness token on its prefix [s]
#: (_refuse_a_served_prefix; a router answers from its table at once: the bound is for a peer that does not)
PREFIX_CHECK_S = 2.0


def _free_port() -> int:
    """A TCP port free on 127.0.0.1 now (for the core's private link)."""
    import socket

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _reply(query: zenoh.Query, ok: bool, data: bytes) -> None:
    """Answer a Zenoh query once and finalise it."""
    try:
        if ok:
            query.reply(query.key_expr, data, encoding=zenoh.Encoding.APPLICATION_JSON)
        else:
            query.reply_err(data, encoding=zenoh.Encoding.APPLICATION_JSON)
    except Exception:  # the session closed under us: nothing left to answer to
        pass
    finally:
        query.drop()


def _call(cb: Callable[[dict[str, Any]], None], arg: dict[str, Any]) -> None:
    try:
        cb(arg)
    except Exception:  # a listener's bug must not stop the control thread
        pass


def _quiet(fn: Callable[[], object]) -> None:
    try:
        fn()
    except Exception:
        pass


def serve(
    config: ServiceConfig,
    *,
    ready: Callable[[HitchService], None] | None = None,
    data_lock: DataDirLock | None = None,
) -> float:
    """Run a service until SIGINT/SIGTERM; returns the shutdown time [s]. ``data_lock``: the data folder's lock
    when the caller holds it (:class:`HitchService`)."""
    with StopSignals() as stop:
        return _serve_until(stop, config, ready, data_lock)


def _serve_until(
    stop: StopSignals,
    config: ServiceConfig,
    ready: Callable[[HitchService], None] | None,
    data_lock: DataDirLock | None = None,
) -> float:
    """:func:`serve`'s body under its signal handlers (``stop``)."""
    service = HitchService(config, data_lock=data_lock).start()
    if service.motion is not None:  # the control cycle runs in this process: as the core process does
        freeze_startup_objects()  # no full-GC pause over the start-up objects
        why = lock_memory()  # no page of the control path evicted
        if why is not None:
            service.warnings.append(f"memory not locked ({why}); pages may be evicted and fault back in")
    try:
        if ready is not None:
            ready(service)
        while not stop.wait(0.5):
            core = service.core
            if service.conflict is not None:
                raise ServiceStopped(service.conflict)
            if core is not None and not core.alive:
                raise ServiceStopped(core.end_reason())
            if any(r.error is not None for r in service._runners):
                raise ServiceStopped(
                    "a CAN thread stopped: " + "; ".join(repr(r.error) for r in service._runners if r.error is not None)
                )
    finally:
        took = service.close()
    return took
