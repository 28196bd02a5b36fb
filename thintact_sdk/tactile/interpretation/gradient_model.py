"""A small network from colour and position to surface slope (the LUT's alternative).

The LUT maps the colour change alone to a slope. A real gel's illumination depends on the
position in the frame (LEDs at the edges, vignetting, a curved gel), so one colour change
means different slopes in different places. As GelSight's own SDK (``gs_sdk``) does, this
model is a multi-layer perceptron applied to every pixel separately:

    inputs (8): colour change I − I₀ (3, ×4), colour I (3, 2I − 1), column and row (−1..1)
    → tanh(W₀x + b₀) → tanh(W₁h + b₁) → W₂h + b₂ → (∂d/∂x, ∂d/∂y) (mm per mm)

Hidden width 32 by default: ~1.4 k weights, trained in seconds on one CPU thread with torch
(Adam, mini-batches of calibration pixels) and applied with numpy (no torch at run time).

File (``thintact-tactile-mlp/1``): an ``.npz`` of plain float32 arrays ``w0 b0 w1 b1 w2 b2``
and ``shape`` (the working grid the positions refer to), written without pickle and read
with :func:`thintact_sdk.formats.safe_arrays.read_npz` (no code from a data file).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError

MLP_FORMAT = "thintact-tactile-mlp/1"
INPUTS = 8
_LAYERS = ("w0", "b0", "w1", "b1", "w2", "b2")


def mlp_inputs(change: np.ndarray, image: np.ndarray) -> np.ndarray:
    """``N × M × 8`` float32 network inputs (module docstring) from the colour change and
    the image (both ``N × M × 3``, display units)."""
    rows, cols = change.shape[:2]
    y = np.linspace(-1.0, 1.0, rows, dtype=np.float32)
    x = np.linspace(-1.0, 1.0, cols, dtype=np.float32)
    out = np.empty((rows, cols, INPUTS), np.float32)
    out[..., 0:3] = 4.0 * np.asarray(change, np.float32)
    out[..., 3:6] = 2.0 * np.asarray(image, np.float32) - 1.0
    out[..., 6] = x[None, :]
    out[..., 7] = y[:, None]
    return out


@dataclass
class MLPGradient:
    """Colour + position → slope network (module docstring).

    Attributes
    ----------
    weights
        ``w0`` (8 × H), ``b0`` (H), ``w1`` (H × H), ``b1`` (H), ``w2`` (H × 2), ``b2`` (2),
        float32.
    shape
        ``(rows, cols)`` of the working grid it was trained on (positions are relative to it).
    meta
        Provenance (presses, hidden width, steps, validation figures).
    """

    weights: dict[str, np.ndarray]
    shape: tuple[int, int]
    meta: dict[str, Any] = field(default_factory=dict)
    _flat: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False, repr=False,
                                                         compare=False)

    def predict(self, change: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(grad_x, grad_y)``, ``N × M`` float32 mm per mm, for ``N × M × 3`` colour change
        and image on the grid the network was trained on.

        The network's answer for the no-contact background itself (``image − change`` with
        no change) is subtracted, so that an unpressed membrane reads exactly flat and a small
        bias does not integrate to a slope across the frame (cached per background).

        Raises
        ------
        CalibrationError
            The images are not on that grid.
        """
        if tuple(change.shape[:2]) != self.shape or tuple(np.shape(image)[:2]) != self.shape:
            raise CalibrationError(
                f"the gradient network was trained on a {self.shape[0]}×{self.shape[1]} working "
                f"grid, got {change.shape[0]}×{change.shape[1]}: recalibrate the device")
        change = np.asarray(change, np.float32)
        out = self._forward(change, image)
        background = np.asarray(image, np.float32) - change
        if self._flat is None or not np.array_equal(self._flat[0], background):
            self._flat = (background, self._forward(np.zeros_like(change), background))
        out -= self._flat[1]
        return out[..., 0], out[..., 1]

    def _forward(self, change: np.ndarray, image: np.ndarray) -> np.ndarray:
        w = self.weights
        x = mlp_inputs(change, image).reshape(-1, INPUTS)
        h = np.tanh(x @ w["w0"] + w["b0"])
        h = np.tanh(h @ w["w1"] + w["b1"])
        return (h @ w["w2"] + w["b2"]).reshape(self.shape + (2,))

    def save(self, path: str | Path) -> Path:
        """Write the network to ``path`` (``.npz``, no pickle)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, Any] = {k: self.weights[k].astype(np.float32) for k in _LAYERS}
        arrays["shape"] = np.asarray(self.shape, np.int64)
        np.savez_compressed(p, allow_pickle=False, **arrays)
        return p

    @classmethod
    def load(cls, path: str | Path, meta: dict[str, Any] | None = None) -> MLPGradient:
        """Read a network written by :meth:`save`; raises CalibrationError naming the file
        and what is wrong (missing, damaged, object arrays, inconsistent layer shapes)."""
        from thintact_sdk.formats.safe_arrays import read_npz

        z = read_npz(path, what="tactile gradient network", error=CalibrationError,
                     members=(*_LAYERS, "shape"), kinds={**{k: "f" for k in _LAYERS}, "shape": "iu"})
        w = {k: np.asarray(z[k], np.float32) for k in _LAYERS}
        shape = tuple(int(v) for v in np.asarray(z["shape"]).ravel())
        hidden = w["w0"].shape[-1] if w["w0"].ndim == 2 else -1
        want = {"w0": (INPUTS, hidden), "b0": (hidden,), "w1": (hidden, hidden),
                "b1": (hidden,), "w2": (hidden, 2), "b2": (2,)}
        bad = [k for k in _LAYERS if w[k].shape != want[k]]
        if hidden < 1 or bad or len(shape) != 2 or min(shape) < 1:
            raise CalibrationError(
                f"{path}: not a {MLP_FORMAT} network (layers {', '.join(bad) or 'ok'}, "
                f"shape {shape})")
        if not all(np.isfinite(a).all() for a in w.values()):
            raise CalibrationError(f"{path}: the network holds non-finite weights")
        return cls(w, (shape[0], shape[1]), dict(meta or {}))


def train_mlp(
    changes: list[np.ndarray],
    images: list[np.ndarray],
    grad_x: list[np.ndarray],
    grad_y: list[np.ndarray],
    valid: list[np.ndarray],
    hidden: int = 32,
    steps: int = 2000,
    batch: int = 2048,
    seed: int = 0,
    threads: int = 1,
) -> MLPGradient:
    """Train the network on calibration pixels with known slopes.

    Parameters
    ----------
    changes, images
        Per press, ``N × M × 3`` colour change and image (display units), all on one grid.
    grad_x, grad_y, valid
        Per press, ``N × M`` target slopes (mm per mm) and the trusted pixels.
    hidden, steps, batch
        Hidden width, Adam steps (learning rate 3e-3, decayed ×0.1 by the end) and pixels per
        step.
    seed
        Initialisation and sampling seed (the result is deterministic for a seed and thread
        count).
    threads
        torch CPU threads used during training (restored afterwards). One by default: a
        network this small gains nothing from more, and on a busy host threads that wait
        for each other made training many times slower.
    """
    import torch

    shapes = {c.shape[:2] for c in changes}
    if len(shapes) != 1:
        raise CalibrationError(f"calibration presses on different grids: {sorted(shapes)}")
    shape = next(iter(shapes))
    x = np.concatenate([mlp_inputs(c, i)[m] for c, i, m in zip(changes, images, valid, strict=True)])
    y = np.concatenate([np.stack([gx, gy], -1)[m]
                        for gx, gy, m in zip(grad_x, grad_y, valid, strict=True)]).astype(np.float32)
    if len(x) < 100:
        raise CalibrationError(
            f"only {len(x)} calibration pixels; press the ball harder or use more presses")
    old_threads = torch.get_num_threads()
    torch.set_num_threads(max(1, threads))
    try:
        gen = torch.Generator().manual_seed(seed)
        torch.manual_seed(seed)
        net = torch.nn.Sequential(
            torch.nn.Linear(INPUTS, hidden), torch.nn.Tanh(),
            torch.nn.Linear(hidden, hidden), torch.nn.Tanh(),
            torch.nn.Linear(hidden, 2))
        opt = torch.optim.Adam(net.parameters(), lr=3e-3)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** (s / max(steps, 1)))
        tx, ty = torch.from_numpy(x), torch.from_numpy(y)
        for _ in range(steps):
            idx = torch.randint(0, len(tx), (min(batch, len(tx)),), generator=gen)
            loss = torch.mean((net(tx[idx]) - ty[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
    finally:
        torch.set_num_threads(old_threads)
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    weights: dict[str, np.ndarray] = {}
    for k, layer in enumerate(lin):
        weights[f"w{k}"] = layer.weight.detach().numpy().T.astype(np.float32).copy()
        weights[f"b{k}"] = layer.bias.detach().numpy().astype(np.float32).copy()
    meta = {"format": MLP_FORMAT, "hidden": hidden, "steps": steps, "pixels": int(len(x)),
            "presses": len(changes)}
    return MLPGradient(weights, (int(shape[0]), int(shape[1])), meta)
