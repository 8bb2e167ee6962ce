"""`--plot`: the live matplotlib window of the wheel speeds (drawn here with the Agg backend,
since the test machine has no display), and the message when there is no display."""

from __future__ import annotations

import matplotlib
import numpy as np

from omnibench.bench import live


def test_the_window_shows_the_four_wheel_speeds_against_board_time(monkeypatch) -> None:
    matplotlib.use("Agg")
    monkeypatch.setattr(live.time, "monotonic", iter(np.arange(0.0, 100.0, 1.0)).__next__)  # redraw each sample
    plot = live._Plot()
    try:
        for k in range(5):
            plot.add(0.01 * k, [1.0 * k, -2.0 * k, 3.0 * k, -4.0 * k])
        for j, line in enumerate(plot.lines):
            x, y = line.get_data()
            assert np.allclose(x, [0.0, 0.01, 0.02, 0.03, 0.04])
            assert np.allclose(y, (j + 1) * (-1) ** j * np.arange(5.0))
        lo, hi = plot.ax.get_ylim()
        assert lo <= -16.0 and hi >= 12.0  # rescaled to the data
    finally:
        plot.close()


def test_no_display_is_said_and_the_terminal_view_stays(monkeypatch) -> None:
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert not live.display_available()
    monkeypatch.setenv("DISPLAY", ":0")
    assert live.display_available()
