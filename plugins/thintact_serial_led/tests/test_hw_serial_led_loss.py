"""serial-led (issue 18): killing the board mid-loop is always DeviceLostError, never a raw
termios/OS error; a command body cannot smuggle a second command past the framing."""

from __future__ import annotations

import subprocess
import sys
import termios
import threading

import pytest
import serial
from thintact_serial_led import SerialLedController
from thintact_serial_led.emulator import LedFirmwareEmulator
from thintact_serial_led.protocol import encode_line

from thintact_sdk.errors import DeviceLostError, ProtocolError

FAST = {"timeout_s": 0.5, "retries": 1}


@pytest.mark.timeout(120)
@pytest.mark.parametrize("kill_after_s", [0.0, 0.02, 0.05, 0.1, 0.2, 0.35])
def test_killing_the_board_during_set_all_is_device_lost(kill_after_s: float) -> None:
    proc = subprocess.Popen([sys.executable, "-m", "thintact_serial_led.emulator"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        assert proc.stdout is not None
        port = proc.stdout.readline().strip()
        ctrl = SerialLedController(port, dict(FAST))
        ctrl.open()
        killer = threading.Timer(kill_after_s, proc.kill)
        killer.start()
        n = 0
        with pytest.raises(DeviceLostError, match="vanished"):
            while n < 100_000:
                ctrl.set_all([(n % 10) / 10] * 10)
                n += 1
        killer.join()
        with pytest.raises(DeviceLostError):
            ctrl.set_all([0.0] * 10)
        ctrl.close()
    finally:
        proc.kill()
        proc.wait(timeout=5)


@pytest.mark.parametrize("body", ["SET 1 10\n00 ALL 0 0", "SET 1 10\r", "SET 1\x0010", "SET 1 10*00",
                                  "SET 1 10\u00e9", "SET  1 10", "", "A" * 90])
def test_body_that_breaks_framing_is_refused(body: str) -> None:
    with pytest.raises(ValueError):
        encode_line(1, body)


def test_controller_never_sends_an_injected_line() -> None:
    with LedFirmwareEmulator() as emu, SerialLedController(emu.port, dict(FAST)) as ctrl:
        ctrl.set_all([0.0] * 10)
        with pytest.raises(ProtocolError, match="0x0a"):
            ctrl.request("SET 1 10\n01 ALL 4095 4095 4095 4095 4095 4095 4095 4095 4095 4095")
        assert ctrl.get_intensities() == [0.0] * 10


class _FailingPort:
    """Wraps the real port; ``method`` raises ``exc`` (what a vanished tty does at that call)."""

    def __init__(self, port: object, method: str, exc: BaseException) -> None:
        self._port, self._method, self._exc = port, method, exc

    def __getattr__(self, name: str) -> object:
        if name == self._method:
            if name == "in_waiting":
                raise self._exc
            def boom(*_a: object, **_k: object) -> None:
                raise self._exc
            return boom
        return getattr(self._port, name)


@pytest.mark.parametrize("method", ["write", "flush", "read", "in_waiting"])
@pytest.mark.parametrize("exc", [termios.error(5, "Input/output error"), OSError(5, "Input/output error"),
                                 serial.SerialException("device reports readiness to read but returned no data")])
def test_every_os_level_port_error_is_device_lost(method: str, exc: BaseException) -> None:
    with LedFirmwareEmulator() as emu:
        ctrl = SerialLedController(emu.port, dict(FAST))
        ctrl.open()
        ctrl._serial = _FailingPort(ctrl._serial, method, exc)  # type: ignore[assignment]
        with pytest.raises(DeviceLostError, match="vanished"):
            ctrl.set_all([0.5] * 10)
        ctrl.close()
