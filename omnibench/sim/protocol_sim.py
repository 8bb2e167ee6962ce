"""pyserial URL handler `sim://`: the simulated Omnibot (or its ammeter) in this process.

Registered by `omnibench.sim.register()` (which appends "omnibench.sim" to
`serial.protocol_handler_packages`); pyserial then imports this module for any `sim://`
URL and uses its `Serial` class, so the tool's real serial code path runs against the
simulator. URL parameters are documented in docs/simulator.md, e.g.

    sim://omnibot?seed=3&mode=upside_down&clock=fast&drop=0.01
    sim://ammeter?board=rig1            (the SCPI ammeter on the board named rig1)

Clocks: `fast` (default) moves simulated time only when the host waits in `read` for bytes
that are not there yet: the board jumps to its next telemetry frame (running the watchdog
and scheduled faults on the way), so a procedure of minutes runs in seconds and the host
never loses a frame. With telemetry off, time follows the wall clock (times `speed`). `realtime`
follows the wall clock (times `speed`).
"""

from __future__ import annotations

import threading
import time

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from omnibench.errors import UserError
from omnibench.sim import registry
from omnibench.sim.ammeter import SimAmmeter
from omnibench.sim.board import SimBoard
from omnibench.sim.world import world_from_url

_POLL_S = 0.002  # wall-clock granularity of waiting in realtime mode


class Serial(SerialBase):
    """A pyserial port whose other end is a `SimBoard` or a `SimAmmeter` in this process."""

    def __init__(self, *args, **kwargs) -> None:
        self.board: SimBoard | None = None
        self.ammeter: SimAmmeter | None = None
        self._rx = bytearray()
        self._lock = threading.RLock()  # reader and heartbeat writer may be different threads
        super().__init__(*args, **kwargs)

    # ------------------------------------------------------------------ open / close
    def open(self) -> None:
        if self.is_open:  # type: ignore[has-type]
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        try:
            device, world, extra = world_from_url(self.portstr)
        except UserError as exc:
            err = SerialException(str(exc))
            err.bad_input = True  # a wrong URL: the opener says so, exit 2
            raise err from exc
        self.world = world
        self._wall_anchor: float | None = None
        if device == "ammeter":
            name = extra.get("board")
            board = registry.get(name) if name else registry.latest()
            if board is None:
                raise SerialException(f"{self.portstr}: no simulated board named {name!r} is open in this process")
            self.ammeter = SimAmmeter(board, noise=float(extra.get("noise", 0.002)),
                                      lsb=float(extra.get("lsb", 1e-4)), seed=int(extra.get("seed", world.seed)))
        else:
            self.board = SimBoard(world)
            registry.register(world.name, self.board)
            self.board.set_host_baud(self._baudrate)
        self._rx.clear()
        self._t0 = time.monotonic()  # board time 0 = now (after building the board)
        self.is_open = True

    def close(self) -> None:
        # Like unplugging a cable: the board keeps its state (its watchdog stops the motors).
        self.is_open = False
        super().close()

    def _reconfigure_port(self) -> None:
        if self.board is not None:
            self.board.set_host_baud(self._baudrate)

    # ------------------------------------------------------------------ time
    @property
    def fast(self) -> bool:
        return self.world.clock == "fast"

    def _wall_clock_us(self) -> int:
        return int((time.monotonic() - self._t0) * self.world.speed * 1e6)

    def _sync(self) -> None:
        """Realtime: bring the board up to the wall clock. Then collect its output."""
        b = self.board
        if b is None:
            return
        if not self.fast:
            b.advance_to(max(self._wall_clock_us(), b.clock_us))
        self._rx += b.take_output()
        if b.disconnected and not self._rx:
            raise SerialException(f"{self.portstr}: device disconnected (simulated cable pulled)")

    def _step_fast(self) -> bool:
        """Fast clock: jump to the board's next output (True), or, with nothing
        scheduled, let simulated time follow the wall clock since the last call (False)."""
        b = self.board
        nxt = b.next_output_us()
        if nxt is not None:
            self._wall_anchor = None
            b.advance_to(max(nxt, b.clock_us))
            return True
        now = time.monotonic()
        if self._wall_anchor is not None:
            b.advance_to(b.clock_us + int((now - self._wall_anchor) * self.world.speed * 1e6))
        self._wall_anchor = now
        return False

    # ------------------------------------------------------------------ pyserial API
    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        if self.ammeter is not None:
            with self._lock:
                self._rx += self.ammeter.take_output()
                return len(self._rx)
        with self._lock:
            self._sync()
            return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        if self.ammeter is not None:
            return self._read_ammeter(size)
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        while True:
            with self._lock:
                self._sync()
                if len(self._rx) >= size:
                    break
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    break
                wait = min(_POLL_S, remaining) if remaining is not None else _POLL_S
                if self.fast and self._step_fast():
                    continue
            time.sleep(wait)
        with self._lock:
            data = bytes(self._rx[:size])
            del self._rx[:size]
            return data

    def write(self, data) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        data = bytes(data)
        if self.ammeter is not None:
            self.ammeter.feed(data)
            return len(data)
        with self._lock:
            self._sync()
            self.board.feed(data)
        return len(data)

    def _read_ammeter(self, size: int) -> bytes:
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        while True:
            with self._lock:
                self._rx += self.ammeter.take_output()
                if len(self._rx) >= size:
                    break
            if deadline is not None and time.monotonic() >= deadline:
                break
            time.sleep(_POLL_S)
        with self._lock:
            data = bytes(self._rx[:size])
            del self._rx[:size]
            return data

    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        self._sync() if self.board is not None else None
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    @property
    def out_waiting(self) -> int:
        return 0

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
