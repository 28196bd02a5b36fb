"""Mask designs from other labs' files: PNG, CSV, NPY → φ (along x, columns) and φ_rows
(along y, rows) of a ``thintact-mask-design/1`` record.

Accepted content:

* a **2-D pattern** of K×K cells (PNG: grey or colour, thresholded at the midpoint of its
  darkest and brightest value; CSV / NPY: numbers, same threshold), open cells bright (1)
  unless ``open_dark``; a PNG drawn with ``c × c`` pixels per cell is read at the cell centres
  when ``K`` is given (its side must be a multiple of K);
* **two vectors** (CSV: two lines; NPY: shape ``(2, K)``) of ±1: φ, then φ_rows.

**Convention check** (CONTRACTS §1): a pattern is open where ``(1 + φ_rows[i]·φ[j])/2 = 1``.
The 2-D pattern ``M = 2·open − 1`` must be exactly ``φ_rows φᵀ`` (rank 1 in ±1); the vectors
are fixed up to one common sign (the same mask) by ``φ[0] = +1``. A pattern that is not
separable is refused with the number of cells that break it; so is a pattern that is all
open or all closed.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from thintact_masks.errors import MaskDesignError

MAX_IMPORT_SIDE = 16384
"""Largest side (pixels or entries) of an imported pattern."""


def _read_array(path: Path) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix == ".png":
        from PIL import Image

        with Image.open(path) as im:
            if max(im.size) > MAX_IMPORT_SIDE:
                raise MaskDesignError(f"{path}: {im.size[0]}×{im.size[1]} px is larger than {MAX_IMPORT_SIDE}")
            return np.asarray(im.convert("L"), np.float64)
    if suffix == ".npy":
        from thintact_sdk.safe_arrays import read_npy

        return np.asarray(read_npy(path, what="mask pattern", error=MaskDesignError, kinds="uifb"), np.float64)
    if suffix in (".csv", ".txt"):
        with path.open(newline="", encoding="utf-8") as fh:
            rows = [[c.strip() for c in r if c.strip()] for r in csv.reader(fh)]
        rows = [r for r in rows if r]
        if not rows or len({len(r) for r in rows}) != 1:
            raise MaskDesignError(f"{path}: every non-empty CSV line must have the same number of entries")
        try:
            return np.asarray([[float(c) for c in r] for r in rows])
        except ValueError as err:
            raise MaskDesignError(f"{path}: CSV entries must be numbers ({err})") from None
    raise MaskDesignError(f"{path}: unknown mask file type {suffix!r} (PNG, CSV, NPY; DXF: export it as PNG)")


def import_pattern(path: str | Path, K: int | None = None, open_dark: bool = False  # noqa: N803
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``(φ, φ_rows)``, each ``(K,)`` int8 ±1, from a design file (module docstring)."""
    p = Path(path)
    a = _read_array(p)
    if a.ndim != 2 or a.size == 0 or not np.all(np.isfinite(a)):
        raise MaskDesignError(f"{p}: expected a finite 2-D pattern or two vectors, got shape {a.shape}")
    if a.shape[0] == 2 and a.shape[1] > 2 and set(np.unique(a)) <= {-1.0, 1.0}:
        phi, phi_rows = a[0].astype(np.int8), a[1].astype(np.int8)
    else:
        if K is not None:
            if a.shape[0] % K or a.shape[1] % K:
                raise MaskDesignError(f"{p}: {a.shape[0]}×{a.shape[1]} is not a multiple of K={K} cells per side")
            cr, cc = a.shape[0] // K, a.shape[1] // K
            a = a[cr // 2::cr, cc // 2::cc]
        if a.shape[0] != a.shape[1]:
            raise MaskDesignError(f"{p}: the pattern is {a.shape[0]}×{a.shape[1]} cells, a square K×K is needed "
                                  "(give --K for a drawing with several pixels per cell)")
        lo, hi = float(a.min()), float(a.max())
        if hi <= lo:
            raise MaskDesignError(f"{p}: the pattern is uniform (all open or all closed)")
        is_open = (a > (lo + hi) / 2) != open_dark
        m = np.where(is_open, 1, -1).astype(np.int8)
        phi_rows = m[:, 0] * m[0, 0]
        phi = m[0] * m[0, 0]
        bad = int(np.count_nonzero(np.outer(phi_rows, phi) != m))
        if bad:
            raise MaskDesignError(
                f"{p}: not a separable mask in the SDK's convention (open where phi_rows[i]*phi[j] = +1): "
                f"{bad} of {m.size} cells break it; check the open colour (--open-dark) and K")
    if phi[0] < 0:
        phi, phi_rows = -phi, -phi_rows
    return phi.astype(np.int8), phi_rows.astype(np.int8)
