"""Duty command files: CSV with columns t, u1, u2, u3, u4 (s, duty in [-1, 1]), held until the next row."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from omnibench.errors import UserError

COLUMNS = ("t", "u1", "u2", "u3", "u4")


@dataclass(frozen=True)
class DutyCommands:
    """Zero-order-hold duty schedule: times t (K,) in s and duties u (K, 4)."""

    t: np.ndarray
    u: np.ndarray

    @property
    def end(self) -> float:
        return float(self.t[-1])


def load_commands(path: str | Path, max_duty: float = 1.0) -> DutyCommands:
    """Read and validate a command CSV; UserError naming file and line on any problem."""
    p = Path(path)
    try:
        handle = p.open(newline="", encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{p}: command file not found") from None
    except OSError as exc:
        raise UserError(f"{p}: cannot read command file ({exc.__class__.__name__})") from None
    times: list[float] = []
    duties: list[list[float]] = []
    with handle:
        reader = csv.reader(handle)
        try:
            header = next(reader)
        except StopIteration:
            raise UserError(f"{p}: empty command file; expected a header t,u1,u2,u3,u4") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise UserError(f"{p}:1: not a CSV file ({exc.__class__.__name__})") from None
        names = [h.strip() for h in header]
        missing = [c for c in COLUMNS if c not in names]
        if missing:
            raise UserError(f"{p}:1: header must name t,u1,u2,u3,u4; missing {','.join(missing)}")
        cols = [names.index(c) for c in COLUMNS]
        try:
            for row in reader:
                line = reader.line_num
                if not row or all(not cell.strip() for cell in row):
                    continue
                try:
                    values = [float(row[k]) for k in cols]
                except (ValueError, IndexError):
                    raise UserError(f"{p}:{line}: expected 5 numbers t,u1,u2,u3,u4, got {','.join(row)!r}") from None
                if not all(math.isfinite(v) for v in values):
                    raise UserError(f"{p}:{line}: values must be finite numbers")
                t, u = values[0], values[1:]
                if t < 0 or (times and t < times[-1]):
                    raise UserError(f"{p}:{line}: time {t} s must be >= 0 and not before the previous row")
                bad = [f"u{j + 1}={v}" for j, v in enumerate(u) if abs(v) > max_duty]
                if bad:
                    raise UserError(f"{p}:{line}: duty out of range [-{max_duty}, {max_duty}]: {', '.join(bad)}")
                times.append(t)
                duties.append(u)
        except (csv.Error, UnicodeDecodeError) as exc:
            raise UserError(f"{p}:{reader.line_num}: not a CSV file ({exc.__class__.__name__})") from None
    if not times:
        raise UserError(f"{p}: no command rows after the header")
    return DutyCommands(np.array(times), np.array(duties))
