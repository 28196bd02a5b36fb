"""Writing a tactile diagnosis: ``report.json``, ``report.html`` (figures as embedded PNGs) and
``fitted_tactile.yaml`` (the fitted tactile profile section)."""

from __future__ import annotations

import base64
import html
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from thintact_sdk.diagnosis.tactile.press_engine import TactileDiagnosis
from thintact_sdk.diagnosis.tactile.press_model import TactileModel
from thintact_sdk.errors import ThinTactError


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


def model_from_section(section: dict[str, Any]) -> TactileModel:
    """Inverse of :func:`model_section` (per-frame exposures are not stored: ones).

    Raises
    ------
    ThinTactError
        When the section lacks ``tactile.simulation_effects`` or a field is malformed.
    """
    try:
        t = section["tactile"]
        e = t["simulation_effects"]
        return TactileModel(
            effects=list(e["effects"]), field_coef=np.asarray(e["field_coef"], np.float64),
            texture_strength=np.asarray(e["texture_strength"], np.float64),
            light=None if "light" not in e else np.asarray(e["light"], np.float64),
            specular=np.asarray(e["specular"], np.float64), shininess=float(e["shininess"]),
            crosstalk=np.asarray(e["crosstalk"], np.float64), gamma=float(e["gamma"]),
            sigma_mm=float(t["elastomer_sigma_mm"]),
            spread_mm=float(e.get("optical_spread_mm", 0.0)),
            skirt_mm=float(e.get("sink_in_skirt_mm", 0.0)))
    except (KeyError, TypeError, ValueError) as exc:
        raise ThinTactError(f"not a fitted tactile section (tactile.simulation_effects): {exc}") from None


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
