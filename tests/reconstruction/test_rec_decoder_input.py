"""A third-party decoder written against docs/plugins.md: it declares what it takes
(``input``: ``"signal"``, ``"raw"`` or ``"binned"`` with ``sensor_bin``), is registered through
the registry like any plugin, and a virtual Sensor hands its one entry point ``decode``
exactly that."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

import thintact_sdk
from thintact_sdk.device.cameras import to_measurement
from thintact_sdk.device.registry import PluginRegistry
from thintact_sdk.device.sensor import Sensor
from thintact_sdk.errors import InvalidValueError
from thintact_sdk.formats.profiles import DecoderConfig, Profile, load_profile
from thintact_sdk.interfaces import Decoder, DecoderInput


class _Probe(Decoder):
    """Remembers what ``decode`` was called with; returns a scene of the frame's mean."""

    def __init__(self, profile: Profile) -> None:
        self.scene = (profile.scene.rows, profile.scene.cols)
        self.calls: list[tuple[np.ndarray, tuple[Any, ...]]] = []

    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        return self._record(frame, black_level_dn)

    def _record(self, frame: np.ndarray, *rest: Any) -> np.ndarray:
        self.calls.append((np.array(frame, copy=True), rest))
        return np.full((*self.scene, frame.shape[2]), float(np.mean(frame)), np.float32)


class SignalProbe(_Probe):
    """The simplest decoder the docs allow: no ``input`` declared, ``decode(signal)`` only."""

    name = "probe-signal"

    def decode(self, signal: np.ndarray) -> np.ndarray:  # type: ignore[override]
        return self._record(signal)


class RawProbe(_Probe):
    name = "probe-raw"
    input = "raw"


class BinnedProbe(_Probe):
    name = "probe-binned"
    input = "binned"
    sensor_bin = 2


class _ProbePlugin:
    @thintact_sdk.hookimpl
    def thintact_decoders(self) -> list[thintact_sdk.Component]:
        return [thintact_sdk.Component(cls.name, lambda p, s, cls=cls: cls(p), "probe")
                for cls in (SignalProbe, RawProbe, BinnedProbe)]


def _sensor(decoder: str) -> Sensor:
    registry = PluginRegistry()
    registry.load_builtins()
    registry.load_entry_points()
    registry.register(_ProbePlugin(), "probe-decoders")
    assert "virtual" in registry.components("camera"), "the virtual camera plugin is not installed"
    base = load_profile("virtual-mini")  # 128 × 160 × 3 measurement, 50 × 64 scene, black 64 DN
    profile = base.model_copy(update={"decoder": DecoderConfig(plugin=decoder)}, deep=True)
    return Sensor(profile, registry=registry)


@pytest.mark.parametrize("name", ["probe-signal", "probe-raw", "probe-binned"])
def test_a_registered_decoder_gets_what_it_declared(name: str) -> None:
    with _sensor(name) as sensor:
        raw = sensor.read_raw()
        image = sensor.reconstruct(sensor.decoder_input(raw))
        decoder = sensor.decoder
    assert isinstance(decoder, _Probe) and decoder.name == name
    assert image.shape == (50, 64, 3) and image.dtype == np.float32
    measurement = to_measurement(raw, sensor.profile)
    assert measurement.data.shape == (128, 160, 3)
    (frame, rest), = decoder.calls
    if name == "probe-signal":  # DN above black, one argument
        assert DecoderInput.of(decoder) == DecoderInput("signal", 1) and rest == ()
        np.testing.assert_array_equal(frame, measurement.signal())
    elif name == "probe-raw":  # DN with the black level, and that black level
        assert DecoderInput.of(decoder) == DecoderInput("raw", 1) and rest == (64.0,)
        np.testing.assert_array_equal(frame, measurement.data)
    else:  # the 2 × 2 block means of the measurement, binned from the mosaic in one pass
        assert DecoderInput.of(decoder) == DecoderInput("binned", 2) and rest == (64.0,)
        assert frame.shape == (64, 80, 3)
        np.testing.assert_array_equal(frame, to_measurement(raw, sensor.profile, sensor_bin=2).data)
        np.testing.assert_allclose(frame, measurement.data.reshape(64, 2, 80, 2, 3).mean(axis=(1, 3)),
                                   rtol=1e-6)


def test_a_binned_decoder_is_refused_a_frame_binned_otherwise_and_a_bad_declaration_is_named() -> None:
    with _sensor("probe-raw") as sensor:
        raw = sensor.read_raw()
        with pytest.raises(InvalidValueError, match="binned 2×2 but decoder 'probe-raw' solves on sensor_bin 1"):
            sensor.reconstruct(to_measurement(raw, sensor.profile, sensor_bin=2))

    class Unknown(RawProbe):
        input = "bayer"  # type: ignore[assignment]

    class Unbinned(BinnedProbe):
        sensor_bin = 1

    profile = load_profile("virtual-mini")
    with pytest.raises(InvalidValueError, match="decoder 'probe-raw': input must be one of signal, raw, binned"):
        DecoderInput.of(Unknown(profile))
    with pytest.raises(InvalidValueError, match="'probe-binned': input 'binned' needs sensor_bin an integer > 1"):
        DecoderInput.of(Unbinned(profile))
