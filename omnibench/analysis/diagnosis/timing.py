"""What a fitted timing effect says in the lab's words: which wheel gets its command first."""

from __future__ import annotations

from collections.abc import Mapping

from omnibench.effects.timing import PACKET_9600

WHEELS = ("FL", "FR", "RL", "RR")


def wheel_order_note(name: str, values: Mapping[str, float], se: Mapping[str, float]) -> str:
    """'' for other effects; for a latency: the order the wheels receive their commands."""
    short = {k.split(".")[-1]: v for k, v in values.items()}
    if name == "per_wheel_latency" and all(f"tau_{j}" in short for j in range(1, 5)):
        taus = [(short[f"tau_{j}"], WHEELS[j - 1]) for j in range(1, 5)]
        taus.sort()
        steps = [b[0] - a[0] for a, b in zip(taus, taus[1:])]
        return ("wheel order: " + " < ".join(f"{w} {1000 * t:.1f} ms" for t, w in taus)
                + f" (steps {', '.join(f'{1000 * d:.1f}' for d in steps)} ms; one 4-byte packet at 9600 baud "
                f"is {1000 * PACKET_9600:.2f} ms)")
    if name == "serial_command_latency" and "tau_packet" in short:
        se_p = next((v for k, v in se.items() if k.endswith("tau_packet")), float("nan"))
        return (f"commands reach the wheels one after another in the run's recorded send order, "
                f"{1000 * short['tau_packet']:.2f} ± {1000 * se_p:.2f} ms apart (one 4-byte packet at 9600 baud: "
                f"{1000 * PACKET_9600:.2f} ms)")
    return ""
