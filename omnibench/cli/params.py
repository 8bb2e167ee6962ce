"""Option types shared by the commands: refuse bad values at the command line, in one line.

click's FLOAT takes "nan" and "inf" and its Path takes "" (the current folder): neither is a
value any omnibench option means, so these types refuse them before a command starts.
"""

from __future__ import annotations

import math
from typing import Any

import click


class FiniteFloat(click.types.FloatParamType):
    """A float that is a number: not NaN, not infinite."""

    name = "number"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> float:
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        return v


class NonEmptyPath(click.Path):
    """click.Path that refuses the empty string (which would mean the current folder)."""

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        if isinstance(value, str) and not value.strip():
            self.fail("an empty path names no file", param, ctx)
        return super().convert(value, param, ctx)


FINITE = FiniteFloat()
