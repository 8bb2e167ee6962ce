"""Import logs written as delimited text (CSV, semicolon- or tab-separated, ...) described by a
map file (TOML): which column holds what, in which unit, and what the map knows about how the
log was taken. docs/run-format.md ("Importing your own logs") describes the map.

Reading a log (`read_log`) decides everything before anything is written:

- the file's layout: separator, decimal mark, a header row of column names, a units row under
  it; each read off the file (or stated in the map and checked against the file);
- each quantity's columns and unit (stated in the map, or in the file's units row; both given
  and different is refused);
- the conditions of the log (`conditions` in run.json): where the robot was, the direction of
  a floor run driven by one drive value, the wheel sign map, when a logged duty acted
  (`duty_timing`), the firmware's command timing, the encoder resolution, the supply. Each is
  recorded with how it was decided: stated (in the map, with an option, in the file name),
  inferred from the data (with the statistic and its threshold), or unknown. Nothing takes a
  default without the run saying so; two statements that disagree, or a statement the data
  clearly contradict, are refused in one line.

`write_run` then writes one run directory with the run writer (omnibench.runs.store), the same
record the board's runs and `import tfm` produce: a trace replayed whole (`step_response` or
`random_duty`), one step per constant-duty segment.

Units: a closed table per quantity (UNITS). pint is a dependency of the project, but it counts
radians as dimensionless, so "counts", "%" or "ppm" would all pass as an angle; encoder counts
and PWM ranges are not pint units either. The table also names the accepted units in the error.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from omnibench.errors import UserError
from omnibench.files import read_toml
from omnibench.runs.store import RunWriter
from omnibench.runs.tfm import DIRECTIONS, SKETCHES, direction_of, file_digest

#: quantity -> (number of columns it may have, the unit table it reads)
QUANTITIES: dict[str, tuple[tuple[int, ...], str]] = {
    "time": ((1,), "time"),
    "duty": ((1, 4), "duty"),
    "encoder": ((4,), "angle"),
    "wheel_speed": ((4,), "speed"),
    "motor_speed": ((4,), "speed"),
    "motor_current": ((4,), "current"),
    "battery_current": ((1,), "current"),
    "battery_voltage": ((1,), "voltage"),
    "pose": ((3,), "pose"),
}

TWO_PI = 2.0 * math.pi
#: unit table -> accepted unit -> factor to SI (None: a unit that needs more than a factor)
UNITS: dict[str, dict[str, float | None]] = {
    "time": {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6},
    "angle": {"counts": None, "count": None, "rev": TWO_PI, "rad": 1.0, "deg": math.pi / 180},
    "speed": {"rad/s": 1.0, "rpm": TWO_PI / 60, "deg/s": math.pi / 180, "rev/s": TWO_PI},
    "current": {"A": 1.0, "mA": 1e-3},
    "voltage": {"V": 1.0, "mV": 1e-3},
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3},
    # a duty: a fraction, a percentage, a PWM value in the map's `range`, or a voltage set-point
    "duty": {"1": 1.0, "%": 1e-2, "pwm": None, "V": 1.0, "mV": 1e-3},
}
SI = {"time": "s", "angle": "rad", "speed": "rad/s", "current": "A", "voltage": "V", "length": "m", "duty": "1"}

#: what the map's [run] `procedure` may name: the trace kinds the analysis replays whole
PROCEDURES = {"step_response": "step_response", "random_duty": "duty_hold"}
WHERE = {"air": "upside_down", "floor": "ground"}
DUTY_TIMINGS = ("from_sample", "interval_before")
SEPARATORS = {",": "comma", ";": "semicolon", "\t": "tab", "|": "bar", " ": "spaces"}

#: words of a file name that state where the robot was
NAME_WORDS = {"floor": "floor", "ground": "floor", "air": "air", "inair": "air", "jacked": "air",
              "upside": "air", "blocks": "air"}

#: thresholds of the inferences (docs/run-format.md)
SIGN_AGREEMENT = 0.5  #: |agreement| of a wheel's travel with its duty needed to read its sign
TIMING_FROM_SAMPLE = 0.12  #: response share before a duty change's sample below this: from_sample
TIMING_INTERVAL_BEFORE = 0.3  #: above this: interval_before
TIMING_MIN_CHANGES = 3  #: isolated duty changes needed to judge the timing
KIN_DUTY_MIN = 0.3  #: the duties break the floor kinematics by at least this (else no evidence)
KIN_FLOOR = 0.2  #: wheels' share of that breach below this: on the floor; above KIN_AIR: in the air
KIN_AIR = 0.6
POSE_FLOOR = 0.5  #: pose excursion / wheel excursion above this: the robot moved (floor)
POSE_AIR = 0.1  #: below this (and the wheels turned > POSE_MIN_WHEEL_M): it did not (air)
POSE_MIN_WHEEL_M = 0.05
TIME_LIMIT_S = 1e8  #: times beyond this (a Unix time stamp) are shifted to start at 0


# ------------------------------------------------------------------------------ the map
@dataclass(frozen=True)
class Quantity:
    """One quantity of the map: its column references (names or 1-based positions), units
    (one per column, None where the map leaves it to the file), and options."""

    name: str
    columns: tuple[str | int, ...]
    units: tuple[str | None, ...]
    pwm_range: tuple[float, float] | None = None
    gear_ratio: float | None = None
    pattern: str | tuple[int, ...] | None = None  # duty from one column: "all", "direction" or 4 signs


@dataclass(frozen=True)
class CsvMap:
    """A map file, validated."""

    path: Path
    text: str
    name: str
    quantities: dict[str, Quantity]
    file: dict[str, Any]
    run: dict[str, Any]

    @property
    def sha256(self) -> str:
        return hashlib.sha256(self.text.encode("utf-8")).hexdigest()


def _bad(path: Path, where: str, why: str) -> UserError:
    return UserError(f"{path}: {where}: {why}")


FILE_KEYS = {"separator", "decimal", "header", "units_row", "skip_lines", "comment"}
RUN_KEYS = {"procedure", "where", "direction", "robot", "counts_per_rev", "signs", "supply_voltage",
            "duty_timing", "sketch", "firmware_timing"}
QUANTITY_KEYS = {"column", "columns", "unit", "units", "range", "gear_ratio", "pattern"}
TIMING_KEYS = {"sketch", "command_order", "command_offset_s", "packet_s", "loop_s"}


def load_map(path: Path | str) -> CsvMap:
    """Read and validate a map file; a one-line UserError naming the file and the key."""
    path = Path(path)
    data, text = read_toml(path, "map file")
    for key in data:
        if key not in ("map", "file", "run", "columns"):
            raise _bad(path, key, "is not a table of a map (map, file, run, columns)")
    meta = _table(path, data, "map")
    file = _table(path, data, "file")
    run = _table(path, data, "run")
    cols = _table(path, data, "columns")
    for key in file:
        if key not in FILE_KEYS:
            raise _bad(path, f"file.{key}", f"unknown key (known: {', '.join(sorted(FILE_KEYS))})")
    for key in run:
        if key not in RUN_KEYS:
            raise _bad(path, f"run.{key}", f"unknown key (known: {', '.join(sorted(RUN_KEYS))})")
    if "separator" in file and file["separator"] not in SEPARATORS:
        raise _bad(path, "file.separator", f"{file['separator']!r} is not one of "
                   f"{', '.join(repr(s) for s in SEPARATORS)}")
    if "decimal" in file and file["decimal"] not in (".", ","):
        raise _bad(path, "file.decimal", "give '.' or ','")
    for key in ("header", "units_row"):
        if key in file and not isinstance(file[key], bool):
            raise _bad(path, f"file.{key}", "give true or false")
    if "skip_lines" in file and (not isinstance(file["skip_lines"], int) or isinstance(file["skip_lines"], bool)
                                 or file["skip_lines"] < 0):
        raise _bad(path, "file.skip_lines", "give a whole number >= 0")
    if "comment" in file and (not isinstance(file["comment"], str) or len(file["comment"]) != 1):
        raise _bad(path, "file.comment", "give one character, e.g. '#'")
    _check_run_table(path, run, cols)
    quantities: dict[str, Quantity] = {}
    for name, spec in cols.items():
        quantities[name] = _quantity(path, name, spec)
    if "time" not in quantities:
        raise _bad(path, "columns.time", "is missing (every log needs its time stamps)")
    if "duty" not in quantities:
        raise _bad(path, "columns.duty", "is missing (the analysis replays the logged duties)")
    motion = [q for q in ("encoder", "wheel_speed", "motor_speed") if q in quantities]
    if len(motion) != 1:
        raise _bad(path, "columns", "name exactly one of encoder, wheel_speed, motor_speed (the wheels' motion)"
                   if not motion else f"name one of {', '.join(motion)}, not several")
    name = meta.get("name", path.stem)
    if not isinstance(name, str):
        raise _bad(path, "map.name", "give a text")
    return CsvMap(path=path, text=text, name=name, quantities=quantities, file=file, run=run)


def _table(path: Path, data: Mapping[str, Any], key: str) -> dict[str, Any]:
    value = data.get(key, {})
    if not isinstance(value, dict):
        raise _bad(path, key, "is not a table")
    return value


def _check_run_table(path: Path, run: Mapping[str, Any], cols: Mapping[str, Any] | None = None) -> None:
    if "procedure" in run and run["procedure"] not in PROCEDURES:
        raise _bad(path, "run.procedure", f"{run['procedure']!r} is not one of {', '.join(PROCEDURES)} "
                   "(a log of samples is replayed whole)")
    if "where" in run and run["where"] not in WHERE:
        raise _bad(path, "run.where", f"{run['where']!r} is not one of {', '.join(WHERE)}")
    if "direction" in run and run["direction"] not in DIRECTIONS:
        raise _bad(path, "run.direction", f"{run['direction']!r} is not one of {', '.join(DIRECTIONS)}")
    if "duty_timing" in run and run["duty_timing"] not in DUTY_TIMINGS:
        raise _bad(path, "run.duty_timing", f"{run['duty_timing']!r} is not one of {', '.join(DUTY_TIMINGS)}")
    if "robot" in run and not isinstance(run["robot"], str):
        raise _bad(path, "run.robot", "give the robot file's path (relative to the map)")
    if "counts_per_rev" in run:
        v = run["counts_per_rev"]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < 1e9:
            raise _bad(path, "run.counts_per_rev", "give a number of counts per wheel revolution > 0")
    if "signs" in run:
        v = run["signs"]
        if not isinstance(v, list) or len(v) != 4 or any(s not in (1, -1) or isinstance(s, bool) for s in v):
            raise _bad(path, "run.signs", "give four signs, FL FR RL RR, e.g. [1, -1, 1, -1]")
    if "supply_voltage" in run:
        _supply(path, run["supply_voltage"])
    duty = (cols or {}).get("duty")
    if "direction" in run and not (isinstance(duty, dict) and duty.get("pattern") == "direction"):
        raise _bad(path, "run.direction", "states the direction of a floor run driven by one value: only with "
                   "columns.duty pattern = \"direction\"")
    if "sketch" in run and "firmware_timing" in run:
        raise _bad(path, "run.sketch", "give either sketch or a firmware_timing table, not both")
    if "sketch" in run and run["sketch"] not in SKETCHES:
        raise _bad(path, "run.sketch", f"{run['sketch']!r} is not one of the 2019 sketches ({', '.join(SKETCHES)}); "
                   "describe another firmware in [run.firmware_timing]")
    ft = run.get("firmware_timing")
    if ft is not None:
        if not isinstance(ft, dict):
            raise _bad(path, "run.firmware_timing", "is not a table")
        for key in ft:
            if key not in TIMING_KEYS:
                raise _bad(path, f"run.firmware_timing.{key}", f"unknown key (known: {', '.join(sorted(TIMING_KEYS))})")
        order = ft.get("command_order")
        if order is not None and (not isinstance(order, list) or sorted(order) != [1, 2, 3, 4]):
            raise _bad(path, "run.firmware_timing.command_order", "give the wheels 1-4 in send order, e.g. [1, 2, 4, 3]")
        for key in ("command_offset_s", "packet_s", "loop_s"):
            v = ft.get(key)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
                                  or abs(v) > 10):
                raise _bad(path, f"run.firmware_timing.{key}", "give a number of seconds")


def _supply(path: Path, value: Any) -> float:
    from omnibench.model.units import to_si

    try:
        v = to_si(value, "V")
    except ValueError as exc:
        raise _bad(path, "run.supply_voltage", str(exc)) from None
    if not 0 < v < 1e4:
        raise _bad(path, "run.supply_voltage", f"{v:g} V is not a supply voltage")
    return v


def _quantity(path: Path, name: str, spec: Any) -> Quantity:
    where = f"columns.{name}"
    if name not in QUANTITIES:
        raise _bad(path, where, f"unknown quantity (known: {', '.join(QUANTITIES)})")
    if not isinstance(spec, dict):
        raise _bad(path, where, "is not a table (e.g. { column = \"t\", unit = \"ms\" })")
    for key in spec:
        if key not in QUANTITY_KEYS:
            raise _bad(path, f"{where}.{key}", f"unknown key (known: {', '.join(sorted(QUANTITY_KEYS))})")
    counts, table = QUANTITIES[name]
    if ("column" in spec) == ("columns" in spec):
        raise _bad(path, where, "give either column (one) or columns (a list)")
    refs = [spec["column"]] if "column" in spec else spec["columns"]
    if not isinstance(refs, list) or len(refs) not in counts:
        raise _bad(path, where, f"needs {' or '.join(map(str, counts))} column(s)")
    for r in refs:
        if isinstance(r, bool) or not ((isinstance(r, str) and r.strip()) or (isinstance(r, int) and r >= 1)):
            raise _bad(path, where, f"{r!r}: give a column name, or its position counting from 1")
    if "unit" in spec and "units" in spec:
        raise _bad(path, where, "give either unit (for every column) or units (one per column)")
    if "units" in spec:
        units = spec["units"]
        if not isinstance(units, list) or len(units) != len(refs) or not all(isinstance(u, str) for u in units):
            raise _bad(path, f"{where}.units", f"give {len(refs)} units, one per column")
    elif "unit" in spec:
        if not isinstance(spec["unit"], str):
            raise _bad(path, f"{where}.unit", "give a unit as text, e.g. \"ms\"")
        units = [spec["unit"]] * len(refs)
    else:
        units = [None] * len(refs)
    for k, u in enumerate(units):
        if u is not None:
            check_unit(name, k, u, lambda why: _bad(path, where, why))
    pwm = None
    if "range" in spec:
        rng = spec["range"]
        if (name != "duty" or not isinstance(rng, list) or len(rng) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in rng) or rng[0] >= rng[1]):
            raise _bad(path, f"{where}.range", "give the PWM values of duty -1 and +1, e.g. [-127, 127] "
                       "(duty only)")
        pwm = (float(rng[0]), float(rng[1]))
    if name == "duty" and "pwm" in units and pwm is None:
        raise _bad(path, where, "unit \"pwm\" needs range = [value at duty -1, value at duty +1]")
    gear = None
    if "gear_ratio" in spec:
        gear = spec["gear_ratio"]
        if name != "motor_speed" or isinstance(gear, bool) or not isinstance(gear, (int, float)) or not gear > 0:
            raise _bad(path, f"{where}.gear_ratio", "give the motor turns per wheel turn (motor_speed only)")
    if name == "motor_speed" and gear is None:
        raise _bad(path, where, "needs gear_ratio (motor turns per wheel turn)")
    pattern: str | tuple[int, ...] | None = None
    if "pattern" in spec:
        p = spec["pattern"]
        if name != "duty" or len(refs) != 1:
            raise _bad(path, f"{where}.pattern", "only a duty from one column has a pattern")
        if p in ("all", "direction"):
            pattern = p
        elif isinstance(p, list) and len(p) == 4 and all(v in (-1, 0, 1) and not isinstance(v, bool) for v in p):
            pattern = tuple(int(v) for v in p)
        else:
            raise _bad(path, f"{where}.pattern", "give \"all\" (every wheel the logged duty), \"direction\" (each "
                       "wheel its sign in a floor run's kinematics) or four of -1, 0, 1")
    elif name == "duty" and len(refs) == 1:
        pattern = "all"
    return Quantity(name=name, columns=tuple(refs), units=tuple(units), pwm_range=pwm, gear_ratio=gear,
                    pattern=pattern)


def check_unit(quantity: str, k: int, unit: str, fail: Any) -> None:
    """Raise fail(why) unless `unit` is accepted for column k of `quantity`."""
    table = unit_table(quantity, k)
    if unit not in UNITS[table]:
        raise fail(f"unknown unit {unit!r} for {quantity} (accepted: {', '.join(UNITS[table])})")


def unit_table(quantity: str, k: int) -> str:
    """The unit table of column k of a quantity (pose: x, y lengths, psi an angle)."""
    table = QUANTITIES[quantity][1]
    if table == "pose":
        return "length" if k < 2 else "angle"
    return table


# ------------------------------------------------------------------------------ the file
@dataclass
class Layout:
    """How the file is written, and how each part of that was decided."""

    separator: str
    decimal: str
    names: list[str] | None
    units: list[str] | None
    rows: list[tuple[int, list[str]]]  # (line number, cells) of the data rows
    decisions: dict[str, dict[str, Any]] = field(default_factory=dict)


def _is_number(cell: str, decimal: str) -> bool:
    c = cell.strip()
    if not c:
        return True  # an empty cell: not measured
    if decimal == ",":
        c = c.replace(",", ".")
    try:
        return math.isfinite(float(c))
    except ValueError:
        return False


def _split(line: str, sep: str) -> list[str]:
    return line.split() if sep == " " else [c.strip() for c in line.split(sep)]


def _rows(lines: Sequence[tuple[int, str]], sep: str, decimal: str) -> tuple[int, int] | tuple[int, str]:
    """(non-numeric leading rows, fields per row) when every row after at most two leading
    non-numeric rows splits into the same number (>= 2) of numbers; else (the line number of the
    first row that does not, "why")."""
    lead = 0
    width = None
    for n, line in lines:
        cells = _split(line, sep)
        numeric = all(_is_number(c, decimal) for c in cells) and any(c.strip() for c in cells)
        if width is None and not numeric:
            lead += 1
            if lead > 2:
                return n, "a third row of text before the numbers (skip_lines skips a preamble)"
            continue
        if not numeric:
            bad = next((c for c in cells if not _is_number(c, decimal)), "")
            return n, f"{bad[:20]!r} is not a number"
        if width is None:
            width = len(cells)
            if width < 2:
                return n, "one field per row"
        elif len(cells) != width:
            return n, f"{len(cells)} fields, the rows before {width}"
    return (lead, width) if width is not None else (lines[-1][0], "no row of numbers")


def _decimal_of(lines: Sequence[tuple[int, str]], sep: str) -> str:
    """',' when the separator is not a comma and the cells write numbers with a decimal comma."""
    if sep == ",":
        return "."
    pat = re.compile(r"^[+-]?\d+,\d+(?:[eE][+-]?\d+)?$")
    for _, line in lines:
        for c in _split(line, sep):
            if pat.match(c.strip()):
                return ","
    return "."


def read_layout(path: Path, fmap: CsvMap) -> Layout:
    """The file's rows and how it is written (separator, decimal mark, names row, units row),
    read off the file and checked against what the map states; one-line UserError otherwise."""
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise UserError(f"{path}: cannot read ({exc.strerror or type(exc).__name__})") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        raise UserError(f"{path}:{line}: not UTF-8 text") from None
    comment = fmap.file.get("comment", "#")
    skip = int(fmap.file.get("skip_lines", 0))
    lines = [(n, line.rstrip("\r\n")) for n, line in enumerate(text.splitlines(), start=1)
             if n > skip and line.strip() and not line.lstrip().startswith(comment)]
    if not lines:
        raise UserError(f"{path}: holds no rows (empty file)")
    stated_sep = fmap.file.get("separator")
    stated_dec = fmap.file.get("decimal")
    fits: dict[str, tuple[str, int, int]] = {}
    failed: dict[str, tuple[int, str]] = {}
    for sep in SEPARATORS:
        dec = stated_dec or _decimal_of(lines, sep)
        got = _rows(lines, sep, dec)
        if isinstance(got[1], int):
            fits[sep] = (dec, got[0], got[1])
        else:
            failed[sep] = (got[0], got[1])
    decisions: dict[str, dict[str, Any]] = {}
    if stated_sep is not None:
        if stated_sep not in fits:
            other = next(iter(fits), None)
            n, why = failed[stated_sep]
            hint = f"; the rows split on {SEPARATORS[other]} ({other!r})" if other else ""
            raise UserError(f"{path}:{n}: the map's separator {stated_sep!r} does not split the rows into numbers "
                            f"of one width ({why}){hint}")
        sep = stated_sep
        decisions["separator"] = {"value": sep, "source": "stated in the map"}
    else:
        if not fits:  # name the row where the separator that got furthest failed
            sep, (n, why) = max(failed.items(), key=lambda kv: kv[1][0])
            raise UserError(f"{path}:{n}: no separator splits every row into the same number of numbers (on "
                            f"{SEPARATORS[sep]}: {why})")
        sep = next(iter(fits))  # in SEPARATORS' order: comma, semicolon, tab, bar, spaces
        others = [SEPARATORS[s] for s in fits if s != sep]
        decisions["separator"] = {"value": sep, "source": f"read off the file: every row splits into {fits[sep][2]} "
                                  f"fields on {SEPARATORS[sep]}" + (f" (also on {', '.join(others)}; {SEPARATORS[sep]} "
                                                                    "taken first)" if others else "")}
    dec, lead, width = fits[sep]
    decisions["decimal"] = ({"value": dec, "source": "stated in the map"} if stated_dec else
                            {"value": dec, "source": "read off the file" + (": numbers written with a decimal comma"
                                                                           if dec == "," else "")})
    header = fmap.file.get("header")
    units_row = fmap.file.get("units_row")
    has_names = lead >= 1 if header is None else header
    has_units = lead - int(has_names) >= 1
    if header is not None and lead < int(header):
        raise UserError(f"{path}:{lines[0][0]}: the map says the file has a names row, but its first row is numbers")
    if header is False and lead:
        raise UserError(f"{path}:{lines[0][0]}: the map says the file has no names row, but its first row is not "
                        "numbers")
    if units_row is not None and units_row != has_units:
        raise UserError(f"{path}: the map says the file {'has' if units_row else 'has no'} units row, but "
                        f"{'no' if units_row else 'a'} row of text follows the names row")
    names = _split(lines[0][1], sep) if has_names else None
    units = _split(lines[1][1], sep) if has_units else None
    for row, what in ((names, "names"), (units, "units")):
        if row is not None and len(row) != width:
            n = lines[0][0] if what == "names" else lines[1][0]
            raise UserError(f"{path}:{n}: the {what} row has {len(row)} fields, the data rows {width}")
    src = "stated in the map" if header is not None else "read off the file"
    decisions["header"] = {"value": bool(has_names), "source": src}
    decisions["units_row"] = {"value": bool(has_units),
                              "source": "stated in the map" if units_row is not None else "read off the file"}
    rows = [(n, _split(line, sep)) for n, line in lines[lead:]]
    if not rows:
        raise UserError(f"{path}: holds no data rows")
    return Layout(separator=sep, decimal=dec, names=names, units=units, rows=rows, decisions=decisions)


def _unit_of_cell(cell: str) -> str | None:
    """A units-row cell as a unit: brackets stripped; None when it states none."""
    u = cell.strip().strip("[](){}").strip()
    return u or None if u not in ("-", "") else None


# ------------------------------------------------------------------------------ reading
@dataclass
class Options:
    """What the user stated on the command line."""

    where: str | None = None
    procedure: str | None = None
    robot_file: Path | None = None


@dataclass
class Log:
    """One log read and decided, ready to be written (`write_run`)."""

    file: Path
    fmap: CsvMap
    procedure: str
    t: np.ndarray  # s
    u: np.ndarray  # (N, 4) duties
    drive: np.ndarray  # (N,) the logged duty value (one column) or the largest-magnitude duty
    command: np.ndarray | None  # the logged PWM value, when the duty was one
    phi: np.ndarray  # (N, 4) rad, signs applied
    enc: np.ndarray | None  # (N, 4) counts, signs applied
    currents: np.ndarray | None
    v_batt: np.ndarray | None
    i_batt: np.ndarray | None
    pose: np.ndarray | None
    counts_per_rev: float
    mode: str | None
    direction: str | None
    pattern: tuple[int, ...] | None
    signs: tuple[int, ...]
    supply: float | None
    duty_timing: str | None
    firmware_timing: dict[str, Any]
    conditions: dict[str, dict[str, Any]]
    layout: dict[str, Any]
    robot: Any = None
    robot_text: str | None = None
    robot_path: Path | None = None


def _column_index(path: Path, layout: Layout, q: Quantity, ref: str | int) -> int:
    width = len(layout.rows[0][1])
    if isinstance(ref, int):
        if ref > width:
            raise UserError(f"{path}: columns.{q.name}: column {ref} does not exist (the rows have {width} fields)")
        return ref - 1
    if layout.names is None:
        raise UserError(f"{path}: columns.{q.name}: column {ref!r} is named, but the file has no names row; give "
                        "its position (1 = first)")
    if layout.names.count(ref) > 1:
        raise UserError(f"{path}: column {ref!r} is named twice in the names row")
    if ref not in layout.names:
        shown = ", ".join(repr(n) for n in layout.names[:12])
        raise UserError(f"{path}: columns.{q.name}: no column {ref!r} (the file's columns: {shown})")
    return layout.names.index(ref)


def _values(path: Path, layout: Layout, idx: int, name: str, required: bool) -> np.ndarray:
    out = np.empty(len(layout.rows))
    for k, (n, cells) in enumerate(layout.rows):
        c = cells[idx].strip()
        if not c:
            if required:
                raise UserError(f"{path}:{n}: {name}: holds no number")
            out[k] = np.nan
            continue
        out[k] = float(c.replace(",", ".") if layout.decimal == "," else c)
    return out


def _read_quantity(path: Path, layout: Layout, q: Quantity, units_used: dict[str, Any],
                   required: bool) -> tuple[np.ndarray, list[str]]:
    """The quantity's columns (N, k) as logged and the unit of each (map or units row)."""
    cols, units = [], []
    for k, ref in enumerate(q.columns):
        idx = _column_index(path, layout, q, ref)
        label = layout.names[idx] if layout.names else f"column {idx + 1}"
        stated = q.units[k]
        in_file = _unit_of_cell(layout.units[idx]) if layout.units else None
        if in_file is not None:
            check_unit(q.name, k, in_file, lambda why: UserError(f"{path}: units row, column {label!r}: {why}"))
        if stated is not None and in_file is not None and not _same_unit(unit_table(q.name, k), stated, in_file):
            raise UserError(f"{path}: column {label!r} is in {in_file!r} by the file's units row, in {stated!r} by "
                            f"the map: the two disagree")
        unit = stated or in_file
        if unit is None:
            raise UserError(f"{path}: column {label!r} ({q.name}) has no unit: state it in the map "
                            f"(unit = ...) or in a units row")
        units.append(unit)
        units_used.setdefault(q.name, []).append(
            {"column": label, "unit": unit,
             "source": "stated in the map" + (" and in the file's units row" if in_file else "") if stated
             else "stated in the file's units row"})
        cols.append(_values(path, layout, idx, label, required))
    return np.column_stack(cols), units


def _same_unit(table: str, a: str, b: str) -> bool:
    if a == b:
        return True
    fa, fb = UNITS[table].get(a), UNITS[table].get(b)
    return fa is not None and fb is not None and math.isclose(fa, fb)


def _name_where(path: Path) -> tuple[str, str] | None:
    """(air|floor, the word) a file name states, None when it states neither (or both)."""
    words = {w for w in re.split(r"[^a-z]+", path.stem.lower()) if w}
    said = {NAME_WORDS[w]: w for w in words if w in NAME_WORDS}
    return next(iter(said.items())) if len(said) == 1 else None


def read_log(file: Path | str, fmap: CsvMap, options: Options | None = None) -> Log:
    """Read one log with its map, decide every condition (stated, inferred, unknown) and check
    the statements against each other and against the data; one-line UserError on bad input."""
    from omnibench.model import default_robot, load_robot

    file = Path(file)
    opts = options or Options()
    if not file.is_file():
        raise UserError(f"{file}: {'is a folder, not a log file' if file.is_dir() else 'no such file'}")
    layout = read_layout(file, fmap)
    conditions: dict[str, dict[str, Any]] = {}
    units_used: dict[str, Any] = {}
    run = fmap.run

    # the procedure kind and the robot: the map's, or the user's option; both and different: refused
    proc_map, proc_opt = run.get("procedure"), opts.procedure
    if proc_opt is not None and proc_opt not in PROCEDURES:
        raise UserError(f"--procedure {proc_opt}: give one of {', '.join(PROCEDURES)}")
    if proc_map and proc_opt and proc_map != proc_opt:
        raise UserError(f"{file}: the map says procedure {proc_map}, --procedure says {proc_opt}")
    procedure = proc_opt or proc_map
    if procedure is None:
        raise UserError(f"{file}: no procedure kind: state it in the map ([run] procedure) or give --procedure "
                        f"({', '.join(PROCEDURES)})")
    conditions["procedure"] = {"value": procedure, "source": "given with --procedure" if proc_opt else
                               "stated in the map"}
    robot_map = (fmap.path.parent / run["robot"]) if "robot" in run else None
    if robot_map is not None and opts.robot_file is not None and (
            file_digest_or_none(robot_map) != file_digest_or_none(opts.robot_file)):
        raise UserError(f"{file}: the map names the robot file {robot_map}, --robot gives {opts.robot_file} "
                        "(another file)")
    robot_path = opts.robot_file or robot_map
    robot = load_robot(robot_path) if robot_path is not None else default_robot()
    robot_text = robot_path.read_text(encoding="utf-8") if robot_path is not None else None
    conditions["robot"] = {"value": robot.name, "file": str(robot_path) if robot_path else None,
                           "source": ("given with --robot" if opts.robot_file else "stated in the map") if robot_path
                           else "not stated: the shipped Omnibot robot file"}

    q = fmap.quantities
    t_raw, (t_unit,) = _read_quantity(file, layout, q["time"], units_used, True)
    t = t_raw[:, 0] * float(UNITS["time"][t_unit] or 1.0)
    if t.size < 3:
        raise UserError(f"{file}: {t.size} data rows: too few to replay")
    bad = np.flatnonzero(np.diff(t) <= 0)
    if bad.size:
        n = layout.rows[int(bad[0]) + 1][0]
        raise UserError(f"{file}:{n}: time {t[bad[0] + 1]:g} s is not after the row before ({t[bad[0]]:g} s): the "
                        "time stamps must increase")
    shift = 0.0
    if abs(t[0]) > TIME_LIMIT_S or abs(t[-1]) > TIME_LIMIT_S:
        shift = -float(t[0])
        t = t + shift

    # supply: stated, or read off a logged battery voltage, or unknown
    v_batt = i_batt = currents = pose = None
    if "battery_voltage" in q:
        vb, (vu,) = _read_quantity(file, layout, q["battery_voltage"], units_used, False)
        v_batt = vb[:, 0] * float(UNITS["voltage"][vu] or 1.0)
    if "battery_current" in q:
        ib, (iu,) = _read_quantity(file, layout, q["battery_current"], units_used, False)
        i_batt = ib[:, 0] * float(UNITS["current"][iu] or 1.0)
    if "motor_current" in q:
        mc, mu = _read_quantity(file, layout, q["motor_current"], units_used, False)
        currents = mc * np.array([float(UNITS["current"][u] or 1.0) for u in mu])
    if "pose" in q:
        ps, pu = _read_quantity(file, layout, q["pose"], units_used, False)
        pose = ps * np.array([float(UNITS[unit_table("pose", k)][u] or 1.0) for k, u in enumerate(pu)])
    supply = None
    if "supply_voltage" in run:
        supply = _supply(fmap.path, run["supply_voltage"])
        conditions["supply_voltage"] = {"value": supply, "source": "stated in the map"}
    elif v_batt is not None and np.isfinite(v_batt).any():
        supply = float(np.nanmedian(v_batt))
        conditions["supply_voltage"] = {"value": supply, "source": "read off the data: median of the logged battery "
                                        "voltage"}
    else:
        conditions["supply_voltage"] = {"value": "unknown", "source": "neither stated nor logged: the analysis "
                                        f"uses the robot file's V_batt, {robot.V_batt:g} V"}

    # duties
    dq = q["duty"]
    d_raw, d_units = _read_quantity(file, layout, dq, units_used, True)
    command = None
    if d_units[0] == "pwm":
        lo, hi = dq.pwm_range or (-1.0, 1.0)
        command = d_raw[:, 0].copy() if d_raw.shape[1] == 1 else None
        duty = (2.0 * (d_raw - lo) / (hi - lo) - 1.0)
    elif d_units[0] in ("V", "mV"):
        scale = float(UNITS["duty"][d_units[0]] or 1.0)
        if supply is None:
            raise UserError(f"{file}: duties given as voltage set-points need the supply: state supply_voltage in "
                            "the map or map the battery_voltage column")
        duty = d_raw * scale / supply  # a voltage set-point as a fraction of the supply
    else:
        duty = d_raw * float(UNITS["duty"][d_units[0]] or 1.0)
    if len(set(d_units)) > 1:
        raise UserError(f"{file}: the duty columns are in different units ({', '.join(d_units)})")
    duty = np.where(np.abs(duty) < 1e-12, 0.0, duty)
    worst = int(np.nanargmax(np.abs(duty).max(axis=1)))
    if not np.all(np.abs(duty) <= 1.0 + 1e-9):
        raise UserError(f"{file}:{layout.rows[worst][0]}: duty {duty[worst][np.argmax(np.abs(duty[worst]))]:.4g} is "
                        "outside [-1, 1]: check the duty's unit (or its PWM range) in the map")
    duty = np.clip(duty, -1.0, 1.0)

    # wheel motion as logged (before the sign map), rad
    enc_counts = None
    if "encoder" in q:
        e_raw, e_units = _read_quantity(file, layout, q["encoder"], units_used, True)
        if len(set(e_units)) > 1:
            raise UserError(f"{file}: the encoder columns are in different units ({', '.join(e_units)})")
        cpr, cpr_src = _counts_per_rev(fmap, robot, robot_path, opts, counted=e_units[0] in ("counts", "count"))
        if e_units[0] in ("counts", "count"):
            enc_counts = e_raw
            phi_raw = e_raw * (TWO_PI / cpr)
        else:
            phi_raw = e_raw * float(UNITS["angle"][e_units[0]] or 1.0)
    else:
        name = "wheel_speed" if "wheel_speed" in q else "motor_speed"
        s_raw, s_units = _read_quantity(file, layout, q[name], units_used, True)
        w = s_raw * np.array([float(UNITS["speed"][u] or 1.0) for u in s_units])
        if name == "motor_speed":
            w = w / float(q[name].gear_ratio or 1.0)
        # the angle since the first sample: trapezoids of the logged speeds
        phi_raw = np.vstack([np.zeros((1, 4)), np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(t)[:, None], axis=0)])
        cpr, cpr_src = _counts_per_rev(fmap, robot, robot_path, opts, counted=False)
    conditions["counts_per_rev"] = {"value": cpr, "source": cpr_src}

    # where the robot was: every statement, then the data
    statements: list[tuple[str, str]] = []
    if opts.where is not None:
        if opts.where not in WHERE:
            raise UserError(f"--where {opts.where}: give one of {', '.join(WHERE)}")
        statements.append((opts.where, "given with --where"))
    if "where" in run:
        statements.append((run["where"], "stated in the map"))
    named = _name_where(file)
    if named is not None:
        statements.append((named[0], f"stated in the file name (the word {named[1]!r})"))
    for (a, sa), (b, sb) in zip(statements, statements[1:]):
        if a != b:
            raise UserError(f"{file}: where the robot was: {_where_words(a)} ({sa}) but {_where_words(b)} ({sb}); "
                            "the statements must agree")

    # each wheel's duty (a floor run driven by one value: by its direction, once the signs are known)
    pattern_spec = dq.pattern
    direction = None
    pattern: tuple[int, ...] | None = None
    drive = duty[:, 0] if duty.shape[1] == 1 else duty[np.arange(len(duty)), np.argmax(np.abs(duty), axis=1)]
    u: np.ndarray | None = None
    if duty.shape[1] == 4:
        u = duty
    elif pattern_spec != "direction":
        pattern = (1, 1, 1, 1) if pattern_spec in (None, "all") else tuple(pattern_spec)  # type: ignore[arg-type]
        u = np.outer(drive, np.asarray(pattern, dtype=float))

    # signs: stated (and checked against the data) or read off the data
    signs, signs_cond = _signs(file, run, u, phi_raw)
    conditions["signs"] = signs_cond
    phi = phi_raw * np.asarray(signs, dtype=float)
    enc = None if enc_counts is None else np.round(enc_counts).astype(np.int64) * np.asarray(signs, dtype=np.int64)
    if u is None:
        direction, dir_cond = _direction(file, run, drive, phi)
        conditions["direction"] = dir_cond
        pattern = DIRECTIONS[direction]
        u = np.outer(drive, np.asarray(pattern, dtype=float))
    where_data = _where_from_data(robot, u, phi, pose)
    stated = statements[0] if statements else None
    if direction is not None:
        if stated is not None and stated[0] == "air":
            raise UserError(f"{file}: where the robot was: in the air ({stated[1]}) but the map's duty pattern is "
                            "a floor run's direction")
        if stated is None:
            stated = ("floor", "implied by the map (a duty pattern by the floor run's direction)")
    if stated is not None and where_data is not None and where_data[0] != stated[0]:
        raise UserError(f"{file}: where the robot was: {_where_words(stated[0])} ({stated[1]}) but the data say "
                        f"{_where_words(where_data[0])} ({where_data[1]})")
    if stated is not None:
        where = stated[0]
        conditions["where"] = {"value": where, "source": stated[1],
                               **({"evidence": f"the data agree: {where_data[1]}"} if where_data else {})}
    elif where_data is not None:
        where = where_data[0]
        conditions["where"] = {"value": where, "source": f"inferred from the data: {where_data[1]}"}
    else:
        where = None
        conditions["where"] = {"value": "unknown", "source": "not stated, and the data show neither (no pose "
                               "columns; the duties fit the floor kinematics, so the wheels' kinematics cannot tell)"}
    mode = WHERE[where] if where else None

    # when a logged duty acted
    timing_data = _duty_timing_from_data(t, u, phi)
    stated_timing = run.get("duty_timing")
    if stated_timing and timing_data and timing_data[0] != stated_timing:
        raise UserError(f"{file}: the map says duty_timing {stated_timing}, but the data say {timing_data[0]} "
                        f"({timing_data[1]})")
    if stated_timing:
        duty_timing: str | None = stated_timing
        conditions["duty_timing"] = {"value": stated_timing, "source": "stated in the map",
                                     **({"evidence": f"the data agree: {timing_data[1]}"} if timing_data else {})}
    elif timing_data:
        duty_timing = timing_data[0]
        conditions["duty_timing"] = {"value": duty_timing, "source": f"inferred from the data: {timing_data[1]}"}
    else:
        duty_timing = None
        why = _timing_statistic(t, u, phi)[1]
        conditions["duty_timing"] = {"value": "unknown", "source": f"not stated, and the data cannot tell ({why}); the "
                                     "analysis replays an "
                                     "imported run's duties from their sample on (from_sample)"}

    firmware = _firmware(run, t)
    conditions["firmware_timing"] = {"value": firmware.get("sketch"), "source": firmware["source"]}

    layout_rec: dict[str, Any] = {**layout.decisions, "columns": units_used}
    if shift:
        layout_rec["time_shift_s"] = {"value": shift, "source": "the file's times exceed the run format's "
                                      f"±{TIME_LIMIT_S:g} s: shifted to start at 0"}
    return Log(file=file, fmap=fmap, procedure=procedure, t=t, u=u, drive=drive, command=command, phi=phi, enc=enc,
               currents=currents, v_batt=v_batt, i_batt=i_batt, pose=pose, counts_per_rev=cpr, mode=mode,
               direction=direction, pattern=pattern, signs=tuple(signs), supply=supply, duty_timing=duty_timing,
               firmware_timing=firmware, conditions=conditions, layout=layout_rec, robot=robot if robot_path else None,
               robot_text=robot_text, robot_path=robot_path)


def file_digest_or_none(path: Path) -> str | None:
    try:
        return file_digest(path)
    except OSError:
        return None


def _where_words(where: str) -> str:
    return "in the air" if where == "air" else "on the floor"


def _counts_per_rev(fmap: CsvMap, robot: Any, robot_path: Path | None, opts: Options,
                    counted: bool) -> tuple[float, str]:
    if "counts_per_rev" in fmap.run:
        return float(fmap.run["counts_per_rev"]), "stated in the map"
    if robot_path is not None:
        return float(robot.counts_per_rev), f"stated in the robot file {robot_path}"
    if counted:
        raise UserError(f"{fmap.path}: the encoders are logged in counts, but neither the map (run.counts_per_rev) "
                        "nor a robot file (--robot, run.robot) states the counts per wheel revolution")
    return float(robot.counts_per_rev), ("not stated (the encoders are not logged in counts): the shipped robot "
                                         "file's, used only for the quantisation noise")


def _signs(file: Path, run: Mapping[str, Any], duty: np.ndarray | None,
           phi: np.ndarray) -> tuple[list[int], dict[str, Any]]:
    """The sign map: stated in the map (and not contradicted by the data) or read off the data
    (each wheel's travel against its own duty; `duty` None: the duties depend on a floor
    direction not known yet, so the signs cannot be read)."""
    stated = run.get("signs")
    agree = _agreement(duty, phi) if duty is not None else None
    if stated is not None:
        if agree is not None:
            for j in range(4):
                a = stated[j] * agree[j]
                if np.isfinite(a) and a < -SIGN_AGREEMENT:
                    raise UserError(f"{file}: the map's sign {stated[j]:+d} for wheel {j + 1} turns it against its duty "
                                    f"(agreement {a:+.2f}): the data say {-stated[j]:+d}")
        cond: dict[str, Any] = {"value": list(stated), "source": "stated in the map"}
        if agree is not None:
            cond["evidence"] = _agreement_text(agree * np.asarray(stated))
        return list(stated), cond
    if agree is None:
        raise UserError(f"{file}: the wheel signs cannot be read off a floor log driven by one value in an unknown "
                        "direction: state signs in the map ([run] signs)")
    for j in range(4):
        if not np.isfinite(agree[j]) or abs(agree[j]) < SIGN_AGREEMENT:
            raise UserError(f"{file}: wheel {j + 1}'s sign cannot be read off the data (its travel agrees with its "
                            f"duty by {agree[j]:+.2f}, |agreement| >= {SIGN_AGREEMENT} needed): state signs in the map")
    signs = [int(np.sign(a)) for a in agree]
    return signs, {"value": signs, "source": f"inferred from the data: {_agreement_text(agree)}"}


def _agreement(duty: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """Per wheel: sum(u dphi) / sum(|u dphi|) over the sample intervals (u at the interval's
    start); NaN for a wheel that never turned under a duty."""
    du = duty[:-1]
    dphi = np.diff(phi, axis=0)
    num = np.sum(du * dphi, axis=0)
    den = np.sum(np.abs(du * dphi), axis=0)
    out = np.full(4, np.nan)
    np.divide(num, den, out=out, where=den > 0)
    return out


def _agreement_text(agree: np.ndarray) -> str:
    vals = ", ".join(f"{a:+.2f}" for a in agree)
    return (f"each wheel's travel against its duty, sum(u dphi)/sum(|u dphi|) = {vals} (FL, FR, RL, RR; "
            f"|value| >= {SIGN_AGREEMENT} reads a sign)")


def _direction(file: Path, run: Mapping[str, Any], drive: np.ndarray, phi: np.ndarray) -> tuple[str, dict[str, Any]]:
    """A floor run's direction (one drive value, each wheel its kinematic sign): the map's,
    checked against the wheels, or read off them (runs.tfm.direction_of)."""
    try:
        seen: str | None = direction_of(drive, phi.T)
        why = None
    except UserError as exc:
        seen, why = None, str(exc)
    stated = run.get("direction")
    if stated is not None:
        if seen is not None and seen != stated:
            raise UserError(f"{file}: the map says direction {stated}, but the wheels travel as in a {seen} run "
                            f"(signs {DIRECTIONS[seen]} against the drive value)")
        return stated, {"value": stated, "source": "stated in the map"}
    if seen is None:
        raise UserError(f"{file}: {why}")
    return seen, {"value": seen, "source": f"inferred from the data: the wheels travel with signs {DIRECTIONS[seen]} "
                  "against the drive value"}


def _floor_null(robot: Any) -> np.ndarray:
    """The unit wheel-speed direction no motion on the floor can give: the left null vector of
    the kinematics R (design.md), e.g. (1, 1, -1, -1)/2 for the Omnibot."""
    from omnibench.model.geometry import inverse_kinematics

    R = inverse_kinematics(robot.L, robot.l, robot.r, robot.alpha)
    n = np.linalg.svd(R.T)[2][-1]
    return n / np.linalg.norm(n)


def _where_from_data(robot: Any, u: np.ndarray, phi: np.ndarray,
                     pose: np.ndarray | None) -> tuple[str, str] | None:
    """(air|floor, the statistic) when the data show where the robot was, else None.

    A logged pose: the robot's excursion against the wheels' rolled distance. Otherwise, the
    floor kinematics: on the floor the wheels can only turn as R v (design.md), so duties that
    break that constraint leave the wheels on it there but not in the air."""
    if pose is not None and np.isfinite(pose).all(axis=1).sum() >= 3:
        ok = np.isfinite(pose).all(axis=1)
        p = pose[ok]
        half = robot.L + robot.l
        moved = float(np.max(np.hypot(p[:, 0] - p[0, 0], p[:, 1] - p[0, 1]) + half * np.abs(p[:, 2] - p[0, 2])))
        rolled = float(robot.r * np.max(np.abs(phi - phi[0])))
        if rolled >= POSE_MIN_WHEEL_M:
            ratio = moved / rolled
            text = (f"the logged pose moved {moved:.3f} m (x, y and (L+l) psi) while the wheels rolled up to "
                    f"{rolled:.3f} m, ratio {ratio:.2f} (floor above {POSE_FLOOR}, air below {POSE_AIR})")
            if ratio > POSE_FLOOR:
                return "floor", text
            if ratio < POSE_AIR:
                return "air", text
        return None
    n = _floor_null(robot)
    # the duties and the wheels' travel of each constant-duty segment
    edges = np.flatnonzero(np.any(np.diff(u, axis=0) != 0, axis=1)) + 1
    starts, ends = np.concatenate([[0], edges]), np.concatenate([edges, [len(u)]]) - 1
    keep = ends - starts >= 2
    if keep.sum() < 1:
        return None
    U = u[starts[keep]]
    D = phi[ends[keep]] - phi[starts[keep]]
    su = float(np.linalg.norm(U @ n)) / max(float(np.linalg.norm(U)), 1e-12)
    if su < KIN_DUTY_MIN:
        return None
    sw = float(np.linalg.norm(D @ n)) / max(float(np.linalg.norm(D)), 1e-12)
    share = sw / su
    text = (f"the duties break the floor kinematics by {su:.2f} (the share of their norm along {np.round(n, 2).tolist()}, "
            f"which no floor motion turns), the wheels' travel by {sw:.2f}: ratio {share:.2f} (floor below {KIN_FLOOR}, "
            f"air above {KIN_AIR})")
    if share < KIN_FLOOR:
        return "floor", text
    if share > KIN_AIR:
        return "air", text
    return None


def _timing_statistic(t: np.ndarray, u: np.ndarray, phi: np.ndarray) -> tuple[float | None, str]:
    """(share, description): of the wheels' speed change at isolated duty changes, the share
    already in the interval that ends at the change's sample. A duty that acts from its sample
    on (from_sample) changes nothing before it; one reported for the interval before it
    (interval_before) does."""
    w = np.diff(phi, axis=0) / np.diff(t)[:, None]  # w[k]: speed over (t_k, t_k+1)
    change = np.flatnonzero(np.any(np.diff(u, axis=0) != 0, axis=1)) + 1  # u[k] != u[k-1]
    before = after = 0.0
    n = 0
    for k in change:
        if k < 2 or k + 1 >= len(u) or np.any(u[k - 2] != u[k - 1]) or np.any(u[k + 1] != u[k]):
            continue
        s = np.sign(u[k] - u[k - 1])
        before += float(s @ (w[k - 1] - w[k - 2]))  # over the interval ending at the change's sample
        after += float(s @ (w[k] - w[k - 1]))
        n += 1
    if n < TIMING_MIN_CHANGES:
        return None, f"{n} isolated duty changes ({TIMING_MIN_CHANGES} needed to read the duty timing off the data)"
    total = before + after
    if total <= 0:
        return None, f"the wheels do not follow the {n} isolated duty changes"
    share = before / total
    return share, (f"at {n} isolated duty changes, {share:.2f} of the wheels' speed change falls in the sample "
                   f"interval that ends at the change (from_sample below {TIMING_FROM_SAMPLE}, interval_before "
                   f"above {TIMING_INTERVAL_BEFORE})")


def _duty_timing_from_data(t: np.ndarray, u: np.ndarray, phi: np.ndarray) -> tuple[str, str] | None:
    share, text = _timing_statistic(t, u, phi)
    if share is None:
        return None
    if share < TIMING_FROM_SAMPLE:
        return "from_sample", text
    if share > TIMING_INTERVAL_BEFORE:
        return "interval_before", text
    return None


def _firmware(run: Mapping[str, Any], t: np.ndarray) -> dict[str, Any]:
    """The firmware's command timing: a 2019 sketch or a table the map states, else unknown
    (replayed with every wheel's command at its time stamp)."""
    loop = float(np.median(np.diff(t)))
    if "sketch" in run:
        return {**SKETCHES[run["sketch"]], "source": "stated in the map", "loop_median_s": loop}
    ft = run.get("firmware_timing")
    if isinstance(ft, Mapping):
        out: dict[str, Any] = {"sketch": str(ft.get("sketch", "stated in the map")), "source": "stated in the map",
                               "loop_median_s": loop}
        for key in ("command_order", "command_offset_s", "packet_s"):
            if key in ft:
                out[key] = ft[key]
        if "loop_s" in ft:
            out["loop_s"] = ft["loop_s"]
        return out
    return {"sketch": "unknown", "loop_median_s": loop,
            "source": "not stated in the map: replayed with every wheel's command acting at "
                      "its time stamp, no send order"}


# ------------------------------------------------------------------------------ writing
def write_run(log: Log, out: Path | str, *, run_dir: Path | None = None) -> Path:
    """Write the log as one run directory under `out` (the run writer); returns its path."""
    kind = PROCEDURES[log.procedure]
    u, t = log.u, log.t
    edges = np.flatnonzero(np.any(np.diff(u, axis=0) != 0, axis=1)) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [len(u)]])
    digest = file_digest(log.file)
    extra: dict[str, Any] = {
        "imported": True,
        "source": f"CSV log read with the map {log.fmap.path.name} ({log.fmap.name})",
        "source_file": str(log.file),
        "source_sha256": digest,
        "source_kind": "csv",
        "csv_map": str(log.fmap.path),
        "csv_map_sha256": log.fmap.sha256,
        "mode": log.mode,
        "sign_map": list(log.signs),
        "sign_map_source": log.conditions["signs"]["source"],
        "supply_voltage": log.supply,
        "duty_timing": log.duty_timing,
        "firmware_timing": log.firmware_timing,
        "conditions": log.conditions,
        "csv_layout": log.layout,
        "steps_planned": int(starts.size),
        "notes": f"Imported from {log.file.name} with the map {log.fmap.path.name}: one step per constant-duty "
                 "segment; what the log does not state is in `conditions` (stated, inferred or unknown).",
        "provenance": {"simulated": False, "world": None, "source_file": str(log.file), "source_sha256": digest,
                       "board_id": None, "boot_id": None, "firmware_version": None, "settings_sha256": None,
                       "robot_file": str(log.robot_path) if log.robot_path else None,
                       "robot_file_sha256": file_digest_or_none(log.robot_path) if log.robot_path else None,
                       "wiring_file": None, "wiring_sha256": None},
    }
    if log.direction is not None:
        extra.update(direction=log.direction, wheel_pattern=list(log.pattern or ()),
                     direction_source=log.conditions["direction"]["source"])
    w = RunWriter.create(Path(out), log.procedure, run_dir=run_dir, name=log.file.stem,
                         counts_per_rev=log.counts_per_rev, extra=extra,
                         robot=log.robot.to_toml_dict() if log.robot is not None else None,
                         robot_text=log.robot_text, robot_file=str(log.robot_path) if log.robot_path else None)
    with w:
        w.event("import", source_file=str(log.file), map=str(log.fmap.path))
        for k, (a, b) in enumerate(zip(starts, ends)):
            w.event("step_start", t=float(t[a]), step=k)
            for n in range(a, b):
                row: dict[str, Any] = {"step": k, "t": float(t[n]), "seq": n,
                                       **{f"u{j + 1}": float(u[n, j]) for j in range(4)},
                                       **{f"phi{j + 1}": float(log.phi[n, j]) for j in range(4)}}
                if log.enc is not None:
                    row.update({f"enc{j + 1}": int(log.enc[n, j]) for j in range(4)})
                if log.currents is not None:
                    row.update({f"i{j + 1}": _num(log.currents[n, j]) for j in range(4)})
                if log.v_batt is not None:
                    row["V_batt"] = _num(log.v_batt[n])
                if log.i_batt is not None:
                    row["I_batt"] = _num(log.i_batt[n])
                w.sample(row)
            w.event("step_end", t=float(t[b - 1]), step=k)
            drive = float(log.drive[a])
            rec: dict[str, Any] = {"step": k, "kind": kind, "duty": drive,
                                   **{f"u{j + 1}": float(u[a, j]) for j in range(4)},
                                   "t_start": float(t[a]), "t_end": float(t[b - 1]), "n_samples": int(b - a)}
            if log.command is not None:
                rec["command"] = float(log.command[a])
            if log.supply is not None:
                rec["voltage"] = drive * log.supply
            w.step_complete(rec)
        if log.pose is not None:
            _write_pose(w.path / "pose.csv", t, log.pose)
    return w.path


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(float(v)) else None


def _write_pose(path: Path, t: np.ndarray, pose: np.ndarray) -> None:
    """pose.csv beside samples.csv: t (s), x, y (m), psi (rad) as logged (empty: not logged)."""
    with open(path, "w", encoding="utf-8") as fh:
        fh.write("t,x,y,psi\n")
        for k in range(len(t)):
            cells = [repr(float(t[k]))] + ["" if not math.isfinite(v) else repr(float(v)) for v in pose[k]]
            fh.write(",".join(cells) + "\n")


MAPS = Path(__file__).with_name("maps")


def shipped_maps() -> list[str]:
    """The names of the maps shipped with omnibench (omnibench/runs/maps/)."""
    return sorted(p.stem for p in MAPS.glob("*.toml"))


def shipped_map(name: str) -> Path:
    """`name` as a map file: an existing file, else a shipped map of that name (with or without
    .toml); a one-line UserError naming the shipped ones otherwise."""
    p = Path(name)
    if p.is_file():
        return p
    stem = p.name[:-5] if p.name.endswith(".toml") else p.name
    if p.parent == Path(".") and stem in shipped_maps():
        return MAPS / f"{stem}.toml"
    if p.is_dir():
        raise UserError(f"--map {name}: is a folder, not a map file")
    raise UserError(f"--map {name}: no such map file, nor a shipped map ({', '.join(shipped_maps())})")
