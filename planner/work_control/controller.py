"""Work control of a soil-engaging implement: position, draft, mixed and float control on top of track mode.

Every control cycle :meth:`WorkController.step` takes the operator's position setpoint ``z`` (the
hitch height in the track session's frame, m), the measured draft [N] with its receive time (or
None), the wheel slip (or None) and the ground reference, and returns the ``z`` setpoint handed to
the :class:`~planner.trajectory.track.TrackFollower` with a status. The follower, the workspace
limits and the guard act on that setpoint as on any other: work control only chooses it.

Ground reference. ``ground_z`` is the hitch height ``z`` at which the tool tip touches the ground
(the track frame, m; None when unknown). The working depth of a setpoint ``z`` is
``ground_z - z``; the depth limits bound the setpoint to ``[ground_z - depth_max, ground_z - depth_min]``.

Modes (:attr:`WorkSettings.mode`):

* ``position``: the operator's ``z`` unchanged (the depth then varies with the ground and the
  draft with the soil).
* ``draft``: hold ``draft_setpoint_n`` by adjusting the working depth. A PI regulator on the relative
  draft error ``e = (D - D_set) / D_set`` acting on the hitch height: ``z_i ← z_i + s·K_I·d_ref·e·Δt``
  (the integral), ``z = clip(z_i + s·K_P·d_ref·e, ground_z - depth_max, ground_z - depth_min)``, with
  ``s`` the sensitivity and ``d_ref`` the middle of the depth limits (so the gains are the same
  fraction of the depth range for any implement). Anti-windup: ``z_i`` is clamped to the same
  depth limits, so after a limit the regulator leaves it as soon as the error changes sign. Given the z range
  the hitch can reach (``step(…, z_range=…)``: the follower's workspace faces), the output and ``z_i`` stay
  within it too (a demand beyond a face only wound up there: a 0.6 m depth limit below the workspace floor
  kept the hitch on the floor for seconds after a lower setpoint), and the status names the face. ``z_i``
  starts at the operator's ``z`` (clipped to the limits) when the mode engages (bumpless). The
  ground reference bounds the setpoint but is not fed forward: the undulation reaches the draft
  loop as a draft error, as on a tractor's draft control (feeding the ground height forward made
  the hitch lag the undulation and *raised* the draft's spread in the twin, see docs/soil.md).
  Hitch speed: given ``z_rate_max_m_s`` (the z speed the hitch follows), the draft demand moves no
  faster than that, and when the rate bounds it the integral is set back to the bounded output less
  the proportional part (back-calculation). Without it a hitch that lags a fast undulation lets the
  integral run ahead of the hitch, and the loop cycles between the depth limits (with the true depth
  beyond them, since the hitch arrives late). The depth limits win over the rate: they move with the
  ground.
* ``draft`` with a ground preview (``ground_ahead_z``: the ground reference where the tool will be when
  the hitch has followed this setpoint, from :class:`planner.work_control.ground_preview.GroundPreview`):
  the PI regulates the working depth, ``d_i ← d_i − s·K_I·d_ref·e·Δt``, ``depth = clip(d_i −
  s·K_P·d_ref·e, depth_min, depth_max)``, and the previewed ground is fed forward, ``z =
  ground_ahead_z − depth``: the undulation no longer reaches the draft loop as an error (on ``chisel``
  it lies above the loop's crossover, so the loop could not remove it), and the depth limits hold on
  the ground the tool will meet. Unlike the ground under the tool (fed forward, it only made the
  hitch lag), the ground one hitch lag ahead lets the hitch arrive in time (docs/soil.md). The rate
  bound and its back-calculation act as without the preview.
* ``mixed``: ``z = (1 - blend)·z_position + blend·z_draft`` (blend 0 = position, 1 = draft).
* ``float``: no down pressure. A position-controlled hitch cannot be force-free, so float means
  here: the hitch carries the implement at the shallowest allowed depth below the ground
  reference (``ground_z - depth_min``, the depth an implement's gauge wheels would set) and never
  pushes it deeper, and it moves only when the ground moved more than :data:`FLOAT_DEAD_BAND_M`
  (the hitch follows the ground without chasing every ripple). The operator's ``z`` is not used
  and no draft is needed.

Slip limiting (``slip_limit`` not None; every mode but float): a PI regulator on the slip excess
``slip - slip_limit`` whose integral is clamped at 0 from below, so it acts only while the slip has
been above the limit and decays once it is below. In draft mode it lowers the draft setpoint (a
cascade: ``D_set·(1 - c)``, ``c = K_P·excess⁺ + K_I·∫excess`` within ``[0, MAX_CUT]``), so the
draft regulator itself makes the tool shallower and the depth limits still hold. It is the outer,
slower loop of that cascade: the excess is that of the slip low-passed with :data:`SLIP_TAU_S`, its
gains put its crossover at about a fifth of the draft loop's, ``c`` changes by at most
:data:`CUT_RATE_MAX` per second, and its integral does not grow while the draft regulator already
sits at the shallow depth limit (anti-windup). Slip follows the draft, so a limiter as fast as the
draft loop (it was: a P-term on the raw slip and 5 /s) adds its gain and its integrator to the draft
loop's, and on a hitch that lags the undulation the two cycled (docs/soil.md). In position and
mixed mode it lifts the setpoint by ``r = K_P·excess⁺ + K_I·∫excess`` within ``[0, depth_max]``
(position: never above the ground contact; mixed: never shallower than ``depth_min``, and while it
lifts the draft integral may only lift too, so the two do not fight). The limiters' target is the
limit less a margin of :data:`MARGIN_SIGMAS` times the slip's ripple RMS (in draft mode only with a
ground preview), so the ripple's tops, not its mean, stay at the limit. An unavailable slip (None,
NaN) leaves the integral as it is and is reported in :attr:`WorkStatus.note`.

Fallback. ``draft`` and ``mixed`` need a usable draft signal and the ground reference. A draft that is
stale (received longer than ``draft_ttl_s`` ago, or never), not a finite number, outside
``[-0.1·draft_max_n, draft_max_n]``, or stuck (exactly the same value for ``stuck_s`` while new
readings arrive: real draft pins always show noise), and a missing ground reference, put the
controller into position control with the reason (:attr:`WorkStatus.fallback`) and an event on the
cycle it happens (:attr:`WorkStatus.event`). The fallback is latched until :meth:`WorkController.resume`
or :meth:`WorkController.configure` (an operator's decision, not a flicker between modes).
Float without a ground reference holds the last float setpoint (or the operator's ``z`` before
the first), reported as a fallback to position too.

Cost: each step is a fixed number of float operations (no allocation beyond the status, no loop).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from planner.errors import HitchInputError, unit_hint

__all__ = [
    "DRAFT_SETPOINT_MAX_N",
    "FLOAT_DEAD_BAND_M",
    "KI_DRAFT",
    "KP_DRAFT",
    "MODES",
    "WorkController",
    "WorkSettings",
    "WorkSettingsError",
    "WorkStatus",
]

MODES = ("position", "draft", "mixed", "float")
#: the largest draft setpoint a work session takes [N] (a category 4 tractor's rated draft, with margin)
DRAFT_SETPOINT_MAX_N = 300_000.0
#: proportional gain of the draft regulator: depth change per unit relative draft error, in d_ref
KP_DRAFT = 0.3
#: integral gain of the draft regulator [1/s]: depth rate per unit relative draft error, in d_ref
KI_DRAFT = 1.5
#: slip limiter: raise per unit slip excess [m] (P) and raise rate per unit slip excess [m/s] (I)
KP_SLIP = 0.3
KI_SLIP = 2.0
#: slip limiter in draft mode (the outer loop of a cascade on the draft setpoint): cut per unit excess of the
#: low-passed slip (P) and its rate [1/s] (I). Slip follows the draft with a slope of about 0.3 per unit
#: relative draft, so the outer loop's crossover is about KI_CUT·0.3 ≈ 0.3 rad/s, a fifth of the draft
#: loop's (K_I = 1.5 /s): the two integrators no longer act at the same speed (they fought at 5 /s).
KP_CUT = 0.5
KI_CUT = 1.0
#: the slip limiters keep a margin below the limit for the slip's ripple: the slip ripples with the draft
#: over the undulation (0.32 Hz on ``chisel``), and a PI on the slip settles with the slip's *mean* at its
#: target, so the ripple's tops stood above the limit (0.128 against 0.10 in position mode on ``chisel``).
#: The target is ``slip_limit − MARGIN_SIGMAS·σ`` with σ the slip's RMS about its mean (the ripple's tops
#: reached 2.8 σ on ``chisel``), the mean low-passed with SLIP_MEAN_S and σ² with SLIP_RIPPLE_S [s], the
#: margin at most MARGIN_MAX·slip_limit. Draft mode keeps the margin only with a ground preview: without one
#: the undulation's draft ripple would park the tool at the shallow limit, which a lagging hitch overshoots.
SLIP_MEAN_S = 2.0
SLIP_RIPPLE_S = 4.0
MARGIN_SIGMAS = 2.0
MARGIN_MAX = 0.5
#: with a preview and the measured z: the depth limits are inset by DEPTH_MARGIN_SIGMAS times the RMS of the
#: hitch's tracking error in depth (the estimated true depth ``ground_z − z_measured`` less the depth last
#: demanded; mean square low-passed with DEPTH_TRACK_S [s]), at most DEPTH_MARGIN_MAX of the depth range: at a
#: limit the true depth then stays inside it although the hitch follows the undulation only within ≈ 1 cm
DEPTH_MARGIN_SIGMAS = 2.0
DEPTH_TRACK_S = 4.0
DEPTH_MARGIN_MAX = 0.25
#: time constant of the slip low-pass feeding the draft-mode limiter [s] (the outer loop of the cascade stays
#: slower than the draft loop; with the ground preview the draft, and so the slip, hardly ripples there)
SLIP_TAU_S = 1.0
#: the fastest the slip limiter changes the draft setpoint's cut [1/s]
CUT_RATE_MAX = 0.2
#: the largest share of the draft setpoint the slip limiter may take away
MAX_CUT = 0.9
#: float: the ground must move more than this before the hitch follows it [m]
FLOAT_DEAD_BAND_M = 0.01
_DT_MAX = 0.1  # a longer gap between steps integrates as this (s)


class WorkSettingsError(HitchInputError):
    """Bad work-control settings or step input; the message names the field and the allowed range."""


#: the unit a setting's name ends in (``depth_max_m``, ``draft_setpoint_n``, ``stuck_s``)
_UNITS = {"_m": "m", "_n": "N", "_s": "s"}


def _num(name: str, v: object, lo: float, hi: float, *, open_lo: bool = False) -> float:
    unit = next((u for suffix, u in _UNITS.items() if name.endswith(suffix)), "")
    rng = f"{'(' if open_lo else '['}{lo:g}, {hi:g}]" + (f" {unit}" if unit else "")
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise WorkSettingsError(f"{name} must be a finite number in {rng}, got {v!r}")
    x = float(v)
    if x < lo or x > hi or (open_lo and x <= lo):  # with its unit and the mm reading of a length typed in mm
        raise WorkSettingsError(f"{name} = {v!r} is outside the allowed range {rng}" + unit_hint(x, lo, hi, unit))
    return x


@dataclass(frozen=True)
class WorkSettings:
    """The operator's work-control settings for one implement (SI units).

    Attributes:
        mode: one of :data:`MODES`.
        draft_setpoint_n: the draft to hold in draft/mixed mode [N], (0, 300 000].
        blend: mixed mode's share of the draft demand, [0, 1].
        sensitivity: scales the draft regulator's gains, [0.1, 2] (1 = nominal; in the twin the loop
            rings from about 1.5 and oscillates at twice the nominal integral gain).
        depth_min_m, depth_max_m: working-depth limits of draft, mixed and float [m], 0 ≤ min < max ≤ 0.6.
        slip_limit: the slip the limiter keeps below, (0, 0.5], or None (no slip limiting).
        draft_ttl_s: a draft reading older than this is stale [s], [0.02, 5].
        draft_max_n: a draft above this (or below -0.1 of it) is implausible [N], (0, 1e6].
        stuck_s: the same draft value for this long is a stuck sensor [s], [0.2, 60], or None (no check).
    """

    mode: str = "position"
    draft_setpoint_n: float = 20_000.0
    blend: float = 0.5
    sensitivity: float = 1.0
    depth_min_m: float = 0.05
    depth_max_m: float = 0.35
    slip_limit: float | None = None
    draft_ttl_s: float = 0.3
    draft_max_n: float = 300_000.0
    stuck_s: float | None = 2.0

    def __post_init__(self) -> None:
        if not isinstance(self.mode, str) or self.mode not in MODES:
            raise WorkSettingsError(f"mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        _num("draft_setpoint_n", self.draft_setpoint_n, 0.0, DRAFT_SETPOINT_MAX_N, open_lo=True)
        _num("blend", self.blend, 0.0, 1.0)
        _num("sensitivity", self.sensitivity, 0.1, 2.0)
        _num("depth_min_m", self.depth_min_m, 0.0, 0.6)
        _num("depth_max_m", self.depth_max_m, 0.0, 0.6)
        if not self.depth_min_m < self.depth_max_m:
            raise WorkSettingsError(
                f"depth_min_m = {self.depth_min_m!r} must be below depth_max_m = {self.depth_max_m!r} "
                "(both in [0, 0.6])"
            )
        if self.slip_limit is not None:
            _num("slip_limit", self.slip_limit, 0.0, 0.5, open_lo=True)
        _num("draft_ttl_s", self.draft_ttl_s, 0.02, 5.0)
        _num("draft_max_n", self.draft_max_n, 0.0, 1.0e6, open_lo=True)
        if self.stuck_s is not None:
            _num("stuck_s", self.stuck_s, 0.2, 60.0)
        if self.draft_setpoint_n > self.draft_max_n:
            raise WorkSettingsError(
                f"draft_setpoint_n = {self.draft_setpoint_n!r} must not exceed draft_max_n = {self.draft_max_n!r}"
            )


@dataclass(frozen=True)
class WorkStatus:
    """One cycle of work control.

    Attributes:
        t: the cycle's time [s].
        z: the setpoint for the track follower (track frame) [m].
        mode: the configured mode; ``active``: the mode in effect (``position`` after a fallback).
        fallback: why draft/mixed/float fell back to position (None: no fallback).
        event: set on the cycle a fallback begins (``"work_fallback: <reason>"``), else None.
        depth_m: the working depth of ``z`` below the ground reference (None without one).
        draft_n: the draft reading used this cycle (None when none was usable).
        draft_error: relative draft error (D - D_set)/D_set (None when not regulating).
        slip_raise_m: position and mixed: the slip limiter's raise of the setpoint [m] (0: not limiting).
        slip_cut: draft: the share of the draft setpoint the slip limiter takes away (0: not limiting).
        slip_limited: the slip limiter acted this cycle.
        note: why an optional input was ignored ("slip unavailable"), else None.
        z_limit: ``"min"`` / ``"max"`` when the reachable z range (``step(…, z_range=…)``) bounded the
            draft demand this cycle (the hitch cannot go deeper / higher), else None.
    """

    t: float
    z: float
    mode: str
    active: str
    fallback: str | None = None
    event: str | None = None
    depth_m: float | None = None
    draft_n: float | None = None
    draft_error: float | None = None
    slip_raise_m: float = 0.0
    slip_cut: float = 0.0
    slip_limited: bool = False
    note: str | None = None
    z_limit: str | None = None


def _finite(v: float | None) -> bool:
    return v is not None and not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)


class WorkController:
    """Per control cycle: the z setpoint of the active mode (module docstring). Not thread-safe."""

    def __init__(self, settings: WorkSettings | None = None, *, z_rate_max_m_s: float | None = None) -> None:
        """``z_rate_max_m_s``: the fastest the hitch follows z [m/s], (0, 2], or None (no rate limit): draft
        and mixed then never command z faster, and the draft integral tracks the rate-limited output
        (anti-windup against the hitch's speed, module docstring)."""
        self._rate = None if z_rate_max_m_s is None else _num("z_rate_max_m_s", z_rate_max_m_s, 0.0, 2.0, open_lo=True)
        self._z_out: float | None = None  # the last z setpoint handed out (any mode): where a restart continues
        self.configure(WorkSettings() if settings is None else settings)

    @property
    def z_rate_max_m_s(self) -> float | None:
        """The hitch's z rate the draft regulator respects (None: none)."""
        return self._rate

    @property
    def settings(self) -> WorkSettings:
        return self._s

    @property
    def fallback(self) -> str | None:
        """The latched fallback reason (None: none)."""
        return self._fallback

    def configure(self, settings: WorkSettings) -> None:
        """New settings (the operator's); the regulator restarts bumpless and a fallback is cleared."""
        if not isinstance(settings, WorkSettings):
            raise WorkSettingsError(f"settings must be a WorkSettings, got {type(settings).__name__}")
        self._s = settings
        self.resume()
        self._slip_raise = 0.0
        self._slip_cut = 0.0
        self._slip_i = 0.0
        self._slip_f: float | None = None
        self._slip_mean: float | None = None  # the slip's low-passed mean and ripple variance (the margin)
        self._slip_var = 0.0

    def resume(self) -> None:
        """Clear a latched fallback: the configured mode engages again on the next step (bumpless)."""
        self._fallback: str | None = None
        self._z_i: float | None = None
        self._d_i: float | None = None  # the depth integral of the regulator with a ground preview
        self._depth_dem: float | None = None  # the last depth demanded with a preview (on the previewed ground)
        self._track_var = 0.0  # the hitch's tracking error in depth, mean square [m²]
        self._z_draft: float | None = None
        self._float_z: float | None = None
        self._last_t: float | None = None
        self._same_value: float | None = None
        self._same_since: float | None = None
        self._last_draft_t: float | None = None

    def _draft_problem(self, now: float, draft_n: float | None, draft_t: float | None) -> str | None:
        s = self._s
        if draft_n is None or draft_t is None:
            return "draft signal stale: no reading"
        if not _finite(draft_n) or not _finite(draft_t):
            return f"draft signal implausible: {draft_n!r} at {draft_t!r} is not a finite number"
        age = now - draft_t
        if age > s.draft_ttl_s:
            return f"draft signal stale: last reading {age:.3f} s ago (ttl {s.draft_ttl_s:g} s)"
        if not -0.1 * s.draft_max_n <= draft_n <= s.draft_max_n:
            lo, hi = -0.1 * s.draft_max_n, s.draft_max_n
            return f"draft signal implausible: {draft_n:.0f} N outside [{lo:.0f}, {hi:.0f}] N"
        if s.stuck_s is not None and draft_t != self._last_draft_t:
            self._last_draft_t = draft_t
            if draft_n != self._same_value or self._same_since is None:
                self._same_value, self._same_since = draft_n, draft_t
            elif draft_t - self._same_since >= s.stuck_s:
                return f"draft signal implausible: stuck at {draft_n:.0f} N for {draft_t - self._same_since:.1f} s"
        return None

    def step(
        self,
        now_s: float,
        z: float,
        *,
        draft_n: float | None = None,
        draft_t: float | None = None,
        slip: float | None = None,
        ground_z: float | None = None,
        ground_ahead_z: float | None = None,
        z_measured: float | None = None,
        z_range: tuple[float, float] | None = None,
    ) -> WorkStatus:
        """One control cycle at ``now_s`` [s] for the operator's setpoint ``z`` [m] (module docstring).

        ``draft_n``/``draft_t``: the latest draft reading [N] and its receive time [s] (None: none);
        ``slip``: travel reduction 0..1 (None: unknown); ``ground_z``: the ground reference [m];
        ``ground_ahead_z``: the ground reference where the tool will be when the hitch has followed this
        setpoint (a ground preview, one hitch lag ahead) [m], or None (no preview: the old regulator);
        ``z_measured``: the hitch's measured z [m] (with a preview: the tool's estimated true depth
        ``ground_z − z_measured`` sets the depth limits' tracking margin), or None (no margin);
        ``z_range``: (lowest, highest) z the hitch can reach [m] (the follower's workspace faces), or None
        (unbounded): the draft demand and its integral stay within it as within the depth limits, so
        they never wind up beyond a face the hitch cannot pass (:attr:`WorkStatus.z_limit` names it).

        Raises:
            WorkSettingsError: ``now_s`` or ``z`` not a finite number, ``ground_z`` not None or finite.
        """
        now = _num("now_s", now_s, -1.0e9, 1.0e9)
        z_op = _num("z", z, -10.0, 10.0)
        g = None if ground_z is None else _num("ground_z", ground_z, -10.0, 10.0)
        ga = None if ground_ahead_z is None or g is None else _num("ground_ahead_z", ground_ahead_z, -10.0, 10.0)
        zm = None if z_measured is None else _num("z_measured", z_measured, -10.0, 10.0)
        r_lo, r_hi = -math.inf, math.inf
        if z_range is not None:
            r_lo = _num("z_range[0]", z_range[0], -10.0, 10.0)
            r_hi = _num("z_range[1]", z_range[1], -10.0, 10.0)
            if r_lo > r_hi:
                raise WorkSettingsError(f"z_range = {z_range!r}: the lowest z must not exceed the highest")
        z_limit: str | None = None
        s = self._s
        dt = 0.0 if self._last_t is None else min(_DT_MAX, max(0.0, now - self._last_t))
        self._last_t = now
        mode = s.mode
        event: str | None = None
        note: str | None = None

        def out(
            zz: float, active: str, limited: bool, used: float | None = None, err: float | None = None
        ) -> WorkStatus:
            depth = None if g is None else g - zz
            self._z_out = zz
            return WorkStatus(
                now,
                zz,
                mode,
                active,
                self._fallback,
                event,
                depth,
                used,
                err,
                self._slip_raise,
                self._slip_cut,
                limited,
                note,
                z_limit,
            )

        if mode == "position":
            zz, limited, note = self._slip_raise_z(z_op, slip, dt, g)
            return out(zz, "position", limited)
        if self._fallback is None:
            problem = "no ground reference" if g is None else None
            if problem is None and mode != "float":
                problem = self._draft_problem(now, draft_n, draft_t)
            if problem is not None:
                self._fallback = problem
                event = f"work_fallback: {problem}"
        if self._fallback is not None:
            if mode == "float" and self._float_z is not None:
                return out(self._float_z, "position", False)
            zz, limited, note = self._slip_raise_z(z_op, slip, dt, g)
            return out(zz, "position", limited)
        assert g is not None
        if mode == "float":
            target = (g if ga is None else ga) - s.depth_min_m
            if self._float_z is None or abs(target - self._float_z) > FLOAT_DEAD_BAND_M:
                self._float_z = target
            return out(self._float_z, "float", False)
        assert draft_n is not None
        d_lo, d_hi = s.depth_min_m, s.depth_max_m
        d_ref = 0.5 * (d_lo + d_hi)
        # the depth limits as hitch heights, within the z the hitch can reach: a demand (or an integral) beyond
        # a workspace face only winds up (the follower clips it), and coming back takes the wound-up way
        dz_lo, dz_hi = g - d_hi, g - d_lo
        z_lo, z_hi = min(r_hi, max(r_lo, dz_lo)), min(r_hi, max(r_lo, dz_hi))
        start = min(z_hi, max(z_lo, z_op if self._z_out is None else self._z_out))  # bumpless (re)start
        if self._z_i is None:
            self._z_i = start
        target = s.draft_setpoint_n
        limited = False
        if mode == "draft" and s.slip_limit is not None:  # the slip limiter lowers the draft setpoint
            shallow = (g if ga is None else ga) - d_lo  # the shallow limit on the ground the demand is set against
            at_shallow = self._z_draft is not None and self._z_draft >= shallow - 1e-9
            note = self._slip_cut_update(slip, dt, at_shallow, ga is not None)
            limited = self._slip_cut > 0.0
            target *= 1.0 - self._slip_cut
        e = (float(draft_n) - target) / s.draft_setpoint_n
        zp = s.sensitivity * KP_DRAFT * d_ref * e
        if ga is not None:
            if zm is not None and self._depth_dem is not None:  # the hitch's tracking error, in depth
                err = (g - zm) - self._depth_dem
                self._track_var += (err * err - self._track_var) * min(1.0, dt / DEPTH_TRACK_S)
            m = min(DEPTH_MARGIN_MAX * (d_hi - d_lo), DEPTH_MARGIN_SIGMAS * math.sqrt(self._track_var))
            z_draft, beyond = self._draft_with_preview(ga, start, e, zp, d_lo + m, d_hi - m, d_ref, dt, r_lo, r_hi)
            self._depth_dem = ga - z_draft
            self._z_i = min(z_hi, max(z_lo, z_draft - zp))  # a step without the preview continues from here
        else:
            self._d_i = self._depth_dem = None
            zi = self._z_i + s.sensitivity * KI_DRAFT * d_ref * e * dt
            if self._slip_raise > 0.0:
                zi = max(zi, self._z_i)  # mixed: while the slip limiter lifts, the draft regulator may only lift
            zi = min(z_hi, max(z_lo, zi))  # anti-windup: the integral stays within the limits (depth, reach)
            want = min(dz_hi, max(dz_lo, zi + zp))  # the demand within the depth limits alone
            z_draft = min(z_hi, max(z_lo, zi + zp))
            beyond = "min" if want < r_lo else "max" if want > r_hi else None
            if self._rate is not None:
                # the hitch's speed: never ask for more, and let the integral keep only what the hitch can
                # follow (back-calculation), or it runs ahead of a lagging hitch and the loop cycles. A
                # (re)start continues from the last z handed out (first: the operator's z): no step
                prev = self._z_draft if self._z_draft is not None else start
                room = self._rate * dt
                z_rl = min(prev + room, max(prev - room, z_draft))
                if z_rl != z_draft:
                    z_draft = min(z_hi, max(z_lo, z_rl))  # the depth limits (they move with the ground) win
                    zi = min(z_hi, max(z_lo, z_draft - zp))
            self._z_i = zi
        self._z_draft = z_draft
        zz = z_draft
        if mode != "draft":
            zz = (1.0 - s.blend) * z_op + s.blend * z_draft
            zz, limited, note = self._slip_raise_z(zz, slip, dt, z_hi)
        # the reachable range bounded the demand and the output sits at that face: name it
        if (beyond == "min" and zz <= r_lo + 1e-9) or (beyond == "max" and zz >= r_hi - 1e-9):
            z_limit = beyond
        return out(zz, mode, limited, float(draft_n), e)

    def _draft_with_preview(
        self,
        ga: float,
        start: float,
        e: float,
        zp: float,
        d_lo: float,
        d_hi: float,
        d_ref: float,
        dt: float,
        r_lo: float = -math.inf,
        r_hi: float = math.inf,
    ) -> tuple[float, str | None]:
        """The draft demand with a ground preview: the PI regulates the working depth, and the previewed
        ground ``ga`` (where the tool will be when the hitch gets there) is fed forward, so the undulation
        never reaches the draft loop as an error. ``depth = clip(d_i − K_P·d_ref·e)``, ``d_i ← d_i −
        K_I·d_ref·e·Δt`` (both scaled by the sensitivity; the signs of the z regulator), ``z = ga − depth``:
        the depth limits hold on the previewed ground, i.e. on the depth the tool will have. With the
        hitch's rate the demand moves no faster than the hitch and the integral is set back to the
        bounded output (back-calculation); the depth limits on ``ga`` win over the rate. The reachable z
        range ``[r_lo, r_hi]`` bounds the depth (and its integral) too: returns the demand and the face the
        demand within the depth limits alone would lie beyond (``"min"``/``"max"``, or None)."""
        s = self._s
        want_lo, want_hi = d_lo, d_hi  # the depth limits alone
        d_lo, d_hi = min(ga - r_lo, max(ga - r_hi, d_lo)), min(ga - r_lo, max(ga - r_hi, d_hi))
        if self._d_i is None:
            self._d_i = min(d_hi, max(d_lo, ga - start))  # bumpless: the depth of the last z handed out
        di = self._d_i - s.sensitivity * KI_DRAFT * d_ref * e * dt
        if self._slip_raise > 0.0:
            di = min(di, self._d_i)  # mixed: while the slip limiter lifts, the draft regulator may only lift
        di = min(d_hi, max(d_lo, di))  # anti-windup within the depth limits (and the reachable z)
        want = min(want_hi, max(want_lo, di - zp))
        beyond = "min" if ga - want < r_lo else "max" if ga - want > r_hi else None
        z_draft = ga - min(d_hi, max(d_lo, di - zp))
        if self._rate is not None:
            prev = self._z_draft if self._z_draft is not None else start
            room = self._rate * dt
            z_rl = min(prev + room, max(prev - room, z_draft))
            if z_rl != z_draft:
                z_draft = min(ga - d_lo, max(ga - d_hi, z_rl))
                di = min(d_hi, max(d_lo, ga - z_draft + zp))
        self._d_i = di
        return z_draft, beyond

    def _slip_target(self, x: float, dt: float, margin: bool = True) -> float:
        """The limiter's target: ``slip_limit`` less the ripple margin (:data:`MARGIN_SIGMAS` times the slip's
        RMS about its low-passed mean, :data:`SLIP_MEAN_S`, :data:`SLIP_RIPPLE_S`, at most :data:`MARGIN_MAX`
        of the limit; none when ``margin`` is False)."""
        lim = self._s.slip_limit
        assert lim is not None
        if self._slip_mean is None:
            self._slip_mean = x
        else:
            self._slip_mean += (x - self._slip_mean) * min(1.0, dt / SLIP_MEAN_S)
            self._slip_var += ((x - self._slip_mean) ** 2 - self._slip_var) * min(1.0, dt / SLIP_RIPPLE_S)
        return lim - min(MARGIN_MAX * lim, MARGIN_SIGMAS * math.sqrt(self._slip_var)) if margin else lim

    def _slip_cut_update(self, slip: float | None, dt: float, at_shallow_limit: bool, margin: bool) -> str | None:
        """Draft mode: the outer loop of the cascade. The cut of the draft setpoint from the low-passed
        slip's excess over the target (the limit, less the ripple margin when ``margin``; P + I), its
        integral frozen while the regulator already sits at the shallow depth limit (cutting more cannot
        lift the tool: anti-windup), the cut rate-limited."""
        lim = self._s.slip_limit
        assert lim is not None
        if not _finite(slip):
            return "slip unavailable"
        assert slip is not None
        x = float(slip)
        if self._slip_f is None:
            self._slip_f = x
        else:
            self._slip_f += (x - self._slip_f) * min(1.0, dt / SLIP_TAU_S)
        excess = self._slip_f - self._slip_target(x, dt, margin)
        if not (at_shallow_limit and excess > 0.0):
            self._slip_i = min(MAX_CUT / KI_CUT, max(0.0, self._slip_i + excess * dt))
        cut = min(MAX_CUT, KP_CUT * max(0.0, excess) + KI_CUT * self._slip_i)
        room = CUT_RATE_MAX * dt
        self._slip_cut = min(self._slip_cut + room, max(self._slip_cut - room, cut))
        return None

    def _slip_update(self, slip: float | None, dt: float, gain_i: float, top: float) -> tuple[float, str | None]:
        """Advance the limiter's integral of the slip's excess over the target (the limit less the ripple
        margin, :meth:`_slip_target`; clamped so that ``gain_i`` times it stays within ``[0, top]``); returns
        the proportional part (the excess, ≥ 0) and a note."""
        lim = self._s.slip_limit
        if lim is None:
            return 0.0, None
        if not _finite(slip):
            return 0.0, "slip unavailable"
        assert slip is not None
        excess = float(slip) - self._slip_target(float(slip), dt)
        self._slip_i = min(top / gain_i, max(0.0, self._slip_i + excess * dt))
        return max(0.0, excess), None

    def _slip_raise_z(
        self, z: float, slip: float | None, dt: float, ceiling: float | None
    ) -> tuple[float, bool, str | None]:
        """Position and mixed: lift ``z`` by the limiter's raise, never above ``ceiling`` nor below ``z``."""
        if self._s.slip_limit is None:
            return z, False, None
        p, note = self._slip_update(slip, dt, KI_SLIP, self._s.depth_max_m)
        self._slip_raise = min(self._s.depth_max_m, KP_SLIP * p + KI_SLIP * self._slip_i)
        if self._slip_raise <= 0.0:
            return z, False, note
        zz = z + self._slip_raise
        if ceiling is not None:
            zz = max(z, min(zz, ceiling))
        return zz, True, note
