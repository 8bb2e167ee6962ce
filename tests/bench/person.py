"""A scripted person at the keyboard of an omnibench command, for tests.

The command runs on a pseudo-terminal (pexpect), so its prompts, the type-ahead flush and the
terminal view behave as for a person. The board is `omnibench sim serve` on another pty; the
person reads its status file like a tape measure (the robot's true pose) and checks, while
pausing at a prompt, that the board is quiet: telemetry off, motors stopped, no fault.
"""

from __future__ import annotations

import math
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field

pexpect = __import__("pytest").importorskip("pexpect", reason="pexpect is not installed (pip install -e .[test])")

YES = r"Type yes when done, or no to stop: ?"
DISTANCE = r"Distance travelled, start mark to robot \(e\.g\. 1\.23 m\): ?"
DISPLACEMENT = r"forward, left \(e\.g\. 0\.52 m, 0\.30 m\): ?"
REMEASURE = r"re-measure\? Type the new reading, or keep: ?"
PROMPTS = [YES, DISTANCE, DISPLACEMENT, REMEASURE]


@dataclass
class Person:
    """Answers every prompt of `args` (an omnibench command line) truthfully after a pause.

    pause(k, prompt_text) -> wall seconds to wait before answering the k-th prompt (0-based).
    tape(k, truth) -> the reading to type at a measuring prompt (default: the truth).
    remeasure(k, text) -> the answer to a re-measure question (default "keep"; "TRUTH" types
    the true reading).
    """

    served: object
    args: list[str]
    pause: Callable[[int, str], float] = lambda k, text: 0.0
    tape: Callable[[int, str], str] | None = None
    remeasure: Callable[[int, str], str] = lambda k, text: "keep"
    answers: Callable[[int, str], bool] = lambda k, text: True  #: False: `before` answered prompt k
    timeout: float = 240.0
    prompts: list[str] = field(default_factory=list)
    quiet: list[dict] = field(default_factory=list)
    answered: list[float] = field(default_factory=list)  #: wall time (time.time()) of each answer
    output: str = ""
    _start: tuple[float, float, float] | None = None

    def spawn(self) -> "pexpect.spawn":
        env = dict(os.environ, COLUMNS="160", LINES="50", TERM="xterm")
        self.child = pexpect.spawn(sys.executable, ["-m", "omnibench", *self.args], env=env,
                                   encoding="utf-8", timeout=self.timeout, dimensions=(50, 160))
        return self.child

    def status_after(self, wall: float) -> dict:
        """The server's status written after `wall` (time.time()): the board as it is now."""
        for _ in range(100):
            st = self.served.status()
            if st.get("wall_time", 0) > wall:
                return st
            time.sleep(0.05)
        raise AssertionError("the simulator's status file is not being refreshed")

    def _truth(self, measure: str) -> str:
        x1, y1, _ = self.status_after(time.time())["pose"]
        x0, y0, psi0 = self._start or (0.0, 0.0, 0.0)
        dx, dy = x1 - x0, y1 - y0
        fwd = math.cos(psi0) * dx + math.sin(psi0) * dy
        left = -math.sin(psi0) * dx + math.cos(psi0) * dy
        if measure == "distance":
            return f"{math.hypot(fwd, left):.3f} m"
        return f"{fwd:.3f} m, {left:.3f} m"

    def run(self, before: Callable[["Person", int, str], None] | None = None) -> int:
        """Answer prompts until the command exits; returns its exit status."""
        child = self.spawn()
        k = 0
        while True:
            i = child.expect([*PROMPTS, pexpect.EOF])
            self.output += (child.before or "") + (child.after if isinstance(child.after, str) else "")
            if i == len(PROMPTS):
                break
            text = (child.before or "")[-400:] + str(child.after)
            self.prompts.append(text)
            if before is not None:
                before(self, k, text)
            wait = self.pause(k, text)
            if wait > 0:
                t0 = time.time()
                time.sleep(wait)
                st = self.status_after(t0)
                self.quiet.append({"prompt": k, "telemetry_hz": st["telemetry_hz"],
                                   "motors_stopped": st["motors_stopped"], "faults": st["faults"],
                                   "board_time": st["board_time"]})
            if not self.answers(k, text):
                pass
            elif i == 0:
                if "start mark" in text:
                    self._start = tuple(self.status_after(time.time())["pose"])
                child.sendline("yes")
            elif i in (1, 2):
                truth = self._truth("distance" if i == 1 else "displacement")
                child.sendline(self.tape(k, truth) if self.tape else truth)
            else:
                said = self.remeasure(k, text)
                child.sendline(self._truth("displacement" if "forward;" in text or "m forward" in text
                                           else "distance") if said == "TRUTH" else said)
            self.answered.append(time.time())
            k += 1
        child.close()
        return child.exitstatus if child.exitstatus is not None else -(child.signalstatus or 1)
