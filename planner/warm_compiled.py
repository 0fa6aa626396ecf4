"""Build the compiled CasADi libraries of the default profile's hot paths once per machine
(:mod:`planner.model.compiled`): ``python -m planner.warm_compiled``, run by ``make`` at install time.
It sits above :mod:`planner.model` and :mod:`planner.trajectory` because it warms both."""

from __future__ import annotations

__all__ = ["warm"]


def warm() -> None:  # pragma: no cover - exercised by `make`
    """Build the libraries of the default profile's hot paths (the exact inverse and the forward batch)."""
    import numpy as np

    from planner.model import compiled  # this module as the others import it (not __main__)
    from planner.model.exact_inverse import ExactInverse
    from planner.model.kinematics import HitchModel
    from planner.trajectory.plan import forward_batch

    model = HitchModel.from_profile()
    inverse = ExactInverse(model)
    inverse.solve_batch(np.zeros((1, 4)), np.zeros((1, 4)))
    inverse.jacobians(np.zeros((1, 4)))
    forward_batch(model)(model.neutral[None, :])
    cc = compiled.compiler()
    built, failed = len(compiled._LOADED), len(compiled._FAILED)
    where = f"{built} compiled with {cc} in {compiled.cache_dir()}" if cc else "the virtual machine (no C compiler)"
    print(f"CasADi libraries: {where}" + (f"; {failed} failed (virtual machine)" if failed else ""))


if __name__ == "__main__":  # pragma: no cover
    warm()
