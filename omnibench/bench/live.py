"""The live view while a procedure runs: a terminal table (rich) of the step, duties, wheel speeds,
motor currents, battery, faults and the time left, and optionally a live matplotlib plot.

The runner calls `sample(step, telemetry)` for every sample, `pause()` before a person is asked
anything (the table stops redrawing so the prompt is readable) and `advance(dt)` as board time
passes. Drawing is throttled to a few times a second of wall time.
"""

from __future__ import annotations

import math
import os
import sys
import time
from typing import Any

from omnibench.bench.prompts import WHEELS

REFRESH_S = 0.25  #: wall seconds between two redraws


def display_available() -> bool:
    """Is there a screen for a matplotlib window (X11 or Wayland)?"""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class LiveView:
    """Table of the latest sample on stderr; `total` board seconds planned for the ETA."""

    def __init__(self, title: str, total: float, n_steps: int, counts_per_rev: float, plot: bool = False,
                 stream: Any = None) -> None:
        from rich.console import Console

        self.title, self.total, self.n_steps, self.cpr = title, float(total), n_steps, float(counts_per_rev)
        self.console = Console(file=stream or sys.stderr)
        self.done = 0.0
        self._live: Any = None
        self._prev: Any = None
        self._speeds = [0.0] * 4
        self._last_draw = 0.0
        self._step: Any = None
        self._sample: Any = None
        self._started = time.monotonic()
        self._paused_at: float | None = None  # wall time a prompt began (None: running)
        self._paused_total = 0.0  # wall seconds spent at prompts: not the robot's work, not in the ETA
        self._plot = _Plot() if plot else None

    # -- runner hooks -----------------------------------------------------------------------
    def advance(self, dt: float, label: str = "") -> None:
        self.done += dt

    def sample(self, step: Any, s: Any) -> None:
        if self._paused_at is not None:  # the prompt was answered: the robot works again
            self._paused_total += time.monotonic() - self._paused_at
            self._paused_at = None
        if self._prev is not None and s.t > self._prev.t and step is self._step:
            k = 2 * math.pi / self.cpr / (s.t - self._prev.t)
            w = [(a - b) * k for a, b in zip(s.encoder, self._prev.encoder)]
            self._speeds = [0.8 * o + 0.2 * n for o, n in zip(self._speeds, w)]  # ~50 ms smoothing at 100 Hz
        self._prev, self._step, self._sample = s, step, s
        if self._plot is not None:
            self._plot.add(s.t, self._speeds)
        now = time.monotonic()
        if now - self._last_draw >= REFRESH_S:
            self._last_draw = now
            self._draw()

    def pause(self) -> None:
        """Stop redrawing (a prompt follows); the next sample starts the table again. The time
        until then is a person's, not the procedure's: it is left out of the ETA."""
        if self._paused_at is None:
            self._paused_at = time.monotonic()
        if self._live is not None:
            self._live.stop()
            self._live = None
        self._prev = None

    def close(self) -> None:
        self.pause()
        if self._plot is not None:
            self._plot.close()

    # -- drawing ------------------------------------------------------------------------------
    def eta(self) -> float | None:
        """Wall seconds left, from the rate board time has advanced so far, time at prompts left
        out (None at the start)."""
        now = time.monotonic()
        waiting = self._paused_total + (now - self._paused_at if self._paused_at is not None else 0.0)
        spent = now - self._started - waiting
        if self.done <= 0 or spent <= 0:
            return None
        return max(self.total - self.done, 0.0) * spent / self.done

    def table(self) -> Any:
        from rich.table import Table

        s, step = self._sample, self._step
        eta = self.eta()
        head = (f"{self.title}: step {step.index + 1}/{self.n_steps} {step.label}" if step is not None else self.title)
        t = Table(title=head, title_justify="left", expand=False)
        t.add_column("")
        for w in WHEELS:
            t.add_column(w, justify="right")
        if s is not None:
            t.add_row("duty", *(f"{u:+.3f}" for u in s.duty))
            t.add_row("speed rad/s", *(f"{w:+.2f}" for w in self._speeds))
            if s.motor_current is not None:
                t.add_row("current A", *(f"{i:+.2f}" for i in s.motor_current))
        batt = "" if s is None or s.battery_voltage is None else f"battery {s.battery_voltage:.2f} V"
        if s is not None and s.battery_current is not None:
            batt += f", {s.battery_current:.2f} A"
        faults = "" if s is None else ("faults: none" if not s.faults else f"FAULTS 0x{s.faults:02x}")
        board_t = "" if s is None else f"board time {s.t:.1f} s"
        left = f"{100 * min(self.done / self.total, 1):.0f} % done" if self.total > 0 else ""
        t.caption = "  ".join(x for x in (board_t, batt, faults, left,
                                          f"ETA {eta:.0f} s" if eta is not None else "") if x)
        t.caption_justify = "left"
        return t

    def _draw(self) -> None:
        if self._live is None:
            from rich.live import Live

            self._live = Live(self.table(), console=self.console, auto_refresh=False, transient=False)
            self._live.start()
        self._live.update(self.table(), refresh=True)


class _Plot:
    """A live matplotlib window of the four wheel speeds against board time."""

    def __init__(self) -> None:
        import matplotlib.pyplot as plt

        plt.ion()
        self.plt = plt
        self.fig, self.ax = plt.subplots(figsize=(7, 4))
        self.lines = [self.ax.plot([], [], label=w)[0] for w in WHEELS]
        self.ax.set_xlabel("board time (s)")
        self.ax.set_ylabel("wheel speed (rad/s)")
        self.ax.legend(loc="upper left")
        self.t: list[float] = []
        self.w: list[list[float]] = [[], [], [], []]
        self.last = 0.0

    def add(self, t: float, speeds: list[float]) -> None:
        self.t.append(t)
        for j in range(4):
            self.w[j].append(speeds[j])
        if len(self.t) > 3000:
            self.t, self.w = self.t[-2000:], [x[-2000:] for x in self.w]
        now = time.monotonic()
        if now - self.last > 0.5:
            self.last = now
            for j, ln in enumerate(self.lines):
                ln.set_data(self.t, self.w[j])
            self.ax.relim()
            self.ax.autoscale_view()
            self.plt.pause(0.001)

    def close(self) -> None:
        self.plt.close(self.fig)
