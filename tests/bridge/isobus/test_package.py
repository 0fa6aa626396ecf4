"""The ``bridge.isobus`` package (the ISO 11783 protocol layer): its public names, their error root, lazy loading."""

import pytest

import bridge.isobus as package
from tests.helpers import bridge_modules_after, check_facade_errors, check_facade_names


def test_every_public_name_is_the_object_of_its_defining_module():
    check_facade_names(package)


def test_every_public_error_is_a_hitch_input_error():
    check_facade_errors(package)


@pytest.mark.parametrize(
    ("module", "expected"),
    [
        ("bridge.isobus", {"bridge", "bridge.isobus"}),
        ("bridge.isobus.j1939", {"bridge", "bridge.isobus", "bridge.isobus.j1939"}),
        (
            "bridge.isobus.codec",
            {"bridge", "bridge.isobus", "bridge.isobus.codec", "bridge.isobus.j1939", "bridge.isobus.messages"},
        ),
    ],
)
def test_imports_stay_light(module, expected):
    assert bridge_modules_after(f"import {module}") == expected
