"""The ThinTact LED line protocol, version 1 (see docs/led-protocol.md).

Every line, in both directions, is ASCII::

    <seq> <body>*<crc>\\n

``seq`` is two hex digits (00–ff) chosen by the host and echoed by the board, ``body`` is
the command or reply, and ``crc`` is two hex digits of CRC-8 (polynomial 0x07, initial
value 0, no reflection: CRC-8/SMBUS) over every byte before the ``*``.
"""

from __future__ import annotations

import numbers
from dataclasses import dataclass

from thintact_sdk.errors import InvalidValueError

PROTOCOL_VERSION = 1
MAX_LINE_BYTES = 96
"""Longest line either side accepts, newline included; longer input is garbage."""
LEVEL_MAX = 4095
"""Full-scale LED level on the wire (12-bit PWM duty)."""
ERROR_SEQ = 0xFF
"""Sequence number of the board's reply to a line whose own ``seq`` it could not read."""


def crc8(data: bytes) -> int:
    """CRC-8/SMBUS (polynomial 0x07, init 0x00, no reflection, no final xor) of ``data``."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc


def check_body(body: str) -> None:
    """Refuse a body that could break the framing: one line of printable ASCII words.

    Raises
    ------
    ValueError
        ``body`` holds a control byte (``\\n``, ``\\r``, NUL, ...), a ``*`` (the CRC
        separator), a non-ASCII character, or does not fit in one line.
    """
    for i, ch in enumerate(body):
        if not " " <= ch <= "~":
            raise ValueError(f"command body has byte {ord(ch):#04x} at {i} (only printable ASCII "
                             f"is allowed): {body[:40]!r}")
        if ch == "*":
            raise ValueError(f"command body has '*' (the checksum separator) at {i}: {body[:40]!r}")
    if not body.strip() or body != " ".join(body.split()):
        raise ValueError(f"command body must be words separated by single spaces: {body[:40]!r}")
    if len(body) + 7 > MAX_LINE_BYTES:  # "ss " + body + "*cc\n"
        raise ValueError(f"command body of {len(body)} bytes does not fit in one {MAX_LINE_BYTES}-byte line")


def encode_line(seq: int, body: str) -> bytes:
    """One protocol line (newline included) carrying ``body`` under sequence number ``seq``.

    Raises
    ------
    ValueError
        ``seq`` outside 0..255, or ``body`` refused by :func:`check_body`.
    """
    if not 0 <= seq <= 0xFF:
        raise ValueError(f"sequence number {seq} outside 0..255")
    check_body(body)
    payload = f"{seq:02x} {body}".encode("ascii")
    return payload + b"*" + f"{crc8(payload):02x}".encode("ascii") + b"\n"


class LineError(ValueError):
    """A received line does not follow the framing (bad CRC, missing fields, not ASCII)."""

    def __init__(self, message: str, crc_mismatch: bool = False, seq: int | None = None) -> None:
        super().__init__(message)
        self.crc_mismatch = crc_mismatch
        self.seq = seq


@dataclass(frozen=True)
class Line:
    """A decoded, checksum-verified line: ``seq`` and the whitespace-split body words."""

    seq: int
    words: tuple[str, ...]

    @property
    def body(self) -> str:
        return " ".join(self.words)


def decode_line(raw: bytes) -> Line:
    """Verify and split one received line (with or without its newline).

    Raises
    ------
    LineError
        When the line is not ASCII, lacks ``seq``/``*crc``, or its CRC does not match
        (``crc_mismatch`` set, ``seq`` filled in when it could be read).
    """
    text = raw.rstrip(b"\r\n")
    if len(text) + 1 > MAX_LINE_BYTES:
        raise LineError(f"line of {len(text)} bytes exceeds {MAX_LINE_BYTES - 1}")
    star = text.rfind(b"*")
    if star < 0 or len(text) - star != 3:
        raise LineError(f"no '*<crc>' trailer in {text[:40]!r}")
    payload, crc_txt = text[:star], text[star + 1:]
    try:
        payload.decode("ascii")
        crc_rx = int(crc_txt.decode("ascii"), 16)
    except (UnicodeDecodeError, ValueError):
        raise LineError(f"not an ASCII protocol line: {text[:40]!r}") from None
    seq: int | None = None
    head = payload.split(b" ", 1)[0]
    if len(head) == 2:
        try:
            seq = int(head.decode("ascii"), 16)
        except ValueError:
            seq = None
    if crc8(payload) != crc_rx:
        raise LineError(
            f"CRC mismatch (got {crc_rx:02x}, computed {crc8(payload):02x}) in {text[:40]!r}",
            crc_mismatch=True,
            seq=seq,
        )
    words = tuple(payload.decode("ascii").split())
    if seq is None or len(words) < 2:
        raise LineError(f"line {text[:40]!r} lacks a two-digit hex sequence number and a body")
    return Line(seq, words[1:])


def level_to_wire(level: float) -> int:
    """Map an intensity in [0, 1] to the 12-bit wire level (rounded).

    Raises
    ------
    InvalidValueError
        ``level`` is not a real number (bools and text included) or not in [0, 1] (NaN
        included).
    """
    if isinstance(level, bool) or not isinstance(level, numbers.Real):
        raise InvalidValueError(f"LED level must be a number in [0, 1], not {level!r}")
    if not 0.0 <= level <= 1.0:
        raise InvalidValueError(f"LED level {level} outside [0, 1]")
    return int(round(level * LEVEL_MAX))


def wire_to_level(value: int) -> float:
    """Map a 12-bit wire level back to [0, 1]."""
    return value / LEVEL_MAX
