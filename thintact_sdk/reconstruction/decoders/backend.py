"""A tiny array-namespace shim so every algorithm is written once for numpy and torch.

Algorithms use only ``@``, ``*``, ``+``, ``-``, ``/``, ``reshape`` and the methods below.
``ArrayBackend("numpy")`` runs on numpy/OpenBLAS; ``ArrayBackend("torch")`` on torch tensors
(CUDA when present unless ``device`` says otherwise). ``gemm_dtype`` may be ``"bfloat16"``
(torch only) for the large products (the first and the last of every closed-form solve),
trading a measured amount of accuracy for speed.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from thintact_sdk.errors import InvalidValueError

_NP_DTYPES = {"float32": np.float32, "float64": np.float64}
# input dtypes torch reads in place and converts in one pass (camera DN and float images)
_TORCH_COPYABLE = {np.dtype(t) for t in (np.uint8, np.uint16, np.int16, np.int32, np.float32, np.float64)}


class ArrayBackend:
    """Array operations on one backend.

    Parameters
    ----------
    name
        ``"numpy"`` or ``"torch"``.
    dtype
        Working precision, ``"float32"`` or ``"float64"``.
    device
        torch device (``"cpu"``, ``"cuda"``); default CUDA when available.
    gemm_dtype
        Precision of the big matrix products (default ``dtype``; torch also ``"bfloat16"``).
    """

    def __init__(
        self,
        name: str = "numpy",
        dtype: str = "float32",
        device: str | None = None,
        gemm_dtype: str | None = None,
    ) -> None:
        if name not in ("numpy", "torch"):
            raise InvalidValueError(f"backend must be 'numpy' or 'torch', got {name!r}")
        if dtype not in _NP_DTYPES:
            raise InvalidValueError(f"dtype must be float32 or float64, got {dtype!r}")
        gemm_dtype = gemm_dtype or dtype
        if gemm_dtype == "bfloat16" and name != "torch":
            raise InvalidValueError("gemm_dtype bfloat16 needs the torch backend")
        self.name = name
        self.dtype_name = dtype
        self.gemm_dtype_name = gemm_dtype
        if name == "torch":
            import torch

            self._torch = torch
            self.device = device or ("cuda" if torch.cuda.is_available() else "cpu")
            self.dtype: Any = getattr(torch, dtype)
            self.gemm_dtype: Any = getattr(torch, gemm_dtype)
        else:
            self.device = "cpu"
            self.dtype = _NP_DTYPES[dtype]
            self.gemm_dtype = _NP_DTYPES[gemm_dtype]

    def __repr__(self) -> str:
        return f"ArrayBackend({self.name!r}, {self.dtype_name}, gemm={self.gemm_dtype_name}, {self.device})"

    def asarray(self, a: np.ndarray, gemm: bool = False) -> Any:
        """Convert a numpy array to this backend (working or GEMM precision), contiguous."""
        dt = self.gemm_dtype if gemm else self.dtype
        if self.name == "numpy":
            return np.ascontiguousarray(a, dtype=dt)
        t = self._torch.from_numpy(np.ascontiguousarray(a))
        return t.to(device=self.device, dtype=dt).contiguous()

    def to_numpy(self, a: Any) -> np.ndarray:
        """Back to a numpy array (float32/64 as computed)."""
        if self.name == "numpy":
            return np.asarray(a)
        return a.detach().to("cpu", dtype=self._torch.float32 if a.dtype == self._torch.bfloat16 else a.dtype).numpy()

    def cast(self, a: Any, gemm: bool) -> Any:
        """Cast an array of this backend to the working or GEMM precision (no copy if equal)."""
        dt = self.gemm_dtype if gemm else self.dtype
        if self.name == "numpy":
            return a.astype(dt, copy=False)
        return a.to(dt)

    def swap(self, a: Any) -> Any:
        """Transpose the last two axes."""
        return a.swapaxes(-1, -2)

    def permute(self, a: Any, axes: tuple[int, ...]) -> Any:
        """Reorder axes."""
        return a.transpose(axes) if self.name == "numpy" else a.permute(*axes)

    def contiguous(self, a: Any) -> Any:
        """A C-contiguous version."""
        return np.ascontiguousarray(a) if self.name == "numpy" else a.contiguous()

    def zeros_like(self, a: Any) -> Any:
        """Zeros of the same shape and type."""
        return np.zeros_like(a) if self.name == "numpy" else self._torch.zeros_like(a)

    def cat(self, arrays: list[Any], axis: int) -> Any:
        """Concatenate along an axis."""
        if self.name == "numpy":
            return np.concatenate(arrays, axis=axis)
        return self._torch.cat(arrays, dim=axis)

    def sum_axis(self, a: Any, axis: int) -> Any:
        """Sum over one axis."""
        return a.sum(axis=axis) if self.name == "numpy" else a.sum(dim=axis)

    def pad_to(self, a: Any, rows: int, cols: int) -> Any:
        """``C × r × c`` → ``C × rows × cols``, zeros in the new rows and columns (``a`` itself
        when it already has that shape)."""
        c, r, k = a.shape
        if (r, k) == (rows, cols):
            return a
        if self.name == "numpy":
            out = np.zeros((c, rows, cols), a.dtype)
            out[:, :r, :k] = a
            return out
        return self._torch.nn.functional.pad(a, (0, cols - k, 0, rows - r))

    def sum_squares(self, a: Any) -> float:
        """``Σ a²`` as a Python float."""
        return float((a * a).sum())

    def channels_first(self, image: np.ndarray, gemm: bool = False) -> Any:
        """``R × S × C`` numpy image (any real dtype, e.g. uint16 DN) → ``C × R × S`` on this backend.

        A frame already stored channel by channel in the target precision (what
        :func:`thintact_sdk.pixels.bayer.bin_bayer` returns) is taken as it is, without a copy: the
        result may share memory with ``image`` and is read, never written, by the decoders.
        Otherwise one pass converts and de-interleaves: numpy ``copyto`` into a channel-first
        buffer, or on a torch CPU backend a ``copy_`` of the permuted input straight into the
        target precision (uint16 → bfloat16 without a float32 intermediate).
        """
        c = image.shape[-1]
        target = self.gemm_dtype if gemm else self.dtype
        planes = np.moveaxis(image, -1, 0)
        if planes.flags.c_contiguous and planes.dtype == np.float32 and (
                target == np.float32 or (self.name == "torch" and target == self._torch.float32)):
            if self.name == "numpy":
                return planes
            if self.device == "cpu":
                return self._torch.from_numpy(planes)
        if self.name == "torch" and self.device != "cpu":
            return self._device_planes(image, planes, target)
        if (self.name == "torch" and self.device == "cpu" and image.dtype in _TORCH_COPYABLE
                and min(image.strides, default=0) >= 0):
            out = self._torch.empty((c, *image.shape[:-1]), dtype=target)
            out.copy_(self._torch.from_numpy(np.asarray(image)).permute(2, 0, 1))
            return out
        buf = np.empty((c, *image.shape[:-1]), np.float32 if self.name == "torch" else target)
        np.copyto(buf, np.moveaxis(image, -1, 0), casting="unsafe")
        if self.name == "numpy":
            return buf
        return self._torch.from_numpy(buf).to(self.device).to(target)

    def _device_planes(self, image: np.ndarray, planes: np.ndarray, target: Any) -> Any:
        """:meth:`channels_first` onto an accelerator (``self.device`` not ``"cpu"``): the frame
        crosses the bus once in its own storage type, and the de-interleave and the conversion
        to ``target`` run on the device.

        - channel-planar float32 (``planes`` C-contiguous): the planes are sent as they are;
        - uint16 DN (the raw path): sent as 16-bit words (half the bytes of float32), widened
          on the device (the words are carried as int16 and masked back to 0..65535, as torch
          accelerators convert int16 everywhere);
        - other real types torch copies (uint8, int16, int32, float32, float64): sent as they
          are; anything else is converted to float32 on the host first.
        """
        torch = self._torch
        if planes.flags.c_contiguous and planes.dtype == np.float32:
            return torch.from_numpy(planes).to(self.device).to(target)
        src = np.ascontiguousarray(image)
        if src.dtype == np.uint16:
            sent = torch.from_numpy(src.view(np.int16)).to(self.device)
            sent = sent.to(torch.int32).bitwise_and_(0xFFFF)
        elif src.dtype in _TORCH_COPYABLE:
            sent = torch.from_numpy(src).to(self.device)
        else:
            sent = torch.from_numpy(src.astype(np.float32)).to(self.device)
        out = torch.empty((src.shape[-1], *src.shape[:-1]), dtype=target, device=self.device)
        out.copy_(sent.permute(2, 0, 1))
        return out

    def synthesise(self, vp: Any, coef: Any, vqt: Any) -> np.ndarray:
        """``vp @ coef @ vqt`` (``C × N × kP``, ``C × kP × kQ``, ``C × kQ × M``; ``vp``/``vqt`` in
        GEMM precision) → ``N × M × C`` float32 numpy: the last products of every closed-form
        decoder, in GEMM precision like the first ones, in the cheaper order
        (:func:`synthesis_macs`)."""
        coef = self.cast(coef, gemm=True)
        n, kp = vp.shape[-2:]
        kq, m = vqt.shape[-2:]
        if n * kq * (kp + m) <= kp * m * (kq + n):
            return self.channels_last((vp @ coef) @ vqt)
        return self.channels_last(vp @ (coef @ vqt))

    def channels_last(self, a: Any) -> np.ndarray:
        """``C × N × M`` on this backend → ``N × M × C`` float32 numpy (a new, interleaved array:
        ``np.stack`` writes it plane by plane, each plane read contiguously, where a transposed
        copy reads with a stride)."""
        planes = self.to_numpy(a)
        return np.stack([np.asarray(p, np.float32) for p in planes], axis=-1)


def synthesis_macs(n: int, kp: int, kq: int, m: int) -> int:
    """Multiply-adds of ``(N × kP) (kP × kQ) (kQ × M)`` in the cheaper of the two orders:
    ``N·kQ·(kP + M)`` (left first) or ``kP·M·(kQ + N)`` (right first)."""
    return min(n * kq * (kp + m), kp * m * (kq + n))
