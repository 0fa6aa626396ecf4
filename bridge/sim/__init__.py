"""The simulated cylinder ECU: the thesis's identified hydraulics, unit controllers and watchdog,
on the CAN bus, and the rig that runs it against the planner link.

The twin of the thesis's PhyCORE-MPC555 cylinder ECU (thesis §2.4–2.5.6):

* :mod:`bridge.sim.cylinder`   — one valve + cylinder, model (thesis 1.1) with dead zone, minimum
  flow, direction-dependent gains, end stops and 10-bit AD quantisation;
* :mod:`bridge.sim.controller` — the modified PD unit controller (thesis 2.56–2.57) and the
  relay-type end-stop protection;
* :mod:`bridge.sim.watchdog`   — valves held at zero unless references keep arriving;
* :mod:`bridge.sim.ecu`        — five of each and the on/off switch, stepped in simulated time;
* :mod:`bridge.sim.can_node`   — the ECU as an ISO 11783 node (its messages, claim, heartbeat);
* :mod:`bridge.sim.fault_injector` — the node's bus through injected faults (cut, loss, delay, restart);
* :mod:`bridge.sim.rig`        — ECU node and planner link on a private bus in simulated time;
* :mod:`bridge.sim.truth`      — the twin's own true machine (truth profile, pin play), tape perturbation, instrument;
* :mod:`bridge.sim.accuracy_run` — the thesis's accuracy test (tables 3-8 … 3-10) against the twin;
* :mod:`bridge.sim.move`       — the closed-loop move experiment of ``hitch sim move``;
* :mod:`bridge.sim.terrain`    — the tractor driving over terrain: attitude, implement ground, crop row;
* :mod:`bridge.sim.sensors`    — the tractor's sensor payloads (slope, wheel speed, ground, row);
* :mod:`bridge.sim.scenario`   — terrain scenarios from TOML (built-ins in ``bridge/sim/scenarios/``);
* :mod:`bridge.sim.tractor_node` — the twin's tractor on the bus (its sensors' CAN messages).
* :mod:`bridge.sim.soil`       — a soil-engaging implement: ASABE D497 draft, soil patches, wheel slip;
* :mod:`bridge.sim.draft_sensor` — the lower-link draft pins and the rear hitch status they feed;
* :mod:`bridge.sim.field`      — field runs: implement, soil and draft pins over a terrain scenario.

Inside the ECU everything runs in AD counts as the thesis ECU did; SI conversions are at
the boundary (:meth:`CylinderParams.counts_to_si`, :meth:`CylinderECU.positions_si`). The
system-state byte the ECU sends is defined by the protocol, in :mod:`bridge.isobus.system_state`.

The names below load lazily (PEP 562): ``import bridge.sim`` imports none of the modules,
so the ECU model loads without the planner link.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from planner.lazy import lazy_exports

if TYPE_CHECKING:
    from bridge.sim.accuracy_run import (
        INSTRUMENTS,
        AccuracyRun,
        AccuracyRunSettings,
        FrameReading,
        read_frame,
        run_accuracy_test,
    )
    from bridge.sim.can_node import (
        EcuCanNode,
        EcuNodeConfig,
        EcuNodeCounters,
        EcuNodeError,
        lift_fraction,
    )
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
    from bridge.sim.draft_sensor import (
        DraftPinConfig,
        DraftPinError,
        DraftPins,
        DraftReading,
        rear_hitch_status,
    )
    from bridge.sim.ecu import (
        ACTUATOR_ORDER,
        CylinderECU,
        ECUError,
    )
    from bridge.sim.fault_injector import (
        CUTS,
        MAX_DELAY_MS,
        FaultCounters,
        FaultError,
        FaultInjector,
        FaultSettings,
    )
    from bridge.sim.field import (
        FieldDraft,
        FieldError,
        FieldRun,
        FieldSample,
        FieldSetup,
        builtin_fields,
        field_from_dict,
        load_field,
    )
    from bridge.sim.move import (
        REFERENCE_KINDS,
        MoveFigures,
        MoveSettings,
        MoveTrace,
        build_move_figures,
        run_move,
    )
    from bridge.sim.rig import (
        LossyBus,
        SimError,
        SimRig,
        SimSettings,
    )
    from bridge.sim.scenario import (
        Scenario,
        ScenarioError,
        builtin_scenarios,
        load_scenario,
        scenario_from_dict,
    )
    from bridge.sim.sensors import TwinSensors
    from bridge.sim.soil import (
        CHISEL_PLOW_STRAIGHT_POINT,
        FIELD_CULTIVATOR_PRIMARY,
        FIELD_CULTIVATOR_SECONDARY,
        MOLDBOARD_PLOW,
        D497Coefficients,
        Implement,
        SoilError,
        SoilField,
        TractionParams,
        d497_draft_n,
        tractive_capacity_n,
        wheel_slip,
    )
    from bridge.sim.terrain import (
        CrossSlopeWave,
        RowSignal,
        SampledGround,
        SineGround,
        SpeedProfile,
        TerrainError,
        TerrainTwin,
        TractorGeometry,
        TractorState,
        Undulation,
    )
    from bridge.sim.tractor_node import (
        TractorNodeConfig,
        TractorNodeError,
        TractorTwinNode,
        hitch_height_from_ecu,
    )
    from bridge.sim.truth import (
        COORDINATE_FIELDS,
        LENGTH_FIELDS,
        MARKED_POINTS,
        NOISE_KINDS,
        PLAY_MARKER,
        Instrument,
        InstrumentNoise,
        MachineTruth,
        Measurement,
        PinPlay,
        TapeErrors,
        TrueMachine,
        TruthError,
        load_machine_truth,
        perturb_profile,
        truth_toml,
    )
    from bridge.sim.watchdog import (
        Watchdog,
        WatchdogError,
    )

#: public name -> the module that defines it
_SOURCES: dict[str, str] = {
    **dict.fromkeys(
        (
            "AD_MAX_COUNTS",
            "VALVE_MAX",
            "CylinderError",
            "CylinderParams",
            "Cylinder",
            "build_cylinder_params",
            "valve_flow_counts_per_s",
        ),
        "bridge.sim.cylinder",
    ),
    **dict.fromkeys(
        (
            "THESIS_A",
            "ControllerError",
            "ControllerConfig",
            "ControllerGains",
            "RelayLimits",
            "ControllerOutput",
            "EndStopRelay",
            "UnitController",
            "build_controller_gains",
            "build_relay_limits",
        ),
        "bridge.sim.controller",
    ),
    **dict.fromkeys(
        (
            "WatchdogError",
            "Watchdog",
        ),
        "bridge.sim.watchdog",
    ),
    **dict.fromkeys(
        (
            "ACTUATOR_ORDER",
            "CylinderECU",
            "ECUError",
        ),
        "bridge.sim.ecu",
    ),
    **dict.fromkeys(
        (
            "EcuCanNode",
            "EcuNodeConfig",
            "EcuNodeCounters",
            "EcuNodeError",
            "lift_fraction",
        ),
        "bridge.sim.can_node",
    ),
    **dict.fromkeys(
        (
            "CUTS",
            "MAX_DELAY_MS",
            "FaultCounters",
            "FaultError",
            "FaultInjector",
            "FaultSettings",
        ),
        "bridge.sim.fault_injector",
    ),
    **dict.fromkeys(
        (
            "LossyBus",
            "SimError",
            "SimRig",
            "SimSettings",
        ),
        "bridge.sim.rig",
    ),
    **dict.fromkeys(
        (
            "INSTRUMENTS",
            "AccuracyRun",
            "AccuracyRunSettings",
            "FrameReading",
            "read_frame",
            "run_accuracy_test",
        ),
        "bridge.sim.accuracy_run",
    ),
    **dict.fromkeys(
        (
            "COORDINATE_FIELDS",
            "LENGTH_FIELDS",
            "MARKED_POINTS",
            "NOISE_KINDS",
            "PLAY_MARKER",
            "Instrument",
            "InstrumentNoise",
            "MachineTruth",
            "Measurement",
            "PinPlay",
            "TapeErrors",
            "TrueMachine",
            "TruthError",
            "load_machine_truth",
            "perturb_profile",
            "truth_toml",
        ),
        "bridge.sim.truth",
    ),
    **dict.fromkeys(
        (
            "MoveFigures",
            "MoveSettings",
            "MoveTrace",
            "REFERENCE_KINDS",
            "build_move_figures",
            "run_move",
        ),
        "bridge.sim.move",
    ),
    **dict.fromkeys(
        (
            "CrossSlopeWave",
            "RowSignal",
            "SampledGround",
            "SineGround",
            "SpeedProfile",
            "TerrainError",
            "TerrainTwin",
            "TractorGeometry",
            "TractorState",
            "Undulation",
        ),
        "bridge.sim.terrain",
    ),
    **dict.fromkeys(
        ("TwinSensors",),
        "bridge.sim.sensors",
    ),
    **dict.fromkeys(
        ("TractorNodeConfig", "TractorNodeError", "TractorTwinNode", "hitch_height_from_ecu"),
        "bridge.sim.tractor_node",
    ),
    **dict.fromkeys(
        (
            "Scenario",
            "ScenarioError",
            "builtin_scenarios",
            "load_scenario",
            "scenario_from_dict",
        ),
        "bridge.sim.scenario",
    ),
    **dict.fromkeys(
        (
            "CHISEL_PLOW_STRAIGHT_POINT",
            "FIELD_CULTIVATOR_PRIMARY",
            "FIELD_CULTIVATOR_SECONDARY",
            "MOLDBOARD_PLOW",
            "D497Coefficients",
            "Implement",
            "SoilError",
            "SoilField",
            "TractionParams",
            "d497_draft_n",
            "tractive_capacity_n",
            "wheel_slip",
        ),
        "bridge.sim.soil",
    ),
    **dict.fromkeys(
        ("DraftPinConfig", "DraftPinError", "DraftPins", "DraftReading", "rear_hitch_status"),
        "bridge.sim.draft_sensor",
    ),
    **dict.fromkeys(
        (
            "FieldDraft",
            "FieldError",
            "FieldRun",
            "FieldSample",
            "FieldSetup",
            "builtin_fields",
            "field_from_dict",
            "load_field",
        ),
        "bridge.sim.field",
    ),
}

__all__ = [
    # valve + cylinder (bridge.sim.cylinder)
    "AD_MAX_COUNTS",
    "VALVE_MAX",
    "CylinderError",
    "CylinderParams",
    "Cylinder",
    "build_cylinder_params",
    "valve_flow_counts_per_s",
    # unit controller and end-stop relay (bridge.sim.controller)
    "THESIS_A",
    "ControllerError",
    "ControllerConfig",
    "ControllerGains",
    "RelayLimits",
    "ControllerOutput",
    "EndStopRelay",
    "UnitController",
    "build_controller_gains",
    "build_relay_limits",
    # watchdog (bridge.sim.watchdog)
    "WatchdogError",
    "Watchdog",
    # the ECU (bridge.sim.ecu)
    "ACTUATOR_ORDER",
    "CylinderECU",
    "ECUError",
    # the ECU on the bus (bridge.sim.can_node)
    "EcuCanNode",
    "EcuNodeConfig",
    "EcuNodeCounters",
    "EcuNodeError",
    "lift_fraction",
    # fault injection (bridge.sim.fault_injector)
    "CUTS",
    "MAX_DELAY_MS",
    "FaultCounters",
    "FaultError",
    "FaultInjector",
    "FaultSettings",
    # the rig (bridge.sim.rig)
    "LossyBus",
    "SimError",
    "SimRig",
    "SimSettings",
    # the thesis's accuracy test against the twin (bridge.sim.accuracy_run)
    "INSTRUMENTS",
    "AccuracyRun",
    "AccuracyRunSettings",
    "FrameReading",
    "read_frame",
    "run_accuracy_test",
    # the twin's own true machine, tape perturbation, measuring instrument (bridge.sim.truth)
    "COORDINATE_FIELDS",
    "LENGTH_FIELDS",
    "MARKED_POINTS",
    "NOISE_KINDS",
    "PLAY_MARKER",
    "Instrument",
    "InstrumentNoise",
    "MachineTruth",
    "Measurement",
    "PinPlay",
    "TapeErrors",
    "TrueMachine",
    "TruthError",
    "load_machine_truth",
    "perturb_profile",
    "truth_toml",
    # closed-loop moves (bridge.sim.move)
    "MoveFigures",
    "MoveSettings",
    "MoveTrace",
    "REFERENCE_KINDS",
    "build_move_figures",
    "run_move",
    # the terrain twin (bridge.sim.terrain, .sensors, .scenario)
    "CrossSlopeWave",
    "RowSignal",
    "SampledGround",
    "SineGround",
    "SpeedProfile",
    "TerrainError",
    "TerrainTwin",
    "TractorGeometry",
    "TractorState",
    "Undulation",
    "TwinSensors",
    # the twin's tractor on the bus (bridge.sim.tractor_node)
    "TractorNodeConfig",
    "TractorNodeError",
    "TractorTwinNode",
    "hitch_height_from_ecu",
    "Scenario",
    "ScenarioError",
    "builtin_scenarios",
    "load_scenario",
    "scenario_from_dict",
    # the soil-engaging implement (bridge.sim.soil, .draft_sensor, .field)
    "CHISEL_PLOW_STRAIGHT_POINT",
    "FIELD_CULTIVATOR_PRIMARY",
    "FIELD_CULTIVATOR_SECONDARY",
    "MOLDBOARD_PLOW",
    "D497Coefficients",
    "Implement",
    "SoilError",
    "SoilField",
    "TractionParams",
    "d497_draft_n",
    "tractive_capacity_n",
    "wheel_slip",
    "DraftPinConfig",
    "DraftPinError",
    "DraftPins",
    "DraftReading",
    "rear_hitch_status",
    "FieldDraft",
    "FieldError",
    "FieldRun",
    "FieldSample",
    "FieldSetup",
    "builtin_fields",
    "field_from_dict",
    "load_field",
]


if not TYPE_CHECKING:
    __getattr__, __dir__ = lazy_exports(__name__, globals(), _SOURCES)
