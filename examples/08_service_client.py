"""The Zenoh service and its client, in one process, on a loopback port.

:class:`HitchService` runs the whole stack — CAN link, the simulated cylinder ECU on an
in-process virtual CAN bus, motion control, the Zenoh queryables and the 50 Hz state
publication. :class:`HitchClient` talks to it as ``hitch goto`` does. Loopback only, no
multicast scouting: nothing leaves this machine.
"""

import socket
import tempfile
import time

from bridge import HitchClient, HitchService, ServiceError, load_service_config


def free_loopback_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
with tempfile.TemporaryDirectory() as data_dir:
    config = load_service_config(  # the defaults, then these values (as the flags of `hitch serve`)
        listen=[endpoint],
        scouting=False,  # no multicast discovery
        can_channel=f"example-{free_loopback_port()}",  # a private virtual CAN channel
        data_dir=data_dir,  # presets and maneuvers (SQLite)
    )
    with HitchService(config) as service, HitchClient([endpoint], timeout_s=5.0) as client:
        deadline = time.monotonic() + 5.0
        while not client.state()["ecu"]["online"] and time.monotonic() < deadline:
            time.sleep(0.05)  # the link claims its address and hears the ECU within a few 100 ms
        p = client.state()["pose"]
        print(f"service on {endpoint}; pose x = {p['x']:+.4f} m, z = {p['z']:+.4f} m")

        ik = client.ik(0.02, 0.20, 0.01, 0.0)
        print(f"ik: {ik['status']}, actuators " + ", ".join(f"{k} {v:.4f}" for k, v in ik["actuators"].items()))

        move = client.goto({"z": 0.20}, speed_scale=1.0)
        print(f"goto z = 0.20 m: motion {move['motion_id']}, {move['duration']:.2f} s planned")
        final = client.wait_motion(move["motion_id"], timeout_s=move["duration"] + 5.0)
        print(f"arrived: z = {final['pose']['z']:+.4f} m (measured over CAN)")

        try:
            client.goto({"z": 0.6})  # above the workspace
        except ServiceError as exc:
            print(f"refused ({exc.code}): {exc}")
    print(f"closed in {1e3 * (service.close_duration_s or 0.0):.0f} ms")
