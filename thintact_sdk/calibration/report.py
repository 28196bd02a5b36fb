"""The calibration's HTML report: matrices, convergence, validation, pass/fail.

One self-contained file (figures as base64 PNG, matplotlib Agg backend).
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from thintact_sdk.profile import Profile

if TYPE_CHECKING:
    from thintact_sdk.calibration.pipeline import CalibrationOutcome


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _matrices_figure(outcome: CalibrationOutcome, profile: Profile) -> str:
    import matplotlib.pyplot as plt

    sm = outcome.bundle.system_matrices
    names = profile.sensor.channels
    fig, axes = plt.subplots(sm.channels, 4, figsize=(15, 3.0 * sm.channels), squeeze=False,
                             layout="constrained")
    for c in range(sm.channels):
        for k, key in enumerate(("Po", "Pc", "Qo", "Qc")):
            a = np.asarray(getattr(sm, key)[c], np.float64)
            ax = axes[c][k]
            lim = float(np.abs(a).max()) or 1.0
            im = ax.imshow(a, aspect="auto", cmap="RdBu_r" if key.endswith("c") else "viridis",
                           vmin=-lim if key.endswith("c") else None, vmax=lim)
            ax.set_title(f"{key} ({names[c] if c < len(names) else c})", fontsize=9)
            fig.colorbar(im, ax=ax, fraction=0.046)
    fig.suptitle("System matrices (DN per display unit; rows: sensor, columns: scene)")
    return _png(fig)


def _convergence_figure(outcome: CalibrationOutcome, profile: Profile) -> str:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3))
    for c, rep in enumerate(outcome.reports):
        name = profile.sensor.channels[c] if c < len(profile.sensor.channels) else str(c)
        ax.semilogy(range(1, len(rep.residual_history) + 1), rep.residual_history, "o-", label=name)
    ax.set_xlabel("iteration (Algorithm 3)")
    ax.set_ylabel("relative residual of the slit fit")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    return _png(fig)


def _validation_figure(outcome: CalibrationOutcome) -> str | None:
    import matplotlib.pyplot as plt

    val = outcome.validation
    if not val:
        return None
    fig, axes = plt.subplots(len(val), 2, figsize=(6, 2.6 * len(val)), squeeze=False,
                             layout="constrained")
    for i, v in enumerate(val):
        axes[i][0].imshow(np.clip(v.truth, 0, 1))
        axes[i][0].set_title(f"{v.label}: displayed", fontsize=9)
        axes[i][1].imshow(np.clip(v.estimate, 0, 1))
        axes[i][1].set_title(f"reconstructed: {v.psnr_db:.1f} dB, SSIM {v.ssim:.3f}", fontsize=9)
        for ax in axes[i]:
            ax.axis("off")
    return _png(fig)


def _table(rows: list[list[Any]], header: list[str]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def write_report(outcome: CalibrationOutcome, profile: Profile, path: str | Path) -> Path:
    """Write ``report.html`` for ``outcome``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    meta = outcome.bundle.meta
    metrics = meta.get("metrics", {})
    lim = metrics.get("limits", {})
    verdict = "PASS" if outcome.passed else "FAIL"
    color = "#1a7f37" if outcome.passed else "#cf222e"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>ThinTact calibration</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px}"
        "img{max-width:100%}</style></head><body>",
        f"<h1>Calibration of {html.escape(profile.name)}</h1>",
        f"<p style='font-size:1.4em;color:{color}'><b>{verdict}</b> — mean PSNR "
        f"{metrics.get('mean_psnr_db', float('nan')):.2f} dB (limit {lim.get('min_psnr_db')}), mean SSIM "
        f"{metrics.get('mean_ssim', float('nan')):.3f} (limit {lim.get('min_ssim')})</p>",
        _table(
            [[k, meta.get(k)] for k in ("created", "source", "profile_hash", "software_version", "tau", "exposure_us")]
            + [["dark level", metrics.get("dark")], ["slit frames", metrics.get("slit_frames")],
               ["frames averaged per pattern", metrics.get("frames_averaged")],
               ["recording", meta.get("recording")]],
            ["field", "value"],
        ),
        "<h2>Solve (Algorithms 2-3)</h2>",
        _table(
            [[s["channel"], s["method"], s["iterations"], s["converged"], f"{s['relative_residual']:.3e}"]
             for s in metrics.get("solve", [])],
            ["channel", "method", "iterations", "converged", "relative residual"],
        ),
        f"<img src='{_convergence_figure(outcome, profile)}'>",
        "<h2>System matrices</h2>",
        "<p>Gauge: the open term is the smoothest mixture, and ‖P‖<sub>F</sub> = ‖Q‖<sub>F</sub> per "
        "term (paper Algorithm 3). Only the products P X Qᵀ are physical.</p>",
        f"<img src='{_matrices_figure(outcome, profile)}'>",
        "<h2>Validation</h2>",
    ]
    rows = []
    for v in outcome.validation:
        ok = v.psnr_db >= lim.get("min_psnr_db", 0) and v.ssim >= lim.get("min_ssim", 0)
        note = "pass" if ok else "below limit"
        if v.saturated_fraction > 0:
            note += f" (saturated: {100 * v.saturated_fraction:.2f} % of pixels)"
        rows.append([v.label, f"{v.psnr_db:.2f}", f"{v.ssim:.3f}", note])
    parts.append(_table(rows, ["scene", "PSNR (dB)", "SSIM", "vs limits"]) if rows else
                 "<p>No validation frames in the recording.</p>")
    fig = _validation_figure(outcome)
    if fig:
        parts.append(f"<img src='{fig}'>")
    if outcome.reference:
        ref = outcome.reference
        parts.append("<h2>Comparison with the reference matrices</h2>")
        parts.append(_table(
            [[c, f"{e:.4f}", ", ".join(f"{k} {v:.4f}" for k, v in t.items())]
             for c, (e, t) in enumerate(zip(ref["operator_error"], ref["term_errors"], strict=True))],
            ["channel", "operator error (gauge-free)", "per-term errors (canonical gauge)"],
        ))
        parts.append(_table(
            [[k, f"{metrics['psnr_db'].get(k, float('nan')):.2f}", f"{v:.2f}"]
             for k, v in ref.get("reference_psnr_db", {}).items()],
            ["scene", "PSNR calibrated (dB)", "PSNR reference (dB)"],
        ))
    reg = metrics.get("registration")
    if reg:
        parts.append("<h2>Registration</h2>")
        parts.append(_table([[k, v] for k, v in reg.items()], ["field", "value"]))
    if metrics.get("saturated_frames"):
        parts.append("<h2>Saturation</h2>")
        parts.append(_table([[k, f"{100 * v:.3f} %"] for k, v in metrics["saturated_frames"].items()],
                            ["frame", "saturated pixels"]))
    parts.append("</body></html>")
    p = Path(path)
    p.write_text("\n".join(parts), encoding="utf-8")
    return p
