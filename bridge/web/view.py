"""The hitch picture's numbers: the model's points for the measured and the target actuators.

The terminal draws a rear view (lower links, lift rods, sway limiters, implement: x and roll) and
a side view (lift arm, lift rod, lower link, top link, mast: z and pitch) from the named points of
:meth:`planner.model.kinematics.HitchModel.forward` (L0, R0, L, R, T, U, H, Q_l, S_l, A_l, …, in
the tractor frame: x to the driver's left, y rearward, z up, origin between the lower-link
pivots). They are computed here, in the web server's process, from the actuators a ``state``
message carries (``actuators`` measured, ``reference.actuators`` what is commanded now,
``goal.actuators`` where the running motion ends), and sent to the page as
``{"type": "view", "data": HitchView.message(state)}`` — the state messages stay as they are.

* :meth:`HitchView.terminal` — what does not change: the ground's z, the workspace, the stroke
  ranges, the stability thresholds, the tractor's weight and rear wheel, the operator words of
  every limit code this hitch can report (:mod:`.wording`) and the picture member each lights up;
  sent once per page (``{"type": "terminal"}``).
* :meth:`HitchView.message` — per state (the server sends it at most :data:`VIEW_RATE_HZ`, and
  only while a page is connected): the points of the three actuator sets (``goal`` None when no
  goto, preset, raise/return or maneuver step runs: the page ghosts it), the lower hitch points'
  heights above the ground, lift as a share of its range, ``state.limited`` in words with the
  members to highlight, and the front-axle load as a share of the empty tractor's weight.

Height above ground: the frame's origin is at the lower-link pivots, ``geometry.pivot_height``
above flat ground (the hitch profile; the tractor profile's heights are measured from the same
ground), so a point's height above ground is ``z + pivot_height``. The front-axle share of the
tractor's weight assumes flat ground: front load = share × (tractor + front ballast + implement)
weight, over the empty tractor's weight (the guard's rule compares the front load with 20 % of
the empty weight; on a slope of angle α the true share is smaller by cos α).

A :class:`HitchModel` is used by one thread only: the view belongs to the web server's loop.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bridge.web.wording import IMPLEMENT_WORDS, KEY_WORDS, MEASURE_WORDS, MODE_WORDS, highlight, limited_entries, words
from planner.errors import HitchInputError
from planner.limits.stability import StabilityThresholds
from planner.limits.tractor import load_tractor_profile
from planner.model.hard_limits import FEATURE_LIMIT_ROWS, STROKE_NAMES, WORKSPACE_NAMES
from planner.model.kinematics import POINT_NAMES, HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES, KinematicsError

__all__ = ["HitchView", "VIEW_RATE_HZ", "limit_codes"]

#: most view messages per second the server sends (forward kinematics: ~20 µs per actuator set)
VIEW_RATE_HZ = 15.0
#: the lower hitch points whose height above the ground the terminal shows
GROUND_POINTS = ("L", "R", "T")
_DIGITS = 6  # points rounded to 1 µm


def limit_codes(model: HitchModel) -> tuple[str, ...]:
    """Every limit code this hitch can report: strokes, workspace faces, feature limits, speed and
    acceleration of every actuator and DOF, each actuator's jerk (a plan's refusal), end stops, the profile's
    keep-out spheres, the guard's measures, the implement's own limits and what a mode caps (the same name
    constructors the planner uses)."""
    codes: list[str] = [n for pair in STROKE_NAMES + WORKSPACE_NAMES for n in pair]
    codes += [n for _, lo, hi in FEATURE_LIMIT_ROWS for n in (lo, hi) if n]
    for kind in ("velocity", "acceleration"):
        codes += [str(LimitName(kind, n)) for n in ACTUATOR_NAMES + CONTROLLED_POSE_NAMES]
    codes += [str(LimitName("jerk", n)) for n in ACTUATOR_NAMES]  # a plan refused for a ramp rougher than the valves'
    codes += [str(LimitName("end_stop", n)) for n in ACTUATOR_NAMES]
    codes += [str(LimitName("keep_out", k.name)) for k in model.profile.limits.keep_out]
    codes += list(MEASURE_WORDS)
    codes += list(IMPLEMENT_WORDS)  # the selected implement's own limits (upper height, lowering speed)
    codes += list(MODE_WORDS)  # what a mode caps (attach: a quarter of full speed)
    return tuple(dict.fromkeys(codes))


def _vector(d: Any) -> np.ndarray | None:
    """Actuators (ACTUATOR_NAMES order) from a state's ``{"lift": …, …}``; None if any is missing or not finite."""
    if not isinstance(d, Mapping):
        return None
    try:
        q = np.array([float(d[n]) for n in ACTUATOR_NAMES])
    except (KeyError, TypeError, ValueError):
        return None
    return q if np.all(np.isfinite(q)) else None


class HitchView:
    """The picture's numbers for one hitch model (see the module docstring).

    Args:
        model: the service's profile and category.
        implement: the tractor profile's implement record attached (None: none), for the weights.
    """

    def __init__(self, model: HitchModel, implement: str | None = None):
        self.model = model
        prof = model.profile
        self.pivot_height = float(prof.geometry.pivot_height)
        self.ground_z = -self.pivot_height
        self.thresholds = StabilityThresholds()  # the service's guard uses the defaults
        self.tractor_weight_n: float | None = None
        self.weight_factor: float | None = None
        self.rear_wheel: dict[str, float] | None = None
        try:
            tp = load_tractor_profile(prof.stability.tractor_profile)
            tractor = tp.tractor(self.pivot_height)
            implement_mass = tp.implement(implement).mass if implement is not None else 0.0
            self.tractor_weight_n = float(tractor.empty_weight)
            total = tractor.mass + float(prof.stability.front_ballast) + implement_mass
            self.weight_factor = total / tractor.mass
            # the rear-axle centre's height above ground is the tyre's static loaded radius
            self.rear_wheel = {
                "y": float(tractor.rear_axle[1]),
                "z": float(tractor.rear_axle[2]),
                "radius": float(tractor.rear_axle[2] - tractor.ground_z),
                "track": float(tractor.rear_track),
            }
        except HitchInputError:  # no tractor data: the picture has no wheel, the share no weight basis
            pass
        self._cache: dict[bytes, dict[str, Any] | None] = {}
        self.computed = 0  # forward-kinematics evaluations (the cost the tests bound)

    @classmethod
    def build(cls, profile: str, category: str | None = None, implement: str | None = None) -> HitchView:
        """A view with a fresh model of ``profile`` and ``category`` (takes seconds: the model compiles)."""
        return cls(HitchModel.from_profile(profile, category), implement)

    # ------------------------------------------------------------------ static
    def terminal(self) -> dict[str, Any]:
        """What the page needs once: ground, workspace, strokes, thresholds, weights, words."""
        m = self.model
        th = self.thresholds
        codes = limit_codes(m)
        return {
            "profile": m.profile.name,
            "category": m.category,
            "ground_z": self.ground_z,
            "pivot_height": self.pivot_height,
            "workspace": None if m.workspace is None else {k: list(v) for k, v in m.workspace.items()},
            "strokes": {n: [float(lo), float(hi)] for n, lo, hi in zip(ACTUATOR_NAMES, m.lower, m.upper, strict=True)},
            "points": list(POINT_NAMES),
            "thresholds": {
                "front_axle_fraction": [th.front_axle_fraction_hard, th.front_axle_fraction_caution],
                "ssm": [th.ssm_hard, th.ssm_caution],
                "lsm": [th.lsm_hard, th.lsm_caution],
                "esm": [th.esm_hard, th.esm_caution],
            },
            "tractor_weight_n": self.tractor_weight_n,
            "weight_factor": self.weight_factor,
            "rear_wheel": self.rear_wheel,
            "words": {c: words(c) for c in codes},
            "key_words": dict(KEY_WORDS),
            "highlight": {c: list(highlight(c)) for c in codes},
            "view_rate_hz": VIEW_RATE_HZ,
        }

    # ------------------------------------------------------------------ per state
    def pose_points(self, q: np.ndarray) -> dict[str, Any] | None:
        """Points, heights above ground and lift share for actuators ``q`` (None: the mechanism
        does not close there). Remembers the last few actuator sets (at rest nothing is recomputed)."""
        key = q.tobytes()
        if key in self._cache:
            return self._cache[key]
        try:
            st = self.model.forward(q)
        except (KinematicsError, ValueError):
            out = None
        else:
            self.computed += 1
            pts = {n: [round(float(c), _DIGITS) for c in st.points[n]] for n in POINT_NAMES}
            lo, hi = float(self.model.lower[0]), float(self.model.upper[0])
            out = {
                "points": pts,
                "above_ground": {n: round(float(st.points[n][2]) + self.pivot_height, _DIGITS) for n in GROUND_POINTS},
                "lift_fraction": (float(q[0]) - lo) / (hi - lo),
            }
        if len(self._cache) >= 8:
            self._cache.pop(next(iter(self._cache)))
        self._cache[key] = out
        return out

    def message(self, state: Mapping[str, Any]) -> dict[str, Any]:
        """The ``view`` message for one state message (a dict as the service publishes it)."""
        q = _vector(state.get("actuators"))
        ref = state.get("reference")
        qr = _vector(ref.get("actuators")) if isinstance(ref, Mapping) else None
        goal = state.get("goal")
        qg = _vector(goal.get("actuators")) if isinstance(goal, Mapping) else None
        limited_in = state.get("limited")
        limited: list[dict[str, Any]] = []
        lit: list[str] = []
        if isinstance(limited_in, Mapping):
            # each limit once: a track DOF flagged by a limit and the guard's reason on that limit are one entry
            for k, said in limited_entries(limited_in, self.tractor_weight_n):
                v = str(limited_in[k])
                code = v.split(":", 1)[1].split(" would be", 1)[0].strip() if " would be " in v else v
                members = highlight(code) or highlight(str(k).rstrip("+-"))
                limited.append({"key": str(k), "code": code, "words": said, "highlight": list(members)})
                lit += [mm for mm in members if mm not in lit]
        share = None
        stab = state.get("stability")
        if isinstance(stab, Mapping) and self.weight_factor is not None:
            s = stab.get("front_axle_share")
            if isinstance(s, (int, float)) and math.isfinite(s):
                share = float(s) * self.weight_factor
        return {
            "seq": state.get("seq"),
            "t": state.get("t"),
            "measured": None if q is None else self.pose_points(q),
            "reference": None if qr is None else self.pose_points(qr),
            "goal": None if qg is None else self.pose_points(qg),
            "limited": limited,
            "highlight": lit,
            "front_axle_of_tractor_weight": share,
        }
