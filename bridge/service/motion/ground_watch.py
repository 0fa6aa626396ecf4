"""A stuck ground-distance sensor under a ``ground``-frame track session (``docs/tracking.md``).

In frame ``ground`` a setpoint z is a height above the ground: z_tractor = z_m + (z_set − d), with the
measured hitch height z_m and the ground distance d. A sensor that keeps sending one value while the hitch
moves turns that into positive feedback: every setpoint asks for the same difference again, and the hitch
runs to its height limit (a CAN fuzz trial: a ground distance held at 0.30 m drove the hitch to z = −0.218 m,
"height limit reached (bottom)").

:class:`GroundWatch` notices it: a reading that stayed within a band ``same_m`` wide for ``frozen_s`` while the
setpoints asked for a move of more than ``asked_min_m`` from it and the measured hitch height moved more than
``moved_m`` is stuck (a real sensor's noise and the follower's lag move
the reading whenever the hitch moves; ground that rises and falls exactly with the hitch for a second is not
what a field does). A setpoint within ``asked_min_m`` of the reading asks for nothing that could run away on
one reading — but a stuck sensor under it asks for the same few millimetres again every cycle (a review: a
setpoint 9 mm from a reading stuck at 0.30 m ran the hitch 333 mm to its bottom limit, never noticed), so a
reading that stays within the band for ``frozen_s`` while every setpoint asked for more than the band (``same_m``)
and the hitch moved more than ``moved_far_m`` is stuck too: a setpoint that stays further from its reading than
the reading's own band while the hitch runs on is not being met. A reading within the band of its setpoint
while the hitch follows a grade, however far, is not stuck (a second review: the rule counting whatever was
asked stopped a slow, well-tracked follower after 120 mm). Pure: no clock, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["GroundWatch", "FROZEN_S", "MOVED_M", "MOVED_FAR_M", "SAME_M", "ASKED_MIN_M"]

#: how long a reading must stay at one value while the hitch moves to be taken for stuck [s]
FROZEN_S = 1.0
#: how far the measured hitch height must move meanwhile [m] (beyond a follower's lag on a terrain ramp)
MOVED_M = 0.04
#: readings that keep within a band this wide count as one value [m]: a stuck sensor may dither by its
#: resolution step (a recheck: 0.300 / 0.301 m alternating ran the hitch to its bottom limit past a 1 µm band)
SAME_M = 0.003
#: a setpoint that asks for at most this much (setpoint − reading) asks for nothing that could run away on one
#: reading [m] (the hitch following a grade it reads well)
ASKED_MIN_M = 0.01
#: how far the measured hitch height may move with one reading while every setpoint asks for more than the band
#: ``SAME_M`` from it [m]: beyond the
#: 100 mm peak to peak of the ground a session follows
MOVED_FAR_M = 0.12


@dataclass
class _Span:
    """Since when [s] a condition held (None: not now) and the hitch height's range over that time [m]."""

    since_s: float | None = None
    z_min_m: float = 0.0
    z_max_m: float = 0.0

    def take(self, holds: bool, now_s: float, z_m: float) -> None:
        if not holds:
            self.since_s = None
        elif self.since_s is None:
            self.since_s, self.z_min_m, self.z_max_m = now_s, z_m, z_m
        else:
            self.z_min_m, self.z_max_m = min(self.z_min_m, z_m), max(self.z_max_m, z_m)

    def exceeds(self, now_s: float, held_s: float, moved_m: float) -> tuple[float, float] | None:
        """(time held [s], hitch moved [m]) when the condition held ``held_s`` and the hitch moved more than
        ``moved_m`` meanwhile, else None."""
        if self.since_s is None or now_s - self.since_s < held_s or self.z_max_m - self.z_min_m <= moved_m:
            return None
        return now_s - self.since_s, self.z_max_m - self.z_min_m


@dataclass
class GroundWatch:
    """The value a ground-distance reading stays at (its band's range [m]) and two spans of it: while the
    setpoints asked for more than ``asked_min_m`` (the 40 mm rule) and while they asked for more than the band
    ``same_m`` (the 120 mm rule)."""

    frozen_s: float = FROZEN_S
    moved_m: float = MOVED_M
    moved_far_m: float = MOVED_FAR_M
    same_m: float = SAME_M
    asked_min_m: float = ASKED_MIN_M
    value_m: float | None = None
    d_min_m: float = 0.0
    d_max_m: float = 0.0
    asked: _Span = field(default_factory=_Span)
    asked_some: _Span = field(default_factory=_Span)

    def check(self, distance_m: float, hitch_z_m: float, now_s: float, asked_m: float | None = None) -> str | None:
        """Take the reading ``distance_m`` with the measured hitch height ``hitch_z_m`` at ``now_s``; why the
        sensor looks stuck (a sentence with the value, the time and how far the hitch moved), else None.

        ``asked_m``: the setpoint's height above the ground less the reading [m] — the move the setpoint asks
        for (None: taken as asking for more than ``asked_min_m``). Stuck: the reading held for ``frozen_s`` while
        every setpoint asked for more than ``asked_min_m`` and the hitch moved more than ``moved_m``, or while
        every setpoint asked for more than the band ``same_m`` and the hitch moved more than ``moved_far_m``. A
        reading at its setpoint (within the band) while the hitch follows a grade, however far (a 1 mm sensor
        tracked to 0.2 mm reads one value, two reviews), is never stuck."""
        if self.value_m is not None:
            self.d_min_m, self.d_max_m = min(self.d_min_m, distance_m), max(self.d_max_m, distance_m)
        if self.value_m is None or self.d_max_m - self.d_min_m > self.same_m:  # a new value: the spans begin again
            self.value_m = self.d_min_m = self.d_max_m = distance_m
            self.asked.since_s = self.asked_some.since_s = None
        far = asked_m is None or abs(asked_m) > self.asked_min_m
        some = asked_m is None or abs(asked_m) > self.same_m
        self.asked.take(far, now_s, hitch_z_m)
        self.asked_some.take(some, now_s, hitch_z_m)
        hit = self.asked.exceeds(now_s, self.frozen_s, self.moved_m) or self.asked_some.exceeds(
            now_s, self.frozen_s, self.moved_far_m
        )
        return None if hit is None else self._why(*hit)

    def _why(self, held_s: float, moved_m: float) -> str:
        assert self.value_m is not None
        at = (
            f"at {self.value_m:.3f} m"
            if self.d_max_m - self.d_min_m < 0.0005
            else f"within {self.d_min_m:.3f} … {self.d_max_m:.3f} m"
        )
        return (
            f"the ground distance stayed {at} for {held_s:.1f} s while the hitch moved "
            f"{moved_m * 1000:.0f} mm: a stuck ground-distance sensor (frame 'ground' would drive the hitch to "
            "its height limit)"
        )
