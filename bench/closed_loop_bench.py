"""Closed-loop benchmark: the same moves with thesis-style step references, with
the plan's actuator positions streamed as references ("trajectory") and with the unit loops'
feed-forward reference (bridge.link.unit_loop, the product default: "trajectory+feedforward"),
side by side, through the real CAN path (codec, virtual bus,
simulated cylinder ECU node, planner link) in simulated time; bus load at the default rate; the
watchdog's stop latency; how fast the simulation runs.

Figures come from the pose the link measures over CAN (what a real planner sees) and from the
simulation truth (forward kinematics of the simulated pistons). Path deviation is the distance
from the straight segment start → goal in (x, z, roll, pitch); see bridge.sim.move.MoveFigures.

Run: .venv/bin/python bench/closed_loop_bench.py [--noise-counts 0.5] [--frame-loss 0.05] [--json out.json]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).parent))
from _common import machine_note, write_json  # noqa: E402

from bridge.isobus.j1939 import BITRATE_BPS, bus_load  # noqa: E402
from bridge.sim.move import MoveSettings, SimRig, SimSettings, build_move_figures, run_move  # noqa: E402
from planner.model.exact_inverse import ExactInverse  # noqa: E402
from planner.model.kinematics import HitchModel  # noqa: E402

MOVES = (  # name, start, goal (SI); lengths in the comments
    ("z 200 mm", None, {"z": -0.0863}),
    ("x 100 + z 173 mm", {"x": -0.05, "z": 0.0}, {"x": 0.05, "z": 0.1732}),
    ("x 100 mm", {"x": -0.05}, {"x": 0.05}),
    ("roll 100 mrad", {"roll": -0.05}, {"roll": 0.05}),
    ("pitch 130 mrad", {"pitch": -0.08}, {"pitch": 0.05}),
    (
        "all four DOF",
        {"x": -0.03, "z": 0.0, "roll": -0.03, "pitch": -0.05},
        {"x": 0.03, "z": 0.2, "roll": 0.03, "pitch": 0.03},
    ),
)


VARIANTS = ("step", "trajectory", "trajectory+feedforward")


def _fmt(ratio) -> str:
    return "-" if ratio is None else f"{ratio:.1f}x"


def _row(f) -> dict:
    return {
        "final_error_position_m": f.final_error_position_m,
        "final_error_angle_rad": f.final_error_angle_rad,
        "final_error": f.final_error,
        "max_path_deviation_m": f.max_path_deviation_m,
        "max_path_deviation_rad": f.max_path_deviation_rad,
        "overshoot": f.overshoot,
        "settling_time_s": f.settling_time_s,
    }


def watchdog_latency(model: HitchModel) -> float:
    """Time from the last reference the ECU received to all valves at zero, s."""
    inv = ExactInverse(model)
    with SimRig(model, initial_actuators=inv(0.0, -0.2, 0.0, 0.0)) as rig:
        rig.start()
        rig.run_until(0.5)
        rig.link.send_reference(inv(0.0, 0.3, 0.0, 0.0), rig.next_tick_s)
        rig.run_until(1.5)
        rig.link.stop_motion()
        last = rig.ecu.watchdog.last_feed_s
        while rig.ecu.valve_commands().any():
            rig.tick()
        return rig.now_s - last


def random_moves(model: HitchModel, sim: SimSettings, n: int, seed: int) -> dict:
    """Final errors and path deviations of ``n`` moves between random poses in 80 % of the
    restricted workspace, with the product's reference (trajectory + feed-forward)."""
    rng = np.random.default_rng(seed)
    box = model.workspace
    out: dict = {w: {"position_m": [], "angle_rad": [], "path_deviation_m": []} for w in ("measured", "truth")}
    for _ in range(n):
        start, goal = ({k: float(0.8 * rng.uniform(*box[k])) for k in ("x", "z", "roll", "pitch")} for _ in range(2))
        tr = run_move(model, goal, MoveSettings(start=start), sim)
        for w in out:
            f = build_move_figures(tr, w)
            out[w]["position_m"].append(f.final_error_position_m)
            out[w]["angle_rad"].append(f.final_error_angle_rad)
            out[w]["path_deviation_m"].append(f.max_path_deviation_m)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--noise-counts", type=float, default=0.0)
    ap.add_argument("--gain-error", type=float, default=0.0)
    ap.add_argument("--frame-loss", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--random", type=int, default=30, help="random moves in the workspace for the steady-state figures")
    ap.add_argument("--json", default=None)
    args = ap.parse_args()
    model = HitchModel.from_profile()
    sim = SimSettings(
        noise_counts=args.noise_counts, gain_error=args.gain_error, frame_loss=args.frame_loss, seed=args.seed
    )
    c = Console()
    results, sim_s, wall_s = [], 0.0, 0.0
    for name, start, goal in MOVES:
        for kind in VARIANTS:
            t0 = time.perf_counter()
            settings = MoveSettings(
                reference=kind.split("+")[0], feedforward=kind.endswith("+feedforward"), start=start
            )
            tr = run_move(model, goal, settings, sim)
            wall_s += time.perf_counter() - t0
            sim_s += float(tr.t[-1]) + 0.5
            m, t = build_move_figures(tr, "measured"), build_move_figures(tr, "truth")
            length = np.asarray(tr.goal) - np.asarray(tr.start)
            results.append(
                {
                    "move": name,
                    "reference": kind,
                    "plan_duration_s": tr.plan_duration_s,
                    "run_s": float(tr.t[-1]),
                    "position_move_m": float(np.hypot(length[0], length[1])),
                    "angle_move_rad": float(np.hypot(length[2], length[3])),
                    "measured": _row(m),
                    "truth": _row(t),
                    "bus_load": tr.bus_load,
                    "faults": list(tr.faults),
                    "dropped_measurements": tr.link_counters["dropped_measurements"],
                }
            )

    table = Table(title="closed loop through CAN: step vs trajectory (measured over CAN | truth)")
    for col in (
        "move",
        "ref",
        "final mm",
        "final mrad",
        "path dev mm",
        "path dev mrad",
        "overshoot %",
        "settle s",
        "plan s",
    ):
        table.add_column(col, justify="right")

    def pair(key, r, scale=1e3, fmt="{:.2f}"):
        return f"{fmt.format(r['measured'][key] * scale)} | {fmt.format(r['truth'][key] * scale)}"

    for r in results:
        st = r["measured"]["settling_time_s"]
        table.add_row(
            r["move"],
            r["reference"],
            pair("final_error_position_m", r),
            pair("final_error_angle_rad", r),
            pair("max_path_deviation_m", r),
            pair("max_path_deviation_rad", r),
            pair("overshoot", r, 100.0),
            "never" if st is None else f"{st:.2f}",
            f"{r['plan_duration_s']:.2f}",
        )
    c.print(f"machine: {machine_note()}")
    c.print(table)
    ratios = {}
    c.print("path deviation ratio step / streamed (truth), position and angle:")
    for name, _, _ in MOVES:
        get = {k: next(r for r in results if r["move"] == name and r["reference"] == k)["truth"] for k in VARIANTS}
        ratios[name] = {
            v: {
                k: get["step"][k] / get[v][k] if get[v][k] > 1e-6 else None
                for k in ("max_path_deviation_m", "max_path_deviation_rad")
            }
            for v in VARIANTS[1:]
        }
        c.print(
            f"{name:>18}: "
            + "   ".join(
                f"{v}: {_fmt(ratios[name][v]['max_path_deviation_m'])}, "
                f"{_fmt(ratios[name][v]['max_path_deviation_rad'])}"
                for v in VARIANTS[1:]
            )
        )
    steady = random_moves(model, sim, args.random, args.seed)
    for which in ("measured", "truth"):
        e = steady[which]
        c.print(
            f"steady state over {args.random} random moves (trajectory+feedforward), {which}: position "
            f"max {1e3 * max(e['position_m']):.2f} mm, p50 {1e3 * float(np.median(e['position_m'])):.2f} mm; angle "
            f"max {1e3 * max(e['angle_rad']):.2f} mrad, p50 {1e3 * float(np.median(e['angle_rad'])):.2f} mrad; "
            f"path deviation max {1e3 * max(e['path_deviation_m']):.2f} mm"
        )
    budget = {rate: {8: rate + 100 + 100 + 10 + 10} for rate in (50, 100, 200)}
    load = {
        rate: {"worst_case_stuffing": bus_load(b), "no_stuffing": bus_load(b, worst_case_stuffing=False)}
        for rate, b in budget.items()
    }
    measured_load = float(np.mean([r["bus_load"] for r in results]))
    latency = watchdog_latency(model)
    c.print(
        f"bus load at 50 Hz references (+ 0xFF22 100 Hz, hitch status 100 Hz, 2 heartbeats 10 Hz; DLC 8): "
        f"{100 * load[50]['worst_case_stuffing']:.2f} % of {BITRATE_BPS // 1000} kbit/s worst-case stuffing, "
        f"{100 * load[50]['no_stuffing']:.2f} % without; measured on the bus {100 * measured_load:.2f} %; "
        f"at 100 Hz {100 * load[100]['worst_case_stuffing']:.2f} %, "
        f"200 Hz {100 * load[200]['worst_case_stuffing']:.2f} %"
    )
    c.print(f"watchdog: valves zero {1e3 * latency:.1f} ms after the last reference")
    c.print(f"simulation speed: {sim_s:.1f} s simulated in {wall_s:.2f} s wall ({sim_s / wall_s:.0f}x real time)")
    write_json(
        args.json,
        {
            "machine": machine_note(),
            "settings": vars(args),
            "moves": results,
            "ratios": ratios,
            "random_moves": steady,
            "bus_load": {str(k): v for k, v in load.items()},
            "bus_load_measured": measured_load,
            "watchdog_latency_s": latency,
            "sim_speed_x_real_time": sim_s / wall_s,
        },
    )


if __name__ == "__main__":
    main()
