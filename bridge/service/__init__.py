"""The Zenoh service of the hitch planner (issue 7).

One long-running process per tractor: queryables for IK, planning, motion, presets and
maneuvers, a 50 Hz ``<prefix>/state`` publication, ``<prefix>/events`` and a liveliness
token ``<prefix>/alive``. Modules, one concept each:

* :mod:`.config`        — :class:`ServiceConfig` (defaults, TOML file, flags);
* :mod:`.schemas`       — strict request schemas and the payload parser;
* :mod:`.api`           — the transport-independent handler
  ``ServiceAPI.handle(key, payload_bytes, user) -> (ok, reply_dict)``;
* :mod:`.motion`        — :class:`MotionController`: the control thread, one motion at a time;
  its values in :mod:`.motion_types`, its loop in :mod:`.periodic`, its running maneuver in
  :mod:`.maneuver_slot`, its state message in :mod:`.state_message`;
* :mod:`.odometer`      — distance travelled from wheel-based speed on the CAN bus;
* :mod:`.server`        — :class:`HitchService`: CAN, Zenoh session, queryables, publishers, shutdown;
* :mod:`.client`        — :class:`HitchClient`: the client side used by the CLI and the bench;
* :mod:`.store`, :mod:`.maneuvers`, :mod:`.maneuver_runner`, :mod:`.security` — presets and
  maneuvers in SQLite, the maneuver language and its step runner, Zenoh authentication/ACL/TLS.

This package file imports nothing, so ``import bridge.service.store`` stays light.
"""

__all__: list[str] = []
