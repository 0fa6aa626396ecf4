"""Field runs: the chisel plough over the terrain scenario (undulation, soil patches, slip, draft message)."""

import math
import tomllib
from importlib import resources

import numpy as np
import pytest

from bridge.isobus.j1939 import Switch
from bridge.sim.field import FieldError, FieldRun, builtin_fields, field_from_dict, load_field
from bridge.sim.scenario import builtin_scenarios
from bridge.sim.soil import wheel_slip

KMH = 1.0 / 3.6


def _chisel_data() -> dict:
    text = (resources.files("bridge.sim") / "scenarios" / "fields" / "chisel.toml").read_text(encoding="utf-8")
    return tomllib.loads(text)


def test_builtin_field_loads_and_terrain_scenarios_are_unchanged():
    assert builtin_fields() == ["chisel"]
    assert builtin_scenarios() == ["flat", "guidance", "levelling", "levelling-inside", "terrain"]
    f = load_field("chisel")
    assert f.scenario.name == "terrain"
    assert f.implement.coefficients.name == "Chisel plow, 5 cm straight point"


def test_flat_uniform_field_gives_the_d497_draft_at_the_working_depth():
    data = _chisel_data()
    data["scenario"] = "flat"
    data["soil"] = {"variation": 0.0}
    data["draft_pins"] = {"noise_rms_n": 0.0, "tau_s": 0.0, "resolution_n": 0.0, "nominal_force_n": 40_000.0}
    f = field_from_dict(data)
    run = FieldRun(f)
    v = f.scenario.twin.speed.speed_m_s(5.0)
    x = run.step(5.0)
    expected = 0.85 * (91 + 5.4 * v / KMH) * 9 * 20  # F_2·(A + B·S)·W·T
    assert x.depth_m == pytest.approx(0.20, abs=1e-9)
    assert x.draft_n == pytest.approx(expected, rel=1e-9)
    assert x.measured.draft_n == pytest.approx(expected, rel=1e-9)
    assert x.vertical_force_n == pytest.approx(0.3 * expected)
    assert x.slip == pytest.approx(wheel_slip(f.traction, expected, 0.3 * expected))
    assert x.status.draft_n == pytest.approx(expected)
    assert x.status.in_work is Switch.ON
    # lifted out of the soil: no draft, not in work, no slip
    up = run.step(6.0, tip_z_m=0.3)
    assert (up.depth_m, up.draft_n, up.slip, up.status.in_work) == (0.0, 0.0, 0.0, Switch.OFF)


def test_undulation_moves_the_depth_and_patches_the_resistance():
    run = FieldRun(load_field("chisel"))
    xs = [run.step(0.05 * k) for k in range(2000)]
    depth = np.array([x.depth_m for x in xs])
    r = np.array([x.resistance for x in xs])
    # +-50 mm undulation of the terrain scenario under a held hitch: the depth swings about 20 cm
    assert depth.min() < 0.18 and depth.max() > 0.22 and depth.min() > 0.10 and depth.max() < 0.30
    assert r.min() >= 0.7 and r.max() <= 1.3 and r.max() - r.min() > 0.2
    d = np.array([x.draft_n for x in xs])
    s = np.array([x.slip for x in xs])
    # slip follows the draft: higher draft, higher slip
    assert np.corrcoef(d, s)[0, 1] > 0.99
    assert all(math.isfinite(x.slip) and not x.stalled for x in xs)


def test_a_draft_beyond_the_tractive_capacity_stalls_without_raising():
    data = _chisel_data()
    data["traction"] = {"cone_index_pa": 3.0e5, "wheel_load_n": 15_000.0}
    x = FieldRun(field_from_dict(data)).step(10.0)
    assert x.stalled and x.slip == 1.0


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda d: d["implement"].update(kind="harrow"), "implement.kind"),
        (lambda d: d["implement"].update(working_depth_m=0.9), "implement.working_depth_m"),
        (lambda d: d["soil"].update(variation=2.0), "soil.variation"),
        (lambda d: d["soil"].update(patch_length_m=50.0, length_m=10.0), "length_m"),
        (lambda d: d["draft_pins"].update(tau_s=-1.0), "draft_pins.tau_s"),
        (lambda d: d["traction"].update(grip=1.0), "traction.grip"),
        (lambda d: d.update(scenario="no-such-scenario"), "scenario"),
    ],
)
def test_bad_field_files_name_the_field(change, field):
    data = _chisel_data()
    change(data)
    with pytest.raises(FieldError, match=field.replace(".", r"\.")):
        field_from_dict(data)


def test_bad_step_input_names_the_field():
    with pytest.raises(FieldError, match="tip_z_m"):
        FieldRun(load_field("chisel")).step(1.0, tip_z_m=math.nan)
