"""Writing a tactile diagnosis: ``report.json``, ``report.html`` (figures as embedded PNGs) and
``fitted_tactile.yaml`` (the fitted tactile profile section)."""

from __future__ import annotations

import base64
import html
import io
import json
import math
import numbers
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from thintact_sdk.diagnosis.tactile.fit import MAX_FIELD_ORDER
from thintact_sdk.diagnosis.tactile.press_engine import TactileDiagnosis
from thintact_sdk.diagnosis.tactile.press_model import TactileModel
from thintact_sdk.diagnosis.tactile.vocabulary import VOCABULARY
from thintact_sdk.errors import ThinTactError
from thintact_sdk.formats.profiles import MAX_PITCH_UM, MIN_PITCH_UM
from thintact_sdk.tactile.simulation.elastomer import TRUNCATE


def model_section(model: TactileModel, mm_per_px: float, source: str) -> dict[str, Any]:
    """The fitted model as a profile's ``tactile`` section (YAML/JSON-ready); read back with
    :func:`model_from_section`."""
    eff: dict[str, Any] = {"effects": list(model.effects),
                           "field_coef": model.field_coef.round(6).tolist(),
                           "texture_strength": model.texture_strength.round(6).tolist(),
                           "texture_from": f"no-contact frame of {source}",
                           "gamma": round(float(model.gamma), 5),
                           "crosstalk": model.crosstalk.round(6).tolist(),
                           "specular": model.specular.round(6).tolist(),
                           "shininess": round(float(model.shininess), 4)}
    if model.light is not None:
        eff["light"] = model.light.round(6).tolist()
    if model.spread_mm > 0:
        eff["optical_spread_mm"] = round(float(model.spread_mm), 5)
    if model.skirt_mm > 0:
        eff["sink_in_skirt_mm"] = round(float(model.skirt_mm), 5)
    return {"tactile": {"mm_per_px": mm_per_px, "elastomer_sigma_mm": round(model.sigma_mm, 5),
                        "simulation_effects": eff}}


SECTION_CHANNELS = 3
"""Colour channels of a fitted section: one light, lobe strength, texture strength, field
polynomial and crosstalk row per channel (what :class:`TactileModel` indexes)."""
FIELD_WIDTHS = tuple((n + 1) * (n + 2) // 2 for n in range(MAX_FIELD_ORDER + 1))
"""Coefficients per channel of an illumination field of order 0 … :data:`MAX_FIELD_ORDER`
(the monomials :func:`~.press_model.polynomial_basis` builds): 1, 3, 6, 10, 15."""
GAMMA_RANGE = (0.05, 20.0)
"""Open interval of the camera response exponent γ. Cameras' power laws lie near 0.3-2.2 (the
diagnosis scans 0.3-1.5); towards 0 or 20 ``linear^γ`` is a flat image or a step, and 0, a
negative or an infinite γ leaves no response (nor its inverse ``I^(1/γ)``) to speak of."""
MAX_SHININESS = 1e4
"""Largest Phong exponent of the lobe (the diagnosis scans 2-30). The lobe ``max(0, r·v)^α``
stays in [0, 1] for any α > 0 (unit light and normal: ``r·v ≤ 1``); beyond 10⁴ it is
narrower than any change of the normal a pixel resolves."""
MAX_LENGTH_MM = 10.0
"""Largest elastomer blur σ_e, optical spread σ_o and sink-in skirt L, in mm, on any grid. The
gel of a camera-based tactile sensor is a few mm thick (GelSight: 2-3 mm) and these widths are
of its order (the diagnosis scans 0.1-1.8 mm); 10 mm would wash out a fingertip-sized frame."""
MM_PER_PX_RANGE = (MIN_PITCH_UM / 1000, MAX_PITCH_UM / 1000)
"""Closed range of ``tactile.mm_per_px``: a profile's (``thintact_sdk.formats.profiles``)."""


_MISSING = object()
"""A required key the section lacks."""


def _shown(value: Any) -> str:
    """``value`` in a few words for an error line."""
    if value is _MISSING:
        return "nothing (the key is missing: not a fitted tactile section?)"
    if isinstance(value, (list, tuple)):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "a mapping"
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _as_float(value: Any) -> float | None:
    """A number (not a bool, not text) as a float (inf past float64), else None."""
    if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)):
        return None
    try:
        return float(value)
    except OverflowError:
        return math.inf


def _number(value: Any, name: str, expected: str, ok: Callable[[float], bool]) -> float:
    """``value`` as a float when it is a finite number that ``ok`` accepts."""
    x = _as_float(value)
    if x is None or not math.isfinite(x) or not ok(x):
        raise ThinTactError(f"{name}: expected {expected}, got {_shown(value)}")
    return x


def _numbers(value: Any, name: str, rows: int, widths: tuple[int, ...] | None = None) -> np.ndarray:
    """``value`` as float64: a list of ``rows`` finite numbers (``widths`` None), or ``rows``
    lists of one same length in ``widths`` (``rows × K``)."""
    if widths is None:
        want = f"a list of {rows} finite numbers"
    elif len(widths) == 1:
        want = f"{rows} lists of {widths[0]} finite numbers ({rows} × {widths[0]})"
    else:
        cols = ", ".join(str(w) for w in widths[:-1]) + f" or {widths[-1]}"
        want = f"{rows} lists of K finite numbers ({rows} × K), K = {cols}"
    if not isinstance(value, (list, tuple)) or len(value) != rows:
        raise ThinTactError(f"{name}: expected {want}, got {_shown(value)}")
    flat: list[Any] = list(value)
    if widths is not None:
        lengths = sorted({len(r) if isinstance(r, (list, tuple)) else -1 for r in value})
        if len(lengths) != 1 or lengths[0] not in widths:
            got = "/".join("a non-list" if n < 0 else str(n) for n in lengths)
            raise ThinTactError(f"{name}: expected {want}, got rows of {got}")
        flat = [x for r in value for x in r]
    out = np.empty(len(flat))
    for i, v in enumerate(flat):
        x = _as_float(v)
        if x is None or not math.isfinite(x):
            raise ThinTactError(f"{name}: expected {want}, got an element {_shown(v)}")
        out[i] = x
    return out if widths is None else out.reshape(rows, -1)


def model_from_section(section: Any, frame: tuple[int, int] | None = None) -> TactileModel:
    """Inverse of :func:`model_section` (per-frame exposures are not stored: ones), the whole
    section checked first: a section is a file a user may be handed, and every array
    :class:`TactileModel` indexes or allocates follows from it.

    Checked, against what :mod:`.press_model` indexes and allocates:

    * ``tactile`` and ``tactile.simulation_effects`` are mappings;
    * ``tactile.mm_per_px``: a number in :data:`MM_PER_PX_RANGE` (a profile's range);
    * ``effects``: a list of distinct names from :data:`~.vocabulary.VOCABULARY`;
    * ``field_coef``: ``3 × K``, K one of :data:`FIELD_WIDTHS` (a field of order 0 to
      :data:`~.fit.MAX_FIELD_ORDER`); ``texture_strength`` and ``specular``: 3 values;
      ``crosstalk``: ``3 × 3``; ``light`` (absent or null: the baseline Phong shading):
      ``3 × 3``, (u, v, w) per channel;
    * every number finite (``.nan``, ``.inf``, a bool, text or an integer past float64 refused);
    * ``gamma`` in the open :data:`GAMMA_RANGE`; ``shininess`` in (0, :data:`MAX_SHININESS`];
    * ``tactile.elastomer_sigma_mm`` in (0, :data:`MAX_LENGTH_MM`]; ``optical_spread_mm`` and
      ``sink_in_skirt_mm`` (absent: 0, the effect off) in [0, :data:`MAX_LENGTH_MM`];
    * with ``frame`` (``(rows, cols)`` of the grid the model is rendered on, at the section's
      ``mm_per_px``): σ_e and σ_o at most ``min(rows, cols) · mm_per_px / (2 · TRUNCATE)``,
      i.e. a Gaussian reach (:data:`~thintact_sdk.tactile.simulation.elastomer.TRUNCATE` σ) of
      at most half the frame's shorter side, so the gel window :func:`~.press_model.ball_normals`
      smooths is at most about twice the frame per side (as the tactile simulator's
      ``2N × 2M`` grids) and the optical spread's kernel no longer than the frame; L at most
      the frame's shorter extent (a longer skirt does not show in the frame). Without
      ``frame`` only the fixed :data:`MAX_LENGTH_MM` applies: pass it where the grid is known.

    Raises
    ------
    ThinTactError
        One line naming the first bad field (dotted, from ``tactile``) and what was expected.
    """
    t = section.get("tactile") if isinstance(section, dict) else None
    if not isinstance(t, dict):
        got = _shown(section.get("tactile", _MISSING)) if isinstance(section, dict) else _shown(section)
        raise ThinTactError("tactile: expected a mapping holding simulation_effects (a fitted tactile "
                            f"section), got {got}")
    e = t.get("simulation_effects")
    if not isinstance(e, dict):
        raise ThinTactError("tactile.simulation_effects: expected a mapping (not a fitted tactile "
                            f"section), got {_shown(t.get('simulation_effects', _MISSING))}")
    fx = "tactile.simulation_effects."

    lo_mm, hi_mm = MM_PER_PX_RANGE
    mm = _number(t.get("mm_per_px", _MISSING), "tactile.mm_per_px",
                 f"a number of mm per pixel in [{lo_mm:g}, {hi_mm:g}]", lambda x: lo_mm <= x <= hi_mm)
    effects = e.get("effects", _MISSING)
    vocab = ", ".join(VOCABULARY)
    if not isinstance(effects, list) or not all(isinstance(n, str) for n in effects):
        raise ThinTactError(f"{fx}effects: expected a list of effect names ({vocab}), "
                            f"got {_shown(effects)}")
    for n in effects:
        if n not in VOCABULARY:
            raise ThinTactError(f"{fx}effects: unknown effect {_shown(n)}; expected names from "
                                f"{vocab}")
    if len(set(effects)) != len(effects):
        dup = next(n for n in effects if effects.count(n) > 1)
        raise ThinTactError(f"{fx}effects: {dup!r} named twice; expected each effect at most once")
    ch = SECTION_CHANNELS
    field_coef = _numbers(e.get("field_coef", _MISSING), fx + "field_coef", ch, FIELD_WIDTHS)
    texture = _numbers(e.get("texture_strength", _MISSING), fx + "texture_strength", ch)
    specular = _numbers(e.get("specular", _MISSING), fx + "specular", ch)
    crosstalk = _numbers(e.get("crosstalk", _MISSING), fx + "crosstalk", ch, (ch,))
    light = None if e.get("light") is None else _numbers(e["light"], fx + "light", ch, (3,))
    g_lo, g_hi = GAMMA_RANGE
    gamma = _number(e.get("gamma", _MISSING), fx + "gamma",
                    f"a camera response exponent in ({g_lo:g}, {g_hi:g})", lambda x: g_lo < x < g_hi)
    shininess = _number(e.get("shininess", _MISSING), fx + "shininess",
                        f"a Phong exponent in (0, {MAX_SHININESS:g}]", lambda x: 0 < x <= MAX_SHININESS)

    short = math.inf if frame is None else min(frame) * mm  # the frame's shorter extent, mm
    grid = "" if frame is None else f"{frame[0]} × {frame[1]} px"

    def length(where: dict[str, Any], key: str, name: str, positive: bool, cap: float,
               why: str) -> float:
        value = where.get(key, _MISSING) if positive else where.get(key, 0.0)
        low = "(0" if positive else "[0"
        x = _number(value, name, f"a length in {low}, {MAX_LENGTH_MM:g}] mm",
                    lambda v: (v > 0 if positive else v >= 0) and v <= MAX_LENGTH_MM)
        if x > cap:
            raise ThinTactError(f"{name}: {x:g} mm is {x / mm:.4g} px at {mm:g} mm/px; expected "
                                f"at most {cap:.4g} mm on the {grid} frame ({why})")
        return x

    reach = f"its Gaussian's reach, {TRUNCATE:g} σ, at most half the frame's shorter side"
    sigma = length(t, "elastomer_sigma_mm", "tactile.elastomer_sigma_mm", True,
                   short / (2 * TRUNCATE), reach)
    spread = length(e, "optical_spread_mm", fx + "optical_spread_mm", False,
                    short / (2 * TRUNCATE), reach)
    skirt = length(e, "sink_in_skirt_mm", fx + "sink_in_skirt_mm", False, short,
                   "at most the frame's shorter extent")
    return TactileModel(effects=list(effects), field_coef=field_coef, texture_strength=texture,
                        light=light, specular=specular, shininess=shininess, crosstalk=crosstalk,
                        gamma=gamma, sigma_mm=sigma, spread_mm=spread, skirt_mm=skirt)


def _png(fig: Any) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _figures(d: TactileDiagnosis) -> dict[str, Any]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figs: dict[str, Any] = {}
    fig, ax = plt.subplots(2, 2, figsize=(10, 7))
    lim = float(np.percentile(np.abs(d.baseline_location.mean_z_map), 99)) or 1.0
    elim = float(np.percentile(np.abs(d.baseline_location.excess_map), 99.5)) or 1.0
    for col, (loc, name) in enumerate(((d.baseline_location, "baseline"),
                                       (d.final_location, "fitted"))):
        im = ax[0, col].imshow(loc.mean_z_map, cmap="RdBu_r", vmin=-lim, vmax=lim)
        ax[0, col].set_title(f"{name}: mean residual / σ (all presses, channels)")
        fig.colorbar(im, ax=ax[0, col], fraction=0.04)
        vmax = elim if col == 0 else float(np.percentile(np.abs(loc.excess_map), 99.5)) or 1.0
        im = ax[1, col].imshow(loc.excess_map, cmap="magma", vmin=0, vmax=vmax)
        ax[1, col].set_title(f"{name}: excess χ² per pixel" + (" (own scale)" if col else ""))
        fig.colorbar(im, ax=ax[1, col], fraction=0.04)
    fig.tight_layout()
    figs["Residual maps before and after (same colour scales)"] = fig
    i = int(np.argmax([p.depth_mm for p in d.presses]))
    fig, ax = plt.subplots(1, 5, figsize=(17, 3.4))
    real = d.data.images[i]
    for a, img, title in zip(ax[:3], (real, d.baseline_pred[i], d.final_pred[i]),
                             ("real", "baseline simulation", "fitted simulation"), strict=True):
        a.imshow(np.clip(img, 0, 1))
        a.set_title(f"press {d.indices[i]}: {title}")
    for a, pred, title in ((ax[3], d.baseline_pred[i], "baseline"), (ax[4], d.final_pred[i], "fitted")):
        a.imshow(np.clip(0.5 + 2.0 * (real - pred), 0, 1))
        a.set_title(f"residual × 2 + 0.5, {title}")
    figs["One press, real against simulated (deepest fitted press)"] = fig
    k = d.final.field_coef.shape[1]
    field = np.einsum("ck,khw->hwc", d.final.field_coef, d.data.basis[:k])
    bg = d.final.background(d.data.basis, d.data.texture)
    fig, ax = plt.subplots(2, 3, figsize=(13, 6))
    for c, ch in enumerate("RGB"):
        im = ax[0, c].imshow(field[..., c], cmap="viridis")
        ax[0, c].set_title(f"illumination field F_{ch} (order {d.final.field_order})")
        fig.colorbar(im, ax=ax[0, c], fraction=0.04)
        im = ax[1, c].imshow(bg[..., c], cmap="viridis")
        ax[1, c].set_title(f"F_{ch}·(1 + α t_{ch}), α = {d.final.texture_strength[c]:.2f}")
        fig.colorbar(im, ax=ax[1, c], fraction=0.04)
    fig.tight_layout()
    figs["Fitted illumination field and background"] = fig
    fig, ax = plt.subplots(1, 3, figsize=(15, 3.6))
    for rep, name in ((d.baseline_location.report, "baseline"), (d.final_location.report, "fitted")):
        sl = rep["by_slope_magnitude"]
        ax[0].plot(range(len(sl)), [b["chi2"] for b in sl], "o-", label=name)
        dr = rep["by_slope_direction"]
        ax[1].plot([b["azimuth_deg"] for b in dr], [b["chi2"] for b in dr], "o-", label=name)
        reg = rep["by_region"]
        ax[2].bar([f"{k}\n{name}" for k in reg], list(reg.values()))
    ax[0].set_xticks(range(len(sl)), [f"{b['lo']}-{b['hi'] or '∞'}" for b in sl], fontsize=7)
    ax[0].set_xlabel("model slope magnitude (mm/mm)")
    ax[1].set_xlabel("slope direction (deg)")
    for a in ax:
        a.set_yscale("log")
        a.set_ylabel("χ² per value")
    ax[0].legend()
    ax[2].tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    figs["Where the mismatch sits: slope magnitude, slope direction, contact region"] = fig
    return figs


def write_tactile_outputs(d: TactileDiagnosis, out: Path) -> dict[str, Path]:
    """Write the three outputs into ``out`` (created).

    Raises
    ------
    ThinTactError
        When the directory cannot be written.
    """
    try:
        out.mkdir(parents=True, exist_ok=True)
        rep = out / "report.json"
        rep.write_text(json.dumps(d.report, indent=1, ensure_ascii=False) + "\n", encoding="utf-8")
        prof = out / "fitted_tactile.yaml"
        section = model_section(d.final, d.data.mm_per_px, d.report["source"])
        prof.write_text("# fitted by thintact diagnose-tactile: the tactile profile section\n"
                        + yaml.safe_dump(section, sort_keys=False), encoding="utf-8")
        page = out / "report.html"
        page.write_text(_html(d), encoding="utf-8")
    except OSError as err:
        raise ThinTactError(f"cannot write the diagnosis to {out}: {err}") from None
    return {"report": rep, "fitted_profile": prof, "html": page}


def _html(d: TactileDiagnosis) -> str:
    r = d.report
    esc = html.escape
    rows = "".join(
        f"<tr><td>{esc(f['effect'])}</td><td><code>{esc(json.dumps(f['params']))}</code></td>"
        f"<td>{f['chi2_per_dof_after']:.3f}</td><td>{f['delta_bic']:.0f}</td>"
        f"<td>{esc(', '.join(f['alternatives']) or '–')}</td></tr>" for f in r["findings"])
    figs = "".join(f"<h3>{esc(t)}</h3><img src='data:image/png;base64,{_png(f)}'/>"
                   for t, f in _figures(d).items())
    unexp = r["unexplained"]
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>Tactile diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}td,th{{border:1px solid #ccc;padding:3px}}
table{{border-collapse:collapse}} img{{max-width:100%}}</style></head><body>
<h1>Tactile simulation against real presses</h1>
<p>{esc(r['source'])}: {len(r['presses_used'])} presses of a {r['ball_radius_mm']} mm ball,
{r['mm_per_px']} mm/px. Per-pixel noise (DN): {r['noise_rms_dn']}.</p>
<p>Baseline (the SDK's tactile simulation, one gain per channel): χ²/dof
<b>{r['baseline']['chi2_per_dof']:.3f}</b>, RMS {r['baseline']['rms_dn']:.2f} DN.
Final: χ²/dof <b>{r['final']['chi2_per_dof']:.3f}</b>, RMS {r['final']['rms_dn']:.2f} DN.</p>
<p>Located: {esc(r['located']['summary'])}</p>
<table><tr><th>effect</th><th>parameters</th><th>χ²/dof after</th><th>ΔBIC</th><th>alternatives</th></tr>{rows}</table>
<p>Unexplained ({'significant' if unexp['significant'] else 'not significant'}): {esc(unexp['summary'])}</p>
{figs}</body></html>
"""
