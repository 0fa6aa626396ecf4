"""Experiment for issue 6 (not product behaviour yet): equal-lag synchronisation of the unit loops.

Each cylinder's reference is delayed to the slowest loop's ramp lag,
r_i(t) = q_i(t − (τ_max − τ_i)) with τ_i = bridge.sim_rig.unit_loop_lag_s, so every cylinder
lags the plan by the same time and the implement follows the planned path later. Compared
side by side with step references and plain trajectories on the simulated ECU over CAN
(truth poses).

Run: .venv/bin/python bench/lag_sync_experiment.py
"""

from __future__ import annotations

import numpy as np

from bridge.sim_run import (_POSE, MoveSettings, SimRig, SimSettings, _drive, build_move_figures, run_move,
                            unit_loop_lag_s)
from planner.kinematics import HitchModel
from planner.trajectory import MotionState, TrajectoryPlanner


def equal_lag_move(model: HitchModel, goal: dict):
    move, sim = MoveSettings(), SimSettings()
    tp = TrajectoryPlanner(model, rate=sim.link.control_rate_hz)
    with SimRig(model, sim, initial_actuators=tp.inverse.solve(model.neutral_pose.controlled())[0]) as rig:
        rig.start()
        rig.run_until(move.warmup_s)
        p0 = rig.link.latest_state().pose.controlled()
        p1 = tp.goal_vector(p0, goal)
        plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(_POSE, p1)))
        sp = plan.setpoints
        lag = unit_loop_lag_s(rig.ecu)
        shift = lag.max() - lag
        dt = 1.0 / tp.rate
        ts = np.arange(0.0, sp.t[-1] + shift.max() + dt / 2, dt)
        refs = np.column_stack([np.interp(np.clip(ts - shift[i], 0, sp.t[-1]), sp.t, sp.actuators[:, i])
                                for i in range(5)])
        return _drive(rig, model, ts, refs, lambda t: plan.state_at(t).position, p0, p1, plan.duration, move)


def main() -> None:
    model = HitchModel.from_profile()
    goals = [{"z": 0.3117}, {"x": 0.05, "z": 0.28}, {"roll": 0.05}, {"x": 0.04, "z": 0.25, "roll": 0.03, "pitch": -0.04}]
    print("max path deviation (truth): step | trajectory | equal-lag trajectory")
    for goal in goals:
        cells = []
        for kind in ("step", "trajectory", "equal-lag"):
            tr = equal_lag_move(model, goal) if kind == "equal-lag" else run_move(model, goal, MoveSettings(reference=kind))
            f = build_move_figures(tr, "truth")
            cells.append(f"{f.max_path_deviation_m * 1e3:5.1f} mm {f.max_path_deviation_rad * 1e3:5.1f} mrad")
        print(f"{str(goal):55s} " + " | ".join(cells))


if __name__ == "__main__":
    main()
