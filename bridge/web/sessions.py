"""Login for the operator terminal: accounts, sessions, CSRF tokens, failed-login throttling.

With access control on, the terminal asks for a user name and password from the same
``user:password`` dictionary the Zenoh links authenticate against; the service hands the
dictionary and the access policy's roles to :func:`~.server.start_http`, which builds
:class:`Accounts`. A successful login opens a :class:`Session`:

* a random token (``secrets.token_urlsafe``, 256 bit) in a cookie that is ``HttpOnly`` (no script
  reads it), ``SameSite=Strict`` (no other site's page sends it) and expires
  (``Max-Age`` = the session's lifetime; the server forgets the token then too);
* a second random token, the **CSRF token**, given to the page in the login answer (and by
  ``GET /api/session``) and required on every state-changing request: the ``X-CSRF-Token``
  header of an HTTP ``POST``, the ``csrf`` field of a WebSocket command. ``stop`` needs neither
  a session nor the token: whoever can reach the page may stop the hitch, also with an expired
  session (the Host/Origin checks still apply).

Passwords are kept only as salted SHA-256 digests (salt per process) and compared in constant
time; an unknown user costs the same comparison. Failed logins are throttled per user name
(:class:`LoginThrottle`). The store is bounded (:data:`MAX_SESSIONS`, oldest first out).
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from planner.errors import HitchInputError

__all__ = [
    "LoginError",
    "Accounts",
    "Session",
    "SessionStore",
    "LoginThrottle",
    "ROLES",
    "MAX_SESSIONS",
    "SESSION_TTL_S",
    "cookie_name",
    "cookie_value",
    "set_cookie",
    "clear_cookie",
]

#: the roles a terminal user can have (from the access policy)
ROLES: tuple[str, ...] = ("operator", "viewer")
#: sessions kept at once; a new login beyond this ends the oldest session
MAX_SESSIONS = 64
#: default session lifetime [s]: one working shift
SESSION_TTL_S = 8 * 3600.0


class LoginError(HitchInputError):
    """A login that is refused; ``status`` is the HTTP status to answer with, ``code`` the error code."""

    def __init__(self, message: str, status: int = 401, code: str = "unauthenticated"):
        self.status = status
        self.code = code
        super().__init__(message)


def _digest(salt: bytes, password: str) -> bytes:
    return hashlib.sha256(salt + password.encode("utf-8")).digest()


class Accounts:
    """Who may log in and with which role.

    Args:
        users: ``user -> password`` (the usrpwd dictionary of the security file).
        role_of: the user's role (``"operator"`` / ``"viewer"``), None for a user the access
            policy gives no role (refused at login: every command would be refused anyway).
    """

    def __init__(self, users: Mapping[str, str], role_of: Callable[[str], str | None]):
        if not isinstance(users, Mapping) or not users:
            raise LoginError("accounts: at least one user:password is needed for a login", 500, "internal")
        self._salt = secrets.token_bytes(16)
        self._digests = {str(u): _digest(self._salt, str(p)) for u, p in users.items()}
        self._dummy = _digest(self._salt, secrets.token_hex(16))
        self._role_of = role_of

    def __len__(self) -> int:
        return len(self._digests)

    def verify(self, user: str, password: str) -> str:
        """The user's role if ``password`` is right; :class:`LoginError` otherwise (same message for
        an unknown user and a wrong password)."""
        stored = self._digests.get(user, self._dummy)
        ok = hmac.compare_digest(stored, _digest(self._salt, password)) and user in self._digests
        if not ok:
            raise LoginError("login: wrong user name or password")
        role = self._role_of(user)
        if role not in ROLES:
            raise LoginError(
                f"login: user {user!r} has no role in the access policy (operators or viewers); "
                "ask whoever maintains the security file",
                403,
                "forbidden",
            )
        return role


@dataclass(frozen=True)
class Session:
    """One logged-in page: ``token`` (the cookie), ``csrf`` (the page's request token), the user,
    the role and the clock time [s, ``time.monotonic``] it ends."""

    token: str
    csrf: str
    user: str
    role: str
    expires_at: float

    def remaining_s(self, now: float) -> float:
        return max(0.0, self.expires_at - now)

    def csrf_ok(self, token: object) -> bool:
        """Is ``token`` this session's CSRF token (constant-time)?"""
        return isinstance(token, str) and hmac.compare_digest(token.encode(), self.csrf.encode())


class SessionStore:
    """The open sessions (thread-safe, bounded); ``clock`` is injectable for tests."""

    def __init__(
        self,
        ttl_s: float = SESSION_TTL_S,
        max_sessions: int = MAX_SESSIONS,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.ttl_s = float(ttl_s)
        self.max_sessions = int(max_sessions)
        self.clock = clock
        self._sessions: OrderedDict[str, Session] = OrderedDict()
        self._lock = threading.Lock()

    def __len__(self) -> int:
        with self._lock:
            return len(self._sessions)

    def open(self, user: str, role: str) -> Session:
        now = self.clock()
        s = Session(secrets.token_urlsafe(32), secrets.token_urlsafe(32), user, role, now + self.ttl_s)
        with self._lock:
            self._sessions[s.token] = s
            while len(self._sessions) > self.max_sessions:
                self._sessions.popitem(last=False)
        return s

    def get(self, token: str | None) -> Session | None:
        """The live session of ``token``; None for an unknown or expired token (then forgotten)."""
        if not token:
            return None
        with self._lock:
            s = self._sessions.get(token)
            if s is None:
                return None
            if self.clock() >= s.expires_at:
                del self._sessions[token]
                return None
            return s

    def close(self, token: str | None) -> Session | None:
        """End a session (logout); the session that ended, or None."""
        if not token:
            return None
        with self._lock:
            return self._sessions.pop(token, None)


class LoginThrottle:
    """At most ``max_failures`` failed logins per user name within ``window_s``; then that name is
    refused for ``lockout_s`` (429) — a password cannot be guessed at network speed."""

    def __init__(
        self,
        max_failures: int = 5,
        window_s: float = 60.0,
        lockout_s: float = 30.0,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.max_failures, self.window_s, self.lockout_s, self.clock = max_failures, window_s, lockout_s, clock
        self._failures: dict[str, deque[float]] = {}
        self._locked_until: dict[str, float] = {}
        self._lock = threading.Lock()

    def check(self, user: str) -> None:
        """:class:`LoginError` (429) while ``user`` is locked out."""
        with self._lock:
            until = self._locked_until.get(user, 0.0)
            wait = until - self.clock()
        if wait > 0:
            raise LoginError(
                f"login: too many failed logins for {user!r}; try again in {wait:.0f} s", 429, "too_many_logins"
            )

    def failed(self, user: str) -> None:
        now = self.clock()
        with self._lock:
            if len(self._failures) > 1024 and user not in self._failures:  # bounded: forget the oldest names
                self._failures.pop(next(iter(self._failures)))
            q = self._failures.setdefault(user, deque())
            q.append(now)
            while q and q[0] < now - self.window_s:
                q.popleft()
            if len(q) >= self.max_failures:
                self._locked_until[user] = now + self.lockout_s
                q.clear()

    def succeeded(self, user: str) -> None:
        with self._lock:
            self._failures.pop(user, None)
            self._locked_until.pop(user, None)


def cookie_name(port: int) -> str:
    """The session cookie's name; per port, because browsers share cookies between the ports of a host."""
    return f"hitch_session_{int(port)}"


def cookie_value(cookie_header: str, name: str) -> str | None:
    """The value of cookie ``name`` in a ``Cookie:`` header, or None."""
    for part in cookie_header.split(";"):
        k, sep, v = part.strip().partition("=")
        if sep and k == name:
            return v.strip() or None
    return None


def set_cookie(name: str, token: str, max_age_s: float) -> str:
    """The ``Set-Cookie`` value of a session cookie (no ``Secure``: the listener is plain HTTP on loopback)."""
    return f"{name}={token}; Path=/; HttpOnly; SameSite=Strict; Max-Age={max(0, int(max_age_s))}"


def clear_cookie(name: str) -> str:
    """The ``Set-Cookie`` value that deletes the session cookie."""
    return f"{name}=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0"
