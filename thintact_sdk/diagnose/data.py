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
        scenes.append(sc.astype(np.float64))
        meas.append(m.astype(np.float64))
        labels.append(fr.label or f"frame{i}")
    if not scenes:
        raise RecordingError(
            f"recording {root} has no frame with a scene: diagnosis compares measurements "
            "with simulated scenes"
        )
    return DiagnosisData(prof, labels, np.stack(scenes), np.stack(meas), skipped)
