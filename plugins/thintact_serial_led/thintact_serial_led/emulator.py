"""A firmware emulator: the LED board's side of the protocol, on a pseudo-terminal.

Run it as a stand-in board::

    python -m thintact_serial_led.emulator        # prints the port path, Ctrl-C to stop

and point a profile's ``light.port`` (or ``thintact devices``) at the printed path.
Tests use :class:`LedFirmwareEmulator` directly; its fault switches (``silent``,
``garbage_replies``, ``corrupt_replies``, ``reply_delay_s``) reproduce a misbehaving board,
and :meth:`LedFirmwareEmulator.unplug` makes the port vanish.
"""

from __future__ import annotations

import argparse
import os
import pty
import select
import signal
import sys
import threading
import time
import tty
from dataclasses import dataclass, field

from thintact_sdk.errors import InvalidShapeError
from thintact_serial_led.protocol import (
    ERROR_SEQ,
    LEVEL_MAX,
    MAX_LINE_BYTES,
    LineError,
    decode_line,
    encode_line,
)

FIRMWARE_VERSION = "thintact-led-emu 1.0.0 proto=1"
DEFAULT_COLORS = "RRGGBBWWWW"


@dataclass
class EmulatorState:
    """What the emulated board holds: levels (0..4095), colours, counters."""

    levels: list[int]
    colors: str
    temperature_c: float = 31.5
    faults: int = 0
    commands: int = 0
    crc_errors: int = 0
    log: list[str] = field(default_factory=list)


class LedFirmwareEmulator:
    """The LED board firmware, speaking protocol v1 on the master side of a pty.

    Parameters
    ----------
    led_count
        Number of LEDs (10 on the ThinTact).
    colors
        One letter per LED (R, G, B, W).

    Attributes
    ----------
    port
        Path of the pty slave that a host opens as its serial port.
    silent
        Swallow every command without replying (a hung board).
    garbage_replies
        Answer every command with line noise instead of a reply.
    corrupt_replies
        Number of upcoming replies sent with a wrong CRC (-1: all of them).
    reply_delay_s
        Wait this long before each reply.
    """

    def __init__(self, led_count: int = 10, colors: str = DEFAULT_COLORS) -> None:
        if len(colors) != led_count:
            raise InvalidShapeError(f"colors {colors!r} must have one letter per LED ({led_count})")
        self.state = EmulatorState(levels=[0] * led_count, colors=colors)
        self.silent = False
        self.garbage_replies = False
        self.corrupt_replies = 0
        self.reply_delay_s = 0.0
        self._started = time.monotonic()
        self._last_line: bytes | None = None
        self._last_reply: bytes | None = None
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._master_fd, self._slave_fd = pty.openpty()
        tty.setraw(self._slave_fd)  # no echo, no line editing: a byte pipe like a USB CDC port
        self.port = os.ttyname(self._slave_fd)
        self._thread = threading.Thread(target=self._serve, name="led-emulator", daemon=True)

    # -- lifecycle --------------------------------------------------------------------
    def start(self) -> LedFirmwareEmulator:
        """Start answering in a background thread; returns self."""
        self._thread.start()
        return self

    def stop(self) -> None:
        """Stop answering and release the pty. Safe to call twice."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        for fd in (self._master_fd, self._slave_fd):
            try:
                os.close(fd)
            except OSError:
                continue
        self._master_fd = self._slave_fd = -1

    def unplug(self) -> None:
        """Make the port vanish, as when the USB cable is pulled: the host's I/O fails."""
        self.stop()

    def __enter__(self) -> LedFirmwareEmulator:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- serving ----------------------------------------------------------------------
    def _serve(self) -> None:
        buf = b""
        while not self._stop.is_set():
            try:
                ready, _, _ = select.select([self._master_fd], [], [], 0.05)
                if not ready:
                    continue
                chunk = os.read(self._master_fd, 4096)
            except OSError:
                return
            if not chunk:
                return
            buf += chunk
            while b"\n" in buf:
                line, buf = buf.split(b"\n", 1)
                self._handle(line)
            if len(buf) > MAX_LINE_BYTES:
                buf = b""
                self._send(encode_line(ERROR_SEQ, "ERR SYN line too long"))

    def _send(self, data: bytes) -> None:
        if self.silent:
            return
        if self.reply_delay_s:
            time.sleep(self.reply_delay_s)
        if self.garbage_replies:
            data = b"\x00\xff#?garbage~~" + bytes(range(0x80, 0x90)) + b"\n"
        elif self.corrupt_replies:
            bad_crc = (int(data[-3:-1], 16) ^ 0x5A) & 0xFF
            data = data[:-3] + f"{bad_crc:02x}".encode() + b"\n"
            if self.corrupt_replies > 0:
                self.corrupt_replies -= 1
        try:
            os.write(self._master_fd, data)
        except OSError:
            self._stop.set()

    def _handle(self, raw: bytes) -> None:
        raw = raw.rstrip(b"\r")
        if not raw:
            return
        try:
            line = decode_line(raw)
        except LineError as err:
            if err.crc_mismatch:
                self.state.crc_errors += 1
                seq = err.seq if err.seq is not None else ERROR_SEQ
                self._send(encode_line(seq, "ERR CRC checksum mismatch"))
            else:
                self._send(encode_line(ERROR_SEQ, "ERR SYN unreadable line"))
            return
        if raw == self._last_line and self._last_reply is not None:
            # a retry of the command just executed (same seq, same body): repeat the
            # answer, do not act twice
            self._send(self._last_reply)
            return
        with self._lock:
            body = self._execute(line.words)
        reply = encode_line(line.seq, body)
        self._last_line, self._last_reply = raw, reply
        self.state.commands += 1
        self.state.log.append(line.body)
        self._send(reply)

    def _execute(self, words: tuple[str, ...]) -> str:
        cmd, args = words[0].upper(), words[1:]
        n = len(self.state.levels)
        if cmd == "VER" and not args:
            return f"OK {FIRMWARE_VERSION}"
        if cmd == "GET" and not args:
            return "OK " + " ".join(str(v) for v in self.state.levels)
        if cmd == "STA" and not args:
            uptime_ms = int((time.monotonic() - self._started) * 1000)
            return (
                f"OK leds={n} colors={self.state.colors} temp_c={self.state.temperature_c:.1f} "
                f"faults={self.state.faults:02x} uptime_ms={uptime_ms}"
            )
        if cmd == "SET":
            if len(args) != 2:
                return "ERR SYN SET takes <index> <level>"
            values = _ints(args)
            if values is None:
                return "ERR SYN SET arguments must be integers"
            idx, level = values
            if not 0 <= idx < n:
                return f"ERR ARG index {idx} outside 0..{n - 1}"
            if not 0 <= level <= LEVEL_MAX:
                return f"ERR ARG level {level} outside 0..{LEVEL_MAX}"
            self.state.levels[idx] = level
            return "OK"
        if cmd == "ALL":
            if len(args) != n:
                return f"ERR SYN ALL takes {n} levels, got {len(args)}"
            values = _ints(args)
            if values is None:
                return "ERR SYN ALL arguments must be integers"
            if any(not 0 <= v <= LEVEL_MAX for v in values):
                return f"ERR ARG levels must be within 0..{LEVEL_MAX}"
            self.state.levels[:] = values
            return "OK"
        if cmd in ("VER", "GET", "STA"):
            return f"ERR SYN {cmd} takes no arguments"
        return f"ERR CMD unknown command {cmd[:12]}"


def _ints(words: tuple[str, ...]) -> list[int] | None:
    try:
        return [int(w, 10) for w in words]
    except ValueError:
        return None


def main(argv: list[str] | None = None) -> int:
    """Run an emulated board until interrupted; prints the port to open."""
    ap = argparse.ArgumentParser(
        prog="python -m thintact_serial_led.emulator",
        description="Emulate a ThinTact LED board (protocol v1) on a pseudo-terminal.",
    )
    ap.add_argument("--leds", type=int, default=10, help="number of LEDs (default 10)")
    ap.add_argument("--colors", default=DEFAULT_COLORS, help="one letter per LED (R, G, B, W)")
    args = ap.parse_args(argv)
    try:
        emu = LedFirmwareEmulator(args.leds, args.colors)
    except ValueError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    with emu:
        print(emu.port, flush=True)
        print(f"emulating {args.leds} LEDs ({args.colors}); Ctrl-C to stop", file=sys.stderr)
        try:
            while not stop.wait(0.2):
                continue
        except KeyboardInterrupt:
            pass
    return 0


if __name__ == "__main__":
    sys.exit(main())
