"""Which array backends are real on this host, and how a preference names one.

A backend is named by a key ``<engine>-<gemm precision>``: ``numpy-float32``,
``torch-float32``, ``torch-bfloat16`` (CPU bfloat16 products), ``cuda-float32``,
``mps-float32``; ``-bin2`` appended: the same arithmetic on the sensor binned 2 × 2
(:mod:`thintact_sdk.reconstruction.decoders.sensor_binning`, offered where the sensor oversamples the scene). Only backends that run in hardware here are candidates: bfloat16 on a CPU
without native support (AVX512-BF16, AMX, Arm BF16) is emulated in software, ~100× slower
than float32, and is never measured nor chosen.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from thintact_sdk.errors import InvalidValueError
from thintact_sdk.host.machine import HostCapabilities
from thintact_sdk.reconstruction.decoders.backend import ArrayBackend


@dataclass(frozen=True)
class BackendSpec:
    """How to build one :class:`ArrayBackend`.

    Attributes
    ----------
    engine
        ``"numpy"`` or ``"torch"``.
    device
        torch device (``"cpu"``, ``"cuda"``, ``"mps"``); ``"cpu"`` for numpy.
    dtype
        Working precision (``"float32"``, ``"float64"``).
    gemm_dtype
        Precision of the large products (``dtype`` or ``"bfloat16"``).
    sensor_bin
        Block side the frame is binned by before the solve (1: not binned).
    """

    engine: str
    device: str = "cpu"
    dtype: str = "float32"
    gemm_dtype: str = "float32"
    sensor_bin: int = 1

    @property
    def key(self) -> str:
        """``numpy-float32``, ``torch-bfloat16``, ``cuda-float32``, ``numpy-float32-bin2``, …"""
        head = self.engine if self.device == "cpu" else self.device
        return f"{head}-{self.gemm_dtype}" + (f"-bin{self.sensor_bin}" if self.sensor_bin > 1 else "")

    def make(self) -> ArrayBackend:
        """The backend object."""
        return ArrayBackend(self.engine, self.dtype, device=self.device, gemm_dtype=self.gemm_dtype)


def candidate_specs(caps: HostCapabilities, dtype: str = "float32", torch_available: bool | None = None,
                    sensor_bin: int = 1) -> list[BackendSpec]:
    """Backends worth measuring on a host with ``caps``, working precision ``dtype``.

    numpy always; torch on the CPU when importable; CPU bfloat16 products only when
    ``caps.native_bf16``; CUDA / MPS when ``caps.gpus`` lists them. With ``sensor_bin`` > 1
    (the decoder can solve on a binned sensor) each of those also binned.
    """
    specs = _unbinned_specs(caps, dtype, torch_available)
    if sensor_bin > 1:
        specs += [replace(s, sensor_bin=sensor_bin) for s in specs]
    return specs


def _unbinned_specs(caps: HostCapabilities, dtype: str, torch_available: bool | None) -> list[BackendSpec]:
    if torch_available is None:
        torch_available = caps.torch is not None
    specs = [BackendSpec("numpy", "cpu", dtype, dtype)]
    if not torch_available:
        return specs
    specs.append(BackendSpec("torch", "cpu", dtype, dtype))
    if caps.native_bf16 and dtype == "float32":
        specs.append(BackendSpec("torch", "cpu", dtype, "bfloat16"))
    if any(g.startswith("cuda") for g in caps.gpus):
        specs.append(BackendSpec("torch", "cuda", dtype, dtype))
    if "mps" in caps.gpus and dtype == "float32":
        specs.append(BackendSpec("torch", "mps", dtype, dtype))
    return specs


def parse_preference(text: str, dtype: str = "float32") -> BackendSpec:
    """A backend named by a user: a key (``torch-bfloat16``, ``numpy-float32-bin2``) or an
    engine / device alone (``numpy``, ``torch``, ``cuda``, ``mps``: working precision for the
    products).

    Raises
    ------
    ValueError
        For a name that is none of those.
    """
    head, _, rest = text.strip().lower().partition("-")
    gemm, _, binned = rest.partition("-")
    gemm = gemm or dtype
    sensor_bin = 1
    if binned:
        if not binned.startswith("bin") or not binned[3:].isdigit() or int(binned[3:]) < 1:
            raise InvalidValueError(f"backend {text!r}: a binned backend ends in -bin<k> (e.g. numpy-float32-bin2)")
        sensor_bin = int(binned[3:])
    if gemm not in ("float32", "float64", "bfloat16"):
        raise InvalidValueError(f"backend {text!r}: precision must be float32, float64 or bfloat16")
    if head == "numpy" and gemm == "bfloat16":
        raise InvalidValueError(f"backend {text!r}: bfloat16 products need torch (torch-bfloat16)")
    if head in ("numpy", "torch"):
        return BackendSpec(head, "cpu", dtype, gemm, sensor_bin)
    if head in ("cuda", "mps"):
        return BackendSpec("torch", head, dtype, gemm, sensor_bin)
    raise InvalidValueError(f"backend {text!r}: expected numpy, torch, cuda or mps (optionally -float32/-bfloat16)")


def preference_from_settings(settings: dict[str, object], dtype: str = "float32") -> BackendSpec | None:
    """The backend a profile's ``decoder.settings`` asks for (``backend``, ``device``,
    ``gemm_dtype``), or None when it names none."""
    if "backend" not in settings and "gemm_dtype" not in settings and "device" not in settings:
        return None
    engine = str(settings.get("backend", "torch" if "device" in settings or "gemm_dtype" in settings
                              else "numpy"))
    device = str(settings.get("device") or "cpu")
    if engine == "numpy" and device != "cpu":
        raise InvalidValueError(f"decoder settings: device {device!r} needs backend torch")
    gemm = str(settings.get("gemm_dtype") or dtype)
    if engine == "numpy" and gemm == "bfloat16":
        raise InvalidValueError("decoder settings: gemm_dtype bfloat16 needs backend torch")
    if engine not in ("numpy", "torch"):
        raise InvalidValueError(f"decoder settings: backend must be 'numpy' or 'torch', got {engine!r}")
    return BackendSpec(engine, device, dtype, gemm)
