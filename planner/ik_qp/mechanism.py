"""A mechanism as the SQP inverse-kinematics core sees it: CasADi functions of its actuators.

The core is mechanism-agnostic. A :class:`Mechanism` supplies, as functions of the actuator
vector ``q`` (``n`` values, SI: m for lengths, rad for angles):

* the task vector ``t(q)`` (``m`` rows, e.g. pose features) and its Jacobian ``dt/dq``;
* optional equalities ``h(q) = 0`` (e.g. the implement rigidity ``|L − R| = span``,
  thesis 2.49) and their Jacobian;
* optional inequalities ``g_lower <= g(q) <= g_upper`` (e.g. top-link angle limits,
  lower-link end heights) and their Jacobian;
* hard actuator bounds ``lower <= q <= upper``.

Functions may return non-finite values where the mechanism cannot close; the solver treats
such points as invalid (it rejects the step), it never propagates them.
:func:`build_mechanism` builds the functions (with their Jacobians by automatic
differentiation) from symbolic expressions.

For the solver, :meth:`Mechanism.linearisation_function` composes everything one SQP
iteration needs into a single CasADi function (evaluated through
:class:`LinearisationPoint` buffers, ~1 µs plus the model), and
:class:`LagrangianCurvature` keeps the secant curvature estimate.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import TypeVar

import casadi as ca
import numpy as np

from planner.ik_qp.errors import IKInputError
from planner.model.fast_function import FastFunction

#: Default trust region per SQP iteration as a fraction of each finite stroke.
DEFAULT_STEP_FRACTION = 0.25
#: Default trust region of actuators with an infinite (or zero) stroke [actuator unit].
DEFAULT_UNBOUNDED_STEP = 0.5

__all__ = [
    "DEFAULT_STEP_FRACTION",
    "DEFAULT_UNBOUNDED_STEP",
    "LagrangianCurvature",
    "LinearisationPoint",
    "Mechanism",
    "TaskError",
    "build_mechanism",
]

#: ``error(target, t) -> e``: task error with ``e(q + dq) ≈ e(q) − J dq`` (default ``target − t``).
TaskError = Callable[[np.ndarray, np.ndarray], np.ndarray]
#: A CasADi symbolic type; all expressions given to :func:`build_mechanism` share one.
Symbolic = TypeVar("Symbolic", ca.SX, ca.MX)


def _names(value, field_name: str) -> tuple[str, ...]:
    names = tuple(value)
    for name in names:
        if not isinstance(name, str) or not name:
            raise IKInputError(f"{field_name}: every name must be a non-empty string, got {name!r}")
    if len(set(names)) != len(names):
        raise IKInputError(f"{field_name}: names must be unique, got {names}")
    return names


def _vector(value, size: int, field_name: str, *, allow_inf: bool) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise IKInputError(f"{field_name}: expected {size} numbers, got {value!r}") from None
    if arr.size != size:
        raise IKInputError(f"{field_name}: expected {size} values, got {arr.size}")
    bad = np.isnan(arr) if allow_inf else ~np.isfinite(arr)
    if bad.any():
        allowed = "numbers or ±inf" if allow_inf else "finite numbers"
        raise IKInputError(f"{field_name}[{int(np.flatnonzero(bad)[0])}] must be {allowed}, got {arr[bad][0]}")
    arr.setflags(write=False)
    return arr


def _check_function(fn, n: int, rows: int, field_name: str) -> None:
    if not isinstance(fn, ca.Function):
        raise IKInputError(f"{field_name}: expected a casadi.Function, got {type(fn).__name__}")
    if fn.n_in() != 1 or fn.size1_in(0) * fn.size2_in(0) != n:
        raise IKInputError(f"{field_name}: must take one input of {n} values (the actuator vector)")
    if fn.n_out() < 2:
        raise IKInputError(f"{field_name}: must return (value ({rows}x1), jacobian ({rows}x{n}))")
    if fn.size_out(0) != (rows, 1) or fn.size_out(1) != (rows, n):
        raise IKInputError(
            f"{field_name}: outputs must be ({rows}x1) and ({rows}x{n}), got {fn.size_out(0)} and {fn.size_out(1)}"
        )


@dataclass(frozen=True, eq=False)
class Mechanism:
    """A mechanism = CasADi functions of its actuator vector ``q`` (``n`` values, SI).

    Attributes:
        name: Label used in messages.
        actuator_names: ``n`` names; limits are reported as ``<limit_kind>:<name>:min|max``.
        lower, upper: Hard actuator bounds ``(n,)`` (±inf allowed, ``lower <= upper``).
        task: ``q -> (t (m,1), dt/dq (m,n))``, the task vector (e.g. pose features).
        task_names: ``m`` names (task bounds are reported as ``<label>:<task name>:min|max``).
        equality: ``q -> (h (p,1), dh/dq (p,n))`` with ``h == 0`` wanted, or ``None``.
        equality_names: ``p`` names.
        inequality: ``q -> (g (r,1), dg/dq (r,n))`` with ``g_lower <= g <= g_upper``, or ``None``.
        inequality_names: ``r`` names; limits reported as ``<name>:min|max`` unless
            ``inequality_side_names`` gives explicit ``(min_name, max_name)`` pairs.
        g_lower, g_upper: ``(r,)`` bounds of the inequality rows, may contain ±inf.
        task_error: Optional ``error(target, t) -> e (m,)`` for tasks whose error is not
            ``target − t``; it must satisfy ``e(q + dq) ≈ e(q) − J dq`` to first order (near
            ``e = 0``) with ``J`` the task function's Jacobian output. E.g. a 6-D pose task:
            ``t = (p, r)`` with ``r`` the rotation vector of ``R``, ``J = (J_v, J_ω)`` (linear and
            world angular-velocity Jacobians), ``e = (p* − p, log(R* Rᵀ))``.
        inequality_side_names: Optional ``r`` pairs ``(min_name, max_name)``.
        limit_kind: What an actuator bound is called in limit names: ``"stroke"`` (the hitch's
            cylinders and lift arms, the default) or e.g. ``"joint"`` (a serial arm's joints).
        several_solutions: Whether a target may have several IK solutions (a serial arm: up to
            eight), so a stationary point of the weighted error at a non-zero residual may be a
            local minimum of a reachable target; the SQP solver's reason then does not claim the
            target is out of reach. ``several_solutions_note`` says where every solution is found.

    Arrays are stored read-only; equality is identity (``eq=False``), so mechanisms can key
    dictionaries.
    """

    name: str
    actuator_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    task: ca.Function
    task_names: tuple[str, ...]
    equality: ca.Function | None = None
    equality_names: tuple[str, ...] = ()
    inequality: ca.Function | None = None
    inequality_names: tuple[str, ...] = ()
    g_lower: np.ndarray = field(default_factory=lambda: np.zeros(0))
    g_upper: np.ndarray = field(default_factory=lambda: np.zeros(0))
    task_error: TaskError | None = None
    inequality_side_names: tuple[tuple[str, str], ...] | None = None
    limit_kind: str = "stroke"
    several_solutions: bool = False
    several_solutions_note: str = ""

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        if not isinstance(self.name, str) or not self.name:
            raise IKInputError(f"name: must be a non-empty string, got {self.name!r}")
        if not isinstance(self.limit_kind, str) or not self.limit_kind.isidentifier():
            raise IKInputError(f"limit_kind: must be a word such as 'stroke' or 'joint', got {self.limit_kind!r}")
        if not isinstance(self.several_solutions, bool):
            raise IKInputError(f"several_solutions: must be True or False, got {self.several_solutions!r}")
        if not isinstance(self.several_solutions_note, str):
            raise IKInputError(f"several_solutions_note: must be a string, got {self.several_solutions_note!r}")
        set_(self, "actuator_names", _names(self.actuator_names, "actuator_names"))
        n = len(self.actuator_names)
        if n == 0:
            raise IKInputError("actuator_names: a mechanism needs at least one actuator")
        set_(self, "lower", _vector(self.lower, n, "lower", allow_inf=True))
        set_(self, "upper", _vector(self.upper, n, "upper", allow_inf=True))
        bad = np.flatnonzero(self.lower > self.upper)
        if bad.size:
            i = int(bad[0])
            raise IKInputError(
                f"lower[{i}] ({self.actuator_names[i]}) = {self.lower[i]} exceeds upper = {self.upper[i]}"
            )
        set_(self, "task_names", _names(self.task_names, "task_names"))
        if not self.task_names:
            raise IKInputError("task_names: a mechanism needs at least one task row")
        _check_function(self.task, n, len(self.task_names), "task")
        set_(self, "equality_names", _names(self.equality_names, "equality_names"))
        if self.equality is None and self.equality_names:
            raise IKInputError("equality_names: given without an equality function")
        if self.equality is not None:
            _check_function(self.equality, n, len(self.equality_names), "equality")
        set_(self, "inequality_names", _names(self.inequality_names, "inequality_names"))
        r = len(self.inequality_names)
        if self.inequality is None and r:
            raise IKInputError("inequality_names: given without an inequality function")
        if self.inequality is not None:
            _check_function(self.inequality, n, r, "inequality")
        set_(self, "g_lower", _vector(self.g_lower, r, "g_lower", allow_inf=True))
        set_(self, "g_upper", _vector(self.g_upper, r, "g_upper", allow_inf=True))
        bad = np.flatnonzero(self.g_lower > self.g_upper)
        if bad.size:
            i = int(bad[0])
            raise IKInputError(
                f"g_lower[{i}] ({self.inequality_names[i]}) = {self.g_lower[i]} exceeds g_upper = {self.g_upper[i]}"
            )
        if self.task_error is not None and not callable(self.task_error):
            raise IKInputError("task_error: must be callable error(target, t) -> e")
        if self.inequality_side_names is not None:
            pairs = tuple((str(a), str(b)) for a, b in self.inequality_side_names)
            if len(pairs) != r:
                raise IKInputError(f"inequality_side_names: expected {r} (min, max) pairs, got {len(pairs)}")
            set_(self, "inequality_side_names", pairs)

    # ------------------------------------------------------------------ sizes
    @property
    def n(self) -> int:
        """Number of actuators."""
        return len(self.actuator_names)

    @property
    def m(self) -> int:
        """Number of task rows."""
        return len(self.task_names)

    @property
    def p(self) -> int:
        """Number of equality rows."""
        return len(self.equality_names)

    @property
    def r(self) -> int:
        """Number of inequality rows."""
        return len(self.inequality_names)

    @cached_property
    def default_max_step(self) -> np.ndarray:
        """Per-iteration trust region: ``DEFAULT_STEP_FRACTION`` of each finite stroke,
        ``DEFAULT_UNBOUNDED_STEP`` otherwise (actuator units, read-only)."""
        span = self.upper - self.lower
        step = np.where(np.isfinite(span) & (span > 0), DEFAULT_STEP_FRACTION * span, DEFAULT_UNBOUNDED_STEP)
        step.setflags(write=False)
        return step

    def limit_names(self) -> tuple[tuple[str, str], ...]:
        """``(min_name, max_name)`` of every inequality row."""
        if self.inequality_side_names is not None:
            return self.inequality_side_names
        return tuple((f"{name}:min", f"{name}:max") for name in self.inequality_names)

    def linearisation_function(self, bound_rows: Sequence[int] = ()) -> ca.Function:
        """Everything one SQP iteration needs at ``q``, in one CasADi call.

        Inputs: ``q``, ``target``, ``weights``, ``c_lower``/``c_upper`` (bounds of ``c``),
        ``lower``/``upper`` (strokes), ``step`` (trust region).

        Outputs: ``t`` (m), ``J = dt/dq`` (m×n), ``e = target − t`` (m), ``JᵀW²J`` (n×n),
        ``JᵀW²e`` (n), the constraint vector ``c = (h, g, t[bound_rows])`` (k) and its
        Jacobian (k×n); the QP bounds of ``(d, C d)``: ``l0 = (max(lower − q, −step),
        c_lower − c)`` and ``u0 = (min(upper − q, step), c_upper − c)`` (±inf where ``c`` has
        no bound); ``stats = (‖W e‖₂, ‖violation‖₁, ‖violation‖∞, ‖JᵀW²e‖∞, max diag JᵀW²J,
        ‖C‖max, ‖q‖∞)``; ``check``, the sum of every value (non-finite iff any value is).
        Dense outputs; expanded to SX when every part allows it, with common
        subexpressions eliminated.
        """
        n, m = self.n, self.m
        rows = list(bound_rows)
        q, target, w = ca.MX.sym("q", n), ca.MX.sym("target", m), ca.MX.sym("weights", m)
        lower, upper, step = ca.MX.sym("lower", n), ca.MX.sym("upper", n), ca.MX.sym("step", n)
        t, J = self.task(q)[:2]
        c_parts, C_parts = [], []
        for fn in (self.equality, self.inequality):
            if fn is not None:
                v, D = fn(q)[:2]
                c_parts.append(v)
                C_parts.append(D)
        if rows:
            c_parts.append(t[rows])
            C_parts.append(J[rows, :])
        c = ca.vertcat(*c_parts) if c_parts else ca.MX(0, 1)
        C = ca.vertcat(*C_parts) if C_parts else ca.MX(0, n)
        k = c.size1()
        cl, cu = ca.MX.sym("c_lower", k), ca.MX.sym("c_upper", k)
        e = target - t
        we = w * e
        wJ = ca.mtimes(ca.diag(w), J)
        H0, g = ca.mtimes(wJ.T, wJ), ca.mtimes(wJ.T, we)
        viol = ca.fmax(ca.fmax(cl - c, c - cu), 0)
        l0 = ca.vertcat(ca.fmax(lower - q, -step), cl - c)
        u0 = ca.vertcat(ca.fmin(upper - q, step), cu - c)
        zero = ca.MX(0)
        stats = ca.vertcat(
            ca.norm_2(we),
            ca.sum1(viol) if k else zero,
            ca.mmax(viol) if k else zero,
            ca.norm_inf(g),
            ca.mmax(ca.diag(H0)),
            ca.mmax(ca.fabs(C)) if k else zero,
            ca.norm_inf(q),
        )
        outs = [ca.densify(o) for o in (t, J, e, H0, g, c, C, l0, u0, stats)]
        outs.append(sum((ca.sum1(ca.sum2(o)) for o in outs[:7]), zero))
        names = ["t", "J", "e", "JtWWJ", "JtWWe", "c", "C", "l0", "u0", "stats", "check"]
        ins = [q, target, w, cl, cu, lower, upper, step]
        in_names = ["q", "target", "weights", "c_lower", "c_upper", "lower", "upper", "step"]
        fn = ca.Function(f"{self.name}_sqp_linearisation", ins, outs, in_names, names)
        try:
            sx = fn.expand()
        except RuntimeError:  # parts not expressible in SX: keep the MX composition
            return ca.Function(fn.name(), ins, outs, in_names, names, {"cse": True})
        # Task, equality and inequality often share one model graph: eliminate the common
        # subexpressions (3x fewer instructions on the hitch, ~5 µs instead of ~16 µs).
        return ca.Function(sx.name(), sx.sx_in(), sx.call(sx.sx_in()), in_names, names, {"cse": True})


def build_mechanism(
    name: str,
    q: Symbolic,
    task: Symbolic,
    *,
    actuator_names: Sequence[str],
    lower,
    upper,
    task_names: Sequence[str],
    equality: Symbolic | None = None,
    equality_names: Sequence[str] = (),
    inequality: Symbolic | None = None,
    inequality_names: Sequence[str] = (),
    g_lower=(),
    g_upper=(),
    task_error: TaskError | None = None,
    inequality_side_names: Sequence[tuple[str, str]] | None = None,
) -> Mechanism:
    """Build a :class:`Mechanism` from symbolic expressions of the actuator symbol ``q``.

    Jacobians come from CasADi automatic differentiation (dense).
    """

    def fn(label: str, expr: Symbolic) -> ca.Function:
        v = ca.vec(expr)
        return ca.Function(f"{name}_{label}", [q], [ca.densify(v), ca.densify(ca.jacobian(v, q))])

    return Mechanism(
        name=name,
        actuator_names=tuple(actuator_names),
        lower=lower,
        upper=upper,
        task=fn("task", task),
        task_names=tuple(task_names),
        equality=fn("equality", equality) if equality is not None else None,
        equality_names=tuple(equality_names),
        inequality=fn("inequality", inequality) if inequality is not None else None,
        inequality_names=tuple(inequality_names),
        g_lower=g_lower,
        g_upper=g_upper,
        task_error=task_error,
        inequality_side_names=tuple(inequality_side_names) if inequality_side_names is not None else None,
    )


class LinearisationPoint:
    """Buffers of one evaluation of :meth:`Mechanism.linearisation_function` (about 1–2 µs
    plus the model). The SQP keeps two and swaps them (current point, trial point).

    After :meth:`load` (``True`` iff every value is finite): arrays ``q``, ``t``, ``J``,
    ``e``, ``H0 = JᵀW²J``, ``g = JᵀW²e``, ``c``, ``C``, ``l0``, ``u0`` and floats ``res``
    (``‖W e‖``), ``v1``/``vinf`` (violation norms), ``g_inf``, ``p_max``, ``c_inf``,
    ``q_inf``. With a custom ``task_error`` the error terms are recomputed in numpy.
    """

    def __init__(self, mechanism: Mechanism, function: ca.Function):
        self.mechanism = mechanism
        self._fn = FastFunction(function)
        out = self._fn.outputs
        self.t, self.J, self.e = out[0][:, 0], out[1], out[2][:, 0]
        self.H0, self.g = out[3], out[4][:, 0]
        self.c, self.C = out[5][:, 0], out[6]
        self.l0, self.u0 = out[7][:, 0], out[8][:, 0]
        self._stats, self._check = out[9][:, 0], out[10]
        self.q = np.zeros(mechanism.n)
        self.res = self.v1 = self.vinf = self.g_inf = self.p_max = self.c_inf = self.q_inf = 0.0
        ins = self._fn.inputs
        ins[5][:], ins[6][:] = mechanism.lower, mechanism.upper

    def set_problem(
        self, target: np.ndarray, weights: np.ndarray, c_lower: np.ndarray, c_upper: np.ndarray, step: np.ndarray
    ) -> None:
        """Bind the problem data (kept until the next call)."""
        ins = self._fn.inputs
        ins[1][:], ins[2][:], ins[3][:], ins[4][:], ins[7][:] = target, weights, c_lower, c_upper, step

    def load(self, q: np.ndarray) -> bool:
        """Evaluate at ``q``; ``False`` if the mechanism gives any non-finite value there."""
        self.q[:] = q
        self._fn(q)
        if not math.isfinite(self._check[0, 0]):
            return False
        self.res, self.v1, self.vinf, self.g_inf, self.p_max, self.c_inf, self.q_inf = self._stats.tolist()
        err = self.mechanism.task_error
        if err is None:
            return True
        target, w = self._fn.inputs[1], self._fn.inputs[2]
        e = np.asarray(err(target.copy(), self.t.copy()), dtype=float).reshape(-1)
        if e.shape != self.e.shape or not np.isfinite(e).all():
            return False
        self.e[:] = e
        we = w * e
        self.res = math.sqrt(we @ we)
        np.matmul(self.J.T, w * we, out=self.g)
        self.g_inf = float(np.abs(self.g).max())
        return True


class LagrangianCurvature:
    """Symmetric-rank-one estimate ``S`` of the Lagrangian curvature that Gauss–Newton's
    ``JᵀW²J`` misses, ``−Σ w_i² e_i ∇²t_i + Σ y_j ∇²c_j`` (residual and constraint
    curvature), learnt from secant pairs of ``∇L = −JᵀW²e + Cᵀy`` between two
    :class:`LinearisationPoint`. No second derivatives; may be indefinite. The SQP uses it
    where Gauss–Newton converges only linearly (out-of-reach targets, curved active limits).
    """

    def __init__(self, n: int):
        self.S = np.zeros((n, n))
        self.pairs = 0

    def reset(self) -> None:
        self.S[:] = 0.0
        self.pairs = 0

    def update(self, new: LinearisationPoint, old: LinearisationPoint, y_c: np.ndarray) -> None:
        """Secant update from the step ``old.q → new.q`` with constraint multipliers ``y_c``."""
        s = new.q - old.q
        r = old.g - new.g - new.H0 @ s - self.S @ s
        if y_c.size:
            r += (new.C - old.C).T @ y_c
        rs = float(r @ s)
        if math.isfinite(rs) and abs(rs) > 1e-8 * math.sqrt(float(r @ r) * float(s @ s)):
            self.S += np.outer(r, r / rs)
            self.pairs += 1
