"""The lower-link draft pins of the twin: noise, first-order filter, quantisation, and the ISO 11783-7
rear hitch status that carries the measured draft.

A draft pin (a strain-gauged lower-link pivot pin) measures the horizontal force in its lower
link; the two pins' sum is the draft. The implement's draft ``D`` is shared equally by the left
and right pins (a centred implement). Each pin reading is modelled as

    y_k = q(x_k),   x_k = x_{k-1} + α·(F_k + n_k - x_{k-1}),   α = 1 - e^(-Δt/τ)

with ``F_k`` the true pin force, ``n_k`` white Gaussian noise of ``noise_rms_n`` (seeded), a
first-order low-pass of time constant ``tau_s`` (the exact discretisation of ``τ·ẋ = u - x`` for
an input held over the step, so a step reaches 1 - 1/e ≈ 63.2 % at ``t = τ``), and ``q`` the
rounding to ``resolution_n``. The filter starts at the first force it sees (no start-up
transient).

:func:`rear_hitch_status` puts the measured draft into :class:`~bridge.isobus.messages.
RearHitchStatus` (PGN 65093): ``draft_n`` (the DBC's RearDraft, 10 N/bit, -320 000..322 550 N) and
``nominal_lower_link_force`` (the DBC's RearNominalLowerLinkForce, the draft as a fraction of a
nominal force, -1..1 at 0.8 %/bit). Values outside what the message can carry are sent as "not
available" (``None``), never clipped into a wrong number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bridge.isobus.j1939 import Switch
from bridge.isobus.messages import RearHitchStatus
from planner.errors import HitchInputError

__all__ = [
    "DRAFT_MAX_N",
    "DRAFT_MIN_N",
    "DraftPinConfig",
    "DraftPinError",
    "DraftPins",
    "DraftReading",
    "rear_hitch_status",
]

DRAFT_MIN_N = -320_000.0
"""The RearDraft field's range (DBC: 10 N/bit, offset -320 000 N)."""
DRAFT_MAX_N = 322_550.0


class DraftPinError(HitchInputError):
    """A draft-pin setting or input out of its range (named in the message)."""


def _number(name: str, value: object, lo: float, hi: float, *, open_lo: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise DraftPinError(f"{name} must be a number, got {value!r}")
    v = float(value)
    bad_lo = v <= lo if open_lo else v < lo
    if not math.isfinite(v) or bad_lo or v > hi:
        raise DraftPinError(f"{name} = {value!r} is outside the allowed range {'(' if open_lo else '['}{lo:g}, {hi:g}]")
    return v


@dataclass(frozen=True)
class DraftPinConfig:
    """One pair of lower-link draft pins.

    Attributes:
        noise_rms_n: white noise on each pin [N] (0..10 kN).
        tau_s: first-order filter time constant [s] (0 = no filter, ..10 s).
        resolution_n: quantisation step of each pin reading [N] (0 = none, ..1 kN).
        seed: noise seed.
    """

    noise_rms_n: float = 50.0
    tau_s: float = 0.1
    resolution_n: float = 10.0
    seed: int = 0

    def __post_init__(self) -> None:
        _number("noise_rms_n", self.noise_rms_n, 0.0, 10_000.0)
        _number("tau_s", self.tau_s, 0.0, 10.0)
        _number("resolution_n", self.resolution_n, 0.0, 1000.0)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**32:
            raise DraftPinError(f"seed = {self.seed!r} must be an integer in [0, 2^32)")


@dataclass(frozen=True)
class DraftReading:
    """One measurement: the left and right pin forces and their sum, the draft [N]."""

    left_n: float
    right_n: float

    @property
    def draft_n(self) -> float:
        return self.left_n + self.right_n


class DraftPins:
    """The two pins, stepped in simulated time (stateful: the filter and the noise stream)."""

    def __init__(self, config: DraftPinConfig | None = None) -> None:
        self._config = config or DraftPinConfig()
        self._rng = np.random.default_rng(self._config.seed)
        self._state: tuple[float, float] | None = None
        self._t: float | None = None

    @property
    def config(self) -> DraftPinConfig:
        return self._config

    def _quantise(self, x: float) -> float:
        q = self._config.resolution_n
        return x if q <= 0.0 else q * round(x / q)

    def measure(self, t: float, draft_n: float) -> DraftReading:
        """The pins' reading at time ``t`` [s] (non-decreasing) for the true draft ``draft_n`` [N]."""
        tt = _number("t", t, -1.0e9, 1.0e9)
        d = _number("draft_n", draft_n, -1.0e6, 1.0e6)
        if self._t is not None and tt < self._t:
            raise DraftPinError(f"t = {t!r} must not go back (last t = {self._t!r})")
        c = self._config
        noise = self._rng.normal(0.0, c.noise_rms_n, 2) if c.noise_rms_n > 0.0 else np.zeros(2)
        u = (0.5 * d + float(noise[0]), 0.5 * d + float(noise[1]))
        if self._state is None or self._t is None:
            x = u
        else:
            dt = tt - self._t
            a = 1.0 if c.tau_s <= 0.0 else 1.0 - math.exp(-dt / c.tau_s)
            x = (self._state[0] + a * (u[0] - self._state[0]), self._state[1] + a * (u[1] - self._state[1]))
        self._state, self._t = x, tt
        return DraftReading(left_n=self._quantise(x[0]), right_n=self._quantise(x[1]))


def rear_hitch_status(
    draft_n: float,
    *,
    nominal_force_n: float,
    position: float | None = None,
    in_work: Switch = Switch.NOT_AVAILABLE,
) -> RearHitchStatus:
    """The ISO 11783-7 rear hitch status carrying the measured ``draft_n`` [N].

    ``nominal_force_n`` (> 0) is the force the nominal lower-link force fraction is relative to
    (the tractor's rated draft). A draft outside the RearDraft range, or a fraction outside -1..1,
    is sent as not available.
    """
    d = _number("draft_n", draft_n, -1.0e7, 1.0e7)
    nominal = _number("nominal_force_n", nominal_force_n, 0.0, 1.0e6, open_lo=True)
    if position is not None:
        _number("position", position, 0.0, 1.0)
    fraction = d / nominal
    return RearHitchStatus(
        position=position,
        in_work=in_work,
        nominal_lower_link_force=fraction if -1.0 <= fraction <= 1.0 else None,
        draft_n=d if DRAFT_MIN_N <= d <= DRAFT_MAX_N else None,
    )
