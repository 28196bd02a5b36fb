"""Slit-scan recordings made through the ``thintact simulate`` CLI (test helper).

A new user's path: a profile, the scenes the calibration wizard would show (dark, white, every
row and column slit, validation scenes), ``thintact simulate --noise`` with the unit's *true*
physics (slightly different distances, a shifted mask: see
:data:`independent_device.TRUE_PHYSICS`), and a ``thintact-recording/1`` directory holding the
nominal profile, the RGB scenes the LCD showed and the simulated DN.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Literal

import numpy as np
from independent_device import TRUE_PHYSICS, validation_scenes

from thintact_sdk.apps.cli.main import main
from thintact_sdk.formats.profiles import Profile, write_profile
from thintact_sdk.formats.recording import Recording, RecordingWriter
from thintact_sdk.reconstruction.filter_training import scene_for_channels


def calibration_scenes(n: int, m: int) -> list[tuple[str, np.ndarray]]:
    """Dark, white, every row and column slit, then the validation scenes (``N × M × 3``)."""
    zero = np.zeros((n, m, 3), np.float32)
    out = [("dark", zero), ("white", np.ones_like(zero))]
    for i in range(n):
        x = zero.copy()
        x[i] = 1.0
        out.append((f"hslit_{i:04d}", x))
    for j in range(m):
        x = zero.copy()
        x[:, j] = 1.0
        out.append((f"vslit_{j:04d}", x))
    return out + validation_scenes(n, m)


def simulate_recording(
    root: Path,
    profile: Profile,
    *,
    encode: Callable[[np.ndarray], np.ndarray] | None = None,
    file_format: Literal["npy", "png", "jpg"] = "npy",
    seed: int = 0,
) -> Recording:
    """Simulate the calibration scenes with ``thintact simulate --noise`` and record them.

    Parameters
    ----------
    root
        The recording directory to create; scratch files go next to it.
    profile
        The nominal device; the frames are simulated with :data:`TRUE_PHYSICS` added.
    encode
        Optional ``F × R × S × C`` raw DN → the measurement stack to store (e.g. the camera's
        tone curve and 8-bit quantisation); by default the DN are stored as uint16.
    file_format
        How the measurements are stored (``jpg``: 8-bit JPEG, as a UVC camera delivers them).
    """
    scratch = root.parent / f"{root.name}_sim"
    scratch.mkdir(parents=True, exist_ok=True)
    truth = profile.with_physics(TRUE_PHYSICS)
    write_profile(truth, scratch / "truth.json")
    labelled = calibration_scenes(profile.scene.rows, profile.scene.cols)
    c = len(profile.sensor.channels)
    np.save(scratch / "scenes.npy", np.stack([scene_for_channels(x, c) for _, x in labelled]))
    rc = main(["simulate", "--profile", str(scratch / "truth.json"), "--scenes", str(scratch / "scenes.npy"),
               "--out", str(scratch / "dn.npy"), "--noise", "--seed", str(seed)])
    assert rc == 0
    dn = np.load(scratch / "dn.npy")
    stored = encode(dn) if encode is not None else dn.astype(np.uint16)
    w = RecordingWriter(root, profile)
    for (label, scene), meas in zip(labelled, stored, strict=True):
        w.add(meas, scene, label=label, file_format=file_format)
    return Recording(root)
