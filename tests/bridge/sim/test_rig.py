"""Closed-loop runs through the real CAN path in simulated time: goal reached within the
quantisation bound, 5 % frame loss without unsafe motion, determinism, bus load, step versus
trajectory, the figures, and the ``hitch sim`` / ``hitch ecu-sim`` commands."""

import json

import numpy as np
import pytest

from bridge.cli.main import main
from bridge.isobus.j1939 import bus_load
from bridge.link.unit_loop import build_unit_loops, unit_loop_lag_s
from bridge.sim.move import (
    MoveSettings,
    MoveTrace,
    SimError,
    SimRig,
    SimSettings,
    build_move_figures,
    run_move,
)
from planner.model.exact_inverse import ExactInverse
from planner.model.sensors import SensorScaling
from planner.trajectory import MotionState, TrajectoryPlanner

Z200 = {"z": -0.0863}  # from the neutral pose (z = 0.1137 m): a 200 mm move down
ROLL = ({"roll": 0.05}, {"roll": -0.05})


@pytest.fixture(scope="module")
def runs(model):
    out = {kind: run_move(model, Z200, MoveSettings(reference=kind)) for kind in ("step", "trajectory")}
    out["roll_step"] = run_move(model, ROLL[0], MoveSettings(reference="step", start=ROLL[1]))
    out["roll_trajectory"] = run_move(model, ROLL[0], MoveSettings(reference="trajectory", start=ROLL[1]))
    return out


def quantisation_bound(model, goal, counts):
    """|pose error| bound from per-actuator errors of ``counts`` AD counts, through |J| at the goal."""
    q = ExactInverse(model).solve(goal)[0]
    jac = model.features(q)[1][[0, 2, 3, 4]]
    b = np.abs(jac) @ (SensorScaling(model.profile).resolution * np.asarray(counts, float))
    return float(np.hypot(b[0], b[1])), float(max(b[2], b[3]))


@pytest.mark.parametrize("key", ["step", "trajectory", "roll_step", "roll_trajectory"])
def test_goal_reached_within_the_quantisation_bound(runs, model, key):
    tr = runs[key]
    res = SensorScaling(model.profile).resolution
    ref_counts = tr.reference[-1] / res
    meas_counts = tr.measured_actuators[-1] / res
    # each cylinder stops within the ECU's cut-off (1 count) of its reference; the lift reading
    # reaches the link through the 0.4 % hitch position, +0.46 count
    assert np.all(np.abs(meas_counts[1:] - ref_counts[1:]) <= 1.0 + 1e-6)
    assert abs(meas_counts[0] - ref_counts[0]) <= 1.0 + 0.46 + 1e-6
    # reference rounding 0.5 + cut-off 1 + AD rounding 0.5 = 2 counts of truth; 1.5 (+0.46) measured
    pos_t, ang_t = quantisation_bound(model, tr.goal, [2, 2, 2, 2, 2])
    pos_m, ang_m = quantisation_bound(model, tr.goal, [1.96, 1.5, 1.5, 1.5, 1.5])
    truth, measured = build_move_figures(tr, "truth"), build_move_figures(tr, "measured")
    assert truth.final_error_position_m <= pos_t and truth.final_error_angle_rad <= ang_t
    assert measured.final_error_position_m <= pos_m and measured.final_error_angle_rad <= ang_m
    assert pos_t < 0.01 and ang_t < 0.008  # the bound is a few counts, not vacuous
    assert not tr.faults and tr.link_counters["malformed"] == 0
    assert tr.node_counters["references"] == tr.link_counters["references_tx"]


def test_trajectory_follows_the_straight_line_better_than_a_step(runs):
    z_step, z_traj = (build_move_figures(runs[k], "truth") for k in ("step", "trajectory"))
    r_step, r_traj = (build_move_figures(runs[k], "truth") for k in ("roll_step", "roll_trajectory"))
    assert z_traj.max_path_deviation_rad < z_step.max_path_deviation_rad / 2  # pitch during the z move
    assert r_traj.max_path_deviation_m < r_step.max_path_deviation_m / 4  # the tool point during roll
    assert z_traj.overshoot <= z_step.overshoot


def test_figures_against_hand_built_trace(runs):
    tr = runs["trajectory"]
    f = build_move_figures(tr, "measured")
    final = tr.measured[tr.t >= tr.t[-1] - 0.5 + 1e-9].mean(axis=0) - tr.goal
    assert f.final_error_position_m == pytest.approx(np.hypot(final[0], final[1]))
    # a pure z move: the deviation from the segment is what x, roll, pitch do, plus z beyond its ends
    d = tr.measured - tr.start
    lo, hi = sorted((0.0, tr.goal[1] - tr.start[1]))
    dz_out = np.maximum(0.0, np.maximum(lo - d[:, 1], d[:, 1] - hi))
    assert f.max_path_deviation_m == pytest.approx(np.max(np.hypot(d[:, 0], dz_out)), abs=1e-9)
    assert f.max_path_deviation_rad == pytest.approx(np.max(np.hypot(d[:, 2], d[:, 3])), abs=1e-9)
    assert f.settling_time_s is not None and f.settling_time_s <= tr.t[-1]
    with pytest.raises(SimError, match="band_position_m"):
        build_move_figures(tr, band_position_m=0)


def synthetic_trace(poses, t=None):
    poses = np.asarray(poses, float)
    n = len(poses)
    t = np.arange(1, n + 1) * 0.01 if t is None else np.asarray(t, float)
    nan5 = np.full((n, 5), np.nan)
    return MoveTrace(
        "step",
        np.zeros(4),
        np.zeros(4),
        np.array([0.0, 0.2, 0.0, 0.0]),
        0.0,
        t,
        poses,
        poses,
        poses,
        nan5,
        nan5,
        nan5,
        {},
        {},
        (),
        0.0,
    )


def test_figures_on_a_synthetic_trace():
    """Start 0, goal z = 0.2 m: hand-computed deviation, overshoot, settling and final error."""
    tr = synthetic_trace(
        [
            [0.0, 0.0, 0.0, 0.0],
            [0.003, 0.1, 0.0, 0.004],  # 3 mm aside, 4 mrad of pitch, mid-way
            [0.0, 0.21, 0.0, 0.0],  # 10 mm beyond the goal
            [0.0, -0.004, 0.0, 0.0],  # 4 mm behind the start
            [0.0, 0.199, 0.001, 0.0],
            [0.0, 0.201, 0.0, -0.001],
        ]
    )
    f = build_move_figures(tr, band_position_m=0.005, band_angle_rad=0.005, final_window_s=0.015)
    assert f.max_path_deviation_m == pytest.approx(0.010)
    assert f.max_path_deviation_rad == pytest.approx(0.004)
    assert f.overshoot == pytest.approx(0.05)  # 10 mm of 200 mm
    assert f.settling_time_s == pytest.approx(0.05)  # inside the band from the 5th sample on
    assert f.final_error == pytest.approx({"x": 0.0, "z": 0.0, "roll": 0.0005, "pitch": -0.0005})
    assert f.final_error_position_m == pytest.approx(0.0) and f.final_error_angle_rad == pytest.approx(0.0005)
    never = build_move_figures(synthetic_trace([[0.0, 0.0, 0.0, 0.0], [0.0, 0.19, 0.0, 0.0]]))
    assert never.settling_time_s is None and never.overshoot == 0.0


def test_bus_load_matches_the_frame_budget(runs):
    # 50 Hz references + 100 Hz measurements + 100 Hz hitch status + 2 x 10 Hz heartbeats + the planner's 10 Hz
    # MeasuredPose (0xFF25), all DLC 8
    expected = bus_load({8: 50 + 100 + 100 + 10 + 10 + 10})
    assert runs["trajectory"].bus_load == pytest.approx(expected, rel=0.02)
    assert 0.16 < expected < 0.18


def test_runs_are_deterministic(model, runs):
    again = run_move(model, Z200, MoveSettings(reference="trajectory"))
    ref = runs["trajectory"]
    for name in ("t", "measured", "truth", "reference", "valves"):
        assert np.array_equal(getattr(again, name), getattr(ref, name))


def test_five_percent_frame_loss_is_tolerated_without_unsafe_motion(model):
    tp = TrajectoryPlanner(model)
    sim = SimSettings(frame_loss=0.05, seed=11)
    with SimRig(model, sim) as rig:
        rig.start()
        rig.run_until(0.5)
        p0 = rig.link.latest_state().pose.controlled()
        plan = tp.plan_move(MotionState.at_rest(p0), Z200)
        sp = tp.sample(plan)
        streamed = [rig.link.check_reference(q).as_tuple() for q in sp.actuators]
        latched, pistons, k = [], [], 0
        t0 = rig.next_tick_s

        def command(t):
            nonlocal k
            while k < len(sp.t) and t >= t0 + sp.t[k] - 1e-9:
                rig.link.send_reference(sp.actuators[k], t)
                k += 1

        while rig.now_s < t0 + plan.duration + 1.5:
            rig.run_until(rig.next_tick_s, every_tick=command)
            ref = rig.ecu.reference_counts()
            if ref is not None and (not latched or tuple(ref) != latched[-1]):
                latched.append(tuple(int(c) for c in ref))
            pistons.append(rig.ecu.piston_counts().copy())
        dropped = rig.node.bus.dropped + rig.link.bus.dropped
        counters, faults, trips = rig.link.counters, rig.link.faults, rig.ecu.watchdog.trip_count
    assert dropped > 0.03 * (counters.frames_rx + rig.node.counters.frames_rx)  # the loss really happened
    assert counters.dropped_measurements > 0
    assert not faults.any and trips == 0  # no stop, no watchdog trip
    # every reference the ECU acted on was one of the checked, streamed ones, in order, no jumps
    idx = [streamed.index(r) for r in latched]
    assert idx == sorted(idx)
    step = np.max(np.abs(np.diff(np.array(streamed), axis=0)), axis=0)
    jumps = np.max(np.abs(np.diff(np.array(latched), axis=0)), axis=0)
    assert np.all(jumps <= 3 * step + 1)
    # the pistons move smoothly: never faster than the valve's full flow (thesis table 3-4)
    speed = np.max(np.abs(np.diff(np.array(pistons), axis=0)), axis=0) / sim.tick_s
    kv = np.array([max(p.kv_pos, p.kv_neg) for p in rig.ecu.params])
    assert np.all(speed <= kv * (254 + 2 - 3) * 1.001)
    final = rig.ecu.measurement_counts()
    assert np.all(np.abs(final - np.array(streamed[-1])) <= 1)


def test_unit_loop_lag_hand_values_and_against_the_simulated_ecu(model):
    lag = unit_loop_lag_s(build_unit_loops(model.profile))
    with SimRig(model) as rig:
        # L / (m a) + T_F with L = 0.1 s, a = 0.581, T_F = 0.01 s, m = 1, 0.5, 0.5, 0.2, 0.2 (table 3-3)
        assert lag == pytest.approx([0.18212, 0.35423, 0.35423, 0.87059, 0.87059], abs=1e-5)
        rig.start()
        rig.run_until(0.5)
        res = SensorScaling(model.profile).resolution
        v_counts = np.array([0.0, 20.0, 0.0, 10.0, 0.0])  # tilt and left limiter ramps, counts/s
        t0 = rig.next_tick_s
        lags = []

        def ramp(t):
            if round(t * 1000) % 20 == 0:
                rig.link.send_reference(model.neutral + v_counts * res * (t - t0), t)

        while rig.now_s < t0 + 6.0:
            rig.run_until(rig.next_tick_s, every_tick=ramp)
            if rig.now_s > t0 + 5.0:  # steady ramp (> 5 time constants): reference − piston, in time
                x = rig.ecu.piston_counts()
                r = np.array(
                    [p.si_to_counts(q) for p, q in zip(rig.ecu.params, model.neutral, strict=True)]
                ) + v_counts * (rig.now_s - t0)
                lags.append((r[[1, 3]] - x[[1, 3]]) / v_counts[[1, 3]])
    measured = np.mean(lags, axis=0)
    # the minimum flow Kv·dy_min (after the dead zone) does part of the work: the P part's lag
    # shrinks by (1 − Kv·dy_min / v); + 10 ms: the 50 Hz stream's zero-order hold
    p = [rig.ecu.params[i] for i in (1, 3)]
    expected = [
        q.transport_delay_s / (q.valve_multiplier * 0.581) * (1 - q.kv_pos * q.min_flow / v) + q.time_constant_s + 0.01
        for q, v in zip(p, v_counts[[1, 3]], strict=True)
    ]
    # the valve command is an integer: the error can rest anywhere within ±0.5 valve unit / (m k),
    # k = a / (Kv L) (thesis 2.57), i.e. ±0.5 / (m k v) s of lag
    slack = [
        0.005 + 0.5 / (q.valve_multiplier * 0.581 / (q.kv_pos * q.transport_delay_s) * v)
        for q, v in zip(p, v_counts[[1, 3]], strict=True)
    ]
    assert abs(measured[0] - expected[0]) <= slack[0] and abs(measured[1] - expected[1]) <= slack[1]
    assert slack[0] < 0.01 and slack[1] < 0.06


def test_feedforward_meets_the_closed_loop_targets_on_a_200_mm_diagonal_move(model):
    """Closed-loop targets on the 200 mm move x 100 mm + z 173 mm: path deviation ≤ 10 mm with
    trajectories and at least 5× smaller than with a step reference; steady state ≤ 2 mm, 2 mrad."""
    goal, start = {"x": 0.05, "z": 0.1732}, {"x": -0.05, "z": 0.0}
    runs = {
        kind: run_move(model, goal, MoveSettings(reference=ref, start=start, feedforward=ff))
        for kind, ref, ff in (("step", "step", False), ("plain", "trajectory", False), ("ff", "trajectory", True))
    }
    assert runs["ff"].reference_kind == "trajectory+feedforward"
    for which in ("truth", "measured"):
        f = {k: build_move_figures(tr, which) for k, tr in runs.items()}
        assert f["ff"].max_path_deviation_m <= 0.010, which
        assert f["step"].max_path_deviation_m >= 5 * f["ff"].max_path_deviation_m, which
        assert f["step"].max_path_deviation_rad >= 5 * f["ff"].max_path_deviation_rad, which
        # without the feed-forward the cylinders' different lags bend the path (the thesis's look)
        assert f["plain"].max_path_deviation_m > 2 * f["ff"].max_path_deviation_m, which
        assert f["ff"].overshoot <= 0.01
    m = build_move_figures(runs["ff"], "measured")
    assert m.final_error_position_m <= 0.002 and m.final_error_angle_rad <= 0.002
    assert not runs["ff"].faults


def test_bad_moves_are_refused(model):
    with pytest.raises(ValueError, match="workspace"):
        run_move(model, {"z": 0.5})
    with pytest.raises(SimError, match="reference"):
        MoveSettings(reference="ramp")
    with pytest.raises(SimError, match="tick_s"):
        SimSettings(tick_s=0.0005)
    with pytest.raises(SimError, match="frame_loss"):
        SimSettings(frame_loss=-0.1)


@pytest.mark.parametrize(
    "setting, words",
    [
        ({"noise_counts": -1}, r"noise_counts must be a number in \[0, 100\] counts, got -1"),
        ({"noise_counts": float("nan")}, r"noise_counts must be a number in \[0, 100\] counts, got nan"),
        ({"gain_error": -1.0}, r"gain_error must be a number in \[-0\.9, 10\] \(relative\), got -1\.0"),
        ({"gain_error": "10%"}, r"gain_error must be a number"),
        ({"watchdog_timeout_s": 0}, r"watchdog_timeout_s must be a number in \[0\.001, 10\] s, got 0"),
    ],
)
def test_sim_settings_are_checked_when_made(setting, words):
    """``SimSettings(noise_counts=-1)`` was taken (the ECU refused it only when a rig was built from it)."""
    with pytest.raises(SimError, match=words):
        SimSettings(**setting)
    assert SimSettings(noise_counts=2, gain_error=0.1, watchdog_timeout_s=0.2).noise_counts == 2


def test_cli_sim_move_json(capsys):
    assert main(["sim", "move", "--to", "z=-0.0863", "--reference", "step", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out["final_error"]) >= {"position_m", "angle_rad"}
    for key in ("max_path_deviation_m", "overshoot", "settling_time_s", "truth", "bus_load"):
        assert key in out
    assert out["final_error"]["position_m"] < 0.01 and out["reference"] == "step"


def test_cli_sim_move_plot_and_errors(tmp_path, capsys):
    png = tmp_path / "move.png"
    assert main(["sim", "move", "--to", "roll=0.03", "--plot", str(png)]) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    capsys.readouterr()
    assert main(["sim", "move", "--to", "q=1"]) == 2
    assert main(["sim", "move", "--to", "z=0.1", "--reference", "ramp"]) == 2
    assert main(["sim", "move", "--to", "z=0.9"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all(line.startswith("hitch: error:") for line in err)
    assert "workspace" in err[-1]


def test_cli_ecu_sim_virtual_runs_and_closes(capsys):
    assert main(["ecu-sim", "--interface", "virtual", "--channel", "cli-test", "--duration", "0.4", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["claim"] == "claimed" and out["counters"]["frames_tx"] > 10
    assert main(["ecu-sim", "--interface", "virtual", "--duration", "-1"]) == 2
