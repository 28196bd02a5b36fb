"""The figure of a :func:`thintact_sdk.device.virtual_demo.run_demo` press, for the CLI and the viewer.

Eight panels: the raw Bayer frame, the binned measurement, the reconstruction next to the
ground-truth scene, the estimated depth next to the true indentation, a depth profile through
the middle row, and the marker displacements (×10) over the reconstruction.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.device.virtual_demo import DemoResult
from thintact_sdk.formats.profiles import Profile

__all__ = ["demo_figure"]


def _stretch(img: np.ndarray) -> np.ndarray:
    lo, hi = np.percentile(img, [0.5, 99.5])
    return np.clip((img - lo) / max(hi - lo, 1e-9), 0, 1)


def demo_figure(path: str | Path, result: DemoResult, profile: Profile, show: bool = False) -> Path:
    """Draw ``result`` (made on ``profile``) and save it as a PNG at ``path`` (90 dpi); returns
    ``path``. Without ``show`` it draws off screen (matplotlib's Agg backend); with ``show`` it
    keeps matplotlib's interactive backend and opens the figure in a window after saving,
    returning once the window is closed."""
    return _figure(Path(path), result.raw, result.signal, result.frame, result.press, profile,
                   result.summary, show)


def _figure(path: Path, raw: np.ndarray, signal: np.ndarray, frame: Any, press: Any,
            profile: Profile, summary: dict[str, Any], show: bool = False) -> Path:
    import matplotlib

    if not show:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    mm = profile.scene.pixel_pitch_um / 1000.0
    n, m = profile.scene.rows, profile.scene.cols
    extent = (-(m / 2) * mm, (m / 2) * mm, (n / 2) * mm, -(n / 2) * mm)
    fig, axes = plt.subplots(2, 4, figsize=(17, 7.5))
    ax = axes[0, 0]
    ax.imshow(raw, cmap="gray")
    ax.set_title(f"raw Bayer frame {raw.shape[0]}×{raw.shape[1]} (DN)")
    ax = axes[0, 1]
    ax.imshow(_stretch(signal))
    ax.set_title("binned measurement R, Ḡ, B (not a picture)")
    ax = axes[0, 2]
    ax.imshow(np.clip(frame.image, 0, 1), extent=extent)
    ax.set_title(f"reconstruction ({summary['psnr_db']:.1f} dB)")
    ax = axes[0, 3]
    ax.imshow(press.scene, extent=extent)
    ax.set_title("ground-truth membrane scene")
    vmax = float(max(press.depth_mm.max(), 1e-3))
    ax = axes[1, 0]
    im = ax.imshow(frame.depth_mm, cmap="viridis", vmin=0, vmax=vmax, extent=extent)
    ax.set_title(f"estimated depth (max {frame.depth_mm.max():.2f} mm)")
    fig.colorbar(im, ax=ax, fraction=0.046, label="mm")
    ax = axes[1, 1]
    im = ax.imshow(press.depth_mm, cmap="viridis", vmin=0, vmax=vmax, extent=extent)
    ax.set_title(f"true indentation (max {press.depth_mm.max():.2f} mm)")
    fig.colorbar(im, ax=ax, fraction=0.046, label="mm")
    ax = axes[1, 2]
    r = n // 2
    xs = (np.arange(m) - (m - 1) / 2) * mm
    ax.plot(xs, press.depth_mm[r], label="true")
    ax.plot(xs, frame.depth_mm[r], label="estimated")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("depth (mm)")
    ax.set_title(f"depth profile, row {r} (RMS error {summary['depth_rms_error_mm']:.3f} mm)")
    ax.legend()
    ax = axes[1, 3]
    ax.imshow(np.clip(frame.image, 0, 1), extent=extent, alpha=0.5)
    pos = frame.marker_positions_mm
    disp = frame.marker_displacements_mm
    good = np.isfinite(pos[:, 0]) & np.isfinite(disp[:, 0]) if len(pos) else np.zeros(0, bool)
    if good.any():
        ax.quiver(pos[good, 0], pos[good, 1], disp[good, 0], disp[good, 1], color="red",
                  angles="xy", scale_units="xy", scale=0.1)
    ax.set_title("marker displacements (×10)")
    ax.set_xlabel("x (mm)")
    for a in axes.flat[:4]:
        a.set_xticks([])
        a.set_yticks([])
    fig.suptitle(f"ThinTact virtual sensor '{profile.name}': {summary['depth_max_mm']['true']:.2f} mm "
                 f"ball press, contact={summary['contact']}")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    if show:
        plt.show()
    plt.close(fig)
    return path
