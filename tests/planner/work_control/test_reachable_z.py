"""The draft regulator within the z range the hitch can reach (``step(…, z_range=…)``): a field trial drove the
setpoint 0.2 m below the workspace floor (depth limit 0.6 m) with the hitch sitting on the floor, reported
the setpoint's depth instead of the real one, and after a lower draft setpoint the hitch stayed on the floor
for 2.3 s while the wound-up demand came back. The toy hitch here follows with a lag and stops at the floor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from planner.work_control import WorkController, WorkSettings
from planner.work_control.controller import KI_DRAFT

DT = 0.02
FLOOR, TOP = -0.2, 0.5  # the reachable z range
G = 0.1  # ground reference: the depth limit 0.6 lies 0.3 m below the floor
DRAFT_N = 1_000.0  # what the soil gives (far below a huge setpoint, above a small one)


def run(wc, z, t0, duration, *, z_range=(FLOOR, TOP), preview=False, tau=0.15):
    """The toy loop: z follows the setpoint with a first-order lag ``tau`` and stops at the floor."""
    rng = np.random.default_rng(1)
    a = 1.0 - math.exp(-DT / tau)
    out = []
    for k in range(int(round(duration / DT))):
        t = t0 + k * DT
        kw = {"ground_ahead_z": G} if preview else {}
        st = wc.step(
            t, 0.0, draft_n=DRAFT_N + float(rng.normal(0.0, 20.0)), draft_t=t, ground_z=G, z_range=z_range, **kw
        )
        z = max(FLOOR, z + a * (st.z - z))
        out.append((t, st, z))
    return out, z


@pytest.mark.parametrize("preview", [False, True])
@pytest.mark.parametrize("rate", [None, 0.08])
def test_a_huge_setpoint_stops_at_the_floor_and_a_lower_one_leaves_it_within_a_time_constant(preview, rate):
    s = WorkSettings(mode="draft", draft_setpoint_n=300_000.0, depth_min_m=0.0, depth_max_m=0.6)
    wc = WorkController(s, z_rate_max_m_s=rate)
    cycles, z = run(wc, 0.0, 0.0, 8.0, preview=preview)
    assert min(st.z for _, st, _ in cycles) >= FLOOR - 1e-12
    _, st, _ = cycles[-1]
    assert st.z == pytest.approx(FLOOR) and st.z_limit == "min"
    assert st.depth_m == pytest.approx(G - FLOOR)  # the depth the hitch can reach, not the limit's 0.6
    wc.configure(WorkSettings(mode="draft", draft_setpoint_n=500.0, depth_min_m=0.0, depth_max_m=0.6))
    after, _ = run(wc, z, 8.0, 2.0, preview=preview)
    left = next(t for t, _, zz in after if zz > FLOOR + 5e-3) - 8.0
    assert left <= 1.0 / KI_DRAFT, left
    assert after[-1][1].z_limit is None


def test_without_the_range_the_old_regulator_winds_up_below_the_floor():
    """The contrast (no ``z_range``: the regulator as it was): the demand goes 0.3 m below the floor and the
    hitch stays on the floor far longer than a time constant after the lower setpoint."""
    s = WorkSettings(mode="draft", draft_setpoint_n=300_000.0, depth_min_m=0.0, depth_max_m=0.6)
    wc = WorkController(s, z_rate_max_m_s=0.08)
    cycles, z = run(wc, 0.0, 0.0, 8.0, z_range=None)
    assert cycles[-1][1].z == pytest.approx(G - 0.6) and cycles[-1][1].z_limit is None
    wc.configure(WorkSettings(mode="draft", draft_setpoint_n=500.0, depth_min_m=0.0, depth_max_m=0.6))
    after, _ = run(wc, z, 8.0, 6.0, z_range=None)
    left = next(t for t, _, zz in after if zz > FLOOR + 5e-3) - 8.0
    assert left > 3.0 / KI_DRAFT, left


def test_mixed_stays_within_the_range_and_names_the_top():
    """The top face too, and mixed mode: with the ground high above the workspace top the draft demand (a draft
    far above its setpoint: shallower) stops at the top and the output is named only when it sits there."""
    s = WorkSettings(mode="draft", draft_setpoint_n=500.0, depth_min_m=0.0, depth_max_m=0.3)
    wc = WorkController(s)
    for k in range(200):
        st = wc.step(k * DT, 0.0, draft_n=DRAFT_N + 5 * math.sin(k), draft_t=k * DT, ground_z=0.9, z_range=(-0.2, 0.5))
        assert st.z <= 0.5 + 1e-12
    assert st.z == pytest.approx(0.5) and st.z_limit == "max" and st.depth_m == pytest.approx(0.4)
    wc.configure(WorkSettings(mode="mixed", blend=0.5, draft_setpoint_n=500.0, depth_min_m=0.0, depth_max_m=0.3))
    for k in range(200, 400):
        st = wc.step(k * DT, 0.0, draft_n=DRAFT_N + 5 * math.sin(k), draft_t=k * DT, ground_z=0.9, z_range=(-0.2, 0.5))
    assert st.z == pytest.approx(0.25) and st.z_limit is None  # half the operator's 0, half the top 0.5


def test_a_bad_range_is_refused():
    from planner.work_control import WorkSettingsError

    wc = WorkController(WorkSettings(mode="draft"))
    with pytest.raises(WorkSettingsError, match="z_range"):
        wc.step(0.0, 0.0, draft_n=1.0, draft_t=0.0, ground_z=0.1, z_range=(0.5, -0.2))
    with pytest.raises(WorkSettingsError, match="z_range"):
        wc.step(0.0, 0.0, draft_n=1.0, draft_t=0.0, ground_z=0.1, z_range=(float("nan"), 0.2))
