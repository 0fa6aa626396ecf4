"""The control core in a process of its own: the service's side (:mod:`.client`) and the core's (:mod:`.process`)."""

from __future__ import annotations

from bridge.service.core.client import CoreError, CoreProcess, MotionProxy

__all__ = ["CoreError", "CoreProcess", "MotionProxy"]
