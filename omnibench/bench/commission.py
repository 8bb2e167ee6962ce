"""`omnibench commission`: find out how a new robot is wired before the first procedure.

With the robot upside down on its stand, each board channel is jogged on its own, briefly and at
low duty. The person says which wheel turned and which way; the encoders say which channel
counted and in which direction; the motor currents and the battery voltage are read on the way.
The result is a wiring file (omnibench.bench.wiring) that every procedure reads. A map that does
not hold together (a wheel named twice, no or several encoders counting, a dead battery reading)
is refused: nothing is written and the exit status is non-zero.
"""

from __future__ import annotations

import datetime as dt
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from omnibench.bench.prompts import WHEELS
from omnibench.bench.wiring import Wiring
from omnibench.errors import UserError

if TYPE_CHECKING:
    from omnibench.model.robot import Robot

JOG_DUTY = 0.15        #: low duty: the wheel turns visibly, nothing else happens
JOG_S = 0.6            #: board seconds per jog
MIN_COUNTS = 20        #: an encoder that counted fewer than this did not see the wheel turn
OTHER_FRACTION = 0.2   #: other encoders must count less than this fraction of the jogged one
CURRENT_SEEN_A = 0.05  #: a working motor current sensor reads more than this while jogging

Ask = Callable[[str, list[str]], str]


def console_ask(question: str, choices: list[str]) -> str:
    """Ask until one of `choices` is typed (no default; type-ahead dropped)."""
    import click

    from omnibench.bench.prompts import read_answer

    while True:
        text = read_answer(f"{question} [{'/'.join(choices)}]").lower()
        if text in choices:
            return text
        if text in ("stop", "quit"):
            raise click.exceptions.Abort()
        click.echo(f"  please type one of {', '.join(choices)}", err=True)


def _jog(board: Any, channel: int, duty: float) -> dict[str, Any]:
    """Drive board `channel` (0-based) alone at `duty` for JOG_S; encoder change per channel,
    mean |current| per channel, mean battery voltage. Motors stopped and telemetry off after."""
    board.configure(telemetry_hz=50, watchdog_s=0.5)
    board.discard_pending()
    u = [0.0] * 4
    u[channel] = duty
    board.set_duties(u)
    first = board.read(2.0)
    last, sent = first, first.t
    cur, volts = [], []
    while last.t - first.t < JOG_S:
        last = board.read(2.0)
        if last.t - sent >= 0.1:  # keep the watchdog fed with the same duty
            board.set_duties(u)
            sent = last.t
        if last.motor_current is not None:
            cur.append(np.abs(last.motor_current))
        if last.battery_voltage is not None:
            volts.append(last.battery_voltage)
        if last.faults:
            board.stop()
            raise UserError(f"the board reported fault 0x{last.faults:02x} while jogging channel {channel + 1}")
    board.stop()
    board.configure(telemetry_hz=0, watchdog_s=0.5)
    return {"counts": np.asarray(last.encoder, dtype=float) - np.asarray(first.encoder, dtype=float),
            "current": np.mean(cur, axis=0) if cur else np.zeros(4),
            "volts": float(np.mean(volts)) if volts else None}


def find_wiring(board: Any, robot: Robot, ask: Ask, echo: Callable[[str], None] = print,
                confirm: Callable[[str], None] | None = None) -> Wiring:
    """Jog every channel, ask, check; the Wiring found, or UserError naming what is wrong."""
    from omnibench.bench.prompts import ask_yes

    (confirm or ask_yes)("Put the robot upside down on its stand, all four wheels free in the air. Next: each "
                         f"board channel in turn drives one wheel at duty +{JOG_DUTY:.2f} for {JOG_S:g} s.")
    if getattr(board, "is_simulator", False):
        board.sim_set_world(mode="upside_down")
    board.stop()
    motor: list[tuple[int, int] | None] = [None] * 4   # per wheel: (channel 1-based, sign)
    enc: list[tuple[int, int] | None] = [None] * 4
    currents, volts = [], []
    problems: list[str] = []
    for ch in range(4):
        echo(f"jogging board channel {ch + 1} at duty +{JOG_DUTY:.2f} for {JOG_S:g} s ...")
        j = _jog(board, ch, JOG_DUTY)
        wheel = ask(f"Channel {ch + 1} moved. Which wheel turned?", [w.lower() for w in WHEELS] + ["none"])
        if wheel == "none":
            problems.append(f"channel {ch + 1}: no wheel turned (motor not connected, or driver off)")
            continue
        way = ask(f"Which way did {wheel.upper()} turn (as if driving the robot)?", ["forward", "backward"])
        w = [x.lower() for x in WHEELS].index(wheel)
        sign = 1 if way == "forward" else -1
        if motor[w] is not None:
            problems.append(f"{wheel.upper()} named for channels {motor[w][0]} and {ch + 1}")  # type: ignore[index]
        motor[w] = (ch + 1, sign)
        counts = j["counts"]
        k = int(np.argmax(np.abs(counts)))
        others = np.delete(np.abs(counts), k)
        if abs(counts[k]) < MIN_COUNTS:
            problems.append(f"channel {ch + 1}: no encoder counted while {wheel.upper()} turned "
                            f"(largest change {abs(counts[k]):.0f} counts)")
        elif others.max() > OTHER_FRACTION * abs(counts[k]):
            problems.append(f"channel {ch + 1}: several encoders counted ({', '.join(f'{c:+.0f}' for c in counts)})")
        else:
            # counts of a wheel turning forward must be positive once the sign is applied
            enc[w] = (k + 1, int(np.sign(counts[k])) * sign)
        currents.append(j["current"][ch])
        if j["volts"] is not None:
            volts.append(j["volts"])
    board.stop()
    if any(m is None for m in motor):
        problems.append("no channel drives " + ", ".join(WHEELS[w] for w in range(4) if motor[w] is None))
    if sorted(e[0] for e in enc if e is not None) != sorted({e[0] for e in enc if e is not None}):
        problems.append("two wheels are read by the same encoder channel")
    v = float(np.mean(volts)) if volts else None
    if v is None or not 0.6 * robot.V_batt <= v <= 1.3 * robot.V_batt:
        problems.append(f"battery voltage reads {v if v is None else f'{v:.2f} V'}; the robot file says "
                        f"{robot.V_batt:g} V: check the battery and the board's voltage sense")
    if problems:
        raise UserError("wrong map, nothing written: " + "; ".join(problems)
                        + ". Fix the wiring (or the answers) and run omnibench commission again")
    cur_ok = bool(getattr(board, "has_motor_current", False) and min(currents) > CURRENT_SEEN_A)
    hello = getattr(board, "hello", {}) or {}
    return Wiring(motor_channel=tuple(m[0] for m in motor), motor_sign=tuple(m[1] for m in motor),  # type: ignore
                  encoder_channel=tuple(e[0] for e in enc), encoder_sign=tuple(e[1] for e in enc),  # type: ignore
                  board_id=None if hello.get("board_id") is None else str(hello["board_id"]),
                  motor_current_sensor=cur_ok,
                  battery_current_sensor=bool(getattr(board, "has_battery_current", False)),
                  battery_voltage_V=round(v, 3),  # type: ignore[arg-type]
                  date=dt.datetime.now(dt.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"))


def firmware_fixes(wiring: Wiring) -> list[str]:
    """The Omnibot firmware's build settings (firmware/Makefile) that would make `wiring` straight.

    Board channel k is the firmware's wheel slot k (MOTOR_FL, MOTOR_FR, MOTOR_RL, MOTOR_RR;
    the k-th entry of ENCODER_SIGNS and ENCODER_CS). Rebuilding with these (make -C firmware
    VAR=value) fixes the wiring in the firmware instead of in the wiring file."""
    fixes = []
    for w in range(4):
        m, ms, e, es = wiring.motor_channel[w], wiring.motor_sign[w], wiring.encoder_channel[w], wiring.encoder_sign[w]
        if m != w + 1:
            fixes.append(f"{WHEELS[w]} is driven by channel {m}: MOTOR_{WHEELS[w]} must be today's "
                         f"MOTOR_{WHEELS[m - 1]}{' with its sign negated' if ms < 0 else ''}")
        elif ms < 0:
            fixes.append(f"{WHEELS[w]} turns backward: negate the sign (third number) of MOTOR_{WHEELS[w]}")
        if e != w + 1:
            fixes.append(f"{WHEELS[w]} is read on encoder channel {e}: entries {w + 1} of ENCODER_CS and "
                         f"ENCODER_SIGNS must be today's entries {e}{' (the sign negated)' if es < 0 else ''}")
        elif es < 0:
            fixes.append(f"{WHEELS[w]}'s counter counts backward: negate entry {w + 1} of ENCODER_SIGNS")
    return fixes


def commission(port: str, out: str | Path, *, robot_file: str | Path | None = None, ask: Ask = console_ask,
               confirm: Callable[[str], None] | None = None, echo: Callable[[str], None] = print,
               timeout: float | None = None) -> Wiring:
    """Open `port`, find the wiring, write it to `out`; motors stopped on every exit path."""
    from omnibench.bench.link_adapter import open_bench_board
    from omnibench.bench.runner import safe_stop
    from omnibench.bench.session import load_robot_file

    robot, _, _ = load_robot_file(robot_file)
    with open_bench_board(port, timeout=timeout) as board:
        try:
            wiring = find_wiring(board, robot, ask, echo, confirm)
        finally:
            safe_stop(board)
    Path(out).write_text(wiring.to_toml(), encoding="utf-8")
    echo(f"wiring: {wiring.describe()}")
    fixes = firmware_fixes(wiring)
    if fixes:
        echo("to fix it in the Omnibot firmware instead (make -C firmware VAR=value, then flash): " + "; ".join(fixes))
    echo(f"motor current sensors {'work' if wiring.motor_current_sensor else 'read nothing'}; battery current "
         f"sensor {'present' if wiring.battery_current_sensor else 'absent (give energy an --ammeter)'}; "
         f"battery {wiring.battery_voltage_V:.2f} V")
    echo(f"written to {out}: every procedure started here reads it (or give --wiring {out})")
    return wiring
