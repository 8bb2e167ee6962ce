"""Simulated 2019 logs on the independent physics (omnibench/worlds/independent.py), written in
the files' own formats and sign maps so that they go through `import tfm`'s path: square-wave
logs in the air (7-row `data`, FR and BR encoders negated as the square-wave sketch logged them)
and floor runs (`t`, `x`, `m`, `Ks`: the drive value and each wheel's revolutions, signs as the
floor sketch corrected them) in any direction."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import scipy.io

from omnibench.model import Scenario
from omnibench.runs.tfm import COUNTS_PER_REV, DIRECTIONS, RAW_SIGNS
from omnibench.worlds.independent import simulate_batch


def sample_times(duration: float, seed: int, lo: float = 0.028, hi: float = 0.042) -> np.ndarray:
    """Irregular Arduino-like sample times (s), lo..hi apart, from 0."""
    rng = np.random.default_rng(seed)
    steps = rng.uniform(lo, hi, int(duration / lo) + 2)
    t = np.concatenate([[0.0], np.cumsum(steps)])
    return np.round(t[t <= duration], 3)  # millis()


def square_wave(t: np.ndarray, amplitude: float, period: float, start: float = 0.3) -> np.ndarray:
    """The drive value (-1..1, on the 1/127 grid) at each sample: 0 until `start`, then +/- amplitude."""
    x = np.where(t < start, 0.0, np.where(((t - start) // (period / 2)) % 2 == 0, amplitude, -amplitude))
    return np.round(x * 127) / 127


def simulate_counts(robot, mode: str, t: np.ndarray, U: np.ndarray, seed: int = 0) -> np.ndarray:
    """Encoder counts (B, 4, N) of each trajectory (duties U (B, N, 4), each acting from its
    sample on) on the independent physics, read at the sample times."""
    B = U.shape[0]
    res = simulate_batch(robot, [Scenario(mode=mode)] * B, t, U, float(t[-1]) + 0.01, dt=1e-3)
    out = np.zeros((B, 4, t.size))
    for j in range(4):
        phi = res.signal(f"phi{j + 1}")
        for b in range(B):
            out[b, j] = np.interp(t, res.t, phi[b])
    return np.round(out / (2 * math.pi) * COUNTS_PER_REV)


def write_square_log(path: Path, robot, amplitude: float, duration: float = 6.0, seed: int = 1) -> Path:
    """A square-wave log in the air as square.ino printed it (7 x N `data`)."""
    t = sample_times(duration, seed)
    x = square_wave(t, amplitude, 1.6)
    counts = simulate_counts(robot, "upside_down", t, np.repeat(x[None, :, None], 4, axis=2))[0]
    data = np.vstack([np.round(x * 127), np.round(t * 1000), np.zeros_like(t),
                      counts * np.asarray(RAW_SIGNS)[:, None]])
    scipy.io.savemat(str(path), {"data": data})
    return path


def floor_logs(folder: Path, robot, directions, amplitude: float = 0.5, duration: float = 6.0,
               seed: int = 2) -> dict[str, Path]:
    """One floor log per direction (results_ground format), all four simulated at once."""
    t = sample_times(duration, seed, 0.030, 0.040)
    x = square_wave(t, amplitude, 2.0)
    U = np.stack([np.asarray(DIRECTIONS[d], dtype=float)[None, :] * x[:, None] for d in directions])
    counts = simulate_counts(robot, "ground", t, U)
    out = {}
    for b, d in enumerate(directions):
        p = Path(folder) / f"sim_ground_{d}.mat"
        scipy.io.savemat(str(p), {"t": t[None], "x": x[None], "m": counts[b] / COUNTS_PER_REV,
                                  "Ks": np.full((4, 127), np.nan), "fits": np.full((4, 127), np.nan)})
        out[d] = p
    return out
