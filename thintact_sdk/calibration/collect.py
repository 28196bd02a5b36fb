"""Stream a recording's slit frames into compressed per-channel slit stacks.

Frames are read one at a time: the dark level is subtracted, exposure differences named in
the frame metadata (``exposure_us``) are normalised to the reference exposure, and every
slit channel is compressed (:func:`thintact_sdk.calibration.lowrank.compress`) before the
next frame is read, so memory stays at one frame plus ``(R + S)·k`` numbers per slit (the
recording keeps what it read, mapped beyond a small budget, so that the later stages take the
same frames without reading their files again: :class:`~thintact_sdk.formats.recording.Recording`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from thintact_sdk.calibration.classify import (
    ChannelRole,
    classify_scene,
    is_dark,
    is_slit,
    roles_for_channels,
)
from thintact_sdk.calibration.lowrank import DEFAULT_RANK, LowRankImage, compress
from thintact_sdk.calibration.slits import ChannelSlits, SlitStack
from thintact_sdk.calibration.sumrule import (
    GAIN_IMPROVEMENT,
    apply_gains,
    dark_from_white,
    find_white,
    fit_white_gains,
    unit_slit_frames,
)
from thintact_sdk.errors import CalibrationError, InvalidValueError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.formats.recording import Recording
from thintact_sdk.host.blas import blas_threads
from thintact_sdk.host.compute_threads import usable_cores

Progress = Callable[[int, int, str], None]
"""``progress(done, total, what)``: called after each frame is processed."""
COLLECT_WORKERS = 2
"""Threads :func:`collect_slits` compresses slit frames on (fewer where the process may use
fewer cores): each frame's compression is independent, and the frames are added in order, so
the collection is the one a single thread makes."""


@dataclass
class SlitCollection:
    """Everything the solve needs from a recording.

    Attributes
    ----------
    channels
        One :class:`ChannelSlits` per channel.
    dark_dn
        ``R × S × C`` float64 level subtracted from every measurement (DN).
    dark_source
        Where :attr:`dark_dn` came from (dark frames or the profile's black level).
    exposure_us
        Reference exposure every frame was normalised to (None when frames carry none).
    validation
        Recording frame indices with a known scene that is neither dark nor a slit.
    saturated
        ``{frame index: fraction of saturated pixels}`` for frames with any.
    frame_scale
        ``{frame index: factor}`` applied to frames whose exposure differed.
    frame_gains
        The white-frame gain fit (see :mod:`thintact_sdk.calibration.sumrule`): whether it
        was applied, the residual share it removed and the gains per orientation.
    """

    channels: list[ChannelSlits]
    dark_dn: np.ndarray
    dark_source: str
    exposure_us: float | None
    validation: list[int] = field(default_factory=list)
    saturated: dict[int, float] = field(default_factory=dict)
    frame_scale: dict[int, float] = field(default_factory=dict)
    slit_frames: int = 0
    frame_gains: dict[str, object] = field(default_factory=dict)


def frame_exposure_us(recording: Recording, i: int) -> float | None:
    """``exposure_us`` recorded with frame ``i`` (None when absent or not a number)."""
    value = recording.frames[i].extra.get("exposure_us")
    return float(value) if isinstance(value, int | float) and value > 0 else None


def signal_of(
    recording: Recording, i: int, dark_dn: np.ndarray, exposure_us: float | None
) -> tuple[np.ndarray, float]:
    """Frame ``i`` as DN above dark at the reference exposure (``R × S × C`` float64).

    Returns the signal and the factor applied for the exposure difference (1 if none).
    """
    meas = np.asarray(recording.measurement(i), dtype=np.float64)
    if meas.ndim == 2:
        meas = meas[..., None]
    scale = exposure_scale(recording, i, exposure_us)
    return (meas - dark_dn) * scale, scale


def exposure_scale(recording: Recording, i: int, exposure_us: float | None) -> float:
    """The factor that brings frame ``i`` to the reference exposure ``exposure_us`` (1 when
    either is unknown or they agree to 1e-6)."""
    exp = frame_exposure_us(recording, i)
    if exposure_us is not None and exp is not None and abs(exp - exposure_us) > 1e-6 * exposure_us:
        return exposure_us / exp
    return 1.0


def _dark(recording: Recording, dark_frames: list[int]) -> tuple[np.ndarray, str]:
    prof = recording.profile
    shape = (prof.sensor.rows, prof.sensor.cols, len(prof.sensor.channels))
    if not dark_frames:
        return np.full(shape, prof.noise.black_level_dn), "profile black level"
    acc = np.zeros(shape)
    for i in dark_frames:
        m = np.asarray(recording.measurement(i), dtype=np.float64)
        acc += m if m.ndim == 3 else m[..., None]
    names = [recording.frames[i].label or recording.frames[i].measurement for i in dark_frames]
    head = ", ".join(str(n) for n in names[:3]) + (" …" if len(names) > 3 else "")
    return acc / len(dark_frames), f"{len(dark_frames)} dark frame(s) ({head})"


def dark_level(recording: Recording, use_dark_frames: bool = True) -> tuple[np.ndarray, str]:
    """The level to subtract from ``recording``'s measurements (``R × S × C`` DN) and its source.

    The mean of the frames whose scene is all zero when there are any (and
    ``use_dark_frames``), else the profile's black level.
    """
    frames = []
    if use_dark_frames:
        for i in range(len(recording)):
            scene = recording.scene(i)
            if scene is not None and is_dark(classify_scene(scene)):
                frames.append(i)
    return _dark(recording, frames)


def white_frame_signal(recording: Recording) -> tuple[np.ndarray, int, str] | None:
    """The first all-white frame of ``recording`` minus its :func:`dark_level`: ``(signal
    R × S × C DN as float64, frame index, "frame LABEL minus SOURCE")``, or None when the
    recording has no frame whose scene is white everywhere (≥ 0.999)."""
    for i in range(len(recording)):
        scene = recording.scene(i)
        if scene is not None and scene.size and float(np.min(scene)) >= 0.999:
            dark, source = dark_level(recording)
            raw = np.asarray(recording.measurement(i), np.float64)
            raw = raw if raw.ndim == 3 else raw[..., None]
            return raw - dark[..., : raw.shape[2]], i, f"frame {recording.frames[i].label or i} minus {source}"
    return None


def collect_slits(
    recording: Recording,
    rank: int = DEFAULT_RANK,
    progress: Progress | None = None,
    frame_gains: str = "off",
) -> SlitCollection:
    """Find the slit, dark and validation frames of ``recording`` and compress the slits.

    Parameters
    ----------
    recording
        A ``thintact-recording/1`` whose frames include single-row and single-column scenes.
    rank
        Rank kept per slit image (≥ 2).
    progress
        Optional callback, see :data:`Progress`.
    frame_gains
        ``"off"``, ``"auto"`` or ``"on"``: correct per-frame gains from the white frame
        (:mod:`~thintact_sdk.calibration.sumrule`); ``auto`` applies them only when they
        explain most of the white-fit residual. Needs a white frame and complete unit slits.
        Ill-conditioned under noise (see the module), hence off by default.

    Without a dark frame, the dark level is measured from the white frame and the slit sums
    when the recording allows it, else the profile's black level is used.

    Raises
    ------
    CalibrationError
        When the recording has no slit frames.
    """
    prof = recording.profile
    n_rows, n_cols = prof.scene.rows, prof.scene.cols
    n_ch = len(prof.sensor.channels)
    roles: dict[int, list[ChannelRole]] = {}
    dark_frames: list[int] = []
    validation: list[int] = []
    for i in range(len(recording)):
        scene = recording.scene(i)
        if scene is None:
            continue
        r = roles_for_channels(classify_scene(scene), n_ch)
        if is_dark(r):
            dark_frames.append(i)
        elif is_slit(r):
            roles[i] = r
        else:
            validation.append(i)
    if not roles:
        raise CalibrationError(
            f"recording {recording.root} holds no slit frames (scenes with a single lit row or "
            "column); record a slit scan with `thintact calibrate --profile ...`"
        )
    exposures = [e for e in (frame_exposure_us(recording, i) for i in roles) if e is not None]
    reference = float(np.median(exposures)) if exposures else None
    dark_dn, dark_source = _dark(recording, dark_frames)
    h_set = unit_slit_frames(roles, "hslit", n_rows)
    v_set = unit_slit_frames(roles, "vslit", n_cols)
    complete = [s for s in (h_set, v_set) if s is not None]
    white = find_white(recording, validation) if complete else None
    same_exposure = len(set(exposures)) <= 1
    if not dark_frames and white is not None and same_exposure:
        dark_dn = dark_from_white(recording, white, complete)
        dark_source = "measured from the white frame and the slit sums (no dark frame)"
    acc = _Accumulator(prof, rank, dark_dn, dark_source, reference, validation)
    items = sorted(roles.items())
    for done, part in enumerate(_in_order(lambda ir: acc.compressed(recording, *ir), items), start=1):
        acc.add(part)
        if progress is not None:
            fr = recording.frames[part.index]
            progress(done, len(items), fr.label or fr.measurement)
    out = acc.collection(frame_gains)
    if frame_gains != "off" and white is not None:
        _white_gains(recording, out, white, h_set is not None, v_set is not None, frame_gains)
    return out


@dataclass
class _Compressed:
    """One slit frame compressed: its index, saturated fraction, exposure factor and, per
    channel slit, ``(channel, horizontal, slit index, profile, image)``."""

    index: int
    saturated: float
    scale: float
    parts: list[tuple[int, bool, int, np.ndarray, LowRankImage]]


def _in_order(work: Callable[[tuple[int, list[ChannelRole]]], _Compressed],
              items: list[tuple[int, list[ChannelRole]]]) -> Iterator[_Compressed]:
    """``work`` of every item, yielded in order, on :data:`COLLECT_WORKERS` threads (one BLAS
    thread each) with at most twice that many frames in flight; the first error in order is
    raised and the frames not started are dropped."""
    workers = min(COLLECT_WORKERS, usable_cores())
    if workers <= 1 or len(items) < 2:
        yield from (work(item) for item in items)
        return
    with blas_threads(1), ThreadPoolExecutor(max_workers=workers, thread_name_prefix="collect") as pool:
        pending: deque[Future[_Compressed]] = deque()
        try:
            for item in items:
                pending.append(pool.submit(work, item))
                if len(pending) >= 2 * workers:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for f in pending:
                f.cancel()


class _Accumulator:
    """The compressed slits of one collection, frame by frame (shared by
    :func:`collect_slits` and :class:`SlitCompressor`)."""

    def __init__(self, prof: Profile, rank: int, dark_dn: np.ndarray, dark_source: str,
                 reference: float | None, validation: list[int]) -> None:
        self.prof, self.rank, self.dark_dn, self.reference = prof, rank, dark_dn, reference
        self.n_ch = len(prof.sensor.channels)
        self.saturation = prof.noise.saturation_dn - 1.0
        self.h: list[tuple[list[int], list[np.ndarray], list[LowRankImage]]] = [
            ([], [], []) for _ in range(self.n_ch)]
        self.v: list[tuple[list[int], list[np.ndarray], list[LowRankImage]]] = [
            ([], [], []) for _ in range(self.n_ch)]
        self.out = SlitCollection([], dark_dn, dark_source, reference, validation)
        self.frames = 0

    def compress_frame(self, recording: Recording, i: int, r: list[ChannelRole]) -> None:
        """Compress slit frame ``i`` (roles ``r``) and add it."""
        self.add(self.compressed(recording, i, r))

    def compressed(self, recording: Recording, i: int, r: list[ChannelRole]) -> _Compressed:
        """Slit frame ``i`` compressed, not yet added (reads the accumulator's settings only,
        so frames may be compressed on several threads and added in order)."""
        raw = np.asarray(recording.measurement(i))
        sat = float(np.mean(raw >= self.saturation))
        recorded = recording.frames[i].extra.get("saturated_fraction")
        if isinstance(recorded, int | float):  # the wizard's worst single frame of the average
            sat = max(sat, float(recorded))
        signal, scale = signal_of(recording, i, self.dark_dn, self.reference)
        parts: list[tuple[int, bool, int, np.ndarray, LowRankImage]] = []
        for c in range(min(self.n_ch, len(r))):
            role = r[c]
            if role.kind in ("hslit", "vslit") and role.profile is not None:
                _check_alive(raw, c, i, recording, self.saturation)
            if role.kind == "hslit" and role.profile is not None:
                parts.append((c, True, role.index, role.profile, compress(signal[..., c], self.rank, seed=i)))
            elif role.kind == "vslit" and role.profile is not None:
                parts.append((c, False, role.index, role.profile, compress(signal[..., c].T, self.rank, seed=i)))
        return _Compressed(i, sat, scale, parts)

    def add(self, done: _Compressed) -> None:
        """Add a frame :meth:`compressed` gave (frames in the recording's order)."""
        out = self.out
        if done.saturated > 0:
            out.saturated[done.index] = done.saturated
        if done.scale != 1.0:
            out.frame_scale[done.index] = done.scale
        for c, horizontal, index, profile, image in done.parts:
            target = self.h[c] if horizontal else self.v[c]
            target[0].append(index)
            target[1].append(profile)
            target[2].append(image)
        self.frames += 1

    def collection(self, frame_gains: str) -> SlitCollection:
        """The collection of the frames compressed so far (a new one on every call)."""
        prof, o = self.prof, self.out
        out = SlitCollection([], o.dark_dn, o.dark_source, o.exposure_us, list(o.validation),
                             dict(o.saturated), dict(o.frame_scale))
        out.slit_frames = self.frames
        if frame_gains not in ("auto", "on", "off"):
            raise InvalidValueError(f"frame_gains must be auto, on or off, got {frame_gains!r}")
        for c in range(self.n_ch):
            h, v = self.h[c], self.v[c]
            if not h[0] or not v[0]:
                raise CalibrationError(
                    f"channel {prof.sensor.channels[c]}: the recording needs both horizontal and "
                    f"vertical slits (found {len(h[0])} row and {len(v[0])} column slits)"
                )
            out.channels.append(
                ChannelSlits(
                    SlitStack.from_images(*h), SlitStack.from_images(*v), prof.scene.rows,
                    prof.scene.cols, meta={"channel": prof.sensor.channels[c]},
                )
            )
        return out


class SlitCompressor:
    """:func:`collect_slits` while the frames are still being recorded (the wizard's capture):
    :meth:`add` compresses each slit frame as it arrives, :meth:`finish` gives the collection
    once the recording is complete, exactly what :func:`collect_slits` gives on it.

    Streaming assumes what the wizard's plan guarantees: the dark frames come before the
    first slit, and every slit frame has the first one's exposure. When the finished
    recording breaks either (or has no dark frame, or ``frame_gains`` is asked for),
    :meth:`finish` collects again from the recording instead.
    """

    def __init__(self, profile: Profile, rank: int = DEFAULT_RANK) -> None:
        self.profile, self.rank = profile, rank
        self.n_ch = len(profile.sensor.channels)
        self.seen: set[int] = set()
        self.dark_frames: list[int] = []
        self.validation: list[int] = []
        self.slits: list[int] = []
        self.acc: _Accumulator | None = None
        self.broken: str | None = None

    def add(self, recording: Recording, i: int) -> None:
        """Take frame ``i`` of ``recording`` (a view that holds it): classify it and compress
        it when it is a slit. Frames may come in any order after the dark frames; each once."""
        if i in self.seen:
            return
        self.seen.add(i)
        scene = recording.scene(i)
        if scene is None:
            return
        r = roles_for_channels(classify_scene(scene), self.n_ch)
        if is_dark(r):
            if self.acc is not None:
                self.broken = f"dark frame {i} after the first slit"
            self.dark_frames.append(i)
            return
        if not is_slit(r):
            self.validation.append(i)
            return
        exposure = frame_exposure_us(recording, i)
        if self.acc is None:
            if not self.dark_frames:
                self.broken = "no dark frame before the slits"
            dark_dn, source = _dark(recording, self.dark_frames)
            self.acc = _Accumulator(self.profile, self.rank, dark_dn, source, exposure, self.validation)
        elif exposure != self.acc.reference:
            self.broken = f"slit frame {i} at another exposure"
        self.slits.append(i)
        self.acc.compress_frame(recording, i, r)

    def finish(self, recording: Recording, frame_gains: str = "off",
               progress: Progress | None = None) -> SlitCollection:
        """The collection of the complete ``recording`` (frames not yet added are added now)."""
        for i in range(len(recording)):
            self.add(recording, i)
        if self.broken or self.acc is None or frame_gains != "off" or sorted(self.slits) != self.slits:
            return collect_slits(recording, self.rank, progress, frame_gains)
        return self.slit_collection()

    def release(self) -> None:
        """Drop the compressed slit images (a collection made of them holds its own stacked
        copies): once the capture's collection is made, nothing reads them again. Afterwards
        :meth:`finish` collects from the recording and :meth:`slit_collection` refuses."""
        self.acc = None
        self.broken = self.broken or "the compressed slits were released"

    def slit_collection(self) -> SlitCollection:
        """The collection of what was added so far (the solve can start once every slit is
        in; its ``validation`` lists the other frames seen so far)."""
        if self.acc is None:
            raise CalibrationError("no slit frame has been recorded yet")
        self.acc.out.validation = sorted(self.validation)
        return self.acc.collection("off")


def _check_alive(raw: np.ndarray, c: int, i: int, recording: Recording, saturation_dn: float) -> None:
    """Refuse a slit frame whose channel ``c`` is constant below ``saturation_dn`` (all zero,
    or one value): a dead frame (camera not exposing, display off, lens cap) carries no slit
    and would corrupt the solve. A channel saturated at every pixel is not dead: it is kept
    and flagged in :attr:`SlitCollection.saturated` (the report's ``saturated_frames``)."""
    channel = raw[..., c] if raw.ndim == 3 else raw
    lo, hi = float(channel.min()), float(channel.max())
    if hi <= lo and lo < saturation_dn:
        fr = recording.frames[i]
        raise CalibrationError(
            f"recording {recording.root}: slit frame {i} ({fr.label or fr.measurement}) is dead in "
            f"channel {recording.profile.sensor.channels[c]}: every pixel reads {lo:g} DN; re-record "
            "that slit (camera exposing? display on?)"
        )


def _white_gains(
    recording: Recording, out: SlitCollection, white: int, horizontal: bool, vertical: bool, mode: str
) -> None:
    """Fit (and maybe apply) per-frame gains of each complete orientation from the white frame."""
    w_signal, _ = signal_of(recording, white, out.dark_dn, out.exposure_us)
    result: dict[str, object] = {}
    for name, use in (("horizontal", horizontal), ("vertical", vertical)):
        if not use:
            continue
        stacks = [getattr(ch, name) for ch in out.channels]
        whites = [w_signal[..., c] if name == "horizontal" else w_signal[..., c].T for c in range(len(stacks))]
        fit = fit_white_gains(stacks, whites)
        applied = mode == "on" or fit.improvement >= GAIN_IMPROVEMENT
        if applied:
            for st in stacks:
                apply_gains(st, fit.factors)
        result[name] = {
            "applied": applied,
            "residual_removed": fit.improvement,
            "gains": (1.0 / fit.factors).tolist(),
        }
    out.frame_gains = result
