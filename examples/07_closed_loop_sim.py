"""A closed-loop move over CAN against the simulated cylinder ECU, in simulated time.

Both nodes run on a private python-can ``virtual`` channel: the planner's link streams the
Ruckig plan (through the unit loops' feed-forward) as position references, the simulated
ECU (identified hydraulics, 10-bit sensors, watchdog) moves its cylinders and sends its
measurements back. Simulated time runs much faster than real time and is deterministic.
"""

from bridge import LinkConfig, MoveSettings, SimSettings, build_move_figures, run_move
from planner import HitchModel

model = HitchModel.from_profile()
sim = SimSettings(noise_counts=0.5, seed=1, link=LinkConfig(control_rate_hz=50.0))  # 0.5-count AD noise
trace = run_move(model, {"x": 0.03, "z": 0.20}, MoveSettings(reference="trajectory", max_time_s=5.0), sim)

print(
    f"{trace.reference_kind} reference: plan {trace.plan_duration_s:.2f} s, run {trace.t[-1]:.2f} s simulated, "
    f"{len(trace.t)} samples, bus load {100 * trace.bus_load:.1f} % of 250 kbit/s"
)
for which in ("measured", "truth"):  # the pose measured over CAN, and the simulated pistons' true pose
    f = build_move_figures(trace, which)
    settle = "never" if f.settling_time_s is None else f"{f.settling_time_s:.2f} s"
    print(
        f"{which:>8}: final error {1e3 * f.final_error_position_m:.2f} mm, {1e3 * f.final_error_angle_rad:.2f} mrad; "
        f"path deviation {1e3 * f.max_path_deviation_m:.2f} mm; settling {settle}"
    )
print("faults: " + ("; ".join(trace.faults) or "none"))
