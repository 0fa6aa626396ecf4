"""JSON on the wire: strict JSON bytes for every reply, state and event the service sends."""

from __future__ import annotations

import json
import math
from typing import Any

__all__ = ["to_json_bytes", "to_json_text"]


def _finite(obj: Any) -> Any:
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite(v) for v in obj]
    return obj


def to_json_bytes(obj: Any) -> bytes:
    """Strict JSON (no NaN/Infinity tokens: non-finite numbers become null)."""
    try:
        return json.dumps(obj, allow_nan=False, separators=(",", ":")).encode()
    except ValueError:
        return json.dumps(_finite(obj), allow_nan=False, separators=(",", ":")).encode()


def to_json_text(obj: Any, *, indent: int | None = None) -> str:
    """:func:`to_json_bytes` as text for people and files (the CLI's ``--json``): strict JSON, non-finite
    numbers as null (Python's ``json`` would write the bare ``NaN`` no JSON reader takes)."""
    try:
        return json.dumps(obj, allow_nan=False, indent=indent)
    except ValueError:
        return json.dumps(_finite(obj), allow_nan=False, indent=indent)
