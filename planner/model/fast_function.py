"""Low-overhead evaluation of CasADi functions through ``Function.buffer()``.

A plain ``Function.__call__`` from Python costs 15-30 µs; binding numpy arrays to a
buffer once and re-evaluating costs about 1 µs. :class:`FastFunction` owns the input
and output arrays; callers copy inputs in and read (or copy) outputs.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from planner.model.types import ModelInputError

__all__ = ["FastFunction"]


class FastFunction:
    """A CasADi ``Function`` with pre-bound dense numpy input/output buffers.

    ``inputs[i]`` is the flat (column-major) input ``i``; ``outputs[i]`` the dense output
    ``i`` as a Fortran-ordered 2-D array, overwritten by every call.
    """

    def __init__(self, function: ca.Function):
        self.function = function
        self._buf, self._eval = function.buffer()
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
