"""Bytes on a serial port: the protocol description, codec (COBS + CRC), board client, ammeter.

Knows nothing of friction or procedures. Procedures use `Board` (omnibench.link.board);
see docs/protocol.md for the wire format.
"""
