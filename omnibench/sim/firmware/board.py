"""The firmware board: the real firmware on a simulated ATmega2560, the plant as its robot.

`FirmwareBoard` has the interface of `SimBoard` (feed / advance_to / take_output / status),
so `omnibench sim serve --firmware X.elf` serves it on a pseudo-terminal with the same loop.
Lockstep, as in flight-controller SITL: the chip runs one step (1 ms of board time), the
bytes the drivers decoded on their S1 line in that step (robot.py: the robot's own wiring,
never the firmware build's settings) set the driver outputs from the instant each packet
ended, the plant integrates to the end of the step, and the counters and analog inputs are
updated from the new state (the counters extrapolate within the step with the wheel speeds).

The robot is powered before the host connects: the rig runs the firmware through its start-up
(STARTUP_US: the drivers' 1.5 s + 0.5 s wait) and drops what it sent meanwhile.

The rig around the board also plays the simulated operator and tape measure, as a person
at the real robot would: the firmware answers the simulator-only messages UNSUPPORTED (it
is the robot's firmware); the rig replaces that ACK's status with the outcome of the world
change, puts SIM_TRUTH before it, sets the SIMULATOR capability in HELLO and renumbers the
board's frames so its `seq` stays continuous (gaps the firmware makes are kept).
"""

from __future__ import annotations

import math
import os
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from omnibench.errors import UserError
from omnibench.link.codec import Codec
from omnibench.link.framing import Deframer, FrameError, decode_chunk, encode_frame
from omnibench.link.spec import load_protocol
from omnibench.sim.firmware.fil import F_CPU, Harness
from omnibench.sim.firmware.robot import MEGA_PINS, RobotWiring, SabertoothLine, load_robot
from omnibench.sim.plant import Plant
from omnibench.sim.sensors import Sensors
from omnibench.sim.world import World

STEP_US = 1000          # lockstep period, µs of board time
STARTUP_US = 2_100_000  # run before serving: the firmware's driver start-up (1.5 s, 0xAA, 0.5 s) is over
CYCLES_PER_US = F_CPU // 1_000_000
MODES = ("ground", "upside_down")
_NO_STATE = ("PING", "HELLO_REQ", "SIM_GET_TRUTH", "SIM_SET_WORLD")


#: rms conversion noise of the ATmega2560's ADC, mV at the pin: half a 4.9 mV code (the datasheet
#: gives +-2 codes absolute accuracy; a conversion of a steady input scatters over a code or two)
ADC_NOISE_MV = 2.44


class FirmwareBoard:
    """The firmware in simavr plus the plant, with SimBoard's interface."""

    def __init__(self, world: World, elf: str | Path, robot: str | Path | RobotWiring | None = None,
                 startup_us: int = STARTUP_US) -> None:
        self.world = world
        self.elf = Path(elf)
        if not self.elf.is_file():
            raise UserError(f"no firmware at {self.elf} (build it with: make -C firmware)")
        self.wiring = robot if isinstance(robot, RobotWiring) else load_robot(robot)
        self.spec = load_protocol(world.protocol)
        self.codec = Codec(self.spec)
        self.lock = threading.RLock()
        self.chip = Harness(self.elf)
        w = self.wiring
        self.chip.s1_config(None if w.s1_pin == 18 else MEGA_PINS[w.s1_pin], w.baud, w.autobaud)
        self.chip.encoder_pins([wh.encoder_cs for wh in w.wheels])
        self.enable_pin = MEGA_PINS[w.enable_pin]
        self.line = SabertoothLine(w.addresses)
        self.encoder_signs = np.array([wh.encoder_sense for wh in w.wheels], dtype=float)
        seeds = np.random.SeedSequence(world.seed).spawn(2)
        self.rng = np.random.default_rng(seeds[0])
        self.robot = world.robot()
        # the firmware is the actuation chain here (its packets are the duties the plant gets):
        # the plant takes them exactly and at once
        self.plant = Plant(self.robot, replace(world, actuation="ideal").scenario(), world.dt)
        self.sensors = Sensors(world.sensors, self.robot.counts_per_rev, np.random.default_rng(seeds[1]))
        self.motor_map = [(wh.driver, wh.channel, wh.sense) for wh in w.wheels]  # the robot's, per wheel
        self.clock_us = 0
        self.disconnected = False
        self.wrong_baud = False
        self.out = bytearray()
        self.wire_packets: list[tuple[float, int, int, int]] = []  # (board s, address, command, value)
        self.record_packets = False
        self.max_wall_s: float | None = None
        self._from_host = Deframer(self.codec.crc, self.spec.max_frame_bytes)
        self._from_board = bytearray()
        self._pending_sim: dict[int, tuple[str, dict]] = {}
        self._host_frames: dict[int, dict] = {}
        self._inserted = 0
        self.boot_id = 0
        self.commanded = np.zeros(4)
        self.faults = 0
        self.telemetry_hz = 0.0
        self.watchdog_s = 0.5
        self.last_command = "BOOT"
        self.host_frames = 0
        self._update_inputs()
        if startup_us:
            self.advance_to(startup_us, step_us=50_000)  # wheels at rest, no host: long steps
            self.out.clear()            # nobody was connected to hear it
            self.wire_packets.clear()

    @property
    def drivers_enabled(self) -> bool:
        """The drivers' enable line (the robot's enable pin) driven high."""
        return self.chip.pin_high(*self.enable_pin)

    # ------------------------------------------------------------------ time
    @property
    def time_us(self) -> int:
        return self.clock_us

    def next_output_us(self) -> int | None:
        """Fast clock: with telemetry on, step 1 ms at a time as the host reads."""
        with self.lock:
            return self.clock_us + STEP_US if self.telemetry_hz else None

    def next_event_us(self) -> int | None:
        with self.lock:
            return self.clock_us + STEP_US

    def duties(self) -> np.ndarray:
        """What each wheel's motor gets now: driver channel output through the wiring, 0 with pin 7 low."""
        if not self.drivers_enabled:
            return np.zeros(4)
        return np.array([s * self.line.output(a, c) for a, c, s in self.motor_map])

    def advance_to(self, clock_us: int, step_us: int = STEP_US) -> None:
        """Run chip and plant in lockstep up to board time `clock_us`.

        With `max_wall_s` set (the pty server sets it), a call returns after that much wall
        time even if short of `clock_us`: on a machine too slow for real time the board then
        runs slower than the wall clock but keeps answering the host."""
        wall_end = time.monotonic() + self.max_wall_s if self.max_wall_s else math.inf
        with self.lock:
            while self.clock_us < clock_us and time.monotonic() < wall_end:
                end = min(int(clock_us), self.clock_us + step_us)
                self.chip.run_until(end * CYCLES_PER_US)
                now_us = self.chip.cycles / CYCLES_PER_US
                for cyc, byte in self.chip.s1_bytes():
                    t = cyc / F_CPU
                    self.line.expire(t)
                    self.plant.advance_to(t, self.duties())
                    pk = self.line.byte(t, byte)
                    if pk and self.record_packets:
                        self.wire_packets.append((t, *pk))
                self.line.expire(now_us * 1e-6)
                self.plant.advance_to(now_us * 1e-6, self.duties())
                self.clock_us = int(now_us)
                self._update_inputs()
                data, _ = self.chip.host_read()
                if data:
                    self._board_bytes(data)

    def _update_inputs(self) -> None:
        """Counters and analog inputs from the plant's state (with the world's sensor noise)."""
        s = self.plant.state
        k = self.robot.counts_per_rev / (2 * math.pi)
        counts = (np.asarray(s.phi) + self.sensors.encoder_phase) * k * self.encoder_signs
        rates = np.asarray(s.phi_dot) * k * self.encoder_signs
        self.chip.set_counters(counts, rates)   # chip i reads wheel i, at the robot's chip-select pin
        w = self.wiring
        v = self.sensors.battery_voltage(float(s.V_batt))
        adc = self._adc_mv
        adc(0, v / w.battery_divider * 1000)
        gain, zero = w.hall_mv_per_a, w.hall_zero_mv
        if w.battery_current == "hall":
            i = float(s.I_batt) + self.rng.normal(0.0, self.world.sensors.battery_current_noise)
            adc(5, zero + gain * i)
        if w.motor_current == "hall":
            cur = np.asarray(s.motor_current) + self.rng.normal(0.0, self.world.sensors.current_noise, 4)
            for w, (_, _, sign) in enumerate(self.motor_map):  # type: ignore[assignment]  # the sensor sits in the driver's lead
                adc(1 + w, zero + gain * sign * cur[w])  # type: ignore[call-overload, operator]  # A1..A4

    def _adc_mv(self, channel: int, mv: float) -> None:
        """An analog input as the chip converts it: with the ATmega2560's own conversion noise
        (ADC_NOISE_MV; simavr converts noise-free), which also dithers the 4.9 mV codes."""
        self.chip.set_adc_mv(channel, mv + self.rng.normal(0.0, ADC_NOISE_MV))

    def _trace(self, text: str) -> None:
        """Debug trace of the rig (env OMNIBENCH_FIL_TRACE=file)."""
        path = os.environ.get("OMNIBENCH_FIL_TRACE")
        if path:
            with open(path, "a") as fh:
                fh.write(f"{self.clock_us / 1e6:.6f} {text}\n")

    # ------------------------------------------------------------------ host side
    def feed(self, data: bytes) -> None:
        """Bytes the host wrote: all go to UART0; the rig notes the frames it must act on."""
        with self.lock:
            if self.wrong_baud:
                data = bytes(self.rng.integers(1, 256, len(data), dtype=np.uint8))
            self.chip.host_write(data)
            for body in self._from_host.feed(data):
                try:
                    msg = self.codec.decode_raw(body)
                except FrameError:
                    continue
                self.host_frames += 1
                self._trace(f"host {msg.name} seq {msg.seq}")
                if self.spec.message(msg.name).sim_only:
                    self._pending_sim[msg.seq] = (msg.name, dict(msg.fields))
                self._host_frames[msg.seq] = dict(msg.fields)  # applied when the firmware ACKs OK
                if len(self._host_frames) > 64:
                    self._host_frames.pop(next(iter(self._host_frames)))

    def _board_bytes(self, data: bytes) -> None:
        """Frames the firmware sent: track its state, act for the simulated operator, renumber."""
        self._from_board += data
        while 0 in self._from_board:
            i = self._from_board.index(0)
            chunk, self._from_board = bytes(self._from_board[:i]), self._from_board[i + 1:]
            try:
                msg = self.codec.decode_raw(decode_chunk(chunk, self.codec.crc))
            except FrameError:
                self._emit_raw(chunk + b"\x00")
                continue
            self._board_frame(msg)

    def _board_frame(self, msg) -> None:
        f = dict(msg.fields)
        if msg.name == "HELLO":
            if msg.seq == 0:  # a (re)boot: the firmware numbers from 0 again
                self._inserted = 0
                self.commanded[:] = 0
                self.faults = 0
                self.telemetry_hz = 0
                self.last_command = "BOOT"
            self.boot_id = f["boot_id"]
            f["capabilities"] |= self.spec.flag_mask("capabilities", "SIMULATOR")
        elif msg.name == "EVENT":
            ev = self.spec.enum_name("event", f["code"])
            self._trace(f"board EVENT {ev} {f['arg']}")
            if ev in ("WATCHDOG", "FAULT"):
                self.commanded[:] = 0
                self.faults |= (1 << self.spec.flags["faults"]["WATCHDOG"]) if ev == "WATCHDOG" else f["arg"]
                self.last_command = ev
        elif msg.name == "TELEMETRY":
            self.faults = f["faults"]
        elif msg.name == "ACK":
            self._ack(msg.seq, f)
            return
        self._emit(msg.name, msg.seq, f)

    def _ack(self, seq: int, f: dict) -> None:
        m = self.spec.by_id(f["cmd_id"])
        name = m.name if m else "?"
        status = self.spec.enum_name("status", f["status"])
        if m is not None and m.sim_only and f["cmd_seq"] in self._pending_sim:
            req, fields = self._pending_sim.pop(f["cmd_seq"])
            status = self._operator(req, fields, seq, int(f["time"]))
            f["status"] = self.spec.enums["status"][status]
        elif status == "OK":
            sent = self._host_frames.get(f["cmd_seq"], {})
            if name == "SET_DUTIES":
                self.commanded[:] = [d / 32767 for d in sent.get("duty", (0, 0, 0, 0))]
            elif name == "STOP":
                self.commanded[:] = 0
            elif name == "CLEAR_FAULTS":
                self.faults = 0
            elif name == "CONFIGURE" and sent:
                self.telemetry_hz = float(sent["telemetry_rate"])
                self.watchdog_s = sent["watchdog"] * 1e-3
        elif status == "FAULT_ACTIVE":
            self.commanded[:] = 0
        if status == "OK" and name not in _NO_STATE and name != "?":
            self.last_command = name
        self._emit("ACK", seq, f)

    def _operator(self, req: str, f: dict, seq: int, t_ack_us: int) -> str:
        """The simulated operator and tape measure (what SimBoard does for these messages).

        SIM_TRUTH carries the board time of the ACK it precedes: the firmware's clock, not the
        rig's (a host drops a frame whose board time runs backwards)."""
        if req == "SIM_GET_TRUTH":
            x, y, psi = self.plant.state.pose
            clip = lambda v: int(min(max(round(v * 1e6), -2**31), 2**31 - 1))  # noqa: E731
            self._emit("SIM_TRUTH", seq, {"x": clip(x), "y": clip(y), "psi": clip(psi),
                                          "mode": MODES.index(self.plant.scenario.mode),
                                          "time": t_ack_us & 0xFFFFFFFF})
            self._inserted += 1
            return "OK"
        bits = self.spec.flags["world_mask"]
        if np.any(self.commanded != 0):  # the board holds running duties (after STOP its stop packets
            return "BAD_STATE"           # may still be on the 9600-baud line: the person waits them out)
        kw: dict[str, Any] = {}
        if f["mask"] & (1 << bits["MODE"]):
            if not 0 <= f["mode"] < len(MODES):
                return "BAD_VALUE"
            kw["mode"] = MODES[f["mode"]]
        if f["mask"] & (1 << bits["PAYLOAD"]):
            kw["payload"] = f["payload"] * 1e-3
        if f["mask"] & (1 << bits["WHEEL_MASS"]):
            masses = tuple(m * 1e-4 for m in f["wheel_mass"])
            if min(masses) <= 0:
                return "BAD_VALUE"
            kw["wheel_mass"] = masses
        self.plant.set_world(**kw)
        self._update_inputs()
        return "OK"

    def _emit(self, name: str, fw_seq: int, raw: dict) -> None:
        """Re-encode with the rig's continuous seq (firmware seq + frames the rig inserted)."""
        seq = (fw_seq + self._inserted) & 0xFFFF
        self._emit_raw(encode_frame(self.codec.encode_raw(name, seq, raw), self.codec.crc))

    def _emit_raw(self, wire: bytes) -> None:
        if self.wrong_baud:
            wire = bytes(self.rng.integers(0, 256, len(wire), dtype=np.uint8))
        self.out += wire

    def take_output(self, n: int | None = None) -> bytes:
        with self.lock:
            n = len(self.out) if n is None else min(n, len(self.out))
            data = bytes(self.out[:n])
            del self.out[:n]
            return data

    def set_host_baud(self, baudrate: int) -> None:
        with self.lock:
            self.wrong_baud = int(baudrate) != self.world.baudrate

    # ------------------------------------------------------------------ truth, status
    def stop_motors(self) -> None:
        """The rig is shut down: the robot's power goes off with it."""
        with self.lock:
            for d in self.line.drivers.values():
                d.out = {1: 0.0, 2: 0.0}
            self.commanded[:] = 0
            self.last_command = "SHUTDOWN"

    def truth(self) -> dict[str, Any]:
        with self.lock:
            s = self.plant.state
            return {"pose": [float(v) for v in s.pose], "phi_dot": [float(v) for v in s.phi_dot],
                    "I_batt": float(s.I_batt), "V_batt": float(s.V_batt), "E_batt": float(s.E_batt)}

    def cpu_load(self) -> tuple[int, int]:
        """(cycles run, cycles asleep) of the simulated ATmega2560 since power-up."""
        return self.chip.cycles, self.chip.sleep_cycles

    def status(self) -> dict[str, Any]:
        with self.lock:
            d = self.duties()
            return {
                "board_time": self.clock_us * 1e-6, "sim_time": self.clock_us * 1e-6, "boot_id": self.boot_id,
                "duties": [float(x) for x in d], "motors_stopped": bool(np.all(d == 0)),
                "commanded": [float(x) for x in self.commanded],
                "faults": self.spec.flag_names("faults", self.faults),
                "telemetry_hz": self.telemetry_hz, "watchdog_s": self.watchdog_s,
                "host_frames": self.host_frames, "last_command": self.last_command,
                "mode": self.plant.scenario.mode, "payload": self.plant.scenario.payload,
                "disconnected": False, "firmware": str(self.elf), "drivers_enabled": self.drivers_enabled,
                "robot": self.wiring.name, "sabertooth_packets": self.line.packets,
                "sabertooth_bad_packets": self.line.bad_checksum, "wiring_findings": self.wiring_findings(),
            }

    def wiring_findings(self) -> list[str]:
        """What a person with a scope on the robot would note when the drivers do not hear the
        firmware: where it talks instead, at which rate, to which address (and the build
        setting that governs it). Empty when the line is clean."""
        w, c, out = self.wiring, self.chip.counters(), []
        s1 = f"S1 (pin {w.s1_pin})"
        if c["s1_framing_errors"]:
            out.append(f"{c['s1_framing_errors']:.0f} bytes on {s1} failed 8N1 at the drivers' {w.baud} baud: "
                       "the firmware sends at another rate (build setting SABERTOOTH_BAUD)")
        if c["s1_wrong_rate_bytes"]:
            out.append(f"USART1 runs at {c['usart1_baud']:.0f} baud, the drivers listen at {w.baud}: "
                       f"{c['s1_wrong_rate_bytes']:.0f} bytes are garbage to them (build setting SABERTOOTH_BAUD)")
        if w.s1_pin != 18 and c["usart1_bytes"] and not self.line.packets:
            out.append(f"the firmware sends on USART1 (TX1, pin 18) but the drivers' S1 is wired to pin {w.s1_pin} "
                       f"(build setting SABERTOOTH_S1_PIN={w.s1_pin})")
        if w.s1_pin == 18 and c["pin6_edges"] and not c["usart1_bytes"]:
            out.append("the firmware sends on pin 6 but the drivers' S1 is wired to pin 18 (TX1) "
                       "(build setting SABERTOOTH_S1_PIN=18)")
        if w.autobaud and not self.chip.s1_baud and self.clock_us >= STARTUP_US:
            out.append(f"the drivers autobaud and never received 0xAA on {s1}")
        for a, n in sorted(self.line.other_address.items()):
            out.append(f"{n} packets for address {a}: no driver has it (the robot's are "
                       f"{', '.join(map(str, w.addresses))}; build settings MOTOR_FL..MOTOR_RR)")
        if self.line.bad_checksum:
            out.append(f"{self.line.bad_checksum} packets with a bad checksum on {s1} (ignored by the drivers)")
        if c["spi_contention"]:
            out.append(f"{c['spi_contention']:.0f} SPI bytes clocked with several LS7366R selected "
                       "(MISO contention; the chips are read one at a time)")
        return out

    def power_cycle_drivers(self) -> None:
        """Switch the drivers off and on (a motor-supply cut): they forget the serial timeout,
        stop, and an autobauding driver waits for a new 0xAA."""
        with self.lock:
            for d in self.line.drivers.values():
                d.power_cycle()
            if self.wiring.autobaud:
                self.chip.s1_config(None if self.wiring.s1_pin == 18 else MEGA_PINS[self.wiring.s1_pin],
                                    self.wiring.baud, True)

    def close(self) -> None:
        self.chip.close()
