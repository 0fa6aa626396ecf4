"""Settings of the operator terminal's web server and its request checks.

* :class:`WebSettings` — listen address (loopback by default), the user the page's commands
  run as without a login, extra accepted host names, the login session's lifetime;
* :func:`parse_address` — ``HOST:PORT`` → (host, port);
* :func:`host_allowed` / :func:`origin_allowed` — DNS-rebinding and cross-site (CSRF,
  cross-site WebSocket hijacking) protection: a page from another site cannot drive the hitch
  through an operator's browser;
* :func:`json_safe` — JSON-ready copies (non-finite floats → null, numpy → plain values);
* :data:`ERROR_STATUS` — HTTP status of each service error code.
"""

from __future__ import annotations

import ipaddress
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from planner.errors import HitchInputError

__all__ = [
    "WebSettings",
    "WebSettingsError",
    "STATIC_DIR",
    "ERROR_STATUS",
    "parse_address",
    "is_loopback",
    "host_allowed",
    "origin_allowed",
    "json_safe",
]

STATIC_DIR = Path(__file__).with_name("static")
#: HTTP status of each service error code (:mod:`bridge.service.api`); unknown codes → 400
ERROR_STATUS = {
    "bad_request": 400,
    "unknown_key": 404,
    "forbidden": 403,
    "mode": 409,
    "busy": 409,
    "locked": 409,
    "in_use": 409,
    "ecu": 503,
    "unavailable": 503,
    "unreachable": 422,
    "refused": 422,
    "ik_failed": 422,
    "not_found": 404,
    "invalid": 422,
    "store": 500,
    "internal": 500,
    # the terminal's own (login): no or an expired session, too many failed logins
    "unauthenticated": 401,
    "too_many_logins": 429,
}
_USER = re.compile(r"[^\s:]{1,64}")


class WebSettingsError(HitchInputError):
    """A listen address or setting of the web server it cannot use (named in the message)."""


def parse_address(addr: str) -> tuple[str, int]:
    """``"127.0.0.1:8080"`` / ``"[::1]:8080"`` / ``"localhost:0"`` → (host, port).

    Anything else: :class:`WebSettingsError` naming the problem.
    """
    if not isinstance(addr, str):
        raise WebSettingsError(f"http address must be a string HOST:PORT, got {addr!r}")
    m = re.fullmatch(r"\[([0-9A-Fa-f:.]+)\]:(\d{1,5})|([^\s:\[\]]+):(\d{1,5})", addr.strip())
    if not m:
        raise WebSettingsError(f"http address {addr!r} must be HOST:PORT, e.g. 127.0.0.1:8080 (port 0-65535)")
    host, port = (m.group(1), m.group(2)) if m.group(1) else (m.group(3), m.group(4))
    if not 0 <= int(port) <= 65535:
        raise WebSettingsError(f"http address {addr!r}: port must be in 0-65535")
    return host, int(port)


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback IP literals (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


@dataclass(frozen=True)
class WebSettings:
    """Where to listen and whom the page's commands run as.

    ``host``/``port``: the listen address (loopback unless configured; port 0 = any free port).
    ``user``: the user name passed to the service handler when the terminal has no login (with a
    login the logged-in user is passed). ``extra_hosts``: further ``Host`` header values
    accepted, e.g. ``"cab-display.local:8080"`` when listening on a LAN address. ``workers``:
    threads running handler calls (``stop`` has its own). ``static_dir``: the page's files.
    ``session_ttl_s``: lifetime of a login session [s] (60 s … 7 days).
    """

    host: str = "127.0.0.1"
    port: int = 8080
    user: str | None = None
    extra_hosts: tuple[str, ...] = ()
    workers: int = 4
    static_dir: Path = STATIC_DIR
    session_ttl_s: float = 8 * 3600.0

    def __post_init__(self) -> None:
        if not isinstance(self.host, str) or not self.host or any(c.isspace() for c in self.host):
            raise WebSettingsError(f"host must be a host name or IP address, got {self.host!r}")
        if isinstance(self.port, bool) or not isinstance(self.port, int) or not 0 <= self.port <= 65535:
            raise WebSettingsError(f"port must be an integer in 0-65535, got {self.port!r}")
        if isinstance(self.workers, bool) or not isinstance(self.workers, int) or not 1 <= self.workers <= 32:
            raise WebSettingsError(f"workers must be an integer in 1-32, got {self.workers!r}")
        if self.user is not None and (not isinstance(self.user, str) or not _USER.fullmatch(self.user)):
            raise WebSettingsError(f"user must be 1-64 characters without spaces or ':', got {self.user!r}")
        if isinstance(self.extra_hosts, str) or not all(isinstance(h, str) and h for h in self.extra_hosts):
            raise WebSettingsError("extra_hosts must be a list of HOST:PORT strings")
        ttl = self.session_ttl_s
        if isinstance(ttl, bool) or not isinstance(ttl, (int, float)) or not 60.0 <= ttl <= 7 * 86400.0:
            raise WebSettingsError(f"session_ttl_s must be a number of seconds in 60-604800, got {ttl!r}")
        object.__setattr__(self, "extra_hosts", tuple(h.lower() for h in self.extra_hosts))
        object.__setattr__(self, "static_dir", Path(self.static_dir))

    @property
    def loopback(self) -> bool:
        return is_loopback(self.host)


def host_allowed(host_header: str, bound: tuple[str, int], settings: WebSettings) -> bool:
    """Is ``Host: host_header`` a name of this server (DNS-rebinding protection)?

    Loopback names with the bound port are always accepted, plus the bound address and
    ``settings.extra_hosts``. A server listening on every interface (``0.0.0.0``, ``::``) also accepts
    any IP address with its port (it cannot know its addresses), but a *name* only from
    ``extra_hosts``: a page that re-points its own domain name to this server's address (DNS
    rebinding) sends its own name as ``Host`` (and as ``Origin``), and an IP literal is never one.
    """
    host = host_header.strip().lower()
    addr, port = bound
    if port == 80 and host and (host.endswith("]") or ":" not in host):  # a browser leaves out the default port
        host = f"{host}:80"
    names = {f"{h}:{port}" for h in ("127.0.0.1", "localhost", "[::1]", addr.lower(), f"[{addr.lower()}]")}
    if host in names or host in settings.extra_hosts:
        return True
    if addr not in ("0.0.0.0", "::"):
        return False
    name, sep, given_port = host.rpartition(":")
    if not sep or given_port != str(port):
        return False
    literal = name[1:-1] if name.startswith("[") and name.endswith("]") else name
    try:
        ipaddress.ip_address(literal)
    except ValueError:
        return False
    return True


def origin_allowed(origin_header: str, host_header: str) -> bool:
    """Same-origin only: no ``Origin`` (not a browser's cross-site request) or ``http(s)://<Host>``."""
    origin = origin_header.strip().lower()
    if not origin:
        return True
    host = host_header.strip().lower()
    return origin in (f"http://{host}", f"https://{host}")


def json_safe(obj: Any) -> Any:
    """A copy with non-finite floats as None and numpy scalars/arrays as plain JSON values."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, (str, int, bool)) or obj is None:
        return obj
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if hasattr(obj, "tolist"):  # numpy scalar or array
        return json_safe(obj.tolist())
    return str(obj)
