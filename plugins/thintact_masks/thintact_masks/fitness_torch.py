"""The paper's mask fitness for a batch of genes with torch (CUDA when present).

The same arithmetic as :meth:`thintact_masks.fitness.FitnessEvaluator.evaluate`, batched over
individuals: coding matrices from the evaluator's direct generation (numpy, a gather per gene),
then on the torch device the batched Gram eigen-decompositions (``B × N × N``, ``B × M × M``),
the closed-form Tikhonov reconstructions of the two scenes, SSIM (the same 11-tap Gaussian
window as :class:`~thintact_masks.fitness.SSIMReference`, with scipy's ``reflect`` borders),
PSNR and ``f_GRAD``; the parts are combined by :func:`~thintact_masks.fitness.combine`.

The fixed noise draw lives in the Gram eigenbases, whose column signs are each LAPACK's own
choice; both paths fix them by one convention (:func:`~thintact_masks.fitness.canonical_signs`),
so the torch fitness is the numpy fitness up to rounding (tested on the CPU to 1e-9 relative).
"""

from __future__ import annotations

import math
import os
from typing import Any

import numpy as np

from thintact_masks.errors import MaskDesignError
from thintact_masks.fitness import FitnessEvaluator, combine, sign_reference

#: ``--device`` values: ``auto`` (CUDA when torch sees a GPU, else numpy), ``cpu`` (numpy, the
#: local path), ``cuda`` (torch on the GPU; an error without one)
DEVICE_CHOICES = ("auto", "cpu", "cuda")
_EPS = 1e-9


#: device nodes of the NVIDIA and ROCm drivers: without them torch cannot see a GPU, and the
#: check does not have to import torch (seconds) on the CPU-only local path
_GPU_DEVICE_NODES = ("/dev/nvidiactl", "/dev/kfd")


def cuda_available() -> bool:
    """Whether torch sees a CUDA (or ROCm) device (False when torch cannot tell)."""
    if not any(os.path.exists(p) for p in _GPU_DEVICE_NODES):
        return False
    try:
        import torch
    except ImportError:
        return False
    return bool(torch.cuda.is_available())


def resolve_device(device: str) -> str:
    """``"cpu"`` (numpy path) or ``"cuda"`` for a ``--device`` choice.

    Raises
    ------
    MaskDesignError
        For an unknown choice, or ``"cuda"`` without a CUDA device.
    """
    if device not in DEVICE_CHOICES:
        raise MaskDesignError(f"--device must be one of {', '.join(DEVICE_CHOICES)}, got {device!r}")
    if device == "auto":
        return "cuda" if cuda_available() else "cpu"
    if device == "cuda" and not cuda_available():
        raise MaskDesignError("--device cuda: torch sees no CUDA device here; use --device cpu")
    return device


def gaussian_kernel(sigma: float, truncate: float = 3.5) -> np.ndarray:
    """scipy.ndimage's 1-D Gaussian weights (radius ``int(truncate·σ + 0.5)``), summing to 1."""
    radius = int(truncate * sigma + 0.5)
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    w = np.exp(-0.5 / (sigma * sigma) * x * x)
    return w / w.sum()


def reflect_index(n: int, radius: int) -> np.ndarray:
    """Indices ``-radius .. n + radius - 1`` folded as scipy's ``reflect`` (``d c b a | a b c d``)."""
    i = np.arange(-radius, n + radius) % (2 * n)
    return np.where(i >= n, 2 * n - 1 - i, i)


class TorchBatchFitness:
    """Fitness of ``G × K`` genes at once on a torch device (a ``batch_fitness`` of the GA).

    Parameters
    ----------
    evaluator
        The numpy :class:`~thintact_masks.fitness.FitnessEvaluator` whose device, scenes,
        noise draws, τ and dtype are used.
    device
        torch device (``"cuda"``, ``"cuda:1"``, or ``"cpu"`` for tests).
    max_batch
        Genes per device batch (bounds memory: about 40 MB per gene at paper scale in float64).
    """

    def __init__(self, evaluator: FitnessEvaluator, device: str = "cuda",
                 max_batch: int = 16) -> None:
        import torch

        if max_batch < 1:
            raise MaskDesignError(f"max_batch must be >= 1, got {max_batch}")
        self.evaluator = evaluator
        self.device = torch.device(device)
        self.max_batch = max_batch
        self.dtype = torch.float64 if evaluator.settings.dtype == "float64" else torch.float32

        def put(a: np.ndarray, dtype: Any = None) -> Any:
            return torch.as_tensor(np.asarray(a), dtype=dtype or self.dtype, device=self.device)

        self._put = put
        self.scenes = {k: put(v) for k, v in evaluator.scenes.items()}
        self.truth64 = {k: put(v, torch.float64) for k, v in evaluator.scenes.items()}
        self.noise = {k: put(v) for k, v in evaluator.noise_draws.items()}
        ref = evaluator.ssim_references["usaf"]
        self._ssim_consts = (ref.c1, ref.c2)
        self._ssim_truth = {k: (put(r.my, torch.float64), put(r.syy, torch.float64))
                            for k, r in evaluator.ssim_references.items()}
        self._kernel = put(gaussian_kernel(ref.sigma), torch.float64)
        n, m = next(iter(evaluator.scenes.values())).shape
        radius = (self._kernel.shape[0] - 1) // 2
        self._rows = put(reflect_index(n, radius), torch.long)
        self._cols = put(reflect_index(m, radius), torch.long)

    # -- image metrics on (B, N, M) float64 --------------------------------------------------
    def _blur(self, x: Any) -> Any:
        """scipy ``gaussian_filter(x, σ, truncate=3.5, mode="reflect")`` over the last two axes."""
        taps = self._kernel.shape[0]
        x = x[:, self._rows, :].unfold(1, taps, 1) @ self._kernel  # along rows (axis 0 first)
        return x[:, :, self._cols].unfold(2, taps, 1) @ self._kernel

    def _ssim(self, name: str, x: Any) -> Any:
        c1, c2 = self._ssim_consts
        my, syy = self._ssim_truth[name]
        mx = self._blur(x)
        sxx = self._blur(x * x) - mx * mx
        sxy = self._blur(x * self.truth64[name]) - mx * my
        num = (2 * mx * my + c1) * (2 * sxy + c2)
        den = (mx * mx + my * my + c1) * (sxx + syy + c2)
        return (num / den).mean(dim=(1, 2))

    def _psnr(self, name: str, x: Any) -> Any:
        import torch

        mse = ((x - self.truth64[name]) ** 2).mean(dim=(1, 2))
        return torch.where(mse > 0, 10.0 * torch.log10(1.0 / mse),
                           torch.full_like(mse, math.inf))

    @staticmethod
    def _f_grad(x: Any) -> Any:
        n, m = x.shape[1:]
        tv = (x.diff(dim=2).abs().sum(dim=(1, 2)) + x.diff(dim=1).abs().sum(dim=(1, 2)))
        return 2.0 * n * m / tv.clamp_min(_EPS)

    # -- reconstruction ----------------------------------------------------------------------
    def _eig(self, a: Any) -> tuple[Any, Any]:
        import torch

        lam, v = torch.linalg.eigh(a.transpose(1, 2) @ a)
        ref = torch.as_tensor(sign_reference(v.shape[-2]), dtype=v.dtype, device=v.device)
        proj = torch.einsum("bnk,n->bk", v, ref)  # the numpy path's sign convention
        return lam.clamp_min(0.0), v * torch.where(proj < 0, -1.0, 1.0).to(v.dtype)[:, None, :]

    def reconstruct(self, genes: np.ndarray) -> dict[str, Any]:
        """Batched reconstructions ``{"usaf", "white"}``: ``(G, N, M)`` float64 tensors."""
        ev = self.evaluator
        mats = [ev.coding_matrices(g) for g in genes]
        pc = self._put(np.stack([p for p, _ in mats]))
        qc = self._put(np.stack([q for _, q in mats]))
        lam_p, vp = self._eig(pc)
        lam_q, vq = self._eig(qc)
        gain = lam_p[:, :, None] * lam_q[:, None, :]
        inv = 1.0 / (gain + ev.tau)
        amp = gain.sqrt()
        out = {}
        for name, x in self.scenes.items():
            if name == "white":  # 1·1ᵀ projects to an outer product
                proj = vp.sum(dim=1)[:, :, None] * vq.sum(dim=1)[:, None, :]
            else:
                proj = vp.transpose(1, 2) @ x @ vq
            core = gain * proj
            if ev.sigma_rel[name] > 0:
                core = core + ev.sigma_rel[name] * amp * self.noise[name]
            core = core * inv
            out[name] = (vp @ core @ vq.transpose(1, 2)).double()
        return out

    def parts(self, genes: np.ndarray) -> list[dict[str, float]]:
        """The fitness parts of each gene (as :meth:`FitnessEvaluator.score` names them)."""
        import torch

        genes = np.asarray(genes)
        if genes.ndim != 2 or genes.shape[1] != self.evaluator.K:
            raise MaskDesignError(f"genes must have shape (G, {self.evaluator.K}), "
                                  f"got {genes.shape}")
        rows: list[dict[str, float]] = []
        with torch.no_grad():
            for start in range(0, genes.shape[0], self.max_batch):
                rec = self.reconstruct(genes[start:start + self.max_batch])
                white = rec["white"]
                mean = white.mean(dim=(1, 2))
                cols = {
                    "ssim_usaf": self._ssim("usaf", rec["usaf"]),
                    "ssim_white": self._ssim("white", white),
                    "psnr_usaf": self._psnr("usaf", rec["usaf"]),
                    "psnr_white": self._psnr("white", white),
                    "f_grad": self._f_grad(white),
                    "uniformity_white": 1.0 - white.std(dim=(1, 2), correction=0)
                    / mean.abs().clamp_min(_EPS),
                }
                host = {k: v.cpu().numpy() for k, v in cols.items()}
                n = next(iter(host.values())).shape[0]
                rows += [{k: float(v[i]) for k, v in host.items()} for i in range(n)]
        return rows

    def __call__(self, genes: np.ndarray) -> np.ndarray:
        """``(G,)`` fitness of ``genes`` (``G × K`` ±1)."""
        return np.array([combine(p) for p in self.parts(genes)], np.float64)
