"""The ``bridge`` facade: every public name is the defining module's object, loaded lazily.

Truth: the defining modules themselves, and ``sys.modules`` of a fresh interpreter (what an
import really loads).
"""

import importlib
import subprocess
import sys
import tomllib
from importlib import resources
from pathlib import Path

import pytest

import bridge


@pytest.mark.parametrize("name", bridge.__all__)
def test_every_public_name_is_the_defining_modules_object(name):
    source = bridge._SOURCES[name]
    assert getattr(bridge, name) is getattr(importlib.import_module(source), name)
    assert name in dir(bridge)


def test_all_and_the_sources_list_the_same_names():
    assert len(set(bridge.__all__)) == len(bridge.__all__)
    assert set(bridge.__all__) == set(bridge._SOURCES)


def test_an_unknown_name_is_an_attribute_error():
    with pytest.raises(AttributeError, match="no attribute 'Nope'"):
        _ = bridge.Nope
    assert not hasattr(bridge, "cli_main")


def _loaded_after(code: str) -> set[str]:
    out = subprocess.run(
        [sys.executable, "-c", code + "\nimport sys\nprint('\\n'.join(sorted(sys.modules)))"],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    return set(out.split())


def test_the_codec_and_the_link_load_without_zenoh_or_the_service():
    loaded = _loaded_after("import bridge.isobus.codec\nfrom bridge import Codec, LinkConfig, open_bus")
    assert "bridge.isobus.codec" in loaded and "bridge.link.state" in loaded
    assert "zenoh" not in loaded
    assert not any(m.startswith(("bridge.service", "bridge.cli", "bridge.web")) for m in loaded)


def test_import_bridge_alone_loads_no_subpackage():
    loaded = _loaded_after("import bridge")
    assert not any(m.startswith("bridge.") for m in loaded)
    assert "zenoh" not in loaded and "casadi" not in loaded


def test_bridge_is_marked_typed_and_ships_the_marker_as_planner_does():
    """Only ``planner/py.typed`` existed: a type checker treated ``bridge`` as untyped."""
    package_data = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())["tool"]["setuptools"][
        "package-data"
    ]
    for package in ("planner", "bridge"):
        assert (resources.files(package) / "py.typed").is_file(), package
        assert "py.typed" in package_data[package], package
