"""Frame integrity fit for a motor command: <= 1 accepted corrupt frame per 1e9 at 1 % byte
errors, computed and measured by fuzzing the real deframer and codec (issue 12)."""

from __future__ import annotations

from omnibench.link.codec import Codec
from omnibench.link.fuzz import fuzz_frames, predicted_rate, spec_with_width

P = 0.01


def test_model_holds_where_accepts_are_measurable_and_gives_under_1e9_at_32_bits() -> None:
    narrow = fuzz_frames(12_000, P, width=8, seed=1)
    wire8 = Codec(spec_with_width(8)).wire_size("TELEMETRY")
    assert narrow.corrupted > 3000  # 1 % of bytes really hit about a third of the frames
    assert narrow.accepted_bad >= 1  # the fuzzer does find frames a weak check lets through
    assert narrow.rate <= 1.5 * predicted_rate(wire8, P, 8)  # the model is an upper bound
    wire32 = Codec().wire_size("TELEMETRY")
    assert wire32 <= 48  # the telemetry budget: 48 bytes per sample at 240 Hz
    assert predicted_rate(wire32, P, 32) * 1e9 <= 1.0


def test_crc32_accepts_no_corrupt_frame_and_every_intact_one() -> None:
    r = fuzz_frames(12_000, P, seed=2)
    assert r.width == 32 and r.accepted_bad == 0
    assert r.accepted_good >= r.frames - r.corrupted - 50  # resynchronised after each bad frame
