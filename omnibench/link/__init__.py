"""Bytes on a serial port: the protocol description, codec (COBS + CRC), board client, ammeter.

Knows nothing of friction or procedures. The wire format is docs/protocol.md, built from
protocols/omnibot-board-v2.toml. What procedures use:

    from omnibench.link.board import Board
    from omnibench.link.ammeter import open_ammeter

    Board.open(url, *, timeout=8.0, baudrate=None, protocol="omnibot-board-v2",
               strict=True, heartbeat=True) -> Board        # context manager: exit stops motors
                                  # heartbeat: PING inside the caller's reads only (no thread);
                                  # device ports are locked (a second process is refused)
    board.hello -> Hello          # protocol_version, firmware_version, board_id, boot_id,
                                  # counts_per_rev, max_telemetry_rate, capabilities, as_dict()
    board.configure(*, telemetry_hz=None, watchdog_s=None) -> None
    board.set_duties(duties: Sequence[float]) -> float      # 4 values in [-1, 1]; board time applied
    board.stop(*, raise_errors=True) -> float | None        # the one stop for every exit path
    board.keepalive() -> None                               # one PING, no ACK wait (feeds the watchdog)
    board.reset_encoders() -> None
    board.clear_faults() -> None
    board.ping() -> float                                   # round trip, s (wall clock)
    board.samples(duration: float) -> Iterator[Sample]      # duration of BOARD time
    board.wait(duration: float) -> list[Sample]
    board.read_samples() -> list[Sample]                    # whatever has arrived
    board.board_time -> float                               # latest board time, s
    board.stats -> LinkStats                                # lost, crc_errors, retries, ...
    board.fault_names(faults: int) -> list[str]
    board.attach_ammeter(ammeter, period_s=0.05) -> None    # fills Sample.ammeter_current
    board.sim_set_world(*, mode=None, payload=None, wheel_mass=None) -> None   # simulator only
    board.sim_truth() -> Pose                                                  # simulator only
    board.close() -> None

    open_ammeter(url, *, timeout=1.0, baudrate=9600) -> ScpiAmmeter   # .measure() -> A

Sample: t (board s), seq, encoder (4 counts), motor_current (4 A), battery_voltage (V),
battery_current (A), faults (bits), duty (4), ammeter_current (A or NaN);
wheel_angles(counts_per_rev) -> rad. Errors: BoardError (exit 3) for board trouble,
UserError (exit 2) for bad arguments; both one line.
"""
