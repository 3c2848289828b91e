"""Nested settings dataclasses (world configs, perception parameters): built from plain values (YAML, keyword
arguments) and checked, with messages that name the key."""
from __future__ import annotations

import math
from dataclasses import fields, is_dataclass
from typing import Any, Mapping, TypeVar

Settings = TypeVar("Settings")


def check_numbers(settings: Any, prefix: str = "", negative_ok: tuple[str, ...] = (),
                  infinite_ok: tuple[str, ...] = ()) -> None:
    """Every number finite and non-negative (unless its field name is listed), and no text where a number goes;
    nested dataclasses are checked too, their keys reported as ``outer.inner``."""
    for f in fields(settings):
        value, name = getattr(settings, f.name), f"{prefix}{f.name}"
        if is_dataclass(value):
            check_numbers(value, f"{name}.", negative_ok, infinite_ok)
        elif isinstance(value, (str, list, dict)) and f.type in ("float", "int"):
            raise ValueError(f"{name} must be a number, got {value!r}")
        elif isinstance(value, (int, float)) and not isinstance(value, bool):
            if not math.isfinite(value) and f.name not in infinite_ok:
                raise ValueError(f"{name} must be finite, got {value}")
            if value < 0 and f.name not in negative_ok:
                raise ValueError(f"{name} must not be negative, got {value}")


def build_settings(cls: type[Settings], values: Mapping[str, Any], what: str, prefix: str = "") -> Settings:
    """``cls(**values)`` for a settings dataclass whose every field has a default, nested dataclasses built from
    nested mappings; each value checked against its default's type (``coerce_setting``). Unknown keys are refused
    by name (``what``: the settings' name in the message, e.g. 'soccer'); keys are reported as ``outer.inner``."""
    known = [f.name for f in fields(cls)]    # type: ignore[arg-type]
    unknown = sorted(set(values) - set(known))
    if unknown:
        raise ValueError(f"unknown {what} setting(s): {', '.join(prefix + u for u in unknown)}; "
                         f"known: {', '.join(prefix + k for k in known)}")
    kwargs: dict[str, Any] = {}
    defaults = cls()
    for name, value in values.items():
        default = getattr(defaults, name)
        if is_dataclass(default) and isinstance(value, Mapping):
            kwargs[name] = build_settings(type(default), dict(value), what, f"{prefix}{name}.")
        elif is_dataclass(default) and not is_dataclass(value):
            raise ValueError(f"{prefix}{name} must be a mapping of settings, got {value!r}")
        else:
            kwargs[name] = coerce_setting(f"{prefix}{name}", value, default)
    try:
        return cls(**kwargs)
    except TypeError as exc:  # a wrong type deep inside a nested dataclass
        raise ValueError(f"{prefix or what}: {exc}") from None


def coerce_setting(name: str, value: Any, default: Any) -> Any:
    """``value`` for a setting whose default is ``default``: a bool stays a bool, an int an int (no bool), a float
    takes an int (as a float), a string a string; ValueError naming ``name`` otherwise. Other types pass as given."""
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise ValueError(f"{name} must be true or false, got {value!r}")
        return value
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"{name} must be an integer, got {value!r}")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{name} must be a number, got {value!r}")
        return float(value)
    if isinstance(default, str) and not isinstance(value, str):
        raise ValueError(f"{name} must be a string, got {value!r}")
    return value
