"""Shared loading of TOML profiles (hitch, arm, tractor): file or built-in name, TOML parsing,
and validation errors that name the field, the value and the allowed range."""

from __future__ import annotations

import math
import tomllib
from importlib import resources
from importlib.resources.abc import Traversable
from os import PathLike
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ValidationError
from pydantic.fields import FieldInfo

from planner.errors import HitchInputError, unit_hint_within
from planner.textfile import read_text_file

__all__ = ["ProfileError", "builtin_profiles", "read_profile", "format_validation_error", "check_profile_name"]


class ProfileError(HitchInputError):
    """A profile that cannot be used; the message names field, value and allowed range.

    Raised for hitch profiles (re-exported by :mod:`planner.profiles.hitch`); arm and tractor
    profiles have their own classes. Inside the pydantic validators it is caught by pydantic
    (it is a ValueError) and reported as one line of the validation message.
    """


def check_profile_name(name: str) -> str:
    """A profile's ``name``: letters, digits, '-', '_' and '.' only (it names files and keys)."""
    if not all(c.isalnum() or c in "-_." for c in name):
        raise ProfileError("name may contain letters, digits, '-', '_' and '.' only")
    return name


def _folder(subfolder: str | None) -> Traversable:
    base = resources.files("planner") / "profiles"
    return base / subfolder if subfolder else base


def builtin_profiles(subfolder: str | None) -> list[str]:
    """Names of the built-in profiles in ``planner/profiles/<subfolder>``."""
    return sorted(p.name[:-5] for p in _folder(subfolder).iterdir() if p.name.endswith(".toml"))


def read_profile(
    name_or_path: str | Path, *, subfolder: str | None, kind: str, error: type[HitchInputError]
) -> tuple[str, dict[str, Any]]:
    """(source, parsed TOML) from a path to a .toml file or a built-in name; ``error`` on failure (also for a
    name that is neither text nor a path: ``None`` failed in ``Path`` with a bare TypeError)."""
    if not isinstance(name_or_path, (str, PathLike)):
        raise error(
            f"{kind}: a built-in name ({', '.join(builtin_profiles(subfolder))}) or a path to a .toml file is "
            f"expected, got {type(name_or_path).__name__} {name_or_path!r}"
        )
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        if p.is_dir():  # "profile file /tmp does not exist" for a folder that does
            raise error(f"{kind} file {p} is a directory, not a file: give a .toml file or a built-in name")
        if not p.is_file():
            raise error(f"{kind} file {p} " + ("is not a regular file" if p.exists() else "does not exist"))
        source, text = str(p), read_text_file(p, f"{kind} file", error)
    else:
        source = str(name_or_path)
        res = _folder(subfolder) / f"{source}.toml"
        if not res.is_file():
            raise error(
                f"{kind} {source!r} not found; built-in {kind}s: {', '.join(builtin_profiles(subfolder))} "
                "(or give a path to a .toml file)"
            )
        text = read_text_file(res, kind, error)
    try:
        return source, tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(f"{kind} {source} is not valid TOML: {exc}") from None


def _field_info(model: type[BaseModel] | None, loc: tuple[int | str, ...]) -> FieldInfo | None:
    """The schema's field at ``loc`` (None where the path leaves the schema)."""
    info = None
    for part in loc:
        if model is None or not isinstance(part, str) or part not in model.model_fields:
            if isinstance(part, (str, int)) and info is not None:  # dict / list item of a model
                continue
            return None
        info = model.model_fields[part]
        ann = info.annotation
        model = ann if isinstance(ann, type) and issubclass(ann, BaseModel) else None
        args = getattr(ann, "__args__", None) or ()
        if model is None and args:
            inner = [a for a in args if isinstance(a, type) and issubclass(a, BaseModel)]
            model = inner[0] if inner else None
    return info


def _field_range(info: FieldInfo | None) -> str:
    """'> 0 and <= 1.5708' from a field's constraints (or '')."""
    if info is None:
        return ""
    parts = []
    for m in info.metadata:
        for attr, sym in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
            v = getattr(m, attr, None)
            if v is not None:
                parts.append(f"{sym} {v:.6g}")
    return " and ".join(parts)


def _field_unit(info: FieldInfo | None) -> str:
    """The unit a field's value is in (its ``json_schema_extra["unit"]``: "m", "rad", "s", …; "" for none)."""
    extra = None if info is None else info.json_schema_extra
    unit = extra.get("unit") if isinstance(extra, dict) else None
    return unit if isinstance(unit, str) else ""


#: pydantic's error types of a number beyond a bound
_BOUND_ERRORS = frozenset(("greater_than", "greater_than_equal", "less_than", "less_than_equal"))


def format_validation_error(kind: str, source: str, err: ValidationError, schema: type[BaseModel] | None = None) -> str:
    """One line per problem: ``<field path> = <value>: <what is wrong> (allowed: <range>)``."""
    lines = [f"invalid {kind} {source}:"]
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "<root>"
        msg = e["msg"].removeprefix("Value error, ")
        if e["type"] == "extra_forbidden":
            msg = f"unknown key (not part of the {kind} schema)"
        elif e["type"] in ("model_type", "model_attributes_type", "dict_type"):  # said in TOML's words, not pydantic's
            msg = "must be a table (a [section] or { key = value, … })"
        elif e["type"] == "list_type":
            msg = "must be an array ([ … ])"
        elif e["type"] == "string_type":
            msg = "must be text (a quoted string)"
        value = e.get("input")
        if e["type"] in _BOUND_ERRORS and isinstance(value, float) and not math.isfinite(value):
            # a schema that lets NaN through names the bound it fails ("less than or equal to 3"): say what it is
            msg = "Input should be a finite number"
        info = _field_info(schema, tuple(e["loc"]))
        allowed, unit = _field_range(info), _field_unit(info)
        if allowed and unit:
            allowed += f" {unit}"
            if isinstance(value, (int, float)) and not isinstance(value, bool) and info is not None:
                allowed += unit_hint_within(float(value), info.metadata, unit)  # mm?, degrees?, t?
        if not allowed:
            ctx = e.get("ctx") or {}
            allowed = " and ".join(
                f"{op} {ctx[k]}" for k, op in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")) if k in ctx
            )
        if allowed:
            msg = f"{msg} (allowed: {allowed})"
        shown = "" if isinstance(value, dict) else f" = {value!r}"
        lines.append(f"  {loc}{shown}: {msg}")
    return "\n".join(lines)
