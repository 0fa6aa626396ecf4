"""Ground preview: the ground under the tool a little ahead in travelled distance, from a sensor ahead.

Why. The hitch's z is measured in the tractor frame, so the ground the tool meets is the ground's
height above the tractor's *contact plane* at the tool, which moves as the tractor pitches over the
undulation. For a tractor on rigid axles travelling straight (level across), the contact plane
touches the ground under the rear axle (distance ``s``) and the front axle (``s + L``), so the
ground at ``x`` metres ahead of the rear axle stands above that plane by

    ρ(s, x) = h(s + x) − h(s) − (x / L)·(h(s + L) − h(s))                                       (1)

(``h`` the ground profile along the travel, ``L`` the wheelbase; :mod:`bridge.sim.terrain`'s contact
plane). The tool is ``d`` behind the rear axle: its ground is ``ρ(s, −d)``. Equation (1) is linear
in ``h`` and zero for any straight (affine) ground, so only the profile's curvature matters and an
unknown height or grade of the whole field drops out.

What is measured (every control cycle, at the travelled distance ``s`` from the odometer):

* a ground-distance sensor ``F`` ahead of the rear axle (on the tractor's front, ``F > L``) gives
  ``ρ(s, F)``, the ground ahead of the front wheels;
* the slope sensor's pitch gives ``tan(pitch) = (h(s + L) − h(s)) / L``;
* the implement's ground-distance sensor gives ``ρ(s, −d)``, the ground under the tool now
  (optional).

Estimate. :class:`GroundPreview` keeps the readings of the last few metres and fits the profile
``h`` on a grid of ``cell_m`` (piecewise linear) over a window from behind the tool to the front
sensor by weighted least squares: each reading is one linear equation in ``h`` (weights 1/σ of that
sensor), plus a weak smoothness prior (second differences, σ ``curvature_m``) and a weak pull of the
mean to 0 (the height is not observable and does not matter). Then

    ground_at_tool(s') = ρ(s', −d)   for   s ≤ s' ≤ s + (F − L)

is (1) evaluated on the fitted profile: the ground under the tool when the tractor will have
travelled to ``s'`` (its front axle must not have passed the sensor's last reading). With the
speed ``v`` and the hitch's lag ``τ``, ``s' = s + v·τ`` gives the ground to command against now
(the feed-forward of :class:`planner.work_control.WorkController`, ``ground_ahead_z``).

The window reaches back to the readings the front sensor took where the tool is now (``F + d``
behind), so the profile under the tool is the one the front sensor saw, and the pitch and tool
equations remove the shapes the front sensor alone cannot see (ground periodic in its spacing).
Cost: one least-squares solve of about ``(2·F + 2·d + back_m)/cell_m`` unknowns per
:meth:`GroundPreview.ground_at_tool` after new readings (≈ 55 unknowns at 0.2 m, a few hundred
rows: 0.5–0.8 ms of CPU in the field loop, measured).

Assumptions: straight travel with the sensors on the centreline, level across (no cross slope),
rigid axles; a constant speed between readings is not needed (the readings are placed by distance).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from planner.errors import HitchInputError

__all__ = ["GroundPreview", "GroundPreviewError", "PreviewGeometry"]


class GroundPreviewError(HitchInputError):
    """A preview geometry or reading that cannot be used; the message names the field and range."""


def _num(name: str, v: object, lo: float, hi: float, *, open_lo: bool = False) -> float:
    rng = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]"
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise GroundPreviewError(f"{name} must be a finite number in {rng}, got {v!r}")
    x = float(v)
    if x < lo or x > hi or (open_lo and x <= lo):
        raise GroundPreviewError(f"{name} = {v!r} is outside the allowed range {rng}")
    return x


@dataclass(frozen=True)
class PreviewGeometry:
    """Where the sensors and the tool are, and how sure each reading is (SI units).

    Attributes:
        wheelbase_m: L, rear axle to front axle [m], (0.5, 10].
        sensor_ahead_m: F, the preview sensor's ground point ahead of the rear axle [m]; more than L + 0.2.
        tool_behind_m: d, the tool's ground point behind the rear axle [m], [0, 10].
        cell_m: the profile's grid spacing [m], [0.02, 0.5].
        back_m: how far behind the tool the fitted window reaches [m], [0, 10].
        sensor_sigma_m, tool_sigma_m: the preview and implement sensors' noise (1 σ) [m], (0, 1].
        pitch_sigma_rad: the slope sensor's pitch noise (1 σ) [rad], (0, 0.1].
        curvature_m: the smoothness prior, 1 σ of a second difference of the profile over one cell [m], (0, 1].
    """

    wheelbase_m: float = 2.70
    sensor_ahead_m: float = 3.70
    tool_behind_m: float = 1.20
    cell_m: float = 0.20
    back_m: float = 0.5
    sensor_sigma_m: float = 0.003
    tool_sigma_m: float = 0.003
    pitch_sigma_rad: float = 0.0005
    curvature_m: float = 0.002

    def __post_init__(self) -> None:
        _num("wheelbase_m", self.wheelbase_m, 0.5, 10.0, open_lo=True)
        _num("sensor_ahead_m", self.sensor_ahead_m, 0.0, 20.0)
        if not self.sensor_ahead_m > self.wheelbase_m + 0.2:
            raise GroundPreviewError(
                f"sensor_ahead_m = {self.sensor_ahead_m!r} must exceed wheelbase_m + 0.2 = {self.wheelbase_m + 0.2:g} "
                "(the preview sensor looks ahead of the front axle)"
            )
        _num("tool_behind_m", self.tool_behind_m, 0.0, 10.0)
        _num("cell_m", self.cell_m, 0.02, 0.5)
        _num("back_m", self.back_m, 0.0, 10.0)
        _num("sensor_sigma_m", self.sensor_sigma_m, 0.0, 1.0, open_lo=True)
        _num("tool_sigma_m", self.tool_sigma_m, 0.0, 1.0, open_lo=True)
        _num("pitch_sigma_rad", self.pitch_sigma_rad, 0.0, 0.1, open_lo=True)
        _num("curvature_m", self.curvature_m, 0.0, 1.0, open_lo=True)

    @property
    def preview_m(self) -> float:
        """How far ahead of the current distance :meth:`GroundPreview.ground_at_tool` reaches: F − L [m]."""
        return self.sensor_ahead_m - self.wheelbase_m


@dataclass(frozen=True)
class _Reading:
    s: float
    tan_pitch: float
    ahead: float
    tool: float | None


class GroundPreview:
    """The ground under the tool ahead in travelled distance (module docstring). Not thread-safe."""

    def __init__(self, geometry: PreviewGeometry | None = None) -> None:
        self.geometry = PreviewGeometry() if geometry is None else geometry
        if not isinstance(self.geometry, PreviewGeometry):
            raise GroundPreviewError(f"geometry must be a PreviewGeometry, got {type(geometry).__name__}")
        self._rows: deque[_Reading] = deque()
        self._fit: tuple[float, np.ndarray] | None = None  # (grid origin [m], heights [m])

    @property
    def distance_m(self) -> float | None:
        """The distance of the newest reading (None: none yet)."""
        return self._rows[-1].s if self._rows else None

    def reset(self) -> None:
        """Forget every reading (a new pass, a reversal, a lost odometer)."""
        self._rows.clear()
        self._fit = None

    def add(
        self, distance_m: float, pitch_rad: float, ahead_ground_m: float, tool_ground_m: float | None = None
    ) -> None:
        """One set of readings at the travelled distance ``distance_m`` [m]: the tractor's pitch [rad, + nose
        up], the ground's height above the contact plane at the preview sensor ``ahead_ground_m`` (ρ(s, F),
        the sensor's mounting height less its reading) [m], and optionally at the tool (ρ(s, −d)) [m].
        A distance below the newest one resets the buffer (the tractor reversed or the odometer restarted)."""
        s = _num("distance_m", distance_m, -1.0e7, 1.0e7)
        p = _num("pitch_rad", pitch_rad, -1.0, 1.0)
        a = _num("ahead_ground_m", ahead_ground_m, -5.0, 5.0)
        tool = None if tool_ground_m is None else _num("tool_ground_m", tool_ground_m, -5.0, 5.0)
        if self._rows and s < self._rows[-1].s:
            self.reset()
        g = self.geometry
        self._rows.append(_Reading(s, math.tan(p), a, tool))
        # a reading is kept while its preview point lies in the window: from ``back_m`` behind the tool on
        oldest = s - g.back_m - g.tool_behind_m - g.sensor_ahead_m - g.cell_m
        while self._rows and self._rows[0].s < oldest:
            self._rows.popleft()
        self._fit = None

    def ready(self, distance_m: float | None = None) -> bool:
        """The front sensor has seen the ground the tool meets at ``distance_m`` (default: now): the readings
        cover the window from the tool point to the front axle."""
        if not self._rows:
            return False
        g = self.geometry
        s_now = self._rows[-1].s
        s = s_now if distance_m is None else distance_m
        return self._rows[0].s + g.sensor_ahead_m <= s - g.tool_behind_m and s <= s_now + g.preview_m + 1e-9

    def ground_at_tool(self, distance_m: float) -> float:
        """ρ(s', −d): the ground's height above the contact plane at the tool [m] when the tractor has
        travelled ``distance_m`` [m] (between the newest reading and F − L beyond it).

        Raises:
            GroundPreviewError: not :meth:`ready` for that distance, or it lies outside the preview.
        """
        s1 = _num("distance_m", distance_m, -1.0e7, 1.0e7)
        g = self.geometry
        if not self._rows:
            raise GroundPreviewError("no readings yet")
        s_now = self._rows[-1].s
        if not s_now - g.back_m <= s1 <= s_now + g.preview_m + 1e-9:
            raise GroundPreviewError(
                f"distance_m = {s1:.3f} is outside the preview [{s_now - g.back_m:.3f}, {s_now + g.preview_m:.3f}] m"
            )
        if not self.ready(s1):
            raise GroundPreviewError(
                f"the preview sensor has not yet seen the ground under the tool at {s1:.3f} m "
                f"(readings from {self._rows[0].s:.3f} m)"
            )
        x0, h = self._solve()
        L, d = g.wheelbase_m, g.tool_behind_m
        hs = self._interp(x0, h, s1)
        return self._interp(x0, h, s1 - d) - hs + (d / L) * (self._interp(x0, h, s1 + L) - hs)

    def _interp(self, x0: float, h: np.ndarray, x: float) -> float:
        u = (x - x0) / self.geometry.cell_m
        i = min(len(h) - 2, max(0, int(math.floor(u))))
        f = u - i
        return float(h[i] * (1.0 - f) + h[i + 1] * f)

    def _solve(self) -> tuple[float, np.ndarray]:
        if self._fit is not None:
            return self._fit
        g = self.geometry
        L, F, d, c = g.wheelbase_m, g.sensor_ahead_m, g.tool_behind_m, g.cell_m
        rows = self._rows
        s_now = rows[-1].s
        x0 = math.floor((rows[0].s - d) / c) * c
        n = int(math.ceil((s_now + F - x0) / c)) + 2
        # each reading's equation: (points relative to s, coefficients), right-hand side, weight: equation (1)
        # of the module docstring at x = F, the pitch, and (1) at x = -d
        s = np.array([r.s for r in rows])
        eqs: list[tuple[np.ndarray, list[tuple[float, float]], np.ndarray, float]] = [
            (
                s,
                [(F, 1.0), (0.0, -1.0 + F / L), (L, -F / L)],
                np.array([r.ahead for r in rows]),
                1.0 / g.sensor_sigma_m,
            ),
            (s, [(L, 1.0), (0.0, -1.0)], L * np.array([r.tan_pitch for r in rows]), 1.0 / (L * g.pitch_sigma_rad)),
        ]
        tool = [(r.s, r.tool) for r in rows if r.tool is not None]
        if tool:
            st = np.array([t[0] for t in tool])
            rhs = np.array([t[1] for t in tool], dtype=float)
            eqs.append((st, [(-d, 1.0), (0.0, -1.0 - d / L), (L, d / L)], rhs, 1.0 / g.tool_sigma_m))
        # weighted least squares through its normal equations (n ≈ 55 unknowns: a small dense solve)
        normal = np.zeros((n, n))
        rhs_n = np.zeros(n)
        for pos, terms, rhs, w in eqs:
            a = np.zeros((len(pos), n))
            r_idx = np.arange(len(pos))
            for off, coef in terms:
                u = np.clip((pos + off - x0) / c, 0.0, n - 1.000001)
                i = np.floor(u).astype(int)
                f = u - i
                a[r_idx, i] += coef * (1.0 - f) * w  # (row, cell) pairs are unique within one term
                a[r_idx, i + 1] += coef * f * w
            normal += a.T @ a
            rhs_n += a.T @ (rhs * w)
        k = np.arange(n - 2)
        smooth = np.zeros((n - 2, n))
        smooth[k, k], smooth[k, k + 1], smooth[k, k + 2] = 1.0, -2.0, 1.0
        normal += (smooth.T @ smooth) / g.curvature_m**2
        normal += 1.0 / n**2  # the mean height (not observable) held near 0 with σ 1 m
        h = np.linalg.solve(normal, rhs_n)
        self._fit = (x0, h)
        return self._fit
