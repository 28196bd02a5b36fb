"""A file of scenes through a profile's simulator: the library behind ``thintact simulate``.

:func:`load_scenes` reads and checks an ``F×N×M×C`` (or ``N×M×C``) ``.npy`` of display
values; :func:`simulate_scenes` shows them to the profile's sensor (RGB or grey scenes as a
monochrome or R/Gr/Gb/B sensor's channels) and returns ``F×R×S×C`` float64: noiseless
irradiance in simulator units, or with noise raw DN (black level included) with Poisson +
read noise, rounded and clipped.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import SCENE_TOLERANCE

__all__ = ["SimulatedFrames", "load_scenes", "simulate_scenes"]


def load_scenes(path: str | Path) -> np.ndarray:
    """The scenes in the ``.npy`` file ``path`` as ``F×N×M×C`` float64 display values
    (an ``N×M×C`` file is one scene).

    Raises
    ------
    ThinTactError
        A missing file, a pickled or non-numeric array, a shape that is not 3-D or 4-D, no
        scene, or a value outside [0, 1] (NaN/Inf included; the first such scene named).
    """
    path = Path(path)
    if not path.is_file():
        raise ThinTactError(f"scenes file not found: {path}")
    from thintact_sdk.formats.safe_arrays import (
        read_npy,  # header first: no pickle, no huge allocation
    )

    x = read_npy(path, what="scenes", kinds="uif")
    if not isinstance(x, np.ndarray) or x.dtype.kind not in "uif":
        kind = x.dtype if isinstance(x, np.ndarray) else type(x).__name__
        raise ThinTactError(f"scenes {path}: dtype {kind} is not a number array")
    if x.ndim == 3:
        x = x[None]
    if x.ndim != 4:
        raise ThinTactError(f"scenes {path} must be F×N×M×C or N×M×C, got shape {x.shape}")
    if x.shape[0] == 0:
        raise ThinTactError(f"scenes {path} holds no scene (shape {x.shape})")
    x = np.asarray(x, dtype=float)
    bad = ~np.isfinite(x) | (x < 0) | (x > 1.0 + SCENE_TOLERANCE)
    if bad.any():
        f = int(np.argwhere(bad)[0][0])
        raise ThinTactError(f"scenes {path}: scene {f} holds values outside [0, 1] (NaN/Inf "
                            "included); scenes are display values in [0, 1]")
    return x


@dataclass(frozen=True)
class SimulatedFrames:
    """What :func:`simulate_scenes` made: ``frames`` ``F×R×S×C`` float64 (irradiance in
    simulator units, or DN with the black level when ``gain`` is not None) and ``gain``
    (DN per simulator unit, None without noise)."""

    frames: np.ndarray
    gain: float | None


def simulate_scenes(
    profile: Profile,
    scenes: str | Path | np.ndarray,
    *,
    noise: bool = False,
    seed: int = 0,
    gain: float | None = None,
    progress: Callable[[int, int], None] | None = None,
    build_progress: Callable[[int, int], None] | None = None,
) -> SimulatedFrames:
    """``scenes`` (a file for :func:`load_scenes`, or an ``F×N×M×C`` array of display
    values) through ``profile``'s simulator, as ``thintact simulate`` does.

    With ``noise``, the signal is ``gain`` DN per simulator unit (None: the simulator's
    reference gain, the brightest all-white pixel at 60 % of saturation minus black) and
    Poisson + read noise drawn from ``numpy.random.default_rng(seed)``, clipped at the
    profile's saturation. ``progress(done, total)`` after each frame;
    ``build_progress(done, total)`` during a kernel build that reports its steps
    (:meth:`~thintact_sdk.simulation.simulator.Simulator.build_kernel`).

    Raises
    ------
    ThinTactError
        Scenes that cannot be read (:func:`load_scenes`), whose ``N×M×C`` does not fit the
        profile (RGB or grey scenes are converted to its channels first), or a simulation
        that gives NaN/Inf values.
    """
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    source = scenes if not isinstance(scenes, np.ndarray) else "the scenes"
    x = load_scenes(scenes) if not isinstance(scenes, np.ndarray) else np.asarray(scenes, float)
    want = (profile.scene.rows, profile.scene.cols, len(profile.sensor.channels))
    if x.shape[1:3] == want[:2] and x.shape[3] in (1, 3) and x.shape[3] != want[2]:
        from thintact_sdk.reconstruction.filter_training import scene_for_channels

        # what the LCD shows (RGB or grey) as this sensor's channels: mono, R/Gr/Gb/B
        x = np.stack([scene_for_channels(s, want[2]) for s in x])
    if x.shape[1:] != want:
        raise ThinTactError(
            f"scenes have shape {x.shape[1:]} per frame but profile {profile.name!r} "
            f"needs N×M×C = {want}"
        )
    sim = Simulator(profile)
    sim.build_kernel(build_progress)
    out = np.empty((x.shape[0], profile.sensor.rows, profile.sensor.cols, want[2]))
    rng = np.random.default_rng(seed)
    if noise and gain is None:
        gain = sim.reference_gain()
    level = sim.physics.get("saturation", {}).get("level_dn")
    for f in range(x.shape[0]):
        if not noise:
            out[f] = sim.forward(x[f])
        else:
            sig = sim.predict_signal_dn(x[f], gain)
            out[f] = signal_to_dn(sig, profile.noise, rng, saturation_dn=level)
        if progress is not None:
            progress(f + 1, x.shape[0])
    if not np.isfinite(out).all():
        raise ThinTactError(f"the simulation of {source} gave NaN/Inf values; nothing written")
    return SimulatedFrames(out, gain if noise else None)
