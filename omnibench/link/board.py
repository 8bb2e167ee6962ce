"""The board client: everything a procedure needs to drive a motor board over a serial URL.

    with Board.open("sim://?seed=1") as board:          # or /dev/ttyACM0, socket://..., hwgrep://...
        board.configure(telemetry_hz=200, watchdog_s=0.5)
        board.reset_encoders()
        board.set_duties([0.3, 0.3, 0.3, 0.3])
        for s in board.samples(2.0):                    # 2 s of BOARD time
            ...                                         # s.t, s.encoder, s.motor_current, ...
        board.stop()
    # leaving the block always stops the motors (also on exceptions and Ctrl-C)

Timing follows the board's clock (telemetry time stamps), never the host's wall clock,
so the same procedure runs in real time on the robot and faster on the simulator.

Reading is pull-based: bytes are read only inside the client's calls, in the caller's
thread, and nothing else ever writes to the port: there is no background thread. With
`heartbeat=True` (the default, for scripts) the client sends a PING while the caller reads
whenever a quarter of the watchdog timeout of board time has passed since it last sent
anything; the bench runner opens with `heartbeat=False` and feeds the watchdog from its own
loop. Either way the watchdog is fed only while the caller makes progress, so a hung
procedure stops the motors within the watchdog timeout.

Every board frame that carries a time is checked against the last one before it is used:
board time that runs backwards, or jumps further than the frames lost in between (sequence
gap) could explain, is a link fault: the frame is dropped and counted (`stats.time_faults`),
never taken as the passage of time.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Iterator, Sequence
from typing import Protocol

import serial

from omnibench.errors import BoardError, UserError
from omnibench.link.codec import Codec, CodecError, Message
from omnibench.link.framing import FrameError
from omnibench.link.spec import DEFAULT_PROTOCOL, load_protocol
from omnibench.link.types import Hello, LinkStats, Pose, Sample
from omnibench.link.urls import open_url

READ_TIMEOUT_S = 0.05       #: wall-clock timeout of one blocking port read
ACK_TIMEOUT_S = 0.1         #: wall-clock wait for an ACK before sending again
ACK_TIMEOUT_BOARD_S = 0.03  #: ... or this much board time + one telemetry period (telemetry keeps arriving)
RETRIES = 20                #: extra attempts per command (a 2 % byte-error cable loses ~40 % of round trips)
TIME_SLACK_S = 0.002        #: allowance on a frame's board time beyond the expected telemetry period
STALL_S = 0.45              #: no byte for this long while telemetry is on: probe the board
PROBE_S = 0.45              #: probe unanswered for this long: the link is lost
BOOTLOADER_SILENCE_S = 5.0  #: the Mega's stock stk500v2 bootloader starts the firmware only after this much silence
                            #: once it has received a byte (8e6 polls of 10 cycles at 16 MHz; stk500boot.c)
BOOT_QUIET_S = 5.5          #: handshake: first request unanswered, nothing heard: stay silent this long
QUIET_RESERVE_S = 1.0       #: ... but stop being silent this long before the handshake timeout (to retry)
HANDSHAKE_TIMEOUT_S = 8.0   #: default handshake timeout: a DTR reset's bootloader (<= 5.1 s), then the firmware
MODES = ("ground", "upside_down")


class Ammeter(Protocol):
    """Anything with `measure() -> float` (A), e.g. link.ammeter.ScpiAmmeter."""

    def measure(self) -> float: ...


class Board:
    """A motor board on a serial URL: handshake, commands with ACKs, telemetry, heartbeat.

    Open with `Board.open(url)`; use as a context manager so the motors stop on every
    exit path. Methods raise `BoardError` (one-line message, exit code 3) when the board
    misbehaves and `UserError` for bad arguments.
    """

    def __init__(self, port: serial.SerialBase, codec: Codec, url: str, *, heartbeat: bool = True) -> None:
        self.url = url
        self.codec = codec
        self.spec = codec.spec
        self.hello: Hello | None = None
        self.stats = LinkStats()
        self.version_ok = False
        self.reset_detected = False
        self._port = port
        self._deframer = codec.deframer()
        self._io = threading.RLock()        # reading and decoding
        self._tx = threading.Lock()         # writing
        self._tx_seq = 0
        self._acks: dict[int, Message] = {}
        self._replies: dict[str, Message] = {}
        self._queue: deque[Sample] = deque()
        self._last_seq: int | None = None
        self._t_wraps = 0
        self._t_last_raw: int | None = None
        self._t_ref: float | None = None    # board time of the last frame accepted (s)
        enc = next(f for f in self.spec.message("TELEMETRY").fields if f.name == "encoder")
        self._enc_range = enc.raw_range     # the encoder counters wrap at the field's width
        self._enc: list[int] | None = None  # unwrapped counters of the last sample
        self._enc_raw: tuple[int, ...] = ()
        self._bound_period = math.inf       # largest telemetry period expected now (s); inf: off
        self._board_time = 0.0
        self._last_tx_board = 0.0
        self._last_tx_wall = time.monotonic()
        self._last_rx_wall = time.monotonic()
        self._last_call_wall = time.monotonic()
        self._telemetry_hz = 0.0
        self._watchdog_s = float(self.spec.board.get("default_watchdog_s", 0.5))
        self._heartbeat_on = heartbeat
        self._ammeter: Ammeter | None = None
        self._ammeter_period = 0.0
        self._ammeter_next = 0.0
        self._lost_error: BoardError | None = None
        self._closed = False
        self._strict = True                 # open(strict=...): refuse another protocol version
        self._faults_seen = 0               # fault bits of the latest sample
        self._bad_frames = 0                # valid CRC but unknown id or wrong length
        self._foreign_version: int | None = None  # from a HELLO whose layout is not ours
        self._reset_reported = False
        self._reset_id = self.spec.message("RESET_ENCODERS").id
        self._reset_message = ""
        self._rx_head = bytearray()          # the first bytes received (to recognise a text-printing sketch)

    # ================================================================== opening
    @classmethod
    def open(cls, url: str, *, timeout: float = HANDSHAKE_TIMEOUT_S, baudrate: int | None = None,
             protocol: str = DEFAULT_PROTOCOL, strict: bool = True, heartbeat: bool = True) -> "Board":
        """Open `url` (any pyserial URL), handshake within `timeout` s, stop the motors.

        A board that answers the first HELLO_REQ opens at once. One that sends nothing back
        may be rebooting because the port opened (an Arduino Mega resets on DTR into its
        bootloader, which starts the firmware only after 0.8 s, or after 5 s of silence on
        its serial line once it has received a byte): the host then stays silent, listening,
        for BOOT_QUIET_S before it asks again (a HELLO or any byte ends the wait at once).
        The default timeout covers that; a timeout shorter than BOOT_QUIET_S +
        QUIET_RESERVE_S cuts the silence short, to keep time for retries.

        `baudrate` defaults to the protocol's ([board].baudrate, 115200). With
        `strict` (default) a board speaking another protocol version raises BoardError
        and nothing is sent to it; with strict=False the board opens (for `board info`)
        but refuses to drive the motors. `heartbeat=False` never sends PINGs on its own:
        the caller feeds the watchdog (`ping()`), as the bench runner does from its loop.
        """
        spec = load_protocol(protocol)
        baud = int(baudrate or spec.board.get("baudrate", 115200))
        port = open_url(url, baudrate=baud, timeout=READ_TIMEOUT_S)
        board = cls(port, Codec(spec), url, heartbeat=heartbeat)
        board._strict = strict
        try:
            board._handshake(timeout, baud)
        except BoardError:
            board._close_port()
            if board.hello is None and board._foreign_version is None:
                from omnibench.link.sniff import sniff_sketch

                hint = sniff_sketch(url, bytes(board._rx_head), baud)
                if hint:
                    raise BoardError(hint) from None
            raise
        except BaseException:
            board._close_port()
            raise
        return board

    def _handshake(self, timeout: float, baud: int) -> None:
        try:
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError):
            pass
        self._deframer.resync()  # a board already sending (telemetry left running) is joined mid-frame
        start = time.monotonic()
        deadline = start + timeout
        hello: Message | None = None
        ack_ok = False
        # A board that reset as the port opened may be in its bootloader, where every byte
        # received restarts the bootloader's wait for silence: after one unanswered request
        # with nothing heard at all, stay silent (listening) until the firmware has had time
        # to start. Any byte from the board shows it is not there (the bootloader says
        # nothing), and a HELLO it sends as it boots ends the silence at once.
        quiet_until: float | None = None
        seq = self._send("HELLO_REQ")
        while (now := time.monotonic()) < deadline:
            heard = self.stats.bytes_in > 0
            if quiet_until is None and not heard and now - start > ACK_TIMEOUT_S:
                quiet_until = min(now + BOOT_QUIET_S, deadline - QUIET_RESERVE_S)
            quiet = quiet_until is not None and now < quiet_until and not heard
            if not quiet and now - self._last_tx_wall > ACK_TIMEOUT_S:
                seq = self._send("HELLO_REQ")
            self._pump(wait=True, check=False)
            hello = self._replies.get("HELLO") or hello
            ack_ok = ack_ok or seq in self._acks
            if hello is not None and ack_ok:
                break
        if hello is None and self._foreign_version is not None:
            raise BoardError(self._mismatch_message(self._foreign_version))
        if hello is None:
            if self.stats.bytes_in:
                silent = ""
            elif timeout < BOOT_QUIET_S + QUIET_RESERVE_S:
                silent = (f"; nothing came back: a Mega that resets as the port opens can take "
                          f"{BOOTLOADER_SILENCE_S:g} s to leave its bootloader, open with the default timeout "
                          f"({HANDSHAKE_TIMEOUT_S:g} s)")
            else:
                silent = "; nothing came back (a board with no firmware stays silent in its bootloader)"
            raise BoardError(
                f"no HELLO from a board on {self.url} within {timeout:g} s: check the port, the baud rate "
                f"(board expects {self.spec.board.get('baudrate', 115200)}, opened at {baud}), that the board "
                f"is powered and runs {self.spec.name} v{self.spec.version} firmware (frames of another version's "
                f"frame check, e.g. v1's CRC-16, are not recognised){silent}")
        self.hello = self._to_hello(hello)
        self._replies.pop("HELLO", None)
        self._acks.clear()
        self.version_ok = self.hello.protocol_version == self.spec.version
        if not self.version_ok:
            if self._strict:
                raise BoardError(self._strict_fail_message())
            return
        self._command("STOP")
        self._command("CONFIGURE", {"watchdog": self._watchdog_s, "telemetry_rate": 0})
        self._queue.clear()  # telemetry a previous session left running is not this session's

    def _strict_fail_message(self) -> str:
        assert self.hello is not None
        return self._mismatch_message(self.hello.protocol_version)

    def _mismatch_message(self, version: int) -> str:
        return (f"board on {self.url} speaks {self.spec.name} protocol v{version}, "
                f"this tool speaks v{self.spec.version}: update the firmware or omnibench "
                "(motors not driven)")

    def _to_hello(self, m: Message) -> Hello:
        f = m.fields
        return Hello(
            protocol_version=int(f["protocol_version"]),
            firmware_version=tuple(int(v) for v in f["firmware_version"]),  # type: ignore[arg-type]
            board_id=int(f["board_id"]),
            boot_id=int(f["boot_id"]),
            counts_per_rev=int(f["counts_per_rev"]),
            max_telemetry_rate=int(f["max_telemetry_rate"]),
            capabilities=tuple(self.spec.flag_names("capabilities", int(f["capabilities"]))),
        )

    # ================================================================== context, stop, close
    def __enter__(self) -> "Board":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        # A link already reported lost has nothing left to stop through: do not raise twice.
        try:
            self.stop(raise_errors=exc_type is None and self._lost_error is None)
        finally:
            self.close()

    def stop(self, *, raise_errors: bool = True) -> float | None:
        """Stop all four motors now; the one stop used on every exit path.

        Sends STOP (always accepted by the board, even with faults latched) and waits for
        its ACK. With `raise_errors=False` (exit paths that are already failing) it tries
        its best and never raises. Safe to call many times and on a lost link. Returns the
        board time (s) at which the board applied the stop (None if not acknowledged).
        """
        if self._closed or self.hello is None or not self.version_ok:
            return None
        try:
            return self.ack_time(self._command("STOP", check_reset=False))
        except (BoardError, serial.SerialException, OSError):
            if raise_errors:
                raise
        return None

    def close(self) -> None:
        """Close the port (call stop() first, or use `with`)."""
        if self._closed:
            return
        self._closed = True
        self._close_port()

    def _close_port(self) -> None:
        try:
            self._port.close()
        except (serial.SerialException, OSError):
            pass

    # ================================================================== commands
    def set_duties(self, duties: Sequence[float]) -> float:
        """Apply four duties (FL, FR, RL, RR), each in [-1, 1]; held until changed or stopped.

        Returns the board time (s) at which the board applied them (from the ACK): samples
        taken under these duties have a later time and report these duties."""
        u = [float(x) for x in duties]
        if len(u) != 4 or not all(math.isfinite(x) and -1.0 <= x <= 1.0 for x in u):
            raise UserError(f"duties must be 4 numbers in [-1, 1], got {list(duties)!r}")
        self._require_drivable()
        return self.ack_time(self._command("SET_DUTIES", {"duty": u}))

    def ack_time(self, ack: Message) -> float:
        """Board time (s, unwrapped) in an ACK: when the board applied the command."""
        return self._unwrap_peek(ack.fields["time"])

    def configure(self, *, telemetry_hz: float | None = None, watchdog_s: float | None = None) -> None:
        """Set the telemetry rate (Hz, 0 = off) and/or the watchdog timeout (s); None keeps it."""
        hz = self._telemetry_hz if telemetry_hz is None else float(telemetry_hz)
        wd = self._watchdog_s if watchdog_s is None else float(watchdog_s)
        max_hz = self.hello.max_telemetry_rate if self.hello else 1000
        if not (0 <= hz <= max_hz and float(int(hz)) == hz):
            raise UserError(f"telemetry rate must be a whole number of Hz in 0..{max_hz}, got {telemetry_hz!r}")
        if not 0.02 <= wd <= 10.0:
            raise UserError(f"watchdog timeout must be in 0.02..10 s, got {watchdog_s!r}")
        old = 1.0 / self._telemetry_hz if self._telemetry_hz > 0 else math.inf
        new = 1.0 / hz if hz > 0 else math.inf
        self._bound_period = max(old, new)  # frames of either schedule (or none) may arrive meanwhile
        try:
            self._command("CONFIGURE", {"watchdog": wd, "telemetry_rate": int(hz)})
        except BaseException:
            self._bound_period = old
            raise
        self._telemetry_hz, self._watchdog_s = hz, wd
        self._bound_period = new

    def reset_encoders(self) -> None:
        """Set the four encoder counters to zero."""
        self._command("RESET_ENCODERS")

    def clear_faults(self) -> None:
        """Clear latched faults (e.g. after the watchdog fired); motors stay stopped."""
        self._command("CLEAR_FAULTS")

    def keepalive(self) -> None:
        """Feed the board's watchdog: one PING, not waiting for its ACK (any valid frame the
        board receives restarts its watchdog; on a lossy cable send these often instead of
        retrying one)."""
        with self._io:
            self._send("PING")

    def ping(self) -> float:
        """Command round trip: wall-clock seconds from sending PING to its ACK."""
        t0 = time.perf_counter()
        self._command("PING")
        return time.perf_counter() - t0

    # ------------------------------------------------------------------ simulator only
    def sim_set_world(self, *, mode: str | None = None, payload: float | None = None,
                      wheel_mass: Sequence[float] | None = None) -> None:
        """Simulated operator: put the robot `mode` ("ground" | "upside_down"), set the
        payload on top (kg) and/or the mass of each mounted wheel (kg, FL FR RL RR).
        Only with the motors stopped. Real firmware refuses (BoardError)."""
        mask, values = 0, {"mode": 0, "payload": 0.0, "wheel_mass": [0.0] * 4}
        bits = self.spec.flags["world_mask"]
        if mode is not None:
            if mode not in MODES:
                raise UserError(f"mode must be 'ground' or 'upside_down', not {mode!r}")
            mask |= 1 << bits["MODE"]
            values["mode"] = MODES.index(mode)
        if payload is not None:
            if not (math.isfinite(payload) and 0 <= payload <= 4e6):
                raise UserError(f"payload must be a mass in kg >= 0, got {payload!r}")
            mask |= 1 << bits["PAYLOAD"]
            values["payload"] = float(payload)
        if wheel_mass is not None:
            wm = [float(m) for m in wheel_mass]
            if len(wm) != 4 or not all(0 < m <= 6.5 for m in wm):
                raise UserError(f"wheel_mass needs 4 masses in kg in (0, 6.5], got {list(wheel_mass)!r}")
            mask |= 1 << bits["WHEEL_MASS"]
            values["wheel_mass"] = wm
        values["mask"] = mask
        self._command("SIM_SET_WORLD", values)

    def sim_truth(self) -> Pose:
        """Simulated tape measure: the robot's true pose (m, m, rad) now. Real firmware refuses."""
        self._command("SIM_GET_TRUTH", reply="SIM_TRUTH")
        m = self._replies.pop("SIM_TRUTH")
        f = m.fields
        return Pose(x=f["x"], y=f["y"], psi=f["psi"], mode=self.spec.enum_name("mode", f["mode"]).lower(),
                    t=self._unwrap_peek(f["time"]))

    # ================================================================== telemetry
    @property
    def board_time(self) -> float:
        """Latest board time seen (s since boot), from telemetry and ACK time stamps."""
        return self._board_time

    def read_samples(self) -> list[Sample]:
        """Every sample received so far and not yet returned (reads what the port holds)."""
        with self._io:
            self._pump(wait=False)
            out = list(self._queue)
            self._queue.clear()
            return out

    def samples(self, duration: float) -> Iterator[Sample]:
        """Yield samples until `duration` s of BOARD time after the latest board time seen.

        Yields the queued samples first (none is lost between calls), then new ones; ends
        after the first sample at or beyond the end time. Raises BoardError if telemetry
        is off, the link is lost (within about a second), or the board resets.
        """
        if self._telemetry_hz <= 0:
            raise BoardError("telemetry is off: call configure(telemetry_hz=...) before reading samples")
        t_end = self._board_time + float(duration)
        probe_at: float | None = None
        last_tel = self.stats.telemetry
        last_tel_wall = time.monotonic()
        while True:
            while self._queue:  # yield outside the lock: the caller may do anything meanwhile
                s = self._queue.popleft()
                yield s
                if s.t >= t_end:
                    return
            with self._io:
                self._pump(wait=True)
                now = time.monotonic()
                if self.stats.telemetry != last_tel:
                    last_tel, last_tel_wall, probe_at = self.stats.telemetry, now, None
                    continue
                # No telemetry (ACKs of heartbeat PINGs do not count): probe once with
                # HELLO_REQ (a board that reset answers with a new boot id), then give up.
                if probe_at is None and now - last_tel_wall > max(STALL_S, 3.0 / self._telemetry_hz):
                    probe_at = now
                    self._send("HELLO_REQ")
                elif probe_at is not None and now - probe_at > PROBE_S:
                    answered = now - self._last_rx_wall < PROBE_S
                    raise self._lost(
                        f"no telemetry for {now - last_tel_wall:.1f} s"
                        + (" although the board answers (was it reconfigured by another program?)" if answered else ""))

    def wait(self, duration: float) -> list[Sample]:
        """All samples over the next `duration` s of board time (see samples())."""
        return list(self.samples(duration))

    def attach_ammeter(self, ammeter: Ammeter | None, period_s: float = 0.05) -> None:
        """Read an external ammeter every `period_s` of board time while reading samples.

        Each reading is stored in `Sample.ammeter_current` of the telemetry sample that
        triggered it: it is taken within one ammeter round trip after that sample's
        board time (exactly at it on the fast simulator). None detaches.
        """
        self._ammeter = ammeter
        self._ammeter_period = float(period_s)
        self._ammeter_next = self._board_time

    def fault_names(self, faults: int) -> list[str]:
        """Names of the fault bits set in `faults` (e.g. ["WATCHDOG"])."""
        return self.spec.flag_names("faults", faults)

    # ================================================================== internals: I/O
    def _require_drivable(self) -> None:
        if not self.version_ok:
            assert self.hello is not None
            raise BoardError(self._strict_fail_message())
        if self.reset_detected:
            raise BoardError(f"board on {self.url} reset during the session: open it again before driving")

    def _send(self, name: str, values: dict | None = None) -> int:
        """Write one frame; returns its sequence number."""
        if self._lost_error is not None:
            raise self._lost_error
        try:
            with self._tx:
                seq = self._tx_seq
                self._tx_seq = (seq + 1) & 0xFFFF
                wire = self.codec.frame(name, seq, values)
                self._port.write(wire)
                self.stats.bytes_out += len(wire)
                self._last_tx_wall = time.monotonic()
                self._last_tx_board = self._board_time
        except CodecError as exc:
            raise UserError(str(exc)) from None
        except (serial.SerialException, OSError) as exc:
            raise self._lost(f"write failed: {exc}") from None
        return seq

    def _command(self, name: str, values: dict | None = None, *, reply: str | None = None,
                 check_reset: bool = True) -> Message:
        """Send a command, wait for its ACK (resending up to RETRIES times), check status."""
        with self._io:
            self._last_call_wall = time.monotonic()
            if reply:
                self._replies.pop(reply, None)
            sent: list[int] = []
            for attempt in range(RETRIES + 1):
                if attempt:
                    self.stats.retries += 1
                sent.append(self._send(name, values))
                wall_end = time.monotonic() + ACK_TIMEOUT_S
                # On a fast simulator the wall clock says little: with telemetry flowing,
                # also give up after some board time (the known board time may be one
                # telemetry period old, hence the allowance).
                board_end = (self._board_time + ACK_TIMEOUT_BOARD_S + 1.0 / self._telemetry_hz
                             if self._telemetry_hz > 0 else math.inf)
                while True:
                    ack = next((self._acks.pop(s) for s in sent if s in self._acks), None)
                    if ack is not None and (reply is None or reply in self._replies):
                        return self._check_ack(name, ack)
                    if time.monotonic() > wall_end or self._board_time > board_end:
                        break
                    self._pump(wait=True, check=check_reset)
            raise self._lost(f"no acknowledgement for {name} after {RETRIES + 1} tries")

    def _check_ack(self, name: str, ack: Message) -> Message:
        status = self.spec.enum_name("status", int(ack.fields["status"]))
        if status == "OK":
            return ack
        m = self.spec.message(name)
        if status == "UNSUPPORTED" and m.sim_only:
            raise BoardError(f"{name} is simulator-only and the board on {self.url} is real firmware")
        if status == "FAULT_ACTIVE":
            faults = self.fault_names(self._last_faults())
            raise BoardError(f"board refused {name}: faults {', '.join(faults) or '?'} latched "
                             "(find the cause, then clear_faults())")
        if status == "BAD_STATE":
            raise BoardError(f"board refused {name} in its present state (stop the motors first)")
        raise BoardError(f"board answered {name} with {status}")

    def _last_faults(self) -> int:
        return self._queue[-1].faults if self._queue else self._faults_seen

    def _lost(self, why: str) -> BoardError:
        if self._lost_error is None:
            self._lost_error = BoardError(f"lost the board on {self.url}: {why} (check the cable and the "
                                          "board's power)")
        return self._lost_error

    def _pump(self, wait: bool, check: bool = True) -> int:
        """Read what the port has (blocking up to READ_TIMEOUT_S if `wait`); decode it.

        Returns the number of frames decoded. Raises BoardError on a lost link or, with
        `check`, on a detected board reset.
        """
        if self._lost_error is not None:
            raise self._lost_error
        self._last_call_wall = time.monotonic()
        try:
            n = self._port.in_waiting
            data = self._port.read(n) if n else (self._port.read(1) if wait else b"")
            if data and not n:
                n = self._port.in_waiting  # the rest of the frame that byte began
                if n:
                    data += self._port.read(n)
        except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
            # pyserial raises TypeError/AttributeError when the device vanished under it.
            raise self._lost(f"read failed: {exc}") from None
        frames = 0
        if data:
            if len(self._rx_head) < 2048:
                self._rx_head += data[:2048 - len(self._rx_head)]
            self._last_rx_wall = time.monotonic()
            self.stats.bytes_in += len(data)
            for body in self._deframer.feed(data):
                frames += 1
                self._dispatch(body)
        ds = self._deframer.stats
        self.stats.crc_errors = ds.crc_errors
        self.stats.framing_errors = ds.framing_errors + self._bad_frames
        if check and self.reset_detected and not self._reset_reported:
            self._reset_reported = True
            raise BoardError(self._reset_message)
        self._heartbeat_board_time()
        return frames

    def _dispatch(self, body: bytes) -> None:
        try:
            msg = self.codec.decode(body)
        except FrameError:
            self._bad_frames += 1
            # HELLO keeps its id and protocol_version (u16, first payload field) in every
            # version, so a board with another layout is still recognised as such.
            hello_id = self.spec.message("HELLO").id
            if len(body) >= 5 and body[0] == hello_id:
                self._foreign_version = int.from_bytes(body[3:5], "little")
            return
        gap = self._seq_gap(msg)
        if "time" in msg.fields and not self._time_plausible(msg, gap):
            return
        self.stats.frames += 1
        self._track_seq(msg)
        name = msg.name
        if name == "TELEMETRY":
            self._on_telemetry(msg)
        elif name == "ACK":
            self._set_time(msg.fields["time"])
            if msg.fields["cmd_id"] == self._reset_id and msg.fields["status"] == self.spec.enums["status"]["OK"]:
                self._enc = None  # the counters restarted at zero
            self._acks[msg.fields["cmd_seq"]] = msg
            if len(self._acks) > 256:
                for k in list(self._acks)[:128]:
                    del self._acks[k]
        elif name == "HELLO":
            self._on_hello(msg)
        elif name == "EVENT":
            code = self.spec.enum_name("event", msg.fields["code"])
            self.stats.events.append((self._unwrap_peek(msg.fields["time"]), code, msg.fields["arg"]))
        else:
            self._replies[name] = msg

    def _seq_gap(self, msg: Message) -> int:
        """Board frames missing between the last frame accepted and `msg` (0: none)."""
        if self._last_seq is None:
            return 0
        gap = (msg.seq - self._last_seq - 1) & 0xFFFF
        return gap if gap < 0x8000 else 0

    def _time_plausible(self, msg: Message, gap: int) -> bool:
        """Is the board time in `msg` possible after the last frame accepted?

        It may not run backwards, and with telemetry on it may not advance more than one
        telemetry period per frame sent since (the frames received plus the `gap` lost),
        with TIME_SLACK_S of jitter. Else the frame is a link fault: dropped and counted."""
        if msg.name == "HELLO" or (self.hello is not None and msg.name == "EVENT"
                                   and self.spec.enum_name("event", msg.fields["code"]) == "BOOT"):
            return True  # a reboot restarts the board clock (detected by its boot id)
        t = self._unwrap_peek(msg.fields["time"])
        if self._t_ref is None:
            self._t_ref = t
            return True
        dt = t - self._t_ref
        limit = (gap + 1) * self._bound_period * 1.5 + TIME_SLACK_S
        if dt < 0 or dt > limit:
            self.stats.time_faults += 1
            why = "ran backwards" if dt < 0 else "jumped"
            self.stats.events.append((self._t_ref, "TIME_FAULT",
                                      f"{msg.name} board time {why} by {dt:+.6f} s (gap {gap} frames)"))
            return False
        self._t_ref = t
        return True

    def _track_seq(self, msg: Message) -> None:
        if msg.name == "HELLO" and self.hello is not None and msg.fields["boot_id"] != self.hello.boot_id:
            self._last_seq = msg.seq
            self._t_ref = None
            self._enc = None
            return
        if self._last_seq is not None:
            gap = (msg.seq - self._last_seq - 1) & 0xFFFF
            if gap < 0x8000:
                self.stats.lost += gap
        self._last_seq = msg.seq

    def _on_hello(self, msg: Message) -> None:
        if self.hello is None:
            self._replies["HELLO"] = msg
            return
        new = int(msg.fields["boot_id"])
        if new != self.hello.boot_id and not self.reset_detected:
            self.reset_detected = True
            self._reset_message = (
                f"board on {self.url} reset (boot id {self.hello.boot_id:08X} -> {new:08X}) after board time "
                f"{self._board_time:.3f} s: it stopped the motors and forgot its settings; the run is incomplete")
            self.stats.events.append((self._board_time, "RESET", new))

    def _on_telemetry(self, msg: Message) -> None:
        f = msg.fields
        t = self._set_time(f["time"])
        self._faults_seen = int(f["faults"])
        amm = math.nan
        if self._ammeter is not None and t >= self._ammeter_next - 1e-7:
            self._ammeter_next = t + self._ammeter_period
            try:
                amm = float(self._ammeter.measure())
            except (BoardError, serial.SerialException, OSError, ValueError):
                amm = math.nan
        self._queue.append(Sample(
            t=t, seq=msg.seq, encoder=self._unwrap_encoders(tuple(f["encoder"])), motor_current=tuple(f["motor_current"]),
            battery_voltage=f["battery_voltage"], battery_current=f["battery_current"],
            faults=int(f["faults"]), duty=tuple(f["duty"]), ammeter_current=amm))
        self.stats.telemetry += 1

    def _unwrap_encoders(self, raw: tuple[int, ...]) -> tuple[int, int, int, int]:
        """Full encoder counts from the wrapping counters on the wire: each sample adds the
        change since the previous one, taken as the smallest in the field's range."""
        lo, hi = self._enc_range
        if self._enc is None:
            self._enc = list(raw)
        else:
            span = hi - lo + 1
            for j, (r, old) in enumerate(zip(raw, self._enc_raw)):
                self._enc[j] += (r - old - lo) % span + lo
        self._enc_raw = raw
        return tuple(self._enc)  # type: ignore[return-value]

    # ------------------------------------------------------------------ board clock
    def _unwrap_peek(self, t_raw_s: float) -> float:
        raw = int(round(t_raw_s * 1e6))
        wraps = self._t_wraps
        if self._t_last_raw is not None and raw < self._t_last_raw - 2**31:
            wraps += 1
        return (wraps * 2**32 + raw) * 1e-6

    def _set_time(self, t_raw_s: float) -> float:
        """Board time in s with the 32-bit µs wrap undone; updates `board_time`."""
        raw = int(round(t_raw_s * 1e6))
        if self._t_last_raw is not None and raw < self._t_last_raw - 2**31:
            self._t_wraps += 1
        self._t_last_raw = raw
        t = (self._t_wraps * 2**32 + raw) * 1e-6
        self._board_time = max(self._board_time, t)
        return t

    # ------------------------------------------------------------------ heartbeat
    def _heartbeat_interval(self) -> float:
        return self._watchdog_s / 4.0

    def _heartbeat_board_time(self) -> None:
        """While reading: PING when a quarter watchdog of board time passed since the last send."""
        if (self._heartbeat_on and self.hello is not None and self.version_ok and not self._closed
                and self._board_time - self._last_tx_board >= self._heartbeat_interval()):
            try:
                self._send("PING")
            except BoardError:
                pass
