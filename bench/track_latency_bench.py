"""Setpoint → CAN reference latency of track mode on the running service (target p99 ≤ one control
period + 2 ms).

The service runs in this process (:class:`HitchService`, the control core in its own process as
deployed) with the simulated ECU; its core records the bus to a CAN log (candump format; every
frame stamped by python-can's virtual bus at its send). A Zenoh client in this process starts a
track session and streams setpoints (puts on ``<prefix>/track/setpoint``) at ``--rate`` Hz for
``--seconds`` s; another session subscribes to ``state``.

Definitions (every time is ``time.time()``, one clock for all processes):

* ``T_put(k)``: just before setpoint ``k`` (the k-th of the session) is put;
* the control cycle that takes it publishes its state first (``state.t``, with the session's
  accepted-setpoint count ``track.setpoints``) and sends the reference after that, in the same
  cycle; so setpoint ``k`` has been taken by the cycle of the first state whose count is ≥ k, and
  ``T_ref(k)`` = the first 0xFF21 frame at or after that state's ``t``;
* latency(k) = ``T_ref(k) − T_put(k)``. A setpoint that was lost on the way makes the later ones
  map to later states: the figure can only grow (never flatter than the truth).

With setpoints at 100 Hz and the control cycle at 50 Hz a setpoint waits up to one period for its
cycle: hence the target of one period plus 2 ms. Also printed, its two parts: ``T_put`` to the
start of the cycle that took it (its state's ``t``: the wait for the cycle, plus the way through
Zenoh), and that start to the reference on the bus (the cycle's own work).

The client's clock and the control cycle's are both steady, so at exactly ``--rate 100`` the phase
between them stays as it happened to start, and one run samples one phase (the wait can sit
anywhere in 0…20 ms for a whole run). ``--rate 99.5`` lets the phase sweep through the whole period
about five times in 20 s: every phase is sampled, the figure a client with its own clock sees.

Run: .venv/bin/python bench/track_latency_bench.py [--seconds 20] [--rate 100|99.5] [--json FILE]
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

try:  # imported as a module
    from bench._common import free_port
except ImportError:  # run as a script: bench/ is sys.path[0]
    from _common import free_port  # type: ignore[no-redef, import-not-found]

REFERENCE_PGN = 0xFF21


def _pgn(arbitration_id: int) -> int:
    from bridge.isobus.j1939 import decode_id

    return decode_id(arbitration_id).pgn


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="streaming time [s] (default 20)")
    ap.add_argument("--rate", type=float, default=100.0, help="setpoints per second (default 100)")
    ap.add_argument("--json", default=None, help="write the figures as JSON here")
    a = ap.parse_args(argv)
    if not 1.0 <= a.seconds <= 600.0 or not 1.0 <= a.rate <= 100.0:
        ap.error("--seconds 1..600, --rate 1..100")

    import can

    from bridge.service.client import HitchClient
    from bridge.service.config import ServiceConfig
    from bridge.service.server import HitchService

    data = Path(tempfile.mkdtemp(prefix="hitch-track-latency-"))
    log = data / "bus.log"
    ep = f"tcp/127.0.0.1:{free_port()}"
    svc = HitchService(ServiceConfig(listen=[ep], data_dir=data, can_log=log, can_channel=f"lat-{os.getpid()}"))
    states: list[tuple[float, int, int]] = []  # (t, session, accepted count)
    puts: list[float] = []
    svc.start()
    try:
        with HitchClient([ep], timeout_s=10) as c, HitchClient([ep], timeout_s=10) as mon:
            end = time.monotonic() + 20.0
            while time.monotonic() < end and not ((mon.state().get("ecu") or {}).get("online")):
                pass
            lock = threading.Lock()

            def on_state(st: dict) -> None:
                tr = st.get("track") or {}
                if tr:
                    with lock:
                        states.append((float(st["t"]), int(tr["session"]), int(tr["setpoints"])))

            mon.subscribe("state", on_state)
            z0 = float(c.state()["pose"]["z"])
            session = int(c.track_start("tractor", ["z"], 500)["session"])
            period = 1.0 / a.rate
            t_next = time.monotonic()
            n = int(a.seconds * a.rate)
            for k in range(1, n + 1):
                z = z0 + 0.02 * math.sin(2 * math.pi * 0.1 * k * period)
                puts.append(time.time())
                c.track_setpoint(session, k, {"z": z})
                t_next += period
                time.sleep(max(0.0, t_next - time.monotonic()))
            c.track_stop(session)
            time.sleep(0.5)
    finally:
        svc.close()
    refs = sorted(m.timestamp for m in can.LogReader(str(log)) if _pgn(m.arbitration_id) == REFERENCE_PGN)
    mine = sorted((t, cnt) for t, s, cnt in states if s == session)
    counts = [cnt for _, cnt in mine]
    lat: list[float] = []
    waited: list[float] = []  # T_put -> the start of the cycle that took it (its state's t)
    cycle: list[float] = []  # that cycle's start -> its reference on the bus
    for k, t_put in enumerate(puts, start=1):
        i = bisect.bisect_left(counts, k)
        if i >= len(mine):
            continue
        j = bisect.bisect_left(refs, mine[i][0])
        if j < len(refs):
            lat.append(refs[j] - t_put)
            waited.append(mine[i][0] - t_put)
            cycle.append(refs[j] - mine[i][0])
    arr = np.array(lat) * 1000.0

    def pct(xs: list[float]) -> dict:
        v = np.array(xs) * 1000.0
        keys = ("p50", "p99", "max")
        return dict(zip(keys, (float(np.percentile(v, 50)), float(np.percentile(v, 99)), float(v.max())), strict=True))

    period_ms = 1000.0 / 50.0
    res = {
        "machine": {"cores": os.cpu_count(), "loadavg": os.getloadavg()},
        "setpoints_sent": len(puts),
        "setpoints_matched": len(lat),
        "latency_ms": {
            "p50": float(np.percentile(arr, 50)) if len(arr) else None,
            "p99": float(np.percentile(arr, 99)) if len(arr) else None,
            "max": float(arr.max()) if len(arr) else None,
        },
        "target_p99_ms": period_ms + 2.0,
        "put_to_cycle_start_ms": pct(waited) if waited else None,
        "cycle_start_to_reference_ms": pct(cycle) if cycle else None,
    }
    p99 = res["latency_ms"]["p99"]
    verdict = "ok" if p99 is not None and p99 <= period_ms + 2.0 else "FAIL"
    print(f"machine: {res['machine']}")
    print(
        f"setpoint -> reference latency ms: p50 {res['latency_ms']['p50']:.1f}  p99 {p99:.1f}  "
        f"max {res['latency_ms']['max']:.1f}  ({len(lat)} of {len(puts)} setpoints)  target p99 <= "
        f"{period_ms + 2.0:.0f}  {verdict}"
    )
    for key in ("put_to_cycle_start_ms", "cycle_start_to_reference_ms"):
        f = res[key]
        if f:
            name = key.removesuffix("_ms").replace("_", " ")
            print(f"  {name} ms: p50 {f['p50']:.1f}  p99 {f['p99']:.1f}  max {f['max']:.1f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
    return res


if __name__ == "__main__":
    main()
