"""Real2Sim inference: a real tactile image in, a simulation-like image out."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import torch

from thintact_sdk.errors import ThinTactError
from thintact_sdk.tactile.learning.model_file import load_generator, select_device
from thintact_sdk.tactile.learning.networks import ResnetGenerator, pad_to_multiple


def to_tensor(images: np.ndarray, device: torch.device) -> torch.Tensor:
    """``B × H × W × 3`` (or ``H × W × 3``) in [0, 1] → ``B × 3 × H × W`` in [-1, 1]."""
    arr = np.asarray(images, np.float32)
    if arr.ndim == 3:
        arr = arr[None]
    t = torch.from_numpy(np.ascontiguousarray(arr)).to(device)
    return t.permute(0, 3, 1, 2) * 2.0 - 1.0


def to_images(t: torch.Tensor) -> np.ndarray:
    """``B × 3 × H × W`` in [-1, 1] → ``B × H × W × 3`` float32 in [0, 1]."""
    out = ((t.clamp(-1.0, 1.0) + 1.0) * 0.5).permute(0, 2, 3, 1)
    return np.ascontiguousarray(out.detach().cpu().numpy(), dtype=np.float32)


class Real2SimTranslator:
    """Applies a trained real→sim generator to tactile images.

    Parameters
    ----------
    generator
        The network (moved to ``device``, eval mode).
    device
        ``auto`` (CUDA when present), ``cpu`` or ``cuda``.
    meta
        Provenance from the generator file.
    """

    def __init__(self, generator: ResnetGenerator, device: str = "auto",
                 meta: dict[str, Any] | None = None) -> None:
        self.device = select_device(device)
        self.generator = generator.to(self.device).eval()
        self.meta = dict(meta or {})

    @classmethod
    def load(cls, path: str | Path, device: str = "auto") -> Real2SimTranslator:
        """A translator from a ``thintact-real2sim/1`` generator file."""
        net, meta = load_generator(path)
        return cls(net, device, meta)

    def __call__(self, images: np.ndarray) -> np.ndarray:
        """Translate ``H × W × 3`` (or ``B × H × W × 3``) float images in [0, 1].

        Returns
        -------
        numpy.ndarray
            float32 of the input's shape, in [0, 1].
        """
        arr = np.asarray(images)
        if arr.ndim not in (3, 4) or arr.shape[-1] != 3:
            raise ThinTactError(f"Real2Sim translates H×W×3 images, got shape {arr.shape}")
        with torch.inference_mode():
            x, (h, w) = pad_to_multiple(to_tensor(arr, self.device))
            y = self.generator(x)[..., :h, :w]
        out = to_images(y)
        return out[0] if arr.ndim == 3 else out
