"""Jog: pose-rate commands with a time-to-live (dead-man), capped at the jog speed, braking before the workspace.

:class:`JogController` integrates rates (vx, vz [m/s], vroll, vpitch [rad/s]) one control cycle at a time,
jerk-limited. A command lives for its time-to-live: a joystick (or ``hitch jog``) sends it again while held;
without a fresh one the hitch brakes to rest. A rate beyond the jog speed limit is capped and flagged; near a
workspace face the rate towards it is capped so the braking fits before the face. The guard checks a jog one
second ahead at the speed it can run: with a heavy implement on a side slope, a jog that would cross a
stability threshold is refused (rates zero) naming the measure, while the jog the other way runs.
"""

from planner import Guard, HitchModel, JogController, MotionState, TrajectoryPlanner, load_tractor_profile

model = HitchModel.from_profile()
planner = TrajectoryPlanner(model)  # the control rate (50 Hz) and the workspace the jog stays in
jog = JogController(planner, MotionState.at_rest(model.neutral_pose.controlled()))
print(f"jog speed limit for z: {jog.limits.velocity[1]:.4f} m/s; control cycle {jog.dt:.3f} s")

# Held for 1 s: 0.1 m/s asked, sent again every cycle with a 0.2 s time-to-live.
for _ in range(50):
    jog.command({"vz": 0.1}, ttl_s=0.2)
    out = jog.step()
z_released, t_released = out.state.position[1], out.t
print(f"held 1 s: z = {z_released:+.4f} m at {out.state.velocity[1]:.4f} m/s, limited: {out.limited}")

# Released: nothing is sent; the command runs out after its 0.2 s time-to-live and the hitch brakes, jerk-limited.
while out.moving:
    out = jog.step()
print(
    f"released: at rest {out.t - t_released:.2f} s later, {1e3 * (out.state.position[1] - z_released):.1f} mm "
    f"further (dead-man stop: {out.expired})"
)

# Held until it stops by itself: it brakes before the workspace's upper face and stops on it.
held = 0
while True:
    jog.command({"vz": 0.1}, ttl_s=0.2)
    out = jog.step()
    held += 1
    if held > 10 and not out.moving:
        break
print(
    f"held {held * jog.dt:.2f} s: stopped at z = {out.state.position[1]:.4f} m "
    f"(workspace top {planner.hi[1]:.4f} m), limited: {out.limited}"
)

# The guard on a jog from z = 0.2 m, one second ahead: the 1500 kg power harrow on a 0.3 rad side slope (left
# side up). Lowering it would take load off the front axle below its threshold; raising it runs.
implements = load_tractor_profile(model.profile.stability.tractor_profile)
guard = Guard(planner, implement=implements.implement("cat2-power-harrow-1500"))
guard.set_slope(0.3, 0.0)  # tractor roll, pitch [rad]
at = MotionState.at_rest([0.0, 0.2, 0.0, 0.0])  # x, z [m], roll, pitch [rad]
for vz in (-0.04, 0.04):  # m/s
    rates, decision = guard.check_jog(at, [0.0, vz, 0.0, 0.0])
    why = "; ".join(r.sentence() for r in decision.reasons)
    print(
        f"harrow, slope 0.30 rad, jog vz = {vz:+.2f} m/s: {decision.action}, allowed vz = {rates[1]:+.3f} m/s"
        + (f" ({why})" if why else "")
    )
