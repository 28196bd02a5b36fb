"""Training the frequency-spatial joint filter on a virtual data set (paper §B).

The data set is made from the system matrices and scene images: ``Y = Po X Qoᵀ + Pc X Qcᵀ``
(+ sensor noise), target ``Yo = Po X Qoᵀ``. The filter ``F(Y) = Φs ⊙ IDCT(Φf ⊙ DCT(Y))`` is
fitted to minimise ``Σ ‖F(Y) − Yo‖²_F`` per channel:

1. closed-form initialisation: with ``Φs = 1`` the loss separates per DCT coefficient
   (Parseval), so ``Φf = Σ DCT(Y)·DCT(Yo) / Σ DCT(Y)²``; given Φf, the loss separates per
   pixel and depends on the data only through ``H = Σ G²`` and ``K = Σ G·Yo``
   (``G = IDCT(Φf ⊙ DCT(Y))``), so ``Φs = K / H`` (or its best weighted rank-r fit).
   A few alternations.
2. gradient descent (Adam, torch) on the exact loss, from that start.

Structure options make the decoder's fast path exact: ``low_block=(kr, ks)`` keeps Φf zero
outside the lowest ``kr × ks`` DCT frequencies, ``phi_s_rank=r`` makes ``Φs = U Vᵀ`` of rank r.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import gaussian_filter

from thintact_sdk.errors import InvalidShapeError, InvalidValueError
from thintact_sdk.reconstruction.dct import SeparableDCT, dct2, idct2
from thintact_sdk.reconstruction.joint_filter import JointFilter
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.simulation.noise import signal_variance_dn
from thintact_sdk.simulation.scenes import gelsight, gelsight_count, make_scene

__all__ = [
    "JointFilter",
    "OpenComponents",
    "TrainingData",
    "make_training_data",
    "scene_for_channels",
    "train_joint_filter",
    "training_scenes",
]


def scene_for_channels(scene: np.ndarray, channels: int) -> np.ndarray:
    """``scene`` (``N × M`` or ``N × M × C``, display units) as ``N × M × channels``.

    A one-channel (monochrome) device sees the mean of the display's linear channels; a
    one-channel scene is shown grey on every channel of a colour device; a device keeping the
    four Bayer sites apart (R, Gr, Gb, B) sees an RGB scene's G on both green planes.

    Raises
    ------
    ValueError
        When the channel counts cannot be matched (e.g. 4 scene channels for a 3-channel device).
    """
    x = np.asarray(scene)
    if x.ndim == 2:
        x = x[..., None]
    if x.ndim != 3:
        raise InvalidShapeError(f"scene must be N×M or N×M×C, got shape {x.shape}")
    have = x.shape[2]
    if have == channels:
        return x
    if channels == 1:
        return x.mean(axis=2, keepdims=True, dtype=np.float64).astype(x.dtype, copy=False)
    if have == 1:
        return np.repeat(x, channels, axis=2)
    if have == 3 and channels == 4:
        return x[..., [0, 1, 1, 2]]
    raise InvalidShapeError(f"scene has {have} channels but the device has {channels}")


def training_scenes(n: int, m: int, count: int = 32, seed: int = 0) -> list[np.ndarray]:
    """A varied scene set for filter training, ``count`` images ``N × M × 3`` in [0, 1].

    GelSight presses, white, USAF, checker, smooth colour, random smooth fields at several
    scales and random sharp shapes (rectangles and discs).
    """
    rng = np.random.default_rng(seed)
    fixed = [make_scene(name, n, m) for name in ("white", "usaf", "checker", "smooth_color")]
    out: list[np.ndarray] = list(fixed)
    gel = [gelsight(n, m, i) for i in range(-1, min(gelsight_count(), 6))]
    out.extend(gel)
    yy, xx = np.mgrid[0:n, 0:m]
    k = 0
    while len(out) < count:
        kind = k % 3
        if kind == 0:
            sigma = float(rng.choice([1.0, 2.0, 4.0, 8.0])) * max(n, m) / 64
            img = gaussian_filter(rng.random((n, m, 3)), (sigma, sigma, 0))
            img = (img - img.min()) / max(float(np.ptp(img)), 1e-9)
        elif kind == 1:
            img = np.full((n, m, 3), rng.random(3) * 0.3)
            for _ in range(int(rng.integers(3, 9))):
                cy, cx = rng.integers(0, n), rng.integers(0, m)
                r = rng.integers(2, max(3, min(n, m) // 4))
                if rng.random() < 0.5:
                    mask = (yy - cy) ** 2 + (xx - cx) ** 2 < r**2
                else:
                    mask = (np.abs(yy - cy) < r) & (np.abs(xx - cx) < rng.integers(2, max(3, m // 3)))
                img[mask] = rng.random(3)
        else:
            img = rng.random((n, m, 3))
        out.append(np.clip(img, 0, 1).astype(np.float32))
        k += 1
    return out[:count]


class OpenComponents:
    """The open components ``Yo_f = Po X_f Qoᵀ`` of a data set, computed again each time a frame
    is read instead of held (``F × C × R × S``, float32 DN, equal to the held ones). The closed
    form reads each twice per round; holding them all takes as much memory as the
    measurements (0.5 GB at the paper's size)."""

    def __init__(self, system_matrices: SystemMatrices, scenes: Sequence[np.ndarray]) -> None:
        self._sm = system_matrices
        self._scenes = list(scenes)
        self.shape = (len(self._scenes), system_matrices.channels, *system_matrices.sensor_shape)

    def __len__(self) -> int:
        return len(self._scenes)

    def __getitem__(self, f: int) -> np.ndarray:
        x = scene_for_channels(self._scenes[f], self._sm.channels)
        return np.moveaxis(self._sm.forward_open(x), -1, 0).astype(np.float32)

    def __iter__(self) -> Iterator[np.ndarray]:
        return (self[f] for f in range(len(self)))

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = np.stack(list(self))
        return out if dtype is None else out.astype(dtype)

    def any(self) -> bool:
        """Whether the open term is non-zero (``Po X Qoᵀ`` is zero for every scene when it is not)."""
        return bool(np.any(self._sm.Po) and np.any(self._sm.Qo))


@dataclass
class TrainingData:
    """Virtual data set: measurements and their open components, ``F × C × R × S`` (DN); the
    open components either held or :class:`OpenComponents` (computed when read)."""

    y: np.ndarray
    y_open: np.ndarray | OpenComponents

    def has_open(self) -> bool:
        """Whether the open components are not all zero."""
        yo = self.y_open
        return yo.any() if isinstance(yo, OpenComponents) else bool(np.any(yo))


def make_training_data(
    system_matrices: SystemMatrices,
    scenes: Sequence[np.ndarray],
    noise: Any | None = None,
    seed: int = 0,
    hold_open: bool = True,
) -> TrainingData:
    """Simulate ``Y`` and ``Yo`` for every scene with the T2S model.

    Parameters
    ----------
    scenes
        ``N × M × C`` display values; reduced or repeated to the matrices' channel count with
        :func:`scene_for_channels` (a monochrome device trains a one-channel filter).
    noise
        A :class:`thintact_sdk.formats.profiles.NoiseSpec` (or ``None`` for noiseless data): Gaussian
        noise of the sensor's variance ``read² + Y / electrons_per_dn`` (DN²) is added to Y.
    hold_open
        Hold the open components (``False``: :class:`OpenComponents`, computed when read; the
        measurements and their noise are the same either way).
    """
    rng = np.random.default_rng(seed)
    ys: np.ndarray | None = None
    yos: np.ndarray | None = None
    for f, scene in enumerate(scenes):  # written in place: no list of frames beside the stack
        x = scene_for_channels(scene, system_matrices.channels)
        yo = system_matrices.forward_open(x)
        y = system_matrices.forward_coding(x)
        y += yo  # in place: one float64 frame fewer at a time (the same sums)
        if noise is not None:
            draw = rng.standard_normal(y.shape)
            draw *= np.sqrt(signal_variance_dn(y, noise))
            y += draw
        if ys is None:
            ys = np.empty((len(scenes), y.shape[-1], *y.shape[:-1]), np.float32)
            yos = np.empty_like(ys) if hold_open else None
        ys[f] = np.moveaxis(y, -1, 0)
        if yos is not None:
            yos[f] = np.moveaxis(yo, -1, 0)
    if ys is None:
        raise InvalidValueError("the joint filter needs at least one training scene")
    return TrainingData(ys, yos if yos is not None else OpenComponents(system_matrices, scenes))


def _transform(shape: tuple[int, int], low_block: tuple[int, int] | None) -> SeparableDCT:
    """Full DCT (scipy) or a low-frequency block DCT by float32 matrices."""
    if low_block is None:
        return SeparableDCT(shape)
    return SeparableDCT(shape, low_block, to_backend=lambda a: a.astype(np.float32))


def _fit_phi_s(h: np.ndarray, k: np.ndarray, rank: int | None, iters: int = 30) -> np.ndarray:
    """Per channel: minimise ``Σ H Φs² − 2 K Φs`` (full) or over ``Φs = U Vᵀ`` of ``rank``."""
    lam = 1e-6 * float(np.mean(h)) + 1e-30
    full = (k + lam) / (h + lam)
    if rank is None:
        return full
    out = np.empty_like(full)
    for c in range(full.shape[0]):
        u_, s_, vt_ = np.linalg.svd(full[c], full_matrices=False)
        u = u_[:, :rank] * s_[:rank]
        v = vt_[:rank].T
        w, kc = h[c] + lam, k[c] + lam
        eye = np.eye(rank) * 1e-12
        for _ in range(iters):  # weighted ALS: rows of U, then rows of V (Gram blocks by GEMM)
            a = (w @ (v[:, :, None] * v[:, None, :]).reshape(-1, rank * rank)).reshape(-1, rank, rank)
            u = np.linalg.solve(a + eye * w.mean(), (kc @ v)[..., None])[..., 0]
            a = (w.T @ (u[:, :, None] * u[:, None, :]).reshape(-1, rank * rank)).reshape(-1, rank, rank)
            v = np.linalg.solve(a + eye * w.mean(), (kc.T @ u)[..., None])[..., 0]
        out[c] = u @ v.T
    return out


def _closed_form(
    data: TrainingData, tr: SeparableDCT, rank: int | None, rounds: int, in_place: bool = False
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """The closed-form alternation; ``in_place``: each frame of ``data.y`` is replaced by its
    spectrum (where shape and dtype allow), so the measurements and their spectra are never
    held side by side (0.5 GB each at the paper's size; ``data.y`` is spent)."""
    # sums over the frames are taken a frame at a time: no F-frame temporaries beside the
    # transformed measurements (at the paper's size each would be 0.5-1 GB)
    first = tr.fwd(data.y[0])
    if in_place and first.shape == data.y.shape[1:] and first.dtype == data.y.dtype:
        zy = data.y
    else:
        zy = np.empty((data.y.shape[0], *first.shape), first.dtype)  # F × C × (block)
    zy[0] = first
    for f in range(1, data.y.shape[0]):
        zy[f] = tr.fwd(data.y[f])
    zz = np.zeros(zy.shape[1:])
    for z in zy:
        zz += z.astype(np.float64) ** 2
    ridge = 1e-9 * float(np.mean(zz)) + 1e-30
    yo_norm = 0.0  # ‖Yo‖², taken in the first round's pass (open components may be computed when read)
    c, r, s = data.y.shape[1:]
    phi_s = np.ones((c, r, s))
    history: list[float] = []
    best: tuple[float, np.ndarray, np.ndarray] | None = None
    for i in range(rounds):
        safe = np.where(np.abs(phi_s) > 1e-3, phi_s, 1e-3)
        num = np.zeros(zy.shape[1:])
        for z, yo in zip(zy, data.y_open, strict=True):
            if i == 0:
                yo_norm += float(np.sum(np.square(yo, dtype=np.float64)))
            num += z * tr.fwd(yo / safe)
        phi_f = num / (zz + ridge)
        h = np.zeros((c, r, s))
        k = np.zeros((c, r, s))
        for f, yo in enumerate(data.y_open):
            g = tr.inv(phi_f * zy[f])
            h += g * g
            k += g * yo
        phi_s = _fit_phi_s(h, k, rank)
        # ‖Φs ⊙ g_f − Yo_f‖² summed over the frames is Σ Φs² H − 2 Φs K + ‖Yo‖²: the relative
        # loss from the sums just taken, with no frame transformed again
        loss = max(0.0, float(np.sum(phi_s * (phi_s * h - 2.0 * k))) + yo_norm) / yo_norm
        history.append(loss)
        if best is None or loss < best[0]:
            best = (loss, phi_f, phi_s)
    assert best is not None
    return best[1], best[2], history


def _refine_torch(
    data: TrainingData,
    low_block: tuple[int, int] | None,
    phi_f: np.ndarray,
    phi_s: np.ndarray,
    rank: int | None,
    steps: int,
    lr: float,
    progress: Callable[[int, float], None] | None,
    start_loss: float,
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """Adam on the exact loss; returns the best parameters seen (the start if never improved)."""
    import torch

    c, r, s = data.y.shape[1:]
    kr, ks = low_block if low_block is not None else (r, s)
    tr = SeparableDCT((r, s), (kr, ks), to_backend=lambda a: torch.from_numpy(a.astype(np.float32)))
    y = torch.from_numpy(data.y)
    yo = torch.from_numpy(np.asarray(data.y_open))
    norm = float(torch.sum(yo.double() ** 2))
    pf = torch.tensor(phi_f, dtype=torch.float32, requires_grad=True)
    params = [pf]
    if rank is None:
        ps = torch.tensor(phi_s, dtype=torch.float32, requires_grad=True)
        params.append(ps)
    else:
        us, vs = [], []
        for ch in range(c):
            u_, s_, vt_ = np.linalg.svd(phi_s[ch], full_matrices=False)
            us.append(u_[:, :rank] * np.sqrt(s_[:rank]))
            vs.append(vt_[:rank].T * np.sqrt(s_[:rank]))
        pu = torch.tensor(np.stack(us), dtype=torch.float32, requires_grad=True)
        pv = torch.tensor(np.stack(vs), dtype=torch.float32, requires_grad=True)
        params += [pu, pv]
    # Adam steps are scale-free; step sizes relative to each parameter's typical magnitude
    scales = [float(torch.mean(torch.abs(p.detach()))) + 1e-12 for p in params]
    opt = torch.optim.Adam([{"params": [p], "lr": lr * sc} for p, sc in zip(params, scales, strict=True)])
    zy = tr.fwd(y)  # F × C × kr × ks, fixed

    def current_phi_s() -> torch.Tensor:
        return ps if rank is None else pu @ pv.transpose(-1, -2)

    history: list[float] = []
    best = (start_loss, phi_f, phi_s)
    for step in range(steps):
        opt.zero_grad()
        g = current_phi_s() * tr.inv(pf * zy)  # the joint filter on the fixed spectrum
        loss = torch.sum((g - yo) ** 2) / norm
        loss.backward()
        opt.step()
        val = float(loss.detach())
        history.append(val)
        if val < best[0]:
            best = (val, pf.detach().numpy().astype(np.float64).copy(),
                    current_phi_s().detach().numpy().astype(np.float64).copy())
        if progress is not None:
            progress(step, val)
    return best[1], best[2], history


ADAM_BETAS = (0.9, 0.999)
ADAM_EPS = 1e-8
"""Adam's moment decays and denominator guard (``torch.optim.Adam``'s defaults, used by both
refinements)."""


def _loss_and_gradient(zy: Sequence[np.ndarray], y_open: np.ndarray | OpenComponents, pf: np.ndarray, ps: np.ndarray,
                       norm: float) -> tuple[float, list[np.ndarray]]:
    """The relative loss ``Σ‖Φs ⊙ IDCT(Φf ⊙ Z_f) − Yo_f‖² / norm`` and its gradients
    ``[∂/∂Φf, ∂/∂Φs]`` (float32, ``C × R × S``) for spectra ``zy`` (``F × C × R × S``); see
    :func:`_refine_fft`."""
    gf, gs = np.zeros_like(pf), np.zeros_like(ps)
    err = 0.0
    for f, z in enumerate(zy):
        g = idct2(pf * z, workers=-1)
        e = ps * g
        e -= y_open[f]
        err += float(np.sum(np.square(e, dtype=np.float64)))
        gs += e * g
        gf += z * dct2(ps * e, workers=-1)
    scale = np.float32(2.0 / norm)
    gf *= scale
    gs *= scale
    return err / norm, [gf, gs]


def _refine_fft(
    data: TrainingData,
    phi_f: np.ndarray,
    phi_s: np.ndarray,
    steps: int,
    lr: float,
    progress: Callable[[int, float], None] | None,
    start_loss: float,
) -> tuple[np.ndarray, np.ndarray, list[float]]:
    """:func:`_refine_torch` for a full-size Φf and an unconstrained Φs, with the gradient
    written out and scipy's fast DCT instead of dense DCT matrices (``O(R·S·log)`` per frame
    instead of ``O(R·S·(R + S))``).

    With ``G_f = IDCT(Φf ⊙ Z_f)`` (``Z_f = DCT(Y_f)``) and the residual
    ``E_f = Φs ⊙ G_f − Yo_f``, the loss ``Σ‖E_f‖² / ‖Yo‖²`` has the gradients
    ``∂/∂Φs = 2 Σ E_f ⊙ G_f / ‖Yo‖²`` and ``∂/∂Φf = 2 Σ Z_f ⊙ DCT(Φs ⊙ E_f) / ‖Yo‖²`` (the DCT
    is orthonormal: the adjoint of its inverse is itself). Adam's update is torch's (same
    betas, ε, per-parameter learning rate ``lr × mean|p|``), in float32 as there; frames are
    taken one at a time, so memory is the data set plus a few ``C × R × S`` arrays.
    """

    y_open = data.y_open
    norm = sum(float(np.sum(yo.astype(np.float64) ** 2)) for yo in y_open)  # frame by frame
    zy = [dct2(y, workers=-1) for y in data.y]  # fixed spectra, float32
    params = [phi_f.astype(np.float32), phi_s.astype(np.float32)]
    lrs = [lr * (float(np.mean(np.abs(p))) + 1e-12) for p in params]
    m1 = [np.zeros_like(p) for p in params]
    m2 = [np.zeros_like(p) for p in params]
    b1, b2 = ADAM_BETAS
    history: list[float] = []
    best = (start_loss, phi_f, phi_s)
    for step in range(steps):
        val, grads = _loss_and_gradient(zy, y_open, params[0], params[1], norm)
        t = step + 1
        for p, gr, a, b, rate in zip(params, grads, m1, m2, lrs, strict=True):
            a *= np.float32(b1)
            a += np.float32(1.0 - b1) * gr
            b *= np.float32(b2)
            b += np.float32(1.0 - b2) * gr * gr
            denom = np.sqrt(b) / np.float32(np.sqrt(1.0 - b2**t)) + np.float32(ADAM_EPS)
            p -= np.float32(rate / (1.0 - b1**t)) * a / denom
        history.append(val)
        if val < best[0]:  # as the torch loop: the loss before the step, the parameters after it
            best = (val, params[0].astype(np.float64), params[1].astype(np.float64))
        if progress is not None:
            progress(step, val)
    return best[1], best[2], history


def auto_low_block(data: TrainingData, energy: float = 0.99999) -> tuple[int, int]:
    """Smallest low-frequency DCT block (same fraction of R and S) holding ``energy`` of ``Yo``."""
    r, s = (int(v) for v in data.y_open.shape[2:])
    zo = np.zeros((r, s))
    for yo in data.y_open:  # frame by frame: no float64 copy of the data set
        zo += np.sum(dct2(yo).astype(np.float64) ** 2, axis=0)
    total = float(zo.sum())
    cum = np.cumsum(np.cumsum(zo, axis=0), axis=1)
    for frac in np.linspace(0.02, 1.0, 50):
        kr, ks = max(1, int(np.ceil(frac * r))), max(1, int(np.ceil(frac * s)))
        if cum[kr - 1, ks - 1] >= energy * total:
            return kr, ks
    return r, s


def train_joint_filter(
    system_matrices: SystemMatrices,
    scenes: Sequence[np.ndarray] | None = None,
    *,
    noise: Any | None = None,
    low_block: tuple[int, int] | str | None = None,
    phi_s_rank: int | None = None,
    closed_form_rounds: int = 3,
    steps: int = 100,
    lr: float = 0.01,
    seed: int = 0,
    data: TrainingData | None = None,
    progress: Callable[[int, float], None] | None = None,
) -> JointFilter:
    """Train Φf and Φs of the joint filter for ``system_matrices`` (paper §B).

    Parameters
    ----------
    system_matrices
        The device's T2S matrices (DN per display unit).
    scenes
        Training scenes ``N × M × C`` in [0, 1]; default :func:`training_scenes` (32 scenes).
    noise
        NoiseSpec for noisy training data (recommended: the filter then learns to ignore noise).
    low_block
        ``(kr, ks)`` support of Φf, ``"auto"`` (99.999 % of the open component's DCT energy) or
        ``None`` (full R × S).
    phi_s_rank
        Rank of Φs (``None``: unconstrained).
    closed_form_rounds
        Alternations of the closed-form initialisation.
    steps, lr
        Adam steps on the exact loss (0 to keep the closed form) and relative learning rate.
    data
        A ready data set (skips simulation; ``scenes`` and ``noise`` are then ignored).
    progress
        Called as ``progress(step, loss)`` during gradient descent.

    Returns
    -------
    JointFilter
        ``meta`` holds the relative training loss ``‖F(Y) − Yo‖² / ‖Yo‖²`` of each stage.
    """
    own_data = data is None
    if data is None:
        n, m = system_matrices.scene_shape
        scenes = training_scenes(n, m, seed=seed) if scenes is None else scenes
        # the closed form alone reads each open component twice per round: computed when
        # read rather than held beside the measurements (the gradient steps read them every step)
        data = make_training_data(system_matrices, scenes, noise=noise, seed=seed, hold_open=steps > 0)
    r, s = data.y.shape[2:]
    if not data.has_open():  # one-term (coding-only) matrices: nothing to remove, F(Y) = 0
        c = data.y.shape[1]
        return JointFilter(np.zeros((c, r, s)), np.ones((c, r, s)),
                           {"method": "none: the system matrices have no open term", "final_loss": 0.0})
    block: tuple[int, int] | None
    if isinstance(low_block, str):
        if low_block != "auto":
            raise InvalidValueError(f"low_block must be (kr, ks), 'auto' or None, got {low_block!r}")
        block = auto_low_block(data)
    else:
        block = None if low_block is None else (int(low_block[0]), int(low_block[1]))
    if block is not None and (block[0] >= r and block[1] >= s):
        block = None
    tr = _transform((r, s), block)
    # data made here and not needed after the closed form: its measurements become their spectra
    phi_f, phi_s, hist_cf = _closed_form(data, tr, phi_s_rank, max(1, closed_form_rounds),
                                         in_place=own_data and steps <= 0)
    hist_gd: list[float] = []
    if steps > 0 and block is None and phi_s_rank is None:
        phi_f, phi_s, hist_gd = _refine_fft(data, phi_f, phi_s, steps, lr, progress, min(hist_cf))
    elif steps > 0:
        phi_f, phi_s, hist_gd = _refine_torch(
            data, block, phi_f, phi_s, phi_s_rank, steps, lr, progress, min(hist_cf)
        )
    c = data.y.shape[1]
    full_f = np.zeros((c, r, s))
    if block is None:
        full_f[:] = phi_f
    else:
        full_f[:, : block[0], : block[1]] = phi_f
    meta = {
        "method": "closed-form init + Adam (paper §B)",
        "frames": int(data.y.shape[0]),
        "low_block": None if block is None else list(block),
        "phi_s_rank": phi_s_rank,
        "closed_form_loss": hist_cf,
        "steps": steps,
        "lr": lr,
        "final_loss": min(hist_cf + hist_gd),
        "noise": noise is not None,
    }
    return JointFilter(full_f, phi_s, meta)
