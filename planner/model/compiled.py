"""CasADi functions compiled to machine code with the system C compiler, cached on disk.

CasADi evaluates an SX function in its virtual machine; the same instructions generated as
C (``CodeGenerator``) and compiled run 2-5× faster for the hitch's kinematics (the exact
inverse over 64 poses 306 → 58 µs, the forward points 138 → 58 µs on this project's
machines). The generated code performs the same IEEE operations in the same order and
calls the same libm functions as the virtual machine; it is compiled without fast-math and
without floating-point contraction (``-ffp-contract=off``: no fused multiply-add), so its
results are those of the virtual machine bit for bit (checked in the tests).

A library is keyed by the SHA-256 of its C source and the compiler command, built once per
machine into the cache directory (``$HITCH_CASADI_CACHE``, else ``$XDG_CACHE_HOME`` or
``~/.cache`` + ``/hitch-planner/casadi``) and loaded with ``casadi.external``. ``make``
builds the default profile's libraries at install time (``python -m planner.warm_compiled``).

Falls back to the virtual machine — same values, slower — when ``HITCH_CASADI_COMPILE=0``,
when no C compiler is found (``$CC``, else ``cc`` / ``gcc``), or when compiling or loading
fails (logged once per library).
"""

from __future__ import annotations

import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Sequence
from pathlib import Path

import casadi as ca

__all__ = ["compile_functions", "compiler", "cache_dir", "CFLAGS"]

_log = logging.getLogger(__name__)

#: flags of every build: optimised, position independent, IEEE semantics kept (no fast-math, no FMA)
CFLAGS: tuple[str, ...] = ("-O2", "-fPIC", "-shared", "-ffp-contract=off", "-fno-fast-math")
_LOCK = threading.Lock()
_LOADED: dict[str, list[ca.Function]] = {}  # by library key: the externals of this process
_FAILED: set[str] = set()


def compiler() -> str | None:
    """Path of the C compiler to use, or None (compilation disabled or no compiler found)."""
    if os.environ.get("HITCH_CASADI_COMPILE", "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    for name in (os.environ.get("CC"), "cc", "gcc"):
        if name:
            path = shutil.which(name)
            if path:
                return path
    return None


def cache_dir() -> Path:
    """Directory of the compiled libraries (created on demand)."""
    env = os.environ.get("HITCH_CASADI_CACHE")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "hitch-planner" / "casadi"


def compile_functions(functions: Sequence[ca.Function]) -> list[ca.Function]:
    """The ``functions`` compiled into one library (one ``casadi.external`` each, same order,
    same inputs and outputs); the functions themselves when compiling is unavailable or fails.

    Names must be distinct. Evaluation only (numeric inputs): the externals take no SX
    symbols, keep the originals for symbolic work.
    """
    fns = list(functions)
    names = [f.name() for f in fns]
    if not fns or len(set(names)) != len(names):
        raise ValueError(f"compile_functions: expected distinct function names, got {names}")
    cc = compiler()
    if cc is None:
        return fns
    gen = ca.CodeGenerator("hitch_compiled.c", {"with_header": False})
    for f in fns:
        gen.add(f)
    source = gen.dump()
    command = (cc, *CFLAGS)
    key = hashlib.sha256("\0".join((*command, ca.CasadiMeta.version(), source)).encode()).hexdigest()[:32]
    with _LOCK:
        if key in _LOADED:
            return list(_LOADED[key])
        if key in _FAILED:
            return fns
        try:
            lib = _build(source, command, key)
            externals = [ca.external(n, str(lib)) for n in names]
        except (OSError, RuntimeError, subprocess.SubprocessError) as exc:
            detail = getattr(exc, "stderr", None) or b""
            detail = detail.decode(errors="replace") if isinstance(detail, bytes) else str(detail)
            _log.warning(
                "CasADi functions %s evaluated in the virtual machine: compiling failed: %s %s",
                names,
                exc,
                detail[-500:],
            )
            _FAILED.add(key)
            return fns
        _LOADED[key] = externals
        return list(externals)


def _build(source: str, command: tuple[str, ...], key: str) -> Path:
    """The library of ``source`` in the cache, compiled there first if missing (atomically:
    built under a temporary name and renamed, so concurrent processes never load half a file)."""
    directory = cache_dir()
    lib = directory / f"hitch_{key}.so"
    if lib.exists():
        return lib
    directory.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=directory, prefix=".build-") as tmp:
        c_file = Path(tmp) / f"hitch_{key}.c"
        c_file.write_text(source)
        out = Path(tmp) / lib.name
        subprocess.run([*command, str(c_file), "-o", str(out), "-lm"], check=True, capture_output=True, timeout=300)
        os.replace(out, lib)
    return lib
