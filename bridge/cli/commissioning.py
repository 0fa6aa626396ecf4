"""``hitch accuracy-test`` and ``hitch calibrate sensors``: commissioning against the twin.

``accuracy-test`` runs the thesis's field accuracy test (:mod:`bridge.sim.accuracy_run`) on the
simulated machine with its own true machine (``--sim-truth``, default the nominal twin) and prints
E, |E|, |E|max and TT per DOF beside the thesis's tables 3-8 … 3-10.

``calibrate sensors`` runs the sensor calibration (:mod:`bridge.link.sensor_calibration`) over the
CAN link to the twin in simulated time and writes the profile with the fitted AD maps.
``--detached`` is the operator's declaration of a procedure step — no implement attached, the top
link unpinned at the mast — under which the top-link angle limits are released; it needs ``--yes``
or an interactive confirmation and is refused together with ``--implement``.
(``hitch calibrate`` is another command's group; this one stands alone.)
"""

from __future__ import annotations

import datetime as _dt
import hashlib
import sys
from pathlib import Path

from bridge.cli.errors import CLIError
from bridge.cli.model import add_model_options, model_from_args, refuse_overwriting_profile, whole_number
from bridge.cli.output import console, output_path
from bridge.cli.realtime import add_realtime_option, realtime_process
from bridge.link.realtime import INTERFACES
from bridge.link.sensor_calibration import (
    SensorCalibration,
    SensorCalibrationError,
    calibration_profile,
    sensor_profile_toml,
)
from bridge.service.wire import to_json_text
from bridge.sim.accuracy_run import INSTRUMENTS, AccuracyRun, AccuracyRunSettings, run_accuracy_test
from bridge.sim.rig import SimRig, SimSettings
from bridge.sim.truth import MachineTruth, load_machine_truth
from planner.calibration.accuracy import THESIS_ACCURACY, DofStatistics, thesis_sequence
from planner.errors import HitchInputError
from planner.limits.tractor import load_tractor_profile
from planner.model.kinematics import HitchModel
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import write_profile_text

__all__ = ["ACCURACY_LEGEND", "accuracy_table", "add_commands", "deflected_dofs"]

_DOF = ("x", "z", "roll", "pitch")
_UNIT = {"x": "mm", "z": "mm", "roll": "mrad", "pitch": "mrad"}


#: what the table's columns are, printed under it (a new user could not tell what E, |E| and TT were)
ACCURACY_LEGEND = "E: mean error (measured − commanded); |E|: mean absolute; |E|max: largest; TT: repeatability"


def _cells(st: DofStatistics) -> str:
    """E, |E|, |E|max, TT of ``st`` [m or rad] in mm / mrad (``–`` for a TT not known), 7 columns each."""
    tt = "–" if st.repeatability != st.repeatability else f"{1e3 * st.repeatability:.1f}"
    return f"{1e3 * st.mean:7.1f} {1e3 * st.mean_abs:7.1f} {1e3 * st.max_abs:7.1f} {tt:>7}"


def deflected_dofs(sequence) -> tuple[str, ...]:
    """The DOF (x, z, roll, pitch order) a test ``sequence`` deflects from home: the others are only held there."""
    moved = {d for step in sequence for d, v in zip(_DOF, step.offset, strict=True) if v != 0.0}
    return tuple(d for d in _DOF if d in moved)


def accuracy_table(run: AccuracyRun, deflected: tuple[str, ...] = _DOF) -> str:
    """The run's table (E, |E|, |E|max, TT, mm / mrad) of each ``deflected`` DOF, the twin's row above the
    thesis's tables 3-8 … 3-10 (one row per source: 66 columns, where one row per DOF took 174), and its legend;
    the DOF not deflected (held at home: cross-talk and the instrument's noise, nothing the thesis's rows
    measured) on a line of their own, marked so."""
    models = list(THESIS_ACCURACY)
    head = f"{'DOF':<6}{'unit':<5}{'source':<24}{'E':>7} {'|E|':>7} {'|E|max':>7} {'TT':>7}"
    lines = [head, "-" * len(head)]
    for d in deflected:
        lines.append(f"{d:<6}{_UNIT[d]:<5}{'twin':<24}{_cells(run.statistics[d])}")
        lines += [f"{d:<6}{_UNIT[d]:<5}{'thesis ' + m:<24}{_cells(THESIS_ACCURACY[m][d])}" for m in models]
    lines.append(ACCURACY_LEGEND)
    held = [d for d in _DOF if d not in deflected]
    if held:
        lines.append("not deflected (held at home: cross-talk and the instrument's noise, not the thesis's rows):")
        lines += [f"{d:<6}{_UNIT[d]:<5}{'twin, held':<24}{_cells(run.statistics[d])}" for d in held]
    lines.append("")
    lines.append(
        "twin without the instrument (true − commanded): "
        + ", ".join(
            f"{d} E {1e3 * st.mean:.1f} |E|max {1e3 * st.max_abs:.1f} {_UNIT[d]}"
            for d, st in ((d, run.true_statistics[d]) for d in deflected)
        )
    )
    return "\n".join(lines)


def _truth(model: HitchModel, path: str | None) -> MachineTruth:
    return MachineTruth.nominal(model.profile) if path is None else load_machine_truth(path)


def _cmd_accuracy_test(args) -> int:
    model = model_from_args(args)
    truth = _truth(model, args.sim_truth)
    dofs = tuple(d.strip() for d in args.dofs.split(",") if d.strip())
    sequence = thesis_sequence(dofs=dofs, combined=set(dofs) == set(_DOF))
    run = run_accuracy_test(model, truth, AccuracyRunSettings(instrument=args.instrument, seed=args.seed), sequence)
    deflected = deflected_dofs(sequence)
    if args.json:
        out = run.as_dict()
        held = [d for d in _DOF if d not in deflected]
        out["deflected"] = list(deflected)
        out["not_deflected"] = {  # held at home: cross-talk and the instrument's noise, not the thesis's rows
            "dofs": held,
            "statistics": {d: out["statistics"].pop(d) for d in held},
            "true_statistics": {d: out["true_statistics"].pop(d) for d in held},
        }
        out["thesis"] = {m: {d: st.as_dict() for d, st in rows.items()} for m, rows in THESIS_ACCURACY.items()}
        print(to_json_text(out))
        return 0
    c = console(width=200)
    c.print(
        f"accuracy test (thesis tables 3-8 … 3-10): planner profile {model.profile.name}, twin truth {run.truth}, "
        f"instrument {run.instrument}, "
        f"{len(run.labels)} measured poses, {run.simulated_s:.0f} s simulated",
        highlight=False,
    )
    c.print(accuracy_table(run, deflected), highlight=False, markup=False)
    return 0


#: What ``--detached`` declares; the operator confirms it (``--yes`` or the prompt) before anything moves.
_DETACHED_DECLARATION = (
    "no implement is attached and the top link is unpinned at the implement's mast (hanging in its rest, or "
    "removed): the top-link angle limits are released for this calibration"
)


def _confirm_detached(args) -> None:
    """Refuse ``--detached`` with ``--implement``, ``--yes`` without ``--detached``; ask for the confirmation."""
    if args.implement not in (None, "none") and args.detached:
        raise CLIError(
            f"--detached declares that no implement is attached: it cannot go with --implement {args.implement}"
        )
    if args.yes and not args.detached:
        raise CLIError("--yes confirms --detached: without --detached there is nothing to confirm")
    if not args.detached or args.yes:
        return
    if not sys.stdin.isatty():
        raise CLIError(f"--detached declares that {_DETACHED_DECLARATION}; confirm it with --yes (no terminal to ask)")
    print(f"--detached: confirm that {_DETACHED_DECLARATION}. [y/N] ", end="", file=sys.stderr, flush=True)
    answer = sys.stdin.readline().strip().lower()
    if answer not in ("y", "yes"):
        raise CLIError("--detached not confirmed: nothing moved")


def _sensors_interrupted(args) -> str:
    """What an interrupted sensor calibration leaves (the ECU's watchdog zeroes the valves without references)."""
    if args.progress is None:
        return "no profile was written; with --progress FILE an interrupted calibration resumes where it stopped"
    if not Path(args.progress).is_file():  # interrupted before the first end was found: nothing recorded
        return f"no profile was written and no end was found yet ({args.progress} was not written)"
    return f"no profile was written; the ends found so far are in {args.progress}: run the same command to resume"


def _twin_identity(truth: str | None, profile: str) -> str:
    """The simulated machine a sensor calibration runs on, for its progress file: the truth file's content
    (a copy elsewhere is the same machine, another seed is not), or the nominal profile."""
    if truth is None:
        return f"the simulated twin of the nominal profile {profile}"
    digest = hashlib.sha256(Path(truth).read_bytes()).hexdigest()[:16]
    return f"the simulated twin of the truth file with sha256 {digest}"


def _actuator_list(text: str | None) -> tuple[str, ...]:
    """``--actuators``: a comma-separated subset of the five, each once (default all); the error names only the
    unknown ones (``lift,tlt`` was refused as "unknown or none ['lift', 'tlt']": a commissioning trial)."""
    if text is None:
        return ACTUATOR_NAMES
    names = [a.strip() for a in text.split(",") if a.strip()]
    unknown = [a for a in names if a not in ACTUATOR_NAMES]
    if unknown or not names:
        what = "unknown " + ", ".join(map(repr, unknown)) if unknown else "none given"
        raise CLIError(f"--actuators {text!r}: {what}; allowed: {', '.join(ACTUATOR_NAMES)}")
    twice = sorted({a for a in names if names.count(a) > 1})
    if twice:
        raise CLIError(f"--actuators {text!r}: {', '.join(map(repr, twice))} given more than once; each at most once")
    return tuple(names)


def _cmd_calibrate_sensors(args) -> int:
    if args.can_interface is not None and args.sim_truth is not None:
        raise CLIError(
            "--sim-truth gives the simulated twin its machine; with --can-interface the machine on the bus is "
            "calibrated: give one of them"
        )
    refuse_overwriting_profile(args.out, args.profile, force=args.force, sim_truth=args.sim_truth)
    _confirm_detached(args)
    nominal_model = model_from_args(args)
    nominal = nominal_model.profile
    truth = _truth(nominal_model, args.sim_truth)
    actuators = _actuator_list(args.actuators)
    implement = None
    if args.implement not in (None, "none"):
        implement = load_tractor_profile(nominal.stability.tractor_profile).implement(args.implement)
    cal_model = HitchModel(calibration_profile(nominal, detached=args.detached), nominal_model.category)
    log = (lambda _m: None) if args.json else (lambda m: console().print(m, highlight=False))
    if args.detached:  # said before anything moves
        log(f"detached: {_DETACHED_DECLARATION}")
    if args.can_interface is not None:  # a real ECU (or a twin in its own process) on a CAN bus
        where = f"the ECU on {args.can_interface} {args.can_channel or '(default channel)'}"
        log(f"calibrating {where}")
        fits = _calibrate_on_bus(args, cal_model, nominal, implement, actuators, log)
    else:
        machine = f"truth {args.sim_truth}" if args.sim_truth else "the nominal profile as truth"
        where = f"the simulated twin ({machine})"
        log(f"calibrating {where}; for a real ECU give --can-interface / --can-channel")
        with SimRig(cal_model, SimSettings(tick_s=0.005, seed=args.seed), truth=truth) as rig:
            rig.start()
            rig.run_until(0.5)
            fits = SensorCalibration(
                rig.link,
                rig,
                nominal,
                implement=implement,
                progress=args.progress,
                log=log,
                detached=args.detached,
                machine=_twin_identity(args.sim_truth, nominal.name),
            ).run(actuators)
    provenance = {
        "date": _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat(),
        "on": where,
        "detached": bool(args.detached),
        "actuators": {
            a: {
                "counts_min": f.counts_min,
                "counts_max": f.counts_max,
                "low": f.low.counts,
                "low_stopped_by": f.low.stopped_by,
                "high": f.high.counts,
                "high_stopped_by": f.high.stopped_by,
            }
            for a, f in fits.items()
        },
    }
    text = sensor_profile_toml(
        args.profile,
        {a: (f.counts_min, f.counts_max) for a, f in fits.items()},
        provenance=provenance,
        out_folder=Path(args.out).parent,
    )
    try:
        write_profile_text(args.out, text, what="--out profile")
    except HitchInputError as exc:
        raise SensorCalibrationError(str(exc)) from None
    result = {a: f.as_dict() for a, f in fits.items()}
    if args.json:
        print(to_json_text({"out": args.out, "detached": args.detached, "on": where, "actuators": result}))
        return 0
    c = console()
    for a, f in fits.items():
        n = nominal.actuator(a)
        c.print(
            f"{a:>6}: counts {f.counts_min} … {f.counts_max} (nominal {n.counts_min} … {n.counts_max}; relay "
            f"{f.low.counts} / {f.high.counts}, margin {f.relay_margin_counts})",
            highlight=False,
        )
    c.print(f"profile written to {args.out} (calibrated on {where})", highlight=False)
    return 0


#: how long ``calibrate sensors`` on a bus waits for the ECU's first complete measurement [s]
FIRST_MEASUREMENT_TIMEOUT_S = 5.0


def _calibrate_on_bus(args, cal_model: HitchModel, nominal, implement, actuators, log) -> dict:
    """The calibration over a real bus: the link in a real-time runner, the procedure on the wall clock; the
    control path's threads under SCHED_FIFO where permitted (bridge.cli.realtime)."""
    from bridge.service.scheduling import CONTROL_RT_PRIORITY

    with realtime_process(args, CONTROL_RT_PRIORITY, "calibrate sensors"):
        return _calibrate_on_bus_now(args, cal_model, nominal, implement, actuators, log)


def _calibrate_on_bus_now(args, cal_model: HitchModel, nominal, implement, actuators, log) -> dict:
    from bridge.link.can_link import CanLink
    from bridge.link.realtime import RealtimeRunner, open_bus
    from bridge.link.sensor_calibration import RealtimeDriver
    from bridge.link.state import LinkConfig

    try:
        bus = open_bus(args.can_interface, args.can_channel)
    except Exception as exc:  # noqa: BLE001 - LinkError, OSError, python-can's CanError family, a transport's own
        raise SensorCalibrationError(f"--can-interface {args.can_interface}: cannot open the bus ({exc})") from None
    link = CanLink(cal_model, bus, LinkConfig(bus_timestamps=True))
    runner = RealtimeRunner(link, name="calibration-link").start()
    try:
        deadline = runner.now() + FIRST_MEASUREMENT_TIMEOUT_S
        while not link.claimed or link.latest_state() is None:  # the address claim takes 250 ms (ISO 11783-5)
            if runner.now() > deadline or runner.wait(0.02):
                raise SensorCalibrationError(
                    f"no address claimed or no complete measurement from the ECU on {args.can_interface} "
                    f"{args.can_channel or '(default channel)'} within {FIRST_MEASUREMENT_TIMEOUT_S:g} s "
                    f"(faults: {', '.join(link.faults.reasons) or 'none'}): is it powered and on this bus?"
                )
        if "lift" in actuators:  # said before anything moves: the ECU's side of the lift reading
            lift = cal_model.profile.actuator("lift")
            log(
                f"the lift is read from the rear hitch position (a fraction of the ECU's lift travel): the ECU must "
                f"be configured with the calibration link's lift travel, counts {lift.counts_min} … "
                f"{lift.counts_max} (hitch ecu-sim --sensor-calibration)"
            )
        ecu = link.peer_name(link.config.ecu_address)
        if ecu is None and args.progress is not None and Path(args.progress).is_file():
            raise SensorCalibrationError(
                f"the ECU did not answer with its ISO 11783 NAME: it cannot be told from another machine, so the "
                f"ends in {args.progress} are not resumed (give another --progress to start afresh)"
            )
        return SensorCalibration(
            link,
            RealtimeDriver(runner),
            nominal,
            implement=implement,
            progress=args.progress,
            log=log,
            detached=args.detached,
            machine=None if ecu is None else f"the ECU of ISO 11783 NAME 0x{ecu.value:016x}",
        ).run(actuators)
    finally:
        link.stop(runner.now())  # no more references: the ECU's watchdog zeroes the valves
        runner.stop(1.0)
        bus.shutdown()


def add_commands(sub) -> None:
    a = sub.add_parser("accuracy-test", help="the thesis's field accuracy test (tables 3-8 … 3-10) on the twin")
    a.add_argument("--sim-truth", default=None, metavar="FILE", help="the twin's true machine (hitch sim perturb)")
    a.add_argument(
        "--instrument",
        choices=tuple(INSTRUMENTS),
        default="tape",
        type=lambda t: "total-station" if t == "station" else t,  # sim measure's and measure-twin's spelling too
        help="tape ±10 mm (default), total-station (or station) σ 1 mm / 1 mrad, none",
    )
    a.add_argument("--seed", type=whole_number("--seed"), default=0, help="seed of the instrument noise")
    a.add_argument(
        "--dofs",
        default="x,z,roll,pitch",
        help="the DOF to deflect (default all four, then the combined deflections; a subset: no combined ones)",
    )
    add_model_options(a)
    a.set_defaults(handler=_cmd_accuracy_test, on_interrupt=lambda _a: "nothing was written")


def add_calibrate_sensors(csub) -> None:
    """``hitch calibrate sensors`` (a sub-command of ``hitch calibrate``, :mod:`bridge.cli.calibrate`)."""
    s = csub.add_parser(
        "sensors", help="sensor calibration over the link: each cylinder to both end stops, fit the AD map"
    )
    s.add_argument(
        "--out", required=True, metavar="FILE", type=output_path, help="write the calibrated profile (TOML) here"
    )
    s.add_argument(
        "--force",
        action="store_true",
        help="write --out over a file that holds a calibration or a twin's truth (refused otherwise: it would be lost)",
    )
    s.add_argument("--sim-truth", default=None, metavar="FILE", help="the twin's true machine (hitch sim perturb)")
    s.add_argument(
        "--progress",
        default=None,
        metavar="FILE",
        type=output_path,
        help="progress file (JSON) to resume from / record to",
    )
    s.add_argument(
        "--actuators", default=None, help=f"comma-separated subset of {','.join(ACTUATOR_NAMES)} (default all)"
    )
    s.add_argument("--implement", default=None, help="implement record of the tractor profile (default: none)")
    s.add_argument(
        "--detached",
        action="store_true",
        help="procedure step the operator confirms: no implement attached, the top link unpinned at the mast "
        "(in its rest or removed); releases the top-link angle limits, keeps every other limit; not with --implement",
    )
    s.add_argument("--yes", action="store_true", help="confirm --detached without the interactive prompt")
    s.add_argument("--seed", type=whole_number("--seed"), default=0, help="seed of the simulated machine")
    s.add_argument(
        "--can-interface",
        default=None,
        choices=INTERFACES,
        help="calibrate the ECU on this CAN bus (a real machine, or hitch ecu-sim); default: the simulated twin",
    )
    s.add_argument("--can-channel", default=None, help="the bus's channel (e.g. can0, a hub's ws:// address)")
    add_model_options(s)
    add_realtime_option(s)
    s.set_defaults(handler=_cmd_calibrate_sensors, on_interrupt=_sensors_interrupted)
