"""Loading a recording into the arrays the diagnosis works on."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from thintact_sdk.errors import RecordingError
from thintact_sdk.profile import Profile
from thintact_sdk.recording import Recording


@dataclass
class DiagnosisData:
    """The frames of a recording that have a scene, as float arrays.

    Attributes
    ----------
    profile
        The recording's device profile (its ``physics`` is the model under test).
    labels
        One label per frame (the manifest label, or ``frame<i>``).
    scenes
        ``F × N × M × C`` float64 display values in [0, 1].
    measured_dn
        ``F × R × S × C`` float64 raw digital numbers (black level not removed).
    skipped
        Number of frames of the recording without a scene (not diagnosable).
    """

    profile: Profile
    labels: list[str]
    scenes: np.ndarray
    measured_dn: np.ndarray
    skipped: int = 0

    @property
    def n_frames(self) -> int:
        return int(self.scenes.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.measured_dn.shape[3])


def load_diagnosis_data(root: str | os.PathLike[str]) -> DiagnosisData:
    """Read every frame with a scene from a ``thintact-recording/1`` directory.

    Raises
    ------
    RecordingError
        When the directory is not a recording, a file is missing or malformed, channel
        counts disagree, or no frame has a scene.
    """
    rec = Recording(root)
    prof = rec.profile
    n_ch = len(prof.sensor.channels)
    scenes: list[np.ndarray] = []
    meas: list[np.ndarray] = []
    labels: list[str] = []
    skipped = 0
    for i, fr in enumerate(rec.frames):
        if fr.scene is None:
            skipped += 1
            continue
        sc = rec.scene(i)
        m = rec.measurement(i)
        assert sc is not None
        if sc.ndim == 2:
            sc = sc[..., None]
        if m.ndim == 2:
            m = m[..., None]
        if sc.shape[2] == 1 and n_ch > 1:
            sc = np.repeat(sc, n_ch, axis=2)
        if m.shape[2] != n_ch or sc.shape[2] != n_ch:
            raise RecordingError(
                f"frame {i} ({fr.label or fr.measurement}): {m.shape[2]} measurement / "
                f"{sc.shape[2]} scene channels, the profile has {n_ch}"
            )
        _check_alive(sc, m, i, fr.label or fr.measurement, prof)
        scenes.append(sc.astype(np.float64))
        meas.append(m.astype(np.float64))
        labels.append(fr.label or f"frame{i}")
    if not scenes:
        raise RecordingError(
            f"recording {root} has no frame with a scene: diagnosis compares measurements "
            "with simulated scenes"
        )
    measured = np.stack(meas)
    if not np.any(measured < prof.noise.saturation_dn):
        raise RecordingError(
            f"recording {root}: every pixel of every frame is at or above saturation_dn "
            f"{prof.noise.saturation_dn:g}; nothing can be compared with the simulation"
        )
    return DiagnosisData(prof, labels, np.stack(scenes), measured, skipped)


def _check_alive(scene: np.ndarray, meas: np.ndarray, i: int, name: str, prof: Profile) -> None:
    """Refuse a frame that shows a lit scene but whose measurement is one constant value (a
    dead camera, a lens cap, a frame of zeros): it would be diagnosed as a missing effect."""
    if float(scene.max()) <= 0.0:
        return  # a dark frame of a noiseless camera may be constant
    lo, hi = float(meas.min()), float(meas.max())
    if hi <= lo and lo >= prof.noise.saturation_dn:
        raise RecordingError(
            f"frame {i} ({name}): every pixel is saturated ({lo:g} DN >= saturation_dn "
            f"{prof.noise.saturation_dn:g}); lower the exposure or the display brightness"
        )
    if hi <= lo:
        raise RecordingError(
            f"frame {i} ({name}): the measurement reads {lo:g} DN at every pixel although its "
            f"scene is lit; a dead frame (camera not exposing, lens cap?) cannot be diagnosed"
        )


def subset_frames(data: DiagnosisData, n: int) -> DiagnosisData:
    """At most ``n`` frames spread evenly over the recording (all when it has fewer)."""
    f = data.n_frames
    if n <= 0 or f <= n:
        return data
    idx = np.unique(np.round(np.linspace(0, f - 1, n)).astype(int))
    return DiagnosisData(
        data.profile, [data.labels[i] for i in idx], data.scenes[idx], data.measured_dn[idx], data.skipped
    )
