"""The twin's own true machine: a truth profile, tape-measure perturbations and a measuring instrument.

The planner always uses its **nominal** profile. The simulated machine may be given a different
**truth** profile of the same schema (``--sim-truth FILE``): the values the real tractor has and
the planner does not know. Truth matters in exactly two places:

1. **The AD map** (``[actuators.*] counts_min / counts_max`` over the stroke ``min / max``). The
   twin's hydraulics move the pistons in AD counts; the ECU built from the truth profile therefore
   reports, for a piston at a true position ``q``, the counts of the *true* map, which differ from
   what the planner's nominal map assumes. The true piston position in SI is the truth map of the
   piston's (unquantised) counts. Valve gains ``kv_*`` are identified through the sensor, in
   counts, and stay as they are.
2. **The true implement pose**: forward kinematics of the true piston positions through the
   *truth* geometry, plus pin play.

The implement is rigid: its lower span is fixed. With five actuators for four DOF the sway
limiters over-determine the mechanism, and the lower span is very sensitive to their geometry
(about 7 mm of span per mm of limiter length, 13 mm per mm of the limiter's tractor point along
y). Forward kinematics alone would put the balls of a tape-measured truth centimetres from the
implement's span. The true machine therefore lets the sway limiters give up a common-mode length
(their compliance; reported as ``limiter_strain_m``) until the balls sit at the implement's span,
keeping their difference (the lateral position): ``rigid_span=True``, the default. With
``rigid_span=False`` the pose is plain forward kinematics of the pistons, the "simulation truth"
the twin had before it had a truth (for truth = nominal and pistons from the IK the two agree to
a fraction of a millimetre: the pistons then sit within a count of a consistent set).

Pin play (backlash at the lower-link balls and the top-link pins) is a dead band between the
mechanism and the implement. It is modelled simply, per controlled DOF, as a backlash operator
(a play hysteresis): the implement's pose follows the mechanism's pose but lags it by up to
``±band`` in each of x, z, roll, pitch, with the band the play mapped through the geometry::

    band_x = band_z = play_lower_link_m
    band_roll  = 2 · play_lower_link_m / lower span (ball centres)
    band_pitch = (play_lower_link_m + play_top_link_m) / mast height

The operator starts centred (implement pose = mechanism pose) and is updated each time the true
machine is observed (:meth:`TrueMachine.observe`). Play is not a field of the profile schema, so a
truth file carries it on one structured comment line, which the normal profile loader ignores::

    #! sim-truth play = { lower_link_m = 0.0004, top_link_m = 0.0007 }

A plain profile (no such line) is a truth without play.

:func:`perturb_profile` draws a random truth with tape-measure-sized errors (:class:`TapeErrors`):

* **coordinates** ±10 mm: every component of ``geometry.lift_arm_pivot``,
  ``geometry.top_link_tractor_point``, ``geometry.limiter_tractor_point``, and the pivot
  placement ``geometry.lower_link_pivot_span`` and ``geometry.pivot_height``;
* **member lengths** ±5 mm: ``geometry.lower_link_length``, ``lift_rod_attachment``,
  ``limiter_bracket_position``, ``limiter_bracket_offset``, ``fixed_lift_rod_length``,
  ``lift_arm_length``;
* **AD offsets** ±3 counts (integer) and **gains** ±2 % of every actuator's sensor: the true
  map reads ``counts_min + offset`` at the stroke's ``min`` and ``counts_min + offset +
  round_toward_zero(span · (1 + gain))`` at its ``max`` (counts are integers in the schema, so the
  realised gain is the drawn one rounded toward zero to whole counts, never beyond ±2 %); the
  physical strokes in SI (the end stops) stay;
* **play** 0…1 mm at the lower-link balls and at the top-link pins.

The implement (ISO 730 categories), limits, valves and motion settings are unchanged. The nominal must load
as ``hitch profile show`` loads it (the model of its default category builds: the neutral pose closes and,
with a restricted workspace, lies within the hard limits), and so must the truth, else the draw is refused
(:func:`check_model_builds`): a truth that ``hitch profile show`` or the twin cannot load is not written.

:class:`Instrument` reports the true implement pose (x, z, roll, pitch) and optionally the
positions of marked points on it (the ball centres L, R and the top-link pin U, or any named
point of the mechanism) with a chosen noise: ``tape`` — uniform ±10 mm on each coordinate and
±20 mrad on each angle (two ±10 mm readings about 1 m apart); ``station`` — a total station,
Gaussian σ = 1 mm and 1 mrad; ``none`` — exact.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchInputError
from planner.model.kinematics import FEATURE_NAMES, POINT_NAMES, HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES, Pose
from planner.profiles.hitch import Profile, load_profile, profile_from_dict

__all__ = [
    "COORDINATE_FIELDS",
    "LENGTH_FIELDS",
    "MARKED_POINTS",
    "NOISE_KINDS",
    "noise_kind",
    "PLAY_MARKER",
    "Instrument",
    "InstrumentNoise",
    "MachineTruth",
    "Measurement",
    "PinPlay",
    "TapeErrors",
    "TrueMachine",
    "TruthError",
    "check_model_builds",
    "load_machine_truth",
    "perturb_profile",
    "truth_toml",
]

#: geometry fields that are coordinates (3-vectors and the pivot placement), perturbed by ±coordinate_m
COORDINATE_FIELDS: tuple[str, ...] = (
    "lift_arm_pivot",
    "top_link_tractor_point",
    "limiter_tractor_point",
    "lower_link_pivot_span",
    "pivot_height",
)
#: geometry fields that are member lengths, perturbed by ±length_m
LENGTH_FIELDS: tuple[str, ...] = (
    "lower_link_length",
    "lift_rod_attachment",
    "limiter_bracket_position",
    "limiter_bracket_offset",
    "fixed_lift_rod_length",
    "lift_arm_length",
)
#: default marked points on the implement: the ball centres and the top-link implement pin
MARKED_POINTS: tuple[str, ...] = ("L", "R", "U")
#: instrument noise presets
NOISE_KINDS: tuple[str, ...] = ("tape", "station", "none")


def noise_kind(text: str) -> str:
    """An instrument's name as the commands take it: ``total-station`` (``hitch accuracy-test``'s spelling)
    is ``station``; the rest as given (an argparse type; ``choices`` then checks it)."""
    return "station" if text == "total-station" else text


#: start of the comment line that carries the pin play in a truth file
PLAY_MARKER = "#! sim-truth play ="
_TRUTH_DIRECTIVE = "#! sim-truth "
#: the other directive lines a profile may carry (the calibrations' provenance records)
_OTHER_DIRECTIVES = ("#! calibration =", "#! sensor_calibration =")

_PLAY_MAX_M = 0.01
_SPAN_ROW = FEATURE_NAMES.index("lower_span")
_SPAN_ITERATIONS = 6
_SPAN_TOL_M = 1e-9
_AD_MAX = 1023


class TruthError(HitchInputError):
    """A truth, perturbation or measurement that cannot be made; the message names the field and range."""


def _number(name: str, value: object, lo: float, hi: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise TruthError(f"{name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    v = float(value)
    if not (math.isfinite(v) and lo <= v <= hi):
        raise TruthError(f"{name} must be a number in [{lo:g}, {hi:g}], got {value!r}")
    return v


@dataclass(frozen=True)
class PinPlay:
    """Pin play (backlash) [m]: at the lower-link balls and at the top-link pins, each 0…10 mm."""

    lower_link_m: float = 0.0
    top_link_m: float = 0.0

    def __post_init__(self) -> None:
        for name in ("lower_link_m", "top_link_m"):
            object.__setattr__(self, name, _number(f"play.{name}", getattr(self, name), 0.0, _PLAY_MAX_M))

    @property
    def any(self) -> bool:
        return self.lower_link_m > 0.0 or self.top_link_m > 0.0


@dataclass(frozen=True)
class MachineTruth:
    """The twin's true machine: a truth profile (same schema as the planner's) and pin play."""

    profile: Profile
    play: PinPlay = field(default_factory=PinPlay)

    def __post_init__(self) -> None:
        if not isinstance(self.profile, Profile):
            raise TruthError(f"truth profile must be a Profile, got {type(self.profile).__name__}")
        if not isinstance(self.play, PinPlay):
            raise TruthError(f"play must be a PinPlay, got {type(self.play).__name__}")

    @classmethod
    def nominal(cls, profile: Profile | str | Path = "thesis-t132") -> MachineTruth:
        """The truth that equals a profile exactly (no play): today's twin."""
        return cls(profile if isinstance(profile, Profile) else load_profile(profile))

    @property
    def scaling(self) -> SensorScaling:
        """The true AD map of the five sensors."""
        return SensorScaling(self.profile)

    def counts_from_si(self, q: ArrayLike) -> np.ndarray:
        """Unquantised true counts [float] of true piston positions ``q`` (SI), ACTUATOR_NAMES order."""
        return self.scaling.counts_of(_vector5("actuators", q))

    def si_from_counts(self, counts: ArrayLike) -> np.ndarray:
        """True piston positions (SI) of unquantised piston counts through the true AD map."""
        sc = self.scaling
        return sc.si_min + (_vector5("counts", counts) - sc.counts_min) * sc.resolution


def _vector5(name: str, value: ArrayLike) -> np.ndarray:
    try:
        v = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise TruthError(f"{name} must be 5 numbers ({', '.join(ACTUATOR_NAMES)}), got {value!r}") from None
    if v.size != 5 or not np.all(np.isfinite(v)):
        raise TruthError(f"{name} must be 5 finite numbers ({', '.join(ACTUATOR_NAMES)}), got {value!r}")
    return v


def _parse_play(text: str, source: str) -> PinPlay:
    """The play line of a truth file; a second one, or a ``#! sim-truth`` line with another key, is an error (a
    misspelt ``flay`` ran as a truth without play, and of two play lines the first won silently)."""
    for n, ln in enumerate(text.splitlines(), 1):  # "#!" lines are directives: a misspelt one is not a comment
        if ln.startswith("#!") and not ln.startswith((_TRUTH_DIRECTIVE, *_OTHER_DIRECTIVES)):
            word = ln[2:].strip().split(" ")[0].split("=")[0] or "(none)"
            raise TruthError(
                f"truth {source} line {n}: unknown directive '#! {word}' (known: {_TRUTH_DIRECTIVE.strip()}, "
                f"{', '.join(d.removesuffix(' =') for d in _OTHER_DIRECTIVES)}); the play line is "
                f"{PLAY_MARKER} {{ lower_link_m = …, top_link_m = … }}"
            )
    lines = [(n, ln) for n, ln in enumerate(text.splitlines(), 1) if ln.startswith(_TRUTH_DIRECTIVE)]
    for n, ln in lines:
        if not ln.startswith(PLAY_MARKER):
            key = ln[len(_TRUTH_DIRECTIVE) :].split("=")[0].strip() or "(none)"
            raise TruthError(
                f"truth {source} line {n}: unknown directive {_TRUTH_DIRECTIVE.strip()} {key!r}; the one there is: "
                f"{PLAY_MARKER} {{ lower_link_m = …, top_link_m = … }}"
            )
    if len(lines) > 1:
        raise TruthError(
            f"truth {source}: {len(lines)} play lines (lines {', '.join(str(n) for n, _ in lines)}); give one"
        )
    if not lines:
        return PinPlay()
    line = lines[0][1]  # the one play line (every directive line is one, and there is one)
    try:
        data = tomllib.loads("play =" + line[len(PLAY_MARKER) :])["play"]
    except tomllib.TOMLDecodeError as exc:
        raise TruthError(f"truth {source}: the play line is not valid TOML: {exc}") from None
    if not isinstance(data, dict) or set(data) - {"lower_link_m", "top_link_m"}:
        unknown = sorted(set(data) - {"lower_link_m", "top_link_m"}) if isinstance(data, dict) else []
        named = f" (unknown: {', '.join(unknown)})" if unknown else ""
        raise TruthError(f"truth {source}: play allows the keys lower_link_m, top_link_m (m, 0…0.01){named}")
    try:
        return PinPlay(**data)
    except TruthError as exc:  # a value out of range: say which file
        raise TruthError(f"truth {source}: {exc}") from None


def load_machine_truth(name_or_path: str | Path) -> MachineTruth:
    """A truth from a profile file (or built-in name) with its optional play line."""
    profile = load_profile(name_or_path)
    p = Path(name_or_path)
    play = _parse_play(p.read_text(encoding="utf-8"), str(p)) if p.is_file() else PinPlay()
    return MachineTruth(profile, play)


# -- perturbation --------------------------------------------------------------------------------
def check_model_builds(profile: Profile, what: str) -> None:
    """:class:`TruthError` naming ``what`` (e.g. ``"--profile mine.toml"``) and why, unless ``profile`` loads as
    ``hitch profile show`` loads it: the model of its default category builds (the neutral pose closes and,
    with a restricted workspace, lies within the hard limits)."""
    category = profile.implement.default_category
    try:
        HitchModel(profile, category)
    except HitchInputError as exc:
        why = str(exc)
    except np.linalg.LinAlgError as exc:  # a singular Newton step of the neutral pose: degenerate geometry
        why = f"profile {profile.name}: cannot find the neutral pose: the geometry is degenerate ({exc})"
    else:
        return
    raise TruthError(f"{what} does not load (category {category}): {why}")


@dataclass(frozen=True)
class TapeErrors:
    """Sizes of tape-measure errors: the largest |error| of each kind (uniformly drawn)."""

    coordinate_m: float = 0.010
    length_m: float = 0.005
    ad_offset_counts: int = 3
    ad_gain: float = 0.02
    play_m: float = 0.001


def perturb_profile(
    profile: Profile | str | Path,
    seed: int,
    *,
    tape: bool = True,
    errors: TapeErrors | None = None,
    source: str | None = None,
) -> tuple[dict[str, Any], PinPlay]:
    """A random truth near ``profile``: (profile data loadable by ``profile_from_dict``, pin play).

    ``tape=True`` uses the tape-measure error sizes (:class:`TapeErrors`, module docstring); it is
    the only error model so far. The same seed gives the same truth. The nominal must load as
    ``hitch profile show`` loads it (its default category's model builds), else :class:`TruthError` names it
    (``source``, default its name) and why. The result is validated: a draw the schema rejects (e.g. counts
    beyond 0…1023), or whose model does not build (:func:`check_model_builds`), raises :class:`TruthError`.
    """
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= int(seed) < 2**63:
        raise TruthError(f"seed must be an integer in [0, 2^63), got {seed!r}")
    if tape is not True:
        raise TruthError("only the tape error model exists so far: tape must be True")
    e = errors if errors is not None else TapeErrors()
    base = profile if isinstance(profile, Profile) else load_profile(profile)
    check_model_builds(base, source or f"the nominal profile {base.name}")
    rng = np.random.default_rng(int(seed))
    data = base.model_dump(mode="python")
    data["name"] = f"{base.name}-truth-{int(seed)}"[:80]
    data["description"] = f"simulated true machine: {base.name} with tape-measure errors, seed {int(seed)}"
    geo = data["geometry"]
    for name in COORDINATE_FIELDS:
        v = geo[name]
        if isinstance(v, (tuple, list)):
            geo[name] = [float(c) + float(rng.uniform(-e.coordinate_m, e.coordinate_m)) for c in v]
        else:
            geo[name] = float(v) + float(rng.uniform(-e.coordinate_m, e.coordinate_m))
    for name in LENGTH_FIELDS:
        geo[name] = float(geo[name]) + float(rng.uniform(-e.length_m, e.length_m))
    for name in ACTUATOR_NAMES:
        spec = data["actuators"][name]
        offset = int(rng.integers(-e.ad_offset_counts, e.ad_offset_counts + 1))
        gain = float(rng.uniform(-e.ad_gain, e.ad_gain))
        span = spec["counts_max"] - spec["counts_min"]
        # rounded toward the nominal span: |realised gain| <= |drawn gain|
        new_span = (math.floor if gain >= 0 else math.ceil)(span * (1.0 + gain))
        lo = spec["counts_min"] + offset
        if not (0 <= lo and lo + new_span <= _AD_MAX):
            raise TruthError(
                f"actuators.{name}: perturbed AD map [{lo}, {lo + new_span}] leaves the 10-bit range 0…{_AD_MAX}"
            )
        spec["counts_min"], spec["counts_max"] = lo, lo + new_span
    play = PinPlay(float(rng.uniform(0.0, e.play_m)), float(rng.uniform(0.0, e.play_m)))
    try:
        truth = profile_from_dict(data, source=f"perturbed {base.name} (seed {int(seed)})")
    except HitchInputError as exc:
        raise TruthError(str(exc)) from None
    try:
        check_model_builds(truth, f"the drawn truth {data['name']} (seed {int(seed)})")
    except TruthError as exc:
        raise TruthError(f"{exc}; the draw is refused, nothing is written (draw another seed)") from None
    return data, play


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, Mapping):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TruthError(f"cannot write {type(v).__name__} to TOML")


def _toml_key(k: str) -> str:
    return k if k and all(c.isalnum() or c in "-_" for c in k) else _toml_value(k)


def _toml_table(out: list[str], path: tuple[str, ...], table: Mapping[str, Any]) -> None:
    scalars = {
        k: v
        for k, v in table.items()
        if v is not None
        and not isinstance(v, Mapping)
        and not (isinstance(v, list) and v and isinstance(v[0], Mapping))
    }
    if path:
        out.append("")
        out.append("[" + ".".join(_toml_key(p) for p in path) + "]")
    out.extend(f"{_toml_key(k)} = {_toml_value(v)}" for k, v in scalars.items())
    for k, v in table.items():
        if isinstance(v, Mapping):
            _toml_table(out, (*path, k), v)
        elif isinstance(v, list) and v and isinstance(v[0], Mapping):
            for item in v:
                out.append("")
                out.append("[[" + ".".join(_toml_key(p) for p in (*path, k)) + "]]")
                out.extend(f"{_toml_key(ik)} = {_toml_value(iv)}" for ik, iv in item.items() if iv is not None)


def truth_toml(data: Mapping[str, Any], play: PinPlay | None = None) -> str:
    """TOML text of a truth: the profile ``data`` (loads with the normal profile loader) + the play line."""
    play = play if play is not None else PinPlay()
    out = [
        "# Simulated true machine (hitch sim perturb): a hitch profile the twin uses instead of the",
        "# planner's; the play line below is read by bridge.sim.truth (the profile loader ignores it).",
        f"{PLAY_MARKER} {{ lower_link_m = {play.lower_link_m!r}, top_link_m = {play.top_link_m!r} }}",
    ]
    _toml_table(out, (), data)
    return "\n".join(out) + "\n"


# -- the true machine ----------------------------------------------------------------------------
def _rotation(roll: float, pitch: float) -> np.ndarray:
    """Small rigid rotation: roll about the longitudinal y axis, then pitch about the lateral x axis."""
    cr, sr, cp, sp = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch)
    r_y = np.array([[cr, 0.0, sr], [0.0, 1.0, 0.0], [-sr, 0.0, cr]])
    r_x = np.array([[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]])
    return r_y @ r_x


class TrueMachine:
    """The true implement pose of the twin from its true piston positions (truth geometry + play).

    ``truth``: the machine; ``category``: the implement's ISO 730 category (default the profile's);
    ``model``: an already-built model of the truth profile and category to reuse (optional).
    """

    def __init__(
        self,
        truth: MachineTruth,
        category: str | None = None,
        *,
        model: HitchModel | None = None,
        rigid_span: bool = True,
    ) -> None:
        if not isinstance(truth, MachineTruth):
            raise TruthError(f"truth must be a MachineTruth, got {type(truth).__name__}")
        if not isinstance(rigid_span, bool):
            raise TruthError(f"rigid_span must be a bool, got {rigid_span!r}")
        self.truth = truth
        self.rigid_span = rigid_span
        self.limiter_strain_m = 0.0
        """Common-mode length the sway limiters give up so the rigid implement fits (last observation) [m]."""
        self.model = model if model is not None else HitchModel(truth.profile, category)
        cat = self.model.profile.category(self.model.category)
        span = self.model.profile.span(self.model.category)
        p = truth.play
        #: dead band half-widths of x, z, roll, pitch [m, m, rad, rad] (module docstring)
        self.band = np.array(
            [
                p.lower_link_m,
                p.lower_link_m,
                2.0 * p.lower_link_m / span,
                (p.lower_link_m + p.top_link_m) / cat.mast_height,
            ]
        )
        self._implement: np.ndarray | None = None  # x, z, roll, pitch of the implement (after play)
        self._mechanism: Pose | None = None
        self._points: dict[str, np.ndarray] = {}

    def actuators_si(self, piston_counts: ArrayLike) -> np.ndarray:
        """True piston positions (SI) of the twin's unquantised piston counts."""
        return self.truth.si_from_counts(piston_counts)

    def mechanism_actuators(self, piston_counts: ArrayLike) -> np.ndarray:
        """The actuators the mechanism takes with the rigid implement on (``rigid_span``): the sway limiters'
        common mode shifted (Newton on the lower span, thesis feature ``lower_span``) until the balls sit
        at the implement's span; their difference, the lateral position, is kept."""
        q = self.actuators_si(piston_counts)
        self.limiter_strain_m = 0.0
        if not self.rigid_span:
            return q
        common = np.array([0.0, 0.0, 0.0, 1.0, 1.0])
        shift = 0.0
        for _ in range(_SPAN_ITERATIONS):
            f, jac = self.model.features(q + shift * common)
            err = float(f[_SPAN_ROW]) - self.model.span
            if abs(err) < _SPAN_TOL_M:
                break
            slope = float(jac[_SPAN_ROW] @ common)
            if abs(slope) < 1e-6:
                break
            shift -= err / slope
        self.limiter_strain_m = shift
        return q + shift * common

    def observe(self, piston_counts: ArrayLike) -> Pose:
        """Update the true machine with the twin's piston counts; returns the true implement pose."""
        state = self.model.forward(self.mechanism_actuators(piston_counts))
        m = state.pose.controlled()
        if self._implement is None:
            self._implement = m.copy()
        else:  # backlash operator per DOF: follow only once the mechanism leaves the dead band
            self._implement = np.clip(self._implement, m - self.band, m + self.band)
        self._mechanism = state.pose
        self._points = dict(state.points)
        return self.pose

    @property
    def play_offset(self) -> np.ndarray:
        """The implement's pose minus the mechanism's now (x, z, roll, pitch) [m, m, rad, rad]: where the play
        leaves it in its dead band (each within ± the band)."""
        if self._mechanism is None or self._implement is None:
            raise TruthError("the true machine has not been observed yet (call observe first)")
        return self._implement - self._mechanism.controlled()

    @property
    def pose(self) -> Pose:
        """The last true implement pose (x, z, roll, pitch after play; y, yaw of the mechanism)."""
        if self._mechanism is None or self._implement is None:
            raise TruthError("the true machine has not been observed yet (call observe first)")
        d = self._mechanism.as_dict()
        d.update(zip(CONTROLLED_POSE_NAMES, map(float, self._implement), strict=True))
        return Pose(**d)

    def points(self, names: Sequence[str] = MARKED_POINTS) -> dict[str, np.ndarray]:
        """True positions [m] of marked points (mechanism points moved rigidly by the play lag about T)."""
        unknown = [n for n in names if n not in POINT_NAMES]
        if unknown:
            raise TruthError(f"points: unknown point(s) {unknown}; allowed: {', '.join(POINT_NAMES)}")
        if self._mechanism is None or self._implement is None:
            raise TruthError("the true machine has not been observed yet (call observe first)")
        lag = self._implement - self._mechanism.controlled()
        rot = _rotation(float(lag[2]), float(lag[3]))
        t = self._points["T"]
        shift = np.array([lag[0], 0.0, lag[1]])
        return {n: t + shift + rot @ (self._points[n] - t) for n in names}


# -- the instrument ------------------------------------------------------------------------------
@dataclass(frozen=True)
class InstrumentNoise:
    """Noise of a measuring instrument: ``uniform`` ±bound or ``gaussian`` σ, on positions [m] and angles [rad]."""

    kind: Literal["uniform", "gaussian", "none"]
    position_m: float
    angle_rad: float

    def __post_init__(self) -> None:
        if self.kind not in ("uniform", "gaussian", "none"):
            raise TruthError(f"noise kind must be uniform, gaussian or none, got {self.kind!r}")
        _number("noise position_m", self.position_m, 0.0, 1.0)
        _number("noise angle_rad", self.angle_rad, 0.0, 1.0)

    @classmethod
    def preset(cls, name: str) -> InstrumentNoise:
        """``tape`` (uniform ±10 mm, ±20 mrad), ``station`` (Gaussian 1 mm, 1 mrad) or ``none``."""
        presets = {
            "tape": cls("uniform", 0.010, 0.020),
            "station": cls("gaussian", 0.001, 0.001),
            "none": cls("none", 0.0, 0.0),
        }
        if name not in presets:
            raise TruthError(f"noise must be one of {', '.join(NOISE_KINDS)}, got {name!r}")
        return presets[name]

    def draw(self, rng: np.random.Generator, size: int, scale: float) -> np.ndarray:
        if self.kind == "uniform":
            return rng.uniform(-scale, scale, size)
        if self.kind == "gaussian":
            return rng.normal(0.0, scale, size)
        return np.zeros(size)


@dataclass(frozen=True)
class Measurement:
    """What the instrument read: the implement pose (x, z, roll, pitch) and marked points [m, rad]."""

    pose: dict[str, float]
    points: dict[str, tuple[float, float, float]]
    noise: InstrumentNoise

    def as_dict(self) -> dict[str, Any]:
        return {
            "pose": dict(self.pose),
            "points": {k: list(v) for k, v in self.points.items()},
            "noise": {"kind": self.noise.kind, "position_m": self.noise.position_m, "angle_rad": self.noise.angle_rad},
        }


class Instrument:
    """A simulated measuring instrument reading the true machine with a noise (seeded)."""

    def __init__(self, noise: InstrumentNoise | str = "station", *, seed: int = 0) -> None:
        self.noise = noise if isinstance(noise, InstrumentNoise) else InstrumentNoise.preset(noise)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise TruthError(f"seed must be a non-negative integer, got {seed!r}")
        self._rng = np.random.default_rng(int(seed))

    def measure(self, machine: TrueMachine, points: Sequence[str] = ()) -> Measurement:
        """One reading of the implement pose and the named points of ``machine`` (observed before)."""
        true = machine.pose.controlled()
        marked = machine.points(points) if points else {}
        n = self.noise
        err = np.concatenate([n.draw(self._rng, 2, n.position_m), n.draw(self._rng, 2, n.angle_rad)])
        pose = {k: float(v) for k, v in zip(CONTROLLED_POSE_NAMES, true + err, strict=True)}
        read = {}
        for name, p in marked.items():
            q = p + n.draw(self._rng, 3, n.position_m)
            read[name] = (float(q[0]), float(q[1]), float(q[2]))
        return Measurement(pose, read, n)
