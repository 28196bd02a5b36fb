"""The core's public algorithm API for plugins: the one module a plugin imports algorithms from.

Plugins (decoders, masks, cameras) build on the core's imaging and tactile algorithms; they
import them from here, never from the modules that implement them, so the core can move code
between its private modules without breaking a plugin. Everything listed in :data:`__all__` is
stable within a major version; ``lint-imports`` (pyproject ``[tool.importlinter]``) refuses a
plugin import of ``thintact_sdk.simulation``, ``.reconstruction``, ``.tactile``,
``.calibration`` or ``.diagnosis`` directly.

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
    from thintact_sdk.calibration.gauge import canonical_gauge  # noqa: F401
    from thintact_sdk.reconstruction.bundle import CalibrationBundle, find_latest  # noqa: F401
    from thintact_sdk.reconstruction.dct import SeparableDCT, dct_matrix  # noqa: F401
    from thintact_sdk.reconstruction.direct_generation import (  # noqa: F401
        AxisGeometry,
        DirectGenerator,
        direct_system_matrices,
    )
    from thintact_sdk.reconstruction.filter_training import (  # noqa: F401
        make_training_data,
        scene_for_channels,
        train_joint_filter,
        training_scenes,
    )
    from thintact_sdk.reconstruction.first_order import largest_eigenvalue, nesterov  # noqa: F401
    from thintact_sdk.reconstruction.joint_filter import JointFilter, joint_filter_open  # noqa: F401
    from thintact_sdk.reconstruction.metrics import psnr, ssim  # noqa: F401
    from thintact_sdk.reconstruction.scene_prior import ScenePrior  # noqa: F401
    from thintact_sdk.reconstruction.t2s import SystemMatrices, kron_sum_norm2  # noqa: F401
    from thintact_sdk.reconstruction.tau_sweep import tune_decoder_tau  # noqa: F401
    from thintact_sdk.reconstruction.tikhonov import TikhonovSolver  # noqa: F401
    from thintact_sdk.reconstruction.virtual_bundle import coding_power, simulate_measurements  # noqa: F401
    from thintact_sdk.simulation.noise import (  # noqa: F401
        default_white_level_dn,
        signal_to_dn,
        signal_variance_dn,
    )
    from thintact_sdk.simulation.scenes import LIBRARY as SCENE_LIBRARY  # noqa: F401
    from thintact_sdk.simulation.scenes import gelsight_count, make_scene, usaf, white  # noqa: F401
    from thintact_sdk.simulation.simulator import Simulator  # noqa: F401
    from thintact_sdk.tactile.calibration.ball_press import ball_radius_for_field  # noqa: F401
    from thintact_sdk.tactile.calibration.store import calibration_roots  # noqa: F401
    from thintact_sdk.tactile.simulation.elastic import Elastomer  # noqa: F401
    from thintact_sdk.tactile.simulation.indenters import Sphere  # noqa: F401
    from thintact_sdk.tactile.simulation.loaded_press import simulate_loaded_press  # noqa: F401
    from thintact_sdk.tactile.simulation.membrane import TactileSimulator  # noqa: F401

_WHERE = {
    "canonical_gauge": "calibration.gauge",
    "CalibrationBundle": "reconstruction.bundle", "find_latest": "reconstruction.bundle",
    "SeparableDCT": "reconstruction.dct", "dct_matrix": "reconstruction.dct",
    "AxisGeometry": "reconstruction.direct_generation", "DirectGenerator": "reconstruction.direct_generation",
    "direct_system_matrices": "reconstruction.direct_generation",
    "make_training_data": "reconstruction.filter_training", "train_joint_filter": "reconstruction.filter_training",
    "training_scenes": "reconstruction.filter_training", "scene_for_channels": "reconstruction.filter_training",
    "largest_eigenvalue": "reconstruction.first_order", "nesterov": "reconstruction.first_order",
    "psnr": "reconstruction.metrics", "ssim": "reconstruction.metrics",
    "default_white_level_dn": "simulation.noise", "signal_to_dn": "simulation.noise",
    "signal_variance_dn": "simulation.noise",
    "JointFilter": "reconstruction.joint_filter", "joint_filter_open": "reconstruction.joint_filter",
    "coding_power": "reconstruction.virtual_bundle", "simulate_measurements": "reconstruction.virtual_bundle",
    "gelsight_count": "simulation.scenes", "make_scene": "simulation.scenes", "usaf": "simulation.scenes",
    "white": "simulation.scenes",
    "Simulator": "simulation.simulator",
    "ScenePrior": "reconstruction.scene_prior",
    "SystemMatrices": "reconstruction.t2s", "kron_sum_norm2": "reconstruction.t2s",
    "tune_decoder_tau": "reconstruction.tau_sweep",
    "TikhonovSolver": "reconstruction.tikhonov",
    "ball_radius_for_field": "tactile.calibration.ball_press",
    "Sphere": "tactile.simulation.indenters",
    "TactileSimulator": "tactile.simulation.membrane",
    "simulate_loaded_press": "tactile.simulation.loaded_press", "Elastomer": "tactile.simulation.elastic",
    "calibration_roots": "tactile.calibration.store",
}
_RENAMED = {"SCENE_LIBRARY": ("simulation.scenes", "LIBRARY")}

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
