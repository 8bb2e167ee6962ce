"""Serve the simulated board on a pseudo-terminal, for other processes (or a person).

`omnibench sim serve` creates a pty pair, prints the slave's path (e.g. /dev/pts/5) and runs
the board until SIGINT/SIGTERM, then stops the motors and says so in the status file.
The host opens that path like any serial port (`Board.open("/dev/pts/5")`).

Clocks: `realtime` (default; `speed` scales it) or `fast`: the board emits its next frame
as soon as the host has read everything it sent (the server watches the slave's input
queue), so simulated time runs as fast as the host reads; while telemetry is off (a person at a
prompt) it follows the wall clock times `speed`, so a test can pause for minutes of board time.

The status file (JSON, replaced atomically) holds the board's duties, faults, boot id and
last command whenever they change, and `"serving": false` with the motors stopped on exit,
so a test can check that an interrupted procedure left the motors stopped.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import select
import signal
import sys
import termios
import threading
import time
import tty
from pathlib import Path
from typing import TextIO

from omnibench.sim.ammeter import SimAmmeter
from omnibench.sim.board import SimBoard
from omnibench.sim.world import World

STATUS_REFRESH_S = 0.05  #: the status file is rewritten at least this often (s): tests wait for a fresh one

_BAUD_OF = {getattr(termios, f"B{n}"): n for n in (9600, 19200, 38400, 57600, 115200, 230400, 460800, 921600)
            if hasattr(termios, f"B{n}")}
_MAX_PENDING = 65536   # bytes the board buffers for a host that does not read; older ones are lost
_TICK_S = 0.01         # longest sleep of the loop (realtime)


class _Pty:
    """One pseudo-terminal pair: the server keeps the master and one handle on the slave."""

    def __init__(self) -> None:
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        attrs = termios.tcgetattr(self.slave)
        attrs[4] = attrs[5] = termios.B115200
        termios.tcsetattr(self.slave, termios.TCSANOW, attrs)
        fl = fcntl.fcntl(self.master, fcntl.F_GETFL)
        fcntl.fcntl(self.master, fcntl.F_SETFL, fl | os.O_NONBLOCK)
        self.path = os.ttyname(self.slave)
        self.pending = bytearray()
        self.lost = 0

    def host_baud(self) -> int | None:
        """The speed the host set on its end (None if unknown)."""
        try:
            return _BAUD_OF.get(termios.tcgetattr(self.slave)[5])
        except termios.error:
            return None

    def unread(self) -> int:
        """Bytes written to the host that it has not read yet.

        A write to the master reaches the slave's read queue later, from a kernel worker; FIONREAD
        alone does not count bytes still on the way (it read 0 for a third of the frames just written,
        on an idle machine), so the fast clock ran ahead of the host, and under load its watchdog
        fired on a host that was feeding it. A poll of the slave first pushes those bytes into the queue (the
        tty line discipline flushes its pending buffer when a poll finds nothing)."""
        select.select([self.slave], [], [], 0)
        buf = bytearray(4)
        fcntl.ioctl(self.slave, termios.FIONREAD, buf)
        return int.from_bytes(buf, sys.byteorder)

    def send(self, data: bytes) -> None:
        """Queue and write what the host can take; drop the oldest beyond _MAX_PENDING."""
        self.pending += data
        if len(self.pending) > _MAX_PENDING:
            cut = len(self.pending) - _MAX_PENDING
            del self.pending[:cut]
            self.lost += cut
        while self.pending:
            try:
                n = os.write(self.master, self.pending[:4096])
            except BlockingIOError:
                return
            except OSError as exc:
                if exc.errno in (errno.EAGAIN, errno.EIO):
                    return
                raise
            del self.pending[:n]

    def receive(self) -> bytes:
        """Bytes the host wrote (empty if none)."""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass


class PtyServer:
    """The simulated board (and optionally its SCPI ammeter) on pseudo-terminals."""

    def __init__(self, world: World, *, status_file: str | Path | None = None, ammeter: bool = False,
                 log: TextIO | None = None, board=None) -> None:
        self.world = world
        self.board = board if board is not None else SimBoard(world)  # or a FirmwareBoard
        self.pty = _Pty()
        self.ammeter_pty = _Pty() if ammeter else None
        self.ammeter = SimAmmeter(self.board, seed=world.seed) if ammeter else None
        self.status_file = Path(status_file) if status_file else None
        self.log = log
        self.stop_event = threading.Event()
        self._last_status: tuple | None = None
        self._last_status_wall = 0.0
        self._baud: int | None = None
        self._closed_link = False

    @property
    def path(self) -> str:
        """The board's device path, e.g. /dev/pts/5."""
        return self.pty.path

    def _say(self, text: str) -> None:
        if self.log is not None:
            print(f"omnibench sim: t={self.board.time_us * 1e-6:.3f} s: {text}", file=self.log, flush=True)

    def write_status(self, serving: bool = True, force: bool = False) -> None:
        """Write the status file if the board's state changed (or `force`)."""
        if self.status_file is None:
            return
        st = self.board.status()
        key = (tuple(st["duties"]), tuple(st["faults"]), st["boot_id"], st["last_command"], st["mode"],
               st["payload"], st["disconnected"], serving)
        now = time.monotonic()
        if not force and key == self._last_status and now - self._last_status_wall < STATUS_REFRESH_S:
            return
        if key != self._last_status and self._last_status is not None:
            self._say(f"{st['last_command']}: duties {st['duties']} faults {st['faults'] or 'none'}")
        self._last_status, self._last_status_wall = key, now
        st.update(serving=serving, pid=os.getpid(), device=self.path,
                  ammeter=self.ammeter_pty.path if self.ammeter_pty else None, wall_time=time.time())
        tmp = self.status_file.with_name(self.status_file.name + ".tmp")
        tmp.write_text(json.dumps(st, indent=1) + "\n")
        os.replace(tmp, self.status_file)

    def serve(self) -> None:
        """Run until `stop_event` is set; then stop the motors and record it."""
        b, p = self.board, self.pty
        fast = self.world.clock == "fast"
        t0 = time.monotonic()
        wall_anchor = t0
        self.write_status(force=True)
        try:
            while not self.stop_event.is_set():
                self._check_baud()
                if fast:
                    now = time.monotonic()
                    nxt = b.next_output_us()
                    if nxt is None:  # telemetry off: time follows the wall clock (x speed)
                        b.advance_to(b.clock_us + int((now - wall_anchor) * self.world.speed * 1e6))
                    elif p.unread() == 0 and not p.pending:
                        b.advance_to(nxt)
                    wall_anchor = now
                else:
                    b.advance_to(max(b.clock_us, int((time.monotonic() - t0) * self.world.speed * 1e6)))
                if b.disconnected and not self._closed_link:
                    self._closed_link = True
                    self._say("simulated disconnect: closing the port")
                    os.close(p.master)
                    p.master = -1
                if not self._closed_link:
                    p.send(b.take_output())
                self._serve_ammeter()
                self.write_status()
                fds = [p.master] if not self._closed_link else []
                if self.ammeter_pty is not None:
                    fds.append(self.ammeter_pty.master)
                if fast and b.next_output_us() is not None:
                    timeout = 0.0002
                else:
                    nxt = b.next_event_us()
                    timeout = _TICK_S
                    if nxt is not None and not fast:
                        timeout = min(_TICK_S, max(0.0, (nxt - b.clock_us) * 1e-6 / self.world.speed))
                r, _, _ = select.select(fds, [], [], timeout) if fds else (time.sleep(timeout), [], [])  # type: ignore[func-returns-value]
                for fd in r or []:
                    if fd == p.master:
                        data = p.receive()
                        if data:
                            self._check_baud()  # the host sets its speed before it writes
                            if not fast:
                                b.advance_to(max(b.clock_us, int((time.monotonic() - t0) * self.world.speed * 1e6)))
                            b.feed(data)
                    elif self.ammeter_pty is not None and fd == self.ammeter_pty.master:
                        self.ammeter.feed(self.ammeter_pty.receive())
        finally:
            b.stop_motors()
            self._say("stopped the motors, shutting down")
            self.write_status(serving=False, force=True)
            self.close()

    def _check_baud(self) -> None:
        """Garble the link while the host's end of the pty is set to another speed."""
        baud = self.pty.host_baud() if not self._closed_link else None
        if baud is not None and baud != self._baud:
            self._baud = baud
            self.board.set_host_baud(baud)
            wire = getattr(self.board, "to_host", None)  # the firmware board garbles as it sends
            if wire is not None and wire.wrong_baud and self.pty.pending:  # still to go out: at the new speed
                self.pty.pending[:] = wire.pass_bytes_garbled(len(self.pty.pending))

    def _serve_ammeter(self) -> None:
        if self.ammeter is not None and self.ammeter_pty is not None:
            out = self.ammeter.take_output()
            if out:
                self.ammeter_pty.send(out)

    def close(self) -> None:
        """Close the pseudo-terminals."""
        if self._closed_link:
            try:
                os.close(self.pty.slave)
            except OSError:
                pass
        else:
            self.pty.close()
        if self.ammeter_pty is not None:
            self.ammeter_pty.close()


def run_server(world: World, *, status_file: str | None, ammeter: bool, out: TextIO, log: TextIO,
               board=None) -> int:
    """Serve until SIGINT/SIGTERM: print the device path(s) on `out`, notes on `log`."""
    server = PtyServer(world, status_file=status_file, ammeter=ammeter, log=log, board=board)

    def _stop(signum, frame) -> None:
        server.stop_event.set()

    signal.signal(signal.SIGTERM, _stop)
    signal.signal(signal.SIGINT, _stop)
    print(server.path, file=out, flush=True)
    if server.ammeter_pty is not None:
        print(server.ammeter_pty.path, file=out, flush=True)
    what = f"firmware {board.elf} on a simulated ATmega2560" if board is not None else "simulated Omnibot"
    print(f"omnibench sim: {what} on {server.path} ({world.clock} clock, seed {world.seed})"
          + (f", ammeter on {server.ammeter_pty.path}" if server.ammeter_pty else "")
          + "; Ctrl-C stops it", file=log, flush=True)
    server.serve()
    return 0
