"""A numeric setting's valid range, declared beside its field.

``x: float = bounded(0.5, UNIT)`` is a dataclass field with default 0.5 whose range travels with it
(in the field's metadata), so renaming or moving the field keeps its check.
:func:`idsplat_ns.runs.settings_checks.validate_settings` reads it; a numeric field without one
must be finite and non-negative, as no count, size, rate, weight or threshold of this project is
meaningfully negative.

Layer: the lowest, beside ``errors``; it imports nothing of the project.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Any, Optional

RANGE_KEY = "idsplat_range"
"""The key of a field's metadata that holds its :class:`Range`."""


@dataclasses.dataclass(frozen=True)
class Range:
    """An interval check; ``None`` is an open end. ``integer`` requires a whole number."""

    low: Optional[float] = None
    high: Optional[float] = None
    low_open: bool = False
    high_open: bool = False
    integer: bool = False

    def ok(self, v: float) -> bool:
        if not math.isfinite(v) or (self.integer and v != int(v)):
            return False
        if self.low is not None and (v <= self.low if self.low_open else v < self.low):
            return False
        return not (self.high is not None and (v >= self.high if self.high_open else v > self.high))

    def text(self) -> str:
        lo = "-inf" if self.low is None else f"{self.low:g}"
        hi = "inf" if self.high is None else f"{self.high:g}"
        kind = "a whole number" if self.integer else "a number"
        return f"{kind} in {'(' if self.low_open or self.low is None else '['}{lo}, {hi}{')' if self.high_open or self.high is None else ']'}"


POSITIVE = Range(0, low_open=True)
NON_NEGATIVE = Range(0)
AT_LEAST_ONE = Range(1, integer=True)
UNIT = Range(0, 1)
FRACTION = Range(0, 1, low_open=True)
OPEN_UNIT = Range(0, 1, low_open=True, high_open=True)
ANY = Range()


def bounded(default: Any, check: Range) -> Any:
    """A dataclass field with ``default`` whose values (each element of a tuple) must pass ``check``."""
    return dataclasses.field(default=default, metadata={RANGE_KEY: check})


def field_range(f: dataclasses.Field) -> Optional[Range]:
    """The range declared beside field ``f``; None where it has none."""
    return f.metadata.get(RANGE_KEY)
