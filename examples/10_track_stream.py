"""Track mode: stream setpoints and the hitch follows them, jerk-limited, within every limit.

A session (``track_start``) takes the motion key; each ``track_setpoint`` is a Zenoh put (not a
query) of the session's DOFs in its frame [m, rad] and optionally their velocity [m/s, rad/s];
``track_stop`` with the last ``seq`` sent ends it smoothly. Without a setpoint within ``ttl_ms`` the
hitch brakes to rest. The whole service runs in this process on a loopback port with its simulated
cylinder ECU, as in ``08_service_client.py``.
"""

import math
import socket
import tempfile
import time

from bridge import HitchClient, HitchService, load_service_config


def free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


RATE_HZ = 50.0  # setpoints per second (up to 100)
AMPLITUDE_M, FREQUENCY_HZ = 0.01, 0.25  # a sine in z within z's velocity limit: followed without lag

endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
with tempfile.TemporaryDirectory() as data_dir:
    config = load_service_config(
        listen=[endpoint], scouting=False, can_channel=f"example-{free_loopback_port()}", data_dir=data_dir
    )
    with HitchService(config) as service, HitchClient([endpoint], timeout_s=5.0) as client:
        deadline = time.monotonic() + 5.0
        while not client.state()["ecu"]["online"] and time.monotonic() < deadline:
            time.sleep(0.05)
        z0 = client.state()["pose"]["z"]
        r = client.track_start(frame="tractor", dof=["z"], ttl_ms=200)
        print(f"track session {r['session']} (motion {r['motion_id']}), ttl {r['ttl_ms']} ms, from z = {z0:+.4f} m")
        w = 2.0 * math.pi * FREQUENCY_HZ
        errors, seq, t0 = [], 0, time.monotonic()
        for seq in range(int(4.0 * RATE_HZ)):  # 4 s: one period
            t = seq / RATE_HZ
            pose, velocity = {"z": z0 + AMPLITUDE_M * math.sin(w * t)}, {"z": AMPLITUDE_M * w * math.cos(w * t)}
            if seq == 0:  # the first as a query: a bad value is named at once
                client.track_setpoint_request(r["session"], seq, pose, velocity)
            else:
                client.track_setpoint(r["session"], seq, pose, velocity)
            if seq % 25 == 0 and seq:
                errors.append(client.state()["pose"]["z"] - pose["z"])
            time.sleep(max(0.0, t0 + (seq + 1) / RATE_HZ - time.monotonic()))
        client.track_stop(r["session"], last_seq=seq)
        end = client.wait_motion(r["motion_id"], timeout_s=5.0)
        print(
            f"streamed {seq + 1} setpoints over {seq / RATE_HZ:.2f} s; z followed within "
            f"{1e3 * max(abs(e) for e in errors):.1f} mm of the setpoint at the samples (one state behind)"
        )
        print(f"stopped at z = {end['pose']['z']:+.4f} m, moving: {end['moving']}")
    print(f"closed in {1e3 * (service.close_duration_s or 0.0):.0f} ms")
