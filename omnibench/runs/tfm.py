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
from typing import Any, cast

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


#: where the robot was: the option's words -> run.json `mode`
WHERE_MODES = {"air": "upside_down", "floor": "ground"}
#: the firmware loop of each 2019 sketch (data README), s, and how close a log's median time-stamp
#: spacing must be to one of them to read that sketch off the data (the two are 14 ms apart: a
#: loop within 3 ms of one is at least 11 ms from the other)
LOOP_S = {"square": 0.030, "rc": 0.044}
LOOP_TOLERANCE_S = 0.003
#: where the robot was is read off the wheels' dynamics only when one mode's wheel-speed NRMSE
#: (the logged duties replayed through the robot file, the wheel's nuisance profiled: WHERE_IW_FACTORS,
#: WHERE_LAG_S) is at most 1/WHERE_MARGIN of the other's; a statement the data contradict by this
#: margin is refused
WHERE_MARGIN = 2.0
#: the wheel's dynamics that a robot file may not know, profiled before air and floor are compared:
#: its in-air inertia as a multiple of the file's I_w (fits of the real 2019 in-air logs give about
#: 7 times the file's 0.00266 kg m^2) and a first-order actuator lag tau_a (s; the real robot's is
#: about 19 ms, the file has none). Each mode keeps its best grid point: a log is placed only when
#: no wheel the file does not know makes the other mode fit as well.
WHERE_IW_FACTORS = (0.3, 0.5, 1.0, 2.0, 3.5, 6.0, 10.0)
WHERE_LAG_S = (0.0, 0.01, 0.02, 0.04)

#: how a condition was decided (run.json `conditions`, docs/run-format.md)
STATED_BY_USER = "stated by the user"
STATED_IN_FILE = "stated in the file"
INFERRED = "inferred from the data"
UNKNOWN = "unknown"
ASSUMED = "assumed"  # only where the analysis does not depend on it (a sweep's firmware timing)

#: what each layout states (data README): (where, sketch, why); None: the layout does not say
LAYOUT_STATES: dict[str, dict[str, tuple[str, str]]] = {
    "jacked": {"where": ("air", "the sweep layout (`ws`, `amps`: steady speed per amplitude) is procedure III.i, "
                                "robot on blocks")},
    "square": {"where": ("air", "the square-wave layout (7-row `data`) is the data README's in-air square waves")},
    "rc": {"where": ("air", "the RC layout (6-row `data`) is the data README's in-air RC log"),
           "sketch": ("rc", "the 6-row `data` layout (millis, drive value, four counts) is what ardu.ino.ino printed")},
}


def condition(value: Any, decided: str, *, statistic: Any = None, margin: Any = None, evidence: str | None = None,
              **more: Any) -> dict[str, Any]:
    """One condition as run.json `conditions` records it: its value, how it was decided
    (STATED_BY_USER, STATED_IN_FILE, INFERRED, UNKNOWN or ASSUMED), the data's statistic and the
    margin the decision needs (where the data were read), and the evidence in words."""
    out: dict[str, Any] = {"value": value, "decided": decided}
    if statistic is not None:
        out["statistic"] = statistic
    if margin is not None:
        out["margin"] = margin
    if evidence:
        out["evidence"] = evidence
    out.update({k: v for k, v in more.items() if v is not None})
    return out


def loop_sketch(t: np.ndarray) -> tuple[str | None, dict[str, float], str]:
    """(sketch key or None, statistic, evidence): the 2019 sketch whose loop period the log's
    median time-stamp spacing matches within LOOP_TOLERANCE_S; None between or far from both."""
    loop = float(np.median(np.diff(np.asarray(t, dtype=float)))) if len(t) > 1 else float("nan")
    near = {k: abs(loop - v) for k, v in LOOP_S.items()}
    best = min(near, key=lambda k: near[k])
    value = best if math.isfinite(loop) and near[best] <= LOOP_TOLERANCE_S else None
    text = (f"median time-stamp spacing {1000 * loop:.1f} ms (square.ino loops every {1000 * LOOP_S['square']:.0f} ms, "
            f"ardu.ino.ino every {1000 * LOOP_S['rc']:.0f} ms; within {1000 * LOOP_TOLERANCE_S:.0f} ms of one reads it)")
    return value, {"loop_median_s": loop}, text


def where_from_dynamics(t: np.ndarray, duty: np.ndarray, phi: np.ndarray, robot: Any = None,
                        offsets: Sequence[float] = (0.0,), iw_factors: Sequence[float] = WHERE_IW_FACTORS,
                        lags: Sequence[float] = WHERE_LAG_S) -> tuple[str | None, dict[str, Any], str]:
    """(air, floor or None; statistic; evidence): the logged duties (N, 4), each acting from its
    sample on, replayed through the robot file (omnibench/model/omnibot.toml unless `robot`) with
    the wheels in the air and on the floor; each mode's wheel-speed NRMSE against the logged
    angles phi (N, 4, rad, sign-corrected), the least over the command `offsets` (s, the candidate
    firmware timings) and over the wheel's nuisance the file may get wrong: I_w times each of
    `iw_factors`, with each actuator lag of `lags` (s). An in-air wheel settles faster and turns
    faster per duty than one carrying the robot, but a heavier wheel or a lagging driver in the
    air can look like the floor: the better mode is chosen only when the other's best NRMSE is
    at least WHERE_MARGIN times its own best. The statistic also keeps each mode's NRMSE with
    the file's own wheel (`nrmse_*_file`) and where each mode's best lies (`best_*`)."""
    from omnibench.model import Scenario, default_robot
    from omnibench.model.scenario import Mode
    from omnibench.model.simulator import simulate_batch

    rb = robot or default_robot()
    t = np.asarray(t, dtype=float) - float(t[0])
    U = np.asarray(duty, dtype=float)
    phi = np.asarray(phi, dtype=float)
    wm = np.diff(phi, axis=0) / np.diff(t)[:, None]
    den = float(np.sqrt(np.mean(wm ** 2)))
    if den <= 0:
        return None, {"nrmse_air": None, "nrmse_floor": None}, "the wheels never turned: where cannot be read"
    change = np.concatenate([[0], np.flatnonzero(np.any(np.diff(U, axis=0) != 0, axis=1)) + 1])
    modes: dict[str, Mode] = {"air": "upside_down", "floor": "ground"}
    grid = [(name, float(f), float(lag)) for name in modes for f in iw_factors for lag in lags]
    robots = [rb.replace(I_w=f * rb.I_w) for _, f, _ in grid]
    scenarios = [Scenario(mode=modes[name], effects={"actuator_lag": {"tau_a": lag}} if lag > 0 else {})
                 for name, _, lag in grid]
    score: dict[tuple[str, float, float], float] = {}
    for off in offsets:
        t_cmd = t[change] + float(off)
        shift = max(0.0, -float(t_cmd[0]))
        res = simulate_batch(robots, scenarios, t_cmd + shift, U[change], float(t[-1]) + shift + 2e-3, dt=1e-3)
        for b, key in enumerate(grid):
            pp = np.stack([np.interp(t + shift, res.t, res.signal(f"phi{j + 1}")[b]) for j in range(4)], axis=1)
            wp = np.diff(pp, axis=0) / np.diff(t)[:, None]
            e = float(np.sqrt(np.mean((wm - wp) ** 2))) / den
            score[key] = min(score.get(key, math.inf), e if math.isfinite(e) else math.inf)
    best = {name: min((k for k in grid if k[0] == name), key=lambda k: score[k]) for name in modes}
    air, floor = score[best["air"]], score[best["floor"]]
    ratio = max(air, floor) / max(min(air, floor), 1e-12)
    better = "air" if air < floor else "floor"
    value = better if ratio >= WHERE_MARGIN else None
    file_point = {name: score.get((name, 1.0, 0.0)) for name in modes}
    stat = {"nrmse_air": air, "nrmse_floor": floor, "ratio": ratio, "robot_file": getattr(rb, "name", None),
            "best_air": {"I_w": best["air"][1] * rb.I_w, "tau_a": best["air"][2]},
            "best_floor": {"I_w": best["floor"][1] * rb.I_w, "tau_a": best["floor"][2]},
            "nrmse_air_file": file_point["air"], "nrmse_floor_file": file_point["floor"],
            "profiled": {"I_w": [f * rb.I_w for f in iw_factors], "tau_a": list(map(float, lags))}}

    def at(name: str) -> str:
        _, f, lag = best[name]
        return f"I_w {f:g} x the file's, tau_a {1000 * lag:.0f} ms"

    text = (f"the logged duties replayed through the robot file with the wheel's inertia ({min(iw_factors):g}-"
            f"{max(iw_factors):g} x the file's) and an actuator lag (0-{1000 * max(lags):.0f} ms) profiled: best "
            f"wheel-speed NRMSE {100 * air:.1f} % in the air ({at('air')}), {100 * floor:.1f} % on the floor "
            f"({at('floor')}), ratio {ratio:.2f} in favour of the {better} ({WHERE_MARGIN:g} needed to read it)")
    return value, stat, text


def _where_words(value: str) -> str:
    return "in the air" if value == "air" else "on the floor"


def _decide(file: Path, what: str, option: str, user: str | None, layout: tuple[str, str] | None,
            data: tuple[str | None, Any, str, Any] | None, force: bool,
            words=lambda v: str(v)) -> tuple[str | None, dict[str, Any]]:
    """One condition from the user's option, the layout's statement ((value, why) or None) and
    the data's reading ((value or None when not decisive, statistic, evidence, margin) or None
    when not read): (value or None, its `conditions` record). Two of them that disagree are
    refused in one line naming both, unless `force` and one of them is the user's (the option
    wins; the record says what it overrode); the layout against the data asks for the option."""
    seen = data[0] if data is not None else None
    stat, evidence, margin = (data[1], data[2], data[3]) if data is not None else (None, None, None)
    overridden = []
    if user is not None and layout is not None and user != layout[0]:
        if not force:
            raise UserError(f"{file}: {option} {user} says {what} {words(user)}, but the file's layout says "
                            f"{words(layout[0])} ({layout[1]}); give --force to import it as you say")
        overridden.append(f"the layout says {words(layout[0])} ({layout[1]})")
    if user is not None and seen is not None and user != seen:
        if not force:
            raise UserError(f"{file}: {option} {user} says {what} {words(user)}, but the data say {words(seen)} "
                            f"({evidence}); give --force to import it as you say")
        overridden.append(f"the data say {words(seen)} ({evidence})")
    if user is None and layout is not None and seen is not None and layout[0] != seen:
        raise UserError(f"{file}: the file's layout says {what} {words(layout[0])} ({layout[1]}), but the data say "
                        f"{words(seen)} ({evidence}); give {option} to say which")
    if user is not None:
        return user, condition(user, STATED_BY_USER, statistic=stat, margin=margin, evidence=evidence,
                               overrides="; ".join(overridden) or None)
    if layout is not None:
        return layout[0], condition(layout[0], STATED_IN_FILE, statistic=stat, margin=margin,
                                    evidence=layout[1] + (f"; the data agree: {evidence}" if evidence else ""))
    if seen is not None:
        return seen, condition(seen, INFERRED, statistic=stat, margin=margin, evidence=evidence)
    return None, condition(UNKNOWN, UNKNOWN, statistic=stat, margin=margin, evidence=evidence)


def _sketch_words(v: str) -> str:
    return f"{v} ({SKETCHES[v]['sketch']})" if v in SKETCHES else str(v)


def import_tfm(
    file: Path | str,
    out: Path | str,
    *,
    signs: Sequence[int] | None = None,
    run_dir: Path | None = None,
    sketch: str | None = None,
    direction: str | None = None,
    where: str | None = None,
    force: bool = False,
) -> Path:
    """Convert one 2019 TFM .mat file into a run directory under `out`; returns its path.

    Each condition the log does not state is read off the data or kept unknown, and recorded in
    run.json `conditions` with how it was decided (docs/run-format.md):

    - `where` ("air" or "floor"): stated by the sweep, square-wave and RC layouts (the data
      README's in-air logs); the floor-run layout states nothing, so there it is read off the
      wheels' dynamics (`where_from_dynamics`), else unknown (run.json `mode` null);
    - `sketch` ("square" or "rc": the 2019 sketch, hence the command timing): stated by the RC
      layout; otherwise read off the loop period (`loop_sketch`), else unknown (the analysis
      profiles over both); a sweep's is assumed the square-wave sketch's (its steady speeds do
      not depend on it);
    - the sign map (`signs`): read off the data for the square-wave and RC layouts (the two
      sketches wrote different signs), the thesis's corrected signs for the sweep and floor runs;
    - `direction` (forward, sideways, rotation, diagonal) of a floor-run layout: read off the data.

    An option that the layout or the data contradict is refused in one line naming both, unless
    `force` (then the option wins, and the record says what it overrode). `signs` is applied as
    given (the data's reading recorded beside it)."""
    file = Path(file)
    if sketch is not None and sketch not in SKETCHES:
        raise UserError(f"unknown sketch {sketch!r}: give one of {', '.join(SKETCHES)}")
    if direction is not None and direction not in DIRECTIONS:
        raise UserError(f"unknown direction {direction!r}: give one of {', '.join(DIRECTIONS)}")
    if where is not None and where not in WHERE_MODES:
        raise UserError(f"unknown --where {where!r}: give one of {', '.join(WHERE_MODES)}")
    data = _load(file)
    try:
        kind = kind_of(data)
    except UserError as exc:
        raise UserError(f"{file}: {exc}") from None
    opts: dict[str, Any] = {"sketch": sketch, "where": where, "force": force}
    if kind == "jacked":
        return _import_jacked(file, data, Path(out), signs, run_dir, sketch=sketch, where=where, force=force)
    if kind == "ground":
        return _import_ground(file, data, Path(out), signs, run_dir, direction=direction, sketch=sketch,
                              where=where, force=force)
    if kind == "rc":
        d = np.asarray(data["data"], dtype=float)
        millis, value, counts = d[0].astype(np.int64), d[1], d[2:6].astype(np.int64)
        cmd = np.trunc(127 * value).astype(np.int64)  # the sketch: command = trunc(127 x value)
        return _import_logged(file, kind, Path(out), run_dir, cmd, millis / 1000.0, counts, signs, opts)
    d = np.asarray(data["data"]).astype(np.int64)
    return _import_logged(file, kind, Path(out), run_dir, d[0], d[1] / 1000.0, d[3:7], signs, opts)


def unknown_timing(why: str | None = None) -> dict[str, Any]:
    """The firmware timing of a log whose sketch is not known: sketch "unknown", the documented
    sketches it may be (`profiled_over`), replayed with the square-wave sketch's timing unless the
    analysis profiles over the others (`alternatives`). `why`: what the data showed."""
    other = {k: RC_SKETCH[k] for k in ("sketch", "command_order", "commands", "command_offset_s")}
    return {**SQUARE_SKETCH, "sketch": UNKNOWN_SKETCH, "default_sketch": SQUARE_SKETCH["sketch"],
            "profiled_over": [SQUARE_SKETCH["sketch"], RC_SKETCH["sketch"]],
            "source": "assumed for replay (the square-wave sketch's timing): neither the file nor its loop tells "
                      f"the sketch ({why or 'the data README names none'}); the analysis profiles over the "
                      "documented sketches; give --sketch if you know",
            "alternatives": [other]}


def _timing(key: str | None, cond: dict[str, Any], loop_text: str) -> dict[str, Any]:
    """The run's firmware_timing for the decided sketch (None: unknown)."""
    if key is None:
        return unknown_timing(loop_text)
    if cond["decided"] == STATED_BY_USER:
        return {**SKETCHES[key], "source": "given at import"}
    if cond["decided"] == INFERRED and key != "square":
        return {**SKETCHES[key], "source": f"read off the data: {loop_text}"}
    return dict(SKETCHES[key])


def _sketch_condition(file: Path, kind: str, t: np.ndarray, sketch: str | None,
                      force: bool) -> tuple[str | None, dict[str, Any], str]:
    seen, stat, text = loop_sketch(t)
    margin = {"loop_s": dict(LOOP_S), "tolerance_s": LOOP_TOLERANCE_S}
    key, cond = _decide(file, "the sketch is", "--sketch", sketch, LAYOUT_STATES.get(kind, {}).get("sketch"),
                        (seen, stat, text, margin), force, _sketch_words)
    return key, cond, text


def _sign_condition(cmd_pattern: np.ndarray, counts: np.ndarray, signs: Sequence[int] | None,
                    layout: tuple[int, ...] | None, why: str) -> tuple[tuple[int, ...], dict[str, Any]]:
    """The sign map: the user's (applied as given), the layout's (`layout`, with `why`), or read
    off the data (`data_signs`); the data's per-wheel agreement recorded as the statistic."""
    dc = np.diff(np.asarray(counts, dtype=float), axis=1)
    du = np.asarray(cmd_pattern, dtype=float)[:, :-1]
    num, den = np.sum(du * dc, axis=1), np.sum(np.abs(du * dc), axis=1)
    agree = [float(n / d) if d > 0 else None for n, d in zip(num, den)]
    stat = {"agreement": agree}
    text = ("each wheel's logged travel against its command, sum(u dcount)/sum(|u dcount|) = "
            + ", ".join("--" if a is None else f"{a:+.2f}" for a in agree) + " (FL, FR, RL, RR)")
    if signs is not None:
        return tuple(signs), condition(list(signs), STATED_BY_USER, statistic=stat, evidence=text)
    if layout is not None:
        return layout, condition(list(layout), STATED_IN_FILE, statistic=stat, evidence=f"{why}; the data: {text}")
    if any(a is None or a == 0 for a in agree):
        raise UserError("cannot read the wheel signs off the data (a wheel never turned with the "
                        "command): give --signs")
    sgn = tuple(int(np.sign(a)) for a in agree if a is not None)
    return sgn, condition(list(sgn), INFERRED, statistic=stat, evidence=text)


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


def _import_jacked(file: Path, data: dict[str, Any], out: Path, signs: Sequence[int] | None,
                   run_dir: Path | None, *, sketch: str | None = None, where: str | None = None,
                   force: bool = False) -> Path:
    ws = np.asarray(data["ws"], dtype=float)
    amps = np.asarray(data["amps"]).ravel().astype(int)
    if ws.shape[0] != 4 or ws.shape[1] != amps.size:
        raise UserError(f"{file}: `ws` should be 4 x {amps.size}, is {ws.shape[0]} x {ws.shape[1]}")
    run_cols = np.where(~np.all(np.isnan(ws), axis=0))[0]
    t = np.asarray(data.get("t", np.empty((1, 0))), dtype=float).ravel()
    x = np.asarray(data.get("x", np.empty((1, 0))), dtype=float).ravel()
    m = np.asarray(data.get("m", np.empty((4, 0))), dtype=float)
    where_v, where_c = _decide(file, "the robot was", "--where", where, LAYOUT_STATES["jacked"]["where"], None, force,
                               _where_words)
    if where_v == "floor":
        raise UserError(f"{file}: a sweep of steady speeds ({LAYOUT_STATES['jacked']['where'][1]}) is analysed in "
                        "the air only: it cannot be imported as on the floor")
    seen, stat, loop_text = loop_sketch(t) if t.size > 1 else (None, None, "no raw samples")
    if sketch is not None:
        sk_c = condition(sketch, STATED_BY_USER, statistic=stat, evidence=loop_text)
        timing = {**SKETCHES[sketch], "source": "given at import"}
    else:
        sk_c = condition("square", ASSUMED, statistic=stat, evidence=loop_text,
                         note="a sweep is fitted on its steady speeds, which do not depend on the command timing: "
                              "the square-wave sketch's is kept for the record")
        timing = SQUARE_SKETCH
    sgn_t = tuple(signs) if signs is not None else JACKED_SIGNS
    sign_c = condition(list(sgn_t), STATED_BY_USER if signs is not None else STATED_IN_FILE,
                       evidence=None if signs is not None else "the thesis scripts had corrected the signs of `ws` "
                                                                "and the raw counts (every one positive)")
    sgn = np.asarray(sgn_t, dtype=float)
    last_cmd = None
    if x.size:
        last_cmd = int(round(float(np.median(x)) * 127))
    w = RunWriter.create(
        out, "upside_down_sweep", run_dir=run_dir, name=Path(file).stem, counts_per_rev=COUNTS_PER_REV,
        extra={**_base_extra(file, sgn_t, "results_jacked", timing), "mode": "upside_down",
               "conditions": {"where": where_c, "sketch": sk_c, "signs": sign_c},
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


def _import_logged(file: Path, kind: str, out: Path, run_dir: Path | None, cmd: np.ndarray, t: np.ndarray,
                   counts: np.ndarray, signs: Sequence[int] | None, opts: dict[str, Any]) -> Path:
    """A square-wave (7-row) or RC (6-row) log: the sketch from the layout or the loop, the signs
    off the data (the two sketches wrote different ones), where from the layout."""
    if np.any(np.diff(t) <= 0):
        raise UserError(f"{file}: the time stamps are not increasing")
    key, sk_c, loop_text = _sketch_condition(file, kind, t, opts["sketch"], opts["force"])
    try:
        sgn, sign_c = _sign_condition(np.repeat(np.asarray(cmd)[None, :], 4, axis=0), counts, signs, None, "")
    except UserError as exc:
        raise UserError(f"{file}: {exc}") from None
    where_v, where_c = _decide(file, "the robot was", "--where", opts["where"], LAYOUT_STATES[kind]["where"], None,
                               opts["force"], _where_words)
    assert where_v is not None, "these layouts state where"
    timing = _timing(key, sk_c, loop_text)
    conditions = {"where": where_c, "sketch": sk_c, "signs": sign_c}
    source = "square_wave" if kind == "square" else "rc_log"
    extra = {**_base_extra(file, sgn, source, timing), "mode": WHERE_MODES[where_v], "conditions": conditions,
             "sign_map_source": "given" if signs else "read off the data (speed against command)"}
    here = "wheels in the air" if where_v == "air" else "robot on the floor"
    if kind == "square":
        notes = (f"Square-wave command on all four motors, {here}. "
                 "Time is Arduino millis()/1000 (irregular 17-45 ms sampling).")
        return _import_trace(file, out, run_dir, "step_response", cmd, t, counts, sgn, extra, "step_response", notes)
    notes = (f"Hand-driven (RC transmitter) command on all four motors, {here}: "
             "each step holds one command level, not a square wave. Time is millis()/1000.")
    return _import_trace(file, out, run_dir, "random_duty", cmd, t, counts, sgn, extra, "duty_hold", notes)


def _import_ground(file: Path, data: dict[str, Any], out: Path, signs: Sequence[int] | None,
                   run_dir: Path | None, *, direction: str | None = None, sketch: str | None = None,
                   where: str | None = None, force: bool = False) -> Path:
    t = np.asarray(data["t"], dtype=float).ravel()
    x = np.asarray(data["x"], dtype=float).ravel()
    m = np.asarray(data["m"], dtype=float)
    if m.shape != (4, t.size) or x.size != t.size:
        raise UserError(f"{file}: `m` should be 4 x {t.size} like `t` and `x`, is {m.shape}")
    if np.any(np.diff(t) <= 0):
        raise UserError(f"{file}: the time stamps are not increasing")
    counts = np.round(m * COUNTS_PER_REV).astype(np.int64)
    cmd = np.round(x * 127).astype(np.int64)
    sgn_t = tuple(signs) if signs is not None else JACKED_SIGNS
    signed = counts * np.asarray(sgn_t, dtype=np.int64)[:, None]
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
    key, sk_c, loop_text = _sketch_condition(file, "ground", t, sketch, force)
    # where: the layout does not say (an in-air sweep can be saved in it): the wheels' dynamics
    offsets = [cast(float, SKETCHES[k]["command_offset_s"]) for k in ([key] if key else list(SKETCHES))]
    duty = np.asarray(pattern, dtype=float)[None, :] * (cmd / 127.0)[:, None]
    phi = (signed * (2 * math.pi / COUNTS_PER_REV)).T
    w_val, w_stat, w_text = where_from_dynamics(t, duty, phi, offsets=offsets)
    where_v, where_c = _decide(file, "the robot was", "--where", where, None, (w_val, w_stat, w_text, WHERE_MARGIN),
                               force, _where_words)
    pat_text = f"the wheels travel with signs {DIRECTIONS[seen]} against the drive value" if seen else None
    conditions = {
        "where": where_c, "sketch": sk_c,
        "signs": condition(list(sgn_t), STATED_BY_USER if signs is not None else STATED_IN_FILE,
                           evidence=None if signs is not None else "the floor-run layout's sketch had corrected the "
                                                                   "signs (FR, BR encoders, FL, FR commands)"),
        "direction": condition(direction, STATED_BY_USER if given else INFERRED, evidence=pat_text,
                               statistic={"travel_signs": list(DIRECTIONS[seen])} if seen else None,
                               margin={"travel_share": 0.1}),
    }
    timing = _timing(key, sk_c, loop_text)
    gains = {k: np.asarray(data[k], dtype=float).tolist() for k in ("Ks", "fits", "Ts") if k in data}
    mode = WHERE_MODES[where_v] if where_v else None
    extra = {**_base_extra(file, sgn_t, "results_ground", timing), "mode": mode, "fitted_gains": gains,
             "conditions": conditions,
             "direction": direction, "wheel_pattern": list(pattern),
             "direction_source": "given at import" if given else "read off the data",
             "fitted_gains_note": "2019 per-amplitude process-model fits: Ks wheel rev/s per unit duty, "
                                  "fits percent (NaN where not run), Ts time constants (s)"}
    here = {"floor": f"Robot on the floor driving {direction} and back", "air": "Wheels in the air",
            None: "Robot on the floor or in the air (unknown: see conditions.where)"}[where_v]
    return _import_trace(file, out, run_dir, "step_response", cmd, t, counts, sgn_t, extra, "step_response",
                         f"{here} (square wave of the drive value, each wheel's duty = {list(pattern)} x the drive "
                         f"value); raw log of the last square wave of {Path(file).name}.", pattern=pattern)


def data_signs(drive: np.ndarray, counts: np.ndarray) -> tuple[int, ...]:
    """Per-wheel sign map read off a log: the sign of each wheel's speed against the command."""
    dc = np.diff(counts, axis=1).astype(float)
    corr = dc @ np.asarray(drive, dtype=float)[:-1]
    if np.any(corr == 0):
        raise UserError("cannot read the wheel signs off the data (a wheel never turned with the "
                        "command): give --signs")
    return tuple(int(v) for v in np.sign(corr))


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
