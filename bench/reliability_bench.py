"""Reliability benchmark: motion safety of a running service under request load, CPU load and link faults.

Scenarios (``--only load,cpu,faults,jog``; each starts its own service; all traffic on 127.0.0.1, no
multicast; every child runs in its own process group and is killed in a ``finally``; CPU hogs also end
on their own after the scenario's duration):

* ``load`` — **moving under load**: the service runs in this process (:class:`HitchService` with a
  :class:`ServiceConfig`) with the simulated ECU on a python-can ``virtual`` channel. With the control
  core in its own process (the default) the channel is in that process, which records every frame to
  its CAN log (``can_log``, candump format, flushed every 0.25 s); with ``--control-core thread`` a
  sniffer bus in this process records them. Everything that loads the service runs in OTHER
  processes, so this process's GIL carries only the service and the sniffer: a *mover* (back-and-forth
  full-speed gotos over 80 % of the workspace, every ``--stop-every``-th one stopped at a random time of
  its cruise; the operator's client: ``HitchClient(realtime=True)`` unless ``--mover-priority ordinary``),
  ``--clients`` load clients (threads in ``--clients-per-process`` processes, each with its own
  Zenoh session and a ``state`` subscription) sending a mix of ``ik``, ``config``, ``presets/list``,
  ``maneuvers/list``, ``maneuvers/validate`` (a 40-step script) and ``plan`` (speed 0.05…1) after
  ``--maneuvers`` scripts and 10 presets were stored, a *monitor* recording ``state`` and ``events``, and
  ``--hogs-per-core`` × cores CPU-bound processes, for ``--duration`` s. Then **idle** for
  ``--idle-duration`` s under the same hogs (the hitch holding after its last motion, no clients).
* ``cpu`` — idle CPU of ``hitch serve`` at rest, no load: utime + stime from ``/proc/<pid>/stat`` of the
  service and every process it started (its control core and planning processes) over
  ``--cpu-duration`` s, summed, as % of one core; a second window after a goto to ``HOLD_GOAL``, the
  hitch at rest holding that pose (the reference re-sent at the control rate). Once with the embedded simulated ECU
  (the default ``hitch serve``) and once for the planner side alone: the ECU then runs as
  ``hitch ecu-sim --interface remote`` on a CAN hub bound to 127.0.0.1 (``bridge.link.loopback``);
  without one that figure is reported as not measurable.
* ``faults`` — one-way (and two-way) link loss during a full-speed goto, through the twin's
  ``sim/fault`` key (``{"cut": "planner_to_ecu" | "ecu_to_planner" | "both" | "none"}``); skipped with a
  line saying why when the service refuses the key.
* ``jog`` — jog takeover of a full-speed goto at each of the 8 workspace faces.

Definitions (every time below is ``time.time()``, one system clock shared by all processes):

* **reference times** are the ``timestamp`` of each sniffed 0xFF21 frame. python-can's virtual bus
  stamps a frame in ``VirtualBus.send`` (``timestamp = time.time()`` unless the *sending* bus was opened
  with ``preserve_timestamps``, which the service does not do) before it copies the frame into every
  receiver's queue (can/interfaces/virtual.py, python-can 4.6): the sniffer reads the sender's send
  time, however late it dequeues the frame. **Reference period** = differences of consecutive
  reference times inside the window (a gap in the stream, for any reason, shows as a long period).
* **watchdog trips** = increments of the simulated ECU's own counter
  (``ecu_node.ecu.watchdog.trip_count``, read in this process before and after the window) and,
  independently, rising edges of the watchdog bit (bit 1 of the system-state byte, byte 8 of 0xFF22)
  in the sniffed measurements inside the window.
* **false faults** = ``fault`` events with ``t`` in the window, and the fault names any ``state``
  message in the window carries in ``ecu.faults`` (nothing is cut in these windows).
* **stop honoured latency** = ``T_brake − T_cmd``. ``T_cmd``: the mover's clock just before it sends
  ``stop``. The stop takes effect when the service installs the braking plan; the first reference
  after that instant is the first braking reference. The instant itself is not on the bus (at the
  hitch's speeds a reference changes by about half an AD count per cycle, so braking cannot be seen in
  the counts for 100 ms or more), so the bench bounds it from above by what the service reports only
  after installing it: the ``t`` of the first ``state`` message reporting the stop motion
  (``motion_id`` = the id ``stop`` answered, else ``motion == "stop"``) and the ``t`` of its
  ``motion_started`` event; ``T_effect`` = the earlier of the two (not before ``T_cmd``) and
  ``T_brake`` = the first reference time ≥ ``T_effect``. The figure can therefore be late by up to one
  period, never early. Also reported: the stop's reply time at the client, the way to the service
  (``t`` of the stop's reply — when the service's callback took it — minus ``T_cmd``: the mover's
  process sending beside the hogs, Zenoh, the router; the rest of the figure is the service's) and ``T_still − T_cmd``,
  ``T_still`` = the time of the first reference change after which the counts stay the same for
  0.3 s (the reference at rest; the next command may move it again later).
* **fault latency** (``faults``) = first ``fault`` event or ``state`` with ``ecu.faults`` after the cut
  minus the time the cut was requested; **motion after the link returns** = largest distance of the
  measured pose (``state``; position |(Δx, Δz)| in mm, angles in mrad) over ``--fault-watch`` s from
  the first fresh measurement (age ≤ 0.1 s) after the link was restored, and the largest change of the
  0xFF21 counts in that time.
* **overshoot** (``jog``) = largest measured pose (``state``) beyond the face, signed outward
  (mm for x, z; mrad for roll, pitch; negative: the hitch stayed inside), also for the commanded
  reference pose; plus whether a goto back to the centre is accepted afterwards.

Run: .venv/bin/python bench/reliability_bench.py [--quick] [--only load,cpu,faults,jog] [--json FILE]
(``--quick``: 15 s moving, 30 s idle, 5 clients, 15 s CPU windows; the reported figures use the full run.)
"""

from __future__ import annotations

import argparse
import bisect
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

try:  # imported as a module (tests/test_bench_helpers.py)
    from bench._common import free_port, kill_group, machine_note, percentiles_ms, proc_cpu_seconds, write_json
except ImportError:  # run as a script: bench/ is sys.path[0]
    from _common import (  # type: ignore[no-redef, import-not-found]
        free_port,
        kill_group,
        machine_note,
        percentiles_ms,
        proc_cpu_seconds,
        write_json,
    )

ROOT = Path(__file__).resolve().parent.parent
POSE = ("x", "z", "roll", "pitch")
RATE_KEY = {"x": "vx", "z": "vz", "roll": "vroll", "pitch": "vpitch"}
REFERENCE_PGN = 0xFF21
MEASUREMENT_PGN = 0xFF22
WATCHDOG_BIT = 0x02
CUTS = ("planner_to_ecu", "ecu_to_planner", "both")
TARGETS = {
    "period_p99_ms": 25.0,
    "period_max_ms": 60.0,
    "stop_p99_ms": 50.0,
    "fault_ms": 300.0,
    "cpu_planner_pct": 5.0,
    "cpu_embedded_pct": 10.0,
    "overshoot_mm": 2.0,
    "overshoot_mrad": 2.0,
}
HOG_CODE = "import sys, time\nend = time.monotonic() + float(sys.argv[1])\nwhile time.monotonic() < end:\n    pass\n"


# ========================================================================== pure helpers (tested, no service)
def pgn_of(arbitration_id: int) -> int:
    """J1939 PGN of a 29-bit identifier (PDU2 messages such as 0xFF21: data page, PF and PS)."""
    pf = (arbitration_id >> 16) & 0xFF
    pgn = (arbitration_id >> 8) & 0x3FFFF
    return pgn if pf >= 0xF0 else pgn & 0x3FF00


def window(times: Sequence[float], t0: float, t1: float) -> np.ndarray:
    """The sorted times within [t0, t1]."""
    a = np.sort(np.asarray(times, float))
    return a[(a >= t0) & (a <= t1)]


def periods(times: Sequence[float] | np.ndarray) -> np.ndarray:
    """Differences of consecutive (sorted) times [s]."""
    a = np.sort(np.asarray(times, float))
    return np.diff(a) if a.size > 1 else np.zeros(0)


def period_figures(times: Sequence[float] | np.ndarray) -> dict:
    """p50/p99/max [ms] and count of the periods of ``times`` [s], plus how many exceed 25, 60 and 100 ms."""
    d = periods(times)
    return {
        **percentiles_ms(d),
        "over_25_ms": int((d > 0.025).sum()),
        "over_60_ms": int((d > 0.060).sum()),
        "over_100_ms": int((d > 0.100).sum()),
    }


def read_steal_ticks() -> int:
    """The machine's stolen time so far (``/proc/stat`` ``cpu`` line, field 8, all CPUs, USER_HZ ticks):
    time the hypervisor ran something else while one of this machine's virtual CPUs wanted to run."""
    try:
        with open("/proc/stat") as f:
            return int(f.readline().split()[8])
    except (OSError, IndexError, ValueError):
        return 0


class StealSampler:
    """Samples the stolen time every ``period_s`` on a thread of its own, to tell a stall of this
    machine's virtual CPUs (the host ran another guest) from a stall of the service."""

    def __init__(self, period_s: float = 0.02) -> None:
        self.samples: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._period = period_s
        self._thread = threading.Thread(target=self._run, name="steal-sampler", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            self.samples.append((time.time(), read_steal_ticks()))
            self._stop.wait(self._period)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(1.0)

    def stolen_s(self, t0: float, t1: float) -> float:
        """CPU time stolen from all virtual CPUs between ``t0`` and ``t1`` [s] (from the samples around them)."""
        if not self.samples:
            return 0.0
        ts = [t for t, _ in self.samples]
        i0 = max(0, bisect.bisect_right(ts, t0) - 1)
        i1 = min(len(ts) - 1, bisect.bisect_left(ts, t1))
        return (self.samples[i1][1] - self.samples[i0][1]) / float(os.sysconf("SC_CLK_TCK"))


def stall_steal(times: Sequence[float] | np.ndarray, steal: StealSampler, t0: float, t1: float, over_s: float) -> dict:
    """For every period longer than ``over_s`` in ``times`` within [t0, t1]: its length and the time the host
    stole from this machine's CPUs meanwhile [ms]; and the stolen share of the whole window."""
    w = np.asarray(window(times, t0, t1))
    gaps = []
    for a, b in zip(w[:-1], w[1:], strict=True):
        if b - a > over_s:
            gaps.append({"period_ms": 1e3 * (b - a), "stolen_ms": 1e3 * steal.stolen_s(a, b)})
    span = max(t1 - t0, 1e-9)
    return {"stalls": gaps, "stolen_share_of_window": steal.stolen_s(t0, t1) / (span * (os.cpu_count() or 1))}


def rising_edges(samples: Iterable[tuple[float, int]], bit: int, t0: float, t1: float) -> int:
    """How often ``bit`` goes from clear to set between consecutive samples (t, byte) with t in [t0, t1]
    (the sample before t0 counts as the previous one)."""
    prev: bool | None = None
    n = 0
    for t, byte in sorted(samples):
        on = bool(byte & bit)
        if t >= t0 and t <= t1 and prev is False and on:
            n += 1
        if t > t1:
            break
        prev = on
    return n


def first_at_or_after(sorted_times: Sequence[float], t: float) -> float | None:
    """The first of ``sorted_times`` ≥ t, or None."""
    i = bisect.bisect_left(sorted_times, t)
    return float(sorted_times[i]) if i < len(sorted_times) else None


def stop_effect_time(
    t_cmd: float, stop_id: int | None, states: Iterable[Mapping], events: Iterable[Mapping]
) -> float | None:
    """Latest possible instant the stop took effect: the earlier of the ``t`` of the first state message
    reporting the stop motion and of its ``motion_started`` event, both at or after ``t_cmd``; None if
    neither was seen. ``states``/``events`` are dicts with ``t``, ``motion_id`` and ``motion`` /
    ``event`` and ``kind``."""

    def is_stop(mid: object, kind: object) -> bool:
        return mid == stop_id if stop_id is not None else kind == "stop"

    cands = [float(s["t"]) for s in states if float(s["t"]) >= t_cmd and is_stop(s.get("motion_id"), s.get("motion"))][
        :1
    ]
    cands += [
        float(e["t"])
        for e in events
        if e.get("event") == "motion_started"
        and float(e.get("t", -1.0)) >= t_cmd
        and is_stop(e.get("motion_id"), e.get("kind"))
    ][:1]
    return max(t_cmd, min(cands)) if cands else None


def stop_latency(t_cmd: float, t_effect: float | None, reference_times: Sequence[float]) -> float | None:
    """``T_brake − T_cmd`` [s]: the first reference time at or after the stop took effect (see the module
    docstring); None when the effect or a later reference is missing."""
    if t_effect is None:
        return None
    t_brake = first_at_or_after(reference_times, max(t_cmd, t_effect))
    return None if t_brake is None else t_brake - t_cmd


def still_time(refs: Sequence[tuple[float, Sequence[int]]], t0: float, t1: float, quiet_s: float = 0.3) -> float | None:
    """The time of the first reference change in [t0, t1] after which the counts stay unchanged for
    ``quiet_s`` (the hitch's reference at rest); None if they never rest that long in the window
    (``refs``: (t, counts) sorted by t). The next command may start a new motion after the rest: the
    window is not read to its end."""
    last: float | None = None
    prev: Sequence[int] | None = None
    for t, c in refs:
        if t > t1:
            break
        if last is not None and t - last > quiet_s:
            return last  # quiet for longer than quiet_s since the last change
        if t >= t0 and prev is not None and tuple(c) != tuple(prev):
            last = t
        prev = c
    return None


def outward_excess(values: Iterable[float], bound: float, outward: int) -> float | None:
    """Largest (value − bound) · outward (outward = +1 for a max face, −1 for a min face); None if empty."""
    a = np.asarray(list(values), float)
    return float(((a - bound) * outward).max()) if a.size else None


def max_displacement(poses: Sequence[Mapping[str, float]]) -> tuple[float, float] | None:
    """Largest |(Δx, Δz)| [m] and largest |Δroll|, |Δpitch| [rad] of ``poses`` from the first one."""
    if not poses:
        return None
    p = np.array([[q[k] for k in POSE] for q in poses], float)
    d = p - p[0]
    return float(np.hypot(d[:, 0], d[:, 1]).max()), float(np.abs(d[:, 2:]).max())


def verdict(value: float | None, limit: float) -> str:
    """``ok`` if value ≤ limit, ``FAIL`` if above, ``-`` when not measured."""
    if value is None:
        return "-"
    return "ok" if value <= limit else "FAIL"


# ========================================================================== processes
def spawn(role: str, *args: str) -> subprocess.Popen:
    """This script in another process (own process group) playing ``role``; stdin/stdout are pipes."""
    return subprocess.Popen(
        [sys.executable, __file__, "--role", role, *args],
        cwd=ROOT,
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )


def start_hogs(n: int, seconds: float) -> list[subprocess.Popen]:
    """``n`` CPU-bound processes that end by themselves after ``seconds``."""
    return [
        subprocess.Popen([sys.executable, "-c", HOG_CODE, f"{seconds:.1f}"], start_new_session=True) for _ in range(n)
    ]


def wait_ready(procs: Sequence[subprocess.Popen], timeout_s: float) -> None:
    """Each child prints one ``ready`` line once connected; raise if one does not in time."""
    end = time.monotonic() + timeout_s
    for p in procs:
        box: list[str] = []
        th = threading.Thread(target=lambda p=p, box=box: box.append(p.stdout.readline() if p.stdout else ""))
        th.daemon = True
        th.start()
        th.join(max(0.1, end - time.monotonic()))
        if not box or "ready" not in box[0]:
            raise RuntimeError(f"a child process did not get ready within {timeout_s:g} s: {box}")


def go(procs: Sequence[subprocess.Popen]) -> None:
    for p in procs:
        if p.stdin is not None:
            p.stdin.write("go\n")
            p.stdin.flush()


def await_go() -> bool:
    print("ready", flush=True)
    return sys.stdin.readline().strip() == "go"  # '' when the parent died: end


def read_json(path: str) -> Any:
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


class LatestState:
    """One ``state`` subscription of a client: the newest sample and a condition to wait on."""

    def __init__(self, client: Any) -> None:
        self.cond = threading.Condition()
        self.last: dict = {}
        self.n = 0
        client.subscribe("state", self._on)

    def _on(self, s: dict) -> None:
        with self.cond:
            self.last = s
            self.n += 1
            self.cond.notify_all()

    def wait_until(self, pred: Any, timeout_s: float) -> bool:
        end = time.monotonic() + timeout_s
        with self.cond:
            while not (self.last and pred(self.last)):
                left = end - time.monotonic()
                if left <= 0:
                    return False
                self.cond.wait(left)
        return True


def workspace_of(client: Any) -> dict[str, tuple[float, float]]:
    ws = client.config()["limits"]["workspace"]
    return {k: (float(ws[k][0]), float(ws[k][1])) for k in POSE}


def centre(ws: Mapping[str, tuple[float, float]]) -> dict[str, float]:
    return {k: 0.5 * (lo + hi) for k, (lo, hi) in ws.items()}


def maneuver_script(i: int, steps: int, ws: Mapping[str, tuple[float, float]]) -> str:
    rng = np.random.default_rng(1000 + i)
    lines = [
        f"name: m{i:03d}",
        "description: stored by the reliability bench",
        "timeout: 120",
        "steps:",
        "  - speed: 0.6",
    ]
    for k in range(steps):
        if k % 3 == 2:
            lines.append("  - wait: 0.2")
            continue
        g = {d: float(lo + (0.1 + 0.8 * rng.random()) * (hi - lo)) for d, (lo, hi) in ws.items()}
        lines.append("  - goto: {" + ", ".join(f"{d}: {v:.4f}" for d, v in g.items()) + "}")
    return "\n".join(lines) + "\n"


# ========================================================================== roles (other processes)
#: what ``--secured`` protects the service with
SECURED_KINDS = {
    "users": "a users file and access control by username",
    "certificates": "TLS with client certificates (mTLS) and access control by certificate name; no users file",
}


def secured_files(directory: str, kind: str = "users") -> tuple[str, str, str]:
    """A secured service's files in ``directory``: its security file, the client file every client of the
    bench uses (one operator) and the endpoint scheme (``tcp`` or ``tls``). ``kind`` (:data:`SECURED_KINDS`):
    ``users``: a users file and access control with one operator, whom every client logs in as;
    ``certificates``: a CA, the service's certificate for 127.0.0.1 and one operator's client certificate
    (made with the ``openssl`` command), mutual TLS and access control by certificate name."""
    import secrets

    from bridge.service.security import (
        AccessPolicy,
        Credentials,
        SecuritySettings,
        TlsSettings,
        security_json5,
        write_users_file,
    )

    d = Path(directory)
    server, client = d / "service.json5", d / "operator.json5"
    if kind == "users":
        password = secrets.token_urlsafe(16)
        users = write_users_file(d / "users.txt", {"operator": password})
        server.write_text(
            security_json5(SecuritySettings(users_file=users, access=AccessPolicy(operators=("operator",))))
        )
        client.write_text(security_json5(SecuritySettings(credentials=Credentials("operator", password))))
        return str(server), str(client), "tcp"
    if kind != "certificates":
        raise ValueError(f"--secured must be one of {', '.join(SECURED_KINDS)}, got {kind!r}")

    def openssl(*args: str) -> None:
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True, timeout=60)

    ec = ("-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes")
    openssl("req", "-x509", *ec, "-days", "2", "-keyout", "ca-key.pem", "-out", "ca.pem", "-subj", "/CN=bench-ca")
    for name, san in (("service", "IP:127.0.0.1"), ("operator", "DNS:operator")):
        openssl("req", *ec, "-keyout", f"{name}-key.pem", "-out", f"{name}.csr", "-subj", f"/CN={name}")
        (d / f"{name}.ext").write_text(f"subjectAltName={san}\nextendedKeyUsage=serverAuth,clientAuth\n")
        openssl(
            "x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem", "-CAcreateserial",
            "-days", "2", "-out", f"{name}.pem", "-extfile", f"{name}.ext",
        )  # fmt: skip

    def tls(name: str) -> TlsSettings:
        return TlsSettings(
            certificate=d / f"{name}.pem", private_key=d / f"{name}-key.pem", root_ca=d / "ca.pem", mutual=True
        )

    server.write_text(
        security_json5(SecuritySettings(tls=tls("service"), access=AccessPolicy(operator_cert_names=("operator",))))
    )
    client.write_text(security_json5(SecuritySettings(tls=tls("operator"))))
    return str(server), str(client), "tls"


def role_monitor(a: argparse.Namespace) -> None:
    """Record ``state`` (compact) and ``events`` until ``go`` + ``--seconds`` or SIGTERM; write ``--out``."""
    from bridge.service.client import HitchClient

    states: list[dict] = []
    events: list[dict] = []
    done = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: done.set())

    def on_state(s: dict) -> None:
        ecu = s.get("ecu") or {}
        ref = s.get("reference") or {}
        states.append(
            {
                "t": s.get("t"),
                "seq": s.get("seq"),
                "motion_id": s.get("motion_id"),
                "motion": s.get("motion"),
                "moving": s.get("moving"),
                "faults": ecu.get("faults") or [],
                "watchdog": ecu.get("watchdog"),
                "age": ecu.get("measurement_age_s"),
                "pose": s.get("pose"),
                "ref": ref.get("pose"),
            }
        )

    with HitchClient([a.connect], timeout_s=5, security=a.client_security) as c:
        c.subscribe("state", on_state)
        c.subscribe("events", events.append)
        if not await_go():
            return
        done.wait(a.seconds)
    Path(a.out).write_text(json.dumps({"states": states, "events": events}))


def role_mover(a: argparse.Namespace) -> None:
    """Back-and-forth full-speed gotos for ``--seconds``; every ``--stop-every``-th is stopped mid-cruise."""
    from bridge.service.client import HitchClient, ServiceError

    rng = np.random.default_rng(a.seed)
    stops: list[dict] = []
    moves: dict[str, Any] = {"accepted": 0, "refused": {}, "not_finished_in_time": 0}
    with HitchClient(
        [a.connect], timeout_s=5, realtime=a.mover_priority == "realtime", security=a.client_security
    ) as c:
        ws = workspace_of(c)
        mid_ = centre(ws)
        ends = [{**mid_, **{k: mid_[k] + s * 0.4 * (ws[k][1] - ws[k][0]) for k in ("x", "z")}} for s in (-1.0, 1.0)]
        latest = LatestState(c)
        if not await_go():
            return
        end = time.monotonic() + a.seconds
        k = 0
        while time.monotonic() < end and k < 100_000:
            goal = ends[k % 2]
            k += 1
            try:
                r = c.goto(goal)
            except ServiceError as exc:
                moves["refused"][exc.code] = moves["refused"].get(exc.code, 0) + 1
                time.sleep(0.2)
                continue
            moves["accepted"] += 1
            mid, dur = int(r["motion_id"]), float(r.get("duration", 5.0))
            if a.stop_every > 0 and k % a.stop_every == 0:
                time.sleep(float(rng.uniform(0.3, max(0.35, 0.6 * dur))))
                t_cmd = time.time()
                try:
                    sr = c.stop()
                    stops.append(
                        {"t_cmd": t_cmd, "t_reply": time.time(), "stop_id": sr.get("motion_id"), "t_taken": sr.get("t")}
                    )
                except ServiceError as exc:
                    stops.append({"t_cmd": t_cmd, "t_reply": time.time(), "stop_id": None, "error": exc.code})
                latest.wait_until(lambda s: not s.get("moving"), 10.0)
            elif not latest.wait_until(
                lambda s, mid=mid: (
                    (s.get("motion_id") or 0) > mid or (s.get("motion_id") == mid and not s.get("moving"))
                ),
                dur + 5.0,
            ):
                moves["not_finished_in_time"] += 1
        try:
            c.stop()
        except ServiceError:
            pass
    out = {"stops": stops, "moves": moves, "priority": a.mover_priority, "realtime_refused": c.realtime_refused}
    Path(a.out).write_text(json.dumps(out))


def role_load(a: argparse.Namespace) -> None:
    """``--threads`` clients (own sessions) sending mixed requests for ``--seconds``; per-key counts and latencies."""
    from bridge.service.client import HitchClient, ServiceError

    kinds = ("ik", "config", "presets/list", "maneuvers/list", "maneuvers/validate", "plan")
    lock = threading.Lock()
    lat: dict[str, list[float]] = {k: [] for k in kinds}
    codes: dict[str, dict[str, int]] = {k: {} for k in kinds}
    state_samples = [0]
    with HitchClient([a.connect], timeout_s=5, security=a.client_security) as c0:
        ws = workspace_of(c0)
    script = maneuver_script(999, 40, ws)
    clients = [HitchClient([a.connect], timeout_s=10, security=a.client_security) for _ in range(a.threads)]
    subs = [LatestState(c) for c in clients]
    try:
        if not await_go():
            return
        end = time.monotonic() + a.seconds

        def worker(i: int) -> None:
            c, rng = clients[i], np.random.default_rng(a.seed * 100 + i)
            for _ in range(1_000_000):
                if time.monotonic() >= end:
                    return
                key = kinds[int(rng.integers(len(kinds)))]
                pose = {d: float(lo + rng.random() * (hi - lo)) for d, (lo, hi) in ws.items()}
                payloads: dict[str, dict] = {
                    "ik": pose,
                    "config": {},
                    "presets/list": {},
                    "maneuvers/list": {},
                    "maneuvers/validate": {"script": script},
                    "plan": {"goal": pose, "speed_scale": float(rng.uniform(0.05, 1.0))},
                }
                payload = payloads[key]
                t0 = time.perf_counter()
                code = "ok"
                try:
                    c.request(key, payload)
                except ServiceError as exc:
                    code = exc.code
                dt = time.perf_counter() - t0
                with lock:
                    lat[key].append(dt)
                    codes[key][code] = codes[key].get(code, 0) + 1

        threads = [threading.Thread(target=worker, args=(i,), daemon=True) for i in range(a.threads)]
        for th in threads:
            th.start()
        for th in threads:
            th.join(a.seconds + 30)
        state_samples[0] = sum(s.n for s in subs)
    finally:
        for c in clients:
            c.close()
    out = {k: {"codes": codes[k], "latency": percentiles_ms(lat[k])} for k in kinds}
    Path(a.out).write_text(json.dumps({"requests": out, "state_samples": state_samples[0]}))


# ========================================================================== the in-process service + sniffer
class Sniffer:
    """A python-can virtual bus on the service's channel: 0xFF21 (t, id, data) and 0xFF22 (t, state byte)."""

    def __init__(self, channel: str) -> None:
        import can

        self.bus = can.Bus(interface="virtual", channel=channel)
        self.refs: list[tuple[float, int, bytes]] = []
        self.meas: list[tuple[float, int]] = []
        self._stop = threading.Event()
        self._th = threading.Thread(target=self._run, name="bench-sniffer", daemon=True)
        self._th.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            f = self.bus.recv(0.1)
            if f is None:
                continue
            pgn = pgn_of(f.arbitration_id)
            if pgn == REFERENCE_PGN:
                self.refs.append((f.timestamp, f.arbitration_id, bytes(f.data)))
            elif pgn == MEASUREMENT_PGN and len(f.data) == 8:
                self.meas.append((f.timestamp, f.data[7]))

    def reference_times(self) -> list[float]:
        return sorted(t for t, _, _ in list(self.refs))

    def reference_counts(self) -> list[tuple[float, tuple[int, ...]]]:
        import can

        from bridge.isobus.codec import PositionCounts, decode_frame

        out: list[tuple[float, tuple[int, ...]]] = []
        for t, aid, data in sorted(list(self.refs)):
            p = decode_frame(can.Message(arbitration_id=aid, data=data, is_extended_id=True)).payload
            if isinstance(p, PositionCounts):
                out.append((t, p.as_tuple()))
        return out

    def close(self) -> None:
        self._stop.set()
        self._th.join(2)
        self.bus.shutdown()


class LogSniffer(Sniffer):
    """The same frames read from the service's CAN log (``can_log``, candump format, flushed every
    0.25 s) when the control core runs in its own process (its virtual channel is not in this one).
    Timestamps are the sender's: python-can's virtual bus stamps a frame in ``send`` and the recorder
    writes that stamp."""

    def __init__(self, path: Path) -> None:  # noqa: D107 — no bus of its own
        self.path = path
        self.refs = []
        self.meas = []

    def _read(self) -> None:
        import can

        refs: list[tuple[float, int, bytes]] = []
        meas: list[tuple[float, int]] = []
        if self.path.exists():
            try:
                for f in can.LogReader(str(self.path)):
                    pgn = pgn_of(f.arbitration_id)
                    if pgn == REFERENCE_PGN:
                        refs.append((f.timestamp, f.arbitration_id, bytes(f.data)))
                    elif pgn == MEASUREMENT_PGN and len(f.data) == 8:
                        meas.append((f.timestamp, f.data[7]))
            except (ValueError, IndexError):  # a line being written: what came before it is complete
                pass
        self.refs, self.meas = refs, meas

    def reference_times(self) -> list[float]:
        self._read()
        return super().reference_times()

    def reference_counts(self) -> list[tuple[float, tuple[int, ...]]]:
        self._read()
        return super().reference_counts()

    def close(self) -> None:
        pass


class InProcessService:
    """:class:`HitchService` in this process on a private virtual channel, with a :class:`Sniffer`
    (or, with the control core in its own process, a :class:`LogSniffer` on the core's CAN log)."""

    def __init__(
        self,
        data_dir: str,
        planning_processes: int | None = None,
        control_core: str | None = None,
        realtime: bool | None = None,
        security: tuple[str, str, str] | None = None,
    ) -> None:
        """``security``: (the service's security file, a client's, the endpoint scheme) for a secured service."""
        from bridge.service.client import HitchClient
        from bridge.service.config import load_service_config
        from bridge.service.server import HitchService

        port = free_port()
        self.endpoint = f"{'tcp' if security is None else security[2]}/127.0.0.1:{port}"
        channel = f"bench-reliability-{os.getpid()}-{port}"
        log = Path(data_dir) / "bus.log"
        cfg = load_service_config(
            listen=[self.endpoint],
            data_dir=data_dir,
            can_channel=channel,
            planning_processes=planning_processes,
            control_core=control_core,
            realtime=realtime,
            security=None if security is None else security[0],
        )
        self.client_security = None if security is None else security[1]
        if cfg.control_core == "process":
            cfg = cfg.model_copy(update={"can_log": log})
            self.sniffer: Sniffer = LogSniffer(log)
        else:
            self.sniffer = Sniffer(channel)
        self.svc = HitchService(cfg)
        try:
            self.svc.start()
            with HitchClient([self.endpoint], timeout_s=10, security=self.client_security) as c:
                latest = LatestState(c)
                if not latest.wait_until(lambda s: (s.get("ecu") or {}).get("online"), 20.0):
                    raise RuntimeError("the simulated ECU never came online")
        except BaseException:
            self.close()
            raise

    def watchdog_trips(self) -> int | None:
        """The simulated ECU's own trip counter (None if this build does not expose it)."""
        try:
            return int(self.svc.ecu_node.ecu.watchdog.trip_count)  # type: ignore[union-attr]
        except AttributeError:  # the ECU runs in the core's process: the bus's watchdog bit counts
            return None

    def close(self) -> None:
        try:
            self.svc.close()
        finally:
            self.sniffer.close()


def wait_rest(latest: LatestState, timeout_s: float = 15.0) -> bool:
    return latest.wait_until(lambda s: not s.get("moving"), timeout_s)


def try_request(client: Any, key: str, payload: dict, timeout_s: float = 5.0) -> tuple[bool, str]:
    from bridge.service.client import ServiceError

    try:
        client.request(key, payload, timeout_s=timeout_s)
        return True, ""
    except ServiceError as exc:
        return False, f"{exc.code}: {exc}"


# ========================================================================== scenarios
def bench_load(a: argparse.Namespace) -> dict:
    """Moving under load (``--duration``), then idle (``--idle-duration``), same hogs (module docstring)."""
    from bridge.service.client import HitchClient

    tmp = tempfile.mkdtemp(prefix="hitch-reliability-")
    security = secured_files(tmp, a.secured) if a.secured else None
    service = InProcessService(tmp, a.planning_processes, a.control_core, a.realtime, security)
    steal = StealSampler()
    procs: list[subprocess.Popen] = []
    hogs: list[subprocess.Popen] = []
    res: dict[str, Any] = {}
    try:
        ep = service.endpoint
        sec = [] if security is None else ["--client-security", security[1]]
        with HitchClient([ep], timeout_s=30, security=service.client_security) as c:
            ws = workspace_of(c)
            saved = sum(
                try_request(c, "maneuvers/save", {"name": f"m{i:03d}", "script": maneuver_script(i, 20, ws)}, 30)[0]
                for i in range(a.maneuvers)
            )
            presets = sum(
                try_request(c, "presets/save", {"name": f"p{i}", "pose": {"z": 0.1 + 0.01 * i}})[0] for i in range(10)
            )
        res["stored"] = {"maneuvers": saved, "maneuvers_asked": a.maneuvers, "presets": presets}
        n_hogs = a.hogs_per_core * (os.cpu_count() or 1)
        hogs = start_hogs(n_hogs, a.duration + a.idle_duration + 120)
        mon_out, mov_out = f"{tmp}/monitor.json", f"{tmp}/mover.json"
        mon_s = str(a.duration + a.idle_duration + 60)
        monitor = spawn("monitor", "--connect", ep, "--seconds", mon_s, "--out", mon_out, *sec)
        mover_args = [
            *sec,
            "--connect",
            ep,
            "--seconds",
            str(a.duration),
            "--seed",
            "7",
            "--stop-every",
            str(a.stop_every),
        ]
        mover_args += ["--mover-priority", a.mover_priority]
        mover = spawn("mover", *mover_args, "--out", mov_out)
        loads, load_outs = [], []
        left, i = a.clients, 0
        while left > 0:
            n = min(left, a.clients_per_process)
            load_outs.append(f"{tmp}/load{i}.json")
            load_args = [*sec, "--connect", ep, "--seconds", str(a.duration), "--threads", str(n), "--seed", str(i + 1)]
            loads.append(spawn("load", *load_args, "--out", load_outs[-1]))
            left, i = left - n, i + 1
        procs = [monitor, mover, *loads]
        wait_ready(procs, 120)
        trips0 = service.watchdog_trips()
        go(procs)
        t0 = time.time()
        print(f"load: moving for {a.duration:g} s, {a.clients} clients, {n_hogs} hogs", flush=True)
        for p in (mover, *loads):
            try:
                p.wait(a.duration + 60)
            except subprocess.TimeoutExpired:
                kill_group(p)
        t1 = min(time.time(), t0 + a.duration)
        trips1 = service.watchdog_trips()
        with HitchClient([ep], timeout_s=5, security=service.client_security) as c:
            try_request(c, "stop", {})
            wait_rest(LatestState(c), 15)
        time.sleep(2.0)
        i0 = time.time()
        print(f"load: idle for {a.idle_duration:g} s under the hogs", flush=True)
        time.sleep(a.idle_duration)
        i1 = time.time()
        trips2 = service.watchdog_trips()
        monitor.send_signal(signal.SIGTERM)
        try:
            monitor.wait(60)
        except subprocess.TimeoutExpired:
            pass
        mon = read_json(mon_out) or {"states": [], "events": []}
        mov = read_json(mov_out) or {"stops": [], "moves": {}}
        lds = [read_json(p) for p in load_outs]
        refs = service.sniffer.reference_times()
        counts = service.sniffer.reference_counts()
        meas = list(service.sniffer.meas)
    finally:
        for p in (*procs, *hogs):
            kill_group(p)
        service.close()
        steal.close()
    states, events = mon["states"], mon["events"]

    def faults_in(w0: float, w1: float) -> dict:
        fe = [e for e in events if e.get("event") == "fault" and w0 <= float(e.get("t", 0)) <= w1]
        names = sorted({f for s in states if s.get("t") and w0 <= s["t"] <= w1 for f in s.get("faults") or []})
        return {"fault_events": len(fe), "fault_names_in_state": names, "messages": [e.get("message") for e in fe][:5]}

    lat, reply, still, taken, missing = [], [], [], [], 0
    for s in mov["stops"]:
        eff = stop_effect_time(s["t_cmd"], s.get("stop_id"), states, events)
        x = stop_latency(s["t_cmd"], eff, refs)
        if x is None:
            missing += 1
            continue
        lat.append(x)
        reply.append(s["t_reply"] - s["t_cmd"])
        if isinstance(s.get("t_taken"), (int, float)):  # the service's own stamp: the way there vs the rest
            taken.append(float(s["t_taken"]) - s["t_cmd"])
        ts = still_time(counts, s["t_cmd"], s["t_cmd"] + 5.0)
        if ts is not None:
            still.append(ts - s["t_cmd"])
    requests: dict[str, Any] = {}
    for ld in lds:
        for k, v in ((ld or {}).get("requests") or {}).items():
            r = requests.setdefault(k, {"codes": {}, "latency_parts": []})
            for code, n in v["codes"].items():
                r["codes"][code] = r["codes"].get(code, 0) + n
            r["latency_parts"].append(v["latency"])
    for r in requests.values():  # p99 of the parts' p99 is not a p99: report the worst part
        parts = [p for p in r.pop("latency_parts") if p["n"]]
        r["p50_ms_median_of_parts"] = float(np.median([p["p50_ms"] for p in parts])) if parts else None
        r["p99_ms_worst_part"] = max((p["p99_ms"] for p in parts), default=None)
        r["max_ms"] = max((p["max_ms"] for p in parts), default=None)
    res.update(
        {
            "clients": a.clients,
            "hogs": n_hogs,
            "secured": a.secured,
            "core_in_own_process": service.svc.core is not None,
            "moving": {
                "window_s": t1 - t0,
                "reference_period": period_figures(window(refs, t0, t1)),
                "stalls_and_steal": stall_steal(refs, steal, t0, t1, 0.060),
                "watchdog_trips_ecu_counter": None if trips0 is None or trips1 is None else trips1 - trips0,
                "watchdog_trips_on_bus": rising_edges(meas, WATCHDOG_BIT, t0, t1),
                "false_faults": faults_in(t0, t1),
                "stop_honoured": percentiles_ms(lat),
                "stop_reply": percentiles_ms(reply),
                "stop_taken": percentiles_ms(taken),
                "stop_to_still": percentiles_ms(still),
                "stops_sent": len(mov["stops"]),
                "stops_unmatched": missing,
                "moves": mov["moves"],
                "operator_client": {"priority": mov.get("priority"), "realtime_refused": mov.get("realtime_refused")},
                "requests": requests,
                "state_samples_at_clients": sum((ld or {}).get("state_samples", 0) for ld in lds),
            },
            "idle": {
                "window_s": i1 - i0,
                "reference_period": period_figures(window(refs, i0, i1)),
                "stalls_and_steal": stall_steal(refs, steal, i0, i1, 0.060),
                "watchdog_trips_ecu_counter": None if trips1 is None or trips2 is None else trips2 - trips1,
                "watchdog_trips_on_bus": rising_edges(meas, WATCHDOG_BIT, i0, i1),
                "false_faults": faults_in(i0, i1),
            },
        }
    )
    return res


class ServeProcess:
    """``hitch serve`` (or another ``hitch`` command) as its own process group on a free loopback port."""

    def __init__(self, *extra: str, data_dir: str) -> None:
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bridge.cli.main", "serve", "--listen", self.endpoint, "--data-dir", data_dir]
            + list(extra),
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            start_new_session=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        self.out: list[str] = []
        self.ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.out.append(line)
            if "ready on" in line:
                self.ready.set()

    def wait_online(self, timeout_s: float) -> str | None:
        """None when the service answers and its ECU is online, else why not."""
        from bridge.service.client import HitchClient, ServiceError

        end = time.monotonic() + timeout_s
        while not self.ready.wait(0.2):
            if self.proc.poll() is not None or time.monotonic() > end:
                time.sleep(0.2)  # let the reader take the last lines
                lines = "".join(self.out).strip().splitlines()
                return "the service did not start: " + (lines[-1] if lines else "no output")
        try:
            with HitchClient([self.endpoint], timeout_s=5) as c:
                if not LatestState(c).wait_until(lambda s: (s.get("ecu") or {}).get("online"), timeout_s):
                    return f"the ECU did not come online within {timeout_s:g} s"
        except ServiceError as exc:
            return f"no state from the service: {exc}"
        return None

    def kill(self) -> None:
        kill_group(self.proc)


def process_tree(pid: int) -> list[int]:
    """``pid`` and every descendant (the service's control core and planning processes), from /proc."""
    children: dict[int, list[int]] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        ppid = int(stat.rsplit(")", 1)[1].split()[1])
        children.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out


def tree_cpu(pid: int, seconds: float) -> tuple[float, dict[int, float]]:
    """CPU of ``pid`` and its descendants over ``seconds``: total and per process, % of one core."""
    pids = process_tree(pid)
    per = cpu_window(pids, seconds)
    return sum(per), dict(zip(pids, per, strict=True))


def cpu_window(pids: Sequence[int], seconds: float) -> list[float]:
    """CPU of each pid over ``seconds`` as % of one core (utime + stime from /proc)."""
    c0, w0 = [proc_cpu_seconds(p) for p in pids], time.monotonic()
    time.sleep(seconds)
    c1, w1 = [proc_cpu_seconds(p) for p in pids], time.monotonic()
    return [100.0 * (b - a_) / (w1 - w0) for a_, b in zip(c0, c1, strict=True)]


#: the pose the ``cpu`` scenario moves to before its second window (holding a pose after a move)
HOLD_GOAL = {"z": 0.25}


def _move_then_hold(endpoint: str) -> str | None:
    """A goto to :data:`HOLD_GOAL`, waited for until it has finished and the hitch holds the pose (the
    link keeps re-sending the reference); None, or why it could not be done."""
    from bridge.service.client import HitchClient, ServiceError

    try:
        with HitchClient([endpoint], timeout_s=10) as c:
            acc = c.goto(HOLD_GOAL)
            state = c.wait_motion(int(acc["motion_id"]), timeout_s=60.0)
    except (ServiceError, OSError, KeyError, ValueError) as exc:
        return f"the goto before the holding window failed: {exc!r}"
    if state.get("moving") or state.get("motion_id") != acc["motion_id"]:
        return f"the goto did not end at rest: {state.get('motion')}"
    time.sleep(2.0)  # the client's state subscription gone; the hitch holds the pose
    return None


def bench_cpu(a: argparse.Namespace) -> dict:
    """Idle CPU of ``hitch serve`` at rest: with the embedded simulated ECU, and the planner side alone."""
    from bridge.link.realtime import INTERFACES

    res: dict[str, Any] = {"window_s": a.cpu_duration, "realtime": a.realtime}
    rt: list[str] = []
    if a.realtime is not None:  # the service's [service] realtime key, from a config file of its own
        conf = Path(tempfile.mkdtemp(prefix="hitch-reliability-conf-")) / "service.toml"
        conf.write_text(f"[service]\nrealtime = {'true' if a.realtime else 'false'}\n", encoding="utf-8")
        rt = ["--config", str(conf)]
    srv = ServeProcess(*rt, data_dir=tempfile.mkdtemp(prefix="hitch-reliability-cpu-"))
    try:
        why = srv.wait_online(60)
        if why is None:
            time.sleep(3.0)  # start-up work done
            res["embedded_ecu_pct"], per = tree_cpu(srv.proc.pid, a.cpu_duration)
            res["embedded_ecu_per_process_pct"] = {str(k): v for k, v in per.items()}
            moved = _move_then_hold(srv.endpoint)
            if moved is None:
                res["embedded_ecu_holding_pct"], _ = tree_cpu(srv.proc.pid, a.cpu_duration)
            else:
                res["embedded_ecu_holding_pct"], res["embedded_ecu_holding_note"] = None, moved
        else:
            res["embedded_ecu_pct"], res["embedded_ecu_note"] = None, why
    finally:
        srv.kill()
    if "remote" not in INTERFACES:
        res["planner_only_pct"] = None
        res["planner_only_note"] = (
            "not measurable yet: no loopback CAN transport in bridge.link.realtime.INTERFACES "
            f"({', '.join(INTERFACES)}) for the ECU as its own process"
        )
        return res
    from bridge.link.loopback import LoopbackHub  # the hub runs in this process: counted for neither pid

    hub = LoopbackHub(0).start()
    ecu: subprocess.Popen | None = None
    planner_srv: ServeProcess | None = None
    try:
        ecu = subprocess.Popen(
            [sys.executable, "-m", "bridge.cli.main", "ecu-sim", "--interface", "remote", "--channel", hub.url],
            cwd=ROOT,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        planner_srv = srv = ServeProcess(
            *rt,
            "--can-interface",
            "remote",
            "--can-channel",
            hub.url,
            "--no-sim-ecu",
            data_dir=tempfile.mkdtemp(prefix="hitch-reliability-cpu-"),
        )
        why = srv.wait_online(60)
        if why is None and ecu.poll() is None:
            time.sleep(3.0)
            tree = process_tree(srv.proc.pid)
            per_pct = cpu_window([*tree, ecu.pid], a.cpu_duration)
            planner, ecu_pct = sum(per_pct[:-1]), per_pct[-1]
            res.update(
                {
                    "planner_only_pct": planner,
                    "planner_per_process_pct": {str(k): v for k, v in zip(tree, per_pct, strict=False)},
                    "ecu_process_pct": ecu_pct,
                    "transport": f"remote {hub.url}",
                }
            )
            moved = _move_then_hold(srv.endpoint)
            if moved is None:
                res["planner_only_holding_pct"] = sum(cpu_window(tree, a.cpu_duration))
            else:
                res["planner_only_holding_pct"], res["planner_only_holding_note"] = None, moved
        else:
            last = (why or "hitch ecu-sim exited").strip().splitlines()[-1]
            res["planner_only_pct"] = None
            res["planner_only_note"] = f"not measurable yet on the loopback hub: {last}"
    finally:
        if planner_srv is not None:
            planner_srv.kill()
        if ecu is not None:
            kill_group(ecu)
        hub.close()
    return res


def bench_faults(a: argparse.Namespace) -> dict:
    """Link loss in each direction during a full-speed goto, through ``sim/fault`` (module docstring)."""
    from bridge.service.client import HitchClient, ServiceError

    service = InProcessService(tempfile.mkdtemp(prefix="hitch-reliability-faults-"))
    res: dict[str, Any] = {"cases": {}}
    try:
        with HitchClient([service.endpoint], timeout_s=5) as c:
            states: list[dict] = []
            events: list[dict] = []
            c.subscribe("state", states.append)
            c.subscribe("events", events.append)
            latest = LatestState(c)
            ws = workspace_of(c)
            mid = centre(ws)
            lo = {**mid, "z": ws["z"][0] + 0.1 * (ws["z"][1] - ws["z"][0])}
            hi = {**mid, "z": ws["z"][1] - 0.1 * (ws["z"][1] - ws["z"][0])}
            ok, why = try_request(c, "sim/fault", {"cut": "none"}, 3.0)
            if not ok:
                res["skipped"] = f"the service refuses hitch/sim/fault ({why}): link-fault figures not measurable"
                return res
            for cut in CUTS:
                try_request(c, "faults/ack", {}, 3.0)
                try:
                    wait_done(latest, c.goto(lo), 20)
                    time.sleep(0.5)
                    r = c.goto(hi)
                except ServiceError as exc:
                    res["cases"][cut] = {"error": f"the goto before the cut was refused: {exc.code}: {exc}"}
                    print(f"faults: {cut}: {res['cases'][cut]['error']}", flush=True)
                    try_request(c, "stop", {})
                    wait_rest(latest, 10)
                    continue
                gid = int(r["motion_id"])
                time.sleep(min(1.0, 0.3 * float(r.get("duration", 3.0))))
                t_cut = time.time()
                ok, why = try_request(c, "sim/fault", {"cut": cut}, 3.0)
                time.sleep(a.fault_hold)
                t_restore = time.time()
                try_request(c, "sim/fault", {"cut": "none"}, 3.0)
                time.sleep(a.fault_watch + 0.5)
                t_end = time.time()
                ev = [e for e in list(events) if float(e.get("t", 0)) >= t_cut]
                st = [s for s in list(states) if float(s.get("t", 0)) >= t_cut]
                t_fault = min(
                    [float(e["t"]) for e in ev if e.get("event") == "fault"][:1]
                    + [float(s["t"]) for s in st if (s.get("ecu") or {}).get("faults")][:1],
                    default=None,
                )
                aborted = [
                    float(e["t"]) for e in ev if e.get("event") == "motion_aborted" and e.get("motion_id") == gid
                ][:1]
                fresh = [
                    s
                    for s in st
                    if t_restore <= s["t"] <= t_restore + a.fault_watch + 0.5
                    and s.get("pose")
                    and ((s.get("ecu") or {}).get("measurement_age_s") or 9.0) <= 0.1
                ]
                fresh = [s for s in fresh if s["t"] <= fresh[0]["t"] + a.fault_watch] if fresh else []
                disp = max_displacement([s["pose"] for s in fresh])
                rc = [cnt for t, cnt in service.sniffer.reference_counts() if t_restore <= t <= t_end]
                res["cases"][cut] = {
                    "cut_accepted": ok,
                    "cut_refusal": why or None,
                    "fault_latency_ms": None if t_fault is None else 1e3 * (t_fault - t_cut),
                    "motion_aborted": bool(aborted),
                    "abort_latency_ms": 1e3 * (aborted[0] - t_cut) if aborted else None,
                    "moving_after_return": any(s.get("moving") for s in st if s["t"] >= t_restore + 0.3),
                    "motion_after_return_mm": None if disp is None else 1e3 * disp[0],
                    "motion_after_return_mrad": None if disp is None else 1e3 * disp[1],
                    "reference_change_after_return_counts": int(np.abs(np.array(rc) - rc[0]).max()) if rc else None,
                    "faults_at_end": list(((st[-1].get("ecu") or {}).get("faults")) or []) if st else None,
                }
                print(f"faults: {cut}: {json.dumps(res['cases'][cut])}", flush=True)
                try_request(c, "stop", {})
                try_request(c, "faults/ack", {}, 3.0)
                wait_rest(latest, 10)
    finally:
        service.close()
    return res


def wait_done(latest: LatestState, reply: Mapping, timeout_s: float) -> bool:
    """Wait until the motion a command answered (``motion_id``) has ended; without an id, until at rest."""
    mid = reply.get("motion_id") if isinstance(reply, Mapping) else None
    if not isinstance(mid, int):
        time.sleep(0.1)
        return wait_rest(latest, timeout_s)
    return latest.wait_until(
        lambda s: (s.get("motion_id") or 0) > mid or (s.get("motion_id") == mid and not s.get("moving")), timeout_s
    )


def bench_jog(a: argparse.Namespace) -> dict:
    """Jog takeover of a full-speed goto at every workspace face (module docstring): the goto runs from
    10 % of the range to the face; the jog (full rate into the face, renewed every 0.1 s for
    ``--jog-seconds``) is sent as soon as the goto's commanded speed along the DOF has dropped 3 % below
    its peak, i.e. when the goto starts braking at its own limits from full speed."""
    from bridge.service.client import HitchClient, ServiceError

    service = InProcessService(tempfile.mkdtemp(prefix="hitch-reliability-jog-"))
    res: dict[str, Any] = {}
    try:
        with HitchClient([service.endpoint], timeout_s=5) as c:
            states: list[dict] = []
            c.subscribe("state", states.append)
            latest = LatestState(c)
            ws = workspace_of(c)
            mid = centre(ws)
            for dof in POSE:
                lo, hi = ws[dof]
                for side, outward in (("max", 1), ("min", -1)):
                    face = hi if side == "max" else lo
                    far = lo + 0.1 * (hi - lo) if side == "max" else hi - 0.1 * (hi - lo)
                    name = f"{dof}:{side}"
                    row: dict[str, Any] = {}
                    try:
                        try_request(c, "faults/ack", {}, 3.0)
                        wait_done(latest, c.goto({**mid, dof: far}), 20)
                        time.sleep(0.3)
                        t0 = time.time()
                        r = c.goto({**mid, dof: face})
                        vmax, v_take = 0.0, None
                        end = time.monotonic() + float(r.get("duration", 5.0)) + 1.0
                        while time.monotonic() < end:
                            st = latest.last
                            v = abs(float(((st.get("velocity") or {}).get(dof)) or 0.0))
                            if st.get("motion_id") == r.get("motion_id"):
                                vmax = max(vmax, v)
                                if vmax > 0 and v < 0.97 * vmax:
                                    v_take = v
                                    break
                            time.sleep(0.01)
                        jog_ok, jr = 0, {}
                        jog_err: dict[str, int] = {}
                        end = time.monotonic() + a.jog_seconds
                        while time.monotonic() < end:
                            try:
                                jr = c.jog(**{RATE_KEY[dof]: float(outward)}, ttl_ms=300)
                                jog_ok += 1
                            except ServiceError as exc:
                                jog_err[exc.code] = jog_err.get(exc.code, 0) + 1
                            time.sleep(0.1)
                        wait_done(latest, jr, 10)
                        time.sleep(0.5)
                        t1 = time.time()
                        win = [s for s in list(states) if t0 <= s.get("t", 0) <= t1]
                        meas = outward_excess([s["pose"][dof] for s in win if s.get("pose")], face, outward)
                        ref = outward_excess(
                            [s["reference"]["pose"][dof] for s in win if s.get("reference")], face, outward
                        )
                        try:
                            back = c.goto(mid)
                            back_ok, back_why = True, ""
                            wait_done(latest, back, 20)
                        except ServiceError as exc:
                            back_ok, back_why = False, f"{exc.code}: {exc}"
                        row = {
                            "overshoot_measured": None if meas is None else 1e3 * meas,
                            "overshoot_reference": None if ref is None else 1e3 * ref,
                            "unit": "mm" if dof in ("x", "z") else "mrad",
                            "goto_peak_speed": vmax,
                            "speed_at_takeover": v_take,
                            "jogs_accepted": jog_ok,
                            "jogs_refused": jog_err,
                            "goto_back_accepted": back_ok,
                            "goto_back_refusal": back_why or None,
                        }
                    except ServiceError as exc:
                        row = {"error": f"{exc.code}: {exc}"}
                        try_request(c, "stop", {})
                        wait_rest(latest, 10)
                    res[name] = row
                    print(f"jog: {name}: {json.dumps(row)}", flush=True)
    finally:
        service.close()
    return res


# ========================================================================== the table
def fmt(x: Any, spec: str = ".1f") -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return format(x, spec)
    return str(x)


def table(res: dict) -> list[str]:
    """One row per figure: measure, p50, p99, max, count, target, verdict."""
    rows: list[tuple[str, Any, Any, Any, Any, str, str]] = []
    T = TARGETS

    def add(measure: str, p50: Any = None, p99: Any = None, mx: Any = None, n: Any = None, tgt: str = "", v: str = ""):
        rows.append((measure, p50, p99, mx, n, tgt, v))

    def zero(*counts: Any) -> str:
        return "ok" if all((c or 0) == 0 for c in counts) else "FAIL"

    for load_key, head in (
        ("load_in_threads", "[core+planning in threads] "),
        ("load_nice_only", "[real-time off] "),
        ("load_ordinary_mover", "[operator's client ordinary] "),
        ("load", ""),
    ):
        if load_key not in res:
            continue
        for phase in ("moving", "idle"):
            ph = res[load_key][phase]
            p = ph["reference_period"]
            v = "-"
            if p["n"] and phase == "moving":
                good = verdict(p["p99_ms"], T["period_p99_ms"]) == verdict(p["max_ms"], T["period_max_ms"]) == "ok"
                v = "ok" if good else "FAIL"
            tgt = "p99 ≤ 25, max ≤ 60" if phase == "moving" else ""
            add(f"{head}{phase}: reference period ms", p["p50_ms"], p["p99_ms"], p["max_ms"], p["n"], tgt, v)
            over = f"{p['over_25_ms']} / {p['over_60_ms']} / {p['over_100_ms']}"
            add(f"{head}{phase}: periods > 25 / 60 / 100 ms", n=over)
            st = ph.get("stalls_and_steal")
            if st is not None:
                pairs = ", ".join(f"{g['period_ms']:.0f}/{g['stolen_ms']:.0f}" for g in st["stalls"][:8]) or "none"
                add(
                    f"{head}{phase}: periods > 60 ms / CPU stolen by the host meanwhile ms",
                    n=f"{pairs}; stolen {100 * st['stolen_share_of_window']:.1f} % of the window",
                )
            wd, bus = ph["watchdog_trips_ecu_counter"], ph["watchdog_trips_on_bus"]
            add(f"{head}{phase}: watchdog trips (ECU / bus)", n=f"{fmt(wd)} / {bus}", tgt="0", v=zero(wd, bus))
            ff = ph["false_faults"]
            names = ",".join(ff["fault_names_in_state"]) or "none"
            add(
                f"{head}{phase}: false faults (events; in state: {names})",
                n=ff["fault_events"],
                tgt="0",
                v=zero(ff["fault_events"], len(ff["fault_names_in_state"])),
            )
            if phase != "moving":
                continue
            for key, label in (
                ("stop_honoured", "stop honoured"),
                ("stop_reply", "stop reply"),
                ("stop_taken", "stop command to the service taking it"),
                ("stop_to_still", "stop to reference at rest"),
            ):
                s = ph[key]
                honoured = key == "stop_honoured"
                add(
                    f"{head}moving: {label} ms",
                    s["p50_ms"],
                    s["p99_ms"],
                    s["max_ms"],
                    s["n"],
                    "p99 ≤ 50" if honoured else "",
                    verdict(s["p99_ms"], T["stop_p99_ms"]) if honoured else "",
                )
            add(f"{head}moving: stops sent / unmatched", n=f"{ph['stops_sent']} / {ph['stops_unmatched']}")
            where = "own process" if res[load_key].get("core_in_own_process") else "the service's threads"
            kind = res[load_key].get("secured")
            kind = "users" if kind is True else kind  # results of the version before the certificates
            secured = f"secured ({SECURED_KINDS[kind]})" if kind else "not secured"
            add(f"{head}moving: the service; its control core", n=f"{secured}; {where}")
            oc = ph.get("operator_client") or {}
            refused = f" (refused: {oc['realtime_refused']})" if oc.get("realtime_refused") else ""
            add(f"{head}moving: the operator's client (sends the stops)", n=f"{oc.get('priority', '-')}{refused}")
            for k, r in sorted(ph["requests"].items()):
                bad = sum(m for c, m in r["codes"].items() if c != "ok")
                add(
                    f"{head}load: {k} ms (refused {bad})",
                    r["p50_ms_median_of_parts"],
                    r["p99_ms_worst_part"],
                    r["max_ms"],
                    sum(r["codes"].values()),
                )
    for cpu_key, head in (("cpu_nice_only", "[real-time off] "), ("cpu", "")):
        if cpu_key not in res:
            continue
        c = res[cpu_key]
        e, pl = c.get("embedded_ecu_pct"), c.get("planner_only_pct")
        add(f"{head}idle CPU % of a core, embedded ECU", mx=e, tgt="≤ 10", v=verdict(e, T["cpu_embedded_pct"]))
        add(f"{head}idle CPU % of a core, planner side", mx=pl, tgt="≤ 5", v=verdict(pl, T["cpu_planner_pct"]))
        e, pl = c.get("embedded_ecu_holding_pct"), c.get("planner_only_holding_pct")
        add(f"{head}idle CPU holding a pose, embedded ECU", mx=e, tgt="≤ 10", v=verdict(e, T["cpu_embedded_pct"]))
        add(f"{head}idle CPU holding a pose, planner side", mx=pl, tgt="≤ 5", v=verdict(pl, T["cpu_planner_pct"]))
    for cut, r in (res.get("faults") or {}).get("cases", {}).items():
        lat = r.get("fault_latency_ms")
        add(f"cut {cut}: fault latency ms", mx=lat, tgt="≤ 300", v=verdict(lat, T["fault_ms"]))
        moved = r.get("motion_after_return_mm")
        good = r.get("motion_aborted") and moved is not None and moved < 1.0 and not r.get("moving_after_return")
        add(
            f"cut {cut}: motion after return mm",
            mx=moved,
            n="aborted" if r.get("motion_aborted") else "NOT aborted",
            tgt="aborted, 0 mm",
            v="ok" if good else "FAIL",
        )
    if "jog" in res:
        for unit, lim in (("mm", T["overshoot_mm"]), ("mrad", T["overshoot_mrad"])):
            vals = [r.get("overshoot_measured") for r in res["jog"].values() if r.get("unit") == unit]
            m = max((v for v in vals if v is not None), default=None)
            add(f"jog takeover overshoot {unit} (worst face)", mx=m, n=len(vals), tgt=f"≤ {lim:g}", v=verdict(m, lim))
        refused = sum(1 for r in res["jog"].values() if r.get("goto_back_accepted") is False)
        errors = sum(1 for r in res["jog"].values() if "error" in r)
        add("jog takeover: goto back refused / errors", n=f"{refused} / {errors}", tgt="0", v=zero(refused, errors))
    w = max([len(r[0]) for r in rows] + [7])
    out = [f"{'measure':<{w}} {'p50':>8} {'p99':>8} {'max':>8} {'count':>14}  {'target':<18} verdict"]
    for m, p50, p99, mx, n, tgt, v in rows:
        out.append(f"{m:<{w}} {fmt(p50):>8} {fmt(p99):>8} {fmt(mx):>8} {fmt(n):>14}  {tgt:<18} {v}")
    if (res.get("faults") or {}).get("skipped"):
        out.append("link faults: " + res["faults"]["skipped"])
    for k in ("embedded_ecu_note", "planner_only_note"):
        if (res.get("cpu") or {}).get(k):
            out.append(f"cpu: {res['cpu'][k]}")
    return out


# ========================================================================== main
def main(argv: Sequence[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    ap.add_argument("--role", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--connect", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=10.0, help=argparse.SUPPRESS)
    ap.add_argument("--threads", type=int, default=1, help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--client-security", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true", help="15 s moving, 30 s idle, 5 clients, 15 s CPU windows")
    ap.add_argument("--only", default="load,cpu,faults,jog", help="scenarios, comma-separated")
    ap.add_argument("--duration", type=float, default=None, help="moving under load [s] (default 120; quick 15)")
    ap.add_argument("--idle-duration", type=float, default=None, help="idle under the hogs [s] (default 600; quick 30)")
    ap.add_argument("--clients", type=int, default=None, help="load clients (default 20; quick 5)")
    ap.add_argument("--clients-per-process", type=int, default=5, help="load clients per client process")
    ap.add_argument("--hogs-per-core", type=int, default=2, help="CPU-bound processes per core")
    ap.add_argument("--maneuvers", type=int, default=70, help="maneuvers stored before the load")
    ap.add_argument("--stop-every", type=int, default=2, help="stop every n-th goto of the mover mid-cruise (0: never)")
    ap.add_argument("--cpu-duration", type=float, default=None, help="CPU window [s] (default 60; quick 15)")
    ap.add_argument("--fault-hold", type=float, default=1.0, help="how long a link cut lasts [s]")
    ap.add_argument("--fault-watch", type=float, default=2.0, help="motion watched after the link returns [s]")
    ap.add_argument("--jog-seconds", type=float, default=1.5, help="jog into a face this long [s]")
    ap.add_argument(
        "--planning-processes",
        type=int,
        default=None,
        help="the service's planning processes (default: the service's default; 0: planning in its threads)",
    )
    ap.add_argument(
        "--control-core",
        choices=("process", "thread"),
        default=None,
        help="where the service's control core runs (default: the service's default)",
    )
    ap.add_argument(
        "--realtime",
        choices=("on", "off"),
        default=None,
        help="the service's real-time scheduling (SCHED_FIFO; default: the service's default, on)",
    )
    ap.add_argument(
        "--compare-realtime",
        action="store_true",
        help="run `load` and `cpu` twice: first with real-time scheduling off (nice values only), then as configured",
    )
    ap.add_argument(
        "--compare-threads",
        action="store_true",
        help="run `load` twice: first with the control core and planning in the service's threads, then as "
        "configured (side by side)",
    )
    ap.add_argument(
        "--mover-priority",
        choices=("realtime", "ordinary"),
        default="realtime",
        help="the operator's client (the mover, which sends the stops): HitchClient(realtime=True), its Zenoh "
        "threads under SCHED_FIFO where permitted (default), or an ordinary process beside the hogs",
    )
    ap.add_argument(
        "--compare-mover",
        action="store_true",
        help="run `load` twice: first with the operator's client at ordinary priority, then as configured",
    )
    ap.add_argument(
        "--secured",
        nargs="?",
        const="users",
        default=None,
        choices=sorted(SECURED_KINDS),
        help="`load`: the service with a security file; `users` (the default): a users file and access control, "
        "every client logged in as its one operator (the core's link logs in as a user the service makes up); "
        "`certificates`: mTLS and access control by certificate name, no users file (the core links through "
        "a Unix socket)",
    )
    ap.add_argument("--json", default=None, help="write the results as JSON to this file")
    a = ap.parse_args(argv)
    if a.role is not None:
        {"monitor": role_monitor, "mover": role_mover, "load": role_load}[a.role](a)
        return
    q = a.quick
    a.realtime = None if a.realtime is None else a.realtime == "on"
    a.duration = a.duration if a.duration is not None else (15.0 if q else 120.0)
    a.idle_duration = a.idle_duration if a.idle_duration is not None else (30.0 if q else 600.0)
    a.clients = a.clients if a.clients is not None else (5 if q else 20)
    a.cpu_duration = a.cpu_duration if a.cpu_duration is not None else (15.0 if q else 60.0)
    for name in ("duration", "idle_duration", "cpu_duration", "fault_hold", "fault_watch", "jog_seconds"):
        if not 0.0 <= getattr(a, name) <= 7200.0:
            ap.error(f"--{name.replace('_', '-')} must lie in [0, 7200] s")
    if not 1 <= a.clients <= 200 or not 1 <= a.clients_per_process <= 50 or not 0 <= a.hogs_per_core <= 16:
        ap.error("--clients 1..200, --clients-per-process 1..50, --hogs-per-core 0..16")
    only = [s for s in a.only.split(",") if s]
    unknown = set(only) - {"load", "cpu", "faults", "jog"}
    if unknown:
        ap.error(f"--only: unknown scenario(s) {', '.join(sorted(unknown))}; allowed: load, cpu, faults, jog")
    res: dict[str, Any] = {
        "machine": {**machine_note(), "loadavg_at_start": os.getloadavg()},
        "args": {k: v for k, v in vars(a).items() if k not in ("role", "connect", "seconds", "threads", "seed", "out")},
    }
    bench = {"load": bench_load, "cpu": bench_cpu, "faults": bench_faults, "jog": bench_jog}
    if "load" in only and a.compare_threads:
        print("--- load, control core and planning in the service's threads", flush=True)
        res["load_in_threads"] = bench_load(
            argparse.Namespace(**{**vars(a), "planning_processes": 0, "control_core": "thread"})
        )
    if "load" in only and a.compare_mover:
        print("--- load, the operator's client at ordinary priority", flush=True)
        res["load_ordinary_mover"] = bench_load(argparse.Namespace(**{**vars(a), "mover_priority": "ordinary"}))
    if "load" in only and a.compare_realtime:
        print("--- load, real-time scheduling off (nice values only)", flush=True)
        res["load_nice_only"] = bench_load(argparse.Namespace(**{**vars(a), "realtime": False}))
    if "cpu" in only and a.compare_realtime:
        print("--- cpu, real-time scheduling off (nice values only)", flush=True)
        res["cpu_nice_only"] = bench_cpu(argparse.Namespace(**{**vars(a), "realtime": False}))
    for name in ("load", "cpu", "faults", "jog"):
        if name in only:
            print(f"--- {name}", flush=True)
            res[name] = bench[name](a)
    res["machine"]["loadavg_at_end"] = os.getloadavg()
    print(f"machine: {res['machine']}")
    print("\n".join(table(res)))
    write_json(a.json, res)
    if a.json:
        print(f"written {a.json}")


if __name__ == "__main__":
    main()
