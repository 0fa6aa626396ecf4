"""A terrain-following client's ground profile from body-mounted ground sensors: the preview of the
ground under the implement, in travelled distance.

A look-ahead ground-distance sensor on the tractor's front (:class:`bridge.sim.terrain.LookAheadGroundSensor`)
sees the ground ``sensor_ahead_m`` before the implement reaches it, but it is fixed to the tractor's
body: it measures the ground relative to the body's contact plane *now*, and the body pitches and
heaves with the ground under its own wheels. What the implement will need when it gets there is the
ground relative to the contact plane *then*. So the client rebuilds the world profile H(σ) [m] along
the travelled distance σ of the rear axle and predicts from it.

Model (rigid tractor on rigid tyres, a longitudinal profile: the twin's :mod:`bridge.sim.terrain`
contact plane with no cross slope): the rear axle rests on the ground under it, so the contact plane
at rear-axle distance σ is ``z = H(σ) + b·(s − σ)`` with the body's slope ``b = tan θ`` (θ the slope
sensor's pitch, + nose up) and ``b = (H(σ + L) − H(σ)) / L`` (L the wheelbase). With a = the
look-ahead sensor's point ahead of the rear axle and d the implement's behind it, every sample is a
linear equation in H:

* look-ahead sensor (mount height m above the plane, reading r): ``H(σ + a) − H(σ) = (m − r) + a·tan θ``;
* the implement's sensor (ground under the implement above the plane, g = pivot height + measured z −
  its reading): ``H(σ − d) − H(σ) = g − d·tan θ``;
* the slope sensor: ``H(σ + L) − H(σ) = L·tan θ``;

each keyed by the odometer's distance when it was valid (the slope sensor's reported latency taken
off). :meth:`GroundProfileEstimator.solve` finds H on a grid (``step_m``, linear between nodes) over a
window from ``behind_window_m`` behind the implement to the newest point seen: weighted least squares
of those equations and a smoothness prior (second differences ~ N(0, ``curvature_sigma_m``)), which also
fixes what the differences leave open (the constant). The ground under the implement relative to the
contact plane when the rear axle is at σ is then (as the twin computes it)

    g(σ) = H(σ − d) − H(σ) + (d / L)·(H(σ + L) − H(σ)),

known up to ``a − L`` ahead of the rear axle (beyond the newest point H is held at its last value).
A terrain-following client sends the tool point's height ``working − pivot + g`` in the tractor frame
(:func:`bridge.service.track_loop.run_track_loop`, ``ground_setpoint="plan"``).

Assumptions (stated, as the twin models them): rigid tyres and suspension, no cross slope (a cross
slope moves the plane's height at the centreline by the mean of the two wheels, which this model
takes as H), the contact points at their nominal horizontal positions.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from planner.errors import HitchInputError

__all__ = ["GroundPreviewError", "GroundPreviewGeometry", "GroundProfileEstimator"]


class GroundPreviewError(HitchInputError):
    """A ground-preview setting out of its range (the message names the field and the range)."""


def _number(name: str, v: object, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise GroundPreviewError(f"{name} must be a number in [{lo:g}, {hi:g}], got {v!r}")
    return float(v)


@dataclass(frozen=True)
class GroundPreviewGeometry:
    """Where the sensors are and how good they are (the client's configuration, SI).

    Attributes:
        wheelbase_m: L [m], (0, 10].
        implement_behind_m: the implement's ground point behind the rear axle, d [m], [0, 10].
        sensor_ahead_m: the look-ahead sensor's point ahead of the implement's [m], (0, 20]; it must be
            ahead of the rear axle (> ``implement_behind_m``).
        mount_height_m: the look-ahead sensor's height above the contact plane at its point [m], [0.1, 3].
        sensor_noise_m: its noise RMS [m], [0, 0.05] (a floor of 0.5 mm is used as the weight).
        implement_noise_m: the implement sensor's and measured height's noise [m], [0, 0.05] (floor 0.5 mm).
        pitch_noise_rad: the slope sensor's pitch noise [rad], [0, 0.05] (floor 0.05 mrad).
    """

    wheelbase_m: float
    implement_behind_m: float
    sensor_ahead_m: float
    mount_height_m: float
    sensor_noise_m: float = 0.003
    implement_noise_m: float = 0.001
    pitch_noise_rad: float = 3e-4

    def __post_init__(self) -> None:
        if _number("wheelbase_m", self.wheelbase_m, 0.0, 10.0) <= 0.0:
            raise GroundPreviewError(f"wheelbase_m must be a number in (0, 10], got {self.wheelbase_m!r}")
        _number("implement_behind_m", self.implement_behind_m, 0.0, 10.0)
        _number("sensor_ahead_m", self.sensor_ahead_m, 0.0, 20.0)
        if self.sensor_ahead_m <= self.implement_behind_m:
            raise GroundPreviewError(
                f"sensor_ahead_m = {self.sensor_ahead_m!r} m must exceed implement_behind_m = "
                f"{self.implement_behind_m!r} m (the sensor ahead of the rear axle), allowed "
                f"({self.implement_behind_m:g}, 20] m"
            )
        _number("mount_height_m", self.mount_height_m, 0.1, 3.0)
        _number("sensor_noise_m", self.sensor_noise_m, 0.0, 0.05)
        _number("implement_noise_m", self.implement_noise_m, 0.0, 0.05)
        _number("pitch_noise_rad", self.pitch_noise_rad, 0.0, 0.05)

    @property
    def ahead_of_rear_m(self) -> float:
        """a: the look-ahead sensor's point ahead of the rear axle [m]."""
        return self.sensor_ahead_m - self.implement_behind_m


class GroundProfileEstimator:
    """The world ground profile H(σ) from the tractor's ground and slope sensors (module docstring).

    Args:
        geometry: the sensors' geometry and noise.
        step_m: grid step [m], [0.02, 1].
        behind_window_m: how far behind the implement's point the window reaches [m], [0.5, 50].
        curvature_sigma_m: the smoothness prior's RMS second difference per node [m], [1e-5, 1].
    """

    def __init__(
        self,
        geometry: GroundPreviewGeometry,
        *,
        step_m: float = 0.1,
        behind_window_m: float = 4.0,
        curvature_sigma_m: float = 0.002,
    ) -> None:
        self.geometry = geometry
        self.step_m = _number("step_m", step_m, 0.02, 1.0)
        self.behind_window_m = _number("behind_window_m", behind_window_m, 0.5, 50.0)
        self.curvature_sigma_m = _number("curvature_sigma_m", curvature_sigma_m, 1e-5, 1.0)
        self._rows: deque[tuple[tuple[float, ...], tuple[float, ...], float, float]] = deque()
        self._newest = -math.inf  # the farthest point a row reaches [m]
        self._nodes: np.ndarray = np.zeros(0)
        self._h: np.ndarray = np.zeros(0)

    def __len__(self) -> int:
        return len(self._rows)

    def _row(self, points: tuple[float, ...], coefs: tuple[float, ...], rhs: float, sigma: float) -> None:
        if not all(math.isfinite(v) for v in (*points, rhs)):
            raise GroundPreviewError(f"a ground sample must be finite, got points {points}, value {rhs!r}")
        self._rows.append((points, coefs, rhs, sigma))
        self._newest = max(self._newest, *points)

    def add_ahead(self, sigma_m: float, reading_m: float, pitch_rad: float) -> None:
        """A look-ahead reading ``reading_m`` [m] taken with the rear axle at ``sigma_m`` [m] and the
        body's pitch ``pitch_rad`` [rad] then."""
        g = self.geometry
        a = g.ahead_of_rear_m
        sig = math.hypot(max(g.sensor_noise_m, 5e-4), a * max(g.pitch_noise_rad, 5e-5))
        rhs = (g.mount_height_m - reading_m) + a * math.tan(pitch_rad)
        self._row((sigma_m + a, sigma_m), (1.0, -1.0), rhs, sig)

    def add_implement(self, sigma_m: float, ground_above_plane_m: float, pitch_rad: float) -> None:
        """The ground under the implement above the contact plane [m] (pivot height + measured z − the
        implement sensor's reading) with the rear axle at ``sigma_m`` and the pitch then."""
        g = self.geometry
        d = g.implement_behind_m
        sig = math.hypot(max(g.implement_noise_m, 5e-4), d * max(g.pitch_noise_rad, 5e-5))
        self._row((sigma_m - d, sigma_m), (1.0, -1.0), ground_above_plane_m - d * math.tan(pitch_rad), sig)

    def add_pitch(self, sigma_m: float, pitch_rad: float) -> None:
        """The slope sensor's pitch [rad] (+ nose up) with the rear axle at ``sigma_m``."""
        g = self.geometry
        L = g.wheelbase_m
        self._row((sigma_m + L, sigma_m), (1.0, -1.0), L * math.tan(pitch_rad), L * max(g.pitch_noise_rad, 5e-5))

    @property
    def newest_m(self) -> float:
        """The farthest distance seen [m] (−inf before the first sample)."""
        return self._newest

    def solve(self, sigma_now_m: float) -> bool:
        """Re-estimate H over the window for the rear axle at ``sigma_now_m``; False without samples."""
        g = self.geometry
        h = self.step_m
        start = sigma_now_m - g.implement_behind_m - self.behind_window_m
        if self._rows and min(min(r[0]) for r in self._rows) < start:  # rows reaching behind the window go
            self._rows = deque(r for r in self._rows if min(r[0]) >= start)
        if not self._rows or not math.isfinite(self._newest):
            return False
        i0 = math.floor(start / h)
        i1 = math.ceil(self._newest / h) + 1
        nodes = h * np.arange(i0, i1 + 1)
        n = nodes.size
        pts = np.array([p for row in self._rows for p in row[0]])
        coefs = np.array([c for row in self._rows for c in row[1]])
        rows = np.repeat(np.arange(len(self._rows)), [len(row[0]) for row in self._rows])
        sig = np.array([row[3] for row in self._rows])
        rhs = np.array([row[2] for row in self._rows]) / sig
        u = (pts - nodes[0]) / h
        j = np.clip(np.floor(u).astype(int), 0, n - 2)
        w = np.clip(u - j, 0.0, 1.0)
        val = coefs / sig[rows]
        a = sp.csr_matrix(
            (np.concatenate([val * (1.0 - w), val * w]), (np.concatenate([rows, rows]), np.concatenate([j, j + 1]))),
            shape=(len(self._rows), n),
        )
        # normal equations of the samples, the smoothness prior (second differences / curvature_sigma_m) and
        # the gauge (the window's mean near 0, weight 1 / (10 m)): n x n, symmetric positive definite
        d2 = sp.diags([1.0, -2.0, 1.0], [0, 1, 2], shape=(max(n - 2, 0), n)) / self.curvature_sigma_m
        normal = (a.T @ a + d2.T @ d2).toarray() + 1.0 / (n * 10.0) ** 2
        self._h = np.asarray(np.linalg.solve(normal, a.T @ rhs), float)
        self._nodes = nodes
        return True

    def height(self, sigma: np.ndarray | float) -> np.ndarray:
        """H at ``sigma`` [m] (the last solve's; held at the window's ends)."""
        if self._nodes.size == 0:
            raise GroundPreviewError("ground preview: no profile yet (solve first)")
        return np.interp(np.asarray(sigma, float), self._nodes, self._h)

    def implement_ground(self, sigma_rear: np.ndarray | float) -> np.ndarray:
        """g: the ground under the implement above the contact plane [m] with the rear axle at
        ``sigma_rear`` [m] (module docstring)."""
        g = self.geometry
        s = np.asarray(sigma_rear, float)
        d, L = g.implement_behind_m, g.wheelbase_m
        h0 = self.height(s)
        return self.height(s - d) - h0 + (d / L) * (self.height(s + L) - h0)
