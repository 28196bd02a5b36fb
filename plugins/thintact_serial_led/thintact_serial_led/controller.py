"""``serial-led``: the sensor's LEDs through a board speaking protocol v1 over a serial port.

Every request carries a fresh sequence number and a CRC-8; the controller waits at most
``timeout_s`` for the matching reply and retries up to ``retries`` times when the reply is
missing, garbled or reports a checksum error. The board repeats (but does not re-execute)
the line it has just executed (same sequence number and body), so retries are safe.

Errors
------
DeviceTimeoutError  no reply at all after every retry (board silent or not powered)
ProtocolError       only garbage / bad checksums came back, or the board refused the command
DeviceLostError     the port vanished (unplugged, closed by the other end)
DeviceNotFoundError the port cannot be opened
InvalidValueError   a bad setting (``light.settings.<key>``) or call argument (index, level)
"""

from __future__ import annotations

import math
import numbers
import operator
import time
from collections.abc import Mapping
from typing import Any

import serial

try:  # POSIX: tcdrain/tcflush on a vanished pty raise termios.error, which is not an OSError
    from termios import error as _TermiosError
    _PORT_ERRORS: tuple[type[BaseException], ...] = (serial.SerialException, OSError, _TermiosError)
except ImportError:  # pragma: no cover - Windows has no termios
    _PORT_ERRORS = (serial.SerialException, OSError)

from thintact_sdk.errors import (
    DeviceError,
    DeviceLostError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    InvalidShapeError,
    InvalidValueError,
    ProtocolError,
)
from thintact_sdk.interfaces import LightController
from thintact_serial_led.protocol import (
    MAX_LINE_BYTES,
    LineError,
    decode_line,
    encode_line,
    level_to_wire,
    wire_to_level,
)
from thintact_serial_led.settings import parse_settings


class SerialLedController(LightController):
    """A :class:`~thintact_sdk.interfaces.LightController` over pyserial.

    Parameters
    ----------
    port
        Device path (``/dev/ttyACM0``), pty path, or any pyserial URL.
    settings
        ``baudrate`` (115200), ``timeout_s`` per attempt (0.25), ``retries`` after the first
        attempt (3), ``led_count`` expected (10; checked against the board's ``STA``);
        validated by :class:`thintact_serial_led.settings.SerialLedSettings`.

    Raises
    ------
    DeviceNotFoundError
        No port given.
    InvalidValueError
        ``port`` is not text, or a setting is unknown, mistyped or out of range (the
        message names ``light.port`` or ``light.settings.<key>``).
    """

    name = "serial-led"

    def __init__(self, port: str | None, settings: Mapping[str, Any] | None = None) -> None:
        parsed = parse_settings(settings)
        if port is not None and not isinstance(port, str):
            raise InvalidValueError(f"light.port must be a device path or pyserial URL, not {port!r}")
        if not port:
            raise DeviceNotFoundError(
                "serial-led needs a port: set light.port in the profile (e.g. /dev/ttyACM0; "
                "'thintact devices' lists serial ports)"
            )
        self.port = port
        self.baudrate = parsed.baudrate
        self.timeout_s = parsed.timeout_s
        self.retries = parsed.retries
        self._expected_leds = parsed.led_count
        self._led_count = self._expected_leds
        self.colors: str | None = None
        self._serial: serial.SerialBase | None = None
        self._seq = 0
        self._rx = b""
        self._lost = False
        self.stats = {"requests": 0, "retries": 0, "bad_lines": 0}

    # -- lifecycle --------------------------------------------------------------------
    def open(self) -> None:
        """Open the port and check the board answers (``STA``) with the expected LED count."""
        try:
            self._serial = serial.serial_for_url(
                self.port, baudrate=self.baudrate, timeout=0.02, write_timeout=self.timeout_s
            )
        except (serial.SerialException, OSError, ValueError) as err:
            raise DeviceNotFoundError(f"cannot open LED controller port {self.port}: {err}") from None
        try:
            self._serial.reset_input_buffer()
        except _PORT_ERRORS:
            pass
        self._seq = int(time.monotonic_ns() % 255)
        self._lost = False
        try:
            status = self.status()
        except BaseException:
            self.close()
            raise
        leds = status.get("leds", str(self._expected_leds))
        if not (leds.isascii() and leds.isdigit()):
            self.close()
            raise ProtocolError(f"LED board on {self.port} reports a non-integer LED count {leds!r}")
        count = int(leds)
        if count != self._expected_leds:
            self.close()
            raise ProtocolError(
                f"LED board on {self.port} drives {count} LEDs, the profile expects "
                f"{self._expected_leds} (settings.led_count)"
            )
        self._led_count = count
        self.colors = status.get("colors")

    def close(self) -> None:
        """Close the port. Safe to call twice."""
        if self._serial is not None:
            try:
                self._serial.close()
            except _PORT_ERRORS:
                pass
            self._serial = None

    # -- LightController API ------------------------------------------------------------
    @property
    def led_count(self) -> int:
        return self._led_count

    def set_intensity(self, index: int, level: float) -> None:
        """Set LED ``index`` (0-based integer) to ``level`` (a real number in [0, 1]; 12-bit
        on the wire).

        Raises
        ------
        InvalidValueError
            ``index`` is not an integer in ``0..led_count-1`` or ``level`` not a finite
            number in [0, 1]; nothing is sent.
        """
        try:
            if isinstance(index, bool):
                raise TypeError
            position = operator.index(index)
        except TypeError:
            raise InvalidValueError(f"LED index must be an integer, not {index!r}") from None
        if not 0 <= position < self._led_count:
            raise InvalidValueError(f"LED index {position} outside 0..{self._led_count - 1}")
        self.request(f"SET {position} {level_to_wire(_level(level, 'level'))}")

    def set_all(self, levels: list[float]) -> None:
        """Set every LED at once (one ``ALL`` command, applied atomically by the board).

        Raises
        ------
        InvalidShapeError
            ``levels`` is not a sequence of ``led_count`` values.
        InvalidValueError
            A level is not a finite number in [0, 1] (named ``levels[i]``); nothing is sent.
        """
        if isinstance(levels, str | bytes | Mapping) or not hasattr(levels, "__len__"):
            raise InvalidShapeError(f"set_all needs a sequence of {self._led_count} levels, "
                                    f"not {type(levels).__name__}")
        values = list(levels)
        if len(values) != self._led_count:
            raise InvalidShapeError(f"set_all needs {self._led_count} levels, got {len(values)}")
        wire = [level_to_wire(_level(v, f"levels[{i}]")) for i, v in enumerate(values)]
        self.request("ALL " + " ".join(str(w) for w in wire))

    def get_intensities(self) -> list[float]:
        """The levels the board applies, in [0, 1]."""
        words = self.request("GET")
        if len(words) != self._led_count:
            raise ProtocolError(f"GET returned {len(words)} levels, expected {self._led_count}")
        try:
            return [wire_to_level(int(w)) for w in words]
        except ValueError:
            raise ProtocolError(f"GET returned non-integer levels {' '.join(words)!r}") from None

    def firmware_version(self) -> str:
        return " ".join(self.request("VER"))

    def status(self) -> dict[str, str]:
        """The board's ``STA`` reply as a dict (``leds``, ``colors``, ``temp_c``, ``faults``...)."""
        out: dict[str, str] = {}
        for word in self.request("STA"):
            key, sep, value = word.partition("=")
            if not sep:
                raise ProtocolError(f"malformed STA field {word!r}")
            out[key] = value
        return out

    # -- transport ----------------------------------------------------------------------
    def request(self, body: str) -> list[str]:
        """Send one command and return the words after ``OK`` of its reply.

        Raises
        ------
        DeviceTimeoutError, ProtocolError, DeviceLostError
            See the module docstring.
        """
        if not isinstance(body, str):
            raise InvalidValueError(f"an LED board command must be text, not {type(body).__name__}")
        if self._serial is None:
            if self._lost:
                raise DeviceLostError(f"LED controller port {self.port} vanished earlier; open it again")
            raise DeviceError(f"LED controller on {self.port} is not open; call open() first")
        self._seq = (self._seq + 1) % 255  # 0xff is reserved for the board's framing errors
        seq = self._seq
        try:
            line = encode_line(seq, body)
        except ValueError as err:  # a control byte, '*' or non-ASCII: never sent
            raise ProtocolError(f"refusing to send to the LED board on {self.port}: {err}") from None
        self.stats["requests"] += 1
        problems: list[str] = []
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats["retries"] += 1
            self._write(line)
            deadline = time.monotonic() + self.timeout_s
            while True:
                raw = self._read_line(deadline)
                if raw is None:
                    break
                try:
                    reply = decode_line(raw)
                except LineError as err:
                    self.stats["bad_lines"] += 1
                    problems.append(str(err))
                    if err.crc_mismatch and err.seq == seq:
                        break  # our reply, damaged in transit: resend now
                    continue
                if reply.seq != seq:
                    if reply.words[:2] == ("ERR", "SYN") or reply.words[:2] == ("ERR", "CRC"):
                        problems.append(f"board could not read our line: {reply.body}")
                        if reply.words[1] == "CRC":
                            break
                    continue  # stale reply to an earlier attempt
                if reply.words[0] == "OK":
                    return list(reply.words[1:])
                if reply.words[:2] == ("ERR", "CRC"):
                    problems.append("board saw a checksum error in our command")
                    break
                raise ProtocolError(f"LED board refused {body.split()[0]!r}: {reply.body}")
        tries = self.retries + 1
        if problems:
            raise ProtocolError(
                f"LED board on {self.port}: no valid reply to {body.split()[0]!r} after {tries} "
                f"attempts; last problem: {problems[-1]}"
            )
        raise DeviceTimeoutError(
            f"LED board on {self.port} did not answer {body.split()[0]!r} within "
            f"{self.timeout_s:.2f} s ({tries} attempts); is it powered and running protocol v1?"
        )

    def _write(self, data: bytes) -> None:
        assert self._serial is not None
        try:
            self._serial.write(data)
            self._serial.flush()
        except serial.SerialTimeoutException:
            raise DeviceTimeoutError(f"writing to the LED board on {self.port} timed out") from None
        except _PORT_ERRORS as err:
            self.close()
            self._lost = True
            raise DeviceLostError(f"LED controller port {self.port} vanished: {err}") from None

    def _read_line(self, deadline: float) -> bytes | None:
        """Next complete line received before ``deadline``, or None."""
        assert self._serial is not None
        while b"\n" not in self._rx:
            if time.monotonic() >= deadline:
                return None
            try:
                chunk = self._serial.read(max(1, self._serial.in_waiting or 1))
            except _PORT_ERRORS as err:
                self.close()
                self._lost = True
                raise DeviceLostError(f"LED controller port {self.port} vanished: {err}") from None
            self._rx += chunk
            if b"\n" not in self._rx and len(self._rx) > MAX_LINE_BYTES:
                self._rx = b""
                return b"\x00overlong line without newline"
        line, self._rx = self._rx.split(b"\n", 1)
        return line


def _level(value: object, name: str) -> float:
    """``value`` as a finite float in [0, 1] (a real number, not a bool or text).

    Raises
    ------
    InvalidValueError
        Naming ``name``.
    """
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise InvalidValueError(f"LED {name} must be a number in [0, 1], not {value!r}")
    level = float(value)
    if not math.isfinite(level) or not 0.0 <= level <= 1.0:
        raise InvalidValueError(f"LED {name} {value!r} outside [0, 1]")
    return level
