"""The closed-loop runner on the simulated rig (bridge.service.track_loop), on short constructed scenarios:
the error is checked against the twin's truth (its attitude, ground and row) and the forward kinematics
of the simulated pistons, never against the controller's own view."""

from __future__ import annotations

import numpy as np
import pytest

from bridge.service.track_loop import (
    LoopSettings,
    SimLoop,
    TrackLoopError,
    _pose_tolerance,
    job_of,
    run_track_loop,
)
from bridge.sim.scenario import load_scenario, scenario_from_dict


def _scenario(name, duration_s, *, terrain=None, signals=None, speed=2.2222, suspension="rigid"):
    data = {
        "schema_version": 1,
        "name": name,
        "duration_s": duration_s,
        "tractor": {"suspension": suspension},
        "speed": {"constant_m_s": speed},
        "signals": {"row_offset_rms_m": 0.0, "row_noise_rms_m": 0.0, **(signals or {})},
    }
    if terrain:
        data["terrain"] = terrain
    return scenario_from_dict(data)


SLOPE = 0.03  # rad, inside the roll workspace (+-0.058 rad)


@pytest.fixture(scope="module")
def side_slope():
    return _scenario("side-slope", 4.5, terrain={"cross_slope_rad": SLOPE})


def test_a_constant_side_slope_is_levelled_and_hold_keeps_the_slope(model, side_slope):
    assert job_of(side_slope) == "levelling"
    track = run_track_loop(model, side_slope, LoopSettings(strategy="track", settle_s=3.0))
    hold = run_track_loop(model, side_slope, LoopSettings(strategy="hold", settle_s=3.0))
    phi = side_slope.twin.attitude(1.0).roll_rad  # the tractor's roll on the slope (right side down)
    assert phi == pytest.approx(SLOPE, abs=1e-3)  # left side higher: the tractor rolls right side down (+)
    assert track.frame == "level" and track.dof == "roll"
    # implement roll relative to gravity after settling: within ~1 count of the tilt sensor
    assert track.figures.max < 2e-3, track.figures
    # hold: the hitch stays at roll 0, so the implement's roll relative to gravity is minus the tractor's
    assert hold.figures.mean == pytest.approx(-phi, abs=1e-3)
    assert hold.figures.rms > 10 * track.figures.rms
    for r in (track, hold):
        assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0
        assert r.counts["outside_workspace"] == 0 and not r.faults


def test_row_offset_is_followed_in_x_and_track_beats_hold(model):
    # a slow row (30 m wavelength at 8 km/h = 0.074 Hz), 20 mm RMS, no camera noise
    sc = _scenario(
        "row",
        8.0,
        signals={"row_offset_rms_m": 0.02, "row_wavelength_min_m": 30.0, "row_wavelength_max_m": 30.0, "seed": 3},
    )
    assert job_of(sc) == "guidance"
    track = run_track_loop(model, sc, LoopSettings(strategy="track", settle_s=3.0))
    hold = run_track_loop(model, sc, LoopSettings(strategy="hold", settle_s=3.0))
    # truth: the row moved (hold sees it all) and the implement followed it in x
    assert np.ptp(track.row[track.evaluated]) > 0.01
    assert np.allclose(hold.error, hold.truth[:, 0] - hold.row)
    assert track.figures.rms < 0.3 * hold.figures.rms, (track.figures, hold.figures)
    assert track.figures.rms < 4e-3
    assert track.counts["references_outside_strokes"] == 0 and track.counts["outside_workspace"] == 0


def test_a_ground_bump_is_followed_in_z_in_the_ground_frame(model):
    # one undulation: 20 mm at 10 m wavelength at 4 km/h (0.11 Hz); the tractor pitches over it too
    sc = _scenario("bump", 8.0, speed=1.1111, terrain={"undulation": [{"amplitude_m": 0.02, "wavelength_m": 10.0}]})
    assert job_of(sc) == "terrain"
    track = run_track_loop(model, sc, LoopSettings(strategy="track", settle_s=3.0))
    hold = run_track_loop(model, sc, LoopSettings(strategy="hold", settle_s=3.0))
    assert track.frame == "ground" and track.dof == "z" and track.working_height_m is not None
    # the truth's height above the ground, from the twin's ground and the pistons' z
    pivot = model.profile.geometry.pivot_height
    height = pivot + track.truth[:, 1] - track.ground_height
    assert np.allclose(track.error, height - track.working_height_m)
    assert np.ptp(track.ground_height[track.evaluated]) > 0.005  # the ground under the implement moved
    assert track.figures.rms < 0.35 * hold.figures.rms, (track.figures, hold.figures)
    assert track.counts["references_outside_strokes"] == 0 and track.counts["refused"] == 0


def test_terrain_with_the_look_ahead_sensor_beats_the_sensor_under_the_implement(model):
    # the terrain scenario's two undulations (30 mm at 7 m, 20 mm at 19 m) at 8 km/h: the implement's own sensor
    # lags (the demand is at z's velocity limit); the look-ahead sensor 4.9 m ahead gives the client a preview
    und = [
        {"amplitude_m": 0.03, "wavelength_m": 7.0},
        {"amplitude_m": 0.02, "wavelength_m": 19.0, "phase_rad": 0.5},
    ]
    sc = _scenario("undulating", 12.0, terrain={"undulation": und}, signals={"ground_sensor_ahead_m": 4.9})
    assert job_of(sc) == "terrain" and sc.twin.ground_sensor.fitted
    plan = run_track_loop(model, sc, LoopSettings(strategy="track", settle_s=5.0, ground_setpoint="plan"))
    under = run_track_loop(model, sc, LoopSettings(strategy="track", settle_s=5.0))
    assert plan.frame == "tractor" and under.frame == "ground"  # the client converts: it knows the ground ahead
    pivot = model.profile.geometry.pivot_height
    height = pivot + plan.truth[:, 1] - plan.ground_height  # the truth's height above the ground under it
    assert np.allclose(plan.error, height - plan.working_height_m)
    demand_rms = float(np.std(plan.demand[plan.evaluated]))  # what holding a fixed z errs by, about
    assert demand_rms > 0.025
    # the preview plan 8.26 mm RMS; the sensor under the implement 14.70 mm before, 12.33 mm since the follower
    # stops short of where the demand turns (1e211fc and after): the preview's lead is 0.67, no longer < 0.6
    assert plan.figures.rms < 0.7 * under.figures.rms, (plan.figures, under.figures)
    assert plan.figures.rms < demand_rms / 3, (plan.figures, demand_rms)
    for r in (plan, under):
        assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0
        assert r.counts["setpoints_rejected"] == 0 and r.counts["outside_workspace"] == 0 and not r.faults


def test_ground_plan_needs_the_look_ahead_sensor_and_its_settings_are_checked(model):
    with pytest.raises(TrackLoopError, match="ground_setpoint"):
        LoopSettings(ground_setpoint="ahead")
    with pytest.raises(TrackLoopError, match=r"plan_every must be an integer in \[1, 50\]"):
        LoopSettings(plan_every=0)
    sc = _scenario("no-sensor", 7.0, terrain={"undulation": [{"amplitude_m": 0.02, "wavelength_m": 10.0}]})
    with pytest.raises(TrackLoopError, match="ground_sensor_ahead_m"):
        run_track_loop(model, sc, LoopSettings(strategy="track", settle_s=1.0, ground_setpoint="plan"))


def test_strategies_compare_on_a_rolling_tractor(model):
    # cross slope wave 0.015 rad at 0.1 Hz (22 m at 8 km/h): inside the workspace and the follower's limits
    sc = _scenario(
        "roll-wave",
        8.0,
        terrain={"cross_slope_wave": [{"amplitude_rad": 0.015, "wavelength_m": 22.2}]},
        suspension="oscillating",
    )
    s = {"settle_s": 3.0}
    track = run_track_loop(model, sc, LoopSettings(strategy="track", **s))
    gotos = run_track_loop(model, sc, LoopSettings(strategy="goto_stream", **s))
    hold = run_track_loop(model, sc, LoopSettings(strategy="hold", **s))
    assert gotos.counts["gotos"] > 100 and track.counts["gotos"] == 0
    assert track.inside[track.evaluated].all()  # the demand stays inside the workspace and the limits
    assert track.figures.rms < hold.figures.rms / 2 and gotos.figures.rms < hold.figures.rms / 2
    for r in (track, gotos, hold):
        assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0
    _ROLL_WAVE[:] = [track.figures.rms, gotos.figures.rms]


_ROLL_WAVE: list[float] = []


def test_track_levels_better_than_goto_stream(model):
    # the follower tracking roll alone moves within roll's own limits (the subset limits, about twice
    # the any-direction ones): as fast as a single-DOF goto plan, without re-planning every cycle
    assert _ROLL_WAVE, "runs after test_strategies_compare_on_a_rolling_tractor"
    track_rms, goto_rms = _ROLL_WAVE
    assert track_rms < goto_rms


def test_the_shipped_levelling_inside_scenario_is_inside_and_levelled_within_5_mrad(model):
    """The scenario where #15's levelling targets can be judged (bench ``levelling-inside``): its demand
    (the tractor's roll from the twin's truth) stays inside the roll workspace and the follower's limits,
    and track mode levels the implement to RMS ≤ 5 mrad and ≥ 5 × better than holding (first 20 s)."""
    sc = load_scenario("levelling-inside")
    ts = np.linspace(0.0, sc.duration_s, 30_001)
    roll = np.array([sc.twin.attitude(float(t)).roll_rad for t in ts])
    assert np.max(np.abs(roll)) == pytest.approx(0.05, abs=2e-3)  # 0.035 + 0.015 rad, nearly in phase
    s = {"settle_s": 3.0, "duration_s": 20.0}
    track = run_track_loop(model, sc, LoopSettings(strategy="track", **s))
    hold = run_track_loop(model, sc, LoopSettings(strategy="hold", **s))
    assert track.inside[track.evaluated].all()  # inside the workspace and the follower's limits
    assert track.figures_inside.rms <= 5e-3 and track.figures.rms <= hold.figures.rms / 5, (track.figures, hold.figures)
    for r in (track, hold):
        assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0
        assert r.counts["outside_workspace"] == 0 and not r.faults


def test_demands_beyond_the_workspace_are_clipped_never_streamed_beyond_the_strokes(model):
    sc = _scenario("steep", 7.0, terrain={"cross_slope_rad": 0.1})  # beyond the roll workspace
    r = run_track_loop(model, sc, LoopSettings(strategy="track", settle_s=5.5))
    assert r.counts["references_outside_strokes"] == 0 and r.counts["refused"] == 0
    assert r.counts["limit_events"] >= 1  # the workspace face was named
    assert np.nanmax(np.abs(r.reference[:, 2])) <= 0.058 + 1e-9
    assert not r.inside.any() and r.figures_inside.n == 0  # the demand is outside: nothing counted inside
    assert r.figures.mean == pytest.approx(0.058 - 0.1, abs=3e-3)  # held at the face


def _stop_at_the_roll_face(model, feedforward: bool) -> tuple[float, float, float, float]:
    """A demand beyond the roll face, 4 s: (face, tolerance of one count, max truth, max measured roll)."""
    with SimLoop(model, "flat") as loop:
        mc, tp = loop.mc, loop.planner
        mc.shaper.enabled = feedforward
        hi = float(tp.hi[2])
        tol = float(_pose_tolerance(model, tp, np.clip(loop.measured_pose(), tp.lo, tp.hi))[2])
        s = mc.track_start("tractor", ("roll",), 0.3).session
        truth, meas = [], []
        for k in range(200):  # at the face after ~2.5 s
            mc.track_setpoint(s, k + 1, {"roll": hi + 0.02}, {"roll": 0.0})
            loop.cycle()
            truth.append(loop.truth_pose()[2])
            meas.append(loop.measured_pose()[2])
    return hi, tol, max(truth), max(meas)


def test_a_stop_at_the_roll_face_overshoots_no_more_than_the_unit_loops_alone(model):
    """The follower stops at the face (jerk-limited); with the unit loops' feed-forward the simulated pistons
    must not run past it further than the same stop streamed without feed-forward (the ECU's own settling on
    the count). Before the feed-forward extrapolated with the jerk: 0.436 mrad past the face against 0.159."""
    hi, tol, truth_ff, meas_ff = _stop_at_the_roll_face(model, True)
    _, _, truth_plain, _ = _stop_at_the_roll_face(model, False)
    assert truth_ff > hi - 1e-3  # it got to the face
    assert truth_ff - hi <= max(truth_plain - hi, 0.0) + 5e-5, (truth_ff - hi, truth_plain - hi)
    assert meas_ff - hi <= tol


def test_bad_settings_name_the_field():
    with pytest.raises(TrackLoopError, match="strategy"):
        LoopSettings(strategy="pid")
    with pytest.raises(TrackLoopError, match="ttl_s"):
        LoopSettings(ttl_s=5.0)
    with pytest.raises(TrackLoopError, match="job"):
        LoopSettings(job="mowing")


def test_job_of_the_shipped_scenarios():
    assert [job_of(load_scenario(n)) for n in ("flat", "levelling", "levelling-inside", "guidance", "terrain")] == [
        "levelling",
        "levelling",
        "levelling",
        "guidance",
        "terrain",
    ]


def test_a_scenario_whose_csv_profiles_end_before_the_run_says_so(tmp_path):
    """A new user's speed file ending at 3 s of a 10 s run, and a 5 m terrain file under 20 m driven, were run
    with their last values holding and nothing said."""
    from bridge.service.track_loop import _coverage_notes

    (tmp_path / "sp.csv").write_text("time_s,speed_m_s\n0,2.0\n3,2.0\n")
    (tmp_path / "g.csv").write_text("distance_m,height_m\n0,0\n5,0.05\n")
    toml = tmp_path / "s.toml"
    toml.write_text(
        'schema_version = 1\nname = "short"\nduration_s = 10.0\n[speed]\ncsv = "sp.csv"\n[terrain]\ncsv = "g.csv"\n'
    )
    sc = load_scenario(str(toml))
    notes = _coverage_notes(sc.twin, sc.duration_s)
    assert notes[0] == "the speed profile ends at 3 s of the 10 s run: its last speed, 2 m/s, holds after it"
    assert notes[1].startswith("the terrain profile covers 0…5 m, the run -1.2…22.7 m")
    (tmp_path / "sp.csv").write_text("time_s,speed_m_s\n0,2.0\n10,2.0\n")
    (tmp_path / "g.csv").write_text("distance_m,height_m\n-2,0\n30,0.05\n")
    covered = load_scenario(str(toml))
    assert _coverage_notes(covered.twin, covered.duration_s) == ()


def test_a_ditch_whose_demand_outruns_a_setpoints_velocity_range_does_not_end_the_session(model, tmp_path):
    """A technician's field: a 2 m wide, 0.25 m deep ditch crossed at 6 km/h. The client's estimate of the
    demand's rate passed 1 m/s (the body pitches into the ditch), the service refused those setpoints whole
    (velocity beyond the plausible ±1 m/s), the stream went stale, the session ended, and every later setpoint
    was refused: the hitch stayed 50 mm off its working height for the rest of the run."""
    import math

    rows = ["distance_m,height_m"]
    for i in range(-40, 121):
        d = i / 4
        rows.append(f"{d:.2f},{-0.25 * math.sin(math.pi * (d - 10) / 2) if 10 <= d <= 12 else 0.0:.4f}")
    (tmp_path / "ditch.csv").write_text("\n".join(rows) + "\n")
    toml = tmp_path / "ditch.toml"
    toml.write_text(
        'schema_version = 1\nname = "ditch"\nduration_s = 11.0\n[speed]\nconstant_m_s = 1.6667\n'
        '[terrain]\ncsv = "ditch.csv"\n'
    )
    r = run_track_loop(model, load_scenario(str(toml)), LoopSettings(strategy="track", settle_s=3.0))
    assert r.job == "terrain" and r.frame == "ground"
    assert r.counts["setpoints_rejected"] == 0, r.notes
    assert r.counts["references_outside_strokes"] == 0 and r.counts["outside_workspace"] == 0
    # past the ditch the implement is back at its working height
    after = r.t > r.t[-1] - 1.0
    assert np.max(np.abs(r.error[after])) < 0.01, np.max(np.abs(r.error[after]))


def test_a_session_that_ends_during_the_run_is_said_whatever_the_notes_hold(model, side_slope, monkeypatch):
    """The ditch run's session went stale after five different velocity refusals had filled the notes (at most
    five); the refusal of every later setpoint (the session was over) was never said, only counted."""
    import bridge.service.track_loop as tl

    # five notes before the session ends, as the ditch's five velocity refusals were
    monkeypatch.setattr(tl, "_coverage_notes", lambda twin, duration: tuple(f"earlier note {k}" for k in range(5)))
    cycles = {"n": 0}

    def on_cycle(loop):
        cycles["n"] += 1
        if cycles["n"] == 150:  # 3 s into the run: an operator's stop ends the session
            loop.mc.stop()

    r = run_track_loop(model, side_slope, LoopSettings(strategy="track", settle_s=3.0), on_cycle=on_cycle)
    assert r.counts["setpoints_rejected"] > 0
    ended = [n for n in r.notes if n.startswith("the track session ended at ")]
    assert len(ended) == 1 and "stop requested" in ended[0], r.notes
