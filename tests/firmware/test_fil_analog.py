"""The firmware's analog readings, code by code: each ADC code is reported at its centre,
converted to mA (Hall sensors) or mV (battery divider) with one rounding at the end.

The rig puts chosen codes on the analog inputs (no noise) and the test reads TELEMETRY. An error
that depends on the code (a centre first rounded to whole mV at the pin is off by up to 0.5 mV:
7.6 mA on a 66 mV/A sensor) is a bias in the averaged currents the fit takes for unbiased, about
1 % at the 0.5 A a free wheel draws; so each reading must be within half its last unit of the exact
conversion.
"""

from __future__ import annotations

from omnibench.link.framing import FrameError, decode_chunk, encode_frame
from omnibench.sim.firmware.fil import ADC_CODES, AVCC_MV
from omnibench.sim.world import World

#: Hall codes tried: the ACS712-30A's output for -8 .. +8 A (the 2500 mV zero is code 512)
HALL_CODES = range(404, 624)
#: battery codes tried on A0 (6:1 divider: 17.1 .. 30 V)
BATTERY_CODES = range(700, 1024)


def centre_mv(code: int) -> float:
    """The pin voltage a code stands for: the centre of the codes' 1/1024 AVCC interval, mV."""
    return (code + 0.5) * AVCC_MV / ADC_CODES


def test_each_adc_code_reads_its_centre_within_half_a_unit(fil_elf) -> None:
    from omnibench.sim.firmware.board import STEP_US, FirmwareBoard

    rig = FirmwareBoard(World(seed=3), fil_elf, "omnibot-2019-hall")
    w = rig.wiring
    codes: dict[int, int] = {}

    def put_codes() -> None:  # the rig's inputs: the chosen codes, without the plant or any noise
        for ch, code in codes.items():
            rig.chip.set_adc_mv(ch, centre_mv(code))

    rig._update_inputs = put_codes  # type: ignore[method-assign]
    codec = rig.codec
    rig.feed(encode_frame(codec.encode_raw("CONFIGURE", 1, {"watchdog": 2000, "telemetry_rate": 200}), codec.crc))
    rest = bytearray()

    def telemetry_after(t_us: int) -> dict:
        """The first TELEMETRY sampled at or after board time t_us (µs)."""
        nonlocal rest
        for _ in range(50):
            rig.advance_to(rig.time_us + STEP_US)
            rest += rig.take_output()
            while 0 in rest:
                i = rest.index(0)
                chunk, rest = bytes(rest[:i]), rest[i + 1:]
                try:
                    msg = codec.decode_raw(decode_chunk(chunk, codec.crc))
                except FrameError:
                    continue
                if msg.name == "TELEMETRY" and msg.fields["time"] >= t_us:
                    return dict(msg.fields)
        raise AssertionError(f"no TELEMETRY sampled after {t_us} µs")

    hall, seen_hall, seen_battery = list(HALL_CODES), set(), set()
    try:
        for k, battery_code in enumerate(BATTERY_CODES):
            on = [hall[(5 * k + j) % len(hall)] for j in range(5)]  # A1..A4 (FL..RR), A5
            codes = {0: battery_code, **{1 + j: c for j, c in enumerate(on[:4])}, 5: on[4]}
            put_codes()
            f = telemetry_after(rig.time_us + 2 * STEP_US)  # a whole round of conversions after the change
            for j, code in enumerate(on[:4]):
                sense = rig.motor_map[j][2]  # the firmware reports a motor current signed with its wheel
                exact = (centre_mv(code) - w.hall_zero_mv) / w.hall_mv_per_a * 1000
                assert abs(sense * f["motor_current"][j] - exact) <= 0.5, (j, code, f["motor_current"][j], exact)
            exact = (centre_mv(on[4]) - w.hall_zero_mv) / w.hall_mv_per_a * 1000
            assert abs(f["battery_current"] - exact) <= 0.5, (on[4], f["battery_current"], exact)
            exact = centre_mv(battery_code) * w.battery_divider
            assert abs(f["battery_voltage"] - exact) <= 0.5, (battery_code, f["battery_voltage"], exact)
            seen_hall.update(on)
            seen_battery.add(battery_code)
    finally:
        rig.close()
    assert seen_hall == set(HALL_CODES) and seen_battery == set(BATTERY_CODES)
