"""The state carries the ECU's readings in AD counts (``actuator_counts``), as the bus brought them.

A new user commissioning by hand (docs/commissioning.md, step 3) had to write the readings at rest into the
measurement file in counts, and the state gave SI values only (through the very AD map being calibrated).

Truth: the simulated ECU's own readings (``CylinderECU.measurement_counts``), and the profile's AD map
applied to the counts gives the state's SI actuators.
"""

from __future__ import annotations

import numpy as np

from bridge.sim.ecu import ACTUATOR_ORDER
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from tests.helpers import SimService


def test_the_state_carries_the_ecus_readings_in_counts(model, tmp_path):
    s = SimService(model, tmp_path / "hitch.sqlite3", settle_s=0.5)
    try:
        s.ok("goto", {"goal": {"z": 0.15, "roll": 0.03}})
        s.run(6.0)
        state = s.states[-1]
        state = state if isinstance(state, dict) else state.to_json()
        counts = state["actuator_counts"]
        assert list(counts) == list(ACTUATOR_NAMES)
        ecu = dict(zip(ACTUATOR_ORDER, s.rig.ecu.measurement_counts(), strict=True))
        for name in ACTUATOR_NAMES:
            assert counts[name] == float(ecu[name]), (name, counts, ecu)  # at rest: the same readings
        si = SensorScaling(model.profile).to_si(tuple(counts[n] for n in ACTUATOR_NAMES))
        np.testing.assert_allclose(si, [state["actuators"][n] for n in ACTUATOR_NAMES], atol=1e-12)
    finally:
        s.close()
