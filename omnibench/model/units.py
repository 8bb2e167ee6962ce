"""Read a value that may carry a unit ("15.75 kg", "45 deg") into SI, with a clear error."""

from __future__ import annotations

from functools import lru_cache

import pint


@lru_cache(maxsize=1)
def registry() -> pint.UnitRegistry:
    return pint.UnitRegistry()


def to_si(value: object, unit: str) -> float:
    """`value` (a number, already SI, or a string with a unit) as a float in `unit`.

    Raises ValueError with a short reason (wrong dimension, not a number).
    """
    if isinstance(value, bool):
        raise ValueError(f"expected a number in {unit}, got {value!r}")
    if isinstance(value, (int, float)):
        return float(value)
    if not isinstance(value, str):
        raise ValueError(f"expected a number in {unit}, got {value!r}")
    ureg = registry()
    try:
        q = ureg.Quantity(value)
    except Exception as exc:  # pint raises several types for garbage
        raise ValueError(f"cannot read {value!r} as a quantity ({type(exc).__name__})") from None
    target = ureg.Quantity(1.0, unit if unit != "1" else "dimensionless")
    try:
        return float(q.to(target.units).magnitude)
    except pint.DimensionalityError:
        raise ValueError(f"{value!r} is not in units compatible with {unit}") from None
