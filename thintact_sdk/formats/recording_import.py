"""A folder of camera files → a ``thintact-recording/1`` (``thintact record import``).

Each file is one frame of a role:

========== ==================================================== ======================
role       file stem (case-insensitive; ``_2``, ``-a`` … suffixes) frame written
========== ==================================================== ======================
white      ``flat``, ``white``, ``flatfield``                   scene all ones
dark       ``dark``, ``black``                                  scene all zeros
reference  ``reference``, ``ref``, ``no-press``, ``nopress``,   no scene
           ``no_press``, ``baseline``
press      ``press`` followed by anything (``press_1``)         no scene
scene      only by mapping: ``scene=PATH`` (a displayed scene,  that scene (validation)
           ``N × M`` (× C) .npy/PNG/TIFF in [0, 1] or 8/16-bit)
========== ==================================================== ======================

A mapping (``{file name: role}``, from a small YAML file or ``FILE=ROLE`` arguments) names
roles the stems do not, and overrides them; files with neither are refused by name. Files
are PNG/TIFF (8 or 16 bit), JPEG, ``.npy``, or a video (MJPEG/MP4/AVI/MKV/MOV, read with
OpenCV; every frame, or the first ``max_video_frames``, averaged into one frame; the
manifest's ``frames`` field says how many).

Each frame goes through, in this order: the declared **colour order** (``RGB``: as the file
format decodes; ``BGR``: the camera wrote blue first, channels 1 and 3 swapped), the
**crop** ``(x, y, w, h)`` in file pixels, the **tone curve** undone (the profile's
``sensor.tone_curve`` by default; ``gamma=G``: normalised linear = delivered^G between the
profile's black level and saturation, so ``gamma=2.2`` undoes a display encoding; ``srgb``;
``none``: the files are linear already), **mono conversion** for a one-channel profile
(Rec. 601 luma ``0.299 R + 0.587 G + 0.114 B`` of the linear values: an RGB JPEG flat or dark
frame of a mono camera is accepted this way and the conversion is reported), and **binning**
to the profile's sensor ``R × S`` (block means; the cropped size must be a whole multiple of
it on each axis). Measurements are written as float32 linear DN, black level included
(``tone_mapped: false``), ``R × S × C``; each manifest entry names its ``source`` file.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.errors import RecordingError
from thintact_sdk.formats.profiles import Profile

ROLE_STEMS = {
    "white": ("flat", "white", "flatfield", "flat_field", "flat-field"),
    "dark": ("dark", "black"),
    "reference": ("reference", "ref", "no-press", "nopress", "no_press", "baseline"),
}
ROLES = ("white", "dark", "reference", "press")
IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".jpg", ".jpeg", ".npy")
VIDEO_SUFFIXES = (".avi", ".mjpeg", ".mjpg", ".mkv", ".mov", ".mp4")
LUMA_WEIGHTS = (0.299, 0.587, 0.114)
"""Rec. 601 luma weights of R, G, B (what OpenCV's BGR2GRAY uses for video of a mono sensor)."""

Progress = Callable[[str], None]


@dataclass
class ImportOptions:
    """How the files were made (module docstring).

    Attributes
    ----------
    colour_order
        ``"RGB"`` or ``"BGR"``: the order the camera wrote the colour channels in.
    linearize
        ``"profile"``, ``"none"``, ``"srgb"`` or ``"gamma=G"`` (G > 0).
    crop
        ``(x, y, w, h)`` in file pixels, or None for the whole frame.
    max_video_frames
        Frames of a video averaged, at most (None: all).
    mapping
        File name → role (``white``, ``dark``, ``reference``, ``press``, ``scene=PATH``).
    """

    colour_order: str = "RGB"
    linearize: str = "profile"
    crop: tuple[int, int, int, int] | None = None
    max_video_frames: int | None = None
    mapping: dict[str, str] = field(default_factory=dict)


@dataclass
class ImportedFrame:
    """One frame written: its label, role, source file, frames averaged and notes."""

    label: str
    role: str
    source: str
    frames: int
    notes: list[str]


def role_of_stem(stem: str) -> str | None:
    """The role a file stem names (module docstring), or None."""
    s = stem.lower()
    if s.startswith("press"):
        return "press"
    base = re.sub(r"([-_ .][0-9a-z]{1,4}|[0-9]+)$", "", s)
    return next((role for role, names in ROLE_STEMS.items() if s in names or base in names), None)


def read_mapping(path: str | os.PathLike[str]) -> dict[str, str]:
    """``{file name: role}`` from a YAML file (a mapping of strings)."""
    from thintact_sdk.formats import safe_yaml as yaml_safe

    p = Path(path)
    try:
        data = yaml_safe.load(p.read_text(encoding="utf-8"))
    except OSError as err:
        raise RecordingError(f"cannot read the role mapping {p}: {err}") from None
    except Exception as err:  # noqa: BLE001 - yaml errors of any kind, named with the file
        raise RecordingError(f"{p}: not a YAML mapping of file name: role ({err})") from None
    if not isinstance(data, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in data.items()):
        raise RecordingError(f"{p}: expected a YAML mapping of file name: role (strings)")
    return dict(data)


def _check_role(role: str, where: str) -> str:
    if role in ROLES or role.startswith("scene="):
        return role
    raise RecordingError(f"{where}: unknown role {role!r}; roles: {', '.join(ROLES)}, scene=PATH")


def _linearizer(profile: Profile, how: str) -> Callable[[np.ndarray, str], np.ndarray]:
    from thintact_sdk.pixels.tone_curve import ToneCurveSpec, linearize

    spec: ToneCurveSpec | None
    if how == "profile":
        spec = profile.sensor.tone_curve
    elif how == "none":
        spec = None
    elif how == "srgb":
        spec = ToneCurveSpec(kind="srgb")
    else:
        m = re.fullmatch(r"gamma=([0-9.eE+-]+)", how)
        try:
            g = float(m.group(1)) if m else float("nan")
        except ValueError:
            g = float("nan")
        if not (g > 0 and np.isfinite(g)):
            raise RecordingError(f"--linearize {how!r}: expected profile, none, srgb or gamma=G with G > 0")
        try:
            spec = ToneCurveSpec(kind="gamma", gamma=1.0 / g)
        except ValueError as err:
            raise RecordingError(f"--linearize {how!r}: {err}") from None
    if spec is None:
        return lambda a, what: np.asarray(a, np.float64)
    prof = profile.model_copy(update={"sensor": profile.sensor.model_copy(update={"tone_curve": spec})})

    def run(a: np.ndarray, what: str) -> np.ndarray:
        try:
            return np.asarray(linearize(a, prof, what), np.float64)
        except ValueError as err:
            raise RecordingError(str(err)) from None

    return run


def _read_stills(path: Path) -> list[np.ndarray]:
    import cv2

    if path.suffix.lower() == ".npy":
        from thintact_sdk.formats.safe_arrays import read_npy

        return [read_npy(path, what="frame", error=RecordingError, kinds="uif")]
    from thintact_sdk.formats.safe_images import read_image

    img = read_image(path, cv2.IMREAD_UNCHANGED, RecordingError)
    if img.ndim == 3:  # OpenCV decodes to BGR(A): back to the file's own order
        img = img[..., :3][..., ::-1]
    return [img]


def _video_frames(path: Path, limit: int | None) -> Any:
    import cv2

    from thintact_sdk.formats.safe_images import opencv_path

    cap = cv2.VideoCapture(opencv_path(path, RecordingError))
    try:
        if not cap.isOpened():
            raise RecordingError(f"{path}: cannot open the video")
        from thintact_sdk.formats.safe_images import check_video_frames

        check_video_frames(cap, path, RecordingError)
        n = 0
        while limit is None or n < limit:
            ok, img = cap.read()
            if not ok or img is None:
                break
            n += 1
            yield np.ascontiguousarray(img[..., ::-1])
        if n == 0:
            raise RecordingError(f"{path}: the video holds no decodable frame")
    finally:
        cap.release()


def _to_frame(raw: np.ndarray, path: Path, profile: Profile, opts: ImportOptions,
              lin: Callable[[np.ndarray, str], np.ndarray], notes: set[str]) -> np.ndarray:
    """One delivered image → ``R × S × C`` float64 linear DN (module docstring)."""
    a = raw if raw.ndim == 3 else raw[..., None]
    if a.ndim != 3:
        raise RecordingError(f"{path}: expected an H×W or H×W×C image, got shape {raw.shape}")
    if a.shape[2] == 3 and opts.colour_order == "BGR":
        a = a[..., ::-1]
    if opts.crop is not None:
        x, y, w, h = opts.crop
        if x + w > a.shape[1] or y + h > a.shape[0]:
            raise RecordingError(f"{path}: --crop {x},{y},{w},{h} reaches beyond the "
                                 f"{a.shape[1]}×{a.shape[0]} (W×H) image")
        a = a[y:y + h, x:x + w]
    a = lin(a, str(path))
    channels = profile.sensor.channels
    if len(channels) == 1 and a.shape[2] == 3:
        a = np.tensordot(a, np.asarray(LUMA_WEIGHTS), axes=([2], [0]))[..., None]
        notes.add("RGB converted to mono (Rec. 601 luma of the linear values)")
    if a.shape[2] != len(channels):
        raise RecordingError(f"{path}: {a.shape[2]} channel(s); profile {profile.name!r} expects "
                             f"{len(channels)} ({', '.join(channels)})")
    rows, cols = profile.sensor.rows, profile.sensor.cols
    h, w = a.shape[:2]
    if h % rows or w % cols:
        raise RecordingError(
            f"{path}: {h}×{w} px (rows × cols{' after --crop' if opts.crop else ''}) is not a whole "
            f"multiple of profile {profile.name!r}'s sensor {rows}×{cols}; crop it (--crop X,Y,W,H) "
            "to a multiple")
    by, bx = h // rows, w // cols
    if by > 1 or bx > 1:
        a = a.reshape(rows, by, cols, bx, a.shape[2]).mean(axis=(1, 3))
        notes.add(f"binned {by}×{bx}")
    return a


def import_folder(folder: str | os.PathLike[str], profile: Profile, out: str | os.PathLike[str],
                  options: ImportOptions | None = None, progress: Progress | None = None,
                  ) -> list[ImportedFrame]:
    """Write the recording ``out`` from the camera files in ``folder`` (module docstring).

    Every file is read and converted before anything is written, so a bad file (unknown
    role, wrong size or channels, unreadable) leaves no recording behind.

    Raises
    ------
    RecordingError
        Naming the file: unknown role, unreadable file, a size that does not bin to the
        profile's sensor, channel count, a scene of the wrong shape; or a folder without
        any frame.
    """
    from thintact_sdk.formats.recording import RecordingWriter

    opts = options or ImportOptions()
    if opts.colour_order not in ("RGB", "BGR"):
        raise RecordingError(f"colour order {opts.colour_order!r}: RGB or BGR")
    src = Path(folder)
    if not src.is_dir():
        raise RecordingError(f"{src}: not a folder of camera files")
    files = sorted(p for p in src.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES + VIDEO_SUFFIXES)
    for name in opts.mapping:
        if not (src / name).is_file():
            raise RecordingError(f"the role mapping names {name!r}, which is not a file in {src}")
    lin = _linearizer(profile, opts.linearize)
    say = progress or (lambda _msg: None)
    frames: list[tuple[ImportedFrame, np.ndarray, np.ndarray | None]] = []
    scene_shape = (profile.scene.rows, profile.scene.cols, len(profile.sensor.channels))
    for n, path in enumerate(files):
        given = opts.mapping.get(path.name)
        role = _check_role(given, f"mapping of {path.name}") if given else role_of_stem(path.stem)
        if role is None:
            raise RecordingError(f"{path.name}: no role (name it flat/white, dark, reference/no-press or "
                                 "press_*, or map it: FILE=ROLE)")
        say(f"[{n + 1}/{len(files)}] {path.name}: {role}")
        notes: set[str] = set()
        if path.suffix.lower() in VIDEO_SUFFIXES:
            acc, count = None, 0
            for img in _video_frames(path, opts.max_video_frames):
                one = _to_frame(img, path, profile, opts, lin, notes)
                acc = one if acc is None else acc + one
                count += 1
            assert acc is not None
            meas = acc / count
            notes.add(f"{count} video frames averaged")
        else:
            meas = np.mean([_to_frame(img, path, profile, opts, lin, notes) for img in _read_stills(path)], axis=0)
            count = 1
        if not np.all(np.isfinite(meas)):  # checked here, before anything is written
            raise RecordingError(f"{path.name}: holds NaN or infinite values once linearized "
                                 f"({opts.linearize})")
        scene: np.ndarray | None = None
        if role == "white":
            scene = np.ones(scene_shape, np.float32)
        elif role == "dark":
            scene = np.zeros(scene_shape, np.float32)
        elif role.startswith("scene="):
            scene = _read_scene(src, role[len("scene="):], scene_shape, path.name)
            role = "scene"
        label = {"white": "white", "dark": "dark", "reference": "reference"}.get(role, path.stem)
        frames.append((ImportedFrame(label, role, path.name, count, sorted(notes)),
                       np.clip(meas, 0.0, None).astype(np.float32), scene))
    if not frames:
        raise RecordingError(f"{src}: no camera files ({', '.join(IMAGE_SUFFIXES + VIDEO_SUFFIXES)})")
    labels = [f.label for f, _, _ in frames]
    seen: dict[str, int] = {}
    for f, _, _ in frames:  # two dark frames: dark_1, dark_2
        if labels.count(f.label) > 1:
            seen[f.label] = seen.get(f.label, 0) + 1
            f.label = f"{f.label}_{seen[f.label]}"
    writer = RecordingWriter(out, profile)
    for f, meas, scene in frames:
        extra: dict[str, Any] = {"source": f.source, "tone_mapped": False}
        if f.frames > 1:
            extra["frames"] = f.frames
        writer.add(meas, scene, f.label, **extra)
    return [f for f, _, _ in frames]


def _read_scene(folder: Path, rel: str, shape: tuple[int, int, int], of: str) -> np.ndarray:
    from thintact_sdk.formats.recording import read_array

    p = (folder / rel) if not Path(rel).is_absolute() else Path(rel)
    arr = read_array(p, is_scene=True)
    arr = arr if arr.ndim == 3 else arr[..., None]
    if arr.shape[:2] != shape[:2] or arr.shape[2] not in (1, 3, shape[2]):
        raise RecordingError(f"{of}: scene {p}: shape {arr.shape}, the profile's scene is "
                             f"{shape[0]}×{shape[1]} with 1, 3 or {shape[2]} channel(s)")
    if not (np.all(np.isfinite(arr)) and arr.min() >= 0.0 and arr.max() <= 1.0 + 1e-6):
        raise RecordingError(f"{of}: scene {p}: values must be display values in [0, 1]")
    return np.asarray(arr, np.float32)


def parse_mapping_args(items: list[str], base: Mapping[str, str] | None = None) -> dict[str, str]:
    """``FILE=ROLE`` arguments (``scene=PATH`` roles keep their own ``=``) over ``base``."""
    out = dict(base or {})
    for item in items:
        name, sep, role = item.partition("=")
        if not sep or not name or not role:
            raise RecordingError(f"--role {item!r}: expected FILE=ROLE")
        out[name] = _check_role(role, f"--role {item}")
    return out
