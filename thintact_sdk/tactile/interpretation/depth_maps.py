"""Depth maps of a press pack or a recording: the library behind ``thintact tactile depth``.

:func:`interpret_frames` sets the interpreter's no-contact reference (the pack's reference
image; the recording's frame labelled ``reference``, else its first) and interprets every
press or frame; :func:`write_depth_maps` writes what the command writes: ``depth_NNNN.npy``
(float32, mm, N×M), ``depth_NNNN.png`` (uint16, µm, clipped to 0..65535) and ``frames.json``
(``thintact-depth-frames/1``: contact, contact area mm², peak depth mm, force N per frame).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import TactileFrame
from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter
from thintact_sdk.tactile.interpretation.photometric import PhotometricLUT

__all__ = ["DEPTH_FRAMES_FORMAT", "DepthMaps", "frame_entry", "interpret_frames", "write_depth_maps"]

DEPTH_FRAMES_FORMAT = "thintact-depth-frames/1"
"""The ``format`` of ``frames.json``."""


def _interpreter(profile: Profile, lut: str | Path | None) -> TactileInterpreter:
    if lut is not None:
        return TactileInterpreter(profile, PhotometricLUT.load(lut))
    return TactileInterpreter.for_profile(profile)


def interpret_frames(
    *,
    pack: str | Path | None = None,
    recording: str | Path | None = None,
    profile: Profile | None = None,
    lut: str | Path | None = None,
    mm_per_px: float | None = None,
) -> Iterator[tuple[int, str, TactileFrame, int]]:
    """``(index, name, tactile frame, count)`` for every press of ``pack`` or every frame of
    ``recording`` (exactly one of the two), after setting the interpreter's reference.

    A pack is interpreted with ``profile`` (its photometric model, or the LUT file ``lut``
    when given), or without a profile with ``lut`` on a profile made for the pack's image
    size and pixel size (``mm_per_px``, mm, else the pack's). A recording needs the
    ``profile`` that recorded it; each frame is reconstructed by that profile's sensor
    (black level removed) before it is interpreted. Names: the pack's press names; the
    recording's frame labels (``frame_K`` for an unlabelled frame).

    Raises
    ------
    ThinTactError
        Neither or both sources; a recording without ``profile``; a pack without ``profile``
        and without ``lut``, or without a pixel size; an unreadable pack, recording or LUT
        (named by file).
    """
    if (pack is None) == (recording is None):
        raise ThinTactError("depth maps need exactly one of a press pack and a recording")
    if pack is not None:
        from thintact_sdk.tactile.calibration.press_pack import load_press_pack, pack_profile

        p = load_press_pack(pack)
        if profile is None:
            if lut is None:
                raise ThinTactError("a pack without --profile needs --lut (a tactile LUT "
                                    "from calibrate-tactile or tactile evaluate --json)")
            mm = mm_per_px or p.mm_per_px
            if mm is None:
                raise ThinTactError("the pack does not state its pixel size: give --mm-per-px")
            profile = pack_profile(p.reference.shape[:2], float(mm))
        interp = _interpreter(profile, lut)
        interp.set_reference(p.reference_image())
        for k in range(len(p.images)):
            yield k, p.names[k], interp.interpret(p.image(k), frame_id=k), len(p.images)
        return
    yield from _recording_frames(Path(recording), profile, lut)  # type: ignore[arg-type]


def _recording_frames(path: Path, profile: Profile | None,
                      lut: str | Path | None) -> Iterator[tuple[int, str, TactileFrame, int]]:
    from thintact_sdk.device.sensor import Sensor
    from thintact_sdk.formats.recording import Recording
    from thintact_sdk.frames import Measurement

    if profile is None:
        raise ThinTactError("--recording needs --profile (the device that recorded it)")
    sensor = Sensor(profile)
    rec = Recording(path, profile)
    interp = _interpreter(profile, lut)
    labels = [f.label for f in rec.frames]
    ref_i = labels.index("reference") if "reference" in labels else 0
    black = float(profile.noise.black_level_dn)

    def image(i: int) -> np.ndarray:
        m = Measurement(rec.measurement(i).astype(np.float32), black)
        return np.asarray(sensor.reconstruct(m), np.float32)

    interp.set_reference(image(ref_i))
    for k in range(len(rec)):
        yield k, labels[k] or f"frame_{k}", interp.interpret(image(k), frame_id=k), len(rec)


def frame_entry(k: int, name: str, frame: TactileFrame) -> dict[str, Any]:
    """``frames.json``'s entry of frame ``k``: ``frame``, ``name``, ``contact``,
    ``contact_area_mm2`` (4 decimals), ``peak_depth_mm`` (4 decimals) and ``force_n``
    (N, 5 decimals, None where not finite; None for a frame without a force estimate)."""
    force = None if frame.force_n is None else [
        None if not math.isfinite(v) else round(float(v), 5) for v in frame.force_n]
    return {"frame": k, "name": name, "contact": bool(frame.contact),
            "contact_area_mm2": round(float(frame.contact_area_mm2), 4),
            "peak_depth_mm": round(float(frame.depth_mm.max()), 4), "force_n": force}


def _write_depth(out: Path, k: int, depth: np.ndarray) -> None:
    import cv2

    np.save(out / f"depth_{k:04d}.npy", np.asarray(depth, np.float32), allow_pickle=False)
    um = np.clip(np.round(np.asarray(depth, np.float64) * 1000.0), 0, 65535).astype(np.uint16)
    # encoded in memory and written by Python: OpenCV's own writer crashes on a path that is
    # not valid UTF-8
    (out / f"depth_{k:04d}.png").write_bytes(cv2.imencode(".png", um)[1].tobytes())


@dataclass(frozen=True)
class DepthMaps:
    """What :func:`write_depth_maps` wrote: ``frames`` (the ``frames.json`` entries, one per
    press or frame, :func:`frame_entry`) and ``frames_json`` (its path)."""

    frames: list[dict[str, Any]]
    frames_json: Path

    @property
    def in_contact(self) -> int:
        """Frames in contact."""
        return sum(bool(f["contact"]) for f in self.frames)


def write_depth_maps(
    out: str | Path,
    *,
    pack: str | Path | None = None,
    recording: str | Path | None = None,
    profile: Profile | None = None,
    lut: str | Path | None = None,
    mm_per_px: float | None = None,
    progress: Callable[[str], None] | None = None,
) -> DepthMaps:
    """Interpret ``pack`` or ``recording`` (:func:`interpret_frames`, same arguments) and
    write into the directory ``out`` (created) ``depth_NNNN.npy``, ``depth_NNNN.png`` per
    frame and ``frames.json`` last, as ``thintact tactile depth`` does. ``progress`` receives
    ``press K/N`` or ``frame K/N`` after each frame. Existing files of the same names are
    replaced (the caller claims ``out``).

    Raises
    ------
    ThinTactError
        As :func:`interpret_frames`.
    """
    root = Path(out)
    what = "press" if pack is not None else "frame"
    frames: list[dict[str, Any]] = []
    for k, name, frame, n in interpret_frames(pack=pack, recording=recording, profile=profile,
                                              lut=lut, mm_per_px=mm_per_px):
        root.mkdir(parents=True, exist_ok=True)
        _write_depth(root, k, frame.depth_mm)
        frames.append(frame_entry(k, name, frame))
        if progress is not None:
            progress(f"{what} {k + 1}/{n}")
    root.mkdir(parents=True, exist_ok=True)
    path = root / "frames.json"
    path.write_text(json.dumps({"format": DEPTH_FRAMES_FORMAT, "frames": frames}, indent=1) + "\n")
    return DepthMaps(frames, path)
