"""The Zenoh service of the hitch planner.

One long-running process per tractor: queryables for IK, planning, motion, presets and
maneuvers, a 50 Hz ``<prefix>/state`` publication, ``<prefix>/events`` and a liveliness
token ``<prefix>/alive``. Modules, one concept each:

* :mod:`.config`        — :class:`ServiceConfig` (defaults, TOML file, flags);
* :mod:`.schemas`       — strict request schemas and the payload parser;
* :mod:`.api`           — the transport-independent handler
  ``ServiceAPI.handle(key, payload_bytes, user) -> (ok, reply_dict)``;
* :mod:`.motion`        — the motion controller (package): :mod:`.motion.controller`
  (:class:`~bridge.service.motion.controller.MotionController`, the control thread, one motion at a
  time), :mod:`.motion.link_port` (what it needs of the CAN link), :mod:`.motion.types` (its values);
* :mod:`.periodic`      — the fixed-rate thread the control loop runs on;
* :mod:`.state_message` — the ``<prefix>/state`` message;
* :mod:`.maneuvers`     — maneuvers (package): :mod:`.maneuvers.steps` (the step schema),
  :mod:`.maneuvers.language` (parsing, validation by planning), :mod:`.maneuvers.runner` (the
  step logic of one run), :mod:`.maneuvers.slot` (the controller's running maneuver);
* :mod:`.odometer`      — distance travelled from wheel-based speed on the CAN bus;
* :mod:`.store`         — presets and maneuvers in SQLite;
* :mod:`.data_lock`     — one service per data folder;
* :mod:`.security`      — Zenoh authentication, access control, TLS;
* :mod:`.server`        — :class:`HitchService`: CAN, Zenoh session, queryables, publishers, shutdown;
* :mod:`.client`        — :class:`HitchClient`: the client side used by the CLI and the bench.

The names below load lazily (PEP 562): this package file imports nothing, so
``import bridge.service.store`` stays light.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.service.api import ServiceAPI
    from bridge.service.client import ClientError, HitchClient, ServiceError, ServiceTimeout
    from bridge.service.config import DEFAULT_LISTEN, ServiceConfig, ServiceConfigError, load_service_config
    from bridge.service.odometer import OdometerError, SimulatedTractor, WheelOdometer
    from bridge.service.periodic import PeriodError, PeriodicThread
    from bridge.service.schemas import API_KEYS, RequestError, parse_request
    from bridge.service.security import (
        MOTION_KEYS,
        AccessPolicy,
        Credentials,
        SecurityError,
        SecuritySettings,
        TlsSettings,
    )
    from bridge.service.server import HitchService, HitchServiceError, ServiceStartError, ServiceStopped, serve
    from bridge.service.state_message import EcuSummary, StateMessage
    from bridge.service.store import HitchStore, Preset, StoredManeuver, StoreError

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        ("ServiceConfig", "ServiceConfigError", "DEFAULT_LISTEN", "load_service_config"), "bridge.service.config"
    ),
    **dict.fromkeys(("API_KEYS", "RequestError", "parse_request"), "bridge.service.schemas"),
    **dict.fromkeys(("ServiceAPI",), "bridge.service.api"),
    **dict.fromkeys(("StateMessage", "EcuSummary"), "bridge.service.state_message"),
    **dict.fromkeys(("PeriodicThread", "PeriodError"), "bridge.service.periodic"),
    **dict.fromkeys(("WheelOdometer", "SimulatedTractor", "OdometerError"), "bridge.service.odometer"),
    **dict.fromkeys(("HitchStore", "Preset", "StoredManeuver", "StoreError"), "bridge.service.store"),
    **dict.fromkeys(
        ("SecuritySettings", "Credentials", "AccessPolicy", "TlsSettings", "SecurityError", "MOTION_KEYS"),
        "bridge.service.security",
    ),
    **dict.fromkeys(
        ("HitchService", "HitchServiceError", "ServiceStartError", "ServiceStopped", "serve"), "bridge.service.server"
    ),
    **dict.fromkeys(("HitchClient", "ClientError", "ServiceError", "ServiceTimeout"), "bridge.service.client"),
}

__all__ = [
    # configuration (bridge.service.config)
    "ServiceConfig",
    "ServiceConfigError",
    "DEFAULT_LISTEN",
    "load_service_config",
    # requests (bridge.service.schemas)
    "API_KEYS",
    "RequestError",
    "parse_request",
    # the handler (bridge.service.api)
    "ServiceAPI",
    # the state message (bridge.service.state_message)
    "StateMessage",
    "EcuSummary",
    # the control loop's thread (bridge.service.periodic)
    "PeriodicThread",
    "PeriodError",
    # distance travelled (bridge.service.odometer)
    "WheelOdometer",
    "SimulatedTractor",
    "OdometerError",
    # presets and maneuvers (bridge.service.store)
    "HitchStore",
    "Preset",
    "StoredManeuver",
    "StoreError",
    # Zenoh security (bridge.service.security)
    "SecuritySettings",
    "Credentials",
    "AccessPolicy",
    "TlsSettings",
    "SecurityError",
    "MOTION_KEYS",
    # the running service (bridge.service.server)
    "HitchService",
    "HitchServiceError",
    "ServiceStartError",
    "ServiceStopped",
    "serve",
    # the client (bridge.service.client)
    "HitchClient",
    "ClientError",
    "ServiceError",
    "ServiceTimeout",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
