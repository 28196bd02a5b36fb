"""Photometric stereo with a look-up table: colour change → surface slope (paper §III-E).

The feature of a pixel is its colour minus the no-contact background at that pixel
(``I − I₀``, three numbers, display units). The table is a regular 3-D grid over the
feature range seen during calibration; each node holds the mean slopes (∂d/∂x, ∂d/∂y)
of the calibration pixels splatted onto it with trilinear weights, nodes without samples
take the value of the nearest node with samples, and look-ups interpolate trilinearly.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.ndimage import distance_transform_edt

from thintact_sdk.errors import CalibrationError
from thintact_sdk.formats import safe_json
from thintact_sdk.formats.safe_arrays import read_npz
from thintact_sdk.tactile.interpretation.gradient_model import ConvGradient, MLPGradient

LUT_FORMAT = "thintact-tactile-lut/1"
MAX_META_MM = 100.0
"""Largest length (mm) a table's metadata may give (``work_mm_per_px``, ``contact_rim_mm``):
far beyond any tactile sensor's field."""
NETWORKS: dict[str, type[MLPGradient] | type[ConvGradient]] = {
    net.kind: net for net in (MLPGradient, ConvGradient)}
"""``gradient_model`` names of the networks a LUT file can name, and their classes."""


@dataclass
class PhotometricLUT:
    """Colour-change → slope table.

    Attributes
    ----------
    lo, hi
        ``(3,)`` float64 feature range covered by the grid (display units).
    table
        ``B × B × B × 2`` float32 slopes (∂d/∂x, ∂d/∂y) at the grid nodes (mm per mm).
    counts
        ``B × B × B`` float32 calibration weight that fell on each node.
    meta
        Provenance (profile, source, ball radius, number of presses, metrics, ...).
    net
        A colour + position network chosen over the table by validation presses at
        calibration time: per pixel
        (:class:`~thintact_sdk.tactile.interpretation.gradient_model.MLPGradient`,
        ``meta["gradient_model"] == "mlp"``) or convolutional
        (:class:`~thintact_sdk.tactile.interpretation.gradient_model.ConvGradient`, ``"cnn"``),
        or None: the table. The table is always kept and used when no image is given.
    """

    lo: np.ndarray
    hi: np.ndarray
    table: np.ndarray
    counts: np.ndarray
    meta: dict[str, Any] = field(default_factory=dict)
    net: MLPGradient | ConvGradient | None = None

    @property
    def bins(self) -> int:
        """Nodes per colour axis B."""
        return int(self.table.shape[0])

    def _coords(self, features: np.ndarray) -> np.ndarray:
        f = np.asarray(features, np.float32).reshape(-1, 3)
        scale = (self.bins - 1) / np.maximum(self.hi - self.lo, 1e-9)
        t = (f - self.lo.astype(np.float32)) * scale.astype(np.float32)
        return np.clip(t, 0.0, self.bins - 1 - 1e-4)

    def lookup(
        self, features: np.ndarray, image: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Slopes for colour changes.

        Parameters
        ----------
        features
            ``... × 3`` colour minus background (display units).
        image
            ``N × M × 3`` image the change comes from (display units): with a network
            (:attr:`net`) the slopes come from the network, which needs the colour and the
            position; without an image, or without a network, from the table.

        Returns
        -------
        (grad_x, grad_y)
            Arrays shaped like ``features[..., 0]``, float32 mm per mm.
        """
        from scipy.ndimage import map_coordinates

        if self.net is not None and image is not None:
            return self.net.predict(np.asarray(features, np.float32), image)
        shape = np.shape(features)[:-1]
        coords = self._coords(features).T  # 3 × P node coordinates, inside the table
        # trilinear interpolation of each slope table (order 1, no prefilter): the same
        # weights as an explicit 8-corner sum, in compiled code
        out = [map_coordinates(self.table[..., k], coords, order=1, mode="nearest",
                               prefilter=False, output=np.float32).reshape(shape)
               for k in (0, 1)]
        return out[0], out[1]

    def save(self, path: str | Path) -> Path:
        """Write ``path`` (``.npz``) and its metadata beside it (``.json``); a network goes
        to :func:`net_path` (``<stem>.mlp.npz`` or ``<stem>.cnn.npz``, named in
        ``meta["mlp_file"]`` / ``meta["cnn_file"]``, its provenance in ``meta["mlp"]`` /
        ``meta["cnn"]``) and ``meta["gradient_model"]`` says which model the device uses
        (``"lut"``, ``"mlp"`` or ``"cnn"``)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        np.savez_compressed(p, lo=self.lo, hi=self.hi, table=self.table, counts=self.counts)
        meta = {"format": LUT_FORMAT, "bins": self.bins, **self.meta}
        meta["gradient_model"] = "lut" if self.net is None else self.net.kind
        for kind in NETWORKS:  # an earlier network's entries do not describe this one
            meta.pop(f"{kind}_file", None)
            meta.pop(kind, None)
        if self.net is not None:
            kind = self.net.kind
            self.net.save(net_path(p, kind))
            meta[f"{kind}_file"] = net_path(p, kind).name
            meta[kind] = self.net.meta
        p.with_suffix(".json").write_text(json.dumps(meta, indent=1, default=str) + "\n")
        return p

    @classmethod
    def load(cls, path: str | Path) -> PhotometricLUT:
        """Read a table written by :meth:`save`; raises CalibrationError if unusable."""
        p = Path(path)
        if not p.is_file():
            raise CalibrationError(f"tactile LUT not found: {p}")
        z = read_npz(p, what="tactile LUT", error=CalibrationError,
                     members=("lo", "hi", "table", "counts"), kinds="uif")
        lo, hi, table, counts = _checked_arrays(p, z["lo"], z["hi"], z["table"], z["counts"])
        del z
        meta: dict[str, Any] = {}
        mp = p.with_suffix(".json")
        if mp.exists() and not mp.is_file():
            raise CalibrationError(f"{mp}: not a file (the table's metadata)")
        if mp.is_file():
            try:
                text = mp.read_text(encoding="utf-8")
            except (OSError, UnicodeDecodeError) as err:
                raise CalibrationError(f"cannot read {mp}: {err}") from None
            meta = safe_json.loads(text, mp, CalibrationError)
            if not isinstance(meta, dict) or meta.get("format") != LUT_FORMAT:
                found = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
                raise CalibrationError(
                    f"{mp}: format {found!r}, this SDK reads {LUT_FORMAT!r}"
                )
        for key, positive in (("work_mm_per_px", True), ("contact_rim_mm", False)):
            _check_length(meta, key, positive, mp)
        net = None
        choice = meta.get("gradient_model", "lut")
        if not isinstance(choice, str):
            raise CalibrationError(f"{mp}: gradient_model must be a name, not {choice!r}")
        if choice in NETWORKS:
            name = meta.get(f"{choice}_file", net_path(p, choice).name)
            if not isinstance(name, str) or not name or name in (".", "..") or "\x00" in name \
                    or len(name.encode("utf-8", "surrogatepass")) > 255 or Path(name).name != name:
                raise CalibrationError(
                    f"{mp}: {choice}_file {str(name)[:80]!r} must be a file name beside it")
            provenance = meta.get(choice)
            net = NETWORKS[choice].load(p.with_name(name), provenance if isinstance(provenance, dict) else None)
        elif choice != "lut":
            raise CalibrationError(f"{mp}: gradient_model {choice!r}, this SDK reads 'lut', "
                                   f"{', '.join(repr(k) for k in NETWORKS)}")
        return cls(lo, hi, table, counts, meta, net)


MAX_BINS = 256
"""Most nodes per colour axis a stored table may have (``thintact calibrate-tactile --bins``
takes at most this many): 256³ × 2 float32 slopes are 128 MiB."""

MAX_SLOPE = 1e3
"""Largest slope (mm per mm) a stored table may hold: a surface at 89.9° has 573; anything
larger is not a surface, and 3e38 made the integrated depth overflow to inf and NaN."""

MAX_FEATURE = 1e3
"""Largest colour-change bound (display units; real ones are within ±1) a table may declare."""


def _checked_arrays(p: Path, lo: np.ndarray, hi: np.ndarray, table: np.ndarray,
                    counts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The members of a stored table as the interpreter uses them (``lo``/``hi`` float64,
    ``table``/``counts`` float32), or CalibrationError naming the file and the member: ``lo``
    and ``hi`` three finite numbers within ±:data:`MAX_FEATURE` with ``lo < hi``; ``table``
    ``B × B × B × 2`` with 2 ≤ B ≤ :data:`MAX_BINS`, finite, within ±:data:`MAX_SLOPE`;
    ``counts`` ``B × B × B``, finite and not negative."""
    for name, a in (("lo", lo), ("hi", hi)):
        if a.shape != (3,):
            raise CalibrationError(f"{p}: {name} has shape {a.shape}, expected three numbers "
                                   "(one per colour channel)")
        if not np.all(np.isfinite(a)) or float(np.abs(a).max()) > MAX_FEATURE:
            raise CalibrationError(f"{p}: {name} holds {a.tolist()}: expected finite colour "
                                   f"bounds within ±{MAX_FEATURE:g}")
    if not np.all(np.asarray(lo, np.float64) < np.asarray(hi, np.float64)):
        raise CalibrationError(f"{p}: lo {lo.tolist()} is not below hi {hi.tolist()} on every channel")
    b = table.shape[0] if table.ndim else 0
    if table.ndim != 4 or table.shape != (b, b, b, 2) or not 2 <= b <= MAX_BINS:
        raise CalibrationError(f"{p}: table shape {table.shape} is not B×B×B×2 with B from 2 to "
                               f"{MAX_BINS}")
    if counts.shape != (b, b, b):
        raise CalibrationError(f"{p}: counts has shape {counts.shape}, the table's nodes are {b}×{b}×{b}")
    table = np.asarray(table, np.float32)
    if not np.all(np.isfinite(table)) or float(np.abs(table).max()) > MAX_SLOPE:
        raise CalibrationError(f"{p}: the table holds slopes that are not finite or beyond "
                               f"±{MAX_SLOPE:g} mm per mm")
    counts = np.asarray(counts, np.float32)
    if not np.all(np.isfinite(counts)) or float(counts.min()) < 0:
        raise CalibrationError(f"{p}: counts holds values that are not finite or negative")
    return np.asarray(lo, np.float64), np.asarray(hi, np.float64), table, counts


def _check_length(meta: dict[str, Any], key: str, positive: bool, where: Path) -> None:
    """Raise CalibrationError naming ``where`` and ``key`` unless ``meta[key]`` (when present)
    is a finite number of mm in ``[0, MAX_META_MM]`` (``> 0`` when ``positive``)."""
    if key not in meta:
        return
    v = meta[key]
    ok = isinstance(v, int | float) and not isinstance(v, bool) \
        and (isinstance(v, int) or math.isfinite(v))  # a 400-digit int has no float
    if not (ok and (v > 0 if positive else v >= 0) and v <= MAX_META_MM):
        low = "over 0" if positive else "from 0"
        raise CalibrationError(
            f"{where}: {key} must be a number of mm {low} to {MAX_META_MM:g}, not {v!r:.40}")


def net_path(lut_path: str | Path, kind: str = "mlp") -> Path:
    """Where the network of the LUT file ``lut_path`` lives: ``<stem>.<kind>.npz`` beside it
    (``kind`` ``"mlp"`` or ``"cnn"``)."""
    p = Path(lut_path)
    return p.with_name(f"{p.stem}.{kind}.npz")


def calibrate_lut(
    features: list[np.ndarray],
    grad_x: list[np.ndarray],
    grad_y: list[np.ndarray],
    valid: list[np.ndarray],
    bins: int = 32,
    margin: float = 0.05,
    meta: dict[str, Any] | None = None,
) -> PhotometricLUT:
    """Build a LUT from calibration images with known slopes.

    Parameters
    ----------
    features
        Per image, ``N × M × 3`` colour minus background (display units).
    grad_x, grad_y
        Per image, ``N × M`` known slopes ∂d/∂x, ∂d/∂y (mm per mm).
    valid
        Per image, ``N × M`` bool: pixels whose slopes are trusted (markers and unsure
        rims excluded).
    bins
        Nodes per colour axis.
    margin
        Fraction of the feature range added on each side of the grid.
    """
    f = np.concatenate([np.asarray(a, np.float64)[m] for a, m in zip(features, valid, strict=True)])
    gx = np.concatenate([np.asarray(a, np.float64)[m] for a, m in zip(grad_x, valid, strict=True)])
    gy = np.concatenate([np.asarray(a, np.float64)[m] for a, m in zip(grad_y, valid, strict=True)])
    if len(f) < 100:
        raise CalibrationError(
            f"only {len(f)} calibration pixels; press the ball harder or use more presses"
        )
    lo, hi = np.percentile(f, 0.05, axis=0), np.percentile(f, 99.95, axis=0)
    span = np.maximum(hi - lo, 1e-3)
    lo, hi = lo - margin * span, hi + margin * span
    lut = PhotometricLUT(
        lo, hi, np.zeros((bins,) * 3 + (2,), np.float32), np.zeros((bins,) * 3, np.float32)
    )
    t = lut._coords(f).astype(np.float64)
    i0 = t.astype(np.int64)
    fr = t - i0
    acc = np.zeros((bins**3, 3))
    for dr in (0, 1):
        wr = fr[:, 0] if dr else 1.0 - fr[:, 0]
        for dg in (0, 1):
            wg = fr[:, 1] if dg else 1.0 - fr[:, 1]
            for db in (0, 1):
                wb = fr[:, 2] if db else 1.0 - fr[:, 2]
                w = wr * wg * wb
                idx = ((i0[:, 0] + dr) * bins + (i0[:, 1] + dg)) * bins + (i0[:, 2] + db)
                np.add.at(acc, idx, np.stack([w, w * gx, w * gy], axis=1))
    nodes = acc.reshape(bins, bins, bins, 3)
    weight = nodes[..., 0]
    filled = weight > 1e-3
    table = np.zeros((bins, bins, bins, 2))
    table[filled] = nodes[filled][:, 1:] / weight[filled][:, None]
    _, nearest = distance_transform_edt(~filled, return_indices=True)
    table = table[nearest[0], nearest[1], nearest[2]]
    lut.table = table.astype(np.float32)
    lut.counts = weight.astype(np.float32)
    lut.meta = dict(meta or {})
    lut.meta.setdefault("calibration_pixels", int(len(f)))
    return lut
