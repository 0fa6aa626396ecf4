"""CLI command ``hitch router``: a Zenoh router for a fleet of services.

Services run as Zenoh clients (``hitch serve --mode client --connect tcp/ROUTER:7447 --prefix
fleet/t07/hitch``) and operators' commands connect to the router (``hitch fleet ls --connect
tcp/ROUTER:7447``). The router is the eclipse-zenoh package in router mode with multicast
scouting off: it only listens on the given endpoints. Ctrl-C (SIGINT) or SIGTERM stops it.

``--security FILE`` is the router's own security file (docs/security.md §5: the users dictionary and the
access control of the fleet): a file that authenticates no link and enables no access control — a client's
file given by mistake — is refused, not run wide open. Like ``hitch serve``, the router warns (stderr) about
what it exposes beyond loopback without protection (``security.router_security_warnings``).
"""

from __future__ import annotations

import json
import sys

from bridge.cli.errors import CLIError
from bridge.cli.model import bounded_float
from bridge.service.config import DEFAULT_LEASE_S, DEFAULT_LISTEN, LEASE_RANGE_S, validate_endpoint

__all__ = ["add_commands", "router_config", "router_warnings"]


def router_config(listen: list[str], security: str | None = None, lease_s: float = DEFAULT_LEASE_S):
    """The zenoh.Config of a router listening on ``listen`` (no multicast scouting), secured by the security file
    ``security``; a file that would leave the router unprotected is refused (``security.SecurityError``, see
    :func:`router_warnings`)."""
    import zenoh

    from bridge.service.security import apply_security

    eps = [validate_endpoint(e) for e in listen]
    router_warnings(eps, security)  # refuses a file that protects nothing
    z = zenoh.Config()
    z.insert_json5("mode", json.dumps("router"))
    z.insert_json5("listen/endpoints", json.dumps(eps))
    z.insert_json5("connect/endpoints", "[]")
    z.insert_json5("scouting/multicast/enabled", "false")
    # its services count a frozen router lost within this (and brake, on_link_loss = "stop")
    z.insert_json5("transport/link/tx/lease", json.dumps(round(lease_s * 1000.0)))
    if security is not None:
        apply_security(z, security)
    return z


def router_warnings(listen: list[str], security: str | None = None) -> list[str]:
    """What the router says at start about its protection (``security.router_security_warnings``); raises
    ``security.SecurityError`` for a security file that authenticates no link and enables no access control."""
    from bridge.service.security import router_security_warnings

    return router_security_warnings([validate_endpoint(e) for e in listen], security)


def _cmd_router(args) -> int:
    import zenoh

    from bridge.service.client import zenoh_reason  # zenoh's own modules only where a router runs
    from bridge.service.security import SecurityError
    from bridge.service.signals import StopSignals

    listen = args.listen or [DEFAULT_LISTEN]
    try:
        warnings = router_warnings(listen, args.security)
        config = router_config(listen, args.security, args.lease_s)
    except SecurityError as exc:
        raise CLIError(f"hitch router: {exc}") from None
    for w in warnings:
        print(f"hitch router: warning: {w}", file=sys.stderr, flush=True)
    with StopSignals() as stop:  # a flag, not an Event: a handler must take no lock (bridge.service.signals)
        try:
            session = zenoh.open(config)
        except zenoh.ZError as exc:
            raise CLIError(f"hitch router: cannot listen on {', '.join(listen)}: {zenoh_reason(exc)}") from None
        try:
            print(
                f"hitch router: ready on {', '.join(listen)} (zid {session.info.zid()}, lease {args.lease_s:g} s)",
                flush=True,
            )
            while not stop.wait(0.5):
                pass
        finally:
            session.close()
        print("hitch router: stopped", flush=True)
        return 0


def add_commands(sub) -> None:
    p = sub.add_parser("router", help="run a Zenoh router for a fleet (services and clients connect to it)")
    p.add_argument(
        "--listen",
        action="append",
        default=None,
        metavar="ENDPOINT",
        help=f"listen endpoint (repeatable; default {DEFAULT_LISTEN})",
    )
    p.add_argument(
        "--security",
        default=None,
        help="the router's Zenoh security file (JSON5: users dictionary, access_control, TLS; docs/security.md §5); "
        "a file that authenticates no link and enables no access control (a client's) is refused",
    )
    lo, hi = LEASE_RANGE_S
    p.add_argument(
        "--lease-s",
        type=bounded_float("--lease-s", lo, hi, unit="s", lo_open=False),
        default=DEFAULT_LEASE_S,
        help=f"the link lease the router announces, [{lo:g}, {hi:g}] s (default {DEFAULT_LEASE_S:g}): its services "
        "count a router silent this long lost (and brake, on_link_loss = stop); for radio links with gaps raise it "
        "and the services' [zenoh] lease_s",
    )
    p.set_defaults(handler=_cmd_router)
