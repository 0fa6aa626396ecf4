"""Service benchmark, every figure measured against a running service.

Scenarios (each starts its own service; loopback only):

* ``ik``       — ``hitch/ik`` round trip from a client process: p50/p99 over sequential queries
                 (target p50 ≤ 1 ms);
* ``sustained``— 500 ``hitch/ik`` queries/s for 30 s, paced open-loop, errors counted (target: none),
                 while a separate subscriber process records ``hitch/state`` arrivals;
* ``jitter``   — ``hitch/state`` period jitter |period − 20 ms| at an otherwise idle service (three
                 20 s windows) and under the sustained load (target p99 ≤ 2 ms), at the subscriber
                 (arrival times, a separate process) and at the service (the message's own ``t``);
* ``fuzz``     — 10 000 fuzzed payloads from a client process (random bytes, broken JSON, wrong
                 types, NaN/Infinity, huge numbers, unknown keys, deep nesting, oversize), each must
                 be answered with an error; interleaved valid extreme commands (gotos to workspace
                 corners, jogs at full rate into the faces) keep references flowing. The service
                 runs in this process so a sniffer on its virtual CAN channel decodes every 0xFF21
                 reference: each must lie within the strokes (in counts) and, converted back, within
                 every hard limit. Afterwards the service must still answer and publish;
* ``kill9``    — a client saves presets as fast as acknowledged; the service is killed with
                 SIGKILL mid-stream, restarted on the same data directory, and every acknowledged
                 preset must be there (several rounds);
* ``shutdown`` — SIGTERM while moving: time until the process has exited (target ≤ 1 s).

Run: .venv/bin/python bench/service_bench.py [--quick] [--only ik,fuzz,...] [--json bench/out/service_bench.json]
(``--quick`` shortens the long runs for a smoke test; the reported figures use the full run.)
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from _common import free_port, machine_note, write_json  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from bridge.service.client import HitchClient, ServiceError  # noqa: E402

POSE = ("x", "z", "roll", "pitch")
WORKSPACE = {"x": (-0.06, 0.06), "z": (-0.21627, 0.311729), "roll": (-0.058, 0.058), "pitch": (-0.1, 0.058)}


# ---------------------------------------------------------------------------------------- helpers


class Service:
    """``hitch serve`` as a subprocess on a free loopback port."""

    def __init__(self, data_dir: str, *extra: str):
        self.port = free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bridge.cli.main",
                "serve",
                "--listen",
                self.endpoint,
                "--data-dir",
                data_dir,
                *extra,
            ],
            cwd=ROOT,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        self.out: list[str] = []
        self._ready = threading.Event()
        threading.Thread(target=self._read, daemon=True).start()
        if not self._ready.wait(60):
            self.kill()
            raise RuntimeError("service did not start: " + "".join(self.out))
        with HitchClient([self.endpoint], timeout_s=10) as c:
            end = time.monotonic() + 15
            while not c.state(timeout_s=5)["ecu"]["online"]:
                if time.monotonic() > end:
                    raise RuntimeError("ECU never online")

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.out.append(line)
            if "ready on" in line:
                self._ready.set()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


def role(name: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, __file__, "--role", name, *args], cwd=ROOT, stdout=subprocess.PIPE, text=True
    )


def random_poses(rng: np.random.Generator, n: int) -> list[dict]:
    lo = np.array([WORKSPACE[k][0] for k in POSE])
    hi = np.array([WORKSPACE[k][1] for k in POSE])
    return [dict(zip(POSE, map(float, lo + (hi - lo) * rng.random(4)), strict=True)) for _ in range(n)]


def pct(a, qs=(50, 90, 99)) -> dict:
    a = np.asarray(a, float)
    return {
        **{f"p{q}_ms": float(np.percentile(a, q) * 1e3) for q in qs},
        "max_ms": float(a.max() * 1e3),
        "n": int(a.size),
    }


def jitter(times: list[float], period: float) -> dict:
    d = np.diff(np.asarray(times, float))
    j = np.abs(d - period)
    return {
        "period_mean_ms": float(d.mean() * 1e3),
        "jitter_p50_ms": float(np.percentile(j, 50) * 1e3),
        "jitter_p99_ms": float(np.percentile(j, 99) * 1e3),
        "jitter_max_ms": float(j.max() * 1e3),
        "n": int(d.size),
    }


# ---------------------------------------------------------------------------------------- roles (subprocesses)
def role_subscriber(a) -> None:
    """Record hitch/state arrivals for ``--seconds``; print JSON (arrival times, sender times, seqs)."""
    arrivals, sent, seqs = [], [], []
    with HitchClient([a.connect], timeout_s=5) as c:

        def on(s):
            arrivals.append(time.perf_counter())
            sent.append(s["t"])
            seqs.append(s["seq"])

        c.subscribe("state", on)
        print("subscribed", flush=True)
        time.sleep(a.seconds)
    print(json.dumps({"arrivals": arrivals, "sent": sent, "seqs": seqs}), flush=True)


def fuzz_payloads(rng: np.random.Generator, n: int):
    """(key, bytes): invalid by construction — every one must be refused."""
    keys = [
        "ik",
        "plan",
        "goto",
        "jog",
        "stop",
        "mode",
        "config",
        "presets/list",
        "presets/save",
        "presets/go",
        "presets/delete",
        "maneuvers/validate",
        "maneuvers/save",
        "maneuvers/list",
        "maneuvers/run",
        "maneuvers/delete",
    ]
    valid = {
        "ik": {"x": 0.0, "z": 0.1, "roll": 0.0, "pitch": 0.0},
        "goto": {"goal": {"z": 0.1}},
        "plan": {"goal": {"z": 0.1}},
        "jog": {"vx": 0.01, "ttl_ms": 100},
        "presets/save": {"name": "p"},
        "presets/go": {"name": "p"},
        "mode": {"mode": "auto"},
        "maneuvers/validate": {"script": "steps: []"},
    }
    for i in range(n):
        key = keys[int(rng.integers(len(keys)))]
        base = valid.get(key, {})
        kind = i % 10
        if kind == 0:
            raw = b"\x00" + bytes(rng.integers(0, 256, int(rng.integers(1, 200)), dtype=np.uint8))
        elif kind == 1:
            t = json.dumps(base) if base else '{"a": 1}'
            raw = t[: int(rng.integers(1, len(t) - 1))].encode()
        elif kind == 2:
            raw = json.dumps({**base, f"unknown_{int(rng.integers(1e6))}": [1, 2]}).encode()
        elif kind == 3:
            raw = json.dumps(
                {**base, "x": [float("nan"), float("inf"), -float("inf")][i % 3], "goal": {"z": float("nan")}}
            ).encode()
        elif kind == 4:
            raw = json.dumps(
                {
                    "x": "0",
                    "z": None,
                    "roll": True,
                    "pitch": [],
                    "goal": "up",
                    "name": 42,
                    "mode": 3,
                    "vx": "fast",
                    "script": 1.5,
                    "ttl_ms": "long",
                }
            ).encode()
        elif kind == 5:
            raw = b'{"x": 1' + b"0" * int(rng.integers(310, 6000)) + b', "goal": {"z": 1e999}, "vx": -1e999}'
        elif kind == 6:
            raw = b"[" * int(rng.integers(2000, 50000))
        elif kind == 7:
            raw = json.dumps([base, 1, "x"]).encode()
        elif kind == 8:
            raw = b'{"name": "' + b"a" * 120_000 + b'"}'
        else:
            raw = json.dumps(
                {
                    **{k: 1e12 for k in ("x", "z", "roll", "pitch", "vx", "vz", "ttl_ms", "speed_scale")},
                    "goal": {"x": -1e12},
                    "name": "../../etc/passwd",
                    "mode": "warp",
                    "script": 7,
                }
            ).encode()
        yield key, raw


def role_fuzzer(a) -> None:
    """Send ``--n`` fuzzed payloads (and valid extreme motion commands between them); print JSON counts."""
    rng = np.random.default_rng(a.seed)
    answered_err, answered_ok, timeouts, bad_codes, extreme_ok, extreme_err = 0, [], 0, {}, 0, 0
    corners = [{k: WORKSPACE[k][int(b)] for k, b in zip(POSE, bits, strict=True)} for bits in np.ndindex(2, 2, 2, 2)]
    t0 = time.perf_counter()
    with HitchClient([a.connect], timeout_s=5) as c:
        for i, (key, raw) in enumerate(fuzz_payloads(rng, a.n)):
            try:
                c.request(key, raw)
                answered_ok.append((key, raw[:60].decode("latin-1")))
            except ServiceError as exc:
                if exc.code == "timeout":
                    timeouts += 1
                else:
                    answered_err += 1
                    bad_codes[exc.code] = bad_codes.get(exc.code, 0) + 1
            if i % 250 == 0:  # keep the hitch moving at its limits
                try:
                    if (i // 250) % 2 == 0:
                        c.goto(corners[int(rng.integers(len(corners)))])
                    else:
                        v = rng.choice([-1.0, 1.0], 4) * np.array([0.5, 0.5, 0.5, 0.5])
                        for _ in range(10):
                            c.jog(*map(float, v), ttl_ms=300)
                    extreme_ok += 1
                except ServiceError:
                    extreme_err += 1  # e.g. refused by the guard or busy: also fine, nothing unsafe moves
    print(
        json.dumps(
            {
                "sent": a.n,
                "answered_with_error": answered_err,
                "answered_ok": answered_ok,
                "timeouts": timeouts,
                "codes": bad_codes,
                "extreme_commands_accepted": extreme_ok,
                "extreme_commands_refused": extreme_err,
                "seconds": time.perf_counter() - t0,
            }
        ),
        flush=True,
    )


# ---------------------------------------------------------------------------------------- scenarios
def bench_ik(endpoint: str, n: int) -> dict:
    rng = np.random.default_rng(1)
    targets = random_poses(rng, n + 200)
    lat, errors = [], 0
    with HitchClient([endpoint], timeout_s=5) as c:
        for i, t in enumerate(targets):
            t0 = time.perf_counter()
            try:
                c.request("ik", t)
            except ServiceError:
                errors += 1
            if i >= 200:
                lat.append(time.perf_counter() - t0)
    return {"round_trip": pct(lat), "errors": errors, "target_p50_ms": 1.0}


def bench_sustained(endpoint: str, rate: float, seconds: float) -> dict:
    rng = np.random.default_rng(2)
    targets = random_poses(rng, 1000)
    sub = role("subscriber", "--connect", endpoint, "--seconds", str(seconds + 2))
    assert "subscribed" in sub.stdout.readline()
    lat, errors, timeouts = [], 0, 0
    with HitchClient([endpoint], timeout_s=2) as c:
        time.sleep(1.0)
        n = int(rate * seconds)
        t0 = time.perf_counter()
        for k in range(n):
            slot = t0 + k / rate
            d = slot - time.perf_counter()
            if d > 0:
                time.sleep(d)
            ts = time.perf_counter()
            try:
                c.request("ik", targets[k % len(targets)])
            except ServiceError as exc:
                timeouts += exc.code == "timeout"
                errors += 1
            lat.append(time.perf_counter() - ts)
        elapsed = time.perf_counter() - t0
    rec = json.loads(sub.stdout.readline())
    sub.wait(10)
    return {
        "queries": n,
        "seconds": elapsed,
        "achieved_rate_per_s": n / elapsed,
        "errors": errors,
        "timeouts": timeouts,
        "round_trip": pct(lat),
        "state_during_load": state_figures(rec),
    }


def state_figures(rec: dict) -> dict:
    seqs = np.asarray(rec["seqs"])
    return {
        "arrival": jitter(rec["arrivals"], 0.02),
        "sender": jitter(rec["sent"], 0.02),
        "missing_seq": int((np.diff(seqs) - 1).sum()) if seqs.size > 1 else None,
    }


def bench_jitter_idle(endpoint: str, seconds: float) -> dict:
    sub = role("subscriber", "--connect", endpoint, "--seconds", str(seconds))
    assert "subscribed" in sub.stdout.readline()
    rec = json.loads(sub.stdout.readline())
    sub.wait(10)
    return state_figures(rec)


def bench_fuzz(n: int) -> dict:
    import can

    from bridge.isobus.codec import PositionCounts, decode_frame
    from bridge.service.config import load_service_config
    from bridge.service.server import HitchService
    from planner.model.hard_limits import HardLimits
    from planner.model.kinematics import HitchModel
    from planner.model.sensors import SensorScaling
    from planner.model.types import KinematicsError

    port = free_port()
    channel = f"bench-fuzz-{os.getpid()}"
    cfg = load_service_config(listen=[f"tcp/127.0.0.1:{port}"], data_dir=tempfile.mkdtemp(), can_channel=channel)
    sniffer = can.Bus(interface="virtual", channel=channel)
    refs: list[tuple[int, ...]] = []
    stop = threading.Event()

    def sniff():
        while not stop.is_set():
            f = sniffer.recv(0.05)
            if f is None or (f.arbitration_id >> 8) & 0xFFFF != 0xFF21:
                continue
            d = decode_frame(f)
            if isinstance(d.payload, PositionCounts):
                refs.append(d.payload.as_tuple())

    th = threading.Thread(target=sniff, daemon=True)
    th.start()
    svc = HitchService(cfg).start()
    try:
        time.sleep(1.0)
        with HitchClient([f"tcp/127.0.0.1:{port}"]) as c:
            seq0 = c.state()["seq"]
        p = role("fuzzer", "--connect", f"tcp/127.0.0.1:{port}", "--n", str(n), "--seed", "11")
        out = json.loads(p.stdout.readline())
        p.wait(30)
        with HitchClient([f"tcp/127.0.0.1:{port}"]) as c:
            alive = c.ik(0.0, 0.1, 0.0, 0.0)["status"] == "ok" and c.state()["seq"] > seq0
            c.stop()
        time.sleep(1.5)
    finally:
        svc.close()
        stop.set()
        th.join(2)
        sniffer.shutdown()
    model = HitchModel.from_profile("thesis-t132")
    scale, hard = SensorScaling(model.profile), HardLimits.from_model(model)
    lo_c, hi_c = scale.to_counts(model.lower), scale.to_counts(model.upper)
    lo, hi = np.minimum(lo_c, hi_c), np.maximum(lo_c, hi_c)  # rint is monotonic: q in the strokes ⇒ counts here
    stroke_bad = feature_bad = 0
    for r in refs:
        counts = np.array(r, float)  # PositionCounts.as_tuple: actuator order
        if np.any(counts < lo - 1e-9) or np.any(counts > hi + 1e-9):
            stroke_bad += 1
            continue
        q = scale.to_si(counts, tolerance_counts=0.5)
        try:
            feats, _ = model.features(q)
            feature_bad += bool(hard.violations(q, feats, tol=2e-3))  # half a count of quantisation
        except KinematicsError:
            feature_bad += 1
    return {
        **out,
        "service_alive_after": bool(alive),
        "references_sniffed": len(refs),
        "references_outside_strokes": stroke_bad,
        "references_outside_other_limits": feature_bad,
    }


def bench_kill9(rounds: int, seconds: float) -> dict:
    data = tempfile.mkdtemp()
    acked: list[str] = []
    lost_total, per_round = 0, []
    for r in range(rounds):
        svc = Service(data)
        killer = threading.Timer(seconds, lambda p=svc.proc: os.kill(p.pid, signal.SIGKILL))
        n0 = len(acked)
        with HitchClient([svc.endpoint], timeout_s=1.0) as c:
            killer.start()
            k = 0
            while True:
                name = f"r{r}-p{k}"
                try:
                    c.request("presets/save", {"name": name, "pose": {"z": 0.1 + 1e-4 * (k % 1000)}})
                except ServiceError:
                    break
                acked.append(name)
                k += 1
        killer.join()
        svc.proc.wait(10)
        svc2 = Service(data)
        with HitchClient([svc2.endpoint], timeout_s=5.0) as c:
            present = {p["name"] for p in c.request("presets/list", {})["presets"]}
        svc2.proc.send_signal(signal.SIGTERM)
        svc2.proc.wait(10)
        lost = [a for a in acked if a not in present]
        lost_total += len(lost)
        per_round.append(
            {
                "acknowledged_this_round": len(acked) - n0,
                "lost": len(lost),
                "unacknowledged_but_present": len(present) - len(set(acked) & present),
            }
        )
    return {"rounds": per_round, "acknowledged_total": len(acked), "lost_total": lost_total}


def bench_shutdown(rounds: int) -> dict:
    took, reported = [], []
    for _ in range(rounds):
        svc = Service(tempfile.mkdtemp())
        with HitchClient([svc.endpoint], timeout_s=5) as c:
            c.goto({"z": 0.3})
            time.sleep(0.3)
        t0 = time.perf_counter()
        svc.proc.send_signal(signal.SIGTERM)
        rc = svc.proc.wait(10)
        took.append(time.perf_counter() - t0)
        time.sleep(0.2)
        line = next((ln for ln in svc.out if "stopped in" in ln), "")
        reported.append(float(line.split("stopped in")[1].split()[0]) if line else float("nan"))
        assert rc == 0, svc.out
    return {"signal_to_exit_s": took, "close_reported_ms": reported, "target_s": 1.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--role", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--connect", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--seconds", type=float, default=10.0, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=10_000, help=argparse.SUPPRESS)
    ap.add_argument("--seed", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--quick", action="store_true", help="short runs (smoke test)")
    ap.add_argument("--only", default="ik,jitter,sustained,fuzz,kill9,shutdown")
    ap.add_argument("--json", default=str(ROOT / "bench" / "out" / "service_bench.json"))
    a = ap.parse_args()
    if a.role == "subscriber":
        return role_subscriber(a)
    if a.role == "fuzzer":
        return role_fuzzer(a)
    only = set(a.only.split(","))
    q = a.quick
    res: dict = {"machine": {**machine_note(), "loadavg_at_start": os.getloadavg()}, "quick": q}
    if only & {"ik", "jitter", "sustained"}:
        svc = Service(tempfile.mkdtemp())
        try:
            if "ik" in only:
                res["ik"] = bench_ik(svc.endpoint, 500 if q else 5000)
                print("ik", json.dumps(res["ik"]), flush=True)
            if "jitter" in only:  # several 20 s windows: on a shared machine single windows scatter
                res["state_idle"] = [bench_jitter_idle(svc.endpoint, 3 if q else 20) for _ in range(1 if q else 3)]
                for r in res["state_idle"]:
                    print("state idle", json.dumps(r), flush=True)
            if "sustained" in only:
                res["sustained"] = bench_sustained(svc.endpoint, 500.0, 3 if q else 30)
                print("sustained", json.dumps(res["sustained"]), flush=True)
        finally:
            svc.kill()
    if "fuzz" in only:
        res["fuzz"] = bench_fuzz(1000 if q else 10_000)
        print(
            "fuzz",
            json.dumps({k: v for k, v in res["fuzz"].items() if k != "answered_ok"}),
            "answered_ok:",
            res["fuzz"]["answered_ok"][:5],
            flush=True,
        )
    if "kill9" in only:
        res["kill9"] = bench_kill9(2 if q else 5, 1.0 if q else 2.0)
        print("kill9", json.dumps(res["kill9"]), flush=True)
    if "shutdown" in only:
        res["shutdown"] = bench_shutdown(1 if q else 3)
        print("shutdown", json.dumps(res["shutdown"]), flush=True)
    res["machine"]["loadavg_at_end"] = os.getloadavg()
    write_json(a.json, res)
    print(f"written {a.json}")


if __name__ == "__main__":
    main()
