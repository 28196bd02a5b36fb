"""Small networks from colour and position to surface slope (the LUT's alternatives).

The LUT maps the colour change alone to a slope. A real gel's illumination depends on the
position in the frame (LEDs at the edges, vignetting, a curved gel), so one colour change
means different slopes in different places. As GelSight's own SDK (``gs_sdk``) does, this
model is a multi-layer perceptron applied to every pixel separately:

    inputs (8): colour change I − I₀ (3, ×4), colour I (3, 2I − 1), column and row (−1..1)
    → tanh(W₀x + b₀) → tanh(W₁h + b₁) → W₂h + b₂ → (∂d/∂x, ∂d/∂y) (mm per mm)

Hidden width 32 by default: ~1.4 k weights, trained in seconds on one CPU thread with torch
(Adam, mini-batches of calibration pixels) and applied with numpy.

File (``thintact-tactile-mlp/1``): an ``.npz`` of plain float32 arrays ``w0 b0 w1 b1 w2 b2``
and ``shape`` (the working grid the positions refer to), written without pickle and read
with :func:`thintact_sdk.formats.safe_arrays.read_npz` (no code from a data file).

:class:`ConvGradient` takes the same inputs through dilated 3 × 3 convolutions, so a pixel's
slope is also read from the shading around it (where the colour change saturates with the
slope, a per-pixel model cannot tell steep flanks apart). File ``thintact-tactile-cnn/1``:
``w0 b0 … w{L} b{L}`` (float32), ``dilations`` and ``shape``; read the same way. Both are
trained with torch (:func:`train_mlp`, :func:`train_cnn`); the convolutional one is applied
with torch too (its 3 × 3 layers are several times faster there than as numpy products).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import CalibrationError
from thintact_sdk.host.compute_threads import prepare_worker_thread

MLP_FORMAT = "thintact-tactile-mlp/1"

GRADIENT_MODELS = ("auto", "lut", "mlp", "cnn")
"""The gradient models calibration accepts (``model=`` of
:func:`~thintact_sdk.tactile.calibration.ball_press.calibrate_from_presses`)."""
MODEL_NAMES = {"lut": "table", "mlp": "per-pixel network", "cnn": "convolutional network"}


def describe_validation(validation: dict[str, Any]) -> str:
    """``"table 0.211, per-pixel network 0.203, …"``: the validation slope RMS of each
    gradient model compared (``meta["validation"]`` of
    :func:`~thintact_sdk.tactile.calibration.ball_press.calibrate_from_presses`)."""
    return ", ".join(f"{name} {validation[f'slope_rms_{k}']:.3f}"
                     for k, name in MODEL_NAMES.items() if f"slope_rms_{k}" in validation)


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


SAME_BACKGROUND = 1e-5
"""Largest difference (display units) at which two backgrounds count as the same no-contact
frame for :meth:`_PixelNetwork.predict`'s cache: float32 rounding of a sum and a difference of
values up to 2 is under 5e-7, a camera's next reference frame differs by its noise and an 8-bit
step (4e-3)."""


class _PixelNetwork(ABC):
    """What both networks share: the slopes of a frame, the no-contact answer subtracted.
    Subclasses hold ``shape`` and ``_flat`` and compute ``_forward``."""

    shape: tuple[int, int]
    _flat: tuple[np.ndarray, np.ndarray] | None

    @abstractmethod
    def _forward(self, change: np.ndarray, image: np.ndarray) -> np.ndarray:
        """``N × M × 2`` raw network output for ``N × M × 3`` colour change and image."""

    @abstractmethod
    def _arrays(self) -> dict[str, np.ndarray]:
        """The file's members besides ``shape`` (float32 layers, integer settings)."""

    def save(self, path: str | Path) -> Path:
        """Write the network to ``path`` (``.npz``, no pickle)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(p, allow_pickle=False, **self._arrays(),
                            shape=np.asarray(self.shape, np.int64))
        return p

    def predict(self, change: np.ndarray, image: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(grad_x, grad_y)``, ``N × M`` float32 mm per mm, for ``N × M × 3`` colour change
        and image on the grid the network was trained on.

        The network's answer for the no-contact background itself (``image − change`` with
        no change) is subtracted, so that an unpressed membrane reads exactly flat and a small
        bias does not integrate to a slope across the frame. That answer is cached per
        background: a background within :data:`SAME_BACKGROUND` of the cached one (the
        rounding of ``(background + change) − change``, which the interpreter's colour is)
        reuses it, so a stream runs the network once per frame, not twice.

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
        if self._flat is None or self._flat[0].shape != background.shape \
                or float(np.abs(self._flat[0] - background).max()) > SAME_BACKGROUND:
            self._flat = (background, self._forward(np.zeros_like(change), background))
        out -= self._flat[1]
        return out[..., 0], out[..., 1]


@dataclass
class MLPGradient(_PixelNetwork):
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

    kind = "mlp"

    def _forward(self, change: np.ndarray, image: np.ndarray) -> np.ndarray:
        w = self.weights
        x = mlp_inputs(change, image).reshape(-1, INPUTS)
        h = np.tanh(x @ w["w0"] + w["b0"])
        h = np.tanh(h @ w["w1"] + w["b1"])
        return (h @ w["w2"] + w["b2"]).reshape(self.shape + (2,))

    def _arrays(self) -> dict[str, np.ndarray]:
        return {k: self.weights[k].astype(np.float32) for k in _LAYERS}

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
        _check_width(path, hidden)
        _check_weights(path, w)
        return cls(w, (shape[0], shape[1]), dict(meta or {}))


MAX_WIDTH = 256
"""Most channels (hidden units) a layer of a stored network may have. The shipped
architectures use 16-32; a frame's activations are ``rows × cols × width`` float32, so a file
declaring a much wider layer would make every frame allocate gigabytes."""


def _check_width(path: str | Path, width: int) -> None:
    """CalibrationError naming the file when a layer is wider than :data:`MAX_WIDTH`."""
    if width > MAX_WIDTH:
        raise CalibrationError(
            f"{path}: a layer of {width} channels (at most {MAX_WIDTH}): every frame would hold "
            f"{width} float32 values per pixel; recalibrate the device")


MAX_WEIGHT = 1e4
"""Largest weight magnitude a stored network may hold. Trained ones stay under 1 (the shipped
architectures' weights are about 0.3 at most); with tanh between the layers and at most
:data:`MAX_WIDTH` channels this keeps every output finite, where a file of 3e38 weights
overflowed to inf and the no-contact subtraction made it NaN."""


def _check_weights(path: str | Path, weights: dict[str, np.ndarray]) -> None:
    """CalibrationError naming the file unless every weight is finite and within
    ±:data:`MAX_WEIGHT`."""
    for k, a in weights.items():
        if a.size and (not np.isfinite(a).all() or float(np.abs(a).max()) > MAX_WEIGHT):
            raise CalibrationError(f"{path}: the network's {k} holds non-finite weights or "
                                   f"weights beyond ±{MAX_WEIGHT:g}")


def _one_grid(changes: list[np.ndarray]) -> tuple[int, int]:
    """The grid every calibration press is on; CalibrationError when they differ."""
    shapes = {c.shape[:2] for c in changes}
    if len(shapes) != 1:
        raise CalibrationError(f"calibration presses on different grids: {sorted(shapes)}")
    rows, cols = next(iter(shapes))
    return int(rows), int(cols)


def _too_few_pixels(count: int) -> None:
    """CalibrationError when fewer than 100 calibration pixels are trusted."""
    if count < 100:
        raise CalibrationError(
            f"only {count} calibration pixels; press the ball harder or use more presses")


@contextmanager
def _torch_threads(threads: int) -> Iterator[None]:
    """torch's CPU threads set to ``threads`` (at least one) inside, restored afterwards."""
    import torch

    old = torch.get_num_threads()
    torch.set_num_threads(max(1, threads))
    try:
        yield
    finally:
        torch.set_num_threads(old)


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

    shape = _one_grid(changes)
    x = np.concatenate([mlp_inputs(c, i)[m] for c, i, m in zip(changes, images, valid, strict=True)])
    y = np.concatenate([np.stack([gx, gy], -1)[m]
                        for gx, gy, m in zip(grad_x, grad_y, valid, strict=True)]).astype(np.float32)
    _too_few_pixels(len(x))
    with _torch_threads(threads):
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
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    weights: dict[str, np.ndarray] = {}
    for k, layer in enumerate(lin):
        weights[f"w{k}"] = layer.weight.detach().numpy().T.astype(np.float32).copy()
        weights[f"b{k}"] = layer.bias.detach().numpy().astype(np.float32).copy()
    meta = {"format": MLP_FORMAT, "hidden": hidden, "steps": steps, "pixels": int(len(x)),
            "presses": len(changes)}
    return MLPGradient(weights, shape, meta)


CNN_FORMAT = "thintact-tactile-cnn/1"
CNN_DILATIONS = (1, 2, 4, 8)
"""Dilations of the 3 × 3 layers: a receptive field of 1 + 2·(1 + 2 + 4 + 8) = 31 working
pixels (about 4 mm on a 0.13 mm grid), the size of a fingertip-scale contact."""
CNN_WIDTH = 16
"""Channels of each 3 × 3 layer (about 8.2 k weights with :data:`CNN_DILATIONS`)."""
_MAX_CNN_LAYERS = 8


@dataclass
class ConvGradient(_PixelNetwork):
    """Colour + position → slope network that also sees a pixel's surroundings.

    The per-pixel network (:class:`MLPGradient`) maps each pixel's colour alone; where a
    gel's colour change stops growing with the slope (about 45° on GelSight-type gels), one
    colour means many slopes and a per-pixel model reads steep flanks short. This model
    takes the same 8 inputs per pixel (:func:`mlp_inputs`) through dilated 3 × 3
    convolutions (:data:`CNN_DILATIONS`, tanh between them, a 1 × 1 output layer), so
    the slope of a pixel is read from the shading around it as well. It learns from the
    calibration presses, so what it has seen there (ball presses) is what it knows how to
    read: calibration chooses it only when validation presses say it is better.

    Attributes
    ----------
    weights
        ``w0 … w{L-1}`` (``3 × 3 × C × O``), ``b0 … b{L-1}`` (O), then ``w{L}`` (``C × 2``)
        and ``b{L}`` (2), float32.
    dilations
        Dilation of each 3 × 3 layer (L of them).
    shape
        ``(rows, cols)`` of the working grid it was trained on.
    meta
        Provenance (presses, width, steps, receptive field).
    """

    weights: dict[str, np.ndarray]
    dilations: tuple[int, ...]
    shape: tuple[int, int]
    meta: dict[str, Any] = field(default_factory=dict)
    _flat: tuple[np.ndarray, np.ndarray] | None = field(default=None, init=False, repr=False,
                                                         compare=False)
    _convs: list[tuple[Any, Any, int]] = field(default_factory=list, init=False, repr=False,
                                               compare=False)

    kind = "cnn"

    def __post_init__(self) -> None:
        # torch is imported here, when a calibration is loaded (a sensor's warm-up), so the
        # first frame does not pay for the import
        import torch

        self._convs = [
            (torch.from_numpy(np.ascontiguousarray(self.weights[f"w{k}"].transpose(3, 2, 0, 1),
                                                   np.float32)),
             torch.from_numpy(np.ascontiguousarray(self.weights[f"b{k}"], np.float32)), d)
            for k, d in enumerate(self.dilations)]

    def _forward(self, change: np.ndarray, image: np.ndarray) -> np.ndarray:
        """The 3 × 3 layers with torch on channels-last tensors (the inputs' own ``N × M × C``
        layout, no copy), the 1 × 1 output layer with numpy.

        Torch runs on the calling thread's intra-op threads; where a stream holds the
        kernels at one thread (:func:`~thintact_sdk.host.compute_threads.single_threaded_kernels`,
        hosts of two cores) the calling thread is put on one as well, as a decode worker is,
        so the layers never wait on a core the decoder holds."""
        import torch
        from torch.nn import functional

        prepare_worker_thread()
        h = torch.from_numpy(mlp_inputs(change, image))[None].permute(0, 3, 1, 2)
        with torch.inference_mode():
            for wt, bt, d in self._convs:
                h = torch.tanh(functional.conv2d(
                    functional.pad(h, (d, d, d, d), mode="replicate"), wt, bt, dilation=d))
            feat = h[0].permute(1, 2, 0).numpy()
        last = len(self.dilations)
        return np.asarray(feat @ self.weights[f"w{last}"] + self.weights[f"b{last}"], np.float32)

    def _arrays(self) -> dict[str, np.ndarray]:
        return {**{k: np.asarray(v, np.float32) for k, v in self.weights.items()},
                "dilations": np.asarray(self.dilations, np.int64)}

    @classmethod
    def load(cls, path: str | Path, meta: dict[str, Any] | None = None) -> ConvGradient:
        """Read a network written by :meth:`save`; raises CalibrationError naming the file
        and what is wrong (missing, damaged, object arrays, too many layers, inconsistent
        layer shapes, dilations outside 1-64, non-finite or huge weights)."""
        from thintact_sdk.formats.safe_arrays import read_npz

        layers = tuple(f"{p}{k}" for k in range(_MAX_CNN_LAYERS + 1) for p in "wb")
        z = read_npz(path, what="tactile gradient network", error=CalibrationError,
                     members=("dilations", "shape"), optional=layers,
                     kinds={**{k: "f" for k in layers}, "dilations": "iu", "shape": "iu"})
        dil = tuple(int(v) for v in np.asarray(z["dilations"]).ravel())
        shape = tuple(int(v) for v in np.asarray(z["shape"]).ravel())
        n = len(dil)
        names = [f"{p}{k}" for k in range(n + 1) for p in "wb"]
        missing = [k for k in names if k not in z]
        if not 1 <= n <= _MAX_CNN_LAYERS or missing or any(not 1 <= d <= 64 for d in dil) \
                or len(shape) != 2 or min(shape) < 1:
            raise CalibrationError(
                f"{path}: not a {CNN_FORMAT} network (dilations {dil}, missing "
                f"{', '.join(missing) or 'nothing'}, shape {shape})")
        w = {k: np.asarray(z[k], np.float32) for k in names}
        bad, cin = [], INPUTS
        for k in range(n):
            cout = w[f"b{k}"].shape[0] if w[f"b{k}"].ndim == 1 else -1
            if w[f"w{k}"].shape != (3, 3, cin, cout) or cout < 1:
                bad.append(f"w{k}/b{k}")
            else:
                _check_width(path, cout)
            cin = max(cout, 1)
        if w[f"w{n}"].shape != (cin, 2) or w[f"b{n}"].shape != (2,):
            bad.append(f"w{n}/b{n}")
        if bad:
            raise CalibrationError(f"{path}: not a {CNN_FORMAT} network (layers {', '.join(bad)})")
        _check_weights(path, w)
        return cls(w, dil, (shape[0], shape[1]), dict(meta or {}))


def _crop_plan(shape: tuple[int, int], ch: int, cw: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where :func:`train_cnn` draws its crops and how it weights their pixels.

    Crop origins are drawn uniformly from ``-crop + 1`` to the grid's last pixel and moved
    inside the grid, so a crop reaches the edge as often as the middle; a pixel's weight is
    the inverse of the chance that a crop covers it (per axis, the chances multiply),
    scaled so that it is ``ch·cw / (rows·cols)`` over that chance: every pixel then counts
    alike in expectation.

    Returns
    -------
    tuple of numpy.ndarray
        The row origins and the column origins to draw from (uniformly, with repeats), and
        the ``rows × cols`` float32 weights.
    """
    def axis(n: int, c: int) -> tuple[np.ndarray, np.ndarray]:
        starts = np.clip(np.arange(-c + 1, n), 0, n - c)
        edges = np.zeros(n + 1)
        np.add.at(edges, starts, 1.0)
        np.add.at(edges, starts + c, -1.0)
        chance = np.cumsum(edges[:-1]) / len(starts)
        return starts, c / (n * chance)

    rows_from, wr = axis(shape[0], ch)
    cols_from, wc = axis(shape[1], cw)
    return rows_from, cols_from, np.outer(wr, wc).astype(np.float32)


def train_cnn(
    changes: list[np.ndarray],
    images: list[np.ndarray],
    grad_x: list[np.ndarray],
    grad_y: list[np.ndarray],
    valid: list[np.ndarray],
    width: int = CNN_WIDTH,
    dilations: tuple[int, ...] = CNN_DILATIONS,
    steps: int = 3000,
    crop: int = 64,
    batch: int = 4,
    seed: int = 0,
    threads: int = 1,
    progress: Callable[[int, int], None] | None = None,
) -> ConvGradient:
    """Train :class:`ConvGradient` on calibration presses with known slopes.

    Parameters
    ----------
    changes, images, grad_x, grad_y, valid
        As :func:`train_mlp` (per press, all on one grid).
    width
        Channels of each 3 × 3 layer.
    dilations
        Dilation of each 3 × 3 layer.
    steps, crop, batch
        Adam steps (learning rate 3e-3 decayed ×0.1 by the end), each on ``batch`` crops of
        ``crop × crop`` pixels (the whole grid when smaller) at one random place in random
        presses; the loss is the squared slope error over the crops' trusted pixels, each
        weighted by the inverse of how often a crop covers it (:func:`_crop_plan`), so
        every pixel of the grid counts alike in expectation (a crop drawn uniformly inside
        the grid covers a pixel on its edge ``crop`` times less often than one in the
        middle, and the network would learn the gel's periphery from few presses).
    seed, threads
        As :func:`train_mlp` (deterministic for a seed and thread count; one thread).
    progress
        Called with ``(done, steps)`` about every tenth of the training.
    """
    import torch

    shape = _one_grid(changes)
    if not 1 <= len(dilations) <= _MAX_CNN_LAYERS:
        raise ValueError(f"1 to {_MAX_CNN_LAYERS} dilations, got {len(dilations)}")
    x = np.stack([mlp_inputs(c, i) for c, i in zip(changes, images, strict=True)])
    y = np.stack([np.stack([gx, gy], -1) for gx, gy in zip(grad_x, grad_y, strict=True)])
    m = np.stack(valid).astype(np.float32)
    _too_few_pixels(int(m.sum()))
    tx = torch.from_numpy(np.ascontiguousarray(x.transpose(0, 3, 1, 2)))
    ty = torch.from_numpy(np.ascontiguousarray(y.transpose(0, 3, 1, 2).astype(np.float32)))
    tm = torch.from_numpy(m)
    ch, cw = min(crop, shape[0]), min(crop, shape[1])
    rows_from, cols_from, weight = _crop_plan(shape, ch, cw)
    tw = torch.from_numpy(weight)
    norm = float(batch * ch * cw * m.mean())  # the trusted pixels a batch holds on average
    with _torch_threads(threads):
        gen = torch.Generator().manual_seed(seed)
        torch.manual_seed(seed)
        layers: list[torch.nn.Module] = []
        cin = INPUTS
        for d in dilations:
            layers += [torch.nn.Conv2d(cin, width, 3, padding=d, dilation=d,
                                       padding_mode="replicate"), torch.nn.Tanh()]
            cin = width
        layers.append(torch.nn.Conv2d(cin, 2, 1))
        net = torch.nn.Sequential(*layers)
        opt = torch.optim.Adam(net.parameters(), lr=3e-3)
        sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: 0.1 ** (s / max(steps, 1)))
        every = max(1, steps // 10)
        for s in range(steps):
            idx = torch.randint(0, len(tx), (batch,), generator=gen)
            r0 = int(rows_from[int(torch.randint(0, len(rows_from), (1,), generator=gen))])
            c0 = int(cols_from[int(torch.randint(0, len(cols_from), (1,), generator=gen))])
            sl = (idx, slice(None), slice(r0, r0 + ch), slice(c0, c0 + cw))
            mb = tm[idx, r0 : r0 + ch, c0 : c0 + cw] * tw[r0 : r0 + ch, c0 : c0 + cw]
            err = ((net(tx[sl]) - ty[sl]) ** 2).sum(1)
            loss = (err * mb).sum() / max(norm, 1.0)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            if progress is not None and ((s + 1) % every == 0 or s + 1 == steps):
                progress(s + 1, steps)
    convs = [mod for mod in net if isinstance(mod, torch.nn.Conv2d)]
    weights: dict[str, np.ndarray] = {}
    for k, conv in enumerate(convs):
        wt = conv.weight.detach().numpy()  # O × C × kh × kw
        if k < len(dilations):
            weights[f"w{k}"] = np.ascontiguousarray(wt.transpose(2, 3, 1, 0), np.float32)
        else:
            weights[f"w{k}"] = np.ascontiguousarray(wt[:, :, 0, 0].T, np.float32)
        assert conv.bias is not None  # every layer is built with a bias
        weights[f"b{k}"] = conv.bias.detach().numpy().astype(np.float32).copy()
    field_px = 1 + 2 * sum(dilations)
    meta = {"format": CNN_FORMAT, "width": width, "dilations": list(dilations),
            "receptive_field_px": field_px, "steps": steps, "crop": crop, "batch": batch,
            "pixels": int(m.sum()), "presses": len(changes)}
    return ConvGradient(weights, tuple(dilations), shape, meta)
