"""Count approach: where each piston stops inside its AD count, chosen by how it comes into the count.

The references are whole 10-bit counts (0xFF21), and the ECU's unit controller cuts a cylinder's valve
when its reading *reaches* the reference count; the piston then coasts on by what the oil in flight
gives. Stepped into count ``c`` from rest ``k`` counts away, it therefore stops at a repeatable place
inside the count, one for each side and back-off (on the twin's ECU the spread is 0.01–0.03 count):

    stop = c + s_below[k]      (rising into c from c − k)
    stop = c + s_above[k]      (falling into c from c + k)

with per-actuator offsets [counts]. The heavy lift coasts the most and the further the faster it comes
(twin, from below: +0.19, +0.31, +0.43 for k = 1, 2, 3; from 4 counts it coasts into the next count and is
driven back); the others stop about 0.1 count inside whatever k. A goto whose last move ends however it
comes leaves a piston anywhere in its count (sd ≈ 0.27 count), on top of rounding the goal to a whole
count (± 0.5): about ± 1 count in all.

With the offsets known, every (c, d, k) is a known stop; per actuator the one nearest the exact
(unrounded) goal ``u`` is chosen:

    (c, d, k) = argmin |c + s_d[k] − u|,   via = c − d · k

``d`` may be fixed per actuator (``sides``): the side from which the goto's final approach segment brings
it (``bridge.link.count_tail.arrival_sides``), so that with the profile's ``motion.final_approach`` the pin
play stays taken up on one side (a lift entering its last
count from above lets the implement's play swing: pitch errors of 3 mrad on the twin). The approach
streams ``via`` for ``via_hold_s`` (the piston settles there), then ``c`` for ``final_hold_s`` (it creeps
into ``c``). Measured on the twin: ``bench/count_floor_bench.py`` and ``bench/calibration_bench.py``
(docs/commissioning.md).

Profile: ``motion.count_approach`` (:class:`planner.profiles.hitch.CountApproachSettings`). The offsets
are the ECU's and the hydraulics', not the geometry's: measure them on the machine's twin
(:func:`bridge.sim.accuracy_run.measure_stop_offsets`). Pure functions; the service streams the result
(``bridge/service/motion``), as does the twin's goto runner (``bridge/sim/accuracy_run.py``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchInputError
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import CountApproachSettings

__all__ = ["CountApproach", "CountApproachError", "build_count_approach", "count_approach_for"]

#: the most counts a via may lie from its final count
MAX_BACK_OFF_COUNTS = 5


class CountApproachError(HitchInputError):
    """Bad input to :func:`build_count_approach` (names the field and the allowed range)."""


@dataclass(frozen=True)
class CountApproach:
    """The end of one goto in AD counts (actuator order lift, tilt, top, left, right).

    Attributes:
        unrounded_counts: the exact goal u [counts, float].
        final_counts: the reference count c each actuator ends on [int].
        via_counts: the count streamed first, ``c − d · k`` [int].
        directions: d, +1 rising into c (from below), −1 falling into it (from above).
        back_off_counts: k, how far the via lies from c [counts, int ≥ 1].
        stop_counts: where the piston is expected to stop, ``c + s_d[k]`` [counts, float].
        via_hold_s, final_hold_s: how long the via and then c are streamed before the motion ends [s].
    """

    unrounded_counts: np.ndarray
    final_counts: np.ndarray
    via_counts: np.ndarray
    directions: np.ndarray
    back_off_counts: np.ndarray
    stop_counts: np.ndarray
    via_hold_s: float
    final_hold_s: float

    @property
    def duration_s(self) -> float:
        """Via and final hold together [s]."""
        return self.via_hold_s + self.final_hold_s

    @property
    def residual_counts(self) -> np.ndarray:
        """Expected stop minus the exact goal [counts]."""
        return self.stop_counts - self.unrounded_counts


def _vector(name: str, value: ArrayLike, lo: float, hi: float) -> np.ndarray:
    v = np.asarray(value, float).reshape(-1)
    if v.size != len(ACTUATOR_NAMES):
        raise CountApproachError(
            f"{name}: need {len(ACTUATOR_NAMES)} values ({', '.join(ACTUATOR_NAMES)}), got {v.size}"
        )
    for k, x in zip(ACTUATOR_NAMES, v, strict=True):
        if not (math.isfinite(x) and lo <= x <= hi):
            raise CountApproachError(f"{name}.{k}: {float(x):g} is outside the allowed [{lo:g}, {hi:g}] counts")
    return v


def _stops(name: str, value: Sequence[Sequence[float]]) -> list[np.ndarray]:
    """Per actuator the stop offsets after a back-off of 1, 2, … counts (1 to 5 of them, each in (−1, 1))."""
    if len(value) != len(ACTUATOR_NAMES):
        raise CountApproachError(f"{name}: need one list per actuator ({', '.join(ACTUATOR_NAMES)}), got {len(value)}")
    out = []
    for k, row in zip(ACTUATOR_NAMES, value, strict=True):
        v = np.asarray(row, float).reshape(-1)
        if not 1 <= v.size <= MAX_BACK_OFF_COUNTS:
            raise CountApproachError(f"{name}.{k}: need 1 to {MAX_BACK_OFF_COUNTS} offsets, got {v.size}")
        bad = [x for x in v if not (math.isfinite(x) and -1.0 < x < 1.0)]
        if bad:
            raise CountApproachError(f"{name}.{k}: {float(bad[0]):g} is outside the allowed (-1, 1) counts")
        out.append(v)
    return out


def build_count_approach(
    unrounded_counts: ArrayLike,
    from_below_counts: Sequence[Sequence[float]],
    from_above_counts: Sequence[Sequence[float]],
    counts_lo: ArrayLike,
    counts_hi: ArrayLike,
    *,
    sides: ArrayLike | None = None,
    via_hold_s: float = 0.6,
    final_hold_s: float = 0.6,
) -> CountApproach:
    """The count approach to the exact goal ``unrounded_counts`` (5 actuators, counts).

    ``from_below_counts[i][k-1]`` / ``from_above_counts[i][k-1]``: actuator i's stop offset after rising /
    falling into its count from ``k`` counts away. Per actuator, over the counts around the goal, the sides
    allowed (``sides[i]``: +1 only from below, −1 only from above, 0 either; None: either) and the back-offs
    given, the (c, d, k) whose stop is nearest ``u`` among those whose ``c`` and via lie within
    ``[counts_lo, counts_hi]`` (the references the link accepts); ties go to the count nearest ``u``, then
    to the shortest back-off, then to rising.

    Raises:
        CountApproachError: a value out of its range, or an actuator with no count in range (the goal
            itself is then outside the references the link accepts).
    """
    u = _vector("unrounded_counts", unrounded_counts, -1e6, 1e6)
    below = _stops("from_below_counts", from_below_counts)
    above = _stops("from_above_counts", from_above_counts)
    lo = _vector("counts_lo", counts_lo, -1e6, 1e6)
    hi = _vector("counts_hi", counts_hi, -1e6, 1e6)
    side = np.zeros(5) if sides is None else _vector("sides", sides, -1.0, 1.0)
    if not np.all(np.isin(side, (-1.0, 0.0, 1.0))):
        raise CountApproachError(f"sides: each must be -1, 0 or 1, got {side.tolist()}")
    for name, v in (("via_hold_s", via_hold_s), ("final_hold_s", final_hold_s)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and 0.0 < v <= 10.0):
            raise CountApproachError(f"{name}: {v!r} is outside the allowed (0, 10] s")
    final, via, dirs, back, stop = (np.zeros(5) for _ in range(5))
    for i, name in enumerate(ACTUATOR_NAMES):
        best: tuple[float, float, int, int, int, float] | None = None  # (error, |c − u|, k, −d, c, stop)
        for c in range(math.floor(u[i]) - 1, math.floor(u[i]) + 3):
            for d, offsets in ((1, below[i]), (-1, above[i])):
                if side[i] not in (0.0, d):
                    continue
                for k, s in enumerate(offsets, start=1):
                    v = c - d * k
                    if not (lo[i] <= c <= hi[i] and lo[i] <= v <= hi[i]):
                        continue
                    key = (abs(c + s - u[i]), abs(c - u[i]), k, -d, c, c + s)
                    if best is None or key < best:
                        best = key
        if best is None:
            raise CountApproachError(
                f"{name}: no count near {u[i]:.2f} with its via within [{lo[i]:g}, {hi[i]:g}] counts"
            )
        _, _, k, neg_d, c, s = best
        final[i], dirs[i], back[i], stop[i] = c, -neg_d, k, s
        via[i] = c - dirs[i] * k
    return CountApproach(
        u.copy(),
        final.astype(np.int64),
        via.astype(np.int64),
        dirs.astype(np.int64),
        back.astype(np.int64),
        stop,
        float(via_hold_s),
        float(final_hold_s),
    )


def count_approach_for(
    settings: CountApproachSettings,
    scaling: SensorScaling,
    goal_actuators: ArrayLike,
    sides: ArrayLike | None = None,
) -> CountApproach:
    """:func:`build_count_approach` for the goal's actuators ``goal_actuators`` (SI: lift [rad], the others
    [m]) with a profile's ``motion.count_approach`` and sensor map, within the sensors' spans (the link's own
    limits are checked on the result); ``sides``: as there."""
    return build_count_approach(
        scaling.counts_of(goal_actuators),
        settings.from_below_counts.values(),
        settings.from_above_counts.values(),
        scaling.counts_min,
        scaling.counts_max,
        sides=sides,
        via_hold_s=settings.via_hold_s,
        final_hold_s=settings.final_hold_s,
    )
