"""The core's public algorithm API for plugins: the one module a plugin imports algorithms from.

Plugins (decoders, masks, cameras) build on the core's imaging and tactile algorithms; they
import them from here, never from the modules that implement them, so the core can move code
between its private modules without breaking a plugin. Everything listed in :data:`__all__` is
stable within a major version; ``lint-imports`` (pyproject ``[tool.importlinter]``) refuses a
plugin import of ``thintact_sdk.imaging``, ``.tactile``, ``.calibration``, ``.physics`` or
``.diagnose`` directly.

The names are loaded on first use (importing this module costs nothing), and typed for mypy.

===========================  ===============================================================
name                         what it is
===========================  ===============================================================
``SystemMatrices``           the T2S model ``Y = Po X Qoᵀ + Pc X Qcᵀ`` (C × R × N, C × S × M)
``kron_sum_norm2``           squared Frobenius norm of a sum of Kronecker products
``canonical_gauge``          the same T2S operator with a smooth (low-rank) open term
``CalibrationBundle``        a device's calibration (matrices, filter, τ); ``find_latest``
``TikhonovSolver``           closed-form separable Tikhonov solve (SVDs once, any τ)
``ScenePrior``               DCT-domain weights of generalised Tikhonov (change of variable)
``JointFilter``              the paper's Φs/Φf joint filter; ``joint_filter_open`` applies it
``SeparableDCT``             orthonormal 2-D DCT (scipy, or by matrices on any backend); ``dct_matrix``
``largest_eigenvalue``       power method; ``nesterov``: accelerated gradient, fixed step
``tune_decoder_tau``         τ sweep of a ``TunableDecoder`` on measurement/scene pairs
``Simulator``                the contract simulator (CONTRACTS §4-5)
``signal_to_dn``             simulated signal → noisy DN (the contract's noise model)
``signal_variance_dn``       variance of the simulated noise; ``default_white_level_dn``
``psnr``, ``ssim``           image quality metrics (dB; SSIM with an 11-tap Gaussian window)
``make_scene``               the scene library (``SCENE_LIBRARY``; ``usaf``, ``white``,
                             ``gelsight_count``)
``direct_system_matrices``   the paper's direct generation of Pc, Qc, Po, Qo from φ;
                             ``AxisGeometry``, ``DirectGenerator`` per axis
``coding_power``             mean squared singular value of the coding operator (DN²)
``simulate_measurements``    noisy virtual measurements of scenes
``make_training_data``,      data and closed-form/Adam training of the joint filter
``train_joint_filter``,
``training_scenes``
``scene_for_channels``       an RGB (or grey) scene as the device's channels (mono, R/Gr/Gb/B)
``TactileSimulator``         tactile scenes of an indenter pressing the gel; ``Sphere``
``ball_radius_for_field``    a calibration ball sized to a field of view
``simulate_loaded_press``    a press with its elastic force and partial slip; ``Elastomer``
``calibration_roots``        where calibrations are looked up (user, ./calibrations, packaged)
===========================  ===============================================================
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the names, for type checkers; at run time they load on first use
    pass

_WHERE = {
    "canonical_gauge": "calibration.gauge",
    "CalibrationBundle": "imaging.calibration_bundle", "find_latest": "imaging.calibration_bundle",
    "SeparableDCT": "imaging.dct", "dct_matrix": "imaging.dct",
    "AxisGeometry": "imaging.direct_generation", "DirectGenerator": "imaging.direct_generation",
    "direct_system_matrices": "imaging.direct_generation",
    "make_training_data": "imaging.filter_training", "train_joint_filter": "imaging.filter_training",
    "training_scenes": "imaging.filter_training", "scene_for_channels": "imaging.filter_training",
    "largest_eigenvalue": "imaging.first_order", "nesterov": "imaging.first_order",
    "psnr": "imaging.metrics", "ssim": "imaging.metrics",
    "default_white_level_dn": "imaging.noise", "signal_to_dn": "imaging.noise",
    "signal_variance_dn": "imaging.noise",
    "JointFilter": "imaging.recon_filter", "joint_filter_open": "imaging.recon_filter",
    "coding_power": "imaging.recon_virtual", "simulate_measurements": "imaging.recon_virtual",
    "gelsight_count": "imaging.scenes", "make_scene": "imaging.scenes", "usaf": "imaging.scenes",
    "white": "imaging.scenes",
    "Simulator": "imaging.simulator",
    "ScenePrior": "imaging.scene_prior",
    "SystemMatrices": "imaging.t2s", "kron_sum_norm2": "imaging.t2s",
    "tune_decoder_tau": "imaging.tau_sweep",
    "TikhonovSolver": "imaging.tikhonov",
    "ball_radius_for_field": "tactile.calibration",
    "Sphere": "tactile.indenters",
    "TactileSimulator": "tactile.simulate",
    "simulate_loaded_press": "tactile.loaded_press", "Elastomer": "tactile.elastic",
    "calibration_roots": "tactile.store",
}
_RENAMED = {"SCENE_LIBRARY": ("imaging.scenes", "LIBRARY")}

__all__ = sorted([*_WHERE, *_RENAMED])


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        module, attr = _WHERE[name], name
    elif name in _RENAMED:
        module, attr = _RENAMED[name]
    else:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    value = getattr(importlib.import_module(f"thintact_sdk.{module}"), attr)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return __all__
