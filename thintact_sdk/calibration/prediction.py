"""What this design should achieve: the validation PSNR predicted from the profile alone.

The whole calibration is simulated on the *design*: the profile (mask, geometry, its
``physics``) through the exact simulator at the unit's measured signal level (one gain per
channel, fitted to the calibrated white response), with the profile's noise model at the
frames averaged: a dark frame, every row and column slit, solved by the same Algorithms 2-3,
a joint filter trained the same way, and each validation scene decoded by the same decoder
with τ chosen by the same cross-validation. The prediction therefore includes what slit
noise costs the calibration. A unit that falls well short of it on a scene is not as good as
its design.
"""

from __future__ import annotations

from collections.abc import Iterable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.calibration.lowrank import DEFAULT_RANK, LowRankImage, compress
from thintact_sdk.calibration.slits import ChannelSlits, SlitStack
from thintact_sdk.calibration.solver import Method, solve_channel
from thintact_sdk.calibration.tau import cross_validate, tau_grid
from thintact_sdk.calibration.validation import (
    averaged_noise,
    make_decoder,
    needs_joint_filter,
    score_psnr,
)
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import NoiseSpec, Profile
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.filter_training import (
    scene_for_channels,
    train_joint_filter,
    training_scenes,
)
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.simulation.noise import MAX_POISSON_ELECTRONS, signal_to_dn
from thintact_sdk.simulation.simulator import Simulator

SLIT_BATCH = 8
"""Slit scenes simulated per batch: memory at paper size is four float32 batches of
8 × 1024 × 1280 × 3 (signal, draws, frames; the previous batch's frames while they are
compressed), 0.5 GB. The Gaussian draws do not depend on it; where exact Poisson draws occur
(read noise under 3.9 electrons) their interleaving with the Gaussian ones does."""

GAUSSIAN_SKEW_LIMIT = 0.1
"""Largest skewness of a pixel's shot + read noise (in electrons: ``λ / (λ + (read·e)²)^1.5``
for ``λ`` expected photo-electrons) at which :func:`slit_dn` draws it as one Gaussian of the
same mean and variance instead of Poisson + Gaussian. The skewness peaks at ``0.385 /
(read·e)`` (at ``λ = 2 (read·e)²``), so for read noise of ``read·e ≥ 3.9`` electrons every
pixel is drawn Gaussian; the excess kurtosis ``λ / (λ + (read·e)²)²`` is smaller still."""


def slit_dn(signal_dn: np.ndarray, noise: NoiseSpec, rng: np.random.Generator) -> np.ndarray:
    """Raw DN of the expected signal ``signal_dn`` (DN above black, any shape): the noise model
    of :func:`~thintact_sdk.simulation.noise.signal_to_dn` drawn in float32 for speed.

    Mean and variance are :func:`signal_to_dn`'s (shot noise ``λ = e·signal`` electrons,
    read noise, rounding, clipping to ``[0, saturation]``). Where the skewness of shot + read
    noise is at most :data:`GAUSSIAN_SKEW_LIMIT`, one Gaussian of variance ``λ/e² + read²``
    replaces the Poisson + Gaussian pair; elsewhere the Poisson draw is exact. Returns
    float32 DN (black level included), same shape; the random stream differs from
    :func:`signal_to_dn`'s.
    """
    e = float(noise.electrons_per_dn)
    read = float(noise.read_noise_dn)
    # in place on as few fresh arrays as possible: at paper size each is a quarter GB, and
    # fresh pages cost more than the arithmetic
    lam = np.multiply(signal_dn, np.float32(e), dtype=np.float32)
    np.maximum(lam, np.float32(0.0), out=lam)
    np.minimum(lam, np.float32(MAX_POISSON_ELECTRONS), out=lam)
    z = rng.standard_normal(lam.shape, dtype=np.float32)
    a = np.float32((read * e) ** 2)
    exact: np.ndarray | None = None
    # the skewness peaks at 0.385 / (read·e): below the limit (with room for float32 rounding)
    # no pixel can be drawn exactly, and the elementwise test is skipped
    if a <= 0 or 2.0 * a / (3.0 * a) ** 1.5 * (1.0 + 1e-4) > GAUSSIAN_SKEW_LIMIT:
        exact = lam > np.float32(0.0)
        exact &= lam > np.float32(GAUSSIAN_SKEW_LIMIT) * (lam + a) ** np.float32(1.5)
    dn = lam + a
    np.sqrt(dn, out=dn)
    dn *= z
    dn += lam
    dn *= np.float32(1.0 / e)
    if exact is not None and np.any(exact):
        lam_x = lam[exact]
        dn[exact] = (rng.poisson(lam_x) / e + read * z[exact]).astype(np.float32)
    dn += np.float32(noise.black_level_dn)
    np.round(dn, out=dn)
    return np.clip(dn, 0.0, float(noise.saturation_dn), out=dn)


@dataclass
class Prediction:
    """Predicted held-out PSNR (dB) per validation label, and how it was made."""

    psnr_db: dict[str, float]
    gains_dn_per_unit: list[float]
    tau: float
    notes: dict[str, Any] = field(default_factory=dict)


def design_gains(profile: Profile, calibrated: SystemMatrices, sim: Simulator) -> np.ndarray:
    """DN per simulator unit, per channel, that make the design's white response match the
    unit's calibrated one in the least-squares sense."""
    n, m = calibrated.scene_shape
    white = np.ones((n, m, calibrated.channels))
    got = calibrated.forward(white)
    model = sim.linear_batch(white[None])[0]
    return np.array([float(np.sum(got[..., c] * model[..., c]) / np.sum(model[..., c] ** 2))
                     for c in range(calibrated.channels)])


def white_gains(profile: Profile, white_signal_dn: np.ndarray, sim: Simulator) -> np.ndarray:
    """:func:`design_gains` from a measured white frame (``R × S × C`` DN above dark) instead of
    the calibrated matrices' white response."""
    n, m = profile.scene.rows, profile.scene.cols
    got = np.asarray(white_signal_dn, np.float64)
    got = got if got.ndim == 3 else got[..., None]
    model = sim.linear_batch(np.ones((1, n, m, got.shape[2])))[0]
    return np.array([float(np.sum(got[..., c] * model[..., c]) / np.sum(model[..., c] ** 2))
                     for c in range(got.shape[2])])


def slit_scenes(idx: Iterable[int], n: int, m: int, c: int) -> np.ndarray:
    """The slit scenes ``len(idx) × n × m × c`` of slit indices ``idx``: index ``i < n`` lights
    scene row ``i``, index ``n + j`` lights scene column ``j`` (display value 1, the rest 0)."""
    idx = list(idx)
    x = np.zeros((len(idx), n, m, c))
    for b, i in enumerate(idx):
        if i < n:
            x[b, i] = 1.0
        else:
            x[b, :, i - n] = 1.0
    return x


def slit_factors(sim: Simulator, channels: int) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """Per channel ``(P, Q)``: the simulator's own separable expansion stacked, ``P`` of
    shape ``K × R × N`` and ``Q`` ``K × S × M`` (linear signal = ``Σ_k P_k X Q_kᵀ``), so that
    horizontal slit ``i`` (scene row ``i`` at 1) images as ``Σ_k P_k[:, i] (Q_k·1)ᵀ`` and
    vertical slit ``j`` as ``Σ_k (P_k·1) Q_k[:, j]ᵀ``: the same linear signal as
    :meth:`Simulator.linear_batch` of the slit scene (the expansion is the kernel), at
    ``R·S·K`` operations per slit instead of a forward pass of the whole scene.

    Returns None when the physics is not separable per channel or has DN-defined effects
    (then slits go through the simulator).
    """
    if sim.has_dn_effects:
        return None
    try:
        terms = [sim.separable_terms(c) for c in range(channels)]
    except ThinTactError:
        return None
    out = []
    for t in terms:
        p = np.stack([np.asarray(a, np.float64) for a, _ in t])  # K × R × N
        q = np.stack([np.asarray(b, np.float64) for _, b in t])  # K × S × M
        out.append((p, q))
    return out


def _slit_signal_dn(factors: list[tuple[np.ndarray, np.ndarray]], gains: np.ndarray, idx: range,
                    n: int) -> np.ndarray:
    """Expected signal (DN above black) of the slits ``idx`` (``< n``: row slits, else
    column ``i − n``) from :func:`slit_factors`: ``len(idx) × R × S × C`` float32 (the products
    taken in float64)."""
    c = len(factors)
    r, s = factors[0][0].shape[1], factors[0][1].shape[1]
    # float32: :func:`slit_dn` takes the signal to float32 first, so storing each float64
    # product's values in float32 here gives the same draws at half the memory
    out = np.empty((len(idx), r, s, c), np.float32)
    for ch, (p, q) in enumerate(factors):
        # K × R, K × S: the terms times the all-ones vector; the gain goes on the small factor
        p1, q1 = p.sum(axis=2) * gains[ch], q.sum(axis=2) * gains[ch]
        for b, i in enumerate(idx):
            if i < n:
                out[b, ..., ch] = p[:, :, i].T @ q1
            else:
                out[b, ..., ch] = p1.T @ q[:, :, i - n]
    return out


def simulated_calibration(profile: Profile, gains: np.ndarray, noise: NoiseSpec, method: Method,
                          max_iter: int, tol: float, rank: int, rng: np.random.Generator,
                          dark_dn: np.ndarray) -> SystemMatrices:
    """Algorithms 2-3 on a simulated slit scan of the design.

    Each slit is one noisy capture (``noise`` already averaged) minus ``dark_dn``, a simulated
    dark capture (raw DN, black level included), as the unit's slits are.
    """
    sim = Simulator(profile)
    n, m = profile.scene.rows, profile.scene.cols
    c = len(gains)
    factors = slit_factors(sim, c)
    h: list[tuple[list[int], list[np.ndarray], list[LowRankImage]]] = [([], [], []) for _ in range(c)]
    v: list[tuple[list[int], list[np.ndarray], list[LowRankImage]]] = [([], [], []) for _ in range(c)]

    def compressed(idx: range, ys: np.ndarray) -> list[list[LowRankImage]]:
        out = []
        for y, i in zip(ys, idx, strict=True):
            y = y - dark_dn
            out.append([compress(y[..., ch] if i < n else y[..., ch].T, rank, seed=i) for ch in range(c)])
        return out

    def add(idx: range, images: list[list[LowRankImage]]) -> None:
        for i, per_channel in zip(idx, images, strict=True):
            for ch, image in enumerate(per_channel):
                target, index, ones = (h[ch], i, np.ones(m)) if i < n else (v[ch], i - n, np.ones(n))
                target[0].append(index)
                target[1].append(ones)
                target[2].append(image)

    # the noise is drawn here, batch after batch from the one generator (the same draws as
    # ever); each batch's compression runs on a worker meanwhile, one batch behind
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="design-compress") as pool:
        pending: Future[list[list[LowRankImage]]] | None = None
        pending_idx = range(0)
        for start in range(0, n + m, SLIT_BATCH):
            idx = range(start, min(start + SLIT_BATCH, n + m))
            if factors is None:
                expected = sim.predict_signal_dn(slit_scenes(idx, n, m, c), gains)
            else:
                expected = _slit_signal_dn(factors, np.asarray(gains, float), idx, n)
            ys = slit_dn(expected, noise, rng)
            del expected
            if pending is not None:
                add(pending_idx, pending.result())
            pending, pending_idx = pool.submit(compressed, idx, ys), idx
            del ys
        if pending is not None:
            add(pending_idx, pending.result())
    mats = []
    for ch in range(c):
        slits = ChannelSlits(SlitStack.from_images(*h[ch]), SlitStack.from_images(*v[ch]), n, m)
        mats.append(solve_channel(slits, method=method, max_iter=max_iter, tol=tol)[0])
    return SystemMatrices(np.stack([a.Po for a in mats]), np.stack([a.Qo for a in mats]),
                          np.stack([a.Pc for a in mats]), np.stack([a.Qc for a in mats]),
                          {"source": "simulated calibration of the design"})


@dataclass
class PredictionDesign:
    """What a prediction needs before the decoder is known: the design's own simulated
    calibration at the unit's signal level (:func:`design_for_prediction`), the dark capture
    its validation frames are taken against and the random stream it continues with."""

    sim: Simulator
    gains: np.ndarray
    noise: NoiseSpec
    dark_dn: np.ndarray
    design: SystemMatrices
    rng: np.random.Generator
    seed: int


def design_for_prediction(
    profile: Profile,
    calibrated: SystemMatrices | None,
    frames_averaged: int,
    *,
    white_signal_dn: np.ndarray | None = None,
    method: Method = "lsq",
    max_iter: int = 50,
    tol: float = 1e-7,
    rank: int = DEFAULT_RANK,
    seed: int = 0,
) -> PredictionDesign:
    """The decoder-independent part of :func:`predict_validation` (the bulk of its time): the
    design's slit scan simulated and solved at the unit's signal level. The calibration runs
    it beside the health check and finishes with :func:`predict_from_design` once the decoder
    is chosen; the two give exactly what :func:`predict_validation` gives.

    The signal level comes from the unit's white frame (``white_signal_dn``, ``R × S × C`` DN
    above dark) when there is one, else from its matrices (``calibrated``): the design's white
    response is matched to it in the least-squares sense. The white frame is there before the
    matrices are solved (the wizard's capture runs this beside the slit scan), and both paths
    then draw the same noise: a gain that differs by 0.1 % changes every Poisson draw, so two
    signal levels would give two Monte Carlo realisations of the prediction.
    """
    sim = Simulator(profile)
    if white_signal_dn is not None:
        gains = white_gains(profile, white_signal_dn, sim)
        c, sensor_shape = len(gains), white_signal_dn.shape[:2]
    elif calibrated is not None:
        gains = design_gains(profile, calibrated, sim)
        c, sensor_shape = calibrated.channels, calibrated.sensor_shape
    else:
        raise ThinTactError("the prediction needs the unit's matrices or its white frame")
    noise = averaged_noise(profile.noise, frames_averaged)
    rng = np.random.default_rng(seed)
    dark_dn = signal_to_dn(np.zeros((*sensor_shape, c)), noise, rng)  # one dark capture
    design = simulated_calibration(profile, gains, noise, method, max_iter, tol, rank, rng, dark_dn)
    return PredictionDesign(sim, gains, noise, dark_dn, design, rng, seed)


def design_signals(prepared: PredictionDesign, scenes: list[np.ndarray],
                   rng: np.random.Generator) -> list[np.ndarray]:
    """The design's validation frames of ``scenes`` (``N × M × C`` display values): signals
    ``R × S × C`` above its dark capture (DN, float32), with the sensor noise drawn from ``rng``."""
    c = prepared.design.channels
    out = []
    for x in scenes:
        expected = prepared.sim.predict_signal_dn(scene_for_channels(x, c).astype(np.float64), prepared.gains)
        raw = signal_to_dn(expected, prepared.noise, rng)
        out.append((raw - prepared.dark_dn).astype(np.float32))
    return out


def predict_from_design(
    profile: Profile,
    prepared: PredictionDesign,
    labels: list[str],
    scenes: list[np.ndarray],
    decoder: str,
    *,
    filter_steps: int = 0,
    filter_scenes: int = 32,
) -> Prediction:
    """Finish a prediction for ``decoder`` (:func:`predict_validation`'s second part)."""
    design, noise, rng, gains = prepared.design, prepared.noise, prepared.rng, prepared.gains
    n, m = design.scene_shape
    jf = None
    if needs_joint_filter(decoder):
        jf = train_joint_filter(design, training_scenes(n, m, count=filter_scenes, seed=0),
                                noise=noise, steps=filter_steps, seed=0)
    bundle = CalibrationBundle.create(profile, design, jf, tau=1.0, source="simulator")
    dec = make_decoder(profile, bundle, decoder)
    signals = design_signals(prepared, scenes, rng)
    grid = tau_grid(design)
    cv = cross_validate(dec, decoder, signals, scenes, labels, grid)
    if cv is not None:
        return Prediction(dict(cv.held_out_psnr), gains.tolist(), cv.curve.tau, {"fold_tau": cv.fold_tau})
    best: dict[str, float] = {}  # one scene: the best τ in hindsight is the design's potential
    for tau in grid:
        dec.set_tau(float(tau))  # type: ignore[attr-defined]
        for label, y, x in zip(labels, signals, scenes, strict=True):
            best[label] = max(best.get(label, -np.inf), score_psnr(dec.decode(y), x))
    return Prediction(best, gains.tolist(), float("nan"), {"tau": "best in hindsight"})


def predict_validation(
    profile: Profile,
    calibrated: SystemMatrices,
    labels: list[str],
    scenes: list[np.ndarray],
    decoder: str,
    frames_averaged: int,
    *,
    filter_steps: int = 0,
    filter_scenes: int = 32,
    method: Method = "lsq",
    max_iter: int = 50,
    tol: float = 1e-7,
    rank: int = DEFAULT_RANK,
    seed: int = 0,
) -> Prediction:
    """Predicted held-out PSNR of each validation scene for a unit built exactly to ``profile``.

    Parameters
    ----------
    calibrated
        The unit's matrices (for the signal level only).
    labels, scenes
        The validation frames' labels and displayed scenes (``N × M × C``).
    decoder
        The decoder the unit is validated with.
    frames_averaged, filter_steps, filter_scenes, method, max_iter, tol, rank
        As for the unit's own calibration.
    """
    prepared = design_for_prediction(profile, calibrated, frames_averaged, method=method,
                                     max_iter=max_iter, tol=tol, rank=rank, seed=seed)
    return predict_from_design(profile, prepared, labels, scenes, decoder,
                               filter_steps=filter_steps, filter_scenes=filter_scenes)
