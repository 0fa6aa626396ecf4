"""The ``bridge.link`` package (the planner-side CAN link): its public names, their error root, lazy loading."""

import bridge.link as package
from tests.helpers import bridge_modules_after, check_facade_errors, check_facade_names


def test_every_public_name_is_the_object_of_its_defining_module():
    check_facade_names(package)


def test_every_public_error_is_a_hitch_input_error():
    check_facade_errors(package)


def test_the_package_loads_nothing_and_the_link_needs_no_simulator():
    assert bridge_modules_after("import bridge.link") == {"bridge", "bridge.link"}
    loaded = bridge_modules_after("import bridge.link.can_link, bridge.link.realtime, bridge.link.unit_loop")
    assert "bridge.link.can_link" in loaded
    assert not any(m.startswith("bridge.sim") for m in loaded), loaded
