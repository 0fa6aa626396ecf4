"""Writing a calibrated profile: an ordinary profile TOML plus its provenance in comments.

The profile schema is strict (no unknown keys), so the provenance is carried by comment lines the
profile loader ignores: a readable header and one structured line

    #! calibration = { date = "…", poses = 20, residual_rms_position_m = …, residual_rms_angle_rad = …,
                       std = { "geometry.lift_arm_pivot[1]" = …, … }, unidentifiable = [ … ] }

which :func:`read_calibration_provenance` reads back. The file loads with ``load_profile``.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from planner.calibration.parameters import CalibrationError, ParameterSet
from planner.calibration.solve import (
    UNIDENTIFIED_SHARE,
    CalibrationResult,
    identification_status,
    weak_fit_cause,
)
from planner.errors import HitchInputError
from planner.model.exact_inverse import ExactInverse
from planner.model.kinematics import HitchModel
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import Profile, profile_from_dict, tractor_profile_for, write_profile_text

__all__ = [
    "PROVENANCE_MARKER",
    "calibrated_description",
    "calibrated_profile_toml",
    "read_calibration_provenance",
    "toml_value",
    "write_calibrated_profile",
]

#: start of the comment line that carries the calibration's provenance
PROVENANCE_MARKER = "#! calibration ="


def toml_value(v: Any) -> str:
    """``v`` (bool, int, float, str, list, mapping) as a TOML value on one line (inline tables)."""
    return _value(v)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if not math.isfinite(v):
            raise CalibrationError(f"cannot write the non-finite number {v} to a profile")
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + " }"
    raise CalibrationError(f"cannot write {type(v).__name__} to TOML")


def _key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "-_" for c in k) else _value(k)


def _table(out: list[str], path: tuple[str, ...], table: Mapping[str, Any]) -> None:
    def is_table_list(v: Any) -> bool:
        return isinstance(v, list) and bool(v) and isinstance(v[0], Mapping)

    scalars = {k: v for k, v in table.items() if v is not None and not isinstance(v, Mapping) and not is_table_list(v)}
    if path:
        out += ["", "[" + ".".join(_key(p) for p in path) + "]"]
    out.extend(f"{_key(k)} = {_value(v)}" for k, v in scalars.items())
    for k, v in table.items():
        if isinstance(v, Mapping):
            _table(out, (*path, k), v)
        elif is_table_list(v):
            for item in v:
                out += ["", "[[" + ".".join(_key(p) for p in (*path, k)) + "]]"]
                out.extend(f"{_key(ik)} = {_value(iv)}" for ik, iv in item.items() if iv is not None)


def _keep_the_neutral_pose(data: dict[str, Any], base: Profile) -> None:
    """Set the actuators' ``neutral`` in ``data`` (a calibrated profile) to the calibrated geometry's inverse of
    the nominal profile's neutral pose: home stays where it was on the machine (with the nominal neutral
    actuators the calibrated geometry put it elsewhere, e.g. 16 mrad of roll, and the accuracy test's
    deflections from it left the workspace). Left as they are when the calibrated profile cannot reach it
    (the caller's check of the written profile then says why)."""
    try:
        home = HitchModel(base).neutral_pose.controlled()
        cal = HitchModel(profile_from_dict(data, source="calibrated profile"))
        q, _ = ExactInverse(cal).solve(home)
    except (HitchInputError, ValueError):
        return
    for name, value in zip(ACTUATOR_NAMES, np.asarray(q, float), strict=True):
        spec = data["actuators"][name]
        if spec.get("neutral") is not None and spec["min"] <= value <= spec["max"]:
            spec["neutral"] = round(float(value), 9)


def calibrated_profile_toml(
    params: ParameterSet,
    result: CalibrationResult,
    *,
    name: str | None = None,
    date: str | None = None,
    inputs: Mapping[str, Any] | None = None,
    out_folder: str | Path | None = None,
    comments: Sequence[str] = (),
    predicted: Mapping[str, Mapping[str, float]] | None = None,
) -> str:
    """TOML text of the profile with the calibrated parameters and the provenance comment lines; ``inputs``
    (what the calibration was made from: the measurement file and its SHA-256, the σ given, …) is recorded
    in the provenance as it is; so is ``predicted`` (the predicted p95 pose error of this profile and of the
    nominal one, :mod:`planner.calibration.predicted`) as ``predicted_p95``. A tractor profile given by path is
    written relative to ``out_folder``, the folder the text goes to (None: absolute). ``comments``: comment lines
    carried over from the source profile (its sensor calibration record), written after the provenance."""
    if result.names != params.names:
        raise CalibrationError("the calibration result is not for this parameter set")
    base = params.profile
    weak = weak_fit_cause(
        result.names,
        result.scale,
        (result.values - result.nominal) / result.scale,
        result.singular_values,
        result.identified,
        result.min_singular,
        result.residual_sigma,
        result.converged,
        [p.unit for p in params.parameters],
    )
    try:
        data = params.profile_dict(result.values, name=name or _calibrated_name(base.name))
    except CalibrationError as exc:
        if weak is None:
            raise
        why = str(exc).split(". The fit went far")[0]
        raise CalibrationError(f"{why}: {weak}; nothing was written") from None
    data["stability"]["tractor_profile"] = tractor_profile_for(data["stability"]["tractor_profile"], out_folder)
    _keep_the_neutral_pose(data, base)
    when = date or _dt.datetime.now(_dt.UTC).replace(microsecond=0).isoformat()
    data["description"] = calibrated_description(base.description, when, result.n_poses)
    status = [identification_status(float(h)) for h in result.identified_share]
    prov = {
        "date": when,
        "poses": result.n_poses,
        "observations": result.n_observations,
        "residual_rms_position_m": float(result.residual_rms_position_m),
        "residual_rms_angle_rad": float(result.residual_rms_angle_rad),
        "residual_sigma": float(result.residual_sigma),
        "identified": result.identified,
        "nominal_profile": base.name,
        # a std only where the data see the parameter (identified share > 0), with the tape prior of the part
        # they do not see (std_total: the identified part's alone read 1.5e-05 m for one 41σ off); the share beside it
        "std": {
            n: float(s)
            for n, s, h in zip(result.names, result.std_total, result.identified_share, strict=True)
            if h >= UNIDENTIFIED_SHARE
        },
        "identified_share": {n: round(float(h), 4) for n, h in zip(result.names, result.identified_share, strict=True)},
        # the words of the text report (identification_status): kept at nominal without a std; under half
        # identified (moves only with the identified combinations, std mostly its tape error); partly identified
        "not_identified": [n for n, w in zip(result.names, status, strict=True) if w == "not identified"],
        "weakly_identified": [n for n, w in zip(result.names, status, strict=True) if w == "weakly identified"],
        "partly_identified": [n for n, w in zip(result.names, status, strict=True) if w == "partly identified"],
        "unidentifiable": list(result.unidentifiable),
    }
    if predicted:
        prov["predicted_p95"] = {k: dict(v) for k, v in predicted.items()}
    if inputs:
        prov["inputs"] = dict(inputs)
    out = [
        f"# Calibrated hitch profile (hitch calibrate geometry), from {base.name}, {when}:",
        f"# {result.n_poses} measured poses, residual RMS {1e3 * result.residual_rms_position_m:.3f} mm / "
        f"{1e3 * result.residual_rms_angle_rad:.3f} mrad, {result.identified} of {len(result.names)} "
        "parameter directions identified; the others stay nominal (unidentifiable in the line below).",
        "# not_identified: parameters kept at nominal (no std); weakly_identified: under half identified (they",
        "# move only with the identified combinations; std mostly their tape error); partly_identified: std",
        "# includes the tape error of the unidentified part; identified_share: the share of each (as printed).",
        f"{PROVENANCE_MARKER} {_value(prov)}",
    ]
    for line in comments:
        if not line.startswith("#") or "\n" in line:
            raise CalibrationError(f"internal: a carried comment must be one line starting with '#', got {line!r}")
        out.append(line)
    _table(out, (), data)
    text = "\n".join(out) + "\n"
    try:
        prof = profile_from_dict(tomllib.loads(text), source="calibrated profile")
    except tomllib.TOMLDecodeError as exc:  # pragma: no cover - our own writer
        raise CalibrationError(f"internal: the calibrated profile is not valid TOML: {exc}") from None
    try:  # a profile the planner cannot use (no neutral pose, no closure) is never written
        HitchModel(prof)
    except HitchInputError as exc:
        if weak is not None:
            raise CalibrationError(
                f"the calibrated profile cannot be used: {exc}. {weak}; nothing was written"
            ) from None
        raise CalibrationError(
            f"the calibrated profile cannot be used: {exc}. The measurements do not fit the model (residual RMS "
            f"{1e3 * result.residual_rms_position_m:.3f} mm / {1e3 * result.residual_rms_angle_rad:.3f} mrad, "
            f"sigma-hat {result.residual_sigma:.3g}): check for a wrong value, a unit slip (mm or degrees in a "
            "column of m or rad), or a sign or left/right slip (x measured to the other side, the L and R points "
            "swapped); nothing was written"
        ) from None
    return text


#: where a calibrated profile's description says so (a recalibration replaces what follows it)
CALIBRATED_DESCRIPTION = "; calibrated "
#: a claim of the nominal profile's description a calibrated one no longer makes (the thesis profile's)
_TAPE_CLAIM = re.compile(r"\s*\(tape-measured\)", re.IGNORECASE)


def calibrated_description(base: str, date: str, poses: int) -> str:
    """The description of a profile calibrated on ``date`` (ISO; its day is written) from ``poses`` poses: the
    nominal profile's own text ``base`` without its "(tape-measured)" (the geometry is calibrated now) and
    without an earlier calibration's note, then ``"; calibrated <day> from <N> poses (hitch calibrate
    geometry)"``. The calibrated thesis profile kept "… (tape-measured)" (a commissioning trial)."""
    own = base.split(CALIBRATED_DESCRIPTION, 1)[0]
    own = _TAPE_CLAIM.sub("", own).strip()
    day = date.split("T", 1)[0]
    note = f"calibrated {day} from {poses} pose{'' if poses == 1 else 's'} (hitch calibrate geometry)"
    return f"{own}; {note}" if own else note[:1].upper() + note[1:]


#: the suffix of a calibrated profile's default name
CALIBRATED_SUFFIX = "-calibrated"


def _calibrated_name(base: str) -> str:
    """``<base>-calibrated`` (at most 80 characters), once: recalibrating ``mine-calibrated`` keeps its name (it
    became ``mine-calibrated-calibrated``)."""
    return base[:80] if base.endswith(CALIBRATED_SUFFIX) else f"{base}{CALIBRATED_SUFFIX}"[:80]


def write_calibrated_profile(
    path: str | Path,
    params: ParameterSet,
    result: CalibrationResult,
    *,
    name: str | None = None,
    inputs: Mapping[str, Any] | None = None,
    comments: Sequence[str] = (),
    predicted: Mapping[str, Mapping[str, float]] | None = None,
) -> Profile:
    """Write the calibrated profile to ``path`` (``inputs``, ``predicted``: :func:`calibrated_profile_toml`) if it
    loads there (nothing is written otherwise); returns it as loaded back by ``load_profile``."""
    p = Path(path)
    if p.suffix != ".toml":
        raise CalibrationError(f"--out {p}: a profile file must end in .toml")
    text = calibrated_profile_toml(
        params, result, name=name, inputs=inputs, out_folder=p.parent, comments=comments, predicted=predicted
    )
    try:
        return write_profile_text(p, text, what="--out profile")
    except HitchInputError as exc:
        raise CalibrationError(str(exc)) from None


def read_calibration_provenance(path: str | Path) -> dict[str, Any] | None:
    """The provenance of a calibrated profile file (None for a profile without one)."""
    for line in Path(path).read_text(encoding="utf-8").splitlines():
        if line.startswith(PROVENANCE_MARKER):
            try:
                data = tomllib.loads("calibration =" + line[len(PROVENANCE_MARKER) :])["calibration"]
            except tomllib.TOMLDecodeError as exc:
                raise CalibrationError(f"{path}: the calibration line is not valid TOML: {exc}") from None
            return dict(data)
    return None
