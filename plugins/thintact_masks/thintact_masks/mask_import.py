"""Mask designs from other labs' files: PNG, DXF, CSV, NPY → φ (along x, columns) and φ_rows
(along y, rows) of a ``thintact-mask-design/1`` record.

Accepted content:

* a **2-D pattern** of K×K cells (PNG: grey or colour, thresholded at the midpoint of its
  darkest and brightest value; CSV / NPY: numbers, same threshold), open cells bright (1)
  unless ``open_dark``; a PNG drawn with ``c × c`` pixels per cell is read at the cell centres
  when ``K`` is given (its side must be a multiple of K);
* **two vectors** (CSV: two lines; NPY: shape ``(2, K)``) of ±1: φ, then φ_rows;
* a **DXF drawing** (read with ``ezdxf``, the optional ``dxf`` extra): the cells drawn as
  closed shapes (closed LWPOLYLINE/POLYLINE, SOLID, TRACE, 3DFACE, HATCH; a shape may cover a
  run of cells; a hatch's holes are honoured; open polylines, lines and text are ignored) are
  the OPEN cells unless ``open_dark``. For a separable mask that is not uniform every row and
  column holds an open and a closed cell, so the drawn shapes span the whole K×K mask: their
  bounding box is the mask, its side / K the pitch δ. K is given, or derived from the
  drawing's ``$INSUNITS`` (mm, µm, cm, m, inch) and the feature size. Row 0 is the drawing's
  top (largest y), column 0 its left, as the drawing looks. ``layer`` keeps one layer only
  (e.g. to leave out a frame drawn around the mask).

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


DXF_UNITS_UM = {1: 25400.0, 4: 1000.0, 5: 10000.0, 6: 1e6, 13: 1.0}
"""Micrometres per drawing unit of the DXF ``$INSUNITS`` codes the importer understands."""
DXF_CELL_TOLERANCE = 0.1
"""Largest distance, in cells, of the drawing's width / feature size from a whole number of
cells (K derived from the drawing's units), and of its height from its width: a drawing on
the stated pitch is exact to drawing precision, a wrong unit or feature size is off by more."""


def _dxf_shapes(path: Path, layer: str | None) -> tuple[list[list[np.ndarray]], float | None]:
    """Each drawn closed shape as its loops (``(n, 2)`` vertices in drawing units), and µm
    per drawing unit (None when the drawing declares no unit the importer knows)."""
    try:
        import ezdxf
        from ezdxf import path as dxf_path
    except ImportError:
        raise MaskDesignError(f"{path}: reading DXF needs ezdxf (pip install 'thintact-masks[dxf]'); "
                              "or export the drawing as PNG") from None
    try:
        doc = ezdxf.readfile(str(path))
    except (OSError, ezdxf.DXFError) as err:
        raise MaskDesignError(f"{path}: not a readable DXF file ({err})") from None
    shapes: list[list[np.ndarray]] = []
    for e in doc.modelspace():
        kind = e.dxftype()
        if layer is not None and e.dxf.get("layer", "0") != layer:
            continue
        if kind == "HATCH":
            paths = list(dxf_path.from_hatch(e))  # type: ignore[arg-type]
        elif kind in ("SOLID", "TRACE", "3DFACE"):
            paths = [dxf_path.make_path(e)]
        elif kind in ("LWPOLYLINE", "POLYLINE"):
            pts = [tuple(v)[:2] for v in (e.get_points("xy") if kind == "LWPOLYLINE"  # type: ignore[attr-defined]
                                          else (v.dxf.location for v in e.vertices))]  # type: ignore[attr-defined]
            closed = bool(e.closed) or (len(pts) > 2 and np.allclose(pts[0], pts[-1]))  # type: ignore[attr-defined]
            if not closed:
                continue
            paths = [dxf_path.make_path(e)]
        else:
            continue
        loops = [np.asarray([(v.x, v.y) for v in p.flattening(1e-3)], np.float64) for p in paths]
        loops = [lp for lp in loops if len(lp) >= 3]
        if loops:
            shapes.append(loops)
    if not shapes:
        where = f" on layer {layer!r}" if layer is not None else ""
        raise MaskDesignError(f"{path}: no closed shapes (closed polylines, solids, hatches){where}")
    return shapes, DXF_UNITS_UM.get(int(doc.header.get("$INSUNITS", 0)))


def _inside(loop: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Even-odd test of the points ``(x, y)`` against one closed loop."""
    out = np.zeros(x.shape, bool)
    xs, ys = loop[:, 0], loop[:, 1]
    for a in range(len(loop)):
        b = (a - 1) % len(loop)
        crosses = (ys[a] > y) != (ys[b] > y)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = xs[a] + (y - ys[a]) * (xs[b] - xs[a]) / (ys[b] - ys[a])
        out ^= crosses & (x < xc)
    return out


def _read_dxf(path: Path, K: int | None, feature_um: float | None, layer: str | None  # noqa: N803
              ) -> np.ndarray:
    """The K×K pattern (1 where a shape is drawn) of a DXF mask drawing (module docstring)."""
    shapes, um = _dxf_shapes(path, layer)
    pts = np.concatenate([lp for loops in shapes for lp in loops])
    (x0, y0), (x1, y1) = pts.min(axis=0), pts.max(axis=0)
    w, h = float(x1 - x0), float(y1 - y0)
    if not (w > 0 and h > 0):
        raise MaskDesignError(f"{path}: the drawn shapes have no area")
    if K is None:
        if um is None or feature_um is None:
            raise MaskDesignError(f"{path}: the drawing declares no length unit ($INSUNITS); give --K "
                                  "(cells per side)")
        cells = w * um / feature_um
        K = int(round(cells))
        if K < 1 or abs(cells - K) > DXF_CELL_TOLERANCE:
            raise MaskDesignError(f"{path}: the drawing is {w * um:g} um wide, {cells:.3f} cells of "
                                  f"{feature_um:g} um; give --K or check the feature size and $INSUNITS")
    if abs(w - h) > DXF_CELL_TOLERANCE * w / K:
        raise MaskDesignError(f"{path}: the drawn shapes span {w:g} x {h:g} drawing units; a square "
                              "K x K mask is needed (a frame or label on another layer? use --layer)")
    cx = x0 + (np.arange(K) + 0.5) * w / K
    cy = y1 - (np.arange(K) + 0.5) * h / K  # row 0 at the top
    gx, gy = np.meshgrid(cx, cy)
    drawn = np.zeros((K, K), bool)
    for loops in shapes:
        inside = np.zeros((K, K), bool)
        for lp in loops:
            inside ^= _inside(lp, gx, gy)
        drawn |= inside
    return drawn.astype(np.float64)


def _read_array(path: Path) -> np.ndarray:
    suffix = path.suffix.lower()
    if suffix == ".png":
        from PIL import Image

        try:
            with Image.open(path) as im:
                if max(im.size) > MAX_IMPORT_SIDE:
                    raise MaskDesignError(f"{path}: {im.size[0]}×{im.size[1]} px is larger than {MAX_IMPORT_SIDE}")
                return np.asarray(im.convert("L"), np.float64)
        except Image.DecompressionBombError as err:  # a header declaring too many pixels
            raise MaskDesignError(f"{path}: refused, the image declares too many pixels ({err})") from None
        except (OSError, ValueError, SyntaxError, EOFError) as err:  # not a PNG, damaged, cut short
            raise MaskDesignError(f"{path}: not a readable PNG ({type(err).__name__}: {err})") from None
    if suffix == ".npy":
        from thintact_sdk.plugin_support import read_npy

        return np.asarray(read_npy(path, what="mask pattern", error=MaskDesignError, kinds="uifb"), np.float64)
    if suffix in (".csv", ".txt"):
        try:
            with path.open(newline="", encoding="utf-8") as fh:
                rows = [[c.strip() for c in r if c.strip()] for r in csv.reader(fh)]
        except UnicodeDecodeError as err:
            raise MaskDesignError(f"{path}: not UTF-8 text ({err})") from None
        except csv.Error as err:
            raise MaskDesignError(f"{path}: not a CSV file ({err})") from None
        rows = [r for r in rows if r]
        if not rows or len({len(r) for r in rows}) != 1:
            raise MaskDesignError(f"{path}: every non-empty CSV line must have the same number of entries")
        try:
            return np.asarray([[float(c) for c in r] for r in rows])
        except ValueError as err:
            raise MaskDesignError(f"{path}: CSV entries must be numbers ({err})") from None
    raise MaskDesignError(f"{path}: unknown mask file type {suffix!r} (PNG, DXF, CSV, NPY)")


def import_pattern(path: str | Path, K: int | None = None, open_dark: bool = False,  # noqa: N803
                   feature_um: float | None = None, layer: str | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """``(φ, φ_rows)``, each ``(K,)`` int8 ±1, from a design file (module docstring).

    ``feature_um`` (the cell side, µm) and ``layer`` are used by DXF drawings only.
    """
    p = Path(path)
    if p.suffix.lower() == ".dxf":
        a = _read_dxf(p, K, feature_um, layer)
        K = None  # noqa: N806 - already one value per cell
    else:
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
        phi_rows = m[:, 0]  # m = phi_rows phi^T gives m[i,0]*m[0,j]*m[0,0] = m[i,j]
        phi = m[0] * m[0, 0]
        bad = int(np.count_nonzero(np.outer(phi_rows, phi) != m))
        if bad:
            raise MaskDesignError(
                f"{p}: not a separable mask in the SDK's convention (open where phi_rows[i]*phi[j] = +1): "
                f"{bad} of {m.size} cells break it; check the open colour (--open-dark) and K")
    if phi[0] < 0:
        phi, phi_rows = -phi, -phi_rows
    return phi.astype(np.int8), phi_rows.astype(np.int8)
