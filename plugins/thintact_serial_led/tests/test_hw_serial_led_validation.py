"""serial-led (issue 30): every setting and every call argument is validated, with an
InvalidValueError naming the field, before anything is sent; against the firmware emulator
on a real pty pair."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from thintact_serial_led import SerialLedController
from thintact_serial_led.emulator import LedFirmwareEmulator
from thintact_serial_led.settings import SerialLedSettings

from thintact_sdk.device.registry import get_registry
from thintact_sdk.errors import InvalidShapeError, InvalidValueError, ThinTactError

FAST = {"timeout_s": 0.15, "retries": 2}


@pytest.fixture(scope="module")
def emu():
    with LedFirmwareEmulator() as e:
        yield e


@pytest.fixture()
def led(emu):
    with SerialLedController(emu.port, dict(FAST)) as ctrl:
        ctrl.set_all([0.0] * 10)
        emu.state.log.clear()
        yield ctrl


@pytest.mark.parametrize(("key", "value"), [
    ("baudrate", "abc"), ("baudrate", 0), ("baudrate", -9600), ("baudrate", 115200.0),
    ("baudrate", True), ("baudrate", None),
    ("led_count", float("nan")), ("led_count", 0), ("led_count", 10.5), ("led_count", "10"),
    ("led_count", 100_000),
    ("timeout_s", float("nan")), ("timeout_s", float("inf")), ("timeout_s", 0), ("timeout_s", -1.0),
    ("timeout_s", "fast"), ("timeout_s", 3600),
    ("retries", -1), ("retries", 1.5), ("retries", "3"), ("retries", 10**9), ("retries", False),
    ("baud_rate", 9600),
])
def test_bad_setting_is_named(emu, key, value):
    with pytest.raises(InvalidValueError, match=rf"light\.settings\.{key}") as err:
        get_registry().create("light_controller", "serial-led", emu.port, {**FAST, key: value})
    assert "\n" not in str(err.value)


def test_settings_must_be_a_mapping_and_port_text(emu):
    with pytest.raises(InvalidValueError, match="light.settings"):
        SerialLedController(emu.port, [("baudrate", 9600)])  # type: ignore[arg-type]
    with pytest.raises(InvalidValueError, match="light.port"):
        SerialLedController(42, {})  # type: ignore[arg-type]


def test_good_settings_are_kept(emu):
    ctrl = SerialLedController(emu.port, {"baudrate": 9600, "timeout_s": 1, "retries": 0, "led_count": 10})
    assert (ctrl.baudrate, ctrl.timeout_s, ctrl.retries, ctrl.led_count) == (9600, 1.0, 0, 10)
    defaults = SerialLedSettings()
    plain = SerialLedController(emu.port)
    assert (plain.baudrate, plain.timeout_s, plain.retries) == (defaults.baudrate, defaults.timeout_s,
                                                                 defaults.retries)


@pytest.mark.parametrize(("index", "level", "named"), [
    (0, "x", "level"), (0, float("nan"), "level"), (0, float("inf"), "level"), (0, -0.1, "level"),
    (0, 1.5, "level"), (0, None, "level"), (0, True, "level"), (0, [0.5], "level"), (0, 1j, "level"),
    ("0", 0.5, "index"), (1.0, 0.5, "index"), (None, 0.5, "index"), (True, 0.5, "index"),
    (-1, 0.5, "index"), (10, 0.5, "index"), (10**30, 0.5, "index"),
])
def test_bad_set_intensity_arguments_send_nothing(led, emu, index, level, named):
    with pytest.raises(InvalidValueError, match=named):
        led.set_intensity(index, level)
    assert emu.state.log == []


def test_numpy_numbers_are_accepted(led, emu):
    led.set_intensity(np.int64(3), np.float32(0.5))
    led.set_all(np.full(10, 0.25))
    assert emu.state.log == ["SET 3 2048", "ALL " + " ".join(["1024"] * 10)]


@pytest.mark.parametrize("levels", [[0.5] * 9, [0.5] * 11, "0123456789", 0.5, None, {i: 0.5 for i in range(10)}])
def test_bad_set_all_shape_sends_nothing(led, emu, levels):
    with pytest.raises(InvalidShapeError, match="set_all"):
        led.set_all(levels)
    assert emu.state.log == []


@pytest.mark.parametrize(("at", "value"), [(0, "x"), (3, float("nan")), (9, 2.0), (5, None), (7, False)])
def test_bad_level_in_set_all_is_named_by_position(led, emu, at, value):
    levels: list[object] = [0.5] * 10
    levels[at] = value
    with pytest.raises(InvalidValueError, match=rf"levels\[{at}\]"):
        led.set_all(levels)  # type: ignore[arg-type]
    assert emu.state.log == []


def test_request_body_must_be_text(led, emu):
    with pytest.raises(InvalidValueError, match="text"):
        led.request(b"GET")  # type: ignore[arg-type]
    assert emu.state.log == []


@settings(max_examples=40, deadline=None)
@given(index=st.one_of(st.integers(-5, 15), st.floats(allow_nan=True), st.text(max_size=3), st.none()),
       level=st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-3, 3),
                       st.text(max_size=3), st.booleans(), st.none()))
def test_fuzzed_arguments_are_applied_or_refused_cleanly(emu, index, level):
    with SerialLedController(emu.port, dict(FAST)) as ctrl:
        valid = (isinstance(index, int) and 0 <= index < 10 and not isinstance(level, bool | str)
                 and level is not None and 0 <= level <= 1)
        try:
            ctrl.set_intensity(index, level)
        except ThinTactError as err:
            assert not valid, err
            assert isinstance(err, InvalidValueError)
        else:
            assert valid
            assert emu.state.levels[index] == round(float(level) * 4095)
