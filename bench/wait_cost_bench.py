"""CPU cost of a thread that wakes at a fixed rate and does nothing else, by the wait it sleeps in.

The real-time runners and the periodic control thread of ``hitch serve`` sleep between deadlines in a wait
that a stop ends at once. This compares ``threading.Event.wait`` (a new ``Condition`` waiter per wait) with
:class:`bridge.link.stop_signal.StopSignal` (one ``Lock.acquire`` with a timeout), and ``time.sleep`` as the
floor (a wait no stop can end). Rounds alternate the waits (A, B, C, A, B, C, …) so the host's load falls on
each alike; the figure is the thread's CPU time (``/proc/self/task/<tid>/schedstat``) over the window, in
% of one core.

Run: .venv/bin/python bench/wait_cost_bench.py [--rate-hz 100] [--window-s 5] [--rounds 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from bridge.link.stop_signal import StopSignal  # noqa: E402


def _thread_cpu_ns(native_id: int) -> int:
    with open(f"/proc/self/task/{native_id}/schedstat", encoding="ascii") as f:
        return int(f.read().split()[0])


def waiter_cpu_pct(wait: Callable[[float], object], rate_hz: float, window_s: float) -> float:
    """% of a core used by a thread calling ``wait(time to the next deadline)`` at ``rate_hz`` for ``window_s``."""
    period = 1.0 / rate_hz
    done = [False]

    def loop() -> None:
        while not done[0]:
            wait(period - (time.monotonic() % period))

    t = threading.Thread(target=loop, daemon=True)
    t.start()
    time.sleep(0.3)  # settled
    assert t.native_id is not None
    c0, t0 = _thread_cpu_ns(t.native_id), time.monotonic()
    time.sleep(window_s)
    c1, t1 = _thread_cpu_ns(t.native_id), time.monotonic()
    done[0] = True
    t.join(2.0)
    return (c1 - c0) / (t1 - t0) / 1e7


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rate-hz", type=float, default=100.0)
    ap.add_argument("--window-s", type=float, default=5.0)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    if not 1.0 <= a.rate_hz <= 1000.0:
        ap.error(f"--rate-hz must lie in [1, 1000], got {a.rate_hz}")
    if not 0.5 <= a.window_s <= 600.0 or not 1 <= a.rounds <= 100:
        ap.error("--window-s must lie in [0.5, 600] and --rounds in [1, 100]")
    event, stop = threading.Event(), StopSignal()
    waits: dict[str, Callable[[float], object]] = {
        "Event.wait": event.wait,
        "StopSignal.wait": stop.wait,
        "time.sleep (floor)": time.sleep,
    }
    load0 = os.getloadavg()
    res: dict[str, list[float]] = {k: [] for k in waits}
    for _ in range(a.rounds):
        for name, fn in waits.items():
            res[name].append(waiter_cpu_pct(fn, a.rate_hz, a.window_s))
    load1 = os.getloadavg()
    print(f"machine: {machine_note()}; load average before {load0[0]:.2f}, after {load1[0]:.2f}")
    print(f"a thread waking at {a.rate_hz:g} Hz, no work; {a.rounds} rounds of {a.window_s:g} s, alternating")
    med = {k: statistics.median(v) for k, v in res.items()}
    for name, v in res.items():
        print(f"{name:20s} median {med[name]:.2f} %  (min {min(v):.2f}, max {max(v):.2f}) of a core")
    ratio = med["Event.wait"] / med["StopSignal.wait"] if med["StopSignal.wait"] > 0 else float("inf")
    print(f"Event.wait / StopSignal.wait: {ratio:.2f}x")
    write_json(a.json, {"machine": machine_note(), "rate_hz": a.rate_hz, "rounds": res, "median_pct": med})


if __name__ == "__main__":
    main()
