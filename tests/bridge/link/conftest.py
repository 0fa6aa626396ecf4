"""Fixtures of the link tests: the simulated rig (the planner's link and the twin's ECU on one virtual bus)."""

import pytest

from bridge.sim.move import SimRig


@pytest.fixture
def rig(model):
    """A started rig, 0.4 s in: the link has claimed its address and the ECU reports."""
    with SimRig(model) as r:
        r.start()
        r.run_until(0.4)
        yield r
