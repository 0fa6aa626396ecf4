"""The ``bridge.sim`` package (the simulated cylinder ECU): its public names, their error root, lazy loading."""

import bridge.sim as package
from tests.helpers import bridge_modules_after, check_facade_errors, check_facade_names


def test_every_public_name_is_the_object_of_its_defining_module():
    check_facade_names(package)


def test_every_public_error_is_a_hitch_input_error():
    check_facade_errors(package)


def test_the_package_loads_nothing_and_the_ecu_model_needs_no_link():
    assert bridge_modules_after("import bridge.sim") == {"bridge", "bridge.sim"}
    loaded = bridge_modules_after("import bridge.sim.ecu")
    assert "bridge.sim.ecu" in loaded
    assert not any(m.startswith("bridge.link") for m in loaded), loaded
