"""Zenoh security for the hitch service: user/password authentication, access control
on the motion keys, TLS and mutual TLS — built programmatically for Zenoh 1.10.

The pieces, each a frozen value, combined in :class:`SecuritySettings`:

* :class:`Credentials` — this node's own user/password (``transport/auth/usrpwd/user|password``),
  sent when it opens a link; ``users_file`` — the ``user:password`` dictionary every incoming link
  must authenticate against (``transport/auth/usrpwd/dictionary_file``; :func:`write_users_file`).
* :class:`AccessPolicy` — the ``access_control`` section: default deny; under the key prefix,
  *operators* may use everything, *viewers* only the reading queries (:data:`VIEWER_QUERIES`:
  ``ik``, ``plan``, ``stop``, ``config``, ``presets/list``, ``maneuvers/validate``,
  ``maneuvers/list``) — never the operator keys (:data:`OPERATOR_KEYS`: the motion keys
  :data:`MOTION_KEYS` ``goto``, ``jog``, ``presets/go``, ``maneuvers/run``, ``mode`` and the
  writing keys :data:`WRITE_KEYS` ``presets/save``, ``presets/delete``, ``maneuvers/save``,
  ``maneuvers/delete``, ``faults/ack``, ``sim/fault``, ``track/…``) — and *services* (service
  nodes behind a router) may declare, publish and answer only under their own prefix
  (:meth:`AccessPolicy.service_prefix`: ``fleet/*/hitch`` gives service ``t01`` ``fleet/t01/hitch``) and send
  no query. Subjects are Zenoh usernames (from usrpwd) and,
  with mTLS, certificate common names. Every API key is either a reading key or an operator key
  (:func:`key_access`); a key in neither is refused to viewers.
* :class:`TlsSettings` — ``transport/link/tls``: a certificate and key (used both to listen on
  ``tls/…`` and, with ``mutual``, to present a client certificate), the CA to verify the other side,
  ``enable_mtls`` for mutual authentication.

Where the ACL must live: access control filters the links of the node that carries it. With
clients connecting straight to the service (the default peer setup) that is the service; in a
fleet behind a router it is the router (the service sees only the router's link and username),
with the service nodes listed as ``services``.

:func:`build_security_config` gives the Zenoh config sections as a dict; :func:`security_json5`
the text of a security file; :func:`apply_security` merges settings or such a file (parsed and
checked by Zenoh itself) into a ``zenoh.Config``. Denied queries get no reply: to a refused
user the motion queryables do not exist.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from planner.errors import HitchInputError

__all__ = [
    "access_policy_from_file",
    "MOTION_KEYS",
    "WRITE_KEYS",
    "WRITE_PREFIXES",
    "OPERATOR_KEYS",
    "VIEWER_QUERIES",
    "key_access",
    "SECTIONS",
    "SecurityError",
    "Credentials",
    "AccessPolicy",
    "TlsSettings",
    "SecuritySettings",
    "motion_keys",
    "write_keys",
    "build_acl",
    "confine_services",
    "build_security_config",
    "security_json5",
    "write_users_file",
    "apply_security",
    "security_sections",
    "exposure_warnings",
    "router_security_warnings",
    "read_users",
    "InternalLink",
    "grant_internal_user",
    "grant_internal_socket",
    "users_file_of",
    "connect_sections",
    "USER_SCOPE",
    "SCOPE_NAME_RULE",
    "scopable_user",
    "user_key",
    "scope_acl_users",
    "acl_scopes_users",
    "login_user",
]

#: API names that move the hitch; restricted to operators
MOTION_KEYS: tuple[str, ...] = (
    "goto",
    "jog",
    "presets/go",
    "maneuvers/run",
    "mode",
    "maneuvers/pause",
    "maneuvers/resume",
    "maneuvers/skip",
    "hitch/raise",
    "hitch/return",
    "work/start",
    "work/stop",
    "work/resume",
)
#: API names that change stored data or the service's state without moving; restricted to operators
WRITE_KEYS: tuple[str, ...] = (
    "presets/save",
    "presets/delete",
    "maneuvers/save",
    "maneuvers/delete",
    "faults/ack",
    "sim/fault",
    "maneuvers/record/start",
    "maneuvers/record/stop",
    "lines/save",
    "lines/delete",
    "implements/define",
    "implements/select",
    "implements/delete",
    "implements/lock",
    "implements/unlock",
    "sim/switch",
    "work/settings",
)
#: API name prefixes whose every key writes (restricted to operators): the track recorder's keys
WRITE_PREFIXES: tuple[str, ...] = ("track/",)
#: every API name restricted to operators (plus any key under WRITE_PREFIXES)
OPERATOR_KEYS: tuple[str, ...] = MOTION_KEYS + WRITE_KEYS
#: the reading queries a viewer may send (API names under the prefix; exact keys, no wildcards).
#: ``stop`` is deliberately open: anyone who can see the hitch may stop it.
VIEWER_QUERIES: tuple[str, ...] = (
    "ik",
    "plan",
    "stop",
    "config",
    "events/recent",
    "presets/list",
    "maneuvers/validate",
    "maneuvers/list",
    "lines/list",
    "implements/list",
)
#: the Zenoh 1.10 ACL message kinds, by the direction a client-side user needs them in
_OBSERVE_IN = ("declare_subscriber", "declare_liveliness_subscriber", "liveliness_query")
_TO_CLIENT = ("put", "delete", "reply", "declare_queryable", "liveliness_token")
_ALL = _OBSERVE_IN + ("query",) + _TO_CLIENT
#: the chunk under the prefix that carries each user's own copy of the request keys: ``hitch/user/alice/plan``
#: is ``plan`` sent by ``alice``. The ACL (:func:`scope_acl_users`) lets a user query only their own, so the
#: service knows who asked: admission of expensive requests, store owners and the black box are per user.
USER_SCOPE = "user"
#: a user name that can be one key chunk (the names :func:`scope_acl_users` scopes), and that rule in words
_SCOPE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$")
SCOPE_NAME_RULE = "1-64 of A-Z a-z 0-9 _ - ., a letter or digit first"
#: id of the rule :func:`scope_acl_users` adds to the services' policy, and the start of every id it adds
#: (``user_scope_<name>`` per user; ``user_scope:viewers``: no user name has a ':')
_SCOPE_ID = "user_scope"
#: the config sections this module owns
SECTIONS: tuple[str, ...] = ("transport/auth/usrpwd", "transport/link/tls", "access_control")


class SecurityError(HitchInputError):
    """Security settings that cannot be used; ``field`` names the setting."""

    def __init__(self, field: str, message: str):
        self.field = field
        super().__init__(f"{field}: {message}")


def _user(name: Any, what: str) -> str:
    if (
        not isinstance(name, str)
        or not name
        or len(name) > 64
        or any(c in name for c in ":\n\r\t ")
        or not name.isprintable()
    ):
        raise SecurityError(what, f"a user name must be 1-64 printable characters without ':' or spaces, got {name!r}")
    return name


def _key(prefix: Any, name: str | None = None, what: str = "prefix") -> str:
    if not isinstance(prefix, str) or not prefix or prefix.startswith("/") or prefix.endswith("/"):
        raise SecurityError(what, f"must be a key expression such as 'hitch' or 'fleet/*/hitch', got {prefix!r}")
    key = prefix if name is None else f"{prefix}/{name}"
    try:
        return str(zenoh.KeyExpr(key))
    except Exception as exc:  # zenoh raises its own ZError
        raise SecurityError(what, f"{key!r} is not a canonical Zenoh key expression ({exc})") from None


def _own_prefix_example(prefix: str) -> str:
    return "/".join("t07" if "*" in c or "$" in c else c for c in prefix.split("/"))


def _own_prefix(prefix: str, name: str, where: str = "access.service_prefixes") -> str:
    """The default prefix service ``name`` owns under ``prefix`` (:meth:`AccessPolicy.service_prefix`)."""
    chunks = prefix.split("/")
    wild = [i for i, c in enumerate(chunks) if "*" in c or "$" in c]
    if not wild:
        return prefix
    if len(wild) == 1 and chunks[wild[0]] == "*":
        if not scopable_user(name):
            raise SecurityError(
                where,
                f"service {name!r} cannot stand for the '*' of the prefix {prefix!r} (a key chunk: "
                f"{SCOPE_NAME_RULE}); name its own prefix in access.service_prefixes, e.g. "
                f"{{{name!r}: {_own_prefix_example(prefix)!r}}}",
            )
        chunks[wild[0]] = name
        return "/".join(chunks)
    raise SecurityError(
        where,
        f"the prefix {prefix!r} does not say which keys service {name!r} owns (only a prefix with one '*' chunk "
        f"does: the service's name in its place); name its own prefix in access.service_prefixes, e.g. "
        f"{{{name!r}: {_own_prefix_example(prefix)!r}}}",
    )


def motion_keys(prefix: str = "hitch") -> tuple[str, ...]:
    """The full motion keys under ``prefix``: ``hitch/goto`` … ``hitch/mode``."""
    return tuple(_key(prefix, k) for k in MOTION_KEYS)


def write_keys(prefix: str = "hitch") -> tuple[str, ...]:
    """The full writing keys under ``prefix`` (``hitch/presets/save`` …, ``hitch/track/**``)."""
    return tuple(_key(prefix, k) for k in WRITE_KEYS) + tuple(_key(prefix, f"{p}**") for p in WRITE_PREFIXES)


def key_access(key: str) -> str | None:
    """``"write"`` for an operator key (motion or data), ``"read"`` for a reading query, None if unknown."""
    if key in OPERATOR_KEYS or key.startswith(WRITE_PREFIXES):
        return "write"
    if key in VIEWER_QUERIES:
        return "read"
    return None


@dataclass(frozen=True)
class Credentials:
    """This node's user and password for usrpwd authentication (the password is not shown in repr)."""

    user: str
    password: str = field(repr=False)

    def __post_init__(self) -> None:
        _user(self.user, "credentials.user")
        if not isinstance(self.password, str) or not self.password or "\n" in self.password or len(self.password) > 256:
            raise SecurityError("credentials.password", "must be 1-256 characters on one line")


@dataclass(frozen=True)
class AccessPolicy:
    """Who may do what under ``prefix`` (a key expression; ``fleet/*/hitch`` on a fleet router)."""

    prefix: str = "hitch"
    operators: tuple[str, ...] = ()  # usernames allowed everything, motion included
    viewers: tuple[str, ...] = ()  # usernames allowed state, events and non-motion queries
    services: tuple[str, ...] = ()  # usernames of service nodes (behind a router): publish, answer
    operator_cert_names: tuple[str, ...] = ()  # mTLS certificate common names with operator rights
    viewer_cert_names: tuple[str, ...] = ()
    service_cert_names: tuple[str, ...] = ()
    viewer_queries: tuple[str, ...] = VIEWER_QUERIES  # API names viewers may query
    #: service name (username or certificate name) -> the keys that service node alone may publish and answer
    #: under (its own prefix, e.g. ``{"svc-7": "fleet/t07/hitch"}``); a service not named here owns
    #: :meth:`service_prefix`'s default
    service_prefixes: Mapping[str, str] = field(default_factory=dict, hash=False)

    def __post_init__(self) -> None:
        _key(self.prefix)
        vq = self.viewer_queries
        if isinstance(vq, str) or not all(isinstance(k, str) for k in vq):
            raise SecurityError("access.viewer_queries", "must be a list of API names such as 'ik'")
        for k in vq:
            if key_access(k) == "write" or "*" in k or "$" in k:
                raise SecurityError(
                    "access.viewer_queries",
                    f"{k!r} is an operator key (it moves the hitch or writes data) or a wildcard "
                    f"(allowed: exact reading API names: {', '.join(VIEWER_QUERIES)}); "
                    "a security file listing it for viewers was written by an older version: regenerate it",
                )
            _key(self.prefix, k, "access.viewer_queries")
        object.__setattr__(self, "viewer_queries", tuple(vq))
        seen: dict[str, str] = {}
        for role in ("operators", "viewers", "services"):
            names = getattr(self, role)
            if isinstance(names, str) or not isinstance(names, Sequence):
                raise SecurityError(f"access.{role}", "must be a list of user names")
            for n in names:
                _user(n, f"access.{role}")
                if n in seen:
                    raise SecurityError(f"access.{role}", f"user {n!r} is also listed in access.{seen[n]}")
                seen[n] = role
            object.__setattr__(self, role, tuple(names))
        for role in ("operator_cert_names", "viewer_cert_names", "service_cert_names"):
            names = getattr(self, role)
            if isinstance(names, str) or not all(isinstance(n, str) and n and n.isprintable() for n in names):
                raise SecurityError(f"access.{role}", "must be a list of non-empty certificate common names")
            object.__setattr__(self, role, tuple(names))
            own = role.removesuffix("_cert_names") + "s"  # a name is one user whether username or certificate
            for n in names:
                if seen.get(n, own) != own:
                    raise SecurityError(
                        f"access.{role}",
                        f"{n!r} is also a user in access.{seen[n]}: a username and a certificate name that are "
                        "equal are one user to the service and must have one role",
                    )
        self._check_service_prefixes()
        if not (
            self.operators
            or self.viewers
            or self.services
            or self.operator_cert_names
            or self.viewer_cert_names
            or self.service_cert_names
        ):
            raise SecurityError("access", "names nobody: with default deny no one could reach the service")

    def _check_service_prefixes(self) -> None:
        sp, where = self.service_prefixes, "access.service_prefixes"
        if not isinstance(sp, Mapping) or not all(isinstance(k, str) and isinstance(v, str) for k, v in sp.items()):
            raise SecurityError(
                where, "must map service names to their own key prefixes, e.g. {'t07': 'fleet/t07/hitch'}"
            )
        services = self.services + self.service_cert_names
        own: dict[str, str] = {}
        for name, prefix in sp.items():
            if name not in services:
                raise SecurityError(
                    where,
                    f"{name!r} is not a service (allowed: the names in access.services and access.service_cert_names: "
                    f"{', '.join(map(repr, services)) or 'none'})",
                )
            key = _key(prefix, what=where)
            if "*" in key or "$" in key or not zenoh.KeyExpr(self.prefix).includes(zenoh.KeyExpr(key)):
                raise SecurityError(
                    where,
                    f"{name!r}: {prefix!r} must be one service's own prefix: a key without wildcards under the "
                    f"prefix {self.prefix!r} (e.g. {_own_prefix_example(self.prefix)!r})",
                )
            own[name] = key
        object.__setattr__(self, "service_prefixes", own)
        for name in services:
            self.service_prefix(name)  # every service owns keys (or the policy is refused here, naming it)

    def service_prefix(self, name: str) -> str:
        """The prefix service node ``name`` owns: it may publish, answer and declare only under it.

        Its entry in :attr:`service_prefixes`; else the policy's prefix with ``name`` in place of its one ``*``
        chunk (``fleet/*/hitch``: service ``t07`` owns ``fleet/t07/hitch``); else, for a prefix without
        wildcards (one service's keys, ``hitch``), the prefix itself. Any other prefix (``**``, two ``*``
        chunks, ``$*``) needs the entry (:class:`SecurityError` naming ``access.service_prefixes``)."""
        own = self.service_prefixes.get(name)
        return own if own is not None else _own_prefix(self.prefix, name)

    def role(self, user: str) -> str | None:
        """``"operator"``, ``"viewer"``, ``"service"`` or None (a name in no role): a username, or a certificate
        common name (the user of a request on that name's own keys, :func:`scope_acl_users`)."""
        for role, names in (
            ("operator", self.operators + self.operator_cert_names),
            ("viewer", self.viewers + self.viewer_cert_names),
            ("service", self.services + self.service_cert_names),
        ):
            if user in names:
                return role
        return None

    def permits(self, user: str, key: str) -> bool:
        """May ``user`` use API name ``key``? Operators: everything; viewers: :attr:`viewer_queries`
        that are not operator keys; everyone else (services included, which answer, not ask): nothing."""
        role = self.role(user)
        if role == "operator":
            return True
        return role == "viewer" and key in self.viewer_queries and key_access(key) != "write"

    def refusal(self, user: str, key: str) -> str:
        """The sentence that refuses ``user`` the key ``key``."""
        head = f"{key}: user {user!r} ({self.role(user) or 'unknown user'}) may not use {key!r}"
        if key_access(key) == "write":
            return f"{head}; it {'moves the hitch' if key in MOTION_KEYS else 'writes data'} and needs an operator"
        return f"{head} (viewers may use: {', '.join(self.viewer_queries)}; everything else needs an operator)"


@dataclass(frozen=True)
class TlsSettings:
    """TLS files (PEM). ``certificate``/``private_key``: this node's (to listen on ``tls/…``, and the
    client certificate with ``mutual``); ``root_ca``: the CA that signed the other side's certificate;
    ``mutual``: mTLS — a listener demands client certificates, a client presents its own."""

    root_ca: Path | None = None
    certificate: Path | None = None
    private_key: Path | None = None
    mutual: bool = False
    verify_name: bool = True  # the server certificate must name the host connected to (e.g. IP:127.0.0.1)

    def __post_init__(self) -> None:
        for name in ("root_ca", "certificate", "private_key"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, Path(v))
        if (self.certificate is None) != (self.private_key is None):
            raise SecurityError(
                "tls.private_key" if self.private_key is None else "tls.certificate",
                "certificate and private_key go together",
            )
        if self.mutual and (self.root_ca is None or self.certificate is None):
            raise SecurityError("tls.mutual", "mutual TLS needs root_ca, certificate and private_key")
        for name in ("root_ca", "certificate", "private_key"):
            v = getattr(self, name)
            if v is not None and not v.is_file():
                raise SecurityError(f"tls.{name}", f"file {v} does not exist")


@dataclass(frozen=True)
class SecuritySettings:
    credentials: Credentials | None = None
    users_file: Path | None = None
    access: AccessPolicy | None = None
    tls: TlsSettings | None = None

    def __post_init__(self) -> None:
        if self.users_file is not None:
            object.__setattr__(self, "users_file", Path(self.users_file))
            if not self.users_file.is_file():
                raise SecurityError("users_file", f"file {self.users_file} does not exist")
        a = self.access
        if a is not None and (a.operators or a.viewers or a.services) and self.users_file is None:
            raise SecurityError(
                "users_file",
                "the access policy names users, but without a users_file no link "
                "is authenticated and no username can match",
            )
        if (
            a is not None
            and (a.operator_cert_names or a.viewer_cert_names or a.service_cert_names)
            and (self.tls is None or not self.tls.mutual)
        ):
            raise SecurityError("tls.mutual", "certificate names in the access policy need mutual TLS")


def build_acl(policy: AccessPolicy) -> dict:
    """The ``access_control`` section: default deny; see :class:`AccessPolicy` and the module docstring."""
    everything = [_key(policy.prefix, "**")]
    rules = [
        {
            "id": "observe",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": list(_OBSERVE_IN),
            "key_exprs": everything,
        },
        # `hitch fleet ls` asks for every service's liveliness token with one query on **/alive, which no
        # prefix includes (ACL rules match keys included in theirs): the names of the live services, nothing else
        {
            "id": "discover",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["liveliness_query"],
            "key_exprs": ["**/alive"],
        },
        {
            "id": "to_client",
            "permission": "allow",
            "flows": ["egress"],
            "messages": list(_TO_CLIENT),
            "key_exprs": everything,
        },
        # queries are allowed by exact key: ACL rules match keys *included* in theirs, so a wildcard
        # query such as 'hitch/**' (which would reach the motion queryables) matches none of these
        {
            "id": "viewer_queries",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["query"],
            "key_exprs": [_key(policy.prefix, k, "access.viewer_queries") for k in policy.viewer_queries],
        },
        {  # by exact key too (scope_acl_users: '<prefix>/**' would include every user's own keys)
            "id": "operator_queries",
            "permission": "allow",
            "flows": ["ingress"],
            "messages": ["query"],
            "key_exprs": _request_keys(policy.prefix),
        },
        # the streamed track setpoints are puts, not queries (operators only; viewers: no_writes); so is
        # the tractor's GNSS (a sensor input that times maneuver line triggers: an operator's receiver
        # bridge or a service node may publish it, a viewer may only observe it)
        {
            "id": "operator_puts",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": ["put", "declare_subscriber"],  # the service's subscriber is declared to the publisher
            "key_exprs": [_key(policy.prefix, "track/setpoint"), _key(policy.prefix, "tractor/gnss")],
        },
        # a put or delete on stop stops as the query does (fleet software broadcasting a stop): open as the query is
        {
            "id": "stop_puts",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": list(STOP_PUT_MESSAGES),
            "key_exprs": [_key(policy.prefix, "stop")],
        },
        {
            "id": "no_motion",
            "permission": "deny",
            "flows": ["ingress", "egress"],
            "messages": list(_ALL),
            "key_exprs": list(motion_keys(policy.prefix)),
        },
        {
            "id": "no_writes",
            "permission": "deny",
            "flows": ["ingress", "egress"],
            "messages": list(_ALL),
            "key_exprs": list(write_keys(policy.prefix)),
        },
        _SERVICE_OUT_RULE(everything),
    ]
    subjects, policies = [], []
    for role, users, certs, rule_ids in (
        (
            "operators",
            policy.operators,
            policy.operator_cert_names,
            ["observe", "discover", "to_client", "operator_queries", "operator_puts", "stop_puts"],
        ),
        (
            "viewers",
            policy.viewers,
            policy.viewer_cert_names,
            ["observe", "discover", "to_client", "viewer_queries", "stop_puts", "no_motion", "no_writes"],
        ),
        ("services", policy.services, policy.service_cert_names, [_SERVICE_OUT]),
    ):
        ids = []
        if users:
            subjects.append({"id": f"{role}_users", "usernames": list(users)})
            ids.append(f"{role}_users")
        if certs:
            subjects.append({"id": f"{role}_certs", "cert_common_names": list(certs)})
            ids.append(f"{role}_certs")
        if ids:
            policies.append({"id": role, "rules": rule_ids, "subjects": ids})
    own = [(n, "usernames", policy.service_prefix(n)) for n in policy.services]
    own += [(c, "cert_common_names", policy.service_prefix(c)) for c in policy.service_cert_names]
    _add_service_rules(rules, subjects, policies, own)
    acl = {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects, "policies": policies}
    return scope_acl_users(acl)


#: id of the rule of the ``services`` policy: what reaches a service node (its own declarations decide what)
_SERVICE_OUT = "service_out"
#: the start of the id of each service node's own subject, rule and policy (``service:<name>``,
#: ``service:cert:<common name>``; no user name has a ':')
_SERVICE_ID = "service:"


def _SERVICE_OUT_RULE(everything: list[str]) -> dict[str, Any]:  # noqa: N802 — a rule, as the others in build_acl
    """Everything under the prefix may go *to* a service node (egress): the router sends it only what its own
    declarations, confined to its own prefix, ask for (queries to its queryables, setpoints to its subscribers)
    and the subscribers that match its publications (a client ``fleet/*/hitch/state`` of every tractor)."""
    return {
        "id": _SERVICE_OUT,
        "permission": "allow",
        "flows": ["egress"],
        "messages": list(_ALL),
        "key_exprs": everything,
    }


def _add_service_rules(
    rules: list[dict[str, Any]],
    subjects: list[dict[str, Any]],
    policies: list[dict[str, Any]],
    own: Sequence[tuple[str, str, str]],
) -> None:
    """Per service node (``own``: name, ``usernames`` or ``cert_common_names``, its own prefix) one subject,
    rule and policy: from it (ingress) every message but ``query`` only under its own prefix — it declares its
    queryables, subscribers and token, publishes state and events and answers there, and asks nothing (a
    service node never sends a query: not to another service, not even a reading one)."""
    messages = [m for m in _ALL if m != "query"]
    for name, kind, prefix in own:
        rid = f"{_SERVICE_ID}cert:{name}" if kind == "cert_common_names" else f"{_SERVICE_ID}{name}"
        rules.append(
            {
                "id": rid,
                "permission": "allow",
                "flows": ["ingress"],
                "messages": messages,
                "key_exprs": [_key(prefix, "**", "access.service_prefixes")],
            }
        )
        subjects.append({"id": rid, kind: [name]})
        policies.append({"id": rid, "rules": [rid], "subjects": [rid]})


#: what the ``stop_puts`` rule lets through on exactly ``<prefix>/stop``: a put or a delete stops (a review: deletes
#: were refused by the default deny); the service's subscriber is declared to the publisher. Zenoh's access
#: control passes a key only when the rule's key includes it: with the fleet prefix ``fleet/*/hitch`` the put on
#: ``fleet/*/hitch/stop`` reaches every tractor, a wider wildcard (``fleet/**/stop``) is refused: send such a stop
#: to each service's own key there
STOP_PUT_MESSAGES = ("put", "delete", "declare_subscriber")


def allow_stop_puts(acl: Mapping[str, Any]) -> dict:
    """``acl`` (an ``access_control`` section as :func:`build_acl` writes it) with the ``stop_puts`` rule a file
    written before it lacks: a put on ``<prefix>/stop`` stops as the query does, and with the default deny such a
    file refused it silently (a put has no reply: the sender believed it had stopped the hitch; a review). Added
    to the operators' and viewers' policies, as the query on stop is open to both. Returned unchanged (a copy) when
    access control is off, the rule is there, or the file was not written by :func:`build_acl` (one prefix)."""
    out = json.loads(json.dumps(dict(acl)))
    rules = out.get("rules") or []
    if not out.get("enabled"):
        return out
    have = next((r for r in rules if r.get("id") == "stop_puts"), None)
    if have is not None:  # a rule of a version that let puts but not deletes through
        have["messages"] = list(dict.fromkeys([*(have.get("messages") or []), *STOP_PUT_MESSAGES]))
        return out
    everything = next((r.get("key_exprs") or [] for r in rules if r.get("id") == "observe"), [])
    prefixes = [k[: -len("/**")] for k in everything if k.endswith("/**")]
    if len(prefixes) != 1:
        return out
    rules.append(
        {
            "id": "stop_puts",
            "permission": "allow",
            "flows": ["ingress", "egress"],
            "messages": list(STOP_PUT_MESSAGES),
            "key_exprs": [f"{prefixes[0]}/stop"],
        }
    )
    out["rules"] = rules
    for policy in out.get("policies") or []:
        if policy.get("id") in ("operators", "viewers"):
            policy["rules"] = [*(policy.get("rules") or []), "stop_puts"]
    return out


def confine_services(acl: Mapping[str, Any]) -> dict:
    """``acl`` (an ``access_control`` section as :func:`build_acl` writes it) with an older version's services
    rule replaced: that one rule (id ``service``) let every service node send every message under the whole
    prefix — service ``t01`` could publish ``fleet/t02/hitch/state``, answer ``fleet/t02/hitch/stop`` and send
    ``fleet/t02/hitch/goto``. Each service node gets its own prefix instead, by the default of
    :meth:`AccessPolicy.service_prefix` (its name in place of the prefix's one ``*`` chunk; a prefix without
    wildcards: the prefix). A file whose prefix or service names give no default is refused
    (:class:`SecurityError`): regenerate it with :attr:`AccessPolicy.service_prefixes`. Returned unchanged (a
    copy) when access control is off, when the file has no such rule (this version's, or hand-written)."""
    out = json.loads(json.dumps(dict(acl)))  # a deep copy
    rules = out.get("rules") or []
    policies = out.get("policies") or []
    services = next((p for p in policies if p.get("id") == "services"), None)
    if not out.get("enabled") or services is None or "service" not in (services.get("rules") or []):
        return out
    everything = next((r.get("key_exprs") or [] for r in rules if r.get("id") == "observe"), [])
    prefixes = [k[: -len("/**")] for k in everything if k.endswith("/**")]
    if len(prefixes) != 1:
        return out  # not written by build_acl (it writes one prefix): left as its author wrote it
    subjects = out.get("subjects") or []
    own = []
    for field_, kind in (("usernames", "usernames"), ("cert_common_names", "cert_common_names")):
        for name in dict.fromkeys(_role_members(subjects, policies, field_).get("services", ())):
            try:
                own.append((name, kind, _own_prefix(prefixes[0], name)))
            except SecurityError as exc:
                raise SecurityError(
                    "access_control",
                    f"written by an older version, whose one services rule let every service node use every key "
                    f"under {prefixes[0]!r}; regenerate the file with security_json5: {exc}",
                ) from None
    rules = [r for r in rules if r.get("id") != "service"]
    rules.append(_SERVICE_OUT_RULE(everything))
    services["rules"] = [_SERVICE_OUT if r == "service" else r for r in services["rules"]]
    _add_service_rules(rules, subjects, policies, own)
    out["rules"], out["subjects"], out["policies"] = rules, subjects, policies
    return out


def scopable_user(name: Any) -> bool:
    """Can ``name`` have its own request keys (``<prefix>/user/<name>/<key>``)? One key chunk of
    letters, digits, ``_``, ``-`` and ``.`` (1-64, a letter or digit first); other user names use the
    shared keys only."""
    return isinstance(name, str) and bool(_SCOPE_NAME.match(name))


def user_key(prefix: str, user: str, key: str) -> str:
    """``<prefix>/user/<user>/<key>``: ``key`` sent as ``user`` (see :data:`USER_SCOPE`)."""
    if not scopable_user(user):
        raise SecurityError("user", f"{user!r} cannot name request keys (allowed: {SCOPE_NAME_RULE})")
    return f"{prefix}/{USER_SCOPE}/{user}/{key}"


def _request_keys(prefix: str) -> list[str]:
    """Every request key under ``prefix``, exact (the operator and the reading keys; ``track/**``)."""
    names = dict.fromkeys(OPERATOR_KEYS + VIEWER_QUERIES)
    return [f"{prefix}/{k}" for k in names] + [f"{prefix}/{p}**" for p in WRITE_PREFIXES]


def scope_acl_users(acl: Mapping[str, Any]) -> dict:
    """``acl`` (an ``access_control`` section as :func:`build_acl` writes it) plus each user's own keys.

    For every operator and viewer whose name is :func:`scopable_user` — a username, or with mutual TLS a
    certificate's common name (a username and a common name that are equal are one user to the service) —
    one subject (that name), one rule and one policy let them query ``<prefix>/user/<name>/<key>``:
    operators every request key, viewers their reading keys, each exact. Nobody else may query under
    ``<prefix>/user/``: the operators' queries are allowed by exact key (no ``<prefix>/**``, which would
    include every user's keys; a file of an earlier version has its ``operator_queries`` rule replaced), a
    rule denying queries on ``<prefix>/user/**`` joins the services' policy (a service node sends no query
    at all: :func:`build_acl`), and the viewers' policy denies every message on the operator keys under
    ``<prefix>/user/*/`` as it does on the plain ones. A deny cannot close the operators' ``<prefix>/**``
    instead: Zenoh takes the role's subject and a user's own for one subject when they name the same users,
    and a deny rule of a subject outweighs its allow rules.

    Rebuilt from the roles each time (a user added to a role by hand gets keys too). Returned unchanged
    when access control is off, when it was not written by :func:`build_acl` (no ``observe`` rule: a
    hand-written ACL names its own rules) or when a prefix contains ``**`` (a rule on ``a/**/hitch/ik``
    would include ``a/x/hitch/user/hitch/ik``: the user keys of the user named like the prefix's last
    chunk). :func:`acl_scopes_users` says whether the result scopes."""
    out = json.loads(json.dumps(dict(acl)))  # a deep copy
    if not out.get("enabled"):
        return out
    rules = [r for r in out.get("rules") or [] if not str(r.get("id", "")).startswith(_SCOPE_ID)]
    everything = next((r.get("key_exprs") or [] for r in rules if r.get("id") == "observe"), [])
    prefixes = [k[: -len("/**")] for k in everything if k.endswith("/**")]
    if not prefixes or any("**" in p for p in prefixes):
        return out
    subjects = [x for x in out.get("subjects") or [] if not str(x.get("id", "")).startswith(_SCOPE_ID)]
    policies = [p for p in out.get("policies") or [] if not str(p.get("id", "")).startswith(_SCOPE_ID)]
    for p in policies:
        p["rules"] = [r for r in p.get("rules") or [] if not str(r).startswith(_SCOPE_ID)]
    for r in rules:
        if r.get("id") == "operator_queries":  # a file of an earlier version allowed '<prefix>/**'
            r["key_exprs"] = [k for p in prefixes for k in _request_keys(p)]
    viewer_rule: dict[str, Any] = next((r for r in rules if r.get("id") == "viewer_queries"), {})
    viewer_keys = [
        k[len(p) + 1 :] for k in viewer_rule.get("key_exprs") or [] for p in prefixes if k.startswith(p + "/")
    ]
    role_users = _role_members(subjects, policies, "usernames")
    role_certs = _role_members(subjects, policies, "cert_common_names")
    viewers_deny = f"{_SCOPE_ID}:viewers"
    operator_only = [*OPERATOR_KEYS, *(f"{w}**" for w in WRITE_PREFIXES)]
    rules += [
        {
            "id": _SCOPE_ID,
            "permission": "deny",
            "flows": ["ingress"],
            "messages": ["query"],
            "key_exprs": [f"{p}/{USER_SCOPE}/**" for p in prefixes],
        },
        {
            "id": viewers_deny,
            "permission": "deny",
            "flows": ["ingress", "egress"],
            "messages": list(_ALL),
            "key_exprs": [f"{p}/{USER_SCOPE}/*/{k}" for p in prefixes for k in operator_only],
        },
    ]
    for p in policies:
        if p.get("id") == "services":
            p["rules"] = [*p["rules"], _SCOPE_ID]
        elif p.get("id") == "viewers":
            p["rules"] = [*p["rules"], viewers_deny]
    operator_keys = [k[len("hitch/") :] for k in _request_keys("hitch")]
    for role, keys in (("operators", operator_keys), ("viewers", viewer_keys)):
        # usernames (usrpwd) and certificate common names (mTLS): ids 'user_scope_<name>', 'user_scope:cert:<cn>'
        # (no user name has a ':', so neither clashes with the other nor with the rules above)
        named = [(u, "usernames", f"{_SCOPE_ID}_{u}") for u in dict.fromkeys(role_users.get(role, ()))]
        named += [(c, "cert_common_names", f"{_SCOPE_ID}:cert:{c}") for c in dict.fromkeys(role_certs.get(role, ()))]
        for user, kind, rid in named:
            if not scopable_user(user) or not keys:
                continue
            rules.append(
                {
                    "id": rid,
                    "permission": "allow",
                    "flows": ["ingress"],
                    "messages": ["query"],
                    "key_exprs": [f"{p}/{USER_SCOPE}/{user}/{k}" for p in prefixes for k in keys],
                }
            )
            subjects.append({"id": rid, kind: [user]})
            policies.append({"id": rid, "rules": [rid], "subjects": [rid]})
    out["rules"], out["subjects"], out["policies"] = rules, subjects, policies
    return out


def _role_members(subjects: Sequence[Mapping], policies: Sequence[Mapping], field: str) -> dict[Any, tuple[str, ...]]:
    """Policy id -> the names (``field``: ``usernames`` or ``cert_common_names``) of its subjects, in order
    (Zenoh writes null for the lists a subject leaves out)."""
    names = {x["id"]: tuple(x.get(field) or ()) for x in subjects}
    return {p.get("id"): tuple(n for sid in p.get("subjects") or [] for n in names.get(sid, ())) for p in policies}


def acl_scopes_users(source: SecuritySettings | Mapping | str | Path) -> bool:
    """Does the security file (or settings) ``source`` give users their own keys once applied
    (:func:`scope_acl_users`: at least one user's allow rule)? Only then may a service take the name in a
    user key for the sender's: the ACL lets no one else send it."""
    text = security_sections(source).get("access_control")
    acl = json.loads(text) if text else None
    if not isinstance(acl, dict):
        return False
    own = (f"{_SCOPE_ID}_", f"{_SCOPE_ID}:cert:")
    return any(str(r.get("id", "")).startswith(own) for r in scope_acl_users(acl).get("rules") or [])


def build_security_config(settings: SecuritySettings) -> dict:
    """The security sections as a nested Zenoh config dict (only what is set)."""
    out: dict[str, Any] = {}
    usrpwd: dict[str, Any] = {}
    if settings.credentials is not None:
        usrpwd.update(user=settings.credentials.user, password=settings.credentials.password)
    if settings.users_file is not None:
        usrpwd["dictionary_file"] = str(settings.users_file.resolve())
    if usrpwd:
        out.setdefault("transport", {})["auth"] = {"usrpwd": usrpwd}
    if settings.tls is not None:
        t = settings.tls
        tls: dict[str, Any] = {"enable_mtls": t.mutual, "verify_name_on_connect": t.verify_name}
        if t.root_ca is not None:
            tls["root_ca_certificate"] = str(t.root_ca.resolve())
        if t.certificate is not None and t.private_key is not None:  # they go together (TlsSettings)
            cert, key = str(t.certificate.resolve()), str(t.private_key.resolve())
            tls.update(listen_certificate=cert, listen_private_key=key)
            if t.mutual:
                tls.update(connect_certificate=cert, connect_private_key=key)
        out.setdefault("transport", {})["link"] = {"tls": tls}
    if settings.access is not None:
        out["access_control"] = build_acl(settings.access)
    return out


def security_json5(settings: SecuritySettings) -> str:
    """Text of a security file (JSON, which is JSON5) for ``--security`` / ``[zenoh] security``."""
    return json.dumps(build_security_config(settings), indent=2) + "\n"


def write_users_file(path: str | Path, users: Mapping[str, str]) -> Path:
    """Write the usrpwd dictionary (``user:password`` per line), readable by the owner only (0600)."""
    lines = []
    for user, password in users.items():
        Credentials(user, password)  # validates both
        lines.append(f"{user}:{password}\n")
    if not lines:
        raise SecurityError("users", "at least one user is needed")
    return _write_private(Path(path), "".join(lines))


def _write_private(path: Path, text: str) -> Path:
    """Write ``text`` to ``path``, readable by the owner only (0600) from its creation on."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(text)
    os.chmod(path, 0o600)
    return path


def _as_sections(config: zenoh.Config) -> dict[str, str]:
    return {s: config.get_json(s) for s in SECTIONS}


def security_sections(source: SecuritySettings | Mapping | str | Path) -> dict[str, str]:
    """Config path → JSON of each security section, from settings, a nested dict or a JSON5 file.

    Files and dicts are parsed and checked by Zenoh itself (unknown keys are errors); a file that
    sets anything outside ``transport/auth/usrpwd``, ``transport/link/tls`` and ``access_control``
    is refused, so a security file cannot quietly change endpoints or the mode.
    """
    if isinstance(source, SecuritySettings):
        source = build_security_config(source)
    if isinstance(source, (str, Path)):
        p = Path(source)
        if not p.is_file():
            raise SecurityError("security", f"file {p} does not exist")
        text, where = p.read_text(encoding="utf-8"), str(p)
    elif isinstance(source, Mapping):
        text, where = json.dumps(source), "<dict>"
    else:
        raise SecurityError("security", f"must be SecuritySettings, a dict or a file path, got {type(source).__name__}")
    if not text.strip():  # (Zenoh's parser said "expected array, boolean, null, number, object, or string")
        raise SecurityError(
            "security",
            f"{where} is empty: a security file is a JSON5 object with transport.auth.usrpwd, transport.link.tls "
            "and/or access_control (docs/security.md: security_json5 writes one)",
        )
    try:
        parsed = zenoh.Config.from_json5(text)
    except Exception as exc:  # zenoh's ZError: unknown key, wrong type, bad JSON5
        raise SecurityError("security", f"{where} is not a valid Zenoh security config: {exc}") from None
    foreign = _foreign_settings(parsed)
    if foreign:
        raise SecurityError(
            "security", f"{where} sets {', '.join(foreign)}; a security file may only set {', '.join(SECTIONS)}"
        )
    return _as_sections(parsed)


def _foreign_settings(parsed: zenoh.Config) -> list[str]:
    default = zenoh.Config()
    out = []
    for top in (
        "mode",
        "connect",
        "listen",
        "open",
        "gateway",
        "region_name",
        "metadata",
        "stats",
        "scouting",
        "timestamping",
        "queries_default_timeout",
        "routing",
        "aggregation",
        "qos",
        "adminspace",
        "namespace",
        "downsampling",
        "low_pass_filter",
        "plugins_loading",
        "plugins",
    ):
        try:
            if json.loads(parsed.get_json(top)) != json.loads(default.get_json(top)):
                out.append(top)
        except Exception:  # a section this Zenoh version does not have
            continue
    t, d = json.loads(parsed.get_json("transport")), json.loads(default.get_json("transport"))
    t["auth"]["usrpwd"], t["link"]["tls"] = d["auth"]["usrpwd"], d["link"]["tls"]
    if t != d:
        out.append("transport settings other than auth.usrpwd and link.tls")
    return out


def apply_security(config: zenoh.Config, source: SecuritySettings | Mapping | str | Path) -> zenoh.Config:
    """Merge the security sections of ``source`` into ``config`` (in place; returned for chaining)."""
    for path, value in security_sections(source).items():
        acl = json.loads(value) if path == "access_control" and value else None
        if isinstance(acl, dict):  # a file written before user scopes, own service prefixes, stop puts gets them
            value = json.dumps(scope_acl_users(confine_services(allow_stop_puts(acl))))
        try:
            config.insert_json5(path, value)
        except Exception as exc:
            raise SecurityError("security", f"Zenoh refused {path}: {exc}") from None
    return config


def access_policy_from_file(source: str | Path, prefix: str) -> AccessPolicy | None:
    """The operator/viewer roles of a security file's ``access_control`` section (as written by
    :func:`build_acl`), so commands that arrive outside Zenoh (the web terminal) are authorised
    exactly like Zenoh queries; None when the file has no access control."""
    sections = security_sections(source)
    text = sections.get("access_control")
    if not text:
        return None
    acl = json.loads(text)
    if not acl.get("enabled", False):
        return None
    subjects, policies = acl.get("subjects") or [], acl.get("policies") or []
    roles = _role_members(subjects, policies, "usernames")
    certs = _role_members(subjects, policies, "cert_common_names")
    viewer_rule = next((r for r in acl.get("rules", []) if r.get("id") == "viewer_queries"), None)
    queries = VIEWER_QUERIES
    if viewer_rule is not None:
        head = prefix.rstrip("/") + "/"
        queries = tuple(k[len(head) :] for k in viewer_rule.get("key_exprs", []) if k.startswith(head))
    return AccessPolicy(
        prefix=prefix,
        operators=roles.get("operators", ()),
        viewers=roles.get("viewers", ()),
        services=roles.get("services", ()),
        operator_cert_names=certs.get("operators", ()),
        viewer_cert_names=certs.get("viewers", ()),
        service_cert_names=certs.get("services", ()),
        viewer_queries=queries,
    )


def read_users(source: str | Path) -> dict[str, str]:
    """The ``user -> password`` dictionary a security file authenticates links against (its
    ``transport/auth/usrpwd/dictionary_file``, as :func:`write_users_file` writes it), e.g. for the
    operator terminal's login; {} when the file names none."""
    path = users_file_of(source)
    return {} if path is None else _read_users_file(path)


def _usrpwd(sections: Mapping[str, str]) -> dict[str, Any]:
    """The ``transport/auth/usrpwd`` section of :func:`security_sections`' result ({} when unset)."""
    return json.loads(sections.get("transport/auth/usrpwd") or "{}") or {}


def users_file_of(source: str | Path) -> Path | None:
    """The usrpwd dictionary file a security file names (None: none)."""
    path = _usrpwd(security_sections(source)).get("dictionary_file")
    return Path(path) if path else None


def login_user(source: str | Path) -> str | None:
    """The user a security file logs in as (``transport/auth/usrpwd/user``); None when it names none."""
    user = _usrpwd(security_sections(source)).get("user")
    return str(user) if user else None


def connect_sections(source: str | Path) -> dict[str, str]:
    """What a node needs from a security file to *connect* as the file's own node: the usrpwd ``user``
    and ``password`` and the TLS settings — not the users dictionary (it accepts no links) and not the
    access control (which would filter its own link by the other side's username, which a connecting
    node never learns: every message would be denied)."""
    sections = security_sections(source)
    usrpwd = _usrpwd(sections)
    out = {"transport/link/tls": sections.get("transport/link/tls") or "{}"}
    login = {k: usrpwd[k] for k in ("user", "password") if usrpwd.get(k)}
    if login:
        out["transport/auth/usrpwd"] = json.dumps(login)
    return out


def _read_users_file(path: Path) -> dict[str, str]:
    """``user -> password`` of a usrpwd dictionary file (``user:password`` per line)."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as exc:
        raise SecurityError("users_file", f"cannot read {path}: {exc}") from None
    users: dict[str, str] = {}
    for n, line in enumerate(lines, 1):
        if not line.strip():
            continue
        user, sep, password = line.partition(":")
        if not sep:
            raise SecurityError("users_file", f"{path} line {n}: expected user:password")
        users[_user(user, "users_file")] = password
    return users


@dataclass(frozen=True)
class _Protection:
    """What a listening node's security settings protect its links with."""

    certificate: bool  # a certificate to listen on tls/…
    passwords: bool  # a users dictionary (usrpwd) every link authenticates against
    mutual: bool  # mutual TLS: every link presents a certificate from the CA
    access: bool  # access control on
    login: str | None = None  # the user the settings log in as (a client's file has one)


def _protection(source: SecuritySettings | Mapping | str | Path | None) -> _Protection:
    if source is None:
        return _Protection(False, False, False, False)
    if isinstance(source, SecuritySettings):
        tls = source.tls
        return _Protection(
            certificate=tls is not None and tls.certificate is not None,
            passwords=source.users_file is not None,
            mutual=tls is not None and tls.mutual,
            access=source.access is not None,
            login=None if source.credentials is None else source.credentials.user,
        )
    sections = security_sections(source)
    usrpwd = _usrpwd(sections)
    tls_section = json.loads(sections.get("transport/link/tls") or "{}") or {}
    acl = json.loads(sections.get("access_control") or "{}") or {}
    dictionary = usrpwd.get("dictionary_file")
    # Zenoh checks no password against an empty dictionary (grant_internal_user): no users, no authentication
    passwords = bool(_read_users_file(Path(str(dictionary)))) if dictionary else False
    return _Protection(
        certificate=bool(tls_section.get("listen_certificate")),
        passwords=passwords,
        mutual=bool(tls_section.get("enable_mtls")) and bool(tls_section.get("root_ca_certificate")),
        access=bool(acl.get("enabled")),
        login=str(usrpwd["user"]) if usrpwd.get("user") else None,
    )


def exposure_warnings(listen: Sequence[str], settings: SecuritySettings | Mapping | str | Path | None) -> list[str]:
    """Sentences about listening beyond loopback without protection (loopback-only is the default).

    ``settings``: the listening node's security settings, or its security file (a path or a parsed dict); None
    without. A ``tls/…`` endpoint without a certificate is an error (:class:`SecurityError`).
    """
    p = _protection(settings)
    out = []
    for ep in listen:
        proto, _, addr = ep.partition("/")
        host = addr.rsplit(":", 1)[0].strip("[]")
        if proto == "tls" and not p.certificate:
            raise SecurityError("tls.certificate", f"listening on {ep} needs a certificate and private key")
        loopback = host in ("localhost", "::1") or host.startswith("127.") or proto == "unixsock-stream"
        if loopback:
            continue
        if proto != "tls":
            out.append(f"{ep} accepts unencrypted links from the network; use tls/… with a certificate")
        if not (p.passwords or (p.mutual and proto == "tls")):
            out.append(f"{ep} accepts links from the network without user/password authentication")
        if not p.access:
            out.append(f"{ep} exposes the motion keys to every connected node (no access_control)")
    return out


def router_security_warnings(
    listen: Sequence[str], source: SecuritySettings | Mapping | str | Path | None
) -> list[str]:
    """What a fleet router listening on ``listen`` with the security file (or settings) ``source`` (None:
    without) should say at start: :func:`exposure_warnings`, and that an authenticating file without access
    control lets every user it authenticates use every key, motion included.

    A ``source`` that authenticates no link (no users in a ``dictionary_file``, no mutual TLS) and enables no
    access control — a client's file given by mistake: it logs in, it protects nothing — is refused
    (:class:`SecurityError` naming ``security``): the router would run wide open while its operator believes
    it secured."""
    p = _protection(source)
    if source is not None and not (p.passwords or p.mutual or p.access):
        client = f" — it looks like a client's file (it logs in as {p.login!r})" if p.login else ""
        raise SecurityError(
            "security",
            f"{str(source) + ' ' if isinstance(source, (str, Path)) else ''}authenticates no link and enables "
            f"no access control{client}: a router's file needs transport/auth/usrpwd/dictionary_file (a users file "
            "with at least one user) or enable_mtls, and access_control (enabled: true); write one with "
            "security_json5(SecuritySettings(users_file=…, access=AccessPolicy(…))) (docs/security.md §5)",
        )
    out = exposure_warnings(listen, source)
    if source is not None and not p.access and not any("no access_control" in w for w in out):
        out.append(
            "the security file enables no access_control: every user it authenticates may use every key of "
            "every service behind the router, motion included"
        )
    if source is not None and p.access and not (p.passwords or p.mutual):
        out.append(
            "the security file authenticates no link (no users in a dictionary_file, no enable_mtls): its "
            "access_control can match no username or certificate name"
        )
    return out


#: the ids under which :func:`grant_internal_user` and :func:`grant_internal_socket` add their subject, rule
#: and policy to an ACL
INTERNAL_ACL_ID = "hitch_control_core"
#: the Unix socket of :func:`grant_internal_socket`, in the service's private 0700 directory
INTERNAL_SOCKET_NAME = "core.sock"


@dataclass(frozen=True)
class InternalLink:
    """How the service's own control core links to the service's session; made up at each start, never in
    the operator's files, never shown. Either a user (a users file authenticates every link: the core logs
    in, ``credentials``, against ``users_file``, the operator's users plus this one) or, without a users
    file, a Unix socket in a directory only the service's user can enter (``endpoint``) and a Zenoh id the
    core's session takes (``zid``), which the ACL allows only on that socket."""

    credentials: Credentials | None
    users_file: Path | None
    endpoint: str | None = None
    zid: str | None = None


def _allow_internal(config: zenoh.Config, prefix: str, subject: dict[str, Any]) -> None:
    """With access control on in ``config``: allow ``subject`` every message under ``prefix`` (the control
    core answers ``stop``, publishes the state and takes the setpoints)."""
    acl = json.loads(config.get_json("access_control") or "{}") or {}
    if not acl.get("enabled"):
        return
    rule = {
        "id": INTERNAL_ACL_ID,
        "permission": "allow",
        "flows": ["ingress", "egress"],
        "messages": list(_ALL),
        "key_exprs": [_key(prefix, "**")],
    }
    acl["rules"] = [*acl.get("rules", []), rule]
    acl["subjects"] = [*acl.get("subjects", []), {"id": INTERNAL_ACL_ID, **subject}]
    acl["policies"] = [
        *acl.get("policies", []),
        {"id": INTERNAL_ACL_ID, "rules": [INTERNAL_ACL_ID], "subjects": [INTERNAL_ACL_ID]},
    ]
    config.insert_json5("access_control", json.dumps(acl))


def grant_internal_user(config: zenoh.Config, prefix: str, directory: Path) -> InternalLink | None:
    """Let a made-up user (random name suffix and 32-byte password) in through ``config``'s usrpwd
    dictionary and, with access control on, allow it everything under ``prefix``; ``config`` is changed
    in place.

    None when ``config`` authenticates no user (no ``dictionary_file``, or one without users): adding a
    user would make Zenoh check passwords and lock out the operator's certificate-only clients; the core
    then links through :func:`grant_internal_socket`. ``directory`` must exist; the combined users file
    is written there (0600) and named in ``config``; Zenoh reads it when the session opens, after which
    the caller removes it."""
    import secrets

    usrpwd = json.loads(config.get_json("transport/auth/usrpwd") or "{}") or {}
    source = usrpwd.get("dictionary_file")
    if not source:
        return None
    users = _read_users_file(Path(source))
    if not users:  # Zenoh checks no password against an empty dictionary: a user added would start the checks
        return None
    name = f"hitch-core-{secrets.token_hex(4)}"
    while name in users:  # pragma: no cover — a clash with an operator's user name is 1 in 2^32
        name = f"hitch-core-{secrets.token_hex(4)}"
    creds = Credentials(name, secrets.token_urlsafe(32))
    text = Path(source).read_text(encoding="utf-8")  # the operator's lines (CRLF read as LF: Zenoh trims lines)
    head = text if not text or text.endswith("\n") else text + "\n"
    combined = _write_private(directory / "users", f"{head}{creds.user}:{creds.password}\n")
    config.insert_json5("transport/auth/usrpwd/dictionary_file", json.dumps(str(combined)))
    _allow_internal(config, prefix, {"usernames": [creds.user]})
    return InternalLink(creds, combined)


def grant_internal_socket(config: zenoh.Config, prefix: str, directory: Path) -> InternalLink:
    """The core's link of a service that authenticates no user by password (certificate-only, or no
    users file): the Unix socket ``directory/core.sock`` (the caller adds :attr:`InternalLink.endpoint` to
    the listen endpoints) and, with access control on in ``config``, everything under ``prefix`` allowed
    to the links that come through a Unix socket *and* carry a Zenoh id made up here (128 random bits; the
    core's session takes it). ``directory`` must be the service's own (0700: no other user of the computer
    can reach the socket) and stay while the session runs. No TLS on that link: it never leaves the
    computer; no password: none is checked."""
    import secrets

    zid = f"{secrets.randbits(128) | 1 << 127:032x}"  # Zenoh refuses an id with a leading 0
    _allow_internal(config, prefix, {"link_protocols": ["unixsock-stream"], "zids": [zid]})
    return InternalLink(None, None, endpoint=f"unixsock-stream/{directory / INTERNAL_SOCKET_NAME}", zid=zid)
