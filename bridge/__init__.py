"""The bridge from the planner to the machine: CAN codec, CAN link, simulated ECU, Zenoh service.

The public API, loaded lazily (PEP 562): ``import bridge`` or ``import bridge.isobus.codec``
imports nothing else, and a name is imported from its defining module on first use, so
``from bridge import Codec`` loads neither Zenoh nor the service::

    from bridge import HitchClient, ServiceError

    with HitchClient(["tcp/127.0.0.1:7447"]) as client:
        print(client.state()["pose"])

* codec (:mod:`bridge.isobus.codec`): :class:`Codec`, :func:`load_codec`, :func:`encode`,
  :func:`decode`, :func:`decode_frame`, :func:`encode_position_reference`, the reference
  payload :class:`PositionCounts`, :class:`Decoded`, :class:`CodecError`;
* link (:mod:`bridge.link`): :class:`CanLink`, :class:`LinkConfig`, :class:`RealtimeRunner`,
  :func:`open_bus`, :data:`INTERFACES`, :class:`LinkError`;
* simulation (:mod:`bridge.sim`): :class:`CylinderECU`, :class:`EcuCanNode`, :class:`SimRig`,
  :class:`SimSettings`, :class:`MoveSettings`, :func:`run_move`, :func:`build_move_figures`,
  :class:`SimError`;
* service (:mod:`bridge.service`): :class:`HitchService`, :class:`ServiceConfig`,
  :func:`load_service_config`, :func:`serve`, :data:`DEFAULT_LISTEN`, the client
  :class:`HitchClient`, its :class:`ServiceError` / :class:`ServiceTimeout` (the service refused
  or did not answer) and :class:`ClientError` (a client setting it cannot use).

The command line (:mod:`bridge.cli`) is not part of it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.isobus.codec import (
        Codec,
        CodecError,
        Decoded,
        PositionCounts,
        decode,
        decode_frame,
        encode,
        encode_position_reference,
        load_codec,
    )
    from bridge.link.can_link import CanLink
    from bridge.link.realtime import INTERFACES, RealtimeRunner, open_bus
    from bridge.link.state import LinkConfig, LinkError
    from bridge.service.client import ClientError, HitchClient, ServiceError, ServiceTimeout
    from bridge.service.config import DEFAULT_LISTEN, ServiceConfig, ServiceConfigError, load_service_config
    from bridge.service.server import HitchService, ServiceStartError, serve
    from bridge.sim.can_node import EcuCanNode
    from bridge.sim.ecu import CylinderECU
    from bridge.sim.move import MoveSettings, SimError, SimRig, SimSettings, build_move_figures, run_move

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "Codec",
            "CodecError",
            "Decoded",
            "PositionCounts",
            "decode",
            "decode_frame",
            "encode",
            "encode_position_reference",
            "load_codec",
        ),
        "bridge.isobus.codec",
    ),
    "CanLink": "bridge.link.can_link",
    **dict.fromkeys(("INTERFACES", "RealtimeRunner", "open_bus"), "bridge.link.realtime"),
    **dict.fromkeys(("LinkConfig", "LinkError"), "bridge.link.state"),
    **dict.fromkeys(("ClientError", "HitchClient", "ServiceError", "ServiceTimeout"), "bridge.service.client"),
    **dict.fromkeys(
        ("DEFAULT_LISTEN", "ServiceConfig", "ServiceConfigError", "load_service_config"), "bridge.service.config"
    ),
    **dict.fromkeys(("HitchService", "ServiceStartError", "serve"), "bridge.service.server"),
    "EcuCanNode": "bridge.sim.can_node",
    "CylinderECU": "bridge.sim.ecu",
    **dict.fromkeys(
        ("MoveSettings", "SimError", "SimRig", "SimSettings", "build_move_figures", "run_move"), "bridge.sim.move"
    ),
}

__all__ = [
    # codec
    "Codec",
    "CodecError",
    "Decoded",
    "PositionCounts",
    "decode",
    "decode_frame",
    "encode",
    "encode_position_reference",
    "load_codec",
    # link
    "CanLink",
    "INTERFACES",
    "LinkConfig",
    "LinkError",
    "RealtimeRunner",
    "open_bus",
    # simulation
    "CylinderECU",
    "EcuCanNode",
    "MoveSettings",
    "SimError",
    "SimRig",
    "SimSettings",
    "build_move_figures",
    "run_move",
    # service and client
    "ClientError",
    "DEFAULT_LISTEN",
    "HitchClient",
    "HitchService",
    "ServiceConfig",
    "ServiceConfigError",
    "ServiceError",
    "ServiceStartError",
    "ServiceTimeout",
    "load_service_config",
    "serve",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
