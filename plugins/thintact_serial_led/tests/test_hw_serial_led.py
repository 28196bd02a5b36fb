"""serial-led against the firmware emulator on a real pty pair: normal use and faults."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest
import serial
from thintact_serial_led.emulator import LedFirmwareEmulator
from thintact_serial_led.protocol import LineError, crc8, decode_line, encode_line

from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import (
    DeviceError,
    DeviceLostError,
    DeviceNotFoundError,
    DeviceTimeoutError,
    ProtocolError,
)

FAST = {"timeout_s": 0.15, "retries": 2}


@pytest.fixture()
def emu():
    with LedFirmwareEmulator() as e:
        yield e


@pytest.fixture()
def led(emu):
    ctrl = get_registry().create("light_controller", "serial-led", emu.port, dict(FAST))
    ctrl.open()
    yield ctrl
    ctrl.close()


def test_crc8_reference_value():
    # CRC-8/SMBUS check value of the standard test string
    assert crc8(b"123456789") == 0xF4
    line = encode_line(0x2A, "SET 3 4095")
    assert line.startswith(b"2a SET 3 4095*") and line.endswith(b"\n")
    assert decode_line(line).words == ("SET", "3", "4095")
    with pytest.raises(LineError) as err:
        decode_line(line.replace(b"4095", b"4094"))
    assert err.value.crc_mismatch and err.value.seq == 0x2A


def test_set_get_version_status(led, emu):
    assert led.led_count == 10 and led.colors == "RRGGBBWWWW"
    assert led.firmware_version().startswith("thintact-led-emu 1.0.0")
    levels = [i / 9 for i in range(10)]
    led.set_all(levels)
    back = led.get_intensities()
    assert max(abs(a - b) for a, b in zip(back, levels, strict=True)) <= 0.5 / 4095
    led.set_intensity(4, 1.0)
    assert emu.state.levels[4] == 4095
    assert float(led.status()["temp_c"]) == pytest.approx(31.5)


def test_board_refuses_bad_argument(led):
    with pytest.raises(ProtocolError, match="ARG"):
        led.request("SET 99 10")
    with pytest.raises(ValueError):
        led.set_intensity(10, 0.5)
    with pytest.raises(ValueError):
        led.set_all([0.5] * 9)


def test_one_corrupted_reply_is_retried_and_not_executed_twice(led, emu):
    emu.corrupt_replies = 1
    led.set_intensity(2, 0.5)
    assert led.stats["retries"] == 1
    assert emu.state.log.count("SET 2 2048") == 1  # the retry was answered from the cache
    assert led.get_intensities()[2] == pytest.approx(2048 / 4095)


def test_persistently_corrupted_checksum_is_a_protocol_error(led, emu):
    emu.corrupt_replies = -1
    t0 = time.monotonic()
    with pytest.raises(ProtocolError, match="CRC mismatch"):
        led.get_intensities()
    assert time.monotonic() - t0 < 2.0


def test_garbage_on_the_line_is_a_protocol_error(led, emu):
    emu.garbage_replies = True
    with pytest.raises(ProtocolError, match="no valid reply"):
        led.set_intensity(0, 0.1)


def test_silence_is_a_timeout(led, emu):
    emu.silent = True
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match="did not answer"):
        led.get_intensities()
    # 3 attempts × 0.15 s, never a hang
    assert time.monotonic() - t0 < 1.5


def test_slow_board_within_timeout_works(led, emu):
    emu.reply_delay_s = 0.05
    assert len(led.get_intensities()) == 10


def test_vanished_port_is_device_lost(led, emu):
    emu.unplug()
    t0 = time.monotonic()
    with pytest.raises(DeviceLostError, match="vanished"):
        led.set_all([0.2] * 10)
    assert time.monotonic() - t0 < 1.5
    with pytest.raises(DeviceLostError, match="vanished earlier"):
        led.get_intensities()


def test_missing_port_and_wrong_led_count(emu):
    reg = get_registry()
    with pytest.raises(DeviceNotFoundError, match="light.port"):
        reg.create("light_controller", "serial-led", None, {})
    ctrl = reg.create("light_controller", "serial-led", "/dev/nonexistent-tty", {})
    with pytest.raises(DeviceNotFoundError, match="cannot open"):
        ctrl.open()
    ctrl = reg.create("light_controller", "serial-led", emu.port, {**FAST, "led_count": 8})
    with pytest.raises(ProtocolError, match="drives 10 LEDs"):
        ctrl.open()


def test_host_side_corruption_is_reported_by_board(emu):
    with serial.serial_for_url(emu.port, timeout=1.0) as port:
        port.write(b"01 GET*00\n")
        reply = decode_line(port.readline())
        assert reply.seq == 1 and reply.words[:2] == ("ERR", "CRC")
        port.write(b"\x00\x01noise\n")
        assert decode_line(port.readline()).words[:2] == ("ERR", "SYN")


def test_emulator_module_runs_as_a_program():
    env = dict(os.environ)
    proc = subprocess.Popen(
        [sys.executable, "-m", "thintact_serial_led.emulator"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )
    try:
        port = proc.stdout.readline().strip()
        assert port.startswith("/dev/pts/")
        from thintact_serial_led import SerialLedController

        with SerialLedController(port, FAST) as ctrl:
            ctrl.set_all([1.0] * 10)
            assert ctrl.get_intensities() == [1.0] * 10
    finally:
        proc.terminate()
        assert proc.wait(timeout=5) == 0


def test_reused_sequence_number_with_a_new_command_is_executed(emu):
    with serial.serial_for_url(emu.port, timeout=1.0) as port:
        port.write(encode_line(7, "SET 1 100"))
        assert decode_line(port.readline()).words == ("OK",)
        port.write(encode_line(7, "SET 1 100"))  # a retry: answered, not executed again
        assert decode_line(port.readline()).words == ("OK",)
        port.write(encode_line(7, "GET"))  # same seq, new command (a restarted host)
        assert decode_line(port.readline()).words[2] == "100"
    assert emu.state.log == ["SET 1 100", "GET"]


def test_silent_board_at_open_times_out_and_releases_the_port(emu):
    emu.silent = True
    ctrl = get_registry().create("light_controller", "serial-led", emu.port, dict(FAST))
    t0 = time.monotonic()
    with pytest.raises(DeviceTimeoutError, match="STA"):
        ctrl.open()
    assert time.monotonic() - t0 < 1.5
    with pytest.raises(DeviceError, match="not open") as err:
        ctrl.get_intensities()
    assert not isinstance(err.value, DeviceLostError)
