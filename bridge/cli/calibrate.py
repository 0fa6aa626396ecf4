"""CLI commands ``hitch calibrate geometry``, ``hitch calibrate plan-poses`` and ``hitch calibrate measure-twin``.

``plan-poses --n N`` chooses the N poses to measure (D-optimal, :mod:`planner.calibration.design`) and
prints them with the nominal AD counts that hold them (``--out FILE.csv``: a measurement template).
``geometry --measurements FILE --out PROFILE`` calibrates the geometry (and the AD map) from a
measurement file (:mod:`planner.calibration.measurements`) and writes the calibrated profile with
its provenance. ``measure-twin`` makes a measurement file from the twin's true machine (a truth
file of ``hitch sim perturb``) for poses planned here, to try the procedure end to end.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bridge.cli.commissioning import add_calibrate_sensors
from bridge.cli.errors import CLIError
from bridge.cli.model import add_model_options, bounded_float, refuse_overwriting_profile, whole_number
from bridge.cli.output import output_path, p95_words
from bridge.link.sensor_calibration import SENSOR_PROVENANCE_MARKER
from bridge.service.wire import to_json_text
from bridge.sim.truth import noise_kind
from planner.calibration.measurements import APPROACH_COLUMN, TARGET_COLUMNS, load_plan_targets
from planner.calibration.solve import (
    IDENTIFIED_SHARE,
    OUTLIER_SIGMA,
    WEAKLY_IDENTIFIED_SHARE,
    identification_status,
)
from planner.errors import HitchInputError
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES

__all__ = ["add_commands"]


def _positive_int(name: str, hi: int):
    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be an integer in [1, {hi}], got {text!r}") from None
        if not 1 <= v <= hi:
            raise argparse.ArgumentTypeError(f"{name} must be an integer in [1, {hi}], got {v}")
        return v

    return parse


def _model(args, *, include_ad: bool = True, include_lag: bool = False, profile=None):
    from planner.calibration.parameters import ParameterSet
    from planner.calibration.parametric import ParametricModel
    from planner.profiles.hitch import load_profile

    prof = profile if profile is not None else load_profile(args.profile)
    params = ParameterSet.from_profile(prof, include_ad=include_ad, include_lag=include_lag)
    return ParametricModel(prof, args.category, params=params)


def _design(args, model):
    from planner.calibration.design import plan_poses

    two_sided = args.two_sided or (getattr(args, "by", None) == "goto" and getattr(args, "sides", None) == "both")
    return plan_poses(
        model, args.n, candidates=args.candidates, seed=args.seed, points=args.points, two_sided=two_sided
    )


def _cmd_plan(args) -> int:
    from planner.model.sensors import SensorScaling

    if args.out is not None and not args.force:
        _refuse_overwriting_measurements(Path(args.out))
    model = _model(args, include_ad=not args.no_ad)
    d = _design(args, model)
    sc = SensorScaling(model.profile)
    counts = np.rint(sc.counts_min + (d.actuators - sc.si_min) / sc.resolution).astype(int)
    rows: list[dict[str, Any]] = [
        {
            "pose": f"p{k + 1}",
            **dict(zip(CONTROLLED_POSE_NAMES, map(float, d.poses[k]), strict=True)),
            **{f"{n}_counts": int(c) for n, c in zip(ACTUATOR_NAMES, counts[k], strict=True)},
        }
        for k in range(d.poses.shape[0])
    ]
    if args.out is not None:
        _write_plan_csv(Path(args.out), rows, _template_sides(model.profile, args.two_sided), points=args.points)
    if args.json:
        print(
            to_json_text(
                {
                    "poses": rows,
                    "log_det": d.log_det,
                    "identifiable": d.identifiable,
                    "rank": d.rank,
                    "determined": d.determined,
                    "candidates": d.candidates,
                }
            )
        )
    else:
        print(
            f"{len(rows)} pose{'' if len(rows) == 1 else 's'} (D-optimal over {d.candidates} candidates; of the "
            f"{d.identifiable} parameter directions the workspace can identify they separate {d.rank} and determine "
            f"{d.determined} well enough for the calibration, which keeps the rest at nominal)"
        )
    _warn_if_too_few(d, "plan-poses")
    if args.json:
        return 0
    for r in rows:
        print(
            f"{r['pose']:>4}: x {1e3 * r['x']:7.1f} mm  z {1e3 * r['z']:7.1f} mm  roll {1e3 * r['roll']:6.1f} mrad  "
            f"pitch {1e3 * r['pitch']:6.1f} mrad   counts "
            + " ".join(f"{n} {r[f'{n}_counts']}" for n in ACTUATOR_NAMES)
        )
    return 0


def _warn_if_too_few(d, command: str) -> None:
    """On stderr: the planned poses ``d`` cannot separate every direction the workspace can identify."""
    if d.rank < d.identifiable:
        print(
            f"hitch calibrate {command}: warning: {d.poses.shape[0]} pose{'' if d.poses.shape[0] == 1 else 's'} can "
            f"separate only {d.rank} of the "
            f"{d.identifiable} parameter directions the workspace can identify, whatever is measured; a "
            f"calibration from them keeps at least {d.identifiable - d.rank} more combinations at nominal: "
            "plan more poses (--n)",
            file=sys.stderr,
        )


def _warn_if_approach_cut(model, poses: np.ndarray, labels: Sequence[str], args) -> None:
    """On stderr: the poses whose gotos (``--by goto``) find less room than the final approach before a face
    from a side they are measured from (a plan of one side measured from both: plan-poses --two-sided)."""
    from planner.calibration.design import approach_shortfalls

    fa = model.profile.motion.final_approach
    if args.by != "goto" or fa is None:
        return
    sides = _template_sides(model.profile, args.sides == "both")
    short = approach_shortfalls(model, poses, sides)
    if not short:
        return
    unit = {"x": ("mm", 1e3), "z": ("mm", 1e3), "roll": ("mrad", 1e3), "pitch": ("mrad", 1e3)}
    listed = ", ".join(
        f"{labels[s.row]} {s.dof} from {s.side} ({s.room * unit[s.dof][1]:.1f} of {s.offset * unit[s.dof][1]:.1f} "
        f"{unit[s.dof][0]})"
        for s in short[:6]
    )
    more = f" and {len(short) - 6} more" if len(short) > 6 else ""
    hint = " (plan-poses --two-sided plans room at both faces)" if args.sides == "both" else ""
    print(
        f"hitch calibrate measure-twin: warning: {len({s.row for s in short})} of {len(poses)} poses lie nearer a "
        f"workspace face than the final approach: {listed}{more}; their approach is cut short and may leave the pin "
        f"play partly taken up, which biases the fit{hint}",
        file=sys.stderr,
    )


def _template_sides(profile, two_sided: bool) -> tuple[str, ...]:
    """The ``approach`` words of a measurement template's passes: the profile's final approach side (and its
    mirror image with ``two_sided``); none without a final approach."""
    fa = profile.motion.final_approach
    if fa is None:
        return ()
    other = "above" if fa.side == "below" else "below"
    return (fa.side, other) if two_sided else (fa.side,)


#: decimals of a template's target_* cells (m, rad): 1 µm / 1 µrad, far below any instrument's σ (repr wrote
#: 0.30116901999999995: a commissioning trial)
TARGET_DECIMALS = 6


def _target_cell(v: float) -> str:
    """A planned pose value [m or rad] as a template cell: fixed :data:`TARGET_DECIMALS` decimals, no "-0"."""
    return f"{round(float(v), TARGET_DECIMALS) + 0.0:.{TARGET_DECIMALS}f}"


#: the measurement columns of the marked points (L, R, U: x, y, z each), in a template planned with --points
POINT_COLUMNS = tuple(f"{p}_{c}" for p in ("L", "R", "U") for c in "xyz")


def _refuse_overwriting_measurements(path: Path) -> None:
    """CLIError when ``path`` exists and is not an empty template: a file with a measured value in any row (or
    one that is no measurement file) would be lost under a new template (a commissioning trial: plan-poses --out
    over the filled file replaced its measurements without a word). ``--force`` writes it all the same."""
    if not path.exists():
        return
    try:
        with path.open(encoding="utf-8-sig", newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError, csv.Error):
        rows = []
    measured = {*CONTROLLED_POSE_NAMES, *POINT_COLUMNS}
    head = [c.strip() for c in rows[0]] if rows else []
    cols = [k for k, c in enumerate(head) if c in measured]
    filled = [n for n, row in enumerate(rows[1:], start=1) if any(k < len(row) and row[k].strip() for k in cols)]
    if cols and not filled:
        return  # a template with nothing measured yet: written over
    why = (
        f"it holds measured values (row {filled[0]}{f' and {len(filled) - 1} more' if len(filled) > 1 else ''})"
        if filled
        else "it is no measurement template"
    )
    raise CLIError(f"--out {path} exists and {why}: a new template would replace it; write to another file, or --force")


def _write_plan_csv(
    path: Path, rows: list[dict[str, Any]], sides: tuple[str, ...] = (), *, points: bool = False
) -> None:
    """The measurement template: label, the planned nominal counts (to be replaced by the readings at rest),
    the measured pose empty (the operator fills it in), with ``points`` the marked points' columns ``L_x … U_z``
    empty too (a --points plan's template had none), the planned pose as ``target_*`` (m, rad) and, with
    ``sides``, the ``approach`` column: one pass over the poses per side (a goto of the profile as it is, then
    one with its final approach's ``side`` flipped)."""
    measured = [*CONTROLLED_POSE_NAMES, *(POINT_COLUMNS if points else ())]
    header = ["pose", *(f"{n}_counts" for n in ACTUATOR_NAMES), *measured, *TARGET_COLUMNS]
    header += [APPROACH_COLUMN] if sides else []
    lines = [",".join(header)]
    for side in sides or ("",):
        for r in rows:
            targets = [_target_cell(r[k]) for k in CONTROLLED_POSE_NAMES]
            cells = [r["pose"], *(str(r[f"{n}_counts"]) for n in ACTUATOR_NAMES), *([""] * len(measured)), *targets]
            lines.append(",".join(cells + ([side] if sides else [])))
    try:
        path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    except OSError as exc:
        raise CLIError(f"--out {path}: cannot write it ({exc.strerror})") from None


def _sensor_record(profile: str) -> str | None:
    """The ``#! sensor_calibration`` line of a profile file (a sensor calibration wrote it), or None."""
    path = Path(profile)
    if not path.is_file():
        return None
    lines = path.read_text(encoding="utf-8").splitlines()
    return next((line for line in lines if line.startswith(SENSOR_PROVENANCE_MARKER)), None)


def _cmd_geometry(args) -> int:
    from planner.calibration.measurements import load_measurements
    from planner.calibration.parameters import CalibrationError
    from planner.calibration.profile_out import write_calibrated_profile
    from planner.calibration.solve import (
        build_calibration_problem,
        check_residual_dof,
        largest_residuals,
        outlying_rows,
        solve_calibration,
    )
    from planner.profiles.hitch import load_profile

    prof = load_profile(args.profile)
    refuse_overwriting_profile(args.out, args.profile, force=args.force)
    if not args.profile_given:
        print(
            f"hitch: note: no --profile: calibrating the built-in profile {args.profile} (give --profile with your "
            "tractor's file, the one the poses were measured with)",
            file=sys.stderr,
        )
    sensors = _sensor_record(args.profile)
    if sensors is None and args.no_ad:
        print(
            f"hitch: note: --no-ad keeps the AD maps of {args.profile}, which records no sensor calibration: they "
            "are its nominal maps (calibrate the sensors first: hitch calibrate sensors)",
            file=sys.stderr,
        )
    if sensors is not None and not args.no_ad:
        print(
            f"hitch: warning: {args.profile} carries a sensor calibration (its AD maps were measured at the end "
            f"stops: its {SENSOR_PROVENANCE_MARKER} line); fitting the AD maps from the poses replaces them: give "
            "--no-ad to keep them",
            file=sys.stderr,
        )
    data = load_measurements(args.measurements, prof)
    _warn_copies(args.measurements, data)
    # the lag of the pin play: found where rows name both approach sides and the planner can compensate it
    include_lag = data.two_sided and prof.motion.final_approach is not None and not args.no_lag
    model = _model(args, include_ad=not args.no_ad, include_lag=include_lag, profile=prof)
    problem = build_calibration_problem(
        model, data, sigma_position_m=1e-3 * args.sigma_position_mm, sigma_angle_rad=1e-3 * args.sigma_angle_mrad
    )
    try:
        result = solve_calibration(problem, min_singular=args.min_singular, tape_prior=not args.no_tape_prior)
        check_residual_dof(result, data)  # too few spare values to check the fit: refused, nothing written
    except CalibrationError as exc:  # "measurements: …" names the file the engineer gave
        raise CalibrationError(f"{args.measurements}: {str(exc).removeprefix('measurements: ')}") from None
    sides = data.side_vector
    if data.sided and not data.two_sided and prof.motion.final_approach is not None:
        print(
            f"hitch: note: {args.measurements}: every row from one side ({'below' if sides.min() < 0 else 'above'}): "
            "the lag of the pin play cannot be told from the geometry and is not fitted; the geometry takes it up "
            "in part (measure each pose from both sides, measure-twin --sides both, to find it: docs/commissioning.md)",
            file=sys.stderr,
        )
    elif data.sided and prof.motion.final_approach is None and np.sum(sides < 0) == np.sum(sides > 0):
        print(
            f"hitch: note: {args.measurements} names approach sides, but {args.profile} has no "
            "motion.final_approach: the lag of the pin play is not fitted (as many rows from each side average it "
            "out of the geometry); to find it and have the planner aim by it, give the profile a "
            "[motion.final_approach], measure each pose by goto from both sides with it (measure-twin --by goto "
            "--sides both) and fit with it as --profile (docs/commissioning.md)",
            file=sys.stderr,
        )
    elif data.sided and not include_lag and np.sum(sides < 0) != np.sum(sides > 0):  # as many each side: averages
        print(
            f"hitch: warning: {args.measurements} names approach sides, more rows from one side than from the other, "
            f"but {args.profile} has no motion.final_approach: the lag of the pin play is not fitted (the planner "
            "compensates it only where a goto ends with its final approach) and biases the geometry; measure each "
            "pose from both sides, or add the final approach to the profile",
            file=sys.stderr,
        )
    inputs = {
        "measurements": str(args.measurements),
        "measurements_sha256": hashlib.sha256(Path(args.measurements).read_bytes()).hexdigest(),
        "profile": str(args.profile),
        # which file it was (a commissioning trial: a path alone does not say the file was not edited since)
        **(
            {"profile_sha256": hashlib.sha256(Path(args.profile).read_bytes()).hexdigest()}
            if Path(args.profile).is_file()
            else {}
        ),
        "sigma_position_m": 1e-3 * args.sigma_position_mm,
        "sigma_angle_rad": 1e-3 * args.sigma_angle_mrad,
        "min_singular": float(args.min_singular),
        "ad_map": "kept (--no-ad)" if args.no_ad else "fitted",
        "prior": "none (--no-tape-prior)"
        if args.no_tape_prior
        else "tape: each geometry and AD-map parameter uniform within ± its scale of the profile's value (lag: none)",
    }
    carried = (sensors,) if sensors is not None and args.no_ad else ()  # the maps it records are kept as they were
    short, noisy, negative_only = _approach_shorter_than_play(prof, result)
    doubts = _implausible_fit(args, model.params, problem, result)
    misfit = (result.residual_sigma > SUSPECT_SIGMA_HAT or bool(doubts)) and not args.accept_misfit
    if result.residual_sigma > SUSPECT_SIGMA_HAT and args.accept_misfit:  # recorded in the profile's provenance
        inputs["misfit_accepted"] = f"sigma-hat {result.residual_sigma:.3g} (--accept-misfit)"
    if doubts and args.accept_misfit:
        inputs["implausible_accepted"] = [f"{d} (--accept-misfit)" for d in doubts]
    # one bad cell hides in a good sigma-hat: its row is named on stderr and recorded in the provenance (a trial: the
    # written profile kept no trace of the warning)
    outliers = outlying_rows(problem, result) if result.residual_sigma <= SUSPECT_SIGMA_HAT else []
    if outliers:
        inputs["rows_beyond_outlier_sigma"] = [f"row {r} ({label}) {col} {v:+.1f} σ" for r, label, col, v in outliers]
    predicted = _predicted_p95(model, result)
    if not short and not misfit:
        write_calibrated_profile(
            args.out, model.params, result, name=args.name, inputs=inputs, comments=carried, predicted=predicted
        )
    worst = largest_residuals(problem, result)
    rows = ", ".join(f"row {r} ({label}) {col} {v:+.1f} σ" for r, label, col, v in worst)
    misfit_text = (
        f"sigma-hat {result.residual_sigma:.3g}: the residuals are {result.residual_sigma:.3g} times the σ given "
        f"(--sigma-position-mm {args.sigma_position_mm:g}, --sigma-angle-mrad {args.sigma_angle_mrad:g}): a wrong "
        "value, a unit slip (mm or degrees in a column of m or rad), a sign or left/right slip, or a σ too small for "
        f"the instrument (a tape: --sigma-position-mm 5.8 --sigma-angle-mrad 11.5); worst fit: {rows}"
    )
    if result.residual_sigma > SUSPECT_SIGMA_HAT and args.accept_misfit:  # said on stderr, also with --json
        print(f"hitch: warning: {misfit_text}; written as asked (--accept-misfit)", file=sys.stderr)
    elif outliers:  # sigma-hat is fine (outliers are looked for only then)
        listed = ", ".join(f"row {r} ({label}) {col} {v:+.1f} σ" for r, label, col, v in outliers[:6])
        more = f" and {len(outliers) - 6} more" if len(outliers) > 6 else ""
        print(
            f"hitch: warning: {args.measurements}: {listed}{more}: beyond {OUTLIER_SIGMA:g} σ of the fit although "
            f"sigma-hat is {result.residual_sigma:.3g}: check these cells for a wrong value or a slip (the fit "
            "takes them in as they are)",
            file=sys.stderr,
        )
    if result.residual_sigma < 1.0 / SUSPECT_SIGMA_HAT:  # σ far too large: written, but said (also with --json)
        print(f"hitch: warning: {_overstated_sigma_text(args, result)}", file=sys.stderr)
    if args.json:
        largest = [{"row": r, "label": label, "column": col, "residual_sigma": v} for r, label, col, v in worst]
        written = None if short or misfit else str(args.out)
        print(
            to_json_text({"out": written, **result.as_dict(), "largest_residuals": largest, "predicted_p95": predicted})
        )
    else:
        _print_fit(model, result)
        _print_predicted(predicted)
    if doubts and args.accept_misfit:
        print(f"hitch: warning: {'; '.join(doubts)}; written as asked (--accept-misfit)", file=sys.stderr)
    if misfit:  # after the report: the fit is shown, the profile is not written
        why = misfit_text if result.residual_sigma > SUSPECT_SIGMA_HAT else "; ".join(doubts)
        raise CLIError(
            f"{args.out} not written: {why}; check the measurements, or give the instrument's σ; to write "
            "it all the same: --accept-misfit"
        )
    if short:
        noise = (
            "; each lies within twice its std of that half, so the instrument's noise alone may put it there: with "
            "a coarse instrument (a tape) keep the profile's lag instead (--no-lag; both sides then average the "
            "play out of the geometry), or measure with a finer one"
            if noisy
            else ""
        )
        if negative_only:  # below zero: a longer approach does not help
            raise CLIError(
                f"{args.out} not written: {'; '.join(short)}: keep the profile's lag instead (--no-lag; both sides "
                "then average the play out of the geometry), or measure with a finer instrument (docs/commissioning.md)"
            )
        raise CLIError(
            f"{args.out} not written: {'; '.join(short)}: if the approach is shorter than the play band, the data "
            "cannot show the whole lag (it ends near half the approach) and the poses may hold the play on either "
            f"side: raise these offsets of [motion.final_approach] in {args.profile} well above twice the lag "
            f"and measure again{noise} (docs/commissioning.md)"
        )
    if not args.json:
        print(f"wrote {args.out}")
    return 0


#: a parameter the fit moves further than this many tape sizes (its scale: the tape error the profile's value
#: may have) from the profile's value is not a tape error: the measurements do not fit the profile
FAR_TAPE_SIZES = 5.0
#: a row's residual beyond this many σ is a wrong cell, not noise (5…10 σ: warned, the fit stands)
WRONG_CELL_SIGMA = 10.0
#: a fitted lag below zero by more than this many of its std: the rows' approach sides are swapped
NEGATIVE_LAG_STD = 3.0


def _implausible_fit(args, params, problem, result) -> list[str]:
    """Why a fit that passed sigma-hat cannot be the machine (each a phrase; empty: none): a parameter moved
    more than :data:`FAR_TAPE_SIZES` tape sizes (a commissioning trial: z measured from the ground with a
    generous σ moved lift_arm_pivot[2] 15 tape sizes, sigma-hat 2.9, and wrote a profile no command loads), a row
    beyond :data:`WRONG_CELL_SIGMA` σ (a row with its left and right counts swapped, 22 σ, was written with a
    warning), a lag of the pin play below zero by more than :data:`NEGATIVE_LAG_STD` std (the approach column's
    below and above swapped: −6 σ in pitch, written without a word; the play can only leave the implement behind
    the mechanism)."""
    from planner.calibration.solve import outlying_rows

    out: list[str] = []
    # how far the measurements alone move each parameter (the least squares): the tape prior pulls it back toward
    # the profile's value and hid a truth 6 tape sizes off (4.8 with the prior, 6.3 without: a review)
    values = result.values if result.values_least_squares is None else result.values_least_squares
    moved = (values - result.nominal) / result.scale
    # the tape-measured values only: a lag of the pin play is not measured with a tape (its own check: at most half
    # the approach); 6 mm of play fitted right was refused as "6.0 tape sizes" (a review)
    taped = [not n.startswith("lag.") for n in result.names]
    far = [i for i in np.argsort(-np.abs(moved)) if taped[i] and abs(moved[i]) > FAR_TAPE_SIZES]
    if far:
        by = " by the measurements alone (least squares)" if result.tape_prior else ""
        words = ", ".join(
            f"{result.names[i]} moved {moved[i]:+.1f} tape sizes{by} "
            f"({_si(values[i] - result.nominal[i], params, i)}, its tape size "
            f"{_si(result.scale[i], params, i, sign=False)}"
            + (f"; {(result.values[i] - result.nominal[i]) / result.scale[i]:+.1f} with the tape prior" if by else "")
            + ")"
            for i in far[:3]
        )
        out.append(
            f"{words} from the value in {args.profile}: a tape-measured value is not that far off; the measurements "
            "do not fit the profile (a column measured from another origin, e.g. z from the ground; a unit or sign "
            "slip) or that value of the profile is wrong (measure it again; an AD map: hitch calibrate sensors)"
        )
    wrong = outlying_rows(problem, result, WRONG_CELL_SIGMA)
    if wrong:
        listed = ", ".join(f"row {r} ({label}) {col} {v:+.1f} σ" for r, label, col, v in wrong[:4])
        more = f" and {len(wrong) - 4} more" if len(wrong) > 4 else ""
        out.append(
            f"{args.measurements}: {listed}{more} beyond {WRONG_CELL_SIGMA:g} σ of the fit: a wrong cell, not noise "
            "(a swapped pair of counts, a typing slip); correct or delete the row"
        )
    for i in params.lag_index:
        lag, std = float(result.values[i]), float(result.std_total[i])  # with a weakly seen part's tape prior
        if std > 0.0 and lag < -NEGATIVE_LAG_STD * std:
            out.append(
                f"the fitted {result.names[i]} = {_si(lag, params, i)} ± {_si(std, params, i, sign=False)} is below "
                f"zero by {-lag / std:.1f} std: the pin play can only leave the implement behind the mechanism; are "
                "below and above swapped in the approach column?"
            )
    return out


def _si(value: float, params, i: int, *, sign: bool = True) -> str:
    """``value`` of parameter ``i`` in mm, mrad or as a number (the unit of the parameter: m, rad, 1)."""
    unit = params.parameters[i].unit
    scaled, shown = (1e3 * value, " mm") if unit == "m" else (1e3 * value, " mrad") if unit == "rad" else (value, "")
    return f"{scaled:+.3g}{shown}" if sign else f"{scaled:.3g}{shown}"


def _overstated_sigma_text(args, result) -> str:
    """What a sigma-hat far below 1 means (the σ given are far larger than the measurements' scatter): how many
    times less they scatter, what is judged with the σ given, the residual RMS (mm / mrad) and the options to set.
    A total station's data fitted with a tape's σ (5.8 mm / 11.5 mrad) gave sigma-hat 0.14 without a word and
    kept 4 more directions at nominal than its own σ (a commissioning trial); small residuals are not wrong data,
    so it is a warning: the profile is written as with any good fit."""
    s = result.residual_sigma
    times = f"{1.0 / s:.3g}" if s > 0.0 else "infinitely"
    return (
        f"sigma-hat {s:.3g}: the measurements scatter {times}× less than the σ given (--sigma-position-mm "
        f"{args.sigma_position_mm:g}, --sigma-angle-mrad {args.sigma_angle_mrad:g}; residual RMS "
        f"{1e3 * result.residual_rms_position_m:.3f} mm / {1e3 * result.residual_rms_angle_rad:.3f} mrad); which "
        f"parameter directions are identified ({result.identified} of {len(result.names)}: --min-singular counts "
        "in units of the σ given) and the standard deviations are judged with those σ, so the fit may keep at "
        "nominal directions the data could identify: give the instrument's own σ (a total station: "
        "--sigma-position-mm 1 --sigma-angle-mrad 1) and fit again (small residuals are not wrong data: the fit "
        "itself stands)"
    )


def _warn_copies(source, data) -> None:
    """On stderr: the rows of ``data``'s file that repeat an earlier row exactly (a copied row), counted once."""
    for row, earlier in data.copies[:5]:
        print(f"hitch: warning: {source}: row {row} repeats row {earlier}: counted once", file=sys.stderr)
    if len(data.copies) > 5:
        print(
            f"hitch: warning: {source}: {len(data.copies) - 5} more rows repeat earlier rows: counted once",
            file=sys.stderr,
        )


def _approach_shorter_than_play(prof, result) -> tuple[list[str], bool, bool]:
    """The DOF whose fitted lag is at least half the profile's final approach there (the profile refuses such a
    lag: an approach shorter than the play band 2·|lag| may not take the play up), as ``lag.x = … ± std, more
    than half of motion.final_approach.x = …`` phrases in mm / mrad; and whether every one of them lies within
    two of its standard deviations of that half (the instrument's noise, not the approach, may be the cause); and
    whether every one of them is below zero (a longer approach does not mend those)."""
    fa = prof.motion.final_approach
    if fa is None:
        return [], False, False
    out, noisy, negative = [], True, []
    for k, off in zip(CONTROLLED_POSE_NAMES, fa.offset(), strict=True):
        name = f"lag.{k}"
        if name not in result.names or off <= 0:
            continue
        i = list(result.names).index(name)
        lag, std = float(result.values[i]), float(result.std_total[i])
        if 2.0 * abs(lag) > off + 1e-12:
            unit = "mm" if k in ("x", "z") else "mrad"
            if lag < 0.0:  # the play cannot lead (a re-run read "more than half the approach … raise these offsets"
                # for lag.x = -1.252 ± 0.887 mm of tape data): the instrument's noise, or the sides swapped
                why = (
                    "the instrument's noise, not the play"
                    if abs(lag) - 2.0 * std <= off / 2.0
                    else f"{-lag / std:.1f} std below zero: are below and above swapped in the approach column?"
                )
                out.append(
                    f"the fitted {name} = {1e3 * lag:.3f} ± {1e3 * std:.3f} {unit} is below zero (the play can only "
                    f"leave the implement behind) by more than half motion.final_approach.{k} = {1e3 * off:.3f} "
                    f"{unit}: {why}"
                )
                negative.append(name)
                continue
            out.append(
                f"the fitted {name} = {1e3 * lag:.3f} ± {1e3 * std:.3f} {unit} is more than half "
                f"motion.final_approach.{k} = {1e3 * off:.3f} {unit}"
            )
            noisy = noisy and abs(lag) - 2.0 * std <= off / 2.0
    return out, noisy and bool(out), bool(out) and len(negative) == len(out)


def _print_fit(model, result) -> None:
    """The fit's report: residuals, the parameters with their spread, what the poses cannot identify."""
    print(
        f"calibrated {model.profile.name} from {result.n_poses} pose{'' if result.n_poses == 1 else 's'} "
        f"({result.n_observations} values) in "
        f"{result.duration_s:.2f} s: residual RMS {1e3 * result.residual_rms_position_m:.3f} mm / "
        f"{1e3 * result.residual_rms_angle_rad:.3f} mrad (nominal {1e3 * result.residual_rms_nominal_position_m:.3f}"
        f" mm / {1e3 * result.residual_rms_nominal_angle_rad:.3f} mrad), sigma-hat {result.residual_sigma:.3g}"
    )
    prior = (
        "weighed with the tape measure's accuracy (each parameter within ± its scale; --no-tape-prior: plain least "
        "squares)"
        if result.tape_prior
        else "plain least squares (--no-tape-prior)"
    )
    print(
        f"{result.identified} of {len(result.names)} parameter directions identified, {prior}; parameters "
        "(value ± std):"
    )
    units = ["" if p.unit == "1" else p.unit for p in model.params.parameters]  # AD gains: dimensionless
    for n, a, v, s, u, share in zip(
        result.names, result.nominal, result.values, result.std_total, units, result.identified_share, strict=True
    ):
        print(f"  {n:36s} {v:+.6f} {u:3s} (nominal {a:+.6f}) {_spread(s, u, share)}")
    share = result.identified_share
    if np.any((share >= REPORTED_STD_SHARE) & (share < IDENTIFIED_SHARE)):
        print(
            "  * partly identified: the share of the parameter the poses identify; its std includes the tape error "
            "(σ = scale/√3) of the part they cannot identify"
        )
    if np.any(share < REPORTED_STD_SHARE):  # the words the profile's record lists them under
        print(
            "  not identified: kept at nominal, no std (the profile's record: not_identified); weakly identified: "
            f"under {100 * REPORTED_STD_SHARE:.0f} % identified, σ mostly its tape error (record: weakly_identified)"
        )
    if result.unidentifiable:
        print("combinations these poses cannot identify (left at nominal along them):")
        for u in result.unidentifiable:
            print(f"  {u}")


def _cmd_check(args) -> int:
    """Fresh measurements against a profile, nothing refitted (``calibrate check``): exit 0 when they fit
    within the instrument's σ (sigma-hat ≤ :data:`SUSPECT_SIGMA_HAT`), 1 when not."""
    from planner.calibration.measurements import MEASURED_COLUMNS, load_measurements
    from planner.calibration.profile_out import read_calibration_provenance
    from planner.calibration.solve import build_calibration_problem, largest_residuals
    from planner.profiles.hitch import load_profile

    prof = load_profile(args.profile)
    data = load_measurements(args.measurements, prof)  # counts through this profile's AD map
    fa = prof.motion.final_approach
    # the profile's own lag of the pin play shifts a pose by its side (rows that name one)
    model = _model(args, include_ad=False, include_lag=fa is not None and fa.lag is not None, profile=prof)
    problem = build_calibration_problem(
        model, data, sigma_position_m=1e-3 * args.sigma_position_mm, sigma_angle_rad=1e-3 * args.sigma_angle_mrad
    )
    y, _ = model.batch(data.readings, None, jacobian=False, seeds=problem.seeds, sides=data.side_vector)
    diff = np.where(data.mask, np.nan_to_num(data.values) - y, np.nan)  # measured − the profile's model
    z = diff / problem.sigma
    sigma_hat = float(np.sqrt(np.nanmean(z**2)))
    per_column = {}
    for k, col in enumerate(MEASURED_COLUMNS):
        d = diff[:, k][np.isfinite(diff[:, k])]
        if d.size:
            per_column[col] = {"rms": float(np.sqrt(np.mean(d**2))), "max_abs": float(np.max(np.abs(d))), "n": d.size}
    worst = [
        {"row": row, "label": label, "column": col, "residual_sigma": v}
        for row, label, col, v in largest_residuals(problem, model.params.nominal)
    ]
    fits = sigma_hat <= SUSPECT_SIGMA_HAT
    prov = read_calibration_provenance(args.profile) if Path(args.profile).is_file() else None
    predicted = ((prov or {}).get("predicted_p95") or {}).get("calibrated")
    if args.json:
        print(
            to_json_text(
                {
                    "profile": str(args.profile),
                    "measurements": str(args.measurements),
                    "rows": len(data.labels),
                    "sigma_hat": sigma_hat,
                    "fits": fits,
                    "residuals": per_column,  # SI: m, rad
                    "worst_rows": worst,
                    "predicted_p95": predicted,
                }
            )
        )
        return 0 if fits else 1
    angle = {"roll", "pitch", "yaw"}
    unit = {c: ("mrad" if c in angle else "mm") for c in per_column}
    print(
        f"{args.measurements}: {len(data.labels)} rows against {prof.name} ({args.profile}), nothing refitted; "
        "measured − the profile's model, RMS / largest:"
    )
    for c, st in per_column.items():
        print(f"  {c:8s} {1e3 * st['rms']:.3f} / {1e3 * st['max_abs']:.3f} {unit[c]}  ({st['n']} values)")
    if predicted:
        print(
            f"the profile predicts p95 {p95_words(predicted)} (geometry only); the instrument's σ adds to the residuals"
        )
    rows = ", ".join(f"row {w['row']} ({w['label']}) {w['column']} {w['residual_sigma']:+.1f} σ" for w in worst)
    given = f"--sigma-position-mm {args.sigma_position_mm:g}, --sigma-angle-mrad {args.sigma_angle_mrad:g}"
    if fits:
        print(f"fits: sigma-hat {sigma_hat:.3g} (the residuals in units of the σ given: {given}); worst: {rows}")
        return 0
    print(
        f"DOES NOT FIT: sigma-hat {sigma_hat:.3g}: the residuals are {sigma_hat:.3g} times the σ given ({given}); "
        f"worst: {rows}. The machine is not what the profile says (calibrate it again: hitch calibrate geometry), "
        "or a measurement is wrong (a unit, a sign, left/right), or the σ is too small for the instrument",
        file=sys.stderr,
    )
    return 1


#: how many random workspace poses the predicted accuracy is taken over (as the calibration bench's evaluation)
PREDICTED_POSES = 200


def _predicted_p95(model, result) -> dict[str, dict[str, float]] | None:
    """The predicted p95 pose error over :data:`PREDICTED_POSES` random workspace poses of the calibrated profile
    and of the nominal (tape-measured) one (:mod:`planner.calibration.predicted`); None for a profile without a
    restricted workspace (no poses to predict at)."""
    from planner.calibration.design import candidate_poses
    from planner.calibration.predicted import calibrated_covariance, predict_accuracy, tape_covariance
    from planner.errors import HitchInputError

    fa = model.profile.motion.final_approach  # gotos end from its side: a fitted lag's error shows there
    side = 0.0 if fa is None else (1.0 if fa.side == "above" else -1.0)
    try:
        _, readings = candidate_poses(model, PREDICTED_POSES, seed=0, random_only=True)
        calibrated = predict_accuracy(model, result.values, calibrated_covariance(result), readings, side=side)
        nominal = predict_accuracy(model, result.nominal, tape_covariance(len(result.names)), readings, side=side)
    except HitchInputError:  # no workspace to predict at, or a fit the mechanism cannot close there (a review):
        return None  # the report and its refusals stand without it
    return {"calibrated": calibrated.as_dict(), "nominal": nominal.as_dict()}


def _print_predicted(predicted: dict[str, dict[str, float]] | None) -> None:
    """The report's predicted accuracy line (mm, mrad): is the profile good enough, and were the measurements?"""
    if predicted is None:
        return

    print(
        f"predicted pose error p95 over {PREDICTED_POSES} random workspace poses, from the parameters' σ: "
        f"{p95_words(predicted['calibrated'])} (a profile known to its tape sizes only, uncalibrated: "
        f"{p95_words(predicted['nominal'])}); "
        "the geometry's part only: the AD counts (about ±1.9 mm of z) and the pin play add to it "
        "(docs/commissioning.md)"
    )


#: sigma-hat (residuals in units of the σ given) above which the fit is reported as suspect
SUSPECT_SIGMA_HAT = 3.0
#: the identified share below which a parameter's std is not printed: it holds only with the unidentified
#: combinations at nominal, and a commissioning trial read "± 0.009 mm" of a value 54 std off the truth
REPORTED_STD_SHARE = WEAKLY_IDENTIFIED_SHARE


def _spread(std: float, unit: str, share: float) -> str:
    """A parameter's ± std as it can be read (:attr:`CalibrationResult.identified_share`): no std for one
    the data cannot see (its std would print as ~1e-18), a conditional one for one they see in part."""
    status = identification_status(share)  # the words of the profile's record too
    if status == "not identified":
        return "not identified (kept nominal)"
    if status == "weakly identified":  # its conditional std (~1e-5 m) would read as known; it is not
        seen = "< 1" if share < 0.005 else f"{100 * share:.0f}"
        return (
            f"weakly identified ({seen} % identified: it moves only with the identified combinations it is part "
            f"of; σ {std:.2e}{' ' + unit if unit else ''}, mostly its tape error)"
        )
    text = f"± {std:.2e} {unit}".rstrip()
    if status == "partly identified":
        text += f", {100 * share:.0f} % identified*"
    return text


def _cmd_measure_twin(args) -> int:
    from bridge.sim.calibration_data import calibration_csv, measure_twin
    from bridge.sim.truth import load_machine_truth

    model = _model(args, include_ad=not args.no_ad)
    if args.by == "goto" and args.sides == "both" and model.profile.motion.final_approach is None:
        # named by the file given (a sensor-calibrated profile keeps its built-in name: "thesis-t132 has none …
        # give that profile with --profile" was read as --profile not taken, a commissioning trial)
        given = f"--profile {args.profile}" if getattr(args, "profile_given", False) else f"the built-in {args.profile}"
        raise CLIError(
            f"measuring from both sides by goto (--sides both) needs the profile's motion.final_approach, and "
            f"{given} has none: add [motion.final_approach] to it (docs/commissioning.md)"
        )
    if args.plan is not None:  # the poses of a plan file, under its labels
        labels, poses = load_plan_targets(args.plan)
    else:
        design = _design(args, model)
        _warn_if_too_few(design, "measure-twin")  # as plan-poses says it
        poses = design.poses
        labels = tuple(f"p{k + 1}" for k in range(poses.shape[0]))
    _warn_if_approach_cut(model, poses, labels, args)
    truth = load_machine_truth(args.sim_truth)
    points = ("L", "R", "U") if args.points else ()
    approach = None if args.sides is None else {"both": "both", "one": "direct"}[args.sides]
    data = measure_twin(
        model.nominal_model,
        truth,
        poses,
        noise=args.noise,
        points=points,
        seed=args.seed,
        by=args.by,
        approach=approach,  # type: ignore[arg-type]
    )
    per_pose = data.counts.shape[0] // poses.shape[0]
    if args.by == "static":  # each pose from below and from above, one after the other
        row_labels = [lab for lab in labels for _ in range(per_pose)]
    else:  # by goto: a pass over every pose per side
        row_labels = [lab for _ in range(per_pose) for lab in labels]
    text = calibration_csv(data, labels=row_labels)
    try:
        Path(args.out).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise CLIError(f"--out {args.out}: cannot write it ({exc.strerror})") from None
    if args.json:
        print(to_json_text({"out": str(args.out), "rows": int(data.counts.shape[0]), "poses": int(poses.shape[0])}))
    else:
        print(f"wrote {data.counts.shape[0]} measurements of {poses.shape[0]} poses to {args.out}")
    return 0


def _add_design_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--n", type=_positive_int("--n", 1000), default=20, help="poses to plan (default 20)")
    p.add_argument("--candidates", type=_positive_int("--candidates", 100_000), default=300, help="random candidates")
    p.add_argument(
        "--seed", type=whole_number("--seed"), default=0, help="seed of the candidates (and of the twin's noise)"
    )
    p.add_argument("--points", action="store_true", help="the instrument also measures the points L, R, U")
    p.add_argument(
        "--no-ad",
        action="store_true",
        help="plan for a fit that keeps the AD maps (calibrate geometry --no-ad, after calibrate sensors)",
    )
    p.add_argument(
        "--two-sided",
        action="store_true",
        help="plan poses to be measured by goto from both sides (each keeps the profile's motion.final_approach "
        "room at the lower and the upper faces); implied by measure-twin --by goto --sides both",
    )


#: the allowed --min-singular: below 0.1 a freed direction moves the fit by less than 0.1 σ per tape size, so
#: the noise carries it ten tape sizes and more (0.01 and 0 ended where the profile cannot close: a trial)
MIN_SINGULAR_RANGE = (0.1, 1e6)


def _min_singular(text: str) -> float:
    """argparse type of --min-singular: a number in :data:`MIN_SINGULAR_RANGE`, the error saying why."""
    try:
        return bounded_float("--min-singular", *MIN_SINGULAR_RANGE, lo_open=False)(text)
    except argparse.ArgumentTypeError as exc:
        raise argparse.ArgumentTypeError(
            f"{exc} (below {MIN_SINGULAR_RANGE[0]:g} the directions it frees move the fit by less than "
            f"{MIN_SINGULAR_RANGE[0]:g} σ per tape size: the noise would carry them far; default 1)"
        ) from None


def _profile_name(text: str) -> str:
    """``--name`` checked where it is read: 'my tractor' was refused only after the fit, as "the calibrated
    parameters do not make a valid profile" (a commissioning trial)."""
    from planner.profiles.loader import check_profile_name

    try:
        if not 1 <= len(text) <= 80:
            raise ValueError(f"must be 1 to 80 characters, got {len(text)}")
        return check_profile_name(text)
    except (HitchInputError, ValueError) as exc:
        raise argparse.ArgumentTypeError(f"{text!r}: {exc}") from None


def _add_sigma_options(p) -> None:
    """The instrument's σ of ``calibrate geometry`` and ``calibrate check`` (mm, mrad at this boundary)."""
    for flag, unit in (("--sigma-position-mm", "mm"), ("--sigma-angle-mrad", "mrad")):
        p.add_argument(
            flag,
            type=bounded_float(flag, 0.0, 1000.0, unit=unit),
            default=1.0,
            help=f"instrument σ, (0, 1000] {unit} (default 1)",
        )


def add_commands(sub) -> None:
    p = sub.add_parser("calibrate", help="geometry calibration: plan poses to measure, fit a profile to measurements")
    csub = p.add_subparsers(dest="calibrate_command", required=True, parser_class=type(p))
    add_calibrate_sensors(csub)

    g = csub.add_parser("geometry", help="calibrate the geometry from a measurement file, write a profile")
    add_model_options(g)
    g.add_argument("--measurements", required=True, help="measurement CSV (see docs/commissioning.md)")
    g.add_argument("--out", required=True, type=output_path, help="calibrated profile to write (.toml)")
    g.add_argument(
        "--force",
        action="store_true",
        help="write --out over a file that holds a calibration or a twin's truth (refused otherwise: it would be lost)",
    )
    g.add_argument(
        "--name",
        default=None,
        type=_profile_name,
        help="name of the calibrated profile: letters, digits, '-', '_', '.', up to 80 (default <profile>-calibrated)",
    )
    _add_sigma_options(g)
    g.add_argument(
        "--min-singular",
        type=_min_singular,
        default=1.0,
        help=f"smallest singular value of the scaled Jacobian still identified, [{MIN_SINGULAR_RANGE[0]:g}, "
        f"{MIN_SINGULAR_RANGE[1]:g}] (default 1)",
    )
    g.add_argument(
        "--no-tape-prior",
        action="store_true",
        help="plain least squares: do not weigh the identified directions with the tape measurement's own accuracy "
        "(each parameter within ± its scale of the profile's value; docs/commissioning.md)",
    )
    g.add_argument("--no-ad", action="store_true", help="keep the AD map (offsets, gains) at the profile's values")
    g.add_argument(
        "--no-lag",
        action="store_true",
        help="keep the profile's lag of the pin play (motion.final_approach.lag) rather than fit it from rows "
        "measured from both sides (an instrument too coarse to tell it)",
    )
    g.add_argument(
        "--accept-misfit",
        action="store_true",
        help=f"write the profile even when the residuals exceed {SUSPECT_SIGMA_HAT:g} times the σ given "
        "(sigma-hat; recorded in the profile)",
    )
    g.set_defaults(handler=_cmd_geometry, on_interrupt=lambda _a: "nothing was written")

    ck = csub.add_parser(
        "check",
        help="measurements against a profile, nothing refitted: does the profile fit them? (exit 1 when not)",
    )
    add_model_options(ck)
    ck.add_argument("--measurements", required=True, help="measurement CSV of new poses (docs/commissioning.md)")
    _add_sigma_options(ck)
    ck.set_defaults(handler=_cmd_check)

    pp = csub.add_parser("plan-poses", help="choose the poses to measure (D-optimal)")
    add_model_options(pp)
    _add_design_options(pp)
    pp.add_argument("--out", default=None, type=output_path, help="also write a measurement template CSV")
    pp.add_argument(
        "--force",
        action="store_true",
        help="write --out over a file that holds measured values (refused otherwise: they would be lost)",
    )
    pp.set_defaults(handler=_cmd_plan, on_interrupt=lambda _a: "nothing was written")

    m = csub.add_parser("measure-twin", help="measure the planned poses on the twin's true machine (CSV)")
    add_model_options(m)
    _add_design_options(m)
    m.add_argument("--sim-truth", required=True, help="truth profile (hitch sim perturb --out)")
    m.add_argument(
        "--noise",
        default="station",
        type=noise_kind,  # accuracy-test's spelling too
        choices=("tape", "station", "none"),
        help="instrument noise: tape ±10 mm, station (or total-station) 1 mm / 1 mrad, none (default station)",
    )
    m.add_argument("--out", required=True, type=output_path, help="measurement CSV to write")
    m.add_argument(
        "--plan",
        default=None,
        metavar="FILE",
        help="measure the poses of this plan file (plan-poses --out), under its labels; default: plan them here",
    )
    m.add_argument(
        "--by",
        default="static",
        choices=("static", "goto"),
        help="static: pistons at the whole counts, each pose approached from both sides (default); goto: real "
        "gotos of the profile's planner over CAN on the running twin (with its motion.final_approach), one row each",
    )
    m.add_argument(
        "--sides",
        default=None,
        choices=("one", "both"),
        help="from how many sides each pose is measured (default: both --by static, one --by goto); --by goto "
        "--sides both: a pass with the profile's final approach and one with its mirror image (side flipped), "
        "so that calibrate geometry finds the lag of the pin play (needs motion.final_approach)",
    )
    m.set_defaults(handler=_cmd_measure_twin, on_interrupt=lambda _a: "nothing was written")
