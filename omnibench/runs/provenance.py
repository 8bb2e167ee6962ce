"""Provenance of a run: what produced it (robot, board, world, source), and the check that the
runs an analysis combines come from one robot on one kind of board in one world.

A run's identity for combining is (robot, simulated, world): the robot's build (encoder counts
per revolution and geometry; not the friction coefficients a fit changes), whether a simulator or a real board took it,
and for a simulator the world its port names (the ``sim://`` query: plant, effects, ...). Boot
ids, board ids of one real board across a resume, source files and sketches of an import do not
make a different robot. Old run folders without these fields read as unknown, never as a mix.
"""
from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any
from urllib.parse import parse_qsl, urlsplit

from omnibench.errors import UserError

__all__ = [
    "board_changes",
    "identity",
    "latest_provenance",
    "mixed_runs",
    "model_build",
    "refuse_mixed",
    "run_provenance",
    "sha256_file",
    "sha256_text",
    "world_of",
]


def sha256_text(text: str) -> str:
    """SHA-256 (hex) of a text's UTF-8 bytes."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def sha256_file(path: str | Path | None) -> str | None:
    """SHA-256 (hex) of a file's bytes; None when there is no such file."""
    if not path:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


#: The ``sim://`` settings that change the simulated robot's physics (omnibench.sim.world): two
#: runs whose ports differ in one of these are of different worlds. Everything else a sim URL
#: may say (seed, clock, speed, dt, board id, firmware version, protocol, baud rate, name, link
#: faults, sensor noise) changes how the robot is driven or read, not what it is; those are
#: listed in CONDUCT_SETTINGS, and tests/runs/test_provenance.py checks that every setting of
#: the simulator is in exactly one of the two.
PHYSICS_SETTINGS = frozenset({"world", "robot", "mode", "payload", "wheel_mass", "plant", "wiring", "encoder_wiring",
                              "actuation"})
PHYSICS_PREFIXES = ("effects.",)
#: physics settings spelled at their default value name the default world (omnibench.sim.world's
#: defaults; tests/runs/test_provenance.py ties the two): ``sim://?actuation=firmware`` is ``sim://``
PHYSICS_DEFAULTS = {"actuation": "firmware"}
CONDUCT_SETTINGS = frozenset({"seed", "clock", "speed", "dt", "board_id", "firmware_version", "protocol", "baudrate",
                              "name", "faults", "sensors"})


def world_of(port: str | None) -> str | None:
    """The simulated world a ``sim://`` port names: its physics settings, sorted ('' for the
    default world); None for a real port. ``sim://?seed=8`` and ``sim://?seed=9&drop=0.01`` are
    one world, ``sim://?payload=2`` another."""
    if not port or not port.startswith("sim:"):
        return None
    pairs = parse_qsl(urlsplit(port).query, keep_blank_values=True)
    kept = {k: v for k, v in pairs if (k in PHYSICS_SETTINGS or k.startswith(PHYSICS_PREFIXES))
            and PHYSICS_DEFAULTS.get(k) != v}
    return "&".join(f"{k}={_number_text(v)}" for k, v in sorted(kept.items()))


def _number_text(v: str) -> str:
    """'2', '2.0' and '2e0' as one text; any other value unchanged."""
    try:
        return f"{float(v):g}"
    except ValueError:
        return v


def robot_sha256(robot: Mapping[str, Any] | None) -> str | None:
    """SHA-256 of a robot description (the run's `robot` table, canonical JSON); None without one."""
    if not robot:
        return None
    return sha256_text(json.dumps(robot, sort_keys=True, separators=(",", ":"), default=str))


def run_provenance(*, robot: Mapping[str, Any] | None, robot_file: str | None, robot_text: str | None,
                   hello: Mapping[str, Any] | None, port: str | None, simulated: bool,
                   wiring_file: str | None) -> dict[str, Any]:
    """The `provenance` table of a run taken on a board (null where the board does not say)."""
    hello = hello or {}
    settings = hello.get("settings")
    return {
        "robot_file": robot_file,
        "robot_file_sha256": sha256_text(robot_text) if robot_text is not None else None,
        "robot_sha256": robot_sha256(robot),
        "board_id": hello.get("board_id"),
        "boot_id": hello.get("boot_id"),
        "firmware_version": hello.get("firmware_version"),
        "settings_sha256": robot_sha256(settings) if isinstance(settings, Mapping) else None,
        "wiring_file": wiring_file,
        "wiring_sha256": sha256_file(wiring_file),
        "simulated": simulated,
        "world": world_of(port) if simulated else None,
    }


def identity(doc: Mapping[str, Any]) -> dict[str, Any]:
    """What must agree for two runs to be combined (a run.json document): the robot's build
    (counts per revolution, L, l, r, alpha), simulated or real, the simulated world; a value None is unknown (old runs) and agrees with anything."""
    raw_prov = doc.get("provenance")
    prov: Mapping[str, Any] = raw_prov if isinstance(raw_prov, Mapping) else {}
    port = doc.get("port") if isinstance(doc.get("port"), str) else None
    if doc.get("imported"):
        simulated: bool | None = False
    elif "simulated" in prov:
        simulated = bool(prov["simulated"])
    elif port:
        simulated = port.startswith("sim:")
    else:
        simulated = None
    raw_robot = doc.get("robot")
    robot: Mapping[str, Any] = raw_robot if isinstance(raw_robot, Mapping) else {}
    raw_geometry = robot.get("geometry")
    build: Mapping[str, Any] = raw_geometry if isinstance(raw_geometry, Mapping) else robot
    geometry = tuple((k, _canonical(build[k])) for k in GEOMETRY if k in build) or None
    encoder = robot.get("encoder")
    robot_cpr = encoder.get("counts_per_rev") if isinstance(encoder, Mapping) else robot.get("counts_per_rev")
    cpr = doc.get("counts_per_rev", robot_cpr)
    world = (world_of(port) if port and port.startswith("sim:") else prov.get("world")) if simulated else None
    return {"counts_per_rev": cpr, "geometry": geometry, "simulated": simulated, "world": world}


#: the robot's build (not its friction coefficients, which a fit or a campaign may change)
GEOMETRY = ("L", "l", "r", "alpha")


def _canonical(value: Any) -> Any:
    """A geometry value comparable across JSON and TOML (lists as tuples, numbers as floats)."""
    if isinstance(value, (list, tuple)):
        return tuple(_canonical(v) for v in value)
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        return float(value)
    return value


def model_build(robot: Any) -> dict[str, Any]:
    """A model's robot (omnibench.model.Robot) as the part of a run.json document the mixing check
    reads: its encoder resolution and geometry, so a model of another robot is refused like a run."""
    return {"counts_per_rev": robot.counts_per_rev,
            "robot": {"geometry": {k: _canonical(getattr(robot, k)) for k in GEOMETRY}}}


def _show(field: str, value: Any) -> str:
    if field == "simulated":
        return "simulated" if value else "real"
    if field == "counts_per_rev":
        return f"{value:g} counts/rev"
    if field == "geometry":
        return ", ".join(f"{k}={v}" for k, v in value)
    return f"sim://?{value}" if value else "the default world"


def mixed_runs(runs: Iterable[tuple[str, Mapping[str, Any]]]) -> tuple[str, str, str, str] | None:
    """The first pair of runs that differ in identity: (field, run A, run B, what differs); None
    when they all agree (unknown agrees with anything)."""
    first: dict[str, tuple[str, Any]] = {}
    for name, doc in runs:
        ident = identity(doc)
        for field in ("simulated", "world", "counts_per_rev", "geometry"):
            value = ident[field]
            if value is None or (field == "world" and ident["simulated"] is not True):
                continue
            if field not in first:
                first[field] = (name, value)
            elif first[field][1] != value:
                other, was = first[field]
                label = {"simulated": "simulated vs real", "world": "simulated world",
                         "counts_per_rev": "robot's encoder resolution",
                         "geometry": "robot geometry"}[field]
                return field, other, name, f"{label}: {_show(field, was)} vs {_show(field, value)}"
    return None


def refuse_mixed(runs: Iterable[tuple[str, Mapping[str, Any]]], *, allow_mixed: bool = False,
                 warn: Any = None) -> None:
    """UserError naming two runs and the field that differs, unless `allow_mixed` (then one
    warning line through `warn`)."""
    found = mixed_runs(runs)
    if found is None:
        return
    _, a, b, what = found
    if allow_mixed:
        if warn is not None:
            warn(f"warning: combining runs of different robots/boards/worlds ({a} and {b} differ in {what}); "
                 "the fit takes the shared coefficients from all of them (--allow-mixed)")
        return
    raise UserError(f"{a} and {b} are not of one robot/board/world ({what}); give --allow-mixed if the mix is meant")


#: What must agree for a run (or a campaign) to go on on the board now connected; a value None
#: is unknown (a board that does not say, an old run) and agrees with anything except where noted.
#: The boot id is not among them: opening the port of an Arduino resets it, so a resume on the
#: same board always sees a new boot id (the segment records the reboot instead).
BOARD_FIELDS = ("simulated", "world", "board_id", "firmware_version", "settings_sha256", "robot_file_sha256",
                "wiring_sha256")
_BOARD_LABEL = {"simulated": "simulated or real", "world": "simulated world", "board_id": "board id",
                "firmware_version": "firmware version", "settings_sha256": "board settings",
                "robot_file_sha256": "robot file", "wiring_sha256": "wiring file"}


def latest_provenance(doc: Mapping[str, Any]) -> dict[str, Any]:
    """The provenance of the board a run's last segment was taken on (run.json document): the
    newest segment's own, else the run's; {} for an old run without one."""
    for seg in reversed(doc.get("segments") or []):
        if isinstance(seg, Mapping) and isinstance(seg.get("provenance"), Mapping):
            return dict(seg["provenance"])
    prov = doc.get("provenance")
    if isinstance(prov, Mapping):
        out = dict(prov)
        if out.get("simulated") and isinstance(doc.get("port"), str) and doc["port"].startswith("sim:"):
            out["world"] = world_of(doc["port"])
        return out
    return {}


def board_changes(before: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    """What differs between the board a run was taken on and the board connected now, one
    phrase each ('board id 0B0B0001 -> 0B0B0002'); [] when nothing known differs. A wiring file
    given on one side and not the other is a change; other unknowns agree."""
    out: list[str] = []
    for f in BOARD_FIELDS:
        if f not in before or f not in now:
            continue
        b, n = before[f], now[f]
        if f == "world" and not (before.get("simulated") and now.get("simulated")):
            continue
        if f != "wiring_sha256" and (b is None or n is None):
            continue
        if b != n:
            out.append(f"{_BOARD_LABEL[f]} {_board_value(f, b, before)} -> {_board_value(f, n, now)}")
    return out


def _board_value(field: str, value: Any, prov: Mapping[str, Any]) -> str:
    if field == "simulated":
        return "simulated" if value else "real"
    if field == "world":
        return f"sim://?{value}" if value else "the default world"
    if field == "wiring_sha256":
        return str(prov.get("wiring_file") or "?") if value else "no wiring file"
    if field.endswith("sha256"):
        return str(value)[:12]
    if isinstance(value, (list, tuple)):
        return ".".join(str(v) for v in value)
    return str(value)
