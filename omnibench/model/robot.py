"""The robot description: the paper's symbols as fields, SI units, read from an editable TOML file.

Errors name the file, the line (when it can be found) and the key, in one line.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

from omnibench.errors import UserError
from omnibench.files import read_toml
from omnibench.model.units import to_si

DEFAULT_ROBOT_FILE = Path(__file__).with_name("omnibot.toml")


@dataclass(frozen=True)
class FieldSpec:
    """How one robot field is written in the file: section, SI unit, kind and bounds."""

    section: str
    unit: str
    kind: str = "scalar"  # scalar | vector4 | count
    positive: bool = True  # strictly > 0
    nonnegative: bool = False  # >= 0 (instead of > 0)
    upper: float = math.inf
    signed: bool = False  # any sign allowed (angles)


FIELDS: dict[str, FieldSpec] = {
    "L": FieldSpec("geometry", "m"),
    "l": FieldSpec("geometry", "m"),
    "r": FieldSpec("geometry", "m"),
    "alpha": FieldSpec("geometry", "rad", kind="vector4", signed=True),
    "m": FieldSpec("mass", "kg"),
    "I_z": FieldSpec("mass", "kg*m^2"),
    "I_w": FieldSpec("mass", "kg*m^2"),
    "wheel_mass": FieldSpec("mass", "kg", kind="vector4"),
    "k_t": FieldSpec("motor", "N*m/A"),
    "k_e": FieldSpec("motor", "V*s/rad"),
    "R_a": FieldSpec("motor", "ohm"),
    "eta": FieldSpec("motor", "1", upper=1.0),
    "V_batt": FieldSpec("motor", "V"),
    "I_0": FieldSpec("motor", "A", positive=False, nonnegative=True),
    "a": FieldSpec("friction", "N*m*s/rad", positive=False, nonnegative=True),
    "b": FieldSpec("friction", "N*m", positive=False, nonnegative=True),
    "c": FieldSpec("friction", "1/N", positive=False, nonnegative=True),
    "a_r": FieldSpec("friction", "N*s/m", positive=False, nonnegative=True),
    "b_r": FieldSpec("friction", "N", positive=False, nonnegative=True),
    "c_r": FieldSpec("friction", "1/N", positive=False, nonnegative=True),
    "C_r": FieldSpec("friction", "1", positive=False, nonnegative=True),
    "counts_per_rev": FieldSpec("encoder", "1", kind="count"),
    "max_duty": FieldSpec("limits", "1", upper=1.0),
    "max_current": FieldSpec("limits", "A"),
    "sign_width_phi": FieldSpec("numerics", "rad/s"),
    "sign_width_sigma": FieldSpec("numerics", "m/s"),
}

# Tables a model file adds beside the robot's (who fitted what, from which runs); the robot
# loader accepts and ignores them, so a fitted model works wherever a robot file does.
PROVENANCE_SECTIONS = ("fit", "diagnosis")
SECTIONS = sorted({spec.section for spec in FIELDS.values()} | {"effects", "firmware_timing", *PROVENANCE_SECTIONS})


@dataclass(frozen=True)
class Robot:
    """A four-mecanum-wheel robot (SI units; symbols as in the paper and docs/robot-file.md, the model)."""

    name: str
    L: float
    l: float
    r: float
    alpha: tuple[float, float, float, float]
    m: float
    I_z: float
    I_w: float
    wheel_mass: tuple[float, float, float, float]
    k_t: float
    k_e: float
    R_a: float
    eta: float
    V_batt: float
    I_0: float
    a: float
    b: float
    c: float
    a_r: float
    b_r: float
    c_r: float
    C_r: float
    counts_per_rev: int
    max_duty: float
    max_current: float
    sign_width_phi: float
    sign_width_sigma: float
    effects: Mapping[str, Mapping[str, float]] = field(default_factory=dict)

    def replace(self, **changes: Any) -> "Robot":
        """A copy with some fields changed (no validation; use for fitted values)."""
        return dataclasses.replace(self, **changes)

    def to_toml_dict(self) -> dict[str, Any]:
        """The robot as a TOML-ready dict in the file's sections (SI numbers)."""
        out: dict[str, Any] = {"name": self.name}
        for key, spec in FIELDS.items():
            value = getattr(self, key)
            out.setdefault(spec.section, {})[key] = list(value) if spec.kind == "vector4" else value
        if self.own_effects:
            out["effects"] = {k: dict(v) for k, v in self.own_effects.items()}
        if self.firmware_timing:  # the firmware's command timing, apart from the robot's effects (issue 36)
            out["firmware_timing"] = {k: dict(v) for k, v in self.firmware_timing.items()}
        return out

    @property
    def firmware_timing(self) -> dict[str, Mapping[str, float]]:
        """The effects that are the recording firmware's command timing (latencies, in the send
        order of the run they are applied to: omnibench/model/timing.py), not the robot's."""
        from omnibench.model.timing import FIRMWARE_TERMS

        return {k: v for k, v in self.effects.items() if k in FIRMWARE_TERMS}

    @property
    def own_effects(self) -> dict[str, Mapping[str, float]]:
        """The robot's own effects (everything but the firmware timing)."""
        from omnibench.model.timing import FIRMWARE_TERMS

        return {k: v for k, v in self.effects.items() if k not in FIRMWARE_TERMS}


def _line_of(text: str, section: str | None, key: str) -> int | None:
    """Line number (1-based) of `key = ...` inside [section] of a TOML text, if found."""
    current = None
    for n, line in enumerate(text.splitlines(), start=1):
        head = re.match(r"\s*\[([^\]]+)\]", line)
        if head:
            current = head.group(1).strip()
            continue
        if re.match(rf"\s*{re.escape(key)}\s*=", line) and (section is None or current == section):
            return n
    return None


class _Reader:
    """Validates a parsed robot TOML and raises UserError pointing at file:line."""

    def __init__(self, path: str, text: str) -> None:
        self.path, self.text = path, text

    def fail(self, section: str | None, key: str, message: str) -> NoReturn:
        line = _line_of(self.text, section, key)
        where = f"{self.path}:{line}" if line else self.path
        where_key = f"[{section}] {key}" if section else key
        raise UserError(f"{where}: {where_key}: {message}")

    def value(self, key: str, spec: FieldSpec, raw: object) -> Any:
        try:
            if spec.kind == "vector4":
                if not isinstance(raw, list) or len(raw) != 4:
                    raise ValueError("expected a list of 4 values, one per wheel (FL, FR, RL, RR)")
                values = tuple(to_si(v, spec.unit) for v in raw)
            elif spec.kind == "count":
                if isinstance(raw, bool) or not isinstance(raw, int):
                    raise ValueError(f"expected a whole number, got {raw!r}")
                values = (raw,)
            else:
                values = (to_si(raw, spec.unit),)
        except ValueError as exc:
            self.fail(spec.section, key, str(exc))
        for v in values:
            if not math.isfinite(v):
                self.fail(spec.section, key, f"{v} is not a finite number")
            if not spec.signed:
                if spec.positive and v <= 0:
                    self.fail(spec.section, key, f"must be positive ({spec.unit}), got {v}")
                if spec.nonnegative and v < 0:
                    self.fail(spec.section, key, f"must not be negative ({spec.unit}), got {v}")
            if v > spec.upper:
                self.fail(spec.section, key, f"must be at most {spec.upper}, got {v}")
        if key == "alpha":
            for v in values:
                if abs(math.sin(v)) < 1e-3 or abs(math.cos(v)) < 1e-3:
                    self.fail(spec.section, key, "roller angles must be strictly between 0 and 90 deg in size")
        return values if spec.kind == "vector4" else values[0]

    def effects(self, raw: object) -> dict[str, dict[str, float]]:
        from omnibench.model.terms import all_terms

        if not isinstance(raw, dict):
            self.fail(None, "effects", "expected tables [effects.<name>]")
        known = {t.name: t for t in all_terms() if not t.core}
        out: dict[str, dict[str, float]] = {}
        for name, params in raw.items():
            if name not in known:
                hint = difflib.get_close_matches(name, known, n=1)
                self.fail(f"effects.{name}", name, "unknown effect" + (f" (did you mean {hint[0]}?)" if hint else f"; known: {', '.join(sorted(known))}"))
            term = known[name]
            specs = {p.name: p for p in term.params}
            values = dict(term.defaults())
            for pname, pval in (params or {}).items():
                if pname not in specs:
                    self.fail(f"effects.{name}", pname, f"unknown parameter of {name}; known: {', '.join(specs)}")
                try:
                    v = to_si(pval, specs[pname].unit)
                except ValueError as exc:
                    self.fail(f"effects.{name}", pname, str(exc))
                if not (specs[pname].lower <= v <= specs[pname].upper):
                    self.fail(f"effects.{name}", pname, f"{v} is outside [{specs[pname].lower}, {specs[pname].upper}]")
                values[pname] = v
            out[name] = values
        return out


def robot_from_dict(data: Mapping[str, Any], *, path: str = "<robot>", text: str = "") -> Robot:
    """Validate a parsed robot description (sections as in omnibot.toml) into a Robot."""
    reader = _Reader(path, text)
    values: dict[str, Any] = {}
    for key, raw in data.items():
        if key == "name":
            continue
        if key not in SECTIONS:
            hint = difflib.get_close_matches(key, SECTIONS, n=1)
            reader.fail(None, key, "unknown section" + (f" (did you mean [{hint[0]}]?)" if hint else f"; sections are {', '.join(SECTIONS)}"))
        if key in ("effects", "firmware_timing") or key in PROVENANCE_SECTIONS:
            continue
        if not isinstance(raw, dict):
            reader.fail(None, key, f"[{key}] must be a table")
        for sub, subraw in raw.items():
            spec = FIELDS.get(sub)
            if spec is None or spec.section != key:
                names = [k for k, s in FIELDS.items() if s.section == key]
                hint = difflib.get_close_matches(sub, list(FIELDS), n=1)
                extra = f" (did you mean {hint[0]}?)" if hint else f"; [{key}] takes {', '.join(names)}"
                if spec is not None:
                    extra = f" (it belongs in [{spec.section}])"
                reader.fail(key, sub, "unknown key" + extra)
            values[sub] = reader.value(sub, spec, subraw)
    missing = [k for k in FIELDS if k not in values]
    if missing:
        where = ", ".join(f"[{FIELDS[k].section}] {k}" for k in missing)
        raise UserError(f"{path}: missing values: {where}")
    effects = reader.effects(data.get("effects", {}))
    firmware = reader.effects(data.get("firmware_timing", {}))  # [firmware_timing.<term>]: latencies only
    from omnibench.model.timing import FIRMWARE_TERMS

    for term in firmware:
        if term not in FIRMWARE_TERMS:
            reader.fail("firmware_timing", term, f"not firmware timing (it belongs in [effects]); "
                        f"[firmware_timing] takes {', '.join(FIRMWARE_TERMS)}")
    effects.update(firmware)
    name = data.get("name", Path(path).stem)
    return Robot(name=str(name), effects=effects, **values)


def load_robot(path: str | Path) -> Robot:
    """Read and validate a robot (or fitted model) TOML file; UserError (one line) on any problem."""
    data, text = read_toml(path, "robot file")
    return robot_from_dict(data, path=str(Path(path)), text=text)


def default_robot() -> Robot:
    """The real Omnibot's numbers (omnibench/model/omnibot.toml)."""
    return load_robot(DEFAULT_ROBOT_FILE)
