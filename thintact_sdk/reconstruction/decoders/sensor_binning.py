"""Decode from the sensor binned ``b × b``: fewer FLOPs where the sensor oversamples the scene.

The paper's device has a 1024 × 1280 (binned RGB) sensor for a 400 × 512 scene: every scene
row is seen by 2.56 sensor rows. The closed forms' first product ``U_Pᵀ Y`` costs
``2·N·R·S`` per channel, over half of the frame's arithmetic; averaging ``2 × 2`` sensor
blocks first (one pass over the frame) and solving the same Tikhonov problem on the binned
operator cuts the products by about half. Where the FLOPs set the frame time (a CPU without
AVX-512 needs a little more than a 30 fps camera period for a paper-size float32 frame) that is the
difference between missing and meeting a 30 fps camera.

It is not free by construction: binning averages the mask's shadow over ``b`` pixels. So it
is offered to the backend selection (:mod:`thintact_sdk.reconstruction.decoders.backend_selection`) as one more candidate
(key suffix ``-bin2``), judged like the others against the *unbinned* float64 solve on the
probe scenes and used only when its PSNR cost is within the same bound. Only a sensor at
least ``b`` times the scene along both axes is offered it (the binned problem stays
over-determined).

The binned problem is the same objective: block means of ``b²`` pixels carry ``1/b²`` of the
residual's energy, so ``τ`` is divided by ``b²`` (``‖B(AX − Y)‖² ≈ ‖AX − Y‖²/b²`` for a
residual smooth over a block); :attr:`SensorBinnedDecoder.tau` and ``set_tau`` speak the
unbinned τ, as every other decoder and the calibration bundle do.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from thintact_sdk.errors import InvalidShapeError, InvalidValueError
from thintact_sdk.interfaces import Decoder, DecoderInput
from thintact_sdk.pixels.bayer import block_mean, planar_frame
from thintact_sdk.reconstruction.decoders.modes import TauSpec, channel_taus
from thintact_sdk.reconstruction.decoders.shapes import check_measurement_shape
from thintact_sdk.reconstruction.t2s import SystemMatrices

SENSOR_BIN = 2
"""The binning offered to the selection (the only one: 2 × 2 halves the work; 3 × 3 would
leave the paper device's sensor under-determined)."""


MIN_FIRST_PRODUCT_GFLOP = 1.0
"""Binning is offered to the selection by default only where the first product ``U_Pᵀ Y``
(``2·C·N·R·S`` FLOPs) is at least this much work per frame (the paper device: 3.1 GFLOP; the
virtual finger: 0.05): below it the products are a few ms on any CPU, and an exact solve is
worth more than the time saved. The decoder setting ``sensor_bin`` (1 or 2) overrides."""


def binning_offered(sensor_shape: tuple[int, int], scene_shape: tuple[int, int], channels: int,
                    setting: object = "auto") -> int:
    """The block side the selection may try: :data:`SENSOR_BIN` or 1 (not offered).

    Parameters
    ----------
    sensor_shape, scene_shape, channels
        The operator's ``(R, S)``, ``(N, M)`` and ``C``.
    setting
        ``"auto"`` (offered where :func:`binning_possible` and the first product is at least
        :data:`MIN_FIRST_PRODUCT_GFLOP`), ``1`` (never) or ``2`` (wherever possible).

    Raises
    ------
    InvalidValueError
        For any other setting.
    """
    possible = binning_possible(sensor_shape, scene_shape)
    if setting in ("auto", None):
        (r, s), (n, _) = sensor_shape, scene_shape
        return SENSOR_BIN if possible and 2 * channels * n * r * s >= MIN_FIRST_PRODUCT_GFLOP * 1e9 else 1
    if str(setting) == "1":
        return 1
    if str(setting) == str(SENSOR_BIN):
        return SENSOR_BIN if possible else 1
    raise InvalidValueError(f"decoder setting sensor_bin: expected 'auto', 1 or {SENSOR_BIN}, got {setting!r}")


def binning_possible(sensor_shape: tuple[int, int], scene_shape: tuple[int, int], b: int = SENSOR_BIN) -> bool:
    """True when ``b × b`` binning keeps at least as many sensor rows/cols as scene rows/cols
    and both sensor sides are multiples of ``b``."""
    (r, s), (n, m) = sensor_shape, scene_shape
    return b > 1 and r % b == 0 and s % b == 0 and r // b >= n and s // b >= m


def _block_mean(a: np.ndarray, axis: int, b: int) -> np.ndarray:
    shape = list(a.shape)
    shape[axis:axis + 1] = [shape[axis] // b, b]
    return np.asarray(a.reshape(shape).mean(axis=axis + 1), a.dtype)


def bin_system_matrices(sm: SystemMatrices, b: int = SENSOR_BIN) -> SystemMatrices:
    """The operator of the ``b × b``-binned sensor: block means of the sensor rows of ``Po``,
    ``Pc`` and of the sensor columns of ``Qo``, ``Qc`` (``C × R/b × N``, ``C × S/b × M``).

    Raises
    ------
    InvalidShapeError
        When a sensor side is not a multiple of ``b``.
    """
    (r, s) = sm.sensor_shape
    if r % b or s % b:
        raise InvalidShapeError(f"a {r}×{s} sensor cannot be binned {b}×{b}: both sides must be multiples of {b}")
    meta = {**sm.meta, "sensor_bin": b}
    return SystemMatrices(_block_mean(sm.Po, 1, b), _block_mean(sm.Qo, 1, b), _block_mean(sm.Pc, 1, b),
                          _block_mean(sm.Qc, 1, b), meta)


def bin_frame(frame: np.ndarray, b: int = SENSOR_BIN, out: np.ndarray | None = None,
              offset: float = 0.0) -> np.ndarray:
    """Block means of ``b × b`` pixels of an ``R × S × C`` frame, minus ``offset`` (DN):
    :func:`thintact_sdk.pixels.bayer.block_mean` with this module's default ``b``."""
    return block_mean(frame, b, out, offset)


def binnable_build(sm: SystemMatrices, tau: TauSpec, make: Callable[..., Decoder]) -> Callable[..., Decoder]:
    """``build(backend, b=1, **kw)`` for the backend selection: ``make(sm, tau, backend, **kw)``,
    or ``make`` on ``sm`` binned ``b × b`` at τ / b² (the same objective) wrapped to bin each
    frame (:class:`SensorBinnedDecoder`); the binned operator is made once per ``b``."""
    binned: dict[int, SystemMatrices] = {}

    def build(xp: Any, b: int = 1, **kw: Any) -> Decoder:
        if b == 1:
            return make(sm, tau, xp, **kw)
        if b not in binned:
            binned[b] = bin_system_matrices(sm, b)
        inner = make(binned[b], channel_taus(tau, sm.channels) / b**2, xp, **kw)
        return SensorBinnedDecoder(inner, sm.sensor_shape, sm.channels, b)

    return build


class SensorBinnedDecoder(Decoder):
    """A decoder built on the binned operator (:func:`bin_system_matrices`) that bins each
    frame itself; it takes and reports the unbinned τ.

    It declares ``input = "binned"`` and ``sensor_bin = b`` (:class:`~thintact_sdk.interfaces.Decoder`):
    the Sensor bins the camera's mosaic straight to ``R/b × S/b`` in one pass
    (:meth:`thintact_sdk.device.sensor.Sensor.decoder_input`) and hands that to :meth:`decode`,
    so the frame is not binned twice; a full ``R × S`` frame (calibration) is binned here.

    Parameters
    ----------
    inner
        The decoder of the binned operator, built with τ / ``b²``.
    sensor_shape
        The unbinned ``(R, S)`` the frames have.
    channels
        Channels ``C`` of a frame.
    b
        Block side.
    """

    input = "binned"

    def __init__(self, inner: Any, sensor_shape: tuple[int, int], channels: int, b: int = SENSOR_BIN) -> None:
        self.inner, self.b = inner, b
        self.sensor_bin = b
        """Block side ``b`` the inner decoder solves on."""
        self.name = str(getattr(inner, "name", "decoder"))
        self.sensor_shape, self.channels = sensor_shape, channels
        self.scene_shape = getattr(inner, "scene_shape", None)
        self.xp = getattr(inner, "xp", None)
        self._local = threading.local()

    @property
    def tau(self) -> float:
        """Representative τ of the unbinned problem (DN²)."""
        return float(self.inner.tau) * self.b**2

    @property
    def channel_tau(self) -> np.ndarray:
        """τ per channel of the unbinned problem (DN²)."""
        return np.asarray(self.inner.channel_tau, np.float64) * self.b**2

    @property
    def kept_modes(self) -> Any:
        """The inner decoder's kept Tikhonov modes."""
        return getattr(self.inner, "kept_modes", None)

    @property
    def info(self) -> dict[str, Any]:
        """The inner decoder's info, with the binning."""
        return {**getattr(self.inner, "info", {}), "sensor_bin": self.b}

    def set_tau(self, tau: TauSpec) -> None:
        """Use ``tau`` (unbinned DN², one value or one per channel) from the next decode on."""
        self.inner.set_tau(channel_taus(tau, self.channels) / self.b**2)

    def gemm_flops(self) -> int:
        """The inner decoder's GEMM FLOPs per frame (the binning pass is not a product)."""
        return int(self.inner.gemm_flops())

    def _buffer(self) -> np.ndarray:
        """This thread's binned frame (decode workers of a stream share the decoder)."""
        out = getattr(self._local, "out", None)
        if out is None:
            out = self._local.out = planar_frame(self.sensor_shape[0] // self.b, self.sensor_shape[1] // self.b,
                                                 self.channels)
        return out

    def decode(self, frame: np.ndarray, black_level_dn: float = 0.0) -> np.ndarray:
        """``R/b × S/b × C`` block means of the measurement (what a Sensor hands a binned
        decoder: :func:`thintact_sdk.device.cameras.to_measurement` with ``sensor_bin = b``), or
        the full ``R × S × C`` measurement, which is binned here first (told apart by shape);
        DN holding the black level ``black_level_dn`` (0: a signal above black) → ``N × M × C``
        float32. Both give the same scene up to float32 rounding."""
        r, s = self.sensor_shape
        if frame.shape == (r // self.b, s // self.b, self.channels):
            binned = frame
        else:
            check_measurement_shape(frame, self.sensor_shape, self.channels)
            binned = bin_frame(frame, self.b, self._buffer())
        return self._decode_binned(binned, float(black_level_dn))

    def project(self, frame: np.ndarray) -> Any:
        """The τ-free first step of :meth:`decode` for a frame decoded at several τ
        (:func:`~thintact_sdk.calibration.tau.shared_decode`): the frame (``R × S × C`` DN
        above black) binned, then the inner decoder's own ``project`` where it has one."""
        check_measurement_shape(frame, self.sensor_shape, self.channels)
        binned = bin_frame(frame, self.b)
        if hasattr(self.inner, "project") and DecoderInput.of(self.inner).kind == "signal":
            return ("inner", self.inner.project(binned))
        return ("binned", binned)

    def decode_projected(self, projected: Any) -> np.ndarray:
        """:meth:`decode` (black level 0) of the frame :meth:`project` gave ``projected`` for,
        at the current τ (the same figures up to float rounding)."""
        kind, value = projected
        if kind == "inner":
            return np.asarray(self.inner.decode_projected(value))
        return self._decode_binned(value, 0.0)

    def _decode_binned(self, binned: np.ndarray, black_level_dn: float) -> np.ndarray:
        """The inner solve with the black level folded in where it can (no full-size pass)."""
        if DecoderInput.of(self.inner).kind != "signal":
            return np.asarray(self.inner.decode(binned, black_level_dn))
        signal = np.subtract(binned, np.float32(black_level_dn), out=self._buffer(), dtype=np.float32)
        return np.asarray(self.inner.decode(signal))
