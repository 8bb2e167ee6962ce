"""Drive the protocol core compiled for the host (firmware/test/host_main.c) line by line."""

from __future__ import annotations

import subprocess
from pathlib import Path

from omnibench.link.codec import Codec, Message
from omnibench.link.framing import decode_chunk


class CoreHost:
    """One core_host process: send a command, get the lines it answered."""

    def __init__(self, build: Path) -> None:
        self.proc = subprocess.Popen([str(build / "host" / "core_host")], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        self.codec = Codec()
        self.host_seq = 0

    def cmd(self, line: str) -> list[str]:
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()
        out = []
        while (got := self.proc.stdout.readline().rstrip("\n")) != ".":
            assert got, "core_host died"
            assert not got.startswith("error"), got
            out.append(got)
        return out

    def frames(self, lines: list[str]) -> list[Message]:
        """The board's frames among the answer lines, decoded by the host codec."""
        msgs = []
        for ln in lines:
            if ln.split()[0].endswith("tx"):
                wire = bytes.fromhex(ln.split()[1])
                assert wire[-1] == 0 and 0 not in wire[:-1]
                msgs.append(self.codec.decode_raw(decode_chunk(wire[:-1], self.codec.crc)))
        return msgs

    @staticmethod
    def duties(lines: list[str]) -> list[tuple[int, ...]]:
        return [tuple(int(x) for x in ln.split()[2:]) for ln in lines if ln.startswith("duty ")]

    def send(self, t_us: int, name: str, raw: dict | None = None, seq: int | None = None) -> list[str]:
        """A well-formed host frame at board time t_us."""
        seq = self.host_seq if seq is None else seq
        self.host_seq = (seq + 1) & 0xFFFF
        wire = self.codec.frame_raw(name, seq, raw or {})
        return self.cmd(f"rx {t_us} {wire.hex()}")

    def close(self) -> None:
        self.proc.stdin.close()
        self.proc.wait(timeout=5)
