"""Simulated cylinder ECU: the thesis's identified hydraulics, unit controllers and watchdog.

The twin of the thesis's PhyCORE-MPC555 cylinder ECU (thesis §2.4–2.5.6), without
the CAN wiring: :class:`CylinderECU` is stepped in simulated time by its caller.

* :mod:`.cylinder`   — one valve + cylinder, model (thesis 1.1) with dead zone, minimum
  flow, direction-dependent gains, end stops and 10-bit AD quantisation;
* :mod:`.controller` — the modified PD unit controller (thesis 2.56–2.57) and the
  relay-type end-stop protection;
* :mod:`.watchdog`   — valves held at zero unless references keep arriving;
* :mod:`.ecu`        — five of each, the on/off switch and the system-state byte.

Everything inside runs in AD counts as the thesis ECU did; SI conversions are at the
boundary (:meth:`CylinderParams.counts_to_si`, :meth:`CylinderECU.positions_si`).
"""

from bridge.sim.controller import (
    THESIS_A,
    ControllerConfig,
    ControllerError,
    ControllerGains,
    ControllerOutput,
    EndStopRelay,
    RelayLimits,
    UnitController,
    build_controller_gains,
    build_relay_limits,
)
from bridge.sim.cylinder import (
    AD_MAX_COUNTS,
    VALVE_MAX,
    Cylinder,
    CylinderError,
    CylinderParams,
    build_cylinder_params,
    valve_flow_counts_per_s,
)
from bridge.sim.ecu import (
    ACTUATOR_ORDER,
    STATE_CONTROLLERS_ON,
    STATE_END_STOP_RELAY,
    STATE_NO_REFERENCE,
    STATE_RESTART_SHIFT,
    STATE_WATCHDOG_TRIPPED,
    CylinderECU,
    ECUError,
    SystemStatus,
    decode_system_state,
)
from bridge.sim.watchdog import Watchdog, WatchdogError

__all__ = [
    "THESIS_A",
    "ControllerConfig",
    "ControllerError",
    "ControllerGains",
    "ControllerOutput",
    "EndStopRelay",
    "RelayLimits",
    "UnitController",
    "build_controller_gains",
    "build_relay_limits",
    "AD_MAX_COUNTS",
    "VALVE_MAX",
    "Cylinder",
    "CylinderError",
    "CylinderParams",
    "build_cylinder_params",
    "valve_flow_counts_per_s",
    "ACTUATOR_ORDER",
    "STATE_CONTROLLERS_ON",
    "STATE_END_STOP_RELAY",
    "STATE_NO_REFERENCE",
    "STATE_RESTART_SHIFT",
    "STATE_WATCHDOG_TRIPPED",
    "CylinderECU",
    "ECUError",
    "SystemStatus",
    "decode_system_state",
    "Watchdog",
    "WatchdogError",
]
