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


def parse_signs(text: str) -> tuple[int, int, int, int]:
    """'+1,-1,+1,-1' -> (1, -1, 1, -1); a one-line UserError otherwise."""
    parts = [p.strip() for p in text.split(",")]
    try:
        vals = tuple(int(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 4 or any(v not in (1, -1) for v in vals):
        raise UserError(f"--signs {text!r}: give four signs, one per wheel FL,FR,RL,RR, e.g. +1,-1,+1,-1")
    return vals  # type: ignore[return-value]


def _load(path: Path) -> dict[str, Any]:
    import scipy.io

    if not path.is_file():
        raise UserError(f"{path}: no such file")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return scipy.io.loadmat(str(path))
    except Exception as exc:  # scipy raises several types for non-MAT input
        raise UserError(f"{path}: not a MATLAB v5 file scipy can read ({type(exc).__name__})") from None


def kind_of(data: dict[str, Any]) -> str:
    """'jacked' (has ws/amps) or 'square' (has a 7-row `data`)."""
    if "ws" in data and "amps" in data:
        return "jacked"
    d = data.get("data")
    if d is not None and getattr(d, "ndim", 0) == 2 and d.shape[0] == 7 and d.shape[1] > 1:
        return "square"
    raise UserError("file holds neither `ws`/`amps` (jacked sweep) nor a 7-row `data` (square wave)")


def import_tfm(
    file: Path | str,
    out: Path | str,
    *,
    signs: Sequence[int] | None = None,
    run_dir: Path | None = None,
) -> Path:
    """Convert one 2019 TFM .mat file into a run directory under `out`; returns its path."""
    file = Path(file)
    data = _load(file)
    try:
        kind = kind_of(data)
    except UserError as exc:
        raise UserError(f"{file}: {exc}") from None
    if kind == "jacked":
        return _import_jacked(file, data, Path(out), tuple(signs or JACKED_SIGNS), run_dir)
    return _import_square(file, data, Path(out), tuple(signs or RAW_SIGNS), run_dir)


def _base_extra(file: Path, signs: Sequence[int], kind: str) -> dict[str, Any]:
    return {
        "source": SOURCE,
        "source_file": str(file),
        "source_kind": kind,
        "sign_map": list(signs),
        "supply_voltage": SUPPLY_V,
        "imported": True,
    }


def _import_jacked(file: Path, data: dict[str, Any], out: Path, signs: tuple[int, ...],
                   run_dir: Path | None) -> Path:
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
        out, "upside_down_sweep", run_dir=run_dir, counts_per_rev=COUNTS_PER_REV,
        extra={**_base_extra(file, signs, "results_jacked"),
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
                   run_dir: Path | None) -> Path:
    d = np.asarray(data["data"]).astype(np.int64)
    cmd, millis, counts = d[0], d[1], d[3:7]
    if np.any(np.diff(millis) <= 0):
        raise UserError(f"{file}: `data` row 2 (millis) is not increasing")
    sgn = np.asarray(signs, dtype=np.int64)
    # steps: maximal runs of constant command
    edges = np.flatnonzero(np.diff(cmd) != 0) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [cmd.size]])
    w = RunWriter.create(
        out, "step_response", run_dir=run_dir, counts_per_rev=COUNTS_PER_REV,
        extra={**_base_extra(file, signs, "square_wave"),
               "steps_planned": int(starts.size),
               "notes": "Square-wave command on all four motors, wheels in the air. "
                        "Time is Arduino millis()/1000 (irregular 17-45 ms sampling)."},
    )
    with w:
        w.event("import", source_file=str(file))
        for k, (a, b) in enumerate(zip(starts, ends)):
            duty = float(cmd[a]) / 127.0
            w.event("step_start", t=millis[a] / 1000.0, step=k, duty=duty)
            for n in range(a, b):
                row = {"step": k, "t": millis[n] / 1000.0, "seq": n,
                       **{f"u{j + 1}": float(cmd[n]) / 127.0 for j in range(4)},
                       **{f"enc{j + 1}": int(sgn[j] * counts[j, n]) for j in range(4)}}
                w.sample(row)
            w.event("step_end", t=millis[b - 1] / 1000.0, step=k)
            w.step_complete({
                "step": k, "kind": "step_response", "command": int(cmd[a]), "duty": duty,
                "voltage": duty * SUPPLY_V, **{f"u{j + 1}": duty for j in range(4)},
                "t_start": millis[a] / 1000.0, "t_end": millis[b - 1] / 1000.0,
                "n_samples": int(b - a),
            })
    return w.path
