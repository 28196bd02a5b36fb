"""Mask design files (``thintact-mask-design/1`` JSON), fitness plots and mask images."""

from __future__ import annotations

import json
import os
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np

from thintact_masks.errors import MaskDesignError
from thintact_sdk import __version__
from thintact_sdk.interfaces import Mask
from thintact_sdk.plugin_support import safe_json

DESIGN_FORMAT = "thintact-mask-design/1"
DESIGNS_DIR = Path(__file__).parent / "designs"


def design_record(mask: Mask, **fields: Any) -> dict[str, Any]:
    """The JSON record of a mask: φ, feature size, design, provenance and extra ``fields``."""
    rec: dict[str, Any] = {
        "format": DESIGN_FORMAT,
        "design": mask.design,
        "K": mask.K,
        "feature_um": mask.feature_um,
        "phi": [int(v) for v in mask.phi],
        "phi_rows": None if mask.phi_rows is None else [int(v) for v in mask.phi_rows],
        "provenance": {"created": datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
                       "software_version": __version__, **mask.provenance},
    }
    rec.update(fields)
    return rec


def write_json_atomic(path: str | os.PathLike[str], record: dict[str, Any]) -> Path:
    """Write ``record`` as JSON to ``path`` via a temporary file and a rename."""
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(json.dumps(record, indent=1) + "\n", encoding="utf-8")
    os.replace(tmp, p)
    return p


def load_design(path: str | os.PathLike[str]) -> tuple[Mask, dict[str, Any]]:
    """Read a design file; returns the :class:`Mask` and the whole record.

    ``path`` may also name a file in the shipped ``designs/`` directory (without ``.json``).
    """
    p = Path(path)
    if not p.is_file() and (DESIGNS_DIR / f"{p.name}.json").is_file():
        p = DESIGNS_DIR / f"{p.name}.json"
    if not p.is_file():
        shipped = ", ".join(sorted(f.stem for f in DESIGNS_DIR.glob("*.json"))) or "(none)"
        raise MaskDesignError(f"design file not found: {path} (shipped designs: {shipped})")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise MaskDesignError(f"cannot read design {p}: not a UTF-8 JSON file ({err})") from None
    rec = safe_json.loads(text, f"design {p}", MaskDesignError)
    if not isinstance(rec, dict) or rec.get("format") != DESIGN_FORMAT:
        raise MaskDesignError(f"{p} is not a {DESIGN_FORMAT} file")
    phi = _signs(rec.get("phi", []))
    if phi is None or phi.size == 0:
        raise MaskDesignError(f"{p}: 'phi' must be a non-empty list of +1/-1")
    rows = rec.get("phi_rows")
    phi_rows = None if rows is None else _signs(rows)
    if rows is not None and (phi_rows is None or phi_rows.shape != phi.shape):
        raise MaskDesignError(f"{p}: 'phi_rows' must be {phi.size} entries of +1/-1")
    feature_um, provenance = rec.get("feature_um", 0.0), rec.get("provenance", {})
    if isinstance(feature_um, bool) or not isinstance(feature_um, int | float):
        raise MaskDesignError(f"{p}: 'feature_um' must be a number, got {feature_um!r}")
    if not isinstance(provenance, dict):
        raise MaskDesignError(f"{p}: 'provenance' must be a JSON object")
    mask = Mask(phi=phi, feature_um=float(feature_um), phi_rows=phi_rows,
                design=str(rec.get("design", "custom")), provenance=dict(provenance))
    return mask, rec


def _signs(value: Any) -> np.ndarray | None:
    """``value`` as an int8 vector when it is a flat list of +1/-1 numbers, else None."""
    if not isinstance(value, list) or not all(
            isinstance(v, int | float) and not isinstance(v, bool) and v in (1, -1) for v in value):
        return None
    return np.asarray(value, np.int8)


def render_mask_png(mask: Mask, path: str | os.PathLike[str], cell_px: int = 1) -> Path:
    """Write the ``K × K`` pattern (open = white) as an 8-bit PNG, ``cell_px`` pixels per cell."""
    import cv2

    if cell_px < 1:
        raise MaskDesignError(f"cell size must be >= 1 px, got {cell_px}")
    img = (mask.pattern() * 255).astype(np.uint8)
    if cell_px > 1:
        img = np.kron(img, np.ones((cell_px, cell_px), np.uint8))
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    # encoded in memory and written by Python: cv2.imwrite crashed the process (segmentation
    # fault) on a path that is not valid UTF-8
    try:
        ok, data = cv2.imencode(p.suffix or ".png", img)
    except cv2.error:
        ok = False
    if not ok:
        raise MaskDesignError(f"cannot write image {p} (use a .png name)")
    try:
        p.write_bytes(data.tobytes())
    except OSError as err:
        raise MaskDesignError(f"cannot write image {p}: {err.strerror or err}") from None
    return p


def plot_fitness(best: list[float], mean: list[float], path: str | os.PathLike[str],
                 baselines: dict[str, float] | None = None, title: str = "") -> Path:
    """PNG plot of best and mean fitness per generation, with baseline lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0), dpi=100)
    gens = np.arange(len(best))
    ax.plot(gens, best, label="best", color="C0")
    ax.plot(gens, mean, label="mean", color="C1", alpha=0.8)
    for n, (name, value) in enumerate(sorted((baselines or {}).items())):
        ax.axhline(value, ls="--", color=f"C{n + 2}", label=name)
    ax.set_xlabel("generation")
    ax.set_ylabel("fitness")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(p)
    plt.close(fig)
    return p
