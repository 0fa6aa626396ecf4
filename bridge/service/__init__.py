"""The Zenoh service of the hitch planner (issue 7).

One long-running process per tractor: queryables for IK, planning, motion, presets and
maneuvers, a 50 Hz ``<prefix>/state`` publication, ``<prefix>/events`` and a liveliness
token ``<prefix>/alive``. Modules, one concept each:

* :mod:`.config`   — :class:`ServiceConfig` (defaults, TOML file, flags);
* :mod:`.api`      — strict request schemas and the transport-independent handler
  ``ServiceAPI.handle(key, payload_bytes, user) -> (ok, reply_dict)``;
* :mod:`.motion`   — :class:`MotionController`: the control thread, one motion at a time;
* :mod:`.server`   — :class:`HitchService`: Zenoh session, queryables, publishers, shutdown;
* :mod:`.client`   — :class:`HitchClient`: the client side used by the CLI and the bench;
* :mod:`.store`, :mod:`.maneuvers`, :mod:`.security` — presets/maneuvers in SQLite, the
  maneuver language, Zenoh authentication/ACL/TLS.

This package file imports nothing, so ``import bridge.service.store`` stays light.
"""

__all__: list[str] = []
