"""The simulated Omnibot motor board: the firmware's behaviour, driven by simulated time.

`SimBoard` has no I/O of its own. Its owner (the `sim://` pyserial handler or the
pseudo-terminal server) feeds it the bytes the host wrote (`feed`), moves its clock
(`advance_to`) and takes the bytes it sends (`take_output`). It speaks the protocol built
from the same description as the host codec (protocols/*.toml) and behaves as
docs/protocol.md says a firmware must: HELLO at boot and on request, one ACK per valid host
frame, telemetry at the configured rate, a watchdog that stops the motors and latches a
fault when the host is silent, and the simulator-only world and truth messages.

Times: `clock_us` is simulated time since the simulator started (never resets);
`time_us` is the board's own clock, which restarts at 0 when the board reboots.
"""

from __future__ import annotations

import threading
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np

from omnibench.link.codec import Codec
from omnibench.link.framing import Deframer, FrameError
from omnibench.link.spec import ProtocolSpec, load_protocol
from omnibench.sim.faults import FaultyWire
from omnibench.sim.plant import Plant
from omnibench.sim.sensors import Sensors
from omnibench.sim.world import World

DUTY_FULL_SCALE = 32767
MODES = ("ground", "upside_down")
PROTECTION_PERIOD_US = 1000  # the board samples motor currents and battery voltage at 1 kHz


@dataclass
class SentFrame:
    """A frame the board sent (kept when `record` is on, for fault tests)."""

    seq: int
    name: str
    raw: dict[str, Any]
    start: int  #: offset of its first wire byte in the board -> host stream
    end: int    #: offset one past its delimiter


def _clip_int(x: float, lo: int, hi: int) -> int:
    return int(min(max(round(x), lo), hi))


class SimBoard:
    """The firmware of the simulated board (thread-safe: every entry point takes `lock`)."""

    def __init__(self, world: World | None = None, spec: ProtocolSpec | None = None,
                 record: bool = False) -> None:
        self.world = world or World()
        self.spec = spec or load_protocol(self.world.protocol)
        self.codec = Codec(self.spec)
        self.lock = threading.RLock()
        seeds = np.random.SeedSequence(self.world.seed).spawn(4)
        self._boot_rng = np.random.default_rng(seeds[0])
        self.robot = self.world.robot()
        if self.world.plant == "independent":  # physics written for testing only
            from omnibench.worlds.independent import IndependentPlant

            self.plant = IndependentPlant(self.robot, self.world.scenario(), self.world.dt)
        else:
            self.plant = Plant(self.robot, self.world.scenario(), self.world.dt)  # type: ignore[assignment]
        self.sensors = Sensors(self.world.sensors, self.robot.counts_per_rev, np.random.default_rng(seeds[1]))
        f = self.world.faults
        self.to_host = FaultyWire(f, np.random.default_rng(seeds[2]), f.direction in ("both", "to_host"))
        self.to_board = FaultyWire(f, np.random.default_rng(seeds[3]), f.direction in ("both", "to_board"))
        self.record = record
        self.to_host.record = record
        self.sent: deque[SentFrame] = deque(maxlen=100_000)
        self.received: deque[tuple[str, int, dict[str, Any]]] = deque(maxlen=1000)
        self.out = bytearray()
        self.clock_us = 0
        self.disconnected = False
        self.boots = 0
        self._reset_done = False
        self._driver_fault_done = False
        b = self.spec.board
        self._max_rate = int(b.get("max_telemetry_hz", 1000))
        self._default_watchdog_us = int(round(float(b.get("default_watchdog_s", 0.5)) * 1e6))
        enc = next(f for f in self.spec.message("TELEMETRY").fields if f.name == "encoder")
        self._encoder_range = enc.raw_range
        self._boot()

    # ------------------------------------------------------------------ boot / reset
    def _boot(self) -> None:
        """Power-on state: motors off, telemetry off, default watchdog, counters zero."""
        self.boots += 1
        self.boot_clock_us = self.clock_us
        self.boot_id = int(self._boot_rng.integers(1, 2**32))
        self.tx_seq = 0
        self.duties = np.zeros(4)
        self.faults = 0
        self.watchdog_us = self._default_watchdog_us
        self.telemetry_period_us = 0
        self.next_telemetry_us: int | None = None
        self.last_rx_clock_us = self.clock_us
        self.deframer = Deframer(self.codec.crc, self.spec.max_frame_bytes)
        self.encoder_offset = self.sensors.encoder_counts(self.plant.state.phi)
        self.host_frames = 0
        self.last_command = "BOOT"
        self._send("HELLO", self._hello_raw())
        self._send("EVENT", {"code": self._enum("event", "BOOT"), "arg": self.boot_id, "time": self._time_raw()})

    @property
    def time_us(self) -> int:
        """Board time, µs since the last boot."""
        return self.clock_us - self.boot_clock_us

    # ------------------------------------------------------------------ time
    def _watchdog_deadline(self) -> int | None:
        """The watchdog is armed while any duty is non-zero: silence until then stops them."""
        if self.duties.any():
            return self.last_rx_clock_us + self.watchdog_us
        return None

    def _events(self) -> list[int]:
        ev = []
        if self.next_telemetry_us is not None:
            ev.append(self.next_telemetry_us)
        wd = self._watchdog_deadline()
        if wd is not None:
            ev.append(wd)
        f = self.world.faults
        if f.reset_at is not None and not self._reset_done:
            ev.append(int(round(f.reset_at * 1e6)))
        if f.disconnect_at is not None and not self.disconnected:
            ev.append(int(round(f.disconnect_at * 1e6)))
        if f.driver_fault_at is not None and not self._driver_fault_done:
            ev.append(int(round(f.driver_fault_at * 1e6)))
        return ev

    def next_output_us(self) -> int | None:
        """Simulated time (clock, µs) of the next scheduled TELEMETRY frame, or None.

        The fast clock jumps only to these: everything else the board does on its own
        (watchdog, scheduled faults) happens on the way, or as wall-clock time passes
        while telemetry is off."""
        with self.lock:
            nt = self.next_telemetry_us
            return None if nt is None else max(nt, self.clock_us)

    def next_event_us(self) -> int | None:
        """Simulated time (clock, µs) of the next thing the board will do on its own."""
        with self.lock:
            ev = [e for e in self._events() if e >= self.clock_us]
            return min(ev) if ev else None

    def advance_to(self, clock_us: int) -> None:
        """Run the board and the physics up to simulated time `clock_us` (µs)."""
        with self.lock:
            clock_us = int(clock_us)
            while True:
                ev = [e for e in self._events() if e <= clock_us]
                if not ev:
                    break
                t = max(min(ev), self.clock_us)
                self._physics_to(t)
                self._handle_events(t)
            self._physics_to(max(clock_us, self.clock_us))

    def _physics_to(self, clock_us: int) -> None:
        f = self.world.faults
        if f.overcurrent_limit is None and f.undervoltage_limit is None:
            self.plant.advance_to(clock_us * 1e-6, self._wheel_duties())
            self.clock_us = clock_us
            return
        # the board's protection samples current and voltage every PROTECTION_PERIOD_US, so a
        # start-up current spike between two telemetry frames trips it as on the real board
        while self.clock_us < clock_us:
            t = min(clock_us, (self.clock_us // PROTECTION_PERIOD_US + 1) * PROTECTION_PERIOD_US)
            self.plant.advance_to(t * 1e-6, self._wheel_duties())
            self.clock_us = t
            self._check_limits()
        self.clock_us = max(self.clock_us, clock_us)

    def _wheel_duties(self) -> np.ndarray:
        """The duty each wheel gets through the (possibly mis-)wired motor connectors: as the
        firmware's drivers apply it (rounded to their packet-serial step) unless the world's
        actuation is ideal. The per-wheel send latency is the plant's (World.scenario)."""
        duties = self.duties
        if self.world.actuation == "firmware" and duties.any():
            from omnibench.model.actuation import applied_duty

            duties = applied_duty(duties)
        w = self.world.wiring
        if w == (1, 2, 3, 4):
            return duties
        out = np.zeros(4)
        for k, x in enumerate(w):
            out[abs(x) - 1] = np.sign(x) * duties[k]
        return out

    @staticmethod
    def _channels(values: np.ndarray, wiring: tuple[int, ...]) -> np.ndarray:
        """Per-wheel `values` as the board's channels see them through `wiring`."""
        return np.array([np.sign(x) * values[abs(x) - 1] for x in wiring])

    def _check_limits(self) -> None:
        """The board's protection (world faults.overcurrent_limit / undervoltage_limit; off by
        default). A tripped limit latches its fault and stops the motors."""
        f = self.world.faults
        s = self.plant.state
        if f.overcurrent_limit is not None and np.max(np.abs(s.motor_current)) > f.overcurrent_limit:
            self._latch("OVERCURRENT")
        if f.undervoltage_limit is not None and s.V_batt < f.undervoltage_limit:
            self._latch("UNDERVOLTAGE")

    def _latch(self, fault: str) -> None:
        """Latch `fault`, stop the motors and tell the host (EVENT FAULT, arg = the new flag)."""
        bit = 1 << self.spec.flags["faults"][fault]
        if self.faults & bit:
            return
        self.faults |= bit
        self.duties = np.zeros(4)
        self.last_command = fault
        self._send("EVENT", {"code": self._enum("event", "FAULT"), "arg": bit, "time": self._time_raw()})

    def _handle_events(self, t: int) -> None:
        f = self.world.faults
        if f.disconnect_at is not None and not self.disconnected and t >= int(round(f.disconnect_at * 1e6)):
            self.disconnected = True
        if f.driver_fault_at is not None and not self._driver_fault_done and t >= int(round(f.driver_fault_at * 1e6)):
            self._driver_fault_done = True
            self._latch("DRIVER")
        if f.reset_at is not None and not self._reset_done and t >= int(round(f.reset_at * 1e6)):
            self._reset_done = True
            self._boot()
            return
        wd = self._watchdog_deadline()
        if wd is not None and t >= wd:
            self.duties = np.zeros(4)
            self.faults |= 1 << self.spec.flags["faults"]["WATCHDOG"]
            silence_ms = (t - self.last_rx_clock_us) // 1000
            self.last_command = "WATCHDOG"
            self._send("EVENT", {"code": self._enum("event", "WATCHDOG"), "arg": silence_ms,
                                 "time": self._time_raw()})
        if self.next_telemetry_us is not None and t >= self.next_telemetry_us:
            self._send("TELEMETRY", self.telemetry_raw())
            self.next_telemetry_us += self.telemetry_period_us

    # ------------------------------------------------------------------ host input
    def feed(self, data: bytes) -> None:
        """Bytes the host wrote, arriving now (after the wire's faults)."""
        with self.lock:
            if self.disconnected:
                return
            for body in self.deframer.feed(self.to_board.pass_bytes(data)):
                self._handle_frame(body)

    def _handle_frame(self, body: bytes) -> None:
        hdr = self.spec.header_struct
        if len(body) < hdr.size:
            return
        msg_id, seq = hdr.unpack_from(body)
        self.last_rx_clock_us = self.clock_us
        self.host_frames += 1
        m = self.spec.by_id(msg_id)
        if m is None or m.direction != "host_to_board":
            self._ack(msg_id, seq, "UNSUPPORTED")
            return
        try:
            msg = self.codec.decode_raw(body)
        except FrameError:
            self._ack(msg_id, seq, "BAD_LENGTH")
            return
        self.received.append((msg.name, seq, dict(msg.fields)))
        handler = getattr(self, f"_on_{msg.name.lower()}", None)
        if handler is None:
            self._ack(msg_id, seq, "UNSUPPORTED")
            return
        status = handler(msg.fields)
        if status == "OK" and msg.name not in ("PING", "HELLO_REQ", "SIM_GET_TRUTH"):
            self.last_command = msg.name
        self._ack(msg_id, seq, status)

    def _ack(self, cmd_id: int, cmd_seq: int, status: str) -> None:
        self._send("ACK", {"cmd_id": cmd_id, "cmd_seq": cmd_seq, "status": self._enum("status", status),
                           "time": self._time_raw()})

    # ------------------------------------------------------------------ command handlers
    def _on_hello_req(self, f: dict) -> str:
        self._send("HELLO", self._hello_raw())
        return "OK"

    def _on_ping(self, f: dict) -> str:
        return "OK"

    def _on_set_duties(self, f: dict) -> str:
        raw = np.asarray(f["duty"], dtype=float)
        if np.any(np.abs(raw) > DUTY_FULL_SCALE):
            return "BAD_VALUE"
        if self.faults:
            self.duties = np.zeros(4)
            return "FAULT_ACTIVE"
        lim = float(self.robot.max_duty)
        self.duties = np.clip(raw / DUTY_FULL_SCALE, -lim, lim)
        return "OK"

    def _on_stop(self, f: dict) -> str:
        self.duties = np.zeros(4)
        return "OK"

    def _on_configure(self, f: dict) -> str:
        wd, rate = int(f["watchdog"]), int(f["telemetry_rate"])
        if not 20 <= wd <= 10000 or not 0 <= rate <= self._max_rate:
            return "BAD_VALUE"
        self.watchdog_us = wd * 1000
        if rate:
            self.telemetry_period_us = int(round(1e6 / rate))
            self.next_telemetry_us = self.clock_us + self.telemetry_period_us
        else:
            self.telemetry_period_us = 0
            self.next_telemetry_us = None
        return "OK"

    def _on_reset_encoders(self, f: dict) -> str:
        self.encoder_offset = self.sensors.encoder_counts(self.plant.state.phi)
        return "OK"

    def _on_clear_faults(self, f: dict) -> str:
        self.faults = 0
        return "OK"

    def _on_sim_set_world(self, f: dict) -> str:
        bits = self.spec.flags["world_mask"]
        mask = int(f["mask"])
        if np.any(self.duties != 0):
            return "BAD_STATE"
        kw: dict[str, Any] = {}
        if mask & (1 << bits["MODE"]):
            if not 0 <= int(f["mode"]) < len(MODES):
                return "BAD_VALUE"
            kw["mode"] = MODES[int(f["mode"])]
        if mask & (1 << bits["PAYLOAD"]):
            kw["payload"] = int(f["payload"]) * 1e-3
        if mask & (1 << bits["WHEEL_MASS"]):
            masses = tuple(int(x) * 1e-4 for x in f["wheel_mass"])
            if min(masses) <= 0:
                return "BAD_VALUE"
            kw["wheel_mass"] = masses
        self.plant.set_world(**kw)
        return "OK"

    def _on_sim_get_truth(self, f: dict) -> str:
        x, y, psi = self.plant.state.pose
        self._send("SIM_TRUTH", {
            "x": _clip_int(x * 1e6, -2**31, 2**31 - 1), "y": _clip_int(y * 1e6, -2**31, 2**31 - 1),
            "psi": _clip_int(psi * 1e6, -2**31, 2**31 - 1),
            "mode": MODES.index(self.plant.scenario.mode), "time": self._time_raw()})
        return "OK"

    # ------------------------------------------------------------------ output
    def _enum(self, table: str, name: str) -> int:
        return self.spec.enums[table][name]

    def _time_raw(self) -> int:
        return self.time_us & 0xFFFFFFFF

    def _hello_raw(self) -> dict[str, Any]:
        caps = ["SIMULATOR"]
        if self.world.actuation == "firmware":
            caps.append("PACKET_SERIAL_DRIVERS")
        if self.world.sensors.battery_current_sensor:
            caps.append("BATTERY_CURRENT")
        if self.world.sensors.motor_current_sensor:
            caps.append("MOTOR_CURRENT")
        version = self.world.faults.protocol_version
        return {
            "protocol_version": self.spec.version if version is None else version,
            "firmware_version": list(self.world.firmware_version),
            "board_id": self.world.board_id,
            "boot_id": self.boot_id,
            "counts_per_rev": int(self.robot.counts_per_rev),
            "max_telemetry_rate": self._max_rate,
            "capabilities": self.spec.flag_mask("capabilities", *caps),
        }

    def telemetry_raw(self) -> dict[str, Any]:
        """Raw TELEMETRY fields for the current state, through the sensor models."""
        s = self.plant.state
        counts = self.sensors.encoder_counts(s.phi) - self.encoder_offset
        counts = self._channels(counts, self.world.encoder_wiring or self.world.wiring).astype(np.int64)
        lo, hi = self._encoder_range
        counts = ((counts - lo) % (hi - lo + 1)) + lo  # the counters wrap at the field's width
        amps = self._channels(np.asarray(s.motor_current), self.world.wiring)
        cur = np.clip(np.round(self.sensors.motor_current(amps) * 1000), -32768, 32767)
        duty = np.clip(np.round(self.duties * DUTY_FULL_SCALE), -DUTY_FULL_SCALE, DUTY_FULL_SCALE)
        return {
            "time": self._time_raw(),
            "encoder": counts.astype(np.int64).tolist(),
            "motor_current": cur.astype(np.int64).tolist(),
            "battery_voltage": _clip_int(self.sensors.battery_voltage(s.V_batt) * 1000, 0, 65535),
            "battery_current": _clip_int(self.sensors.battery_current(s.I_batt) * 1000, -32768, 32767),
            "faults": self.faults & 0xFF,
            "duty": duty.astype(np.int64).tolist(),
        }

    def encode_tx(self, name: str, raw: dict[str, Any]) -> bytes:
        """Clean wire bytes of the board's next frame (uses and advances `tx_seq`).

        Fields the description has but this simulator does not model are sent as 0, so a
        description with extra fields still works unchanged."""
        m = self.spec.message(name)
        if any(f.name not in raw for f in m.fields):
            raw = {f.name: raw.get(f.name, [0] * f.count if f.count > 1 else 0) for f in m.fields}
        wire = self.codec.frame_raw(name, self.tx_seq, raw)
        self.tx_seq = (self.tx_seq + 1) & 0xFFFF
        return wire

    def _send(self, name: str, raw: dict[str, Any]) -> None:
        seq = self.tx_seq
        wire = self.encode_tx(name, raw)
        if self.disconnected:
            return
        start = self.to_host.bytes_in
        self.out += self.to_host.pass_bytes(wire)
        if self.record:
            self.sent.append(SentFrame(seq, name, raw, start, start + len(wire)))

    def take_output(self, n: int | None = None) -> bytes:
        """Remove and return up to `n` bytes (all if None) the board has sent."""
        with self.lock:
            n = len(self.out) if n is None else min(n, len(self.out))
            data = bytes(self.out[:n])
            del self.out[:n]
            return data

    def set_host_baud(self, baudrate: int) -> None:
        """The host's port speed: anything but the board's garbles both directions."""
        with self.lock:
            wrong = self.world.faults.wrong_baud or int(baudrate) != self.world.baudrate
            if wrong and not self.to_host.wrong_baud and self.out:
                # bytes not yet on the wire go out at the new speed too: the boot HELLO, encoded
                # as the board powered up, reached a host that had opened at 9600 intact (CI)
                self.out[:] = self.to_host.pass_bytes_garbled(len(self.out))
            self.to_host.wrong_baud = wrong
            self.to_board.wrong_baud = wrong

    # ------------------------------------------------------------------ ground truth, status
    def stop_motors(self) -> None:
        """Duties to zero (the server calls it on every exit path)."""
        with self.lock:
            self.duties = np.zeros(4)
            self.last_command = "SHUTDOWN"

    def truth(self) -> dict[str, Any]:
        """True pose, wheel speeds and battery current of the simulated robot (SI)."""
        with self.lock:
            s = self.plant.state
            return {"pose": [float(v) for v in s.pose], "phi_dot": [float(v) for v in s.phi_dot],
                    "I_batt": float(s.I_batt), "V_batt": float(s.V_batt), "E_batt": float(s.E_batt)}

    def status(self) -> dict[str, Any]:
        """What a person (or a test) needs to know about the board, JSON-ready."""
        with self.lock:
            names = self.spec.flag_names("faults", self.faults)
            return {
                "board_time": self.time_us * 1e-6,
                "sim_time": self.clock_us * 1e-6,
                "boot_id": self.boot_id,
                "duties": [float(d) for d in self.duties],
                "motors_stopped": bool(np.all(self.duties == 0)),
                "faults": names,
                "telemetry_hz": (1e6 / self.telemetry_period_us) if self.telemetry_period_us else 0,
                "watchdog_s": self.watchdog_us * 1e-6,
                "host_frames": self.host_frames,
                "last_command": self.last_command,
                "mode": self.plant.scenario.mode,
                "payload": self.plant.scenario.payload,
                "disconnected": self.disconnected,
                "pose": [float(v) for v in self.plant.state.pose],  # what a person's tape would read
            }
