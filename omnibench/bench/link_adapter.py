"""Adapts the board client of omnibench.link (`Board`) to the runner's `BenchBoard` interface.

The client unwraps the board clock, checks every frame's board time and detects a lost link
or a board reset. It is opened without its own heartbeat: the runner feeds the watchdog from
its loop (`keepalive`), so a hung runner lets the board stop the motors. This adapter only
reshapes: one sample at a time, identity as a dict, pose as a tuple, command times.
"""

from __future__ import annotations

import contextlib
import math
from collections import deque
from collections.abc import Iterator, Sequence
from typing import Any

from omnibench.bench.board import BenchBoard, Telemetry


@contextlib.contextmanager
def open_bench_board(url: str, timeout: float | None = None, ammeter: str | None = None) -> Iterator[BenchBoard]:
    """Open the board at `url` (serial device, `sim://...`) as a BenchBoard, with an optional
    SCPI ammeter on its own serial URL for the battery current; motors stopped on exit."""
    with LinkBoard.open(url, timeout=timeout, ammeter=ammeter) as board:
        yield board  # type: ignore[misc]


class LinkBoard:
    """A `BenchBoard` over `omnibench.link.board.Board`."""

    def __init__(self, board: Any) -> None:
        self.board = board
        hello = board.hello
        self.hello: dict[str, Any] = hello.as_dict() if hello is not None else {}
        caps = set(hello.capabilities) if hello is not None else set()
        self.is_simulator = "SIMULATOR" in caps
        self.has_battery_current = "BATTERY_CURRENT" in caps
        self.has_motor_current = "MOTOR_CURRENT" in caps
        #: the duties reach the motors through the project's firmware's packet-serial drivers
        #: (rounded and sent one packet per wheel: omnibench/model/actuation.toml)
        self.packet_serial_drivers = "PACKET_SERIAL_DRIVERS" in caps
        self._buf: deque[Any] = deque()
        self.ammeter_attached = False

    @classmethod
    @contextlib.contextmanager
    def open(cls, url: str, timeout: float | None = None, ammeter: str | None = None,
             ammeter_period: float = 0.05) -> Iterator["LinkBoard"]:
        """Open `url` with the link client (and the SCPI ammeter at `ammeter`, read every
        `ammeter_period` s of board time); leaving the block stops the motors and closes both.
        `timeout` None: the link's handshake default (covers a Mega's reset and bootloader)."""
        from omnibench.link.board import HANDSHAKE_TIMEOUT_S, Board

        with Board.open(url, timeout=HANDSHAKE_TIMEOUT_S if timeout is None else timeout,
                        heartbeat=False) as board:
            lb = cls(board)
            meter = None
            if ammeter:
                from omnibench.link.ammeter import open_ammeter

                meter = open_ammeter(ammeter)
                board.attach_ammeter(meter, ammeter_period)
                lb.ammeter_attached = True
                lb.has_battery_current = True
                lb.hello["ammeter"] = {"url": ammeter, "idn": meter.idn, "period_s": ammeter_period}
            try:
                yield lb
            finally:
                if meter is not None:
                    board.attach_ammeter(None)
                    meter.close()

    def _drain(self) -> None:
        """Take the telemetry already waiting on the port before sending a command.

        Why: the client waits for a command's ACK for a limited span of *board* time; if the
        host has fallen behind (a slow disk flush, a busy machine), old telemetry still queued
        on the port would use up that span before the ACK behind it is read. The drained
        samples are kept and handed out by `read` in order: nothing is lost.
        """
        self._buf.extend(self.board.read_samples())

    def configure(self, *, telemetry_hz: float, watchdog_s: float) -> None:
        self._drain()
        self.board.configure(telemetry_hz=int(round(telemetry_hz)), watchdog_s=watchdog_s)

    def latched_faults(self, timeout: float = 2.0) -> int:
        """Fault bits the board has latched now (from the next sample; telemetry must be on)."""
        s = self.read(timeout)
        self._buf.appendleft(s)
        return int(s.faults)

    def clear_faults(self) -> None:
        """Clear latched faults (only with the operator's consent: the runner asks)."""
        self._drain()
        self.board.clear_faults()

    def reset_encoders(self) -> None:
        self._drain()
        self.board.reset_encoders()

    def set_duties(self, duties: Sequence[float]) -> float:
        self._drain()
        return self.board.set_duties(duties)

    def stop(self) -> float | None:
        try:
            self._drain()
        finally:
            t = self.board.stop()
        return t

    def keepalive(self) -> None:
        """PING the board without waiting for the ACK (feeds its watchdog)."""
        self.board.keepalive()

    @property
    def link_stats(self) -> dict[str, Any]:
        """The link's counters (frames, lost, CRC errors, time faults, retries), JSON-ready."""
        return self.board.stats.as_dict()

    def read(self, timeout: float) -> Telemetry:
        """The next sample (the client raises BoardError if the link is lost)."""
        while not self._buf:
            for s in self.board.samples(0.0):
                self._buf.append(s)
        s = self._buf.popleft()
        ib: float | None = s.battery_current
        if self.ammeter_attached:
            # the external ammeter is the battery current; it reads every ammeter period, so
            # samples between its readings have no battery current (left empty, never mixed)
            am = getattr(s, "ammeter_current", math.nan)
            ib = None if am is None or math.isnan(am) else float(am)
        elif not self.has_battery_current:
            ib = None
        return Telemetry(
            t=s.t, seq=s.seq, encoder=tuple(s.encoder),
            motor_current=tuple(s.motor_current) if self.has_motor_current else None,
            battery_voltage=s.battery_voltage, battery_current=ib, faults=int(s.faults),
            duty=tuple(s.duty),
        )

    def discard_pending(self) -> int:
        n = len(self._buf) + len(self.board.read_samples())
        self._buf.clear()
        return n

    def sim_set_world(self, *, mode: str | None = None, payload: float | None = None,
                      wheel_mass: Sequence[float] | None = None) -> None:
        self._drain()
        self.board.sim_set_world(mode=mode, payload=payload, wheel_mass=wheel_mass)

    def sim_truth(self) -> tuple[float, float, float]:
        self._drain()
        p = self.board.sim_truth()
        return (p.x, p.y, p.psi)
