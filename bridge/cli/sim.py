"""CLI commands ``hitch sim move``, ``hitch sim fault``, ``hitch ecu-sim`` and ``hitch can-hub``.

``hitch sim move`` runs :func:`bridge.sim.move.run_move` in simulated time (see
:mod:`bridge.sim.move` for how time is handled) and reports the figures of the move.
``hitch ecu-sim`` runs the simulated cylinder ECU as its own process on a real
python-can interface, in real time, with :class:`RealtimeRunner`, until Ctrl-C or
``--duration`` (either way it prints its summary); the bus is closed on every exit path. ``--interface remote`` joins a
``hitch can-hub`` (a CAN hub on 127.0.0.1: cross-process CAN without multicast).
``hitch sim fault`` asks a running service whose ECU is simulated to inject link faults
(service key ``sim/fault``).
``hitch sim perturb --seed S --tape`` writes a random true machine (a truth profile with
tape-measure errors, :mod:`bridge.sim.truth`); ``--sim-truth FILE`` gives the twin that truth
(``hitch ecu-sim``, ``hitch sim measure``; ``hitch serve`` has the same flag).
``hitch sim measure`` holds the twin at a pose (the planner's nominal IK) or an AD reading in
simulated time and reports the planner's measured pose, the true pose and an instrument's reading
of it (``--noise tape|station|none``, ``--points`` for marked points).
"""

from __future__ import annotations

import argparse
import math
import socket
import sys
import time
from pathlib import Path
from urllib.parse import urlsplit

import numpy as np

from bridge.cli.errors import CLIError
from bridge.cli.model import (
    add_model_options,
    bounded_float,
    bounded_int,
    finite_float,
    model_from_args,
    whole_number,
)
from bridge.cli.output import console, output_path, plot_path
from bridge.cli.plan import parse_pose_arg
from bridge.cli.realtime import add_realtime_option, realtime_process
from bridge.cli.service import _client_options
from bridge.link.realtime import INTERFACES, RealtimeRunner, open_bus, shutdown_bus
from bridge.link.state import LinkConfig, LinkError
from bridge.service.maneuvers.language import MIN_SPEED_SCALE
from bridge.service.scheduling import TWIN_RT_PRIORITY
from bridge.service.wire import to_json_text
from bridge.sim.can_node import EcuCanNode
from bridge.sim.cylinder import VALVE_MAX
from bridge.sim.ecu import ACTUATOR_ORDER, CylinderECU
from bridge.sim.fault_injector import CUTS, MAX_DELAY_MS, FaultSettings
from bridge.sim.move import (
    REFERENCE_KINDS,
    MoveFigures,
    MoveSettings,
    MoveTrace,
    SimError,
    SimSettings,
    build_move_figures,
    run_move,
)
from bridge.sim.rig import SimRig
from bridge.sim.truth import (
    COORDINATE_FIELDS,
    LENGTH_FIELDS,
    MARKED_POINTS,
    NOISE_KINDS,
    Instrument,
    MachineTruth,
    PinPlay,
    TruthError,
    load_machine_truth,
    noise_kind,
    perturb_profile,
    truth_toml,
)
from planner.errors import HitchInputError
from planner.model.kinematics import POINT_NAMES, HitchModel
from planner.model.sensors import SensorScaling
from planner.profiles.hitch import Profile, load_profile, tractor_profile_for, write_profile_text
from planner.trajectory import TrajectoryPlanner
from planner.work_control import DRAFT_SETPOINT_MAX_N

__all__ = [
    "add_commands",
    "ecu_sim_summary_text",
    "measure_in_sim",
    "move_json",
    "perturbation_summary",
    "plot_move",
    "plot_track",
]

_POSE = ("x", "z", "roll", "pitch")


# -- hitch sim move ------------------------------------------------------------------------


def _figure(value: float | None, spec: str, missing: str) -> str:
    """``value`` formatted, or ``missing`` when there is none (None or NaN: nothing was measured)."""
    return missing if value is None or not math.isfinite(value) else format(value, spec)


def _figures_json(f: MoveFigures) -> dict:
    return {
        "final_error": {"position_m": f.final_error_position_m, "angle_rad": f.final_error_angle_rad, **f.final_error},
        "max_path_deviation_m": f.max_path_deviation_m,
        "max_path_deviation_rad": f.max_path_deviation_rad,
        "overshoot": f.overshoot,
        "settling_time_s": f.settling_time_s,
    }


def move_json(trace: MoveTrace, measured: MoveFigures, truth: MoveFigures) -> dict:
    """The ``--json`` document: figures from the CAN-measured pose at the top level,
    simulation truth under ``truth``, plus the run's context."""
    return {
        "reference": trace.reference_kind,
        "start": dict(zip(_POSE, map(float, trace.start), strict=True)),
        "goal": dict(zip(_POSE, map(float, trace.goal), strict=True)),
        "plan_duration_s": trace.plan_duration_s,
        "run_duration_s": float(trace.t[-1]),
        **_figures_json(measured),
        "truth": _figures_json(truth),
        "settle_band": {"position_m": measured.band_position_m, "angle_rad": measured.band_angle_rad},
        "bus_load": trace.bus_load,
        "faults": list(trace.faults),
        "link": trace.link_counters,
        "ecu_node": trace.node_counters,
    }


def plot_move(path: str, trace: MoveTrace, title: str = "") -> None:
    """PNG: pose vs time (planned, measured over CAN, truth), path deviation, actuators."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(4, 1, figsize=(10, 12), sharex=True, constrained_layout=True)
    t = trace.t
    for i, unit, scale in ((0, "mm", 1e3), (1, "mm", 1e3), (2, "mrad", 1e3), (3, "mrad", 1e3)):
        a = ax[0] if i < 2 else ax[1]
        (line,) = a.plot(t, trace.planned[:, i] * scale, "--", lw=1, label=f"{_POSE[i]} planned")
        a.plot(t, trace.measured[:, i] * scale, color=line.get_color(), lw=1.5, label=f"{_POSE[i]} measured (CAN)")
        a.plot(t, trace.truth[:, i] * scale, ":", color=line.get_color(), lw=1, label=f"{_POSE[i]} truth")
        a.set_ylabel(unit)
    ax[0].set_title(title or f"{trace.reference_kind} reference: x, z")
    ax[1].set_title("roll, pitch")
    for name, pose, start in (("measured", trace.measured, trace.start), ("truth", trace.truth, trace.truth_start)):
        d = trace.goal - start
        s = np.clip((pose - start) @ d / (float(d @ d) or 1.0), 0, 1)
        e = pose - (start + s[:, None] * d)
        ax[2].plot(t, np.hypot(e[:, 0], e[:, 1]) * 1e3, label=f"position [mm], {name}")
        ax[2].plot(t, np.hypot(e[:, 2], e[:, 3]) * 1e3, label=f"angle [mrad], {name}")
    ax[2].set_title("deviation from the straight path start → goal")
    lo = np.nanmin(np.vstack([trace.reference, trace.measured_actuators]), axis=0)
    hi = np.nanmax(np.vstack([trace.reference, trace.measured_actuators]), axis=0)
    span = np.where(hi - lo > 1e-12, hi - lo, 1.0)
    for i, n in enumerate(ACTUATOR_ORDER):
        (line,) = ax[3].plot(t, (trace.reference[:, i] - lo[i]) / span[i], "--", lw=1, label=f"{n} reference")
        ax[3].plot(
            t, (trace.measured_actuators[:, i] - lo[i]) / span[i], color=line.get_color(), lw=1.5, label=f"{n} measured"
        )
    ax[3].set_title("actuators, normalised to the range each covers in this move")
    ax[3].set_xlabel("t since the first command [s]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(loc="best", fontsize=7, ncol=2)
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _cmd_sim_move(args) -> int:
    if args.no_feedforward and args.reference != "trajectory":
        raise CLIError(f"--no-feedforward applies to --reference trajectory only (got --reference {args.reference})")
    model = model_from_args(args)
    rate = args.rate if args.rate is not None else model.profile.motion.control_rate
    sim = SimSettings(
        noise_counts=args.noise_counts,
        gain_error=args.gain_error,
        seed=args.seed,
        frame_loss=args.frame_loss,
        link=LinkConfig(control_rate_hz=rate),
    )
    move = MoveSettings(
        reference=args.reference,
        start=args.start,
        speed_scale=args.speed_scale,
        feedforward=not args.no_feedforward,
        max_time_s=args.max_time,
    )
    trace = run_move(model, args.to, move, sim, truth=_truth_arg(args))
    measured = build_move_figures(trace, "measured", band_position_m=args.band_position, band_angle_rad=args.band_angle)
    truth = build_move_figures(trace, "truth", band_position_m=args.band_position, band_angle_rad=args.band_angle)
    if args.plot:
        plot_move(args.plot, trace)
    if args.json:
        print(to_json_text(move_json(trace, measured, truth)))
        return 0
    c = console()
    c.print(
        f"{trace.reference_kind} reference, {len(trace.t)} samples over {trace.t[-1]:.2f} s simulated "
        f"(plan {trace.plan_duration_s:.2f} s), bus load {100 * trace.bus_load:.1f} % of 250 kbit/s"
    )
    d = np.asarray(trace.goal, float) - np.asarray(trace.start, float)
    tiny = math.hypot(d[0], d[1]) <= args.band_position and float(np.max(np.abs(d[2:]))) <= args.band_angle
    for name, f in (("measured over CAN", measured), ("simulation truth", truth)):
        settle = "never" if f.settling_time_s is None else f"{f.settling_time_s:.2f} s"
        # a share of a move within the settling band means nothing (x=0 → x=0 read 110 %)
        over = "n/a (the move lies within the settling band)" if tiny else f"{100 * f.overshoot:.2f} %"
        c.print(
            f"{name:>18}: final error {1e3 * f.final_error_position_m:.2f} mm, "
            f"{1e3 * f.final_error_angle_rad:.2f} mrad; "
            f"path deviation {1e3 * f.max_path_deviation_m:.2f} mm, {1e3 * f.max_path_deviation_rad:.2f} mrad; "
            f"overshoot {over}; settling {settle}"
        )
    if trace.faults:
        c.print("faults: " + "; ".join(trace.faults))
    if args.plot:
        c.print(f"plot written to {args.plot}")
    return 0


# -- hitch sim track -----------------------------------------------------------------------
def plot_track(path: str, result) -> None:
    """PNG of a closed loop: setpoint, tractor-frame reference, measured and truth of the DOF; the job's error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    d, r = result.dof_index, result
    unit = "mm" if r.dof in ("x", "z") else "mrad"
    fig, ax = plt.subplots(2, 1, figsize=(11, 7), sharex=True, constrained_layout=True)
    ax[0].plot(r.t, r.demand * 1e3, color="k", lw=1, label=f"demand ({r.dof} for zero error, tractor frame)")
    ax[0].plot(r.t, r.reference[:, d] * 1e3, "--", lw=1, label="reference (controller)")
    ax[0].plot(r.t, r.measured[:, d] * 1e3, lw=1, label="measured (CAN)")
    ax[0].plot(r.t, r.truth[:, d] * 1e3, ":", lw=1, label="truth")
    if r.frame == "tractor" and np.any(np.isfinite(r.setpoint)):
        ax[0].plot(r.t, r.setpoint * 1e3, lw=0.6, alpha=0.6, label="setpoint")
    ax[0].set_ylabel(f"{r.dof} [{unit}]")
    ax[0].set_title(f"{r.scenario}: {r.job}, strategy {r.strategy} (frame {r.frame})")
    ax[1].plot(r.t, r.error * 1e3, lw=1, label=f"error ({r.job}), RMS {r.figures.rms * 1e3:.2f} {unit}")
    ax[1].axvline(r.t[r.evaluated][0] if r.evaluated.any() else 0.0, color="grey", lw=0.8, ls=":")
    ax[1].set_ylabel(f"error [{unit}]")
    ax[1].set_xlabel("scenario time since the loop started [s]")
    for a in ax:
        a.grid(alpha=0.3)
        a.legend(loc="upper right", fontsize=7)
    fig.savefig(path, dpi=90)
    plt.close(fig)


#: ``--json`` given without a FILE (``sim track``, ``sim field``): the summary goes to stdout, as JSON only
JSON_STDOUT = "-"


def _json_summary(json_file: str | None, summary: dict) -> bool:
    """``--json [FILE]``: True when the summary went to stdout as JSON (nothing else to print); with a FILE it
    is written there (strict JSON, indented) and the text summary follows."""
    if json_file is None:
        return False
    if json_file == JSON_STDOUT:
        print(to_json_text(summary))
        return True
    with open(json_file, "w", encoding="utf-8") as fh:
        fh.write(to_json_text(summary, indent=1))
    return False


#: a closed loop's warm-up plus the settling its figures leave out [s] (LoopSettings' and FieldLoopSettings'
#: defaults): a shorter run has no figures
_TRACK_SETTLE_S = 5.5
_FIELD_SETTLE_S = 3.5


def _cmd_sim_track(args) -> int:
    from bridge.service.track_loop import LoopSettings, run_track_loop

    model = model_from_args(args)
    settings = LoopSettings(strategy=args.strategy, job=args.job, duration_s=args.duration, truth=_truth_arg(args))
    result = run_track_loop(model, args.scenario, settings)
    if args.plot:
        plot_track(args.plot, result)
    summary = result.summary()
    if _json_summary(args.json_file, summary):
        return 0
    c = console()
    unit, k = ("mm", 1e3) if result.dof in ("x", "z") else ("mrad", 1e3)
    f, fi = result.figures, result.figures_inside
    c.print(
        f"{result.scenario}: {result.job} ({result.dof}), strategy {result.strategy}, frame {result.frame}, "
        f"{summary['duration_s']:.1f} s simulated"
    )
    c.print(f"error RMS {f.rms * k:.2f} {unit}, p95 {f.p95 * k:.2f} {unit}, max {f.max * k:.2f} {unit} (n = {f.n})")
    inside = f"RMS {fi.rms * k:.2f} {unit}, max {fi.max * k:.2f} {unit}" if fi.n > 0 else "no sample to judge (n/a)"
    c.print(f"inside workspace and limits ({100 * result.inside_fraction:.0f} % of the samples): {inside}")
    c.print("counts: " + ", ".join(f"{n} {v}" for n, v in result.counts.items()))
    for note in result.notes:
        c.print(f"note: {note}")
    if result.faults:
        c.print("faults: " + "; ".join(result.faults))
    if args.plot:
        c.print(f"plot written to {args.plot}")
    if args.json_file is not None:
        c.print(f"summary written to {args.json_file}")
    return 0


def _cmd_sim_field(args) -> int:
    """``hitch sim field FIELD``: one closed loop of work control over a field (bridge.service.field_loop)."""
    from bridge.service.field_loop import FieldLoopSettings, plot_field, run_field_loop
    from planner.work_control import WorkSettings

    model = model_from_args(args)
    work = {k: getattr(args, k) for k in ("draft_setpoint_n", "blend", "sensitivity", "depth_min_m", "depth_max_m")}
    work = {k: v for k, v in work.items() if v is not None}
    if args.draft_setpoint_kn is not None:  # the operator's unit at this boundary only; N inside
        work["draft_setpoint_n"] = args.draft_setpoint_kn * 1000.0
    settings = FieldLoopSettings(
        work=WorkSettings(mode=args.mode, slip_limit=args.slip_limit, **work),
        z_m=args.z,
        duration_s=args.duration,
        truth=_truth_arg(args),
    )
    result = run_field_loop(model, args.field, settings)
    summary = result.summary()
    if args.plot:
        plot_field(args.plot, [result])
    if _json_summary(args.json_file, summary):
        return 0
    f = summary["figures"]
    c = console()
    c.print(f"{result.field}: mode {result.mode}, {summary['duration_s']:.1f} s simulated")
    c.print(
        f"draft mean {f['draft_mean_n'] / 1e3:.2f} kN, SD {f['draft_sd_n'] / 1e3:.2f} kN; "
        f"depth {f['depth_min_m'] * 100:.1f}..{f['depth_max_m'] * 100:.1f} cm; slip max {f['slip_max']:.3f} "
        f"(heavy patches {_figure(f['slip_max_heavy'], '.3f', 'n/a: no heavy patch')}); "
        f"controller cycle p99 {f['cycle_p99_us']:.1f} us"
    )
    c.print("counts: " + ", ".join(f"{n} {v}" for n, v in result.counts.items()))
    for e in result.events:
        c.print(f"event: {e}")
    for note in result.notes:
        c.print(f"note: {note}")
    if result.faults:
        c.print("faults: " + "; ".join(result.faults))
    if args.plot:
        c.print(f"plot written to {args.plot}")
    if args.json_file is not None:
        c.print(f"summary written to {args.json_file}")
    return 0


#: a draft setpoint [N] below this is refused as a value meant in kN: no tool works at a draft of less than 1 kN,
#: and 1…999 kN would be plausible drafts (a chisel: 10…40 kN)
DRAFT_SETPOINT_KN_HINT_BELOW_N = 1000.0


def draft_setpoint_newtons(text: str) -> float:
    """argparse type of ``--draft-setpoint`` [N]: in (0, 300000] N, and at least 1000 N — a smaller number is
    taken for kN given in the wrong unit (``20`` → "did you mean kN? 20 kN = 20000 N")."""
    v = finite_float("--draft-setpoint")(text)
    if not 0.0 < v <= DRAFT_SETPOINT_MAX_N:
        raise argparse.ArgumentTypeError(f"--draft-setpoint must lie in (0, {DRAFT_SETPOINT_MAX_N:g}] N, got {text}")
    if v < DRAFT_SETPOINT_KN_HINT_BELOW_N:
        raise argparse.ArgumentTypeError(
            f"--draft-setpoint is in newtons: {v:g} N is below {DRAFT_SETPOINT_KN_HINT_BELOW_N:g} N, no working "
            f"draft; did you mean kN? {v:g} kN = {v * 1000.0:g} N (--draft-setpoint {v * 1000.0:g} or "
            f"--draft-setpoint-kn {v:g})"
        )
    return v


#: what the ``ecu-sim`` status line's valve figures are: the ECU's valve commands, integers in
#: -VALVE_MAX…VALVE_MAX (bridge.sim.cylinder: ±254 = the full command; + = the reading grows)
VALVE_COMMANDS_LABEL = f"valve commands [±{VALVE_MAX} = full]"


def _ecu_status_line(now_s: float, node: EcuCanNode, ecu: CylinderECU) -> str:
    """The ``ecu-sim`` status line: plain numbers (print it without markup: numpy's repr in brackets was taken
    for rich markup and vanished); each valve command named by its actuator, with its scale."""
    n = node.counters
    valves = "  ".join(f"{a} {int(v)}" for a, v in zip(ACTUATOR_ORDER, ecu.valve_commands(), strict=True))
    return (
        f"t={now_s:7.1f} s  {node.claim_state.value}  refs {n.references}  "
        f"tx {n.frames_tx}  malformed {n.malformed}  {VALVE_COMMANDS_LABEL}: {valves}"
    )


#: the words of the ``ecu-sim`` summary for the node's counters (EcuNodeCounters; another one: its own name)
_COUNTER_WORDS = {
    "frames_rx": "received",
    "frames_tx": "sent",
    "references": "references",
    "parameters": "parameter frames",
    "parameters_rejected": "parameter frames rejected",
    "malformed": "malformed",
    "unknown_pgn": "unknown PGN",
    "ignored": "ignored",
    "error_frames": "error frames",
    "tx_errors": "send errors",
    "restarts": "ECU restarts",
}


def ecu_sim_summary_text(summary: dict) -> str:
    """The closing summary of ``hitch ecu-sim`` as labelled lines (``--json``: the same as JSON)."""
    counters = ", ".join(f"{_COUNTER_WORDS.get(k, k.replace('_', ' '))} {v}" for k, v in summary["counters"].items())
    counts = ", ".join(f"{k} {v}" for k, v in summary["measurement_counts"].items())
    return "\n".join(
        (
            f"ecu-sim ran {summary['time_s']:.3f} s on interface {summary['interface']}; "
            f"address claim: {summary['claim']}; watchdog trips: {summary['watchdog_trips']}",
            f"frames: {counters}",
            f"measurement [AD counts]: {counts}",
        )
    )


def _open_ecu_bus(interface: str, channel: str | None):
    """``open_bus`` for ``ecu-sim``: with ``--interface remote`` and no hub listening at the channel, the refusal
    says to start ``hitch can-hub --port P`` (P: the channel's port) first — ecu-sim joins a hub, it starts none."""
    try:
        return open_bus(interface, channel)
    except LinkError as exc:
        if interface != "remote":
            raise
        from bridge.link.loopback import DEFAULT_HUB_PORT, hub_url

        url = channel or hub_url()
        try:
            parts = urlsplit(url)
            host, port = parts.hostname, parts.port or DEFAULT_HUB_PORT
        except ValueError:
            raise exc from None
        if host not in ("127.0.0.1", "localhost") or not _refused(host, port):
            raise
        raise LinkError(
            f"cannot open remote channel {url!r}: no CAN hub runs there (connection refused). ecu-sim "
            f"--interface remote joins a running hub: start `hitch can-hub --port {port}` first (another terminal), "
            f"then ecu-sim with --channel {hub_url(port)}"
        ) from None


def _refused(host: str, port: int) -> bool:
    """True when nothing listens on ``host``:``port`` (TCP connection refused)."""
    try:
        socket.create_connection((host, port), timeout=1.0).close()
    except ConnectionRefusedError:
        return True
    except OSError:
        return False
    return False


# -- hitch ecu-sim -------------------------------------------------------------------------
def _cmd_ecu_sim(args) -> int:
    with realtime_process(args, TWIN_RT_PRIORITY, "ecu-sim"):  # the ECU's computer: its threads inherit it
        return _run_ecu_sim(args)


def _run_ecu_sim(args) -> int:
    if args.duration is not None and not (np.isfinite(args.duration) and args.duration > 0):
        raise SimError(f"--duration must be a positive number of seconds, got {args.duration}")
    if not (np.isfinite(args.status_every) and 0.05 <= args.status_every <= 3600):
        raise SimError(f"--status-every must lie in [0.05, 3600] s, got {args.status_every}")
    nominal = load_profile(args.profile)
    profile = nominal if args.sim_truth is None else load_machine_truth(args.sim_truth).profile
    configured = nominal
    if args.sensor_calibration:  # the lift travel hitch calibrate sensors' link reads the hitch position on
        from bridge.link.sensor_calibration import calibration_profile

        configured = calibration_profile(nominal)
        lift = configured.actuator("lift")
        console(stderr=True).print(
            f"ecu-sim: configured for hitch calibrate sensors: lift travel counts {lift.counts_min} … "
            f"{lift.counts_max} (the calibration link's; nominal {nominal.actuator('lift').counts_min} … "
            f"{nominal.actuator('lift').counts_max})",
            highlight=False,
        )
    ecu = CylinderECU(
        profile, rng=args.seed, noise_counts=args.noise_counts, gain_error=args.gain_error, calibration=configured
    )
    bus = _open_ecu_bus(args.interface, args.channel)
    node = EcuCanNode(ecu, bus)
    runner = RealtimeRunner(node)
    c = console(stderr=True)
    try:
        runner.start()
        deadline = time.monotonic() + args.duration if args.duration else None
        while True:
            step = (
                args.status_every if deadline is None else min(args.status_every, max(deadline - time.monotonic(), 0))
            )
            if runner.wait(step) or (deadline is not None and time.monotonic() >= deadline):
                break
            if not args.json:
                c.print(_ecu_status_line(runner.now(), node, ecu), markup=False, highlight=False)
    except KeyboardInterrupt:  # Ctrl-C is the normal end: stop cleanly and print the summary
        pass
    finally:
        runner.stop()
        try:  # heartbeat 255: on a bus that went away (the hub killed) the send fails
            node.shutdown(runner.now())
        except Exception as exc:  # noqa: BLE001 (OSError, CanError, python-can-remote's WebsocketClosed …: said below)
            gone: BaseException | None = exc
        else:
            gone = None
        gone = shutdown_bus(bus) or gone
    if runner.error is not None:
        raise SimError(f"ECU node stopped: the CAN bus failed: {type(runner.error).__name__}: {runner.error}")
    if gone is not None:
        raise SimError(f"ECU node stopped: the CAN bus went away: {type(gone).__name__}: {gone}")
    summary = {
        "interface": args.interface,
        "time_s": round(ecu.time_s, 3),
        "claim": node.claim_state.value,
        "counters": node.counters.as_dict(),
        "watchdog_trips": ecu.watchdog.trip_count,
        "measurement_counts": dict(zip(ACTUATOR_ORDER, map(int, ecu.measurement_counts()), strict=True)),
    }
    print(to_json_text(summary) if args.json else ecu_sim_summary_text(summary))
    return 0


# -- hitch sim fault -----------------------------------------------------------------------
def _cmd_sim_fault(args) -> int:
    settings = FaultSettings(cut=args.cut, loss=args.loss, delay_ms=args.delay_ms, restart_ecu=args.restart_ecu)
    from bridge.service.client import HitchClient  # zenoh only for the commands that talk to a service
    from bridge.service.config import DEFAULT_LISTEN

    with HitchClient(
        args.connect or [DEFAULT_LISTEN], prefix=args.prefix, timeout_s=args.timeout, security=args.security
    ) as client:
        reply = client.request("sim/fault", settings.to_json())
    if args.json:
        print(to_json_text(reply))
    else:
        console().print(fault_settings_text(reply.get("applied") or {}), markup=False, highlight=False)
    return 0


def fault_settings_text(applied: dict) -> str:
    """One line for the twin's fault injection now in force (``sim/fault``'s ``applied``)."""
    cut = applied.get("cut", "none")
    named = {"planner_to_ecu": "planner → ECU", "ecu_to_planner": "ECU → planner", "both": "both directions"}
    parts = ["link cut: " + named.get(str(cut), str(cut))]
    parts.append(f"frame loss {100.0 * float(applied.get('loss') or 0.0):g} %")
    parts.append(f"delay {float(applied.get('delay_ms') or 0.0):g} ms")
    if applied.get("restart_ecu"):
        parts.append("ECU restarted")
    return "twin fault injection: " + ", ".join(parts)


# -- hitch can-hub -------------------------------------------------------------------------
def _cmd_can_hub(args) -> int:
    with realtime_process(args, TWIN_RT_PRIORITY, "can-hub"):  # the bus's wire: the hub's threads inherit it
        return _run_can_hub(args)


def _run_can_hub(args) -> int:
    from bridge.link.loopback import LoopbackHub

    hub = LoopbackHub(args.port)
    console(stderr=True).print(
        f"CAN hub on {hub.url} (open buses with --interface remote --channel {hub.url}); next, in other "
        f"terminals: hitch ecu-sim --interface remote --channel {hub.url}, then hitch serve --can-interface remote "
        f"--can-channel {hub.url} --no-sim-ecu",
        markup=False,
        highlight=False,
    )
    try:
        hub.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        hub.close()
    return 0


def _add_plant_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--noise-counts", type=float, default=0.0, help="AD noise standard deviation [counts] (default 0)")
    p.add_argument("--gain-error", type=float, default=0.0, help="relative valve-gain error of the plant, e.g. 0.1")
    p.add_argument("--seed", type=whole_number("--seed"), default=0, help="seed of the noise (and frame loss)")


def _add_json_summary_option(p: argparse.ArgumentParser) -> None:
    """``--json [FILE]`` of the closed loops (``sim track``, ``sim field``): :func:`_json_summary`."""
    p.add_argument(
        "--json",
        dest="json_file",
        nargs="?",
        const=JSON_STDOUT,
        default=None,
        type=_json_file,
        metavar="FILE",
        help="print the summary as JSON (as --json everywhere), or with FILE (*.json) write it there beside the text",
    )


def _json_file(text: str) -> str:
    """``--json FILE``: an output path ending in ``.json`` (:func:`output_path`). A scenario or field name
    after ``--json`` was taken as its FILE, and the run then refused for want of its scenario."""
    path = output_path(text)  # a folder, or one that does not exist, said first
    if text != "-" and not text.lower().endswith(".json"):
        raise argparse.ArgumentTypeError(
            f"FILE {text!r} must end in .json (a scenario or field name right after --json is taken as the FILE: "
            "give it before --json, or write --json=out.json)"
        )
    return path


def _truth_arg(args: argparse.Namespace) -> MachineTruth | None:
    """The twin's true machine of ``--sim-truth FILE`` (None: exactly the planner's profile)."""
    return None if args.sim_truth is None else load_machine_truth(args.sim_truth)


def _add_truth_option(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--sim-truth",
        default=None,
        metavar="FILE",
        help="the simulated machine's own true profile (hitch sim perturb); default: the planner's profile",
    )


# -- hitch sim perturb / measure -----------------------------------------------------------
def perturbation_summary(nominal: Profile, data: dict, play: PinPlay) -> dict:
    """The drawn errors of a truth: per field, truth − nominal (m, counts; gain as a fraction)."""
    geo = nominal.geometry.model_dump()
    errors: dict[str, object] = {}
    for k in (*COORDINATE_FIELDS, *LENGTH_FIELDS):
        v, n = data["geometry"][k], geo[k]
        errors[f"geometry.{k}"] = (
            [float(a) - float(b) for a, b in zip(v, n, strict=True)] if isinstance(n, tuple) else float(v) - float(n)
        )
    for a in ACTUATOR_ORDER:
        spec, t = nominal.actuator(a), data["actuators"][a]
        errors[f"actuators.{a}.ad_offset_counts"] = int(t["counts_min"]) - spec.counts_min
        span = spec.counts_max - spec.counts_min
        errors[f"actuators.{a}.ad_gain"] = (int(t["counts_max"]) - int(t["counts_min"]) - span) / span
    return {
        "name": data["name"],
        "errors": errors,
        "play_m": {"lower_link": play.lower_link_m, "top_link": play.top_link_m},
    }


def _cmd_sim_perturb(args) -> int:
    from bridge.sim.truth import check_model_builds

    nominal = load_profile(args.profile)
    # the nominal loads as `hitch profile show` loads it (else its own error), and the drawn truth too
    data, play = perturb_profile(nominal, args.seed, tape=args.tape, source=f"--profile {args.profile}")
    stability = data["stability"]  # the nominal's tractor, from the file the truth goes to (printed: absolute)
    stability["tractor_profile"] = tractor_profile_for(stability["tractor_profile"], args.out and Path(args.out).parent)
    text = truth_toml(data, play)
    if args.out:
        try:
            write_profile_text(  # the file as written loads there, as `hitch profile show` loads it
                args.out, text, what="--out truth", check=lambda p: check_model_builds(p, f"truth {p.name}")
            )
        except HitchInputError as exc:
            raise TruthError(str(exc)) from None
    summary = perturbation_summary(nominal, data, play)
    if args.json:
        print(to_json_text({**summary, "out": args.out}))
    elif args.out:
        console().print(
            f"truth {summary['name']} written to {args.out} (play {1e3 * play.lower_link_m:.2f} mm at the "
            f"lower-link balls, {1e3 * play.top_link_m:.2f} mm at the top-link pins)"
        )
    else:
        print(text, end="")
    return 0


def _counts_arg(text: str) -> tuple[int, ...]:
    parts = [p.strip() for p in text.split(",")]
    if len(parts) != 5:
        raise argparse.ArgumentTypeError(f"--counts needs 5 integers ({','.join(ACTUATOR_ORDER)}), got {text!r}")
    try:
        values = tuple(int(p) for p in parts)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--counts must be integers 0..1023, got {text!r}") from None
    off = [f"{name}={v}" for name, v in zip(ACTUATOR_ORDER, values, strict=True) if not 0 <= v <= 1023]
    if off:
        raise argparse.ArgumentTypeError(f"--counts: {', '.join(off)} outside 0..1023 (the 10-bit AD range)")
    return values


def _points_arg(text: str) -> tuple[str, ...]:
    names = tuple(p.strip() for p in text.split(",") if p.strip())
    unknown = [n for n in names if n not in POINT_NAMES]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"--points: unknown point(s) {unknown or text!r}; allowed: {','.join(POINT_NAMES)}"
        )
    return names


def measure_in_sim(
    model: HitchModel,
    truth: MachineTruth,
    *,
    pose: dict[str, float] | None = None,
    counts: tuple[int, ...] | None = None,
    noise: str = "station",
    points: tuple[str, ...] = (),
    seed: int = 0,
    settle_s: float = 0.5,
) -> dict:
    """Measure the twin in simulated time: the pistons hold ``counts`` (or the counts of the planner's
    nominal inverse kinematics of ``pose``; default the neutral pose), the link reads them over CAN
    (the planner's measured pose, nominal profile) and the instrument reads the true pose."""
    nominal = SensorScaling(model.profile)
    if counts is None:
        tp = TrajectoryPlanner(model)
        p = tp.goal_vector(model.neutral_pose.controlled(), pose or {})
        tp.check_in_workspace(p, "pose")
        held = nominal.counts_min + (tp.inverse.solve(p)[0] - nominal.si_min) / nominal.resolution
    else:
        held = np.asarray(counts, dtype=float)
        true_map = truth.scaling  # the pistons' counts: the true sensors'
        for name, v, a, b in zip(ACTUATOR_ORDER, held, true_map.counts_min, true_map.counts_max, strict=True):
            if not a <= v <= b:
                raise CLIError(f"--counts: {name} = {v:.0f} lies outside its sensor's stroke {a:.0f}..{b:.0f} counts")
    instrument = Instrument(noise, seed=seed)
    with SimRig(model, SimSettings(seed=seed), initial_actuators=truth.si_from_counts(held), truth=truth) as rig:
        rig.start()
        rig.run_until(settle_s)
        state = rig.link.latest_state()
        if state is None:
            raise SimError(f"no measurement from the simulated ECU after {settle_s} s")
        true = rig.true_pose()
        reading = instrument.measure(rig.true_machine, points)
        reported = rig.ecu.measurement_counts()
    planner = dict(zip(_POSE, map(float, state.pose.controlled()), strict=True))
    true_d = dict(zip(_POSE, map(float, true.controlled()), strict=True))
    return {
        "truth": truth.profile.name,
        "counts": dict(zip(ACTUATOR_ORDER, map(int, reported), strict=True)),
        "planner_pose": planner,
        "true_pose": true_d,
        "planner_minus_true": {k: planner[k] - true_d[k] for k in _POSE},
        "measured": reading.as_dict(),
    }


#: the seeds ``sim measure`` draws without ``--seed`` lie in [0, MEASURE_SEED_RANGE)
MEASURE_SEED_RANGE = 2**31


def measure_seed(given: int | None) -> int:
    """The instrument's seed of one ``sim measure``: ``--seed`` as given (reproducible), else a fresh one per
    call. A default of 0 gave every pose the same instrument error (tape: x +2.739 mm, z −4.604 mm each
    time), so 20 poses fitted "excellently" and 22σ off; the seed drawn is reported to repeat a reading."""
    if given is not None:
        return given
    import secrets

    return secrets.randbelow(MEASURE_SEED_RANGE)


def _cmd_sim_measure(args) -> int:
    model = model_from_args(args)
    truth = MachineTruth.nominal(model.profile) if args.sim_truth is None else load_machine_truth(args.sim_truth)
    seed = measure_seed(args.seed)
    out = measure_in_sim(
        model, truth, pose=args.pose, counts=args.counts, noise=args.noise, points=args.points, seed=seed
    )
    out["seed"] = seed
    warnings: list[str] = []
    if args.counts is not None:  # readings typed by hand may not fit one another: said as hitch fk says it
        from bridge.cli.model import _fk_warnings

        q = SensorScaling(model.profile).to_si(np.asarray(args.counts, dtype=float), tolerance_counts=1e9)
        warnings = [f"the planner's reading of --counts: {w}" for w in _fk_warnings(model, q, model.forward(q))]
    if args.json:
        print(to_json_text({**out, "warnings": warnings}))
        return 0
    for w in warnings:
        print(f"hitch: warning: {w}", file=sys.stderr)
    c = console()
    counts = out["counts"]
    reading = ", ".join(f"{k}={v}" for k, v in counts.items()) + " counts" if isinstance(counts, dict) else str(counts)
    c.print(f"truth {out['truth']}, AD reading {reading}", markup=False, highlight=False)
    c.print(f"planner profile {model.profile.name}", markup=False, highlight=False)
    for label, key in (("planner", "planner_pose"), ("true", "true_pose")):
        d = out[key]
        c.print(
            f"{label:>18}: x {1e3 * d['x']:8.2f} mm  z {1e3 * d['z']:8.2f} mm  "
            f"roll {1e3 * d['roll']:7.2f} mrad  pitch {1e3 * d['pitch']:7.2f} mrad"
        )
    m = out["measured"]
    d = m["pose"]
    c.print(
        f"{'measured (' + args.noise + ')':>18}: x {1e3 * d['x']:8.2f} mm  z {1e3 * d['z']:8.2f} mm  "
        f"roll {1e3 * d['roll']:7.2f} mrad  pitch {1e3 * d['pitch']:7.2f} mrad"
    )
    for name, p in m["points"].items():
        c.print(f"{'point ' + name:>18}: ({', '.join(f'{1e3 * v:.1f}' for v in p)}) mm")
    drawn = "given" if args.seed is not None else "drawn for this call"
    c.print(
        f"instrument noise seed {seed} ({drawn}; --seed {seed} repeats this reading)", markup=False, highlight=False
    )
    return 0


def _cmd_sim_stop_offsets(args) -> int:
    """``hitch sim stop-offsets``: the twin's ECU stops inside a count, as a profile's ``motion.count_approach``."""
    from bridge.sim.accuracy_run import measure_stop_offsets
    from planner.calibration.design import candidate_poses
    from planner.calibration.parametric import ParametricModel

    model = model_from_args(args)
    truth = MachineTruth.nominal(model.profile) if args.sim_truth is None else load_machine_truth(args.sim_truth)
    poses = candidate_poses(ParametricModel(model.profile), args.poses, random_only=True, seed=args.seed)[0]
    off = measure_stop_offsets(model, poses, truth, max_back_off_counts=args.max_back_off)
    if args.json:
        print(
            to_json_text(
                {
                    **off.table(),
                    "sd_below_counts": dict(zip(ACTUATOR_ORDER, map(list, off.sd_below), strict=True)),
                    "sd_above_counts": dict(zip(ACTUATOR_ORDER, map(list, off.sd_above), strict=True)),
                    "poses": off.n,
                }
            )
        )
        return 0
    worst = max(max(v) for v in (*off.sd_below, *off.sd_above))
    print(f"# the twin's ECU ({truth.profile.name}), {off.n} poses; largest sd {worst:.3f} counts; piston - count")
    print(off.toml(), end="")
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("sim", help="closed-loop runs against the simulated cylinder ECU over CAN")
    ssub = p.add_subparsers(dest="sim_command", required=True, parser_class=type(p))
    m = ssub.add_parser("move", help="move to a pose through the CAN path in simulated time")
    m.add_argument("--to", type=parse_pose_arg, required=True, help="goal, e.g. x=0.05,z=0.25")
    m.add_argument("--from", dest="start", type=parse_pose_arg, default=None, help="start pose (default: neutral)")
    m.add_argument(
        "--reference",
        choices=REFERENCE_KINDS,
        default="trajectory",
        help="step: goal actuators at once (thesis); trajectory: the plan streamed (default)",
    )
    m.add_argument(
        "--no-feedforward",
        action="store_true",
        help="trajectory: stream the plan's actuator positions as they are (each cylinder then "
        "lags by its own unit loop); default: the unit loops' feed-forward reference",
    )
    m.add_argument("--plot", default=None, type=plot_path, help="write a PNG of the run")
    m.add_argument(
        "--rate",
        type=bounded_float("--rate", 1.0, 200.0, unit="Hz", lo_open=False),
        default=None,
        help="control rate [Hz], 1..200 (default: profile, 50)",
    )
    m.add_argument(
        "--speed-scale",
        type=bounded_float("--speed-scale", MIN_SPEED_SCALE, 1.0, lo_open=False),
        default=1.0,
        help=f"fraction of full trajectory speed, [{MIN_SPEED_SCALE:g}, 1], default 1",
    )
    m.add_argument(
        "--frame-loss",
        type=bounded_float("--frame-loss", 0.0, 1.0, lo_open=False, hi_open=True),
        default=0.0,
        help="probability a node misses a frame, [0, 1), default 0",
    )
    m.add_argument(
        "--max-time",
        type=bounded_float("--max-time", 0.1, 600.0, unit="s", lo_open=False),
        default=30.0,
        help="longest run after the first command [s], [0.1, 600], default 30",
    )
    m.add_argument(
        "--band-position",
        type=bounded_float("--band-position", 0.0, 10.0, unit="m"),
        default=0.005,
        help="settling band on |(dx, dz)| [m], (0, 10], default 0.005",
    )
    m.add_argument(
        "--band-angle",
        type=bounded_float("--band-angle", 0.0, 10.0, unit="rad"),
        default=0.005,
        help="settling band on roll and pitch [rad], (0, 10], default 0.005",
    )
    _add_plant_options(m)
    _add_truth_option(m)
    add_model_options(m)
    m.set_defaults(handler=_cmd_sim_move)
    tr = ssub.add_parser("track", help="closed-loop continuous control of a terrain scenario in simulated time")
    tr.add_argument(
        "scenario", help="built-in scenario (flat, levelling, levelling-inside, guidance, terrain) or a .toml path"
    )
    tr.add_argument("--strategy", choices=("track", "goto_stream", "hold"), default="track", help="default track")
    tr.add_argument(
        "--job", choices=("levelling", "guidance", "terrain"), default=None, help="default: from the scenario"
    )
    tr.add_argument(
        "--duration",
        # the loop's warm-up and settling (LoopSettings' defaults) come first: a shorter run has no figures
        type=bounded_float("--duration", _TRACK_SETTLE_S, 3600.0, unit="s"),
        default=None,
        help=f"scenario seconds to run, more than {_TRACK_SETTLE_S:g} (default: the scenario's)",
    )
    tr.add_argument("--plot", default=None, type=plot_path, help="write a PNG of the run")
    _add_json_summary_option(tr)
    tr.add_argument("--profile", default="thesis-t132", help="built-in profile name or path to a .toml")
    tr.add_argument("--category", default=None, help="ISO 730 implement category (default: the profile's, 2)")
    _add_truth_option(tr)
    tr.set_defaults(handler=_cmd_sim_track)
    fl = ssub.add_parser("field", help="work control (position/draft/mixed/float) over a field in simulated time")
    fl.add_argument("field", help="built-in field (chisel) or a field .toml path")
    fl.add_argument(
        "--mode", choices=("position", "draft", "mixed", "float"), default="position", help="default position"
    )
    draft = fl.add_mutually_exclusive_group()
    draft.add_argument(
        "--draft-setpoint",
        dest="draft_setpoint_n",
        type=draft_setpoint_newtons,
        help=f"[N], (0, {DRAFT_SETPOINT_MAX_N:g}] N; below {DRAFT_SETPOINT_KN_HINT_BELOW_N:g} N refused as a value "
        "likely meant in kN (use --draft-setpoint-kn)",
    )
    draft.add_argument(
        "--draft-setpoint-kn",
        dest="draft_setpoint_kn",
        type=bounded_float("--draft-setpoint-kn", 0.0, DRAFT_SETPOINT_MAX_N / 1000.0, unit="kN"),
        default=None,
        help=f"the same in kN, as hitch work settings takes it: (0, {DRAFT_SETPOINT_MAX_N / 1000.0:g}] kN",
    )
    fl.add_argument("--blend", type=finite_float("--blend"), default=None, help="mixed: draft share, [0, 1]")
    fl.add_argument("--sensitivity", type=finite_float("--sensitivity"), default=None, help="[0.1, 2], 1 = nominal")
    fl.add_argument("--depth-min", dest="depth_min_m", type=finite_float("--depth-min"), help="[m]")
    fl.add_argument("--depth-max", dest="depth_max_m", type=finite_float("--depth-max"), help="[m]")
    fl.add_argument("--slip-limit", type=finite_float("--slip-limit"), default=None, help="(0, 0.5]; default none")
    fl.add_argument("--z", type=finite_float("--z"), default=0.0, help="operator's position setpoint z [m], default 0")
    fl.add_argument(
        "--duration",
        type=bounded_float("--duration", _FIELD_SETTLE_S, 3600.0, unit="s"),
        default=None,
        help=f"field seconds to run, more than {_FIELD_SETTLE_S:g} (default: the field's)",
    )
    fl.add_argument("--plot", default=None, type=plot_path, help="write a PNG of depth, draft and slip")
    _add_json_summary_option(fl)
    fl.add_argument("--profile", default="thesis-t132", help="built-in profile name or path to a .toml")
    fl.add_argument("--category", default=None, help="ISO 730 implement category (default: the profile's, 2)")
    _add_truth_option(fl)
    fl.set_defaults(handler=_cmd_sim_field)
    f = ssub.add_parser("fault", help="inject link faults into a running service's simulated ECU")
    f.add_argument("--cut", choices=CUTS, default="none", help="cut one direction or both (default none)")
    f.add_argument(
        "--loss",
        type=bounded_float("--loss", 0.0, 1.0, lo_open=False),
        default=0.0,
        help="frame loss probability, [0, 1] (default 0)",
    )
    f.add_argument(
        "--delay-ms",
        type=bounded_float("--delay-ms", 0.0, MAX_DELAY_MS, unit="ms", lo_open=False),
        default=0.0,
        help=f"frame delay [ms], [0, {MAX_DELAY_MS:g}] (default 0)",
    )
    f.add_argument("--restart-ecu", action="store_true", help="restart the simulated ECU once")
    _client_options(f)
    f.set_defaults(handler=_cmd_sim_fault)
    e = sub.add_parser(
        "ecu-sim",
        help="run the simulated cylinder ECU on a CAN interface in real time",
        description="Run the simulated cylinder ECU on a CAN interface in real time. Across processes on this "
        "computer: start the hub first (hitch can-hub --port P), then hitch ecu-sim --interface remote --channel "
        "ws://127.0.0.1:P/, then hitch serve --can-interface remote --can-channel ws://127.0.0.1:P/ --no-sim-ecu. "
        "Status lines go to stderr, the summary to stdout when it stops (Ctrl-C or --duration).",
    )
    e.add_argument(
        "--interface",
        choices=INTERFACES,
        default="udp_multicast",
        help="python-can interface (default udp_multicast; remote: joins a running hitch can-hub, start that first)",
    )
    e.add_argument(
        "--channel",
        default=None,
        help="channel (udp_multicast: python-can's default IPv4 group; socketcan: vcan0; "
        "remote: the URL of a running hitch can-hub, default ws://127.0.0.1:54701/)",
    )
    e.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: Ctrl-C)")
    e.add_argument("--status-every", type=float, default=1.0, help="status line period [s]")
    e.add_argument("--profile", default="thesis-t132", help="built-in profile name or path to a .toml")
    e.add_argument("--json", action="store_true", help="print the final summary as JSON")
    e.add_argument(
        "--sensor-calibration",
        action="store_true",
        help="configure the ECU for hitch calibrate sensors: the rear hitch position (the lift, a fraction of "
        "the travel) on the calibration link's lift travel, the nominal one widened by the reach (as the "
        "twin of calibrate sensors without a bus is); without it the lift cannot be calibrated over the bus",
    )
    _add_plant_options(e)
    _add_truth_option(e)
    add_realtime_option(e)
    e.set_defaults(handler=_cmd_ecu_sim)
    pp = ssub.add_parser("perturb", help="write a random true machine (truth profile) with tape-measure errors")
    pp.add_argument(
        "--seed", type=whole_number("--seed"), required=True, help="seed of the draw (the same seed, the same truth)"
    )
    pp.add_argument(
        "--tape",
        action="store_true",
        required=True,
        help="tape-measure errors: coordinates ±10 mm, lengths ±5 mm, AD ±3 counts / ±2 %%, play 0..1 mm",
    )
    pp.add_argument("--profile", default="thesis-t132", help="the nominal profile (name or .toml, default thesis-t132)")
    pp.add_argument("--out", default=None, metavar="FILE", help="write the truth here (default: print it)")
    pp.add_argument("--json", action="store_true", help="print the drawn errors as JSON")
    pp.set_defaults(handler=_cmd_sim_perturb)
    me = ssub.add_parser("measure", help="measure the true implement pose of the twin in simulated time")
    at = me.add_mutually_exclusive_group()
    at.add_argument("--pose", type=parse_pose_arg, default=None, help="the pose the planner holds, e.g. z=0.1")
    at.add_argument(
        "--counts", type=_counts_arg, default=None, help="the AD reading the twin holds: lift,tilt,top,left,right"
    )
    me.add_argument(
        "--noise",
        choices=NOISE_KINDS,
        default="station",
        type=noise_kind,  # accuracy-test's spelling too
        help="tape ±10 mm, station (or total-station) 1 mm / 1 mrad, none (default station)",
    )
    me.add_argument(
        "--points",
        type=_points_arg,
        default=(),
        metavar="NAMES",
        help=f"marked points to read, e.g. {','.join(MARKED_POINTS)} (default none)",
    )
    me.add_argument(
        "--seed",
        type=whole_number("--seed"),
        default=None,
        help="seed of the instrument noise (default: a fresh one each call, reported in the output; the same "
        "seed, the same reading)",
    )
    _add_truth_option(me)
    add_model_options(me)
    me.set_defaults(handler=_cmd_sim_measure)
    so = ssub.add_parser(
        "stop-offsets",
        help="measure where the twin's ECU stops each piston inside a count (prints [motion.count_approach])",
    )
    so.add_argument(
        "--poses", type=bounded_int("--poses", 1, 100), default=10, help="random workspace poses (default 10)"
    )
    so.add_argument(
        "--max-back-off",
        type=bounded_int("--max-back-off", 1, 5),
        default=3,
        help="largest back-off tried [counts] (default 3)",
    )
    so.add_argument("--seed", type=whole_number("--seed"), default=11, help="seed of the poses (default 11)")
    _add_truth_option(so)
    add_model_options(so)
    so.set_defaults(handler=_cmd_sim_stop_offsets)
    h = sub.add_parser(
        "can-hub",
        help="a CAN hub on 127.0.0.1 for nodes in several processes (--interface remote)",
        description="A CAN hub on 127.0.0.1 for nodes in several processes; start it first, then the nodes "
        "(hitch ecu-sim --interface remote --channel ws://127.0.0.1:PORT/, hitch serve --can-interface remote "
        "--can-channel ws://127.0.0.1:PORT/ --no-sim-ecu). It runs until Ctrl-C.",
    )
    h.add_argument("--port", type=int, default=54701, help="TCP port on 127.0.0.1 (default 54701; 0: any free one)")
    add_realtime_option(h)
    h.set_defaults(handler=_cmd_can_hub)
