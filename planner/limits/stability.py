"""Static stability of tractor + mounted implement: axle loads, SSM, LSM, ESM, front ballast.

Pure functions over :mod:`planner.limits.tractor` values.  The implement pose enters as the
tool point ``T`` (3,) [m] and its rotation ``R_i`` (3x3, columns x_i, y_i, z_i in the tractor
frame), so nothing here depends on the hitch model.

Slope convention.  ``slope_roll`` and ``slope_pitch`` [rad] are the tractor's attitude from its
IMU as Tait-Bryan angles in yaw-pitch-roll order: ``slope_pitch > 0`` = nose up (front higher
than rear, driving forward uphill), ``slope_roll > 0`` = left side up (the right side is
downhill).  The unit gravity direction in the tractor frame (x left, y rearward, z up) is

    g_hat = (-sin(roll) cos(pitch), sin(pitch), -cos(roll) cos(pitch)).

Measures (seed 003 §4.1.1-4.1.4, ESM after Messuri & Klein 1985) over the support triangle
rear-left contact, rear-right contact, front-axle pivot, with edges ``rear`` (backward
overturn), ``right`` (rear-right -> pivot) and ``left`` (pivot -> rear-left):

- SSM [m]: in-plane distance from the CoM's projection along g_hat onto the triangle's plane
  to the nearest edge; outside, minus the distance to the triangle.
- LSM [m]: along the direction of travel (tractor y axis in that plane), distance from the
  projection to where the line leaves the triangle going forward (``lsm_front``) and rearward
  (``lsm_rear``); ``lsm`` is the smaller (either direction of travel).  Negative when already
  past that exit; both equal SSM (< 0) if the line misses the triangle.
- ESM [J]: per edge, the energy m g (h_max - h0) to rotate the CoM about the edge up to the
  vertical plane through it; negative when already past that plane; the minimum over edges.
  Unlike SSM it sees CoM height and slope (seed 003 fig. 4.2).

SSM, LSM and ESM are all > 0 exactly when the projected CoM is strictly inside the triangle.
Forward overturn over the front wheels and the front-axle oscillation stops are not modelled.
"""

from __future__ import annotations

import math
import weakref
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np

from planner.limits.tractor import (
    STANDARD_GRAVITY,
    ImplementRecord,
    StabilityInputError,
    Tractor,
    _rotation,
    _scalar,
    _vector3,
)

__all__ = [
    "EDGE_NAMES",
    "MEASURE_UNITS",
    "Measure",
    "StabilityInputError",
    "gravity_direction",
    "LoadCase",
    "build_load_case",
    "AxleLoads",
    "axle_loads",
    "SupportMargins",
    "support_margins",
    "EnergyMargins",
    "energy_margins",
    "minimum_front_ballast",
    "StabilityThresholds",
    "StabilityViolation",
    "StabilityReport",
    "evaluate_stability",
]

#: Support-triangle edges, in the order of every per-edge tuple.
EDGE_NAMES: tuple[str, str, str] = ("rear", "right", "left")
#: A stability measure: front-axle load [N], SSM [m], LSM [m], ESM [J].
Measure = Literal["front_axle_load", "ssm", "lsm", "esm"]
#: The SI unit of each measure (its value and its thresholds).
MEASURE_UNITS: dict[str, str] = {"front_axle_load": "N", "ssm": "m", "lsm": "m", "esm": "J"}
_EDGES = ((0, 1, 2), (1, 2, 0), (2, 0, 1))  # (A, B, opposite vertex) over Tractor.support_vertices
#: pose-independent parts of the margins per tractor (a Tractor is frozen, its arrays read-only)
_SUPPORT_CACHE: weakref.WeakKeyDictionary[Tractor, tuple] = weakref.WeakKeyDictionary()
_ENERGY_CACHE: weakref.WeakKeyDictionary[Tractor, dict[bytes, tuple]] = weakref.WeakKeyDictionary()


def _dot(a, b) -> float:
    """a · b of two short vectors in IEEE doubles, summed left to right (a0 b0 + a1 b1 + …). Not numpy's ``@``:
    it calls BLAS, whose kernels fuse multiply and add on some CPUs (AVX-512) and so round differently on
    another machine (``stability_scalar`` gave other last bits than this reference on one: a CI machine's
    finding); this is the same on every machine and is what ``stability_scalar`` computes."""
    x, y = np.asarray(a, dtype=float).tolist(), np.asarray(b, dtype=float).tolist()
    s = x[0] * y[0]
    for xi, yi in zip(x[1:], y[1:], strict=True):
        s += xi * yi
    return float(s)


def _cross3(a, b) -> np.ndarray:
    """Cross product of two 3-vectors (np.cross costs ~35 µs per call; this ~1 µs)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def gravity_direction(slope_roll: float, slope_pitch: float) -> np.ndarray:
    """Unit gravity vector (3,) in the tractor frame; roll > 0 left side up, pitch > 0 nose up [rad]."""
    r, p = (_scalar(n, v) for n, v in (("slope_roll", slope_roll), ("slope_pitch", slope_pitch)))
    for name, v in (("slope_roll", r), ("slope_pitch", p)):
        if abs(v) >= math.pi / 2:
            raise StabilityInputError(f"{name} = {v} rad is outside the allowed range (-π/2, π/2)")
    return np.array([-math.sin(r) * math.cos(p), math.sin(p), -math.cos(r) * math.cos(p)])


def _unit_gravity(gravity) -> np.ndarray:
    g = _vector3("gravity", gravity)
    if abs(float(np.linalg.norm(g)) - 1.0) > 1e-9:
        raise StabilityInputError(f"gravity must be a unit vector (see gravity_direction), |g| = {np.linalg.norm(g)}")
    return g


@dataclass(frozen=True)
class LoadCase:
    """What the support carries: total mass [kg], combined CoM (3,) [m]; the implement's mass
    [kg], CoM and tool point T in the tractor frame (3,) [m] (None without one); ballast [kg]."""

    mass: float
    centre_of_mass: np.ndarray
    implement_mass: float
    implement_centre_of_mass: np.ndarray | None
    tool_point: np.ndarray | None
    front_ballast: float


def build_load_case(
    tractor: Tractor, implement: ImplementRecord | None, T=None, R_i=None, front_ballast: float = 0.0
) -> LoadCase:
    """Combine tractor, implement at pose (T, R_i) and a front ballast [kg] into one mass and CoM.

    The implement CoM is p_i = T + R_i c_i with c_i its CoM in the implement frame.  Without an
    implement (``None``) T and R_i are ignored.
    """
    ballast = _scalar("front_ballast", front_ballast, 0.0, 20_000.0)
    m = tractor.mass + ballast
    moment = tractor.mass * tractor.centre_of_mass + ballast * tractor.front_ballast_point
    p_i = t = None
    m_i = 0.0
    if implement is not None:
        t = _vector3("T", T)
        p_i = t + _rotation("R_i", R_i) @ np.asarray(implement.centre_of_mass)
        p_i.setflags(write=False)
        m_i = implement.mass
        m += m_i
        moment = moment + m_i * p_i
    com = moment / m
    com.setflags(write=False)
    return LoadCase(m, com, m_i, p_i, t, ballast)


@dataclass(frozen=True)
class AxleLoads:
    """Ground-normal axle loads [N]; a negative front load means the front axle would lift."""

    front: float
    rear: float

    @property
    def total(self) -> float:
        return self.front + self.rear

    @property
    def front_share(self) -> float:
        """front / (front + rear)."""
        return self.front / self.total


def axle_loads(tractor: Tractor, mass: float, centre_of_mass, gravity) -> AxleLoads:
    """Axle loads from the moment balance about the rear-contact line (x axis at ground level).

    Weight W = m g_n g_hat (mass [kg], unit ``gravity``) at the CoM p (3,) [m]; ground z_g,
    rear axle y_r, wheelbase b: front = [(p_y - y_r) W_z - (p_z - z_g) W_y] / b, rear = -W_z -
    front.  Friction acts at ground level and has no moment about that line.  On level ground
    this is the manuals' T_V = T_L (y_r - p_y) / b.
    """
    m = _scalar("mass", mass, 0.0, 100_000.0, open_lo=True)
    g = _unit_gravity(gravity)
    return _axle_loads(tractor, m, _vector3("centre_of_mass", centre_of_mass), g)


def _axle_loads(tractor: Tractor, mass: float, p: np.ndarray, g: np.ndarray) -> AxleLoads:
    """:func:`axle_loads` of inputs already checked."""
    W = mass * STANDARD_GRAVITY * g
    y_r = tractor.rear_axle[1]
    front = ((p[1] - y_r) * W[2] - (p[2] - tractor.ground_z) * W[1]) / tractor.wheelbase
    return AxleLoads(float(front), float(-W[2] - front))


def _support_frame(tractor: Tractor):
    """Support plane: unit normal n (z-up side), in-plane axes e1 (+x), e2 = n x e1, 2-D vertices."""
    V = tractor.support_vertices
    n = _cross3(V[1] - V[0], V[2] - V[0])
    n /= np.linalg.norm(n)
    if n[2] < 0:
        n = -n
    e1 = (V[0] - V[1]) / np.linalg.norm(V[0] - V[1])
    e2 = _cross3(n, e1)
    return V, n, e1, e2, (V - V[0]) @ np.column_stack([e1, e2])


def _segment_distance(q: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    ab = b - a
    s = min(1.0, max(0.0, _dot(q - a, ab) / _dot(ab, ab)))
    r = q - (a + s * ab)
    return math.sqrt(_dot(r, r))


@dataclass(frozen=True)
class SupportMargins:
    """Static and longitudinal margins [m] of one CoM over the support triangle."""

    #: gravity projection of the CoM onto the support plane (3,) [m]
    projection: np.ndarray
    #: signed in-plane distances to the edge lines (rear, right, left), > 0 inside [m]
    edge_distances: tuple[float, float, float]
    ssm: float
    lsm_front: float
    lsm_rear: float

    @property
    def lsm(self) -> float:
        return min(self.lsm_front, self.lsm_rear)

    @property
    def inside(self) -> bool:
        return min(self.edge_distances) > 0.0

    @property
    def weakest_edge(self) -> str:
        return EDGE_NAMES[int(np.argmin(self.edge_distances))]


def _support_constants(tractor: Tractor):
    """The pose-independent part of :func:`support_margins` (kept per tractor: its arrays are
    read-only): support frame, unit travel direction in plane coordinates, and per edge
    (start vertex in the plane, unit inward normal m, m . travel)."""
    const = _SUPPORT_CACHE.get(tractor)
    if const is None:
        V, n, e1, e2, V2 = _support_frame(tractor)
        travel = np.array([e1[1], e2[1]])  # tractor y axis (rearward) in plane coordinates
        travel /= np.linalg.norm(travel)
        edges = []
        for a, b, c in _EDGES:
            edge = V2[b] - V2[a]
            m = np.array([-edge[1], edge[0]]) / np.linalg.norm(edge)
            if m @ (V2[c] - V2[a]) < 0:
                m = -m
            edges.append((V2[a], m, float(m @ travel)))
        const = _SUPPORT_CACHE[tractor] = (V, n, e1, e2, V2, tuple(edges))
    return const


def support_margins(tractor: Tractor, centre_of_mass, gravity) -> SupportMargins:
    """SSM and LSM of ``centre_of_mass`` (3,) [m] for gravity direction ``gravity`` (unit, (3,))."""
    return _support_margins(tractor, _vector3("centre_of_mass", centre_of_mass), _unit_gravity(gravity))


def _support_margins(tractor: Tractor, p: np.ndarray, g: np.ndarray) -> SupportMargins:
    """:func:`support_margins` of inputs already checked."""
    V, n, e1, e2, V2, edges = _support_constants(tractor)
    denom = _dot(n, g)
    if abs(denom) < 1e-9:
        raise StabilityInputError("slope: gravity is parallel to the support plane; no projection exists")
    q = p + (_dot(n, V[0] - p) / denom) * g
    q2 = np.array([_dot(q - V[0], e1), _dot(q - V[0], e2)])
    d = [_dot(m, q2 - va) for va, m, _ in edges]
    if min(d) > 0:
        ssm = min(d)
    else:
        ssm = -min(_segment_distance(q2, V2[a], V2[b]) for a, b, _ in _EDGES)
    lsm_front, lsm_rear = _travel_margins(d, [mv for _, _, mv in edges], ssm)
    q.setflags(write=False)
    return SupportMargins(q, (d[0], d[1], d[2]), float(ssm), float(lsm_front), float(lsm_rear))


def _travel_margins(d: Sequence[float], mvs: Sequence[float], ssm: float) -> tuple[float, float]:
    """(LSM front, LSM rear): Cyrus–Beck clipping of the travel line q2 + s·travel against the support
    triangle, ``d`` the reference's distances inside each edge and ``mvs`` each edge's inward normal
    · travel (di + s·mv ≥ 0 for every edge); both are ``ssm`` when the line misses the triangle."""
    s_lo, s_hi, misses = -math.inf, math.inf, False
    for di, mv in zip(d, mvs, strict=True):
        if abs(mv) < 1e-12:
            misses |= di < 0
        elif mv > 0:
            s_lo = max(s_lo, -di / mv)
        else:
            s_hi = min(s_hi, -di / mv)
    if misses or s_lo > s_hi:
        return ssm, ssm
    return -s_lo, s_hi


@dataclass(frozen=True)
class EnergyMargins:
    """Signed tip-over energies per edge (rear, right, left) [J]; ESM is their minimum."""

    edge_energies: tuple[float, float, float]

    @property
    def esm(self) -> float:
        return min(self.edge_energies)

    @property
    def weakest_edge(self) -> str:
        return EDGE_NAMES[int(np.argmin(self.edge_energies))]


def energy_margins(tractor: Tractor, mass: float, centre_of_mass, gravity) -> EnergyMargins:
    """Energy stability margin (Messuri-Klein) of a mass [kg] at ``centre_of_mass`` (3,) [m].

    Edge A->B, unit axis a, r = p - A, r_perp = r - (r.a) a, u = -g_hat: rotating about the edge
    the CoM rises by h_max - h0 = |r_perp| sqrt(1 - (a.u)^2) - r_perp.u; E = m g_n (h_max - h0),
    negative when p is past the vertical plane through the edge (away from the third vertex).
    """
    m = _scalar("mass", mass, 0.0, 100_000.0, open_lo=True)
    p = _vector3("centre_of_mass", centre_of_mass)
    return _energy_margins(tractor, m, p, _unit_gravity(gravity))


def _energy_margins(tractor: Tractor, m: float, p: np.ndarray, g: np.ndarray) -> EnergyMargins:
    """:func:`energy_margins` of inputs already checked."""
    up = -g
    out = []
    for A, axis, lift, side in _energy_constants(tractor, up):
        r = p - A
        r_perp = r - _dot(r, axis) * axis
        rise = math.sqrt(_dot(r_perp, r_perp)) * lift - _dot(r_perp, up)
        sign = float(np.sign(_dot(side, r)))
        out.append(sign * m * STANDARD_GRAVITY * max(0.0, float(rise)))
    return EnergyMargins((out[0], out[1], out[2]))


def _energy_constants(tractor: Tractor, up: np.ndarray):
    """Per edge of :func:`energy_margins`: start vertex A, unit axis, sqrt(1 - (axis . up)^2)
    and the normal of the vertical plane through the edge towards the third vertex (kept per
    tractor and up direction)."""
    per_up = _ENERGY_CACHE.setdefault(tractor, {})
    key = up.tobytes()
    const = per_up.get(key)
    if const is None:
        V = tractor.support_vertices
        edges = []
        for a_i, b_i, c_i in _EDGES:
            A = V[a_i]
            axis = (V[b_i] - A) / np.linalg.norm(V[b_i] - A)
            lift = math.sqrt(max(0.0, 1.0 - float(axis @ up) ** 2))
            side = _cross3(axis, up)  # normal of the vertical plane through the edge
            if side @ (V[c_i] - A) < 0:
                side = -side
            edges.append((A, axis, lift, side))
        if len(per_up) >= 32:  # slopes change: keep the last few
            per_up.clear()
        const = per_up[key] = tuple(edges)
    return const


def minimum_front_ballast(
    implement_mass: float,
    c: float,
    d: float,
    *,
    empty_mass: float,
    empty_front_axle_mass: float,
    wheelbase: float,
    ballast_arm: float,
    front_fraction: float = 0.2,
) -> float:
    """Minimum front ballast [kg] for a rear-mounted implement, as tractor/implement manuals give it.

        G_V,min = [G_H (c + d) - T_V b + 0.2 T_L b] / (a + b),   clipped at 0

    G_H implement mass, T_V front-axle load of the empty tractor, T_L empty tractor mass [kg];
    a front-ballast CoG to front-axle centre, b wheelbase, c rear-axle centre to lower-link
    ball centres, d lower-link ball centres to the implement CoG [m] (horizontal, level ground);
    0.2 is the rule "front axle >= 20 % of the empty tractor" (``front_fraction``).  It solves
    the level-ground moment balance T_V,act b = G_V (a + b) + T_V b - G_H (c + d) for
    T_V,act = 0.2 T_L.  Source: AMAZONE Cenio 3000 operating manual MG6806 (2022), §6
    "Calculating the required tractor characteristics" (definitions of a..d and the formula);
    the same formula in HORSCH, RAUCH, CLAAS and SAME manuals.
    """
    G_H = _scalar("implement_mass", implement_mass, 0.0, 50_000.0)
    T_L = _scalar("empty_mass", empty_mass, 0.0, 50_000.0, open_lo=True)
    T_V = _scalar("empty_front_axle_mass", empty_front_axle_mass, 0.0, T_L)
    b = _scalar("wheelbase", wheelbase, 0.0, 10.0, open_lo=True)
    a = _scalar("ballast_arm", ballast_arm, 0.0, 10.0)
    cd = _scalar("c", c, -10.0, 10.0) + _scalar("d", d, -10.0, 10.0)
    f = _scalar("front_fraction", front_fraction, 0.0, 1.0)
    return _front_ballast(G_H, cd, T_V, T_L, a, b, f)


def _front_ballast(G_H: float, cd: float, T_V: float, T_L: float, a: float, b: float, f: float) -> float:
    """:func:`minimum_front_ballast`'s formula on checked values (an evaluation's own c + d is not a typed
    input: an implement's centre of mass may lie up to 10 m from its frame in every axis, so d reaches
    beyond ±10 m once the implement is pitched; checked as an input, it latched an ``internal`` fault in the
    service for an implement the service had accepted, an operator's trial)."""
    return max(0.0, (G_H * cd - T_V * b + f * T_L * b) / (a + b))


@dataclass(frozen=True)
class StabilityThresholds:
    """Hard and caution thresholds; a value below ``*_hard`` refuses, below ``*_caution`` slows.

    ``front_axle_fraction_*``: fractions of the empty tractor's weight (0.20 is the manuals'
    rule); ``ssm_*``, ``lsm_*`` [m]; ``esm_*`` [J].  assumed: the margin defaults, about half
    the static tip angle of the default 6 t tractor: with the 1500 kg implement (7.5 t; 2 kJ =
    2.7 cm CoM rise) ESM reaches 2 kJ near 11-13° nose-up (static tip-back 23-27°); without an
    implement near 21° side slope (static side tip 37°, where SSM = 0.10 m is near 31°).
    """

    front_axle_fraction_hard: float = 0.20
    front_axle_fraction_caution: float = 0.25
    ssm_hard: float = 0.10
    ssm_caution: float = 0.20
    lsm_hard: float = 0.10
    lsm_caution: float = 0.20
    esm_hard: float = 2_000.0
    esm_caution: float = 5_000.0

    def __post_init__(self) -> None:
        for measure, hi in (("front_axle_fraction", 1.0), ("ssm", 10.0), ("lsm", 10.0), ("esm", 1e7)):
            hard = _scalar(f"{measure}_hard", getattr(self, f"{measure}_hard"), -hi, hi)
            caution = _scalar(f"{measure}_caution", getattr(self, f"{measure}_caution"), -hi, hi)
            if measure == "front_axle_fraction" and hard < 0:
                raise StabilityInputError(f"front_axle_fraction_hard = {hard} must lie in [0, 1]")
            if caution < hard:
                raise StabilityInputError(f"{measure}_caution = {caution} must be >= {measure}_hard = {hard}")


@dataclass(frozen=True)
class StabilityViolation:
    """A measure below a threshold: value and threshold in the measure's unit (N, m or J)."""

    measure: Measure
    value: float
    threshold: float
    level: Literal["hard", "caution"]


@dataclass(frozen=True)
class StabilityReport:
    """All measures for one pose and slope. ``ok`` = no hard violation."""

    axle_loads: AxleLoads
    front_axle_share: float
    ssm: float
    lsm: float
    esm: float
    min_front_ballast_kg: float
    ok: bool
    violations: tuple[StabilityViolation, ...]
    #: edge with the smallest SSM ("rear", "right", "left")
    weakest_edge: str
    load: LoadCase = field(repr=False)
    margins: SupportMargins = field(repr=False)
    energy: EnergyMargins = field(repr=False)

    @property
    def caution(self) -> bool:
        """Any threshold (hard or caution) crossed."""
        return bool(self.violations)

    def as_dict(self) -> dict:
        """JSON-ready summary: axle loads [N], front-axle share, SSM, LSM [m], ESM [J], ballast advice [kg]."""
        return {
            "axle_loads": {"front": self.axle_loads.front, "rear": self.axle_loads.rear},
            "front_axle_share": self.front_axle_share,
            "ssm": self.ssm,
            "lsm": self.lsm,
            "esm": self.esm,
            "min_front_ballast": self.min_front_ballast_kg,
            "ok": self.ok,
            "weakest_edge": self.weakest_edge,
            "violations": [asdict(v) for v in self.violations],
        }


def evaluate_stability(
    tractor: Tractor,
    implement: ImplementRecord | None,
    T,
    R_i,
    slope_roll: float,
    slope_pitch: float,
    *,
    thresholds: StabilityThresholds = StabilityThresholds(),
    front_ballast: float = 0.0,
) -> StabilityReport:
    """Axle loads, SSM, LSM, ESM and the manual front-ballast advice for one pose and slope.

    ``T`` (3,) [m] and ``R_i`` (3x3) give the implement pose in the tractor frame; slopes [rad]
    per the module convention; ``front_ballast`` [kg] already fitted to the front carrier.
    The ballast advice is the manual formula (total front ballast, compare with ``front_ballast``)
    with c, d taken along y from the current pose (the manuals' level-ground convention); the
    other measures include the slope.
    """
    if not isinstance(thresholds, StabilityThresholds):
        raise StabilityInputError("thresholds must be a StabilityThresholds")
    g = gravity_direction(slope_roll, slope_pitch)
    load = build_load_case(tractor, implement, T, R_i, front_ballast)
    # the load case is checked (finite, total mass within 90 t) and g is a unit vector: the
    # measures without checking their inputs again
    loads = _axle_loads(tractor, load.mass, load.centre_of_mass, g)
    margins = _support_margins(tractor, load.centre_of_mass, g)
    energy = _energy_margins(tractor, load.mass, load.centre_of_mass, g)
    return _report(tractor, load, thresholds, loads, margins, energy)


def _report(
    tractor: Tractor,
    load: LoadCase,
    thresholds: StabilityThresholds,
    loads: AxleLoads,
    margins: SupportMargins,
    energy: EnergyMargins,
) -> StabilityReport:
    """The report of one evaluation from its axle loads, margins and energy margins: the ballast
    advice (from the manuals' c and d) and the violations of the thresholds."""
    c = d = 0.0  # the manuals' c (rear axle -> lower-link balls) and d (balls -> implement CoG) [m]
    t_pt, p_impl = load.tool_point, load.implement_centre_of_mass
    if t_pt is not None and p_impl is not None:  # both are set exactly when there is an implement
        c, d = t_pt[1] - tractor.rear_axle[1], p_impl[1] - t_pt[1]
    ballast = _front_ballast(
        float(load.implement_mass),
        float(c + d),
        float(tractor.empty_front_axle_mass),
        float(tractor.mass),
        float(tractor.front_ballast_arm),
        float(tractor.wheelbase),
        float(thresholds.front_axle_fraction_hard),
    )
    th, w = thresholds, tractor.empty_weight
    rows: tuple[tuple[Measure, float, float, float], ...] = (
        ("front_axle_load", loads.front, th.front_axle_fraction_hard * w, th.front_axle_fraction_caution * w),
        ("ssm", margins.ssm, th.ssm_hard, th.ssm_caution),
        ("lsm", margins.lsm, th.lsm_hard, th.lsm_caution),
        ("esm", energy.esm, th.esm_hard, th.esm_caution),
    )
    violations = tuple(
        StabilityViolation(n, v, hard if v < hard else caution, "hard" if v < hard else "caution")
        for n, v, hard, caution in rows
        if v < caution
    )
    return StabilityReport(
        axle_loads=loads,
        front_axle_share=loads.front_share,
        ssm=margins.ssm,
        lsm=margins.lsm,
        esm=energy.esm,
        min_front_ballast_kg=ballast,
        ok=not any(v.level == "hard" for v in violations),
        violations=violations,
        weakest_edge=margins.weakest_edge,
        load=load,
        margins=margins,
        energy=energy,
    )
