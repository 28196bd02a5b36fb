"""Calibration bundles for virtual devices, made from the simulator (no slit scan needed).

The system matrices are the best two-term separable fit to the simulator
(:meth:`SystemMatrices.two_term_fit`, DN per display unit at the virtual camera's reference
exposure). The joint filter is trained on measurements simulated with the *full* simulator
(plus sensor noise), with the target ``Yo = Y_sim − Pc X Qcᵀ``: what the closed-form solve
expects to remain after the filter, so the filter also absorbs what the two-term fit misses.
τ is the value maximising the mean PSNR on validation scenes that are not training scenes.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from thintact_sdk.device.virtual_bench import REFERENCE_EXPOSURE_US, signal_scale_dn
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.interfaces import TunableDecoder
from thintact_sdk.reconstruction.bundle import CalibrationBundle
from thintact_sdk.reconstruction.decoders.components import (
    make_flatcam,
    make_iterative,
    make_noniterative,
    make_t2s_closed_form,
)
from thintact_sdk.reconstruction.filter_training import (
    TrainingData,
    train_joint_filter,
    training_scenes,
)
from thintact_sdk.reconstruction.metrics import psnr, ssim
from thintact_sdk.reconstruction.t2s import SystemMatrices
from thintact_sdk.reconstruction.tau_sweep import tune_decoder_tau
from thintact_sdk.simulation.scenes import make_scene
from thintact_sdk.simulation.simulator import Simulator

#: τ candidates relative to the mean squared singular value of the coding operator.
TAU_GRID_REL = (0.1, 0.2, 0.4, 0.7, 1.0, 1.5, 2.0, 3.0, 5.0, 8.0)
#: Validation scenes: (library name, index).
VALIDATION_SCENES = (("white", 0), ("usaf", 0), ("gelsight", 20), ("gelsight", 31), ("smooth_color", 0))


def coding_power(sm: SystemMatrices) -> float:
    """Mean squared singular value of ``Qc ⊗ Pc`` over channels, ``‖Pc‖²‖Qc‖² / (N·M)`` (DN²)."""
    n, m = sm.scene_shape
    vals = [float(np.sum(sm.Pc[c] ** 2) * np.sum(sm.Qc[c] ** 2)) / (n * m) for c in range(sm.channels)]
    return float(np.mean(vals))


@dataclass
class VirtualCalibrationOptions:
    """Settings of :func:`make_virtual_bundle`.

    Attributes
    ----------
    training_count
        Number of training scenes (:func:`training_scenes`).
    low_block, phi_s_rank
        Filter structure (see :func:`train_joint_filter`); the defaults let the decoder fold
        the filter exactly into its matrix products.
    steps
        Adam steps after the closed-form initialisation.
    seed
        Seed of scenes and noise.
    camera_settings
        Virtual camera settings (``white_level_dn``) that set the DN scale.
    """

    training_count: int = 48
    low_block: tuple[int, int] | str | None = "auto"
    phi_s_rank: int | None = 4
    steps: int = 60
    seed: int = 0
    camera_settings: dict[str, Any] = field(default_factory=dict)


def simulate_measurements(
    simulator: Any, scale_dn: float, scenes: Sequence[np.ndarray], noise: Any | None, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(noisy, clean)`` signals in DN above black, ``F × R × S × C`` float32 each."""
    from thintact_sdk.simulation.noise import signal_to_dn

    rng = np.random.default_rng(seed)
    clean = simulator.forward_batch(np.stack(scenes)) * scale_dn
    if noise is None:
        return clean.astype(np.float32), clean.astype(np.float32)
    noisy = signal_to_dn(clean, noise, rng) - noise.black_level_dn
    return noisy.astype(np.float32), clean.astype(np.float32)


def evaluate(decode: Callable[[np.ndarray], np.ndarray], measurements: np.ndarray,
             scenes: Sequence[np.ndarray]) -> tuple[list[float], list[float]]:
    """PSNR (dB) and SSIM of ``decode`` (clipped to [0, 1]) on every measurement/scene pair."""
    ps, ss = [], []
    for y, x in zip(measurements, scenes, strict=True):
        xh = np.clip(decode(y), 0.0, 1.0)
        ps.append(float(psnr(xh, x)))
        ss.append(float(ssim(xh, x)))
    return ps, ss


def make_virtual_bundle(
    profile: Profile,
    options: VirtualCalibrationOptions | None = None,
    progress: Callable[[str], None] | None = None,
) -> CalibrationBundle:
    """Two-term fit + trained joint filter + τ choice + validation metrics for a virtual profile.

    Returns
    -------
    CalibrationBundle
        ``source="simulator"``; ``metrics`` holds the fit error, filter loss, τ table and the
        per-scene PSNR/SSIM of the non-iterative decoder and of FlatCam.
    """
    opts = options or VirtualCalibrationOptions()
    say = progress or (lambda _msg: None)
    sim = Simulator(profile)
    scale = signal_scale_dn(profile, opts.camera_settings)
    say("two-term fit")
    sm = SystemMatrices.two_term_fit(sim, scale_dn=scale)
    n, m = sm.scene_shape
    say("training data")
    train = training_scenes(n, m, opts.training_count, seed=opts.seed)
    noisy, clean = simulate_measurements(sim, scale, train, profile.noise, opts.seed)
    coding = np.stack([sm.forward_coding(x) for x in train]).astype(np.float32)
    data = TrainingData(np.moveaxis(noisy, -1, 1).copy(), np.moveaxis(clean - coding, -1, 1).copy())
    say("filter training")
    jf = train_joint_filter(sm, data=data, low_block=opts.low_block, phi_s_rank=opts.phi_s_rank,
                            steps=opts.steps, seed=opts.seed)
    say("choosing tau")
    val_scenes = [make_scene(name, n, m, i) for name, i in VALIDATION_SCENES]
    val_y, _ = simulate_measurements(sim, scale, val_scenes, profile.noise, opts.seed + 1)
    unit = coding_power(sm)
    # the core's own decoders (reconstruction.decoders), on an in-memory bundle
    provisional = CalibrationBundle.create(profile, sm, jf, tau=unit, source="simulator",
                                           scale_dn_per_unit=scale)

    def decoder(factory: Callable[..., Any], **settings: Any) -> Any:
        return factory(profile, {"bundle": provisional, **settings})

    ni, cf = decoder(make_noniterative), decoder(make_t2s_closed_form)
    tau, table = choose_tau(ni, unit, val_y, val_scenes)
    tau_cf, table_cf = choose_tau(cf, unit, val_y, val_scenes)
    say("validation")
    labels = [f"{name}{'' if name != 'gelsight' else '-' + str(i)}" for name, i in VALIDATION_SCENES]
    decoders = {
        "": ni.decode,
        "t2s_closed_form_": cf.decode,
        "iterative800_": decoder(make_iterative, tau=tau_cf, iterations=800).decode,
        "flatcam_": decoder(make_flatcam, tau=tau).decode,
    }
    metrics: dict[str, Any] = {
        "two_term_fit_relative_error": sm.meta["fit_relative_error"],
        "filter_training_loss": jf.meta["final_loss"],
        "filter_structure": {"low_block": jf.meta["low_block"], "phi_s_rank": jf.meta["phi_s_rank"]},
        "tau_table_mean_psnr_db": table,
        "t2s_closed_form_tau_table_mean_psnr_db": table_cf,
        "validation_noise": "virtual camera noise model (Poisson + read noise, rounded)",
    }
    for prefix, decode in decoders.items():
        ps, ss = evaluate(decode, val_y, val_scenes)
        metrics[f"{prefix}psnr_db"] = dict(zip(labels, np.round(ps, 2).tolist(), strict=True))
        metrics[f"{prefix}ssim"] = dict(zip(labels, np.round(ss, 3).tolist(), strict=True))
    return CalibrationBundle.create(
        profile, sm, jf, tau=tau, source="simulator", exposure_us=REFERENCE_EXPOSURE_US,
        metrics=metrics, scale_dn_per_unit=scale, tau_t2s_closed_form=tau_cf,
    )


def choose_tau(
    decoder: TunableDecoder, unit: float, measurements: np.ndarray, scenes: Sequence[np.ndarray]
) -> tuple[float, dict[str, float]]:
    """τ from ``TAU_GRID_REL × unit`` maximising the mean PSNR of ``decoder``; leaves the
    decoder at that τ and returns it with the table ``{f"{tau:.4g}": mean PSNR dB}``."""
    sweep = tune_decoder_tau(decoder, [rel * unit for rel in TAU_GRID_REL], list(measurements), scenes)
    return sweep.tau, {f"{tau:.4g}": round(value, 2) for tau, value in sweep.scores}
