"""For tests and scripts: run `omnibench sim serve` as a subprocess, read its device path and status file, stop it."""

from __future__ import annotations

import json
import math
import os
import select
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

START_TIMEOUT_S = 240.0  # a first start may compile the physics kernel (numba), slowly on a busy machine


def sigint_as_in_a_terminal() -> None:
    """Popen `preexec_fn` for a child a test will interrupt: SIGINT back to its default, as a
    terminal's foreground job has it. A non-interactive shell starts a background command with
    SIGINT ignored (POSIX), every child inherits that, and Python then installs no
    KeyboardInterrupt: a suite launched as `cmd &` saw its Ctrl-C tests run to their end."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@dataclass
class Served:
    proc: subprocess.Popen
    path: str
    status_file: Path
    lines: list[str]

    def status(self) -> dict:
        """The server's status file (its board's duties, faults, last command...): while it
        serves, one written after this call (it is rewritten at least every 50 ms), so it holds
        every command the board acknowledged before; once it has exited, its last."""
        after = time.time()
        deadline = time.monotonic() + 20.0
        st = None
        while time.monotonic() < deadline:
            try:
                st = json.loads(self.status_file.read_text())
            except (FileNotFoundError, json.JSONDecodeError):
                st = None
            if st is not None and (self.proc.poll() is not None or st.get("wall_time", math.inf) > after):
                return st
            time.sleep(0.02)
        raise AssertionError("status file never appeared" if st is None else "the status file is not being refreshed")

    def stop(self, sig: int = signal.SIGTERM) -> int:
        """Signal the server and wait for it (kills it after 10 s); returns its exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout=5)
        for f in (self.proc.stdout, self.proc.stderr):
            if f:
                f.close()
        return self.proc.returncode


def spawn_server(tmp: Path, *args: str, lines: int = 1) -> Served:
    """Run `python -m omnibench sim serve ARGS --status-file ...`; wait for its path line(s)."""
    status = tmp / f"sim-status-{time.monotonic_ns()}.json"
    proc = subprocess.Popen([sys.executable, "-m", "omnibench", "sim", "serve", "--status-file", str(status), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=dict(os.environ))
    got: list[str] = []
    buf = b""
    deadline = time.monotonic() + START_TIMEOUT_S
    while len(got) < lines:
        left = deadline - time.monotonic()
        if left <= 0 or proc.poll() is not None:
            proc.kill()
            err = proc.stderr.read().decode() if proc.stderr else ""
            raise AssertionError(f"sim serve did not print its path: {err[-500:]}")
        r, _, _ = select.select([proc.stdout], [], [], min(left, 0.5))
        if r:
            chunk = os.read(proc.stdout.fileno(), 4096)
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                got.append(line.decode().strip())
    return Served(proc, got[0], status, got)


class HostStalls:
    """Inject host stalls into the bench runner's board adapter (for tests and benchmarks).

    Patches `LinkBoard.set_duties` so that, with probability `p`, the host sleeps a random
    0..`max_s` seconds before sending the command (telemetry of the previous command piles up
    on the port) and again after it (telemetry of the new one piles up), as a slow disk, a
    lazy import or a busy machine would. Use as a context manager; `stalls` lists the sleeps.
    """

    def __init__(self, max_s: float = 2.0, p: float = 1.0, seed: int = 0) -> None:
        import random

        self.max_s, self.p = max_s, p
        self.rng = random.Random(seed)
        self.stalls: list[float] = []

    def _sleep(self) -> None:
        if self.rng.random() < self.p:
            d = self.rng.uniform(0.0, self.max_s)
            self.stalls.append(d)
            time.sleep(d)

    def __enter__(self) -> "HostStalls":
        from omnibench.bench.link_adapter import LinkBoard

        self._orig = LinkBoard.set_duties
        inject = self

        def set_duties(board, duties):
            inject._sleep()
            t = inject._orig(board, duties)
            inject._sleep()
            return t

        LinkBoard.set_duties = set_duties
        return self

    def __exit__(self, *exc) -> None:
        from omnibench.bench.link_adapter import LinkBoard

        LinkBoard.set_duties = self._orig
