"""A tiny device, its recordings and its calibration bundle, for the robustness tests.

Everything here is small enough (24×30 sensor, 10×12 scene) that a reconstruction takes
milliseconds and a diagnosis a second or two, so the fuzz tests can run many inputs.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.formats.profiles import Profile, profile_from_dict

K = 40

FUZZ_OUTCOMES: dict[str, Counter[str]] = {}
"""``{fuzz target: Counter(outcome)}``, filled by the fuzz tests, printed at the end of the run."""


class Kit(dict):  # type: ignore[type-arg]
    """The tiny device's fixtures (a dict with a short repr, for readable failure reports)."""

    def __repr__(self) -> str:
        return f"<tiny device kit: {', '.join(self)}>"


def tiny_profile_dict() -> dict[str, Any]:
    """A valid ``thintact-profile/1`` dict of a 24×30-pixel device."""
    rng = np.random.default_rng(7)
    return {
        "format": "thintact-profile/1",
        "name": "robust-tiny",
        "sensor": {"rows": 24, "cols": 30, "pixel_pitch_um": 20.0, "channels": ["R", "G", "B"]},
        "scene": {"rows": 10, "cols": 12, "pixel_pitch_um": 60.0},
        "mask": {"feature_um": 20.0, "phi": [int(v) for v in rng.choice([-1, 1], K)]},
        "geometry": {"scene_to_mask_mm": 2.0, "mask_to_sensor_mm": 0.5},
        "noise": {"black_level_dn": 64.0, "read_noise_dn": 2.0, "electrons_per_dn": 4.0,
                  "saturation_dn": 4095.0},
    }


def tiny_profile() -> Profile:
    return profile_from_dict(tiny_profile_dict())


def scenes(count: int, seed: int = 0) -> np.ndarray:
    """``count × 10 × 12 × 3`` scenes: white first, then random blocks, in [0, 1]."""
    rng = np.random.default_rng(seed)
    out = rng.uniform(0.0, 1.0, (count, 10, 12, 3)).astype(np.float32)
    out[0] = 1.0
    return out


def measurements(profile: Profile, scene_stack: np.ndarray, seed: int = 0) -> np.ndarray:
    """Noisy raw DN (black level included) of ``scene_stack``, ``F × 24 × 30 × 3`` uint16."""
    from thintact_sdk.simulation.noise import signal_to_dn
    from thintact_sdk.simulation.simulator import Simulator

    sim = Simulator(profile)
    gain = sim.reference_gain()
    rng = np.random.default_rng(seed)
    return np.stack([
        signal_to_dn(sim.predict_signal_dn(s.astype(float), gain), profile.noise, rng)
        for s in scene_stack
    ]).astype(np.uint16)


def write_recording(root: Path, profile: Profile, scene_stack: np.ndarray,
                    meas: np.ndarray) -> Path:
    """A ``thintact-recording/1`` directory written by hand (not by the SDK's writer)."""
    (root / "scenes").mkdir(parents=True)
    (root / "measurements").mkdir()
    (root / "profile.json").write_text(json.dumps(profile.contract_dict()))
    frames = []
    for i, (s, m) in enumerate(zip(scene_stack, meas, strict=True)):
        np.save(root / "scenes" / f"{i:03d}.npy", s)
        np.save(root / "measurements" / f"{i:03d}.npy", m)
        frames.append({"scene": f"scenes/{i:03d}.npy", "measurement": f"measurements/{i:03d}.npy",
                       "label": f"f{i}", "frame_id": i, "exposure_us": 1000.0})
    (root / "manifest.json").write_text(json.dumps(
        {"format": "thintact-recording/1", "profile": "profile.json", "frames": frames}))
    return root


def write_bundle(root: Path, profile: Profile) -> Path:
    """A calibration bundle of the tiny device: the simulator's two-term fit, a joint filter
    that passes the measurement through as the open part estimate's complement, τ from the
    matrices' scale."""
    from thintact_sdk.reconstruction.bundle import CalibrationBundle
    from thintact_sdk.reconstruction.joint_filter import JointFilter
    from thintact_sdk.reconstruction.t2s import SystemMatrices
    from thintact_sdk.simulation.simulator import Simulator

    sim = Simulator(profile)
    sm = SystemMatrices.two_term_fit(sim, scale_dn=sim.reference_gain())
    shape = (3, 24, 30)
    jf = JointFilter(np.zeros(shape, np.float32), np.zeros(shape, np.float32))
    tau = 1e-3 * float(np.linalg.norm(sm.Pc[0], 2) * np.linalg.norm(sm.Qc[0], 2)) ** 2
    bundle = CalibrationBundle.create(profile, sm, jf, tau=tau, source="simulator")
    return bundle.save(root)
