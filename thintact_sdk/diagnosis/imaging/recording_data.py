"""Loading a recording into the arrays the diagnosis works on."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording


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
    saturated_frames
        ``{label: level_dn}`` of the lit frames that read one value at every pixel at the
        recording's clip level (or at ``saturation_dn``): saturated, not dead. They are kept:
        the ``saturation`` effect explains them.
    """

    profile: Profile
    labels: list[str]
    scenes: np.ndarray
    measured_dn: np.ndarray
    skipped: int = 0
    saturated_frames: dict[str, float] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return int(self.scenes.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.measured_dn.shape[3])


def load_diagnosis_data(root: str | os.PathLike[str]) -> DiagnosisData:
    """Read every frame with a scene from a ``thintact-recording/1`` directory.

    A lit frame whose measurement is one value at every pixel is judged by that value
    (:func:`judge_constant_frame`): at the clip level it is saturated and kept (listed in
    :attr:`DiagnosisData.saturated_frames`), near the black level it is dead and refused.

    Raises
    ------
    RecordingError
        When the directory is not a recording, a file is missing or malformed, channel
        counts disagree, no frame has a scene, or a lit frame is dead (no light) or stuck.
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
    measured = np.stack(meas)
    clip_dn = float(measured.max())
    saturated: dict[str, float] = {}
    frames_with_scene = [i for i, fr in enumerate(rec.frames) if fr.scene is not None]
    for k, i in enumerate(frames_with_scene):
        fr = rec.frames[i]
        level = judge_constant_frame(scenes[k], measured[k], clip_dn, prof,
                                     f"frame {i} ({fr.label or fr.measurement})")
        if level is not None:
            saturated[labels[k]] = level
    if not np.any(measured < prof.noise.saturation_dn):
        raise RecordingError(
            f"recording {root}: every pixel of every frame is at or above saturation_dn "
            f"{prof.noise.saturation_dn:g}; nothing can be compared with the simulation"
        )
    return DiagnosisData(prof, labels, np.stack(scenes), measured, skipped, saturated)


CLIP_TOLERANCE_DN = 0.5
"""How far below the recording's highest value a constant frame may read and still be at
its clip level (values are integers, or averages of them)."""


def judge_constant_frame(scene: np.ndarray, meas: np.ndarray, clip_dn: float, prof: Profile,
                         name: str) -> float | None:
    """Judge a lit frame whose measurement (``R × S × C`` DN) is one value at every pixel.

    Returns None for a frame that is not constant (or shows a dark scene: a noiseless
    camera's dark frame may be constant), and the value for a *saturated* frame: one at the
    recording's clip level ``clip_dn`` (its highest value; the sensor's own clip may lie
    below the declared ``saturation_dn``, the ``saturation`` effect) or at ``saturation_dn``.
    Saturated frames are data, the diagnosis explains them.

    Raises
    ------
    RecordingError
        For a *dead* frame, one constant value near the black level (no light reached the
        sensor: camera not exposing, lens cap), or a *stuck* one, a constant value between
        the black level and the clip level: neither can be diagnosed as physics.
    """
    if float(scene.max()) <= 0.0:
        return None
    lo, hi = float(meas.min()), float(meas.max())
    if hi > lo:
        return None
    noise = prof.noise
    if lo >= noise.saturation_dn or lo >= clip_dn - CLIP_TOLERANCE_DN and lo > _dark_ceiling(prof):
        return lo
    if lo <= _dark_ceiling(prof):
        raise RecordingError(
            f"{name}: the measurement reads {lo:g} DN at every pixel, at the black level "
            f"({noise.black_level_dn:g} DN), although its scene is lit; a dead frame (no light: "
            "camera not exposing, lens cap?) cannot be diagnosed"
        )
    raise RecordingError(
        f"{name}: the measurement reads {lo:g} DN at every pixel although its scene is lit, "
        f"neither the black level ({noise.black_level_dn:g} DN) nor the recording's clip level "
        f"({clip_dn:g} DN); a stuck frame (camera fault?) cannot be diagnosed"
    )


def _dark_ceiling(prof: Profile) -> float:
    """Highest value a frame without light reads: the black level plus five read-noise
    standard deviations (at least one DN)."""
    return prof.noise.black_level_dn + max(5.0 * prof.noise.read_noise_dn, 1.0)


def subset_frames(data: DiagnosisData, n: int) -> DiagnosisData:
    """At most ``n`` frames spread evenly over the recording (all when it has fewer)."""
    f = data.n_frames
    if n <= 0 or f <= n:
        return data
    idx = np.unique(np.round(np.linspace(0, f - 1, n)).astype(int))
    return DiagnosisData(
        data.profile, [data.labels[i] for i in idx], data.scenes[idx], data.measured_dn[idx], data.skipped
    )
