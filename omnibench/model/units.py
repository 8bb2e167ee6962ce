"""Read a value that may carry a unit ("15.75 kg", "45 deg") into SI, with a clear error.

A string is parsed by a small grammar first: one decimal number, then a unit made only of
unit names, `*`, `/`, spaces, parentheses and one-digit exponents (`m/s^2`, `kg*m**2`). Only
that unit is handed to pint, never the whole string, so an input such as "9**9**9 V" cannot
make pint compute (pint evaluates arithmetic in quantity strings); it is refused at once.
"""

from __future__ import annotations

import hashlib
import math
import re
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING

from omnibench.resources import cache_root

if TYPE_CHECKING:
    import pint

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d{1,3})?"
_NAME = r"[^\W\d](?:[^\W]|°)*|°|%|Ω|µ\w*"
_UNIT = rf"(?:{_NAME}|\()(?:{_NAME}|[*/() ]|\*\*-?\d|\^-?\d)*"
_POWER_OF_POWER = re.compile(r"(?:\*\*|\^)-?\d\s*\)*\s*(?:\*\*|\^)")  # m**9**9: pint would compute it
_QUANTITY = re.compile(rf"\s*({_NUMBER})\s*({_UNIT})?\s*")
MAX_LENGTH = 64  #: longer strings are refused before any parsing
#: (unit written, unit asked) -> factor, converted without pint: importing pint and loading its
#: registry is ~0.3 s of CPU in every command that reads a robot file, and the shipped one gives
#: its roller angles in degrees. The product is pint's own to the last bit (tests/model/test_units_cache.py
#: compares them over thousands of values).
EXACT = {("deg", "rad"): math.pi / 180.0}


@lru_cache(maxsize=1)
def registry() -> "pint.UnitRegistry":
    """pint's registry, its parsed definitions cached on disk by pint (0.05 s instead of
    0.3-1 s of CPU in every command that reads a robot file); uncached when that folder cannot
    be used.

    The cache is kept per pint installation (`pint_cache_folder`): pint's own default folder
    (~/.cache/pint) is shared by every environment, and its entries name the definition files of
    the environment that wrote them, so once that environment is deleted every other one fails
    to read the cache and silently pays the uncached parse."""
    import pint

    try:
        return pint.UnitRegistry(cache_folder=pint_cache_folder())
    except Exception:  # noqa: BLE001 - a read-only home or a pint without the cache
        return pint.UnitRegistry()


def pint_cache_folder() -> Path:
    """The disk cache of this pint installation's definitions: omnibench's cache folder /
    pint / a key of pint's version and location."""
    import pint

    home = Path(pint.__file__).resolve().parent
    key = hashlib.sha256(f"{pint.__version__}\0{home}".encode()).hexdigest()[:16]
    return cache_root() / "pint" / key


def parse_quantity(text: str) -> tuple[float, str | None]:
    """(number, unit text or None) of "12.5 V"; ValueError if it is not number + unit name."""
    m = _QUANTITY.fullmatch(text) if len(text) <= MAX_LENGTH else None
    if m is None or _POWER_OF_POWER.search(m.group(2) or ""):
        raise ValueError(f"cannot read {text[:MAX_LENGTH]!r} as a number with a unit (e.g. '12 V', '0.5 s')")
    number = float(m.group(1))
    if not math.isfinite(number):
        raise ValueError(f"{text!r} is not a finite number")
    unit = (m.group(2) or "").strip()
    return number, unit or None


def to_si(value: object, unit: str) -> float:
    """`value` (a number, already SI, or a string with a unit) as a finite float in `unit`.

    Raises ValueError with a short reason (wrong dimension, not a number, NaN or infinite).
    """
    if isinstance(value, bool):
        raise ValueError(f"expected a number in {unit}, got {value!r}")
    if isinstance(value, (int, float)):
        if not math.isfinite(float(value)):
            raise ValueError(f"expected a finite number in {unit}, got {value!r}")
        return float(value)
    if not isinstance(value, str):
        raise ValueError(f"expected a number in {unit}, got {value!r}")
    number, unit_text = parse_quantity(value)
    factor = EXACT.get((unit_text or "", unit))
    if factor is not None:
        out = number * factor
        if not math.isfinite(out):
            raise ValueError(f"{value!r} is out of range")
        return out
    import pint

    ureg = registry()
    target = ureg.Quantity(1.0, unit if unit != "1" else "dimensionless")
    if unit_text is None:
        return number  # a bare number is SI
    try:
        q = ureg.Quantity(number, ureg.parse_units(unit_text.replace("^", "**")))
    except Exception as exc:  # noqa: BLE001 - pint raises several types for unknown names
        raise ValueError(f"cannot read {value!r}: unknown unit {unit_text!r} ({type(exc).__name__})") from None
    try:
        out = float(q.to(target.units).magnitude)
    except pint.DimensionalityError:
        raise ValueError(f"{value!r} is not in units compatible with {unit}") from None
    if not math.isfinite(out):
        raise ValueError(f"{value!r} is out of range")
    return out
