"""The field loop (bridge.service.field_loop): the work controller closing the loop through a track
session on the simulated rig, the draft over CAN. Constructed fields; figures from the twin's truth
(the field run's true depth and draft), never the controller's view."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.field_loop import FieldLoopError, FieldLoopSettings, run_field_loop
from bridge.sim.field import field_from_dict
from planner.work_control import WorkSettings

LIMITS = {"depth_min_m": 0.1, "depth_max_m": 0.3}


@pytest.fixture(scope="module")
def patches():
    """Flat ground (8 km/h), the chisel plough at 20 cm, 12 m soil patches of ±30 % (5.4 s each)."""
    return field_from_dict(
        {
            "schema_version": 1,
            "name": "patches",
            "scenario": "flat",
            "implement": {"kind": "chisel_plow_straight_point", "width": 9.0, "working_depth_m": 0.2},
            "soil": {"variation": 0.3, "patch_length_m": 12.0, "blend_m": 1.0, "seed": 4},
        }
    )


@pytest.fixture(scope="module")
def runs(model, patches):
    pos = run_field_loop(model, patches, FieldLoopSettings(duration_s=20.0, settle_s=2.0))
    sp = float(np.mean(pos.draft[pos.evaluated]))
    work = WorkSettings(mode="draft", draft_setpoint_n=sp, **LIMITS)
    drf = run_field_loop(model, patches, FieldLoopSettings(work=work, duration_s=20.0, settle_s=2.0))
    lost = run_field_loop(
        model, patches, FieldLoopSettings(work=work, duration_s=8.0, settle_s=2.0, draft_lost_at_s=5.0)
    )
    assert pos.mode == "position"
    return pos, drf, lost, sp


def test_draft_control_halves_the_draft_spread_of_position_control(runs):
    pos, drf, _, sp = runs
    fp, fd = pos.figures(), drf.figures()
    assert np.ptp(pos.resistance[pos.evaluated]) > 0.2  # the soil did change under the implement
    assert fd["draft_sd_n"] < 0.5 * fp["draft_sd_n"], (fd, fp)
    assert fd["draft_mean_n"] == pytest.approx(sp, rel=0.05)
    # the true working depth stayed inside the limits; position control kept its 20 cm
    assert 0.1 - 0.005 <= fd["depth_min_m"] and fd["depth_max_m"] <= 0.3 + 0.005
    assert fp["depth_min_m"] == pytest.approx(0.2, abs=0.005) and fp["depth_max_m"] == pytest.approx(0.2, abs=0.005)
    for r in (pos, drf):
        assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0 and not r.faults
        assert r.counts["fallbacks"] == 0 and set(r.active) == {r.mode}
        # the draft the controller read over CAN is the pins' reading of the true draft
        m = np.isfinite(r.draft_measured) & r.evaluated
        assert np.median(np.abs(r.draft_measured[m] - r.draft[m])) < 0.05 * sp


def test_a_lost_draft_signal_falls_back_to_position_with_an_event(runs):
    *_, lost, _ = runs
    assert lost.counts["fallbacks"] == 1 and len(lost.events) == 1
    assert "work_fallback: draft signal stale" in lost.events[0]
    before, after = lost.t < 4.9, lost.t > 5.5
    assert set(np.array(lost.active)[before]) == {"draft"} and set(np.array(lost.active)[after]) == {"position"}
    assert np.all(lost.z_setpoint[after] == 0.0)  # the operator's position setpoint (z_m)


def test_bad_settings_are_named(model, patches):
    with pytest.raises(FieldLoopError, match="z_m"):
        FieldLoopSettings(z_m=1.0)
    with pytest.raises(FieldLoopError, match="work"):
        FieldLoopSettings(work={"mode": "draft"})
    with pytest.raises(FieldLoopError, match="duration_s"):
        run_field_loop(model, patches, FieldLoopSettings(duration_s=3.0, settle_s=3.0))


def test_the_draft_demand_respects_the_hitch_speed(model, runs):
    """The loop gives the work controller the follower's z speed (z alone): between the depth limits the
    draft demand never moves faster than that share of it (the draft integral cannot run ahead of the
    hitch), and the flag is validated."""
    from bridge.service.work import Z_RATE_SHARE

    _, drf, _, _ = runs
    ev = drf.evaluated
    steps = np.abs(np.diff(drf.z_setpoint[ev])) / np.diff(drf.t[ev])
    inside = np.abs(np.diff(drf.ground_z[ev])) < 1e-3  # flat ground: the limits do not move
    assert steps[inside].max() <= Z_RATE_SHARE * 0.09 + 1e-6  # the follower's z-only speed is 88 mm/s
    with pytest.raises(FieldLoopError, match="rate_limit"):
        FieldLoopSettings(rate_limit="yes")


def test_the_ground_preview_sees_the_ground_under_the_tool_one_hitch_lag_ahead(model, runs):
    """The preview in the loop (front sensor, pitch, implement sensor, odometer over the bus): on flat
    ground it is flat (within 3 mm of the reference's median, and steadier than the measured reference);
    over the ``terrain`` undulation (chisel field, 8 s of draft control) the ground it hands the controller
    at t is the ground reference measured at t + lead within a third of what the current ground is off by
    (the lag the old regulator had to live with); its cost is recorded; the settings are validated."""
    from bridge.sim.field import load_field

    _, drf, _, _ = runs
    ok = np.isfinite(drf.ground_ahead_z) & drf.evaluated
    assert ok.sum() > 0.8 * drf.evaluated.sum()
    flat = float(np.median(drf.ground_z[ok]))  # flat ground: the true reference is one constant
    assert np.max(np.abs(drf.ground_ahead_z[ok] - flat)) < 0.003
    assert np.std(drf.ground_ahead_z[ok]) < np.std(drf.ground_z[ok])  # steadier than the measured reference
    assert drf.preview_cpu_s.size == drf.cycle_s.size and np.all(drf.preview_cpu_s >= 0.0)
    work = WorkSettings(mode="draft", draft_setpoint_n=20_500.0, **LIMITS)
    st = FieldLoopSettings(work=work, duration_s=8.0, settle_s=2.0)
    r = run_field_loop(model, load_field("chisel"), st)
    k = int(round(st.preview_lead_s / 0.02))
    ok = np.isfinite(r.ground_ahead_z[:-k]) & np.isfinite(r.ground_z[k:])
    ahead = r.ground_ahead_z[:-k][ok] - r.ground_z[k:][ok]
    now = r.ground_z[:-k][ok] - r.ground_z[k:][ok]
    assert ok.sum() > 200
    assert np.sqrt(np.mean(ahead**2)) < np.sqrt(np.mean(now**2)) / 3.0, (np.std(ahead), np.std(now))
    with pytest.raises(FieldLoopError, match="preview_lead_s"):
        FieldLoopSettings(preview_lead_s=2.0)
    with pytest.raises(FieldLoopError, match="preview"):
        FieldLoopSettings(preview="front")


def test_a_draft_demand_beyond_the_workspace_floor_stops_at_the_floor_in_the_field_loop(model, patches):
    """A review: the live service clips the draft regulator to the z the session can reach, the field loop (the
    benches' closed loop) did not: a draft setpoint far above what the soil gives wound its z setpoint below
    the workspace floor."""
    from planner.trajectory import TrajectoryPlanner

    floor = float(TrajectoryPlanner(model).lo[1])
    work = WorkSettings(mode="draft", draft_setpoint_n=300_000.0, depth_min_m=0.0, depth_max_m=0.6)
    r = run_field_loop(model, patches, FieldLoopSettings(work=work, duration_s=6.0, settle_s=1.0))
    assert np.nanmin(r.z_setpoint) >= floor - 1e-9, (float(np.nanmin(r.z_setpoint)), floor)
    assert np.nanmin(r.z_setpoint) == pytest.approx(floor, abs=1e-3)  # it went down to it
