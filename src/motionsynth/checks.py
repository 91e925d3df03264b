"""Argument checks shared by the library's public functions: one wording for every clear error."""

from __future__ import annotations

import math
from collections.abc import Collection
from typing import Any


def positive_number(value: Any, name: str) -> float:
    """``float(value)`` when it is a finite number > 0, else ``ValueError`` naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}") from None
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive finite number, got {value!r}")
    return v


def one_of(value: Any, name: str, choices: Collection) -> Any:
    """``value`` when it is one of ``choices``, else ``ValueError`` listing them."""
    if value not in choices:
        raise ValueError(f"{name} must be one of {tuple(choices)}, got {value!r}")
    return value
