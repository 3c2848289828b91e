"""Checking nested settings dataclasses (world config, perception parameters) with messages that name the key."""
from __future__ import annotations

import math
from dataclasses import fields, is_dataclass
from typing import Any


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
