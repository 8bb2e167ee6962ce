"""Import the real 2019 Omnibot logs (thesis TFM, MATLAB v5 files) into run directories.

Two kinds of file (shared/data/omnibot-tfm/README.md):

- ``results_jacked.mat``: robot on blocks, wheels in the air. ``ws`` (4 x 127) holds the
  steady wheel speed (rad/s) reached at each command amplitude 1..127 (NaN where not run);
  ``t, x, m`` are the raw log of the last step (time s, command/127, wheel position in
  revolutions). Becomes an ``upside_down_sweep`` run: one completed step per amplitude run,
  carrying ``w1..w4`` = ``ws`` (times the sign map), plus the raw samples of the last step.
- ``square_*.mat``: ``data`` (7 x N) rows = command (-127..127), Arduino ``millis()``, unused,
  encoder counts FL, FR, BL, BR. A square-wave command on all four motors, wheels in the air.
  Becomes a ``step_response`` run: one step per constant-command segment, raw samples with
  duty = command/127, board time = millis/1000 s, encoder counts times the sign map.

- ``results_ground_*.mat`` (older analysis format): robot on the floor; ``t, x, m`` the raw log
  of the last square wave (wheel signs already corrected by the sketch, which negated the FR and
  BR encoders and the FL and FR commands). Becomes a ``step_response`` run with ``mode =
  "ground"``; the fitted gains ``Ks`` / ``fits`` / ``Ts`` are kept in run.json
  (``fitted_gains``), the 1 ms resampled ``tr``/``mr`` are not imported (not measurements).
  ``x`` is the value of the one axis driven (the RC sketch mixes drive, strafe and turn: FL =
  d - t - s, FR = d + t + s, RL = d - t + s, RR = d + t - s); which axis is the run's direction:
  ``forward`` (x), ``sideways`` (y, the wheels in opposite pairs), ``rotation`` (psi) or
  ``diagonal`` (x and y: FR and RL only). Each wheel's duty is its pattern entry times x
  (`DIRECTIONS`, the columns of the kinematics R); the direction is read off the data (the sign
  of each wheel's travel against x) unless given, and a log whose wheels disagree with the
  given direction's kinematics is refused.
- ``inputs.mat``: ``data`` (6 x N) rows = ``millis()``, drive value in [-1, 1] (command =
  trunc(127 value)), encoder counts FL, FR, BL, BR, written by the RC sketch. Becomes a
  ``random_duty`` run: wheels in the air, one step per constant command ("hold" steps of a
  hand-driven command, not a square wave); its default sign map is read off the data.

Firmware timing (README of the data): each loop sends four 4-byte Sabertooth packets at 9600
baud (4.17 ms each) in the sketch's order, after reading the encoders (square-wave sketch,
FL, FR, BL, BR) or before (RC sketch ``ardu.ino.ino``, FL, FR, BR, BL: the commands of a log
line left 4 packets before its time stamp). Every run records it in run.json ``firmware_timing``
(sketch, ``command_order``, ``packet_s``, ``command_offset_s``: when the first packet of a
logged command started, relative to its time stamp) and the analysis uses it: the offset shifts
the logged schedule, the order is what ``serial_command_latency`` follows.

Sign map: the 2019 firmware negated the FR and BR encoder readings and drove FL and FR with
the negated command, so in the raw square-wave logs wheels 2 and 4 read negative speed for a
positive command. The map multiplies each wheel's logged counts (and speeds) so that a
positive duty gives a positive wheel speed on every wheel. The thesis had already corrected
the signs in ``results_jacked.mat`` (every ``ws`` and raw count is positive), so its default
map is +1 on every wheel. The duties stay the logged command for every wheel.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from omnibench.errors import UserError
from omnibench.runs.store import RunWriter

COUNTS_PER_REV = 980  # LS7366 counts per wheel revolution (20 x 49)
SUPPLY_V = 24.7  # V, supply voltage noted in the README
RAW_SIGNS = (1, -1, 1, -1)  # square-wave logs: wheels 2 and 4 read negative for a positive command
JACKED_SIGNS = (1, 1, 1, 1)  # results_jacked.mat: already corrected by the thesis scripts

SOURCE = "InigoMoreno/TFM matlab/ (2019 master's thesis logs)"
PACKET_S = 4 * 10 / 9600.0  # one 4-byte Sabertooth packet at 9600 baud, s

#: the two 2019 sketches' command timing (shared/data/omnibot-tfm/README.md)
SQUARE_SKETCH = {"sketch": "arduino/square/square.ino", "command_order": [1, 2, 3, 4],
                 "commands": "after reading the encoders", "packet_s": PACKET_S, "command_offset_s": 0.0,
                 "channels": {"FL": "128/2", "FR": "128/1", "RL": "129/1", "RR": "129/2"}}
RC_SKETCH = {"sketch": "arduino/ardu.ino.ino", "command_order": [1, 2, 4, 3],
             "commands": "before reading the encoders", "packet_s": PACKET_S, "command_offset_s": -4 * PACKET_S,
             "channels": {"FL": "128/1", "FR": "128/2", "RL": "129/2", "RR": "129/1"}}
SKETCHES = {"square": SQUARE_SKETCH, "rc": RC_SKETCH}


#: a floor run's direction -> each wheel's duty per unit of the logged drive value x (FL, FR, RL,
#: RR): the RC sketch's mixing, which is the sign pattern of the kinematics R v (design.md:
#: sideways +y turns FL and RR back, FR and RL forward; rotation +psi turns the left wheels back)
DIRECTIONS = {"forward": (1, 1, 1, 1), "sideways": (-1, 1, 1, -1), "rotation": (-1, 1, -1, 1),
              "diagonal": (0, 1, 1, 0)}
#: the body velocity direction (v1, v2, psi_dot) of each, for the check against the kinematics
DIRECTION_VELOCITY = {"forward": (1.0, 0.0, 0.0), "sideways": (0.0, 1.0, 0.0), "rotation": (0.0, 0.0, 1.0),
                      "diagonal": (1.0, 1.0, 0.0)}
UNKNOWN_SKETCH = "unknown"


def kinematic_pattern(direction: str, robot=None) -> np.ndarray:
    """Each wheel's speed sign (-1, 0, +1) for a run in `direction`, from the robot's inverse
    kinematics (design.md's R): what a floor log's wheels must show."""
    from omnibench.model import default_robot
    from omnibench.model.geometry import inverse_kinematics

    rb = robot or default_robot()
    w = inverse_kinematics(rb.L, rb.l, rb.r, rb.alpha) @ np.asarray(DIRECTION_VELOCITY[direction])
    return np.where(np.abs(w) > 1e-9 * np.max(np.abs(w)), np.sign(w), 0.0)


def direction_of(drive: np.ndarray, counts: np.ndarray) -> str:
    """A floor run's direction read off the log: the sign of each wheel's travel against the
    drive value (a wheel that travels less than a tenth of the most travelled: 0), matched to
    `DIRECTIONS`; a one-line UserError when no direction fits."""
    dc = np.diff(np.asarray(counts, dtype=float), axis=1)
    corr = dc @ np.asarray(drive, dtype=float)[:-1]
    top = float(np.max(np.abs(corr))) if corr.size else 0.0
    if top <= 0:
        raise UserError("no wheel turned with the command: cannot tell the run's direction (give --direction)")
    seen = tuple(int(v) for v in np.where(np.abs(corr) > 0.1 * top, np.sign(corr), 0))
    for name, pat in DIRECTIONS.items():
        if seen == pat:
            return name
    raise UserError(f"wheels FL, FR, RL, RR travel with signs {seen} against the command: no floor direction "
                    f"({', '.join(f'{k} {v}' for k, v in DIRECTIONS.items())}); check --signs or give --direction")


def parse_signs(text: str) -> tuple[int, int, int, int]:
    """'+1,-1,+1,-1' -> (1, -1, 1, -1); a one-line UserError otherwise."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(int(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 4 or any(v not in (1, -1) for v in vals):
        raise UserError(f"--signs {text!r}: give four signs, one per wheel FL,FR,RL,RR, e.g. +1,-1,+1,-1")
    return vals


def _load(path: Path) -> dict[str, Any]:
    import scipy.io

    if not path.is_file():
        raise UserError(f"{path}: {'is a folder, not a log file' if path.is_dir() else 'no such file'}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return scipy.io.loadmat(str(path))
    except Exception as exc:  # scipy raises several types for non-MAT input
        raise UserError(f"{path}: not a MATLAB v5 file scipy can read ({type(exc).__name__})") from None


def kind_of(data: dict[str, Any]) -> str:
    """'jacked' (ws/amps), 'ground' (Ks/fits with a raw t, x, m), 'square' (7-row `data`) or
    'rc' (6-row `data`)."""
    if "ws" in data and "amps" in data:
        return "jacked"
    if "Ks" in data and all(k in data for k in ("t", "x", "m")):
        return "ground"
    d = data.get("data")
    if d is not None and getattr(d, "ndim", 0) == 2 and d.shape[1] > 1 and d.shape[0] in (6, 7):
        return "square" if d.shape[0] == 7 else "rc"
    raise UserError("file holds none of `ws`/`amps` (jacked sweep), `Ks` with `t`, `x`, `m` (floor "
                    "runs), a 7-row `data` (square wave) or a 6-row `data` (RC log)")


def file_digest(file: Path | str) -> str:
    """SHA-256 of a file's bytes (hex): the identity of an imported log, whatever its path."""
    import hashlib

    h = hashlib.sha256()
    with open(file, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def import_tfm(
    file: Path | str,
    out: Path | str,
    *,
    signs: Sequence[int] | None = None,
    run_dir: Path | None = None,
    sketch: str | None = None,
    direction: str | None = None,
) -> Path:
    """Convert one 2019 TFM .mat file into a run directory under `out`; returns its path.
    `sketch` ("square" or "rc") says which 2019 sketch recorded it, when you know better than
    the data README (default: the RC sketch for the RC log, the square-wave sketch otherwise;
    for the floor runs the README names no sketch: their sketch is recorded as unknown, replayed
    with the square-wave sketch's timing unless profiled). `direction` (forward, sideways,
    rotation, diagonal) says which axis a floor run drove (default: read off the data)."""
    file = Path(file)
    if sketch is not None and sketch not in SKETCHES:
        raise UserError(f"unknown sketch {sketch!r}: give one of {', '.join(SKETCHES)}")
    if direction is not None and direction not in DIRECTIONS:
        raise UserError(f"unknown direction {direction!r}: give one of {', '.join(DIRECTIONS)}")
    data = _load(file)
    try:
        kind = kind_of(data)
    except UserError as exc:
        raise UserError(f"{file}: {exc}") from None
    given = {**SKETCHES[sketch], "source": "given at import"} if sketch else None
    if kind == "jacked":
        return _import_jacked(file, data, Path(out), tuple(signs or JACKED_SIGNS), run_dir, given or SQUARE_SKETCH)
    if kind == "ground":
        return _import_ground(file, data, Path(out), tuple(signs or JACKED_SIGNS), run_dir, given or unknown_timing(),
                              direction)
    if kind == "rc":
        return _import_rc(file, data, Path(out), signs, run_dir, given or RC_SKETCH)
    return _import_square(file, data, Path(out), tuple(signs or RAW_SIGNS), run_dir, given or SQUARE_SKETCH)


def unknown_timing() -> dict[str, Any]:
    """The firmware timing of a log whose sketch is not documented (the floor runs): sketch
    "unknown", the documented sketches it may be (`profiled_over`), replayed with the square-wave
    sketch's timing unless the analysis profiles over the others (`alternatives`)."""
    other = {k: RC_SKETCH[k] for k in ("sketch", "command_order", "commands", "command_offset_s")}
    return {**SQUARE_SKETCH, "sketch": UNKNOWN_SKETCH, "default_sketch": SQUARE_SKETCH["sketch"],
            "profiled_over": [SQUARE_SKETCH["sketch"], RC_SKETCH["sketch"]],
            "source": "assumed for replay (the square-wave sketch's timing): the data README names no sketch "
                      "for the floor runs (results_ground_x.mat samples every 35 ms, between the square-wave "
                      "logs' 30 ms and the RC log's 44 ms); the analysis profiles over the documented sketches; "
                      "give --sketch if you know",
            "alternatives": [other]}


def _base_extra(file: Path, signs: Sequence[int], kind: str, timing: dict[str, Any] = SQUARE_SKETCH) -> dict[str, Any]:
    return {
        "firmware_timing": dict(timing),
        "source": SOURCE,
        "source_file": str(file),
        "source_sha256": file_digest(file),  # `import tfm` knows the same log when it comes again
        "source_kind": kind,
        "sign_map": list(signs),
        "supply_voltage": SUPPLY_V,
        "imported": True,
        "provenance": {"simulated": False, "world": None, "source_file": str(file),
                       "source_sha256": file_digest(file), "board_id": None, "boot_id": None,
                       "firmware_version": None, "settings_sha256": None, "robot_file": None,
                       "robot_file_sha256": None, "wiring_file": None, "wiring_sha256": None},
    }


def _import_jacked(file: Path, data: dict[str, Any], out: Path, signs: tuple[int, ...],
                   run_dir: Path | None, timing: dict[str, Any] = SQUARE_SKETCH) -> Path:
    ws = np.asarray(data["ws"], dtype=float)
    amps = np.asarray(data["amps"]).ravel().astype(int)
    if ws.shape[0] != 4 or ws.shape[1] != amps.size:
        raise UserError(f"{file}: `ws` should be 4 x {amps.size}, is {ws.shape[0]} x {ws.shape[1]}")
    run_cols = np.where(~np.all(np.isnan(ws), axis=0))[0]
    sgn = np.asarray(signs, dtype=float)
    t = np.asarray(data.get("t", np.empty((1, 0))), dtype=float).ravel()
    x = np.asarray(data.get("x", np.empty((1, 0))), dtype=float).ravel()
    m = np.asarray(data.get("m", np.empty((4, 0))), dtype=float)
    last_cmd = None
    if x.size:
        last_cmd = int(round(float(np.median(x)) * 127))
    w = RunWriter.create(
        out, "upside_down_sweep", run_dir=run_dir, name=Path(file).stem, counts_per_rev=COUNTS_PER_REV,
        extra={**_base_extra(file, signs, "results_jacked", timing), "mode": "upside_down",
               "steps_planned": int(run_cols.size),
               "notes": "Steady speeds per amplitude from `ws`; raw samples only for the last "
                        "amplitude run (t, x, m). Wheel loads were not recorded."},
    )
    with w:
        w.event("import", source_file=str(file))
        for k, col in enumerate(run_cols):
            cmd = int(amps[col])
            duty = cmd / 127.0
            rec: dict[str, Any] = {
                "step": k, "kind": "hold", "wheel_set": "2019", "direction": 1,
                "command": cmd, "duty": duty, "voltage": duty * SUPPLY_V,
                **{f"u{j + 1}": duty for j in range(4)},
                **{f"wheel_mass{j + 1}": None for j in range(4)},
                "steady": True,
                **{f"w{j + 1}": float(sgn[j] * ws[j, col]) for j in range(4)},
            }
            if last_cmd is not None and cmd == last_cmd and m.shape == (4, t.size):
                w.event("step_start", t=float(t[0]), step=k, duty=duty)
                for n in range(t.size):
                    counts = np.round(m[:, n] * COUNTS_PER_REV) * sgn
                    row = {"step": k, "t": float(t[n]), "seq": n,
                           **{f"u{j + 1}": float(x[n]) for j in range(4)},
                           **{f"enc{j + 1}": int(counts[j]) for j in range(4)},
                           **{f"phi{j + 1}": float(sgn[j] * m[j, n] * 2 * math.pi) for j in range(4)}}
                    w.sample(row)
                w.event("step_end", t=float(t[-1]), step=k)
                rec.update(t_start=float(t[0]), t_end=float(t[-1]), has_samples=True)
            else:
                rec.update(t_start=None, t_end=None, has_samples=False)
            w.step_complete(rec)
    return w.path


def _import_square(file: Path, data: dict[str, Any], out: Path, signs: tuple[int, ...],
                   run_dir: Path | None, timing: dict[str, Any] = SQUARE_SKETCH) -> Path:
    d = np.asarray(data["data"]).astype(np.int64)
    return _import_trace(file, out, run_dir, "step_response", d[0], d[1] / 1000.0, d[3:7], signs,
                         _base_extra(file, signs, "square_wave", timing), "step_response",
                         "Square-wave command on all four motors, wheels in the air. "
                         "Time is Arduino millis()/1000 (irregular 17-45 ms sampling).")


def _import_ground(file: Path, data: dict[str, Any], out: Path, signs: tuple[int, ...],
                   run_dir: Path | None, timing: dict[str, Any] = SQUARE_SKETCH, direction: str | None = None) -> Path:
    t = np.asarray(data["t"], dtype=float).ravel()
    x = np.asarray(data["x"], dtype=float).ravel()
    m = np.asarray(data["m"], dtype=float)
    if m.shape != (4, t.size) or x.size != t.size:
        raise UserError(f"{file}: `m` should be 4 x {t.size} like `t` and `x`, is {m.shape}")
    counts = np.round(m * COUNTS_PER_REV).astype(np.int64)
    cmd = np.round(x * 127).astype(np.int64)
    signed = counts * np.asarray(signs, dtype=np.int64)[:, None]
    try:
        seen = direction_of(cmd, signed)
    except UserError as exc:
        if direction is None:
            raise UserError(f"{file}: {exc}") from None
        seen = None
    if direction is not None and seen is not None and seen != direction:
        raise UserError(f"{file}: the wheels travel as in a {seen} run (signs {DIRECTIONS[seen]} against the command), "
                        f"not as --direction {direction} ({DIRECTIONS[direction]}) says: check --signs or --direction")
    given = direction
    direction = direction or seen
    assert direction is not None, "without --direction a failed direction_of raised above"
    pattern = DIRECTIONS[direction]
    gains = {k: np.asarray(data[k], dtype=float).tolist() for k in ("Ks", "fits", "Ts") if k in data}
    extra = {**_base_extra(file, signs, "results_ground", timing), "mode": "ground", "fitted_gains": gains,
             "direction": direction, "wheel_pattern": list(pattern),
             "direction_source": "given at import" if given else "read off the data",
             "fitted_gains_note": "2019 per-amplitude process-model fits: Ks wheel rev/s per unit duty, "
                                  "fits percent (NaN where not run), Ts time constants (s)"}
    return _import_trace(file, out, run_dir, "step_response", cmd, t, counts, signs, extra, "step_response",
                         f"Robot on the floor driving {direction} and back (square wave of the drive value, each "
                         f"wheel's duty = {list(pattern)} x the drive value); raw log of the last square wave of "
                         f"{Path(file).name}.", pattern=pattern)


def data_signs(drive: np.ndarray, counts: np.ndarray) -> tuple[int, ...]:
    """Per-wheel sign map read off a log: the sign of each wheel's speed against the command."""
    dc = np.diff(counts, axis=1).astype(float)
    corr = dc @ np.asarray(drive, dtype=float)[:-1]
    if np.any(corr == 0):
        raise UserError("cannot read the wheel signs off the data (a wheel never turned with the "
                        "command): give --signs")
    return tuple(int(v) for v in np.sign(corr))


def _import_rc(file: Path, data: dict[str, Any], out: Path, signs: Sequence[int] | None,
               run_dir: Path | None, timing: dict[str, Any] = SQUARE_SKETCH) -> Path:
    d = np.asarray(data["data"], dtype=float)
    millis, value, counts = d[0].astype(np.int64), d[1], d[2:6].astype(np.int64)
    cmd = np.trunc(127 * value).astype(np.int64)  # the sketch: command = trunc(127 x value)
    sgn = tuple(signs) if signs else data_signs(cmd, counts)
    extra = {**_base_extra(file, sgn, "rc_log", timing),
             "sign_map_source": "given" if signs else "read off the data (speed against command)"}
    return _import_trace(file, out, run_dir, "random_duty", cmd, millis / 1000.0, counts, sgn, extra,
                         "duty_hold",
                         "Hand-driven (RC transmitter) command on all four motors, wheels in the air: "
                         "each step holds one command level, not a square wave. Time is millis()/1000.")


def _import_trace(file: Path, out: Path, run_dir: Path | None, procedure: str, cmd: np.ndarray,
                  t: np.ndarray, counts: np.ndarray, signs: Sequence[int], extra: dict[str, Any],
                  step_kind: str, notes: str, pattern: Sequence[int] = (1, 1, 1, 1)) -> Path:
    """A logged command trace (command -127..127, time s, counts 4 x N) as one step per
    constant-command segment, raw samples with wheel j's duty = pattern_j x command/127 (a floor
    run's direction; all four the same otherwise) and counts times the sign map."""
    pat = [float(p) for p in pattern]
    if np.any(np.diff(t) <= 0):
        raise UserError(f"{file}: the time stamps are not increasing")
    if isinstance(extra.get("firmware_timing"), dict) and t.size > 1:  # the loop as logged
        extra = {**extra, "firmware_timing": {**extra["firmware_timing"],
                                              "loop_median_s": float(np.median(np.diff(t)))}}
    sgn = np.asarray(signs, dtype=np.int64)
    edges = np.flatnonzero(np.diff(cmd) != 0) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [cmd.size]])
    w = RunWriter.create(out, procedure, run_dir=run_dir, name=Path(file).stem, counts_per_rev=COUNTS_PER_REV,
                         extra={"mode": "upside_down", **extra, "steps_planned": int(starts.size),
                                "notes": notes})
    with w:
        w.event("import", source_file=str(file))
        for k, (a, b) in enumerate(zip(starts, ends)):
            duty = float(cmd[a]) / 127.0
            w.event("step_start", t=float(t[a]), step=k, duty=duty)
            for n in range(a, b):
                w.sample({"step": k, "t": float(t[n]), "seq": n,
                          **{f"u{j + 1}": pat[j] * float(cmd[n]) / 127.0 for j in range(4)},
                          **{f"enc{j + 1}": int(sgn[j] * counts[j, n]) for j in range(4)}})
            w.event("step_end", t=float(t[b - 1]), step=k)
            w.step_complete({
                "step": k, "kind": step_kind, "command": int(cmd[a]), "duty": duty,
                "voltage": duty * SUPPLY_V, **{f"u{j + 1}": pat[j] * duty for j in range(4)},
                "t_start": float(t[a]), "t_end": float(t[b - 1]), "n_samples": int(b - a),
            })
    return w.path
