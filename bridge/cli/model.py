"""CLI commands on the kinematic model: ``demo``, ``fk``, ``profile show``, ``profile fit-workspace``."""

from __future__ import annotations

import argparse
import math
import re
import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from rich.table import Table

from bridge.cli.errors import CLIError
from bridge.cli.output import POSE_UNITS, console, esc, p95_words, signed
from bridge.cli.ranges import ACTUATOR_UNITS, check_actuators
from bridge.service.wire import to_json_text
from planner.model.kinematics import HitchModel
from planner.model.types import ACTUATOR_NAMES, POSE_NAMES

__all__ = [
    "add_commands",
    "finite_float",
    "bounded_float",
    "whole_number",
    "add_model_options",
    "model_from_args",
    "refuse_overwriting_profile",
]


#: a plain decimal number as the command line and the files take it: Python's ``float()`` also reads "1_000" as 1000
#: and full-width or other scripts' digits ("１") as digits (a fuzz trial: ``--z=１`` was taken as 1 m)
PLAIN_NUMBER = re.compile(
    r"\s*[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?\s*|\s*[+-]?(?:inf|infinity|nan)\s*", re.ASCII | re.IGNORECASE
)
#: what a number must look like, in errors
PLAIN_NUMBER_WORDS = "a plain decimal number such as 10, -0.5 or 1.5e-3: ASCII digits, no '_' or other separators"


def _converted(name: str, text: str, cast, what: str):
    """``cast(text)``, or the argparse error naming the option and what it must be."""
    try:
        return cast(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{name} must be {what}, got {text!r}") from None


def plain_number(name: str, text: str) -> float:
    """``text`` as a float when it is a :data:`PLAIN_NUMBER` (non-finite ones included: the caller says why
    those are refused), else the argparse error naming ``name``."""
    v = _converted(name, text, float, "a number")
    if not PLAIN_NUMBER.fullmatch(text):
        raise argparse.ArgumentTypeError(f"{name} must be {PLAIN_NUMBER_WORDS}, got {text!r}")
    return v


def finite_float(name: str):
    """argparse type: a finite float, with an error naming the option."""

    def parse(text: str) -> float:
        v = plain_number(name, text)
        if not math.isfinite(v):
            raise argparse.ArgumentTypeError(f"{name} must be finite, got {text!r}")
        return v

    return parse


def bounded_float(name: str, lo: float, hi: float, *, unit: str = "", lo_open: bool = True, hi_open: bool = False):
    """argparse type: a finite float in ``(lo, hi]`` (``[lo, …`` if not ``lo_open``, ``…, hi)`` if
    ``hi_open``), the error naming the option and the allowed range."""
    finite = finite_float(name)
    left, right = "(" if lo_open else "[", ")" if hi_open else "]"
    allowed = f"{left}{lo:g}, {hi:g}{right}{' ' + unit if unit else ''}"

    def parse(text: str) -> float:
        v = finite(text)
        above = (lo < v) if lo_open else (lo <= v)
        below = (v < hi) if hi_open else (v <= hi)
        if not (above and below):
            raise argparse.ArgumentTypeError(f"{name} must lie in {allowed}, got {text}")
        return v

    return parse


def bounded_int(name: str, lo: int, hi: int, *, unit: str = ""):
    """argparse type: a whole number in ``[lo, hi]``, the error naming the option and the allowed range."""
    allowed = f"[{lo}, {hi}]{' ' + unit if unit else ''}"

    def parse(text: str) -> int:
        n = _converted(name, text, int, f"a whole number in {allowed}")
        if not lo <= n <= hi:
            raise argparse.ArgumentTypeError(f"{name} must lie in {allowed}, got {text}")
        return n

    return parse


def whole_number(name: str):
    """argparse type: a whole number >= 0, the error naming the option and the allowed range."""

    def parse(text: str) -> int:
        n = _converted(name, text, int, "a whole number >= 0")
        if n < 0:
            raise argparse.ArgumentTypeError(f"{name} must be a whole number >= 0, got {text}")
        return n

    return parse


class _GivenProfile(argparse.Action):
    """``--profile``, and that it was given (``profile_given``): a command that writes a calibration says when it
    calibrates the built-in profile because none was given (a commissioning trial's tractor file was fitted as
    thesis-t132 without a word)."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        setattr(namespace, self.dest, values)
        namespace.profile_given = True


def add_model_options(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--profile",
        default="thesis-t132",
        action=_GivenProfile,
        help="built-in profile name or path to a .toml (default thesis-t132)",
    )
    p.set_defaults(profile_given=False)
    p.add_argument("--category", default=None, help="ISO 730 implement category (default: the profile's, 2)")
    p.add_argument("--json", action="store_true", help="print JSON")


def model_from_args(args) -> HitchModel:
    return HitchModel.from_profile(args.profile, args.category)


def _vec(v) -> list[float]:
    return [float(x) for x in np.asarray(v).reshape(-1)]


def state_to_json(state) -> dict:
    return {
        "pose": state.pose.as_dict(),
        "actuators": state.actuators.as_dict(),
        "points": {k: _vec(v) for k, v in state.points.items()},
        "link_angles": dict(zip(("theta_xl", "theta_zl", "theta_xr", "theta_zr"), state.link_angles, strict=True)),
        "top_link_angles": {"yaw": state.top_link_angles[0], "pitch": state.top_link_angles[1]},
        "lower_span": state.lower_span,
    }


#: what each ``hitch fk`` actuator flag is (help text and error messages)
_ACTUATOR_LABELS = {
    "lift": "lift-arm angle theta_E",
    "tilt": "tilt cylinder length",
    "top": "top link length",
    "left": "left sway limiter length",
    "right": "right sway limiter length",
}


def _cmd_fk(args) -> int:
    model = model_from_args(args)
    q = np.array([args.lift, args.tilt, args.top, args.left, args.right])
    check_actuators(q, model.lower, model.upper, _ACTUATOR_LABELS)  # every flag off its stroke, before FK
    state = model.forward(q)
    warnings = _fk_warnings(model, q, state)
    if args.json:
        print(to_json_text({**state_to_json(state), "warnings": warnings}))
        return 0
    c = console()
    p = state.pose
    c.print(
        f"pose: x={signed(p.x, 4)} m  y={signed(p.y, 4)} m  z={signed(p.z, 4)} m  roll={signed(p.roll, 4)} rad  "
        f"pitch={signed(p.pitch, 4)} rad  yaw={signed(p.yaw, 4)} rad"
    )
    c.print(
        f"lower span |L-R| = {state.lower_span:.4f} m (implement: {model.span:.4f} m); "
        f"top-link angles yaw={state.top_link_angles[0]:+.4f} pitch={state.top_link_angles[1]:+.4f} rad"
    )
    t = Table("point", "x [m]", "y [m]", "z [m]")
    for k, v in state.points.items():
        t.add_row(esc(k), *(f"{x:+.4f}" for x in v))
    c.print(t)
    for w in warnings:
        c.print(f"[yellow]warning:[/yellow] {esc(w)}")
    return 0


#: how far the lower links' ball span may differ from the implement's before fk says the pose cannot be taken [m]
FK_SPAN_TOLERANCE_M = 0.001


def _fk_warnings(model: HitchModel, q: np.ndarray, state) -> list[str]:
    """What makes the five lengths a pose no implement takes (an engineer's report: 51 mm of span mismatch and a
    top-link yaw beyond its limit came back without a word): the implement's span, the hard limits."""
    from planner.model.hard_limits import HardLimits

    out = []
    gap = state.lower_span - model.span
    if abs(gap) > FK_SPAN_TOLERANCE_M:
        out.append(
            f"not a pose the implement can take: the lower-link balls are {state.lower_span:.4f} m apart, the "
            f"implement's span is {model.span:.4f} m ({gap * 1000:+.1f} mm); the five lengths do not fit one another"
        )
    f, _ = model.features(q)
    bad = HardLimits.from_model(model).violations(q, f)
    if bad:
        out.append(f"beyond the hard limits: {', '.join(bad)}")
    return out


def neutral_warnings(model: HitchModel) -> list[str]:
    """What makes the category's neutral pose one the hitch cannot take: each hard limit it breaks, a stroke with
    the actuator, its value and the stroke (a new user's trial: ``profile show --category 4`` listed a neutral
    top link of 0.9728 m beside its 0.905 m stroke without a word). A category with a restricted workspace
    never loads so (:meth:`HitchModel._check_neutral`); one without may (the thesis profile's category 4: its
    1.1 m mast needs that top link at zero pitch)."""
    from planner.model.hard_limits import STROKE_NAMES, HardLimits

    q = model.neutral
    f, _ = model.features(q)
    out = []
    for name in HardLimits.from_model(model).violations(q, f):
        i = next((k for k, pair in enumerate(STROKE_NAMES) if name in pair), None)
        if i is None:
            out.append(f"the neutral pose of category {model.category} breaks {name}")
            continue
        n, unit = ACTUATOR_NAMES[i], ACTUATOR_UNITS[ACTUATOR_NAMES[i]]
        out.append(
            f"the neutral pose of category {model.category} needs {n} = {q[i]:.4f} {unit}, beyond its stroke "
            f"{model.lower[i]:g}..{model.upper[i]:g} {unit} ({name}): the hitch cannot take this pose"
            + ("; the category has no restricted workspace (no Cartesian motion)" if model.workspace is None else "")
        )
    return out


def profile_summary(model: HitchModel) -> dict:
    prof = model.profile
    return {
        "profile": prof.name,
        "description": prof.description,
        "category": model.category,
        "categories": list(prof.implement.categories),
        "span": model.span,
        "mast_height": model.mast_height,
        "strokes": {
            n: [float(lo), float(hi)] for n, lo, hi in zip(ACTUATOR_NAMES, model.lower, model.upper, strict=True)
        },
        "neutral_actuators": dict(zip(ACTUATOR_NAMES, _vec(model.neutral), strict=True)),
        "neutral_pose": model.neutral_pose.as_dict(),
        "top_link_reference": {
            "yaw": model.top_link_reference[0],
            "pitch": model.top_link_reference[1],
            "reference": prof.limits.top_link_angle_reference,
        },
        "limits": prof.limits.model_dump(),
        "pivot_height": prof.geometry.pivot_height,
        "thesis_box": {k: list(v) for k, v in model.thesis_box().items()},
        "z_reference": prof.workspace.z_reference,
        "workspace": None if model.workspace is None else {k: list(v) for k, v in model.workspace.items()},
        "motion": prof.motion.model_dump(mode="json"),
        "warnings": neutral_warnings(model),
    }


def check_workspace_reachable(model: HitchModel) -> None:
    """The check ``serve`` (its control core) and every planner make of the category's restricted box: each point
    of its 3⁴ grid reachable within the hard limits, else the :class:`PlanError` naming the box's face and the
    point and pointing at ``hitch profile fit-workspace`` (``profile show`` passed a box that ``serve`` and
    ``accuracy-test`` refused). Nothing to check for a category without a restricted box."""
    if model.workspace is None:
        return
    from planner.trajectory import TrajectoryPlanner

    TrajectoryPlanner(model)


def profile_records(profile: str) -> dict[str, Any]:
    """The commissioning records a profile file carries (its comment lines): ``calibration`` (a geometry
    calibration's provenance), ``sensor_calibration`` (a sensor calibration's); absent ones are left out; a
    built-in profile name has none."""
    from bridge.link.sensor_calibration import SENSOR_PROVENANCE_MARKER
    from planner.calibration.profile_out import read_calibration_provenance

    path = Path(profile)
    if not path.is_file():
        return {}
    out: dict[str, Any] = {}
    geometry = read_calibration_provenance(path)
    if geometry is not None:
        out["calibration"] = geometry
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith(SENSOR_PROVENANCE_MARKER):
            try:
                out["sensor_calibration"] = tomllib.loads("r =" + line[len(SENSOR_PROVENANCE_MARKER) :])["r"]
            except tomllib.TOMLDecodeError as exc:
                raise CLIError(f"{path}: its sensor_calibration line is not valid TOML: {exc}") from None
    return out


def _record_lines(records: Mapping[str, Any]) -> list[str]:
    """``profile show``'s words for :func:`profile_records` (a commissioning trial: the calibration a profile
    came from was only in its file's comment lines)."""
    out = []
    geo = records.get("calibration")
    if geo is not None:
        line = (
            f"geometry calibration: {geo.get('date')}, {geo.get('poses')} poses, residual RMS "
            f"{1e3 * float(geo.get('residual_rms_position_m', math.nan)):.3f} mm / "
            f"{1e3 * float(geo.get('residual_rms_angle_rad', math.nan)):.3f} mrad, "
            f"{geo.get('identified')} parameter directions identified, from {geo.get('nominal_profile')}"
        )
        pred = (geo.get("predicted_p95") or {}).get("calibrated")
        if pred:
            line += f"; predicted p95 {p95_words(pred)} (geometry only)"
        out.append(line)
    sensors = records.get("sensor_calibration")
    if sensors is not None:
        when = sensors.get("date", "?") if isinstance(sensors, dict) else "?"
        out.append(f"sensor calibration: {when} (its AD maps measured at the end stops)")
    return out


def _cmd_profile_show(args) -> int:
    model = model_from_args(args)
    check_workspace_reachable(model)  # exit 2 naming the face, as serve refuses it
    s = profile_summary(model)
    records = profile_records(args.profile)
    if records:
        s = {**s, "records": records}
    if args.json:
        print(to_json_text(s))
        return 0
    c = console()
    c.print(f"[bold]{esc(s['profile'])}[/bold] — {esc(s['description'])}")
    c.print(
        f"category {esc(s['category'])} (of {esc(', '.join(s['categories']))}): span {s['span']:.4f} m (ball centres), "
        f"mast height {s['mast_height']:.3f} m"
    )
    t = Table("actuator", "min", "max", "neutral", "unit")
    for n in ACTUATOR_NAMES:
        lo, hi = s["strokes"][n]
        t.add_row(n, f"{lo:.4f}", f"{hi:.4f}", f"{s['neutral_actuators'][n]:.4f}", ACTUATOR_UNITS[n])
    c.print(t)
    c.print("neutral pose: " + "  ".join(f"{k}={signed(v, 4)} {POSE_UNITS[k]}" for k, v in s["neutral_pose"].items()))
    for w in s["warnings"]:
        c.print(f"[yellow]warning:[/yellow] {esc(w)}")
    ws = s["workspace"]
    c.print(
        "restricted workspace: "
        + (
            "none for this category"
            if ws is None
            else "  ".join(f"{k} [{a:+.4f}, {b:+.4f}] {POSE_UNITS[k]}" for k, (a, b) in ws.items())
        )
    )
    lim = s["limits"]
    c.print(
        f"top link: yaw ±{lim['top_link_yaw_max']} rad, pitch +{lim['top_link_pitch_up_max']}/"
        f"-{lim['top_link_pitch_down_max']} rad from the {lim['top_link_angle_reference']} direction; "
        f"ground clearance {lim['ground_clearance']} m (pivot height {s['pivot_height']} m)"
    )
    fa = model.profile.motion.final_approach
    if fa is None:
        c.print("final approach: off (gotos end straight from where they come)")
    else:
        offs = _approach_values(fa.offset())
        lag = "none" if fa.lag is None else _approach_values(fa.lag.vector())
        c.print(f"final approach: from {fa.side}, offsets {offs}; lag of the pin play: {lag}")
    ca = model.profile.motion.count_approach
    c.print(
        "count approach: off"
        if ca is None
        else f"count approach: on (keep_arrival_side {ca.keep_arrival_side}, via {ca.via_hold_s:g} s, "
        f"final {ca.final_hold_s:g} s)"
    )
    for line in _record_lines(records):
        c.print(esc(line))
    return 0


#: the display unit of each controlled DOF of a final approach (offsets and lag; the profile holds m, rad) and the
#: factor from SI to it
_APPROACH_UNITS = {"x": ("mm", 1e3), "z": ("mm", 1e3), "roll": ("mrad", 1e3), "pitch": ("mrad", 1e3)}


def _approach_values(values) -> str:
    """Offsets or a lag of the final approach (x, z, roll, pitch; m, rad) as ``x=0.557 mm  …  pitch=… mrad``:
    the lag printed as ``x=0.000556913`` without a unit (a new user's trial)."""
    return "  ".join(
        f"{k}={signed(factor * v, 3)} {unit}"
        for (k, (unit, factor)), v in zip(_APPROACH_UNITS.items(), np.asarray(values, float), strict=True)
    )


def _cmd_fit_workspace(args) -> int:
    from planner.model.workspace import fit_restricted_box

    model = model_from_args(args)
    res = fit_restricted_box(model)
    lines = _box_lines(model.category, res)
    target = _write_fitted_box(args, model, lines) if args.write or args.out is not None else None
    if args.json:
        print(
            to_json_text(
                {
                    "category": model.category,
                    "box": {k: list(v) for k, v in res.box.items()},
                    "stopped_by": res.stopped_by,
                    "written": target,  # the profile file the box was written into (--write, --out), or None
                }
            )
        )
        return 0
    print("\n".join(lines))
    if target is not None:
        print(f"wrote [workspace.restricted.{model.category}] into {target} (its other lines and comments kept)")
    return 0


def _box_lines(category: str, res) -> list[str]:
    """The fitted box as the TOML lines of ``[workspace.restricted.<category>]`` (m, rad; 6 decimals, rounded
    inward), each with the limits that stopped its faces as a comment."""
    out = [f"[workspace.restricted.{category}]"]
    for k, (lo, hi) in res.box.items():
        # round inward; a face within 1e-12 m (rad) of a whole µm is that µm: the solver's last digits (a face at a
        # bound of exactly 0.056 m came out 0.05599999999999 after a change of the neutral pose's start: 0.055999)
        lo, hi = math.ceil(lo * 1e6 - 1e-6) / 1e6, math.floor(hi * 1e6 + 1e-6) / 1e6
        out.append(
            f"{k} = [{lo:.6f}, {hi:.6f}]   # {k}:min {res.stopped_by[k + ':min']}; {k}:max {res.stopped_by[k + ':max']}"
        )
    return out


def _builtin_profile_file(path: Path) -> bool:
    """``path`` is one of the profile files shipped with the package (a built-in profile or tractor)."""
    import planner.profiles

    folder = Path(planner.profiles.__file__).resolve().parent
    resolved = path.resolve()
    return resolved.suffix == ".toml" and folder in resolved.parents


def _write_fitted_box(args, model: HitchModel, lines: list[str]) -> str:
    """Write the profile of ``--profile`` with its ``[workspace.restricted.<category>]`` replaced by ``lines``
    (:func:`_box_lines`) into the profile file itself (``--write``) or into ``--out``; the file written. The
    profile's text is edited in place: the box's four lines are replaced where the table stands (a table not
    there is appended), every other line and comment is kept. Refused (nothing written): a built-in profile
    as the file to write, a box given other than as a ``[workspace.restricted.<category>]`` table of its own,
    a text that would not load or whose box the planner refuses (the checks of ``profile show``)."""
    from planner.profiles.hitch import tractor_profile_for, write_profile_text

    source = Path(args.profile)
    from_file = source.suffix == ".toml" or source.exists()
    if args.write and args.out is not None:
        raise CLIError("--write writes the fitted box into the --profile file, --out into another: give one of them")
    if args.write and not from_file:
        raise CLIError(
            f"--write: {args.profile} is a built-in profile, which is never changed: give --out FILE.toml for a copy "
            "with the fitted box"
        )
    target = source if args.write else Path(args.out)
    if _builtin_profile_file(target):
        raise CLIError(
            f"{target} lies in the folder of the built-in profiles, which are never changed: write to another file"
        )
    if from_file:
        text = source.read_text(encoding="utf-8")
    else:
        import planner.profiles

        text = (Path(planner.profiles.__file__).resolve().parent / f"{args.profile}.toml").read_text(encoding="utf-8")
    text = _replace_box(text, model.category, lines, str(source))
    tractor = model.profile.stability.tractor_profile
    written = tractor_profile_for(tractor, target.parent)
    if written != tractor:  # a tractor profile by path: as seen from the written file's folder
        text = _TRACTOR_LINE.sub(lambda m: m.group(1) + _toml_string(written), text, count=1)

    def check(prof) -> None:
        check_workspace_reachable(HitchModel(prof, model.category))

    write_profile_text(target, text, what="fitted profile", check=check)
    return str(target)


#: the ``stability.tractor_profile = "…"`` line of a profile text (its value group 2)
_TRACTOR_LINE = re.compile(r'^(\s*tractor_profile\s*=\s*)("(?:[^"\\]|\\.)*"|\'[^\']*\')', re.MULTILINE)
#: a table header line ``[…]`` or ``[[…]]``
_TABLE_HEADER = re.compile(r"^\s*\[")
#: a box key line of a restricted table: ``x = [lo, hi]`` on one line (comment allowed)
_BOX_KEY = re.compile(r"^\s*(x|z|roll|pitch)\s*=\s*\[[^\]]*\]\s*(#.*)?$")


def _toml_string(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _replace_box(text: str, category: str, lines: list[str], source: str) -> str:
    """``text`` (a profile's TOML) with the box of ``[workspace.restricted.<category>]`` replaced by ``lines``
    (header first): the table's x, z, roll, pitch lines give way to the new ones where the first stood, its
    other lines (comments) stay; without such a table the lines are appended at the end. CLIError where the
    box is written otherwise (an inline table, a key over several lines): the text cannot be edited safely."""
    header = re.compile(
        r"^\s*\[\s*workspace\s*\.\s*restricted\s*\.\s*(?:" + re.escape(category) + r'|"' + re.escape(category) + r'")'
        r"\s*\]\s*(#.*)?$"
    )
    rows = text.splitlines()
    at = [i for i, row in enumerate(rows) if header.match(row)]
    if not at:
        box = (tomllib.loads(text).get("workspace", {}).get("restricted") or {}).get(category)
        if box is not None:
            raise CLIError(
                f"{source}: its workspace.restricted.{category} is not written as a [workspace.restricted.{category}] "
                "table of its own; it is not edited in place: copy the printed box into it by hand"
            )
        return text.rstrip("\n") + "\n\n" + "\n".join(lines) + "\n"
    start = at[0] + 1
    end = next((i for i in range(start, len(rows)) if _TABLE_HEADER.match(rows[i])), len(rows))
    body = rows[start:end]
    keys = [i for i, row in enumerate(body) if _BOX_KEY.match(row)]
    stray = [row for row in body if re.match(r"^\s*(x|z|roll|pitch)\s*=", row) and not _BOX_KEY.match(row)]
    if stray or len(keys) != len({_BOX_KEY.match(body[i]).group(1) for i in keys}):  # type: ignore[union-attr]
        raise CLIError(
            f"{source}: [workspace.restricted.{category}] writes its box other than one line per key; it is not "
            "edited in place: copy the printed box into it by hand"
        )
    first = keys[0] if keys else 0
    kept = [row for i, row in enumerate(body) if i not in keys]
    new_body = kept[:first] + lines[1:] + kept[first:]
    return "\n".join(rows[:start] + new_body + rows[end:]) + ("\n" if text.endswith("\n") else "")


def _cmd_demo(args) -> int:
    model = model_from_args(args)
    c = console()
    s = profile_summary(model)
    c.print(f"[bold]hitch-planner demo[/bold] — profile {esc(s['profile'])}, category {esc(model.category)}")
    c.print(
        "neutral actuators: " + "  ".join(f"{k}={v:.4f} {ACTUATOR_UNITS[k]}" for k, v in s["neutral_actuators"].items())
    )
    c.print(
        "neutral pose:      " + "  ".join(f"{k}={signed(v, 4)} {POSE_UNITS[k]}" for k, v in s["neutral_pose"].items())
    )
    for w in s["warnings"]:
        c.print(f"[yellow]warning:[/yellow] {esc(w)}; the table below holds it there")
    t = Table(title="forward kinematics over the lift stroke (other actuators at neutral)")
    for h in ("lift [rad]",) + tuple(f"{n} [{'m' if n in ('x', 'y', 'z') else 'rad'}]" for n in POSE_NAMES):
        t.add_column(h, justify="right")
    for lift in np.linspace(model.lower[0], model.upper[0], 7):
        q = model.neutral.copy()
        q[0] = lift
        p = model.forward(q).pose
        t.add_row(f"{lift:+.3f}", *(f"{v:+.4f}" for v in p.as_array()))
    c.print(t)
    return 0


def add_commands(sub) -> None:
    p = sub.add_parser("demo", help="print the default profile's neutral pose and a forward-kinematics table")
    add_model_options(p)
    p.set_defaults(handler=_cmd_demo)

    p = sub.add_parser("fk", help="forward kinematics: actuators -> pose and points")
    for name in ACTUATOR_NAMES:
        flag = f"--{name}"
        p.add_argument(
            flag,
            type=finite_float(flag),
            required=True,
            help=f"{_ACTUATOR_LABELS[name]} [{ACTUATOR_UNITS[name]}] within the profile's stroke (profile show)",
        )
    add_model_options(p)
    p.set_defaults(handler=_cmd_fk)

    prof = sub.add_parser("profile", help="geometry profiles").add_subparsers(dest="profile_command", required=True)
    p = prof.add_parser("show", help="show a profile with the selected category")
    add_model_options(p)
    p.set_defaults(handler=_cmd_profile_show)
    p = prof.add_parser("fit-workspace", help="fit the restricted workspace box of a category (prints TOML)")
    add_model_options(p)
    p.add_argument(
        "--write",
        action="store_true",
        help="write the fitted box into the --profile file (its [workspace.restricted.<category>] lines replaced, "
        "its other lines and comments kept; never a built-in profile)",
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="FILE",
        type=_profile_out_path,
        help="write a copy of the --profile file with the fitted box here (.toml)",
    )
    p.set_defaults(handler=_cmd_fit_workspace)


def _profile_out_path(text: str) -> str:
    """argparse type of ``profile fit-workspace --out``: an output file (:func:`bridge.cli.output.output_path`)
    ending in .toml."""
    from bridge.cli.output import output_path

    path = output_path(text)
    if Path(path).suffix != ".toml":
        raise argparse.ArgumentTypeError(f"{text!r}: a profile file must end in .toml")
    return path


#: The structured comment lines that make a file a calibration's result or a twin's truth (the records of
#: ``calibrate geometry``, ``calibrate sensors`` and ``sim perturb``), with what they are called in a refusal.
_RECORDS = (
    ("#! calibration", "a geometry calibration (hitch calibrate geometry)"),
    ("#! sensor_calibration", "a sensor calibration (hitch calibrate sensors)"),
    ("#! sim-truth", "a twin's true machine (hitch sim perturb)"),
)


def _record_held(path: Path) -> str | None:
    """What :data:`_RECORDS` line an existing file holds (its description), or None (no file, or none)."""
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError:
        return None
    for line in text.splitlines():
        for prefix, what in _RECORDS:
            if line.startswith(prefix + " "):
                return what
    return None


def refuse_overwriting_profile(out: str, profile: str, *, force: bool = False, sim_truth: str | None = None) -> None:
    """CLIError when a command's ``--out`` is the profile it starts from (``--profile``): the nominal profile is
    what a calibration is measured against, and it was replaced without a word; or when ``--out`` cannot be a
    profile file (checked before anything moves: ``calibrate sensors --out sensors.csv`` drove all ten stroke ends
    and only then said the name must end in .toml, a commissioning trial); or when ``--out`` is the twin's truth
    (``--sim-truth``); or, unless ``force``, when ``--out`` exists and holds a calibration's record or a truth
    (``calibrate sensors --out tractor.toml`` replaced a geometry-calibrated profile with the nominal geometry, and
    ``calibrate geometry`` an earlier calibration, without a word: a commissioning trial)."""
    if Path(out).suffix != ".toml":
        raise CLIError(f"--out profile file {out}: the name must end in .toml")
    if Path(out).resolve() == Path(profile).resolve():
        raise CLIError(f"--out {out} is the profile the calibration starts from (--profile): write it to another file")
    if sim_truth is not None and Path(out).resolve() == Path(sim_truth).resolve():
        raise CLIError(f"--out {out} is the twin's true machine (--sim-truth): write it to another file")
    if not force:
        held = _record_held(Path(out))
        if held is not None:
            raise CLIError(
                f"--out {out} exists and holds {held}: it would be replaced; write to another file, or --force"
            )
