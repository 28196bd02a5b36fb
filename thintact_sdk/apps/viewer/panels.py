"""The viewer's dashboard: one RGB image with six panels and a status line.

::

    +-------------------+-------------------+-------------------+
    | raw measurement   | reconstruction    | depth map         |
    +-------------------+-------------------+-------------------+
    | marker arrows     | contact and shear | (status: fps, ...) |
    +-------------------+-------------------+-------------------+
    | status line: frame, fps, latency                          |

Every panel is :data:`PANEL_W` × :data:`PANEL_H` pixels under a :data:`TITLE_H` title bar;
:func:`panel_boxes` gives where each one is, so a test can look at them in a screenshot.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from thintact_sdk.device.cameras import binning_pattern
from thintact_sdk.formats.profiles import Profile
from thintact_sdk.frames import RawFrame, TactileFrame
from thintact_sdk.pixels.bayer import bin_bayer
from thintact_sdk.tactile.interpretation.grid import TactileParams

PANEL_W, PANEL_H, TITLE_H, STATUS_H = 320, 250, 22, 30
COLUMNS = 3
PANELS = ("raw measurement", "reconstruction", "depth map", "marker displacements",
          "contact and shear", "rates")
ARROW_GAIN = 10.0
"""Marker displacement arrows are drawn this many times their true length."""
MIN_DEPTH_SCALE_MM = 0.2

_BG = (24, 24, 28)
_FG = (235, 235, 235)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


@dataclass
class Rates:
    """What the status panel shows: rates and latencies, NaN when not yet known."""

    sensor_fps: float = float("nan")
    """Tactile frames made per second."""
    served_fps: float = float("nan")
    """Distinct frames sent to the browser per second."""
    latency_ms: float = float("nan")
    """Median camera timestamp → frame served, ms."""
    processing_ms: float = float("nan")
    """Median raw frame → tactile frame, ms."""


def panel_boxes() -> dict[str, tuple[int, int, int, int]]:
    """``name → (x, y, width, height)`` of each panel's picture in the dashboard, px."""
    boxes = {}
    for k, name in enumerate(PANELS):
        row, col = divmod(k, COLUMNS)
        boxes[name] = (col * PANEL_W, row * (PANEL_H + TITLE_H) + TITLE_H, PANEL_W, PANEL_H)
    return boxes


def dashboard_size() -> tuple[int, int]:
    """``(width, height)`` of the dashboard image in px."""
    rows = -(-len(PANELS) // COLUMNS)
    return COLUMNS * PANEL_W, rows * (PANEL_H + TITLE_H) + STATUS_H


def _fit(image: np.ndarray) -> np.ndarray:
    """``image`` (uint8 RGB) scaled to fit a panel, centred on the background."""
    h, w = image.shape[:2]
    scale = min(PANEL_W / w, PANEL_H / h)
    nw, nh = max(1, int(round(w * scale))), max(1, int(round(h * scale)))
    interp = cv2.INTER_AREA if scale < 1 else cv2.INTER_NEAREST
    resized = cv2.resize(image, (nw, nh), interpolation=interp)
    out = np.full((PANEL_H, PANEL_W, 3), _BG, np.uint8)
    y0, x0 = (PANEL_H - nh) // 2, (PANEL_W - nw) // 2
    out[y0:y0 + nh, x0:x0 + nw] = resized
    return out


def _to_uint8(image: np.ndarray, lo: float, hi: float) -> np.ndarray:
    scaled = (np.nan_to_num(image.astype(np.float32), nan=lo) - lo) / max(hi - lo, 1e-12)
    return np.round(np.clip(scaled, 0.0, 1.0) * 255).astype(np.uint8)


def _rgb(image: np.ndarray) -> np.ndarray:
    return np.repeat(image[..., None], 3, axis=2) if image.ndim == 2 else image[..., :3]


def preview_mosaic(data: np.ndarray, max_cols: int = PANEL_W) -> np.ndarray:
    """Every s-th 2 × 2 Bayer cell of an ``H × W`` mosaic, so that binning it gives at most
    about ``max_cols`` columns (the CFA phase is kept; other arrays are returned as they are).
    """
    h, w = data.shape[:2]
    step = max(1, (w // 2) // max_cols)
    if data.ndim != 2 or step == 1 or h % 2 or w % 2:
        return data
    cells = data.reshape(h // 2, 2, w // 2, 2)[::step, :, ::step, :]
    return cells.reshape(cells.shape[0] * 2, cells.shape[2] * 2)


def raw_panel(raw: RawFrame, profile: Profile) -> np.ndarray:
    """The binned measurement above black level, stretched to its 0.5–99.5 percentiles.

    Binned from a subsampled mosaic (:func:`preview_mosaic`): the panel shows at most
    :data:`PANEL_W` columns, so a paper-size frame costs no more than a small one.
    """
    data = raw.data[..., :3] if raw.data.ndim == 3 else raw.data
    pattern = binning_pattern(raw, profile)
    small = data if pattern == "none" else preview_mosaic(data)
    binned = small if pattern == "none" else bin_bayer(small, pattern)
    signal = binned.astype(np.float32) - np.float32(profile.noise.black_level_dn)
    lo, hi = (float(v) for v in np.percentile(signal, [0.5, 99.5]))
    return _fit(_rgb(_to_uint8(signal, lo, hi)))


def image_panel(frame: TactileFrame) -> np.ndarray:
    """The reconstruction in display units, clipped to [0, 1]."""
    return _fit(_rgb(_to_uint8(frame.image, 0.0, 1.0)))


def depth_panel(frame: TactileFrame) -> tuple[np.ndarray, str]:
    """Depth in viridis from 0 to max(deepest, 0.2 mm); returns the panel and its scale."""
    depth = np.asarray(frame.depth_mm, np.float32)
    top = max(float(np.nanmax(depth)) if depth.size and np.isfinite(depth).any() else 0.0,
              MIN_DEPTH_SCALE_MM)
    coloured = cv2.applyColorMap(_to_uint8(depth, 0.0, top), cv2.COLORMAP_VIRIDIS)[..., ::-1]
    return _fit(np.ascontiguousarray(coloured)), f"0-{top:.2f} mm"


def marker_panel(frame: TactileFrame, params: TactileParams) -> np.ndarray:
    """Markers (circles) and their displacements (arrows, ×:data:`ARROW_GAIN`) on the image."""
    base = _to_uint8(np.mean(np.clip(frame.image, 0, 1), axis=2), 0.0, 1.0) // 2
    panel = _fit(_rgb(base))
    h, w = frame.image.shape[:2]
    scale = min(PANEL_W / w, PANEL_H / h)
    x0, y0 = (PANEL_W - w * scale) / 2, (PANEL_H - h * scale) / 2
    pos = np.asarray(frame.marker_positions_mm, np.float64).reshape(-1, 2)
    disp = np.asarray(frame.marker_displacements_mm, np.float64).reshape(-1, 2)
    start = params.mm_to_px(pos)
    end = params.mm_to_px(pos + ARROW_GAIN * disp)
    for (r0, c0), (r1, c1) in zip(start, end, strict=True):
        if not np.all(np.isfinite([r0, c0, r1, c1])):
            continue
        p0 = (int(x0 + (c0 + 0.5) * scale), int(y0 + (r0 + 0.5) * scale))
        p1 = (int(x0 + (c1 + 0.5) * scale), int(y0 + (r1 + 0.5) * scale))
        cv2.circle(panel, p0, 3, (90, 200, 255), 1, cv2.LINE_AA)
        if p1 != p0:  # no arrow for a marker that has not moved a pixel
            cv2.arrowedLine(panel, p0, p1, (255, 210, 60), 2, cv2.LINE_AA, tipLength=0.3)
    _text(panel, [f"{len(pos)} markers, arrows x{ARROW_GAIN:g}"], y=PANEL_H - 10)
    return panel


def contact_panel(frame: TactileFrame) -> np.ndarray:
    """Contact flag, area, depth and shear as text, with the mean shear as an arrow."""
    panel = np.full((PANEL_H, PANEL_W, 3), _BG, np.uint8)
    disp = np.asarray(frame.marker_displacements_mm, np.float64).reshape(-1, 2)
    finite = disp[np.all(np.isfinite(disp), axis=1)]
    mean = finite.mean(axis=0) if len(finite) else np.zeros(2)
    colour = (230, 70, 60) if frame.contact else (70, 190, 90)
    cv2.rectangle(panel, (10, 10), (PANEL_W - 10, 46), colour, -1)
    cv2.putText(panel, "CONTACT" if frame.contact else "no contact", (20, 37), _FONT, 0.8,
                (255, 255, 255), 2, cv2.LINE_AA)
    depth = np.asarray(frame.depth_mm)
    deepest = float(np.nanmax(depth)) if depth.size and np.isfinite(depth).any() else 0.0
    shear = frame.shear_direction_rad
    lines = [f"area {frame.contact_area_mm2:.1f} mm2", f"deepest {deepest:.3f} mm",
             f"shear {np.hypot(*mean) * 1000:.0f} um"
             + (f" at {np.degrees(shear):.0f} deg" if np.isfinite(shear) else "")]
    if frame.force_n is not None:
        fx, fy, fz = (float(v) for v in np.asarray(frame.force_n).reshape(3))
        lines.append(f"force {fz:.2f} N normal, ({fx:.2f}, {fy:.2f}) N shear")
    if frame.slip_ratio is not None:
        lines.append(f"slip ratio {frame.slip_ratio:.2f}")
    _text(panel, lines, y=72)
    centre = (PANEL_W - 60, PANEL_H - 60)
    cv2.circle(panel, centre, 45, (80, 80, 90), 1, cv2.LINE_AA)
    norm = float(np.hypot(*mean))
    if norm > 0:
        length = 45 * min(1.0, norm / 0.2)  # full circle radius at 0.2 mm
        tip = (int(centre[0] + length * mean[0] / norm), int(centre[1] + length * mean[1] / norm))
        cv2.arrowedLine(panel, centre, tip, (255, 210, 60), 3, cv2.LINE_AA, tipLength=0.3)
    return panel


def rates_panel(rates: Rates, frame: TactileFrame) -> np.ndarray:
    """Frame rates and latencies as text."""
    panel = np.full((PANEL_H, PANEL_W, 3), _BG, np.uint8)

    def fmt(value: float, unit: str) -> str:
        return f"{value:.1f} {unit}" if np.isfinite(value) else "-"

    _text(panel, [
        f"frame id {frame.frame_id}",
        f"sensor  {fmt(rates.sensor_fps, 'fps')}",
        f"served  {fmt(rates.served_fps, 'fps')}",
        f"latency {fmt(rates.latency_ms, 'ms')}",
        "  (camera stamp -> served)",
        f"processing {fmt(rates.processing_ms, 'ms')}",
    ], y=30, size=0.6)
    return panel


def _text(panel: np.ndarray, lines: list[str], y: int, size: float = 0.55) -> None:
    for k, line in enumerate(lines):
        cv2.putText(panel, line, (12, y + k * int(34 * size + 8)), _FONT, size, _FG, 1,
                    cv2.LINE_AA)


def render_dashboard(raw: RawFrame, frame: TactileFrame, profile: Profile, rates: Rates,
                     title: str) -> np.ndarray:
    """The whole dashboard, ``H × W × 3`` uint8 RGB (size: :func:`dashboard_size`)."""
    depth, depth_scale = depth_panel(frame)
    pictures = {
        "raw measurement": raw_panel(raw, profile),
        "reconstruction": image_panel(frame),
        "depth map": depth,
        "marker displacements": marker_panel(frame, TactileParams.from_profile(profile)),
        "contact and shear": contact_panel(frame),
        "rates": rates_panel(rates, frame),
    }
    width, height = dashboard_size()
    out = np.full((height, width, 3), _BG, np.uint8)
    for name, (x, y, w, h) in panel_boxes().items():
        out[y:y + h, x:x + w] = pictures[name]
        label = f"{name} ({depth_scale})" if name == "depth map" else name
        cv2.putText(out, label, (x + 8, y - 6), _FONT, 0.5, _FG, 1, cv2.LINE_AA)
        cv2.rectangle(out, (x, y), (x + w - 1, y + h - 1), (60, 60, 70), 1)
    cv2.putText(out, title, (8, height - 10), _FONT, 0.5, _FG, 1, cv2.LINE_AA)
    return out


def encode_jpeg(image: np.ndarray, quality: int = 85) -> bytes:
    """``H × W × 3`` uint8 RGB → JPEG bytes."""
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(image[..., ::-1]),
                           [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError("JPEG encoding failed")
    return buf.tobytes()
