"""The twin's preview ground sensor: a ground-distance sensor on the tractor's front, looking at the ground ahead.

A sensor (ultrasonic or radar, pointing down) is mounted ``ahead_of_front_axle_m`` ahead of the front
axle (on the front ballast or the front linkage), ``height_m`` above the tractor's contact plane. It
reads its distance to the ground along the body's vertical,

    reading = height_m − ρ(s, F) + n,   F = wheelbase + ahead_of_front_axle_m,

with ρ(s, F) the ground's height above the contact plane F ahead of the rear axle (the contact plane
of :mod:`bridge.sim.terrain`: the same closed form :meth:`TerrainTwin.implement_ground_z` uses behind
the rear axle, here ahead of it), n white Gaussian noise of ``noise_rms_m`` (seeded), the result
rounded to ``resolution_m``. The lateral offset is 0 (centreline; the cross slope adds nothing there).

Defaults (assumed, typical of agricultural ultrasonic height sensors): 1 m ahead of the front axle,
0.8 m high, 3 mm RMS noise, 1 mm resolution.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bridge.sim.terrain import TerrainTwin, contact_plane
from planner.errors import HitchInputError

__all__ = ["PreviewSensor", "PreviewSensorConfig", "PreviewSensorError"]


class PreviewSensorError(HitchInputError):
    """A preview-sensor setting that cannot be used; the message names the field and range."""


def _num(name: str, v: object, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise PreviewSensorError(f"{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


@dataclass(frozen=True)
class PreviewSensorConfig:
    """Mounting and noise of the preview sensor (SI units).

    Attributes:
        ahead_of_front_axle_m: the sensor's ground point ahead of the front axle [m], [0.2, 5].
        height_m: its height above the contact plane [m], [0.2, 3].
        noise_rms_m: white noise per reading (1 σ) [m], [0, 0.1].
        resolution_m: the reading's rounding [m], [0, 0.05] (0: none).
        seed: the noise's seed.
    """

    ahead_of_front_axle_m: float = 1.0
    height_m: float = 0.8
    noise_rms_m: float = 0.003
    resolution_m: float = 0.001
    seed: int = 0

    def __post_init__(self) -> None:
        _num("ahead_of_front_axle_m", self.ahead_of_front_axle_m, 0.2, 5.0)
        _num("height_m", self.height_m, 0.2, 3.0)
        _num("noise_rms_m", self.noise_rms_m, 0.0, 0.1)
        _num("resolution_m", self.resolution_m, 0.0, 0.05)
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or not 0 <= self.seed < 2**32:
            raise PreviewSensorError(f"seed must be an integer in [0, 2**32), got {self.seed!r}")


class PreviewSensor:
    """The preview sensor over one terrain twin (module docstring); each :meth:`read` draws new noise."""

    def __init__(self, twin: TerrainTwin, config: PreviewSensorConfig | None = None) -> None:
        self.twin = twin
        self.config = PreviewSensorConfig() if config is None else config
        self._rng = np.random.default_rng(self.config.seed)

    @property
    def ahead_of_rear_axle_m(self) -> float:
        """F: the sensor's ground point ahead of the rear axle [m]."""
        return self.twin.tractor.wheelbase_m + self.config.ahead_of_front_axle_m

    def true_ground_m(self, t: float) -> float:
        """ρ(s, F): the ground's true height above the contact plane under the sensor at ``t`` [m]."""
        tw = self.twin
        z0, b, _ = contact_plane(*tw.contacts_m(t), tw.tractor)
        f = self.ahead_of_rear_axle_m
        return tw.ground.profile_m(tw.distance_m(t) + f) - (z0 + b * f)

    def read(self, t: float) -> float:
        """The sensor's distance reading at ``t`` [m]: mounting height less the ground, with noise, rounded."""
        c = self.config
        r = c.height_m - self.true_ground_m(t) + (float(self._rng.normal(0.0, c.noise_rms_m)) if c.noise_rms_m else 0.0)
        if c.resolution_m > 0.0:
            r = round(r / c.resolution_m) * c.resolution_m
        return r
