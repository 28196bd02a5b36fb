"""Press packs: a no-contact reference and ball-press images of one sensor, in one file.

Format (``.npz``, no pickle; the Taxim ``dataPack`` layout, which it reads as it is):

* ``imgs`` P × H × W × 3 uint8 (RGB), ``f0`` H × W × 3 uint8, the no-contact reference;
* optional ``names`` (P strings), ``mm_per_px`` and ``ball_radius_mm`` (scalars), and
  annotated contact circles ``touch_center`` (P × 2, [x (column), y (row)] px) and
  ``touch_radius`` (P, px).

:func:`import_folder` builds one from a folder of JPEG/PNG files (a reference image and the
press images, e.g. ``ref.jpg`` + ``sample_*.jpg`` as GelSight calibration folders hold
them), with the colour order and crop declared. :func:`evaluate_pack` calibrates a gradient
model on some presses, without annotations, and gives the figures of
:mod:`thintact_sdk.tactile.calibration.ball_eval` on the others.
"""

from __future__ import annotations

import glob
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from thintact_sdk.errors import CalibrationError

if TYPE_CHECKING:
    from thintact_sdk.tactile.calibration.ball_eval import TaughtShape

_IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")


@dataclass
class PressPack:
    """A reference and press images (module docstring).

    Attributes
    ----------
    images
        ``P × H × W × 3`` uint8 RGB.
    reference
        ``H × W × 3`` uint8 RGB, no contact.
    names
        One name per press.
    mm_per_px, ball_radius_mm
        Pixel size and ball radius when the pack states them.
    centres_rc, radii_px
        Annotated contact circles ((row, col) and radius, px), or None.
    meta
        Import provenance (folder, colour order, crop).
    """

    images: np.ndarray
    reference: np.ndarray
    names: list[str]
    mm_per_px: float | None = None
    ball_radius_mm: float | None = None
    centres_rc: np.ndarray | None = None
    radii_px: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def image(self, i: int) -> np.ndarray:
        """Press ``i`` as ``H × W × 3`` float32 in [0, 1]."""
        return self.images[i].astype(np.float32) / 255.0

    def reference_image(self) -> np.ndarray:
        """The reference as ``H × W × 3`` float32 in [0, 1]."""
        return self.reference.astype(np.float32) / 255.0

    def save(self, path: str | Path) -> Path:
        """Write the pack (``.npz``, no pickle)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        arrays: dict[str, Any] = {"imgs": self.images, "f0": self.reference,
                                  "names": np.asarray(self.names, dtype=str)}
        if self.mm_per_px is not None:
            arrays["mm_per_px"] = np.float64(self.mm_per_px)
        if self.ball_radius_mm is not None:
            arrays["ball_radius_mm"] = np.float64(self.ball_radius_mm)
        if self.centres_rc is not None and self.radii_px is not None:
            arrays["touch_center"] = self.centres_rc[:, ::-1].astype(np.float64)
            arrays["touch_radius"] = self.radii_px.astype(np.float64)
        np.savez_compressed(p, allow_pickle=False, **arrays)
        return p


def _uint8(a: np.ndarray, what: str, path: Path) -> np.ndarray:
    if a.dtype == np.uint8:
        return a
    if a.dtype.kind == "f" and np.isfinite(a).all() and float(a.max(initial=0)) <= 1.0:
        return np.clip(np.round(a * 255.0), 0, 255).astype(np.uint8)
    if a.dtype.kind in "iuf" and np.isfinite(a).all() and float(a.min(initial=0)) >= 0 \
            and float(a.max(initial=0)) <= 255:
        return np.round(a).astype(np.uint8)
    raise CalibrationError(f"{path}: {what} must be uint8 or floats in [0, 1], got {a.dtype}")


def load_press_pack(path: str | Path) -> PressPack:
    """Read a press pack (module docstring) strictly: no pickle, every member's header
    checked; raises CalibrationError naming the file and the member when it is unusable."""
    from thintact_sdk.formats.safe_arrays import read_npz

    p = Path(path)
    z = read_npz(p, what="press pack", error=CalibrationError, members=("imgs", "f0"),
                 optional=("names", "mm_per_px", "ball_radius_mm", "touch_center",
                           "touch_radius"),
                 kinds={"imgs": "uif", "f0": "uif", "names": "U", "mm_per_px": "f",
                        "ball_radius_mm": "f", "touch_center": "if", "touch_radius": "if"})
    imgs, f0 = z["imgs"], z["f0"]
    if imgs.ndim != 4 or imgs.shape[3] != 3 or len(imgs) < 1:
        raise CalibrationError(f"{p}: imgs must be P × H × W × 3, got {imgs.shape}")
    if f0.shape != imgs.shape[1:]:
        raise CalibrationError(f"{p}: f0 is {f0.shape}, the presses {imgs.shape[1:]}")
    if min(f0.shape[:2]) < 8:
        raise CalibrationError(f"{p}: images of {f0.shape[0]}×{f0.shape[1]} px are too small")
    names = [str(n) for n in z["names"]] if "names" in z else [f"press_{i}" for i in range(len(imgs))]
    if len(names) != len(imgs):
        names = [f"press_{i}" for i in range(len(imgs))]

    def scalar(key: str) -> float | None:
        if key not in z:
            return None
        v = np.asarray(z[key], np.float64).ravel()
        if v.size != 1 or not np.isfinite(v[0]) or v[0] <= 0:
            raise CalibrationError(f"{p}: {key} must be one positive number")
        return float(v[0])

    centres = radii = None
    if "touch_center" in z and "touch_radius" in z:
        tc = np.asarray(z["touch_center"], np.float64)
        tr = np.asarray(z["touch_radius"], np.float64).ravel()
        if tc.shape == (len(imgs), 2) and tr.shape == (len(imgs),) and np.isfinite(tc).all() \
                and np.isfinite(tr).all():
            centres, radii = tc[:, ::-1].copy(), tr
    return PressPack(_uint8(imgs, "imgs", p), _uint8(f0, "f0", p), names, scalar("mm_per_px"),
                     scalar("ball_radius_mm"), centres, radii, {"source": str(p)})


def parse_crop(text: str) -> tuple[int, int, int, int]:
    """``"top,bottom,left,right"`` (pixels removed from each side, ≥ 0) → a tuple; raises
    CalibrationError naming the option."""
    parts = text.split(",")
    try:
        vals = tuple(int(v) for v in parts)
    except ValueError:
        vals = ()
    if len(vals) != 4 or min(vals) < 0:
        raise CalibrationError(
            f"--crop {text!r}: give four whole numbers of pixels to remove, top,bottom,left,right")
    return vals[0], vals[1], vals[2], vals[3]


def _read_image(path: Path, colour_order: str) -> np.ndarray:
    """The image as RGB (``colour_order`` says what the file holds); its decoded size was
    checked against the memory there is with the folder's other images."""
    import cv2

    from thintact_sdk.formats.safe_images import read_image

    raw = read_image(path, cv2.IMREAD_COLOR, CalibrationError, checked=True)
    # OpenCV decodes to B, G, R; a file written from a BGR buffer as if it were RGB holds the
    # channels swapped, which --colour-order bgr declares
    return raw[..., ::-1] if colour_order == "rgb" else raw


def import_folder(
    folder: str | Path,
    reference: str = "ref.*",
    presses: str = "sample_*",
    colour_order: str = "rgb",
    crop: tuple[int, int, int, int] = (0, 0, 0, 0),
    mm_per_px: float | None = None,
    ball_radius_mm: float | None = None,
) -> PressPack:
    """A press pack from a folder of images.

    Parameters
    ----------
    folder
        The folder.
    reference, presses
        Glob patterns (in the folder) of the no-contact image (exactly one match) and of the
        press images (sorted by name, numbers in names compared as numbers).
    colour_order
        ``"rgb"``: the files are ordinary colour images; ``"bgr"``: their red and blue are
        swapped (written from a camera's BGR buffer by a tool that took it for RGB).
    crop
        Pixels removed from the top, bottom, left and right of every image.
    mm_per_px, ball_radius_mm
        Stored in the pack when given.
    """
    import re

    root = Path(folder)
    if not root.is_dir():
        raise CalibrationError(f"{root}: not a folder")
    if colour_order not in ("rgb", "bgr"):
        raise CalibrationError(f"--colour-order must be rgb or bgr, not {colour_order!r}")

    def matches(pattern: str) -> list[Path]:
        found = [Path(p) for p in glob.glob(str(root / pattern))]
        found = [p for p in found if p.suffix.lower() in _IMAGE_SUFFIXES and p.is_file()]
        key = lambda p: [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", p.name)]  # noqa: E731
        return sorted(found, key=key)

    refs = matches(reference)
    if len(refs) != 1:
        raise CalibrationError(
            f"{root}: the reference pattern {reference!r} matches {len(refs)} images, it must "
            "match exactly one")
    items = [p for p in matches(presses) if p != refs[0]]
    if not items:
        raise CalibrationError(f"{root}: no press images match {presses!r}")
    top, bottom, left, right = crop
    from thintact_sdk.formats.safe_images import check_image_budget

    # the pack holds every image decoded at once: refuse a set that cannot fit (a small file
    # can declare gigabytes of pixels) before decoding any
    check_image_budget([refs[0], *items], CalibrationError)

    def load(p: Path) -> np.ndarray:
        img = _read_image(p, colour_order)
        h, w = img.shape[:2]
        if top + bottom >= h - 8 or left + right >= w - 8:
            raise CalibrationError(f"--crop {crop} leaves nothing of {p.name} ({h}×{w})")
        return np.ascontiguousarray(img[top : h - bottom, left : w - right])

    ref = load(refs[0])
    # filled in place: a list and its stacked copy would hold every image twice
    imgs = np.empty((len(items), *ref.shape), ref.dtype)
    for k, p in enumerate(items):
        img = load(p)
        if img.shape != ref.shape:
            raise CalibrationError(f"{p}: {img.shape[0]}×{img.shape[1]} px, the reference "
                                   f"{refs[0].name} is {ref.shape[0]}×{ref.shape[1]}")
        imgs[k] = img
    meta = {"folder": str(root), "reference": refs[0].name, "colour_order": colour_order,
            "crop_top_bottom_left_right": list(crop)}
    return PressPack(imgs, ref, [p.name for p in items], mm_per_px, ball_radius_mm,
                     meta=meta)


def pack_profile(shape: tuple[int, int], mm_per_px: float, elastomer_sigma_mm: float = 0.25,
                 name: str = "press-pack") -> Any:
    """A lens-sensor profile whose scene grid is the pack's images (identity decoder, no
    stored LUT), for calibrating and interpreting a pack without a device."""
    from thintact_sdk.formats.profiles import SceneSpec, TactileConfig, load_profile

    base = load_profile("gelsight-mini")
    tactile = base.tactile.model_dump() if base.tactile is not None else {}
    tactile.update({"mm_per_px": mm_per_px, "elastomer_sigma_mm": elastomer_sigma_mm,
                    "lut": None, "real2sim": None})
    return base.model_copy(update={
        "name": name,
        "scene": SceneSpec(rows=shape[0], cols=shape[1], pixel_pitch_um=mm_per_px * 1000),
        "tactile": TactileConfig.model_validate(tactile),
    }, deep=True)


def split(count: int, train: list[int] | None = None) -> tuple[list[int], list[int]]:
    """``(train, test)``: ``train`` (default: the even presses) and the rest."""
    train = list(range(0, count, 2)) if train is None else sorted(set(train))
    bad = [i for i in train if not 0 <= i < count]
    if bad:
        raise CalibrationError(f"--train presses {bad} are not in the pack (0..{count - 1})")
    rest = [i for i in range(count) if i not in set(train)]
    if not train or not rest:
        raise CalibrationError("the split needs at least one training and one test press")
    return train, rest


def _taught_shape(meta: Any) -> TaughtShape | None:
    """The calibration's ball model from ``lut.meta["ball_model"]`` (None when it has none or
    it is not one: a table calibrated elsewhere)."""
    from thintact_sdk.tactile.calibration.ball_press import BallModel

    if not isinstance(meta, dict):
        return None
    try:
        return BallModel(str(meta.get("model")), float(meta.get("skirt_length_mm") or 0.0))
    except (CalibrationError, TypeError, ValueError):
        return None


def evaluate_pack(
    pack: PressPack,
    ball_radius_mm: float,
    mm_per_px: float,
    train: list[int] | None = None,
    model: str = "auto",
    bins: int = 24,
    elastomer_sigma_mm: float = 0.25,
    mlp_steps: int = 1500,
    boundary: str = "free",
    stage: Callable[[str], None] | None = None,
    lut: Any = None,
    ball_model: str = "auto",
    cnn_options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Calibrate on the ``train`` presses from the images and the ball radius alone (what
    ``thintact calibrate-tactile`` does) and measure the other presses through the
    interpreter (:mod:`~thintact_sdk.tactile.calibration.ball_eval` figures; against the annotated
    circles too when the pack has them).

    With ``lut`` (a :class:`~thintact_sdk.tactile.interpretation.photometric.PhotometricLUT`
    calibrated elsewhere, e.g. on a fitted simulation) nothing is calibrated: the ``train``
    presses are left out and the others measured with it.

    ``ball_model``: how the training presses are shaped into the gel (``"auto"``, ``"rigid"``,
    ``"sink-in"``), ``mlp_steps``, ``cnn_options``: as
    :func:`~thintact_sdk.tactile.calibration.ball_press.calibrate_from_presses`.

    Returns
    -------
    dict
        ``summary`` (:func:`~thintact_sdk.tactile.calibration.ball_eval.summarise`), ``presses`` (per
        test press figures), ``train``, ``test``, ``gradient_model``, ``validation``,
        ``press_report`` (the calibration's per-press report), ``ball_model`` (the model the
        calibration used and how it was chosen; ``None`` with a given ``lut``),
        ``contact_rim_mm`` (how far the contact regions were grown; ``None`` when the table
        has no such figure).
    """
    from thintact_sdk.tactile.calibration.ball_eval import (
        press_figures,
        summarise,
        taught_contact_ratio,
    )
    from thintact_sdk.tactile.calibration.ball_press import BallPress, calibrate_from_presses
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter

    say = stage or (lambda _m: None)
    train, test = split(len(pack.images), train)
    profile = pack_profile(pack.reference.shape[:2], mm_per_px, elastomer_sigma_mm)
    if lut is None:
        try:
            lut = calibrate_from_presses(profile, pack.reference_image(),
                                         [BallPress(pack.image(i)) for i in train],
                                         ball_radius_mm, bins, model=model, mlp_steps=mlp_steps,
                                         stage=say, ball_model=ball_model,
                                         cnn_options=cnn_options)
        except CalibrationError as err:  # "press k" counts the training presses
            raise CalibrationError(f"{err} (training presses, in order: {train})") from None
    interp = TactileInterpreter(profile, lut, boundary=boundary)  # type: ignore[arg-type]
    interp.set_reference(pack.reference_image())
    taught = _taught_shape(lut.meta.get("ball_model"))
    taught_blur = float(np.hypot(elastomer_sigma_mm, interp.smooth_px * interp.work.mm_per_px))
    figs = []
    for k, i in enumerate(test):
        say(f"test press {k + 1}/{len(test)}")
        gx, gy, depth = interp.work_slopes(pack.image(i))
        ann = None
        if pack.centres_rc is not None and pack.radii_px is not None:
            f = interp.factor
            ann = ((float(pack.centres_rc[i][0]) / f, float(pack.centres_rc[i][1]) / f),
                   float(pack.radii_px[i]) / f)
        fig = press_figures(depth, gx, gy, ball_radius_mm, interp.work.mm_per_px,
                            interp.params.contact_threshold_mm, ann, interp.work.mm_per_px,
                            interp.contact_rim_mm)
        if taught is not None:  # the shape taught: the elastomer's and the colour's smoothing
            fig.contact_ratio_taught = taught_contact_ratio(
                taught, depth.shape, fig.centre_rc, fig.peak_mm, ball_radius_mm,
                interp.work.mm_per_px, taught_blur, interp.params.contact_threshold_mm,
                interp.work.mm_per_px, interp.contact_rim_mm)
        figs.append(fig)
    return {
        "summary": summarise(figs, ball_radius_mm),
        "presses": [{"press": i, "name": pack.names[i], **f.as_dict()}
                    for i, f in zip(test, figs, strict=True)],
        "train": train,
        "test": test,
        "gradient_model": lut.meta.get("gradient_model"),
        "validation": lut.meta.get("validation"),
        "press_report": lut.meta.get("press_report", []),
        "ball_model": lut.meta.get("ball_model"),
        "contact_rim_mm": lut.meta.get("contact_rim_mm"),
        "lut": lut,
    }
