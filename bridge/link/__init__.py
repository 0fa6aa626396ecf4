"""The planner's side of the CAN bus: references out, measured state in, faults latched.

* :mod:`bridge.link.can_link` — :class:`CanLink`, the link to one cylinder ECU;
* :mod:`bridge.link.state` — its settings, measured state, faults, counters and errors;
* :mod:`bridge.link.arrival_rate` — frames of one source arriving faster than their sender sends them;
* :mod:`bridge.link.realtime` — opening a python-can bus and running a node in real time;
* :mod:`bridge.link.stop_signal` — the stop flag the real-time loops sleep on;
* :mod:`bridge.link.loopback` — a CAN hub on 127.0.0.1 for nodes in other processes;
* :mod:`bridge.link.unit_loop` — the feed-forward reference through the ECU's unit loops;
* :mod:`bridge.link.reference_check` — the hard-limit and count check of a reference before it is streamed;
* :mod:`bridge.link.count_tail` — a goto's end as whole counts (the profile's count approach);
* :mod:`bridge.link.sensor_calibration` — the sensor calibration: each cylinder to its end stops, the AD map fitted;
* :mod:`bridge.link.tractor_sensors` — the tractor's sensors (slope, ground, row, wheel speed) read from the bus.

The link runs without a simulator: nothing here imports ``bridge.sim``. The names below
load lazily (PEP 562): ``import bridge.link`` imports none of the modules.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.link.arrival_rate import ArrivalRate
    from bridge.link.can_link import CanLink
    from bridge.link.count_tail import CountTail, arrival_sides, build_count_tail, plan_count_tail
    from bridge.link.loopback import DEFAULT_HUB_PORT, LOOPBACK_HOST, LoopbackHub, hub_url
    from bridge.link.realtime import (
        INTERFACES,
        BusNode,
        RealtimeRunner,
        ReceivingNode,
        open_bus,
    )
    from bridge.link.reference_check import ReferenceCheck
    from bridge.link.sensor_calibration import (
        EndReading,
        LinkDriver,
        RealtimeDriver,
        RelayRule,
        SensorCalibration,
        SensorCalibrationError,
        SensorCalibrationSettings,
        SensorFit,
        calibration_profile,
        check_full_stroke,
        fit_sensor,
        full_stroke_hold,
        sensor_profile_toml,
    )
    from bridge.link.state import (
        HITCH_POSITION_STEPS,
        LinkConfig,
        LinkCounters,
        LinkError,
        LinkFaultError,
        LinkFaults,
        LinkState,
        LinkStatus,
        MeasurementAssembler,
        ReferenceRefused,
        check_address,
        check_period,
        lift_counts_from_fraction,
    )
    from bridge.link.stop_signal import StopSignal
    from bridge.link.tractor_sensors import (
        Plausibility,
        SignalReading,
        TractorReadings,
        TractorSensorCounters,
        TractorSensors,
        TractorSensorsConfig,
        WheelDistance,
    )
    from bridge.link.unit_loop import (
        ActuatorMotion,
        FeedforwardShaper,
        PoseState,
        SolveFull,
        UnitLoop,
        UnitLoopError,
        actuator_motion,
        build_unit_loops,
        feedforward_reference,
        safe_reference,
        unit_loop_lag_s,
    )
    from bridge.link.virtual import InProcessBus

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    "CanLink": "bridge.link.can_link",
    "ReferenceCheck": "bridge.link.reference_check",
    **dict.fromkeys(
        ("CountTail", "arrival_sides", "build_count_tail", "plan_count_tail"),
        "bridge.link.count_tail",
    ),
    **dict.fromkeys(
        (
            "LinkConfig",
            "LinkCounters",
            "LinkError",
            "LinkFaultError",
            "LinkFaults",
            "LinkState",
            "HITCH_POSITION_STEPS",
            "LinkStatus",
            "MeasurementAssembler",
            "ReferenceRefused",
            "check_address",
            "check_period",
            "lift_counts_from_fraction",
        ),
        "bridge.link.state",
    ),
    **dict.fromkeys(
        (
            "BusNode",
            "INTERFACES",
            "RealtimeRunner",
            "ReceivingNode",
            "open_bus",
        ),
        "bridge.link.realtime",
    ),
    **dict.fromkeys(("DEFAULT_HUB_PORT", "LOOPBACK_HOST", "LoopbackHub", "hub_url"), "bridge.link.loopback"),
    "InProcessBus": "bridge.link.virtual",
    "StopSignal": "bridge.link.stop_signal",
    "ArrivalRate": "bridge.link.arrival_rate",
    **dict.fromkeys(
        (
            "Plausibility",
            "SignalReading",
            "TractorReadings",
            "TractorSensorCounters",
            "TractorSensors",
            "TractorSensorsConfig",
            "WheelDistance",
        ),
        "bridge.link.tractor_sensors",
    ),
    **dict.fromkeys(
        (
            "ActuatorMotion",
            "FeedforwardShaper",
            "PoseState",
            "SolveFull",
            "UnitLoop",
            "UnitLoopError",
            "actuator_motion",
            "build_unit_loops",
            "feedforward_reference",
            "safe_reference",
            "unit_loop_lag_s",
        ),
        "bridge.link.unit_loop",
    ),
    **dict.fromkeys(
        (
            "EndReading",
            "LinkDriver",
            "RealtimeDriver",
            "RelayRule",
            "SensorCalibration",
            "SensorCalibrationError",
            "SensorCalibrationSettings",
            "SensorFit",
            "calibration_profile",
            "check_full_stroke",
            "fit_sensor",
            "full_stroke_hold",
            "sensor_profile_toml",
        ),
        "bridge.link.sensor_calibration",
    ),
}

__all__ = [
    # the link (bridge.link.can_link)
    "CanLink",
    # the check of a reference before it is streamed (bridge.link.reference_check)
    "ReferenceCheck",
    # a goto's end as whole counts (bridge.link.count_tail)
    "CountTail",
    "arrival_sides",
    "build_count_tail",
    "plan_count_tail",
    # settings, state, faults, errors (bridge.link.state)
    "LinkConfig",
    "LinkCounters",
    "LinkError",
    "LinkFaultError",
    "LinkFaults",
    "LinkState",
    "HITCH_POSITION_STEPS",
    "LinkStatus",
    "MeasurementAssembler",
    "ReferenceRefused",
    "check_address",
    "check_period",
    "lift_counts_from_fraction",
    # sensor calibration over the link (bridge.link.sensor_calibration)
    "EndReading",
    "LinkDriver",
    "RealtimeDriver",
    "RelayRule",
    "SensorCalibration",
    "SensorCalibrationError",
    "SensorCalibrationSettings",
    "SensorFit",
    "calibration_profile",
    "check_full_stroke",
    "fit_sensor",
    "full_stroke_hold",
    "sensor_profile_toml",
    # real time (bridge.link.realtime)
    "BusNode",
    "INTERFACES",
    "RealtimeRunner",
    "ReceivingNode",
    "StopSignal",
    "ArrivalRate",
    "open_bus",
    # python-can's in-process virtual bus with a cheaper frame copy (bridge.link.virtual)
    "InProcessBus",
    # loopback hub (bridge.link.loopback)
    "DEFAULT_HUB_PORT",
    "LOOPBACK_HOST",
    "LoopbackHub",
    "hub_url",
    # the tractor's sensors (bridge.link.tractor_sensors)
    "Plausibility",
    "SignalReading",
    "TractorReadings",
    "TractorSensorCounters",
    "TractorSensors",
    "TractorSensorsConfig",
    "WheelDistance",
    # unit-loop feed-forward (bridge.link.unit_loop)
    "ActuatorMotion",
    "FeedforwardShaper",
    "PoseState",
    "SolveFull",
    "UnitLoop",
    "UnitLoopError",
    "actuator_motion",
    "build_unit_loops",
    "feedforward_reference",
    "safe_reference",
    "unit_loop_lag_s",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
