#!/usr/bin/env python
"""Figures and table of Real2Sim trained against the simulation ``diagnose-tactile`` fitted to
the sensor (issue 29 item 4), on the held-out presses of a press pack.

Reads ``thintact real2sim evaluate --json`` output (the held-out tables) and the generator,
and writes into ``--figures``:

* ``images.png``: three held-out presses: the real colour change, its translation's, and the
  fitted simulation's for a ball at the place and depth the translation's depth map fits;
* ``per_press.png``: per held-out press, the fitted sphere radius and the depth RMS against the
  fixed-radius ball, real path against Real2Sim path;

and measures the fitted simulation on itself (``in-domain``: its own presses at known places
and depths through a LUT of its exact slopes, the figures of the held-out table), which says
whether what is lost is lost in the translation or in the simulation. With ``--docs`` the
table replaces the text between ``<!-- real2sim_fitted -->`` and ``<!-- /real2sim_fitted -->``.

Usage::

    thintact real2sim evaluate --generator G --real PACK --json eval.json
    python tools/real2sim_figures.py --eval eval.json --generator G --real PACK \\
        --figures docs/figures/real2sim --docs docs/tactile.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np
from docs_block import host_line, write_block

MARK_OPEN, MARK_CLOSE = "<!-- real2sim_fitted -->", "<!-- /real2sim_fitted -->"
ROWS = {
    "real": "real images; table/network calibrated on the real training presses",
    "real2sim": "Real2Sim translations; calibrated on the translated training presses",
    "real2sim+fitted-sim-lut": "Real2Sim translations; LUT of the fitted simulation (no real truth)",
    "real+fitted-sim-lut": "real images; LUT of the fitted simulation (no real truth)",
    "in-domain": "the fitted simulation's own presses; LUT of its exact slopes",
}


def _host() -> str:
    return host_line()


def in_domain(section: dict[str, Any], reference: np.ndarray, radius: float, mm: float,
              count: int = 16) -> dict[str, Any]:
    """The fitted simulation's presses through its own LUT: the held-out table's figures."""
    from thintact_sdk.diagnosis.tactile.correction import fitted_images, fitted_simulation_lut
    from thintact_sdk.diagnosis.tactile.report import model_from_section
    from thintact_sdk.tactile.calibration.ball_eval import press_figures, summarise
    from thintact_sdk.tactile.calibration.press_pack import pack_profile
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter

    model = model_from_section(section, reference.shape[:2])
    ref = reference.astype(np.float64)
    lut = fitted_simulation_lut(model, ref, radius, mm)
    flat, images, _gx, _gy = fitted_images(model, ref, radius, mm, count=count, seed=7)
    profile = pack_profile(reference.shape[:2], mm)
    interp = TactileInterpreter(profile, lut)  # type: ignore[arg-type]
    interp.set_reference(np.clip(flat, 0, 1).astype(np.float32))
    figs = []
    for im in images:
        gx, gy, depth = interp.work_slopes(np.clip(im, 0, 1).astype(np.float32))
        figs.append(press_figures(depth, gx, gy, radius, interp.work.mm_per_px,
                                  interp.params.contact_threshold_mm))
    return {"summary": summarise(figs, radius), "gradient_model": "lut"}


def table(rows: dict[str, dict[str, Any]], radius: float) -> str:
    head = ("| photometric stereo on | sphere radius, median (middle half) | contact / √(2Rp−p²) "
            "| depth RMS inside the contact, fixed-R ball | slope RMS (flat) "
            "| vs annotated: depth / slope RMS | peak |\n"
            "|---|---|---|---|---|---|---|\n")
    out = []
    for name, res in rows.items():
        s = res["summary"]
        ann = (f"{s['annotated_depth_rms_mm']:.3f} mm / {s['annotated_slope_rms']:.3f}"
               if s.get("annotated_depth_rms_mm") is not None else "–")
        ratio = "–" if s["contact_ratio_median"] is None else f"{s['contact_ratio_median']:.2f}"
        model = res.get("gradient_model") or "lut"
        out.append(f"| {ROWS.get(name, name)} ({model}) | {s['sphere_radius_median_mm']:.2f} mm "
                   f"({s['sphere_radius_q25_mm']:.2f}-{s['sphere_radius_q75_mm']:.2f}), "
                   f"{s['sphere_radius_median_mm'] / radius - 1:+.0%} | {ratio} | "
                   f"{s['depth_rms_mm']:.3f} mm | {s['slope_rms']:.3f} ({s['slope_rms_flat']:.2f}) | "
                   f"{ann} | {s['peak_mean_mm']:.2f} mm |")
    return head + "\n".join(out) + "\n"


def figures(out: Path, ev: dict[str, Any], translator: Any, pack: Any, section: dict[str, Any],
            radius: float, mm: float) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from thintact_sdk.diagnosis.tactile.press_model import (
        Press,
        ball_normals,
        polynomial_basis,
        texture_map,
    )
    from thintact_sdk.diagnosis.tactile.report import model_from_section
    from thintact_sdk.tactile.calibration.press_pack import pack_profile
    from thintact_sdk.tactile.interpretation.interpreter import TactileInterpreter

    out.mkdir(parents=True, exist_ok=True)
    f = TactileInterpreter(pack_profile(pack.reference.shape[:2], mm)).factor  # working grid → image
    model = model_from_section(section, pack.reference.shape[:2])
    ref = pack.reference_image().astype(np.float64)
    bg = model.background(polynomial_basis(*ref.shape[:2], model.field_order), texture_map(ref))
    flat = model.respond(bg)
    ref_t = translator(pack.reference_image())
    r2s = {p["press"]: p for p in ev["ball_figures"]["real2sim"]["presses"]}
    picks = ev["test"][:: max(1, len(ev["test"]) // 3)][:3]
    fig, axes = plt.subplots(len(picks), 3, figsize=(9, 2.6 * len(picks)))
    for row, i in zip(np.atleast_2d(axes), picks, strict=True):
        real = pack.image(i)
        trans = translator(real)
        p = r2s[i]
        sim_press = Press(p["centre_rc"][0] * f, p["centre_rc"][1] * f, p["press_mm"])
        sim = model.respond(bg * model.shading(ball_normals(ref.shape[:2], sim_press, radius, mm,
                                                            model.sigma_mm, model.skirt_mm)))
        for ax, img, title in zip(row, (real - pack.reference_image(), trans - ref_t, sim - flat),
                                  (f"real, press {i}", "Real2Sim translation",
                                   f"fitted simulation, {p['press_mm']:.2f} mm"), strict=True):
            ax.imshow(np.clip(0.5 + 2.0 * img, 0, 1))
            ax.set_title(title, fontsize=9)
            ax.axis("off")
    fig.suptitle("colour change against the no-contact frame (×2 around grey)", fontsize=10)
    fig.tight_layout()
    paths = [out / "images.png"]
    fig.savefig(paths[0], dpi=90)
    plt.close(fig)

    real_p = {p["press"]: p for p in ev["ball_figures"]["real"]["presses"]}
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    ids = [i for i in ev["test"] if i in real_p and i in r2s]
    for ax, key, label in ((a, "sphere_radius_mm", "fitted sphere radius (mm)"),
                           (b, "depth_rms_mm", "depth RMS vs fixed-R ball (mm)")):
        x = np.array([real_p[i][key] for i in ids])
        y = np.array([r2s[i][key] for i in ids])
        ax.scatter(x, y, s=14)
        lo, hi = float(min(x.min(), y.min())), float(max(x.max(), y.max()))
        ax.plot([lo, hi], [lo, hi], "k:", lw=1)
        if key == "sphere_radius_mm":
            ax.axhline(radius, color="g", lw=1, label=f"ball {radius:g} mm")
            ax.axvline(radius, color="g", lw=1)
            ax.legend(fontsize=8)
        ax.set_xlabel(f"real path: {label}", fontsize=9)
        ax.set_ylabel(f"Real2Sim path: {label}", fontsize=9)
    fig.suptitle(f"held-out presses ({len(ids)}), host {_host()}", fontsize=9)
    fig.tight_layout()
    paths.append(out / "per_press.png")
    fig.savefig(paths[1], dpi=90)
    plt.close(fig)
    return paths


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eval", type=Path, required=True, help="real2sim evaluate --json output")
    ap.add_argument("--generator", type=Path, required=True)
    ap.add_argument("--real", type=Path, required=True, help="the press pack")
    ap.add_argument("--figures", type=Path, required=True, help="directory for the PNGs")
    ap.add_argument("--docs", type=Path, help="markdown file to write the table into")
    a = ap.parse_args()

    from thintact_sdk.tactile.calibration.press_pack import load_press_pack
    from thintact_sdk.tactile.learning.evaluate import fitted_section_of
    from thintact_sdk.tactile.learning.translate import Real2SimTranslator

    ev = json.loads(a.eval.read_text(encoding="utf-8"))
    translator = Real2SimTranslator.load(a.generator)
    section = fitted_section_of(translator)
    if section is None or "ball_figures" not in ev:
        print("needs a generator trained with --sim-model and evaluate's ball figures", file=sys.stderr)
        return 2
    pack = load_press_pack(a.real)
    radius = float(pack.ball_radius_mm or translator.meta.get("ball_radius_mm") or 2.0)
    mm = float(pack.mm_per_px or translator.meta.get("mm_per_px") or 0.1245)
    rows = dict(ev["ball_figures"])
    rows["in-domain"] = in_domain(section, pack.reference_image(), radius, mm)
    paths = figures(a.figures, ev, translator, pack, section, radius, mm)
    text = (f"Held-out presses {len(ev['test'])} (trained on {len(ev['train'])}); generator "
            f"{translator.meta.get('iterations', '?')} iterations; host {_host()}, load average "
            f"{os.getloadavg()[0]:.1f}.\n\n" + table(rows, radius))
    print(text)
    print("figures: " + ", ".join(str(p) for p in paths))
    if a.docs is not None:
        write_block(a.docs, MARK_OPEN, MARK_CLOSE, text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
