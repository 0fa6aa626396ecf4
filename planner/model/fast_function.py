"""Low-overhead evaluation of CasADi functions through ``Function.buffer()``.

A plain ``Function.__call__`` from Python costs 15-30 µs; binding numpy arrays to a
buffer once and re-evaluating costs about 1 µs. :class:`FastFunction` owns the input
and output arrays; callers copy inputs in and read (or copy) outputs.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from planner.model.compiled import compile_functions
from planner.model.types import ModelInputError

__all__ = ["FastFunction", "MappedFunction"]


class FastFunction:
    """A CasADi ``Function`` with pre-bound dense numpy input/output buffers.

    ``inputs[i]`` is the flat (column-major) input ``i``; ``outputs[i]`` the dense output
    ``i`` as a Fortran-ordered 2-D array, overwritten by every call. With ``compiled``, the
    function is evaluated as compiled machine code (:func:`~planner.model.compiled.compile_functions`:
    the same values, bit for bit; the virtual machine when no compiler is available);
    ``function`` stays the given (symbolic) one.
    """

    def __init__(self, function: ca.Function, *, compiled: bool = False):
        self.function = function
        evaluated = compile_functions([function])[0] if compiled else function
        self._buf, self._eval = evaluated.buffer()
        self.inputs: list[np.ndarray] = [
            np.zeros(function.size1_in(i) * function.size2_in(i)) for i in range(function.n_in())
        ]
        self.outputs: list[np.ndarray] = [
            np.zeros((function.size1_out(i), function.size2_out(i)), order="F") for i in range(function.n_out())
        ]
        # The SWIG wrapper takes (i, buffer) and derives the size from the buffer itself;
        # casadi.pyi declares an extra ``size`` argument the runtime rejects.
        for i, arr in enumerate(self.inputs):
            self._buf.set_arg(i, arr.data)  # type: ignore[call-arg]  # casadi.pyi: spurious size argument
        for i, out in enumerate(self.outputs):
            if not function.sparsity_out(i).is_dense():
                raise ModelInputError(f"output {i} of {function.name()} must be dense")
            self._buf.set_res(i, out.reshape(-1, order="F").data)  # type: ignore[call-arg]  # as set_arg

    def __call__(self, *args: ArrayLike) -> list[np.ndarray]:
        """Evaluate with the given inputs; returns the (shared, overwritten) output arrays.

        Fewer arguments than inputs leave the remaining inputs as they are.
        """
        for dst, src in zip(self.inputs, args, strict=False):  # trailing inputs may be bound once
            if isinstance(src, np.ndarray) and src.ndim == 1:
                dst[:] = src
            else:
                dst[:] = np.ravel(src, order="F")
        self._eval()
        return self.outputs


class MappedFunction:
    """A CasADi ``Function`` of column-vector inputs evaluated over N columns at once.

    ``function.map(c)`` for chunk sizes ``chunks`` (largest first, the last 1; by default 64, 8,
    1, compiled the powers of two from 128), each through
    a :class:`FastFunction` built on first use: N columns cost ⌈N / c⌉ + a few calls instead
    of N. Every column is evaluated by the same instructions as ``function`` alone, so the
    values are those of N single calls, bit for bit.

    With ``compiled``, the chunk functions are compiled to machine code on first use, all in
    one library (:func:`~planner.model.compiled.compile_functions`: the same values, bit for
    bit; the virtual machine when no compiler is available).
    """

    def __init__(self, function: ca.Function, chunks: tuple[int, ...] | None = None, *, compiled: bool = False):
        for i in range(function.n_in()):
            if function.size2_in(i) != 1:
                raise ModelInputError(f"input {i} of {function.name()} must be a column vector")
        if chunks is None:  # compiled, a call costs ~1 µs: powers of two, at most 8 calls below 256 columns
            chunks = (128, 64, 32, 16, 8, 4, 2, 1) if compiled else (64, 8, 1)
        if not chunks or chunks[-1] != 1 or list(chunks) != sorted(chunks, reverse=True):
            raise ModelInputError(f"chunks must be decreasing and end with 1, got {chunks}")
        self.function = function
        self.chunks = tuple(int(c) for c in chunks)
        self.compiled = compiled
        self._fast: dict[int, FastFunction] = {}

    def _chunk(self, c: int) -> FastFunction:
        fast = self._fast.get(c)
        if fast is None:
            if self.compiled:  # every chunk at once: one library
                fns = compile_functions([self.function if k == 1 else self.function.map(k) for k in self.chunks])
                self._fast.update({k: FastFunction(f) for k, f in zip(self.chunks, fns, strict=True)})
                return self._fast[c]
            fast = self._fast[c] = FastFunction(self.function if c == 1 else self.function.map(c))
        return fast

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        """Inputs ``args[i]`` of shape (size of input i, N); returns, per output, a new array
        (rows, columns of the output × N): column block k is the output for input column k."""
        fn = self.function
        if len(args) != fn.n_in():
            raise ModelInputError(f"{fn.name()}: expected {fn.n_in()} inputs of N columns each, got {len(args)}")
        cols = [np.asarray(a, float).reshape(fn.size1_in(i), -1) for i, a in enumerate(args)]
        n = cols[0].shape[1] if cols else 0
        if any(c.shape[1] != n for c in cols):
            raise ModelInputError(f"{fn.name()}: every input must have the same number of columns")
        widths = [fn.size2_out(i) for i in range(fn.n_out())]
        outs = [np.empty((fn.size1_out(i), w * n), order="F") for i, w in enumerate(widths)]
        s = 0
        for c in self.chunks:
            while n - s >= c:
                res = self._chunk(c)(*(col[:, s : s + c] for col in cols))
                for out, r, w in zip(outs, res, widths, strict=True):
                    out[:, s * w : (s + c) * w] = r
                s += c
        return outs
