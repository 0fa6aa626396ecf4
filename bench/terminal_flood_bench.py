"""An HTTP ``stop`` to the operator terminal while pages flood its WebSocket with junk commands.

A fuzz trial (2026-12-07): one page sending thousands of tiny junk messages a second kept the terminal's
loop busy and an HTTP stop was answered 3.6–7.5 s late (eight pages: 7–12 s). The hub now closes a page
above its command rate (``bridge.web.hub.CommandRate``) and yields between a page's buffered commands.

Here ``N`` flooding pages each send batches of 200 masked ``garbage`` frames as fast as the socket takes them,
reconnecting whenever the terminal closes them (an attacker's worst case); meanwhile a stop is POSTed every
0.2 s on a fresh connection and timed from its send to its answer. The terminal serves a handler that answers
at once (the service's own stop path is measured by ``bench/service_bench.py``): the figure is the terminal's
own delay. Printed: the stops' median and maximum [ms], the junk frames sent and the connections made.

Run: .venv/bin/python bench/terminal_flood_bench.py [--pages 1,8] [--seconds 5] [--json FILE]
"""

from __future__ import annotations

import argparse
import http.client
import os
import socket
import threading
import time

try:  # imported as a module
    from bench._common import machine_note, percentiles_ms, write_json
except ImportError:  # run as a script: bench/ is sys.path[0]
    from _common import machine_note, percentiles_ms, write_json  # type: ignore[no-redef, import-not-found]


def _ws_connect(address: tuple[str, int]) -> socket.socket:
    """A WebSocket handshake on a raw socket (RFC 6455), the response head read and dropped."""
    import base64

    host, port = address
    sock = socket.create_connection((host, port), timeout=5)
    key = base64.b64encode(os.urandom(16)).decode()
    sock.sendall(
        (
            f"GET /ws HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
        ).encode()
    )
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(4096)
        if not chunk:
            raise ConnectionError("closed during the handshake")
        buf += chunk
    return sock


def _flood(address: tuple[str, int], done: threading.Event, counts: dict[str, int]) -> None:
    from bridge.web.websocket import OP_TEXT, encode_frame

    batch = encode_frame(OP_TEXT, b"garbage", mask=os.urandom(4)) * 200
    while not done.is_set():
        try:
            sock = _ws_connect(address)
            sock.settimeout(0.05)
            counts["connections"] += 1
            while not done.is_set():
                sock.sendall(batch)
                counts["sent"] += 200
                try:
                    while sock.recv(1 << 20):
                        pass
                except (TimeoutError, BlockingIOError):
                    pass
        except OSError:
            continue


def measure(pages: int, seconds: float) -> dict:
    from bridge.web.server import WebServer
    from bridge.web.settings import WebSettings

    def handler(name, body, user, *, received):
        return True, ({"stopped": True} if name == "stop" else {})

    web = WebServer(handler, WebSettings(port=0, workers=2)).start()
    done, counts = threading.Event(), {"sent": 0, "connections": 0}
    threads = [threading.Thread(target=_flood, args=(web.address, done, counts), daemon=True) for _ in range(pages)]
    try:
        for t in threads:
            t.start()
        time.sleep(0.5)
        stops: list[float] = []
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            conn = http.client.HTTPConnection(*web.address, timeout=30)
            t0 = time.monotonic()
            conn.request("POST", "/api/stop", body=b"{}", headers={"Content-Type": "application/json"})
            resp = conn.getresponse()
            resp.read()
            stops.append(time.monotonic() - t0)
            conn.close()
            time.sleep(0.2)
    finally:
        done.set()
        web.close()
    return {"pages": pages, "stops": len(stops), **percentiles_ms(stops, (50,)), **counts}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pages", default="1,8", help="comma-separated numbers of flooding pages (default 1,8)")
    ap.add_argument("--seconds", type=float, default=5.0, help="how long stops are sent per case (default 5)")
    ap.add_argument("--json", default=None, help="write the results here too")
    args = ap.parse_args()
    rows = [measure(int(n), args.seconds) for n in args.pages.split(",")]
    load = os.getloadavg()[0]
    print(f"HTTP stop under a WebSocket junk flood (load average {load:.1f} over 1 min, {os.cpu_count()} cores)")
    print("pages  stops  median ms  max ms  junk frames  connections")
    for r in rows:
        print(
            f"{r['pages']:>5}  {r['stops']:>5}  {r['p50_ms']:>9.1f}  {r['max_ms']:>6.1f}  {r['sent']:>11}  "
            f"{r['connections']:>11}"
        )
    write_json(args.json, {"machine": machine_note(), "load_1min": load, "rows": rows})


if __name__ == "__main__":
    main()
