"""The calibration's HTML report: verdict with fixes, τ choice, validation against the design's
prediction, health (residuals, noise, defects), matrices, convergence.

One self-contained file (figures as base64 PNG, matplotlib Agg backend).
"""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.calibration.outcome import CalibrationOutcome
from thintact_sdk.formats.profiles import Profile


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


def _framed(ax: Any) -> None:
    """No ticks but a dark frame, so a white panel stays visible on the white page."""
    ax.set_xticks([])
    ax.set_yticks([])
    for spine in ax.spines.values():
        spine.set_visible(True)
        spine.set_color("#444")
        spine.set_linewidth(1.0)


def _validation_figure(outcome: CalibrationOutcome) -> str | None:
    import matplotlib.pyplot as plt

    val = outcome.validation
    if not val:
        return None
    fig, axes = plt.subplots(len(val), 2, figsize=(6, 2.6 * len(val)), squeeze=False,
                             layout="constrained")
    for i, v in enumerate(val):
        axes[i][0].imshow(_display(v.truth), vmin=0, vmax=1, cmap="gray")
        axes[i][0].set_title(f"{v.label}: displayed", fontsize=9)
        axes[i][1].imshow(_display(v.estimate), vmin=0, vmax=1, cmap="gray")
        axes[i][1].set_title(f"reconstructed (held out): {v.psnr_db:.1f} dB, SSIM {v.ssim:.3f}", fontsize=9)
        for ax in axes[i]:
            _framed(ax)
    return _png(fig)


def _display(image: np.ndarray) -> np.ndarray:
    """``N × M × C`` display values as an image matplotlib shows (one channel: grey)."""
    x = np.clip(np.asarray(image, np.float32), 0, 1)
    return x[..., 0] if x.ndim == 3 and x.shape[2] == 1 else x


def _tau_figure(outcome: CalibrationOutcome) -> str | None:
    import matplotlib.pyplot as plt

    sel = outcome.selection
    if sel is None or not sel.curves:
        return None
    psnr_curves = [c for c in sel.curves if c.unit.startswith("mean PSNR dB")]
    noise_curves = [c for c in sel.curves if not c.unit.startswith("mean PSNR dB")]
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.4), layout="constrained")
    for c in psnr_curves:
        line = axes[0].semilogx(c.taus, c.values, ".-", label=c.criterion)[0]
        if np.isfinite(c.tau):
            axes[0].axvline(c.tau, color=line.get_color(), ls=":", lw=1)
    axes[0].axvline(sel.tau, color="k", lw=1.5, label=f"chosen τ = {sel.tau:.3g} ({sel.decoder})")
    axes[0].set_xlabel("τ (DN²)")
    axes[0].set_ylabel("mean PSNR (dB)")
    axes[0].legend(fontsize=7)
    axes[0].grid(True, which="both", alpha=0.3)
    for c in noise_curves:
        line = axes[1].loglog(c.taus, c.values, ".-", label=f"{c.criterion}: {c.unit}")[0]
        if np.isfinite(c.tau):
            axes[1].axvline(c.tau, color=line.get_color(), ls=":", lw=1)
    if noise_curves:
        axes[1].axhline(1.0, color="gray", lw=0.8)
        axes[1].set_xlabel("τ (DN²)")
        axes[1].legend(fontsize=7)
        axes[1].grid(True, which="both", alpha=0.3)
    else:
        axes[1].axis("off")
    return _png(fig)


def _health_figure(outcome: CalibrationOutcome, profile: Profile) -> str | None:
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    h = outcome.health
    if h is None:
        return None
    fig, axes = plt.subplots(1, 4 if h.ghost_scans else 3, figsize=(20 if h.ghost_scans else 15, 3.6),
                             layout="constrained")
    vals = list(h.slit_chi2.values())
    axes[0].plot(range(len(vals)), vals, ".", ms=3)
    axes[0].axhline(1.0, color="gray", lw=0.8)
    axes[0].set_xlabel("slit frame (rows, then columns)")
    axes[0].set_ylabel("mean r²/σ² (1 = noise)")
    axes[0].set_title("Per-slit fit residual against the measured noise", fontsize=9)
    im = axes[1].imshow(h.chi2_map, cmap="magma", vmin=0, vmax=max(3.0, float(np.percentile(h.chi2_map, 99.9))))
    fig.colorbar(im, ax=axes[1], fraction=0.046)
    axes[1].set_title("Slit residual r²/σ² per sensor pixel (defects boxed)", fontsize=9)
    for d in h.defects:
        if d.kind == "ghost":  # the whole image: its offset is in the ghost panel
            continue
        axes[1].add_patch(Rectangle((d.col0 - 0.5, d.row0 - 0.5), d.col1 - d.col0, d.row1 - d.row0,
                                    fill=False, ec="cyan", lw=1.5))
        axes[1].annotate(d.kind, (d.col1, d.row0), color="cyan", fontsize=8)
    names = profile.sensor.channels
    for c in range(h.column_deviation.shape[0]):
        axes[2].plot(100 * h.column_deviation[c], lw=0.8, label=f"columns {names[c] if c < len(names) else c}")
    for c in range(h.row_deviation.shape[0]):
        axes[2].plot(100 * h.row_deviation[c], lw=0.8, ls="--", label=f"rows {names[c] if c < len(names) else c}")
    axes[2].set_xlabel("sensor column / row")
    axes[2].set_ylabel("open response vs neighbours (%)")
    axes[2].set_title("Dim or bright sensor lines", fontsize=9)
    axes[2].legend(fontsize=7)
    if h.ghost_scans:
        from thintact_sdk.calibration.ghost import MIN_STRENGTH

        for g in h.ghost_scans:
            line = axes[3].plot(g.lags, 100 * np.asarray(g.strength), ".-", ms=3, lw=0.8, label=g.name)[0]
            if g.significant:
                axes[3].plot([g.lag], [100 * g.value], "o", ms=9, mfc="none", color=line.get_color())
        axes[3].axhline(100 * MIN_STRENGTH, color="gray", ls=":", lw=1, label="reported from")
        axes[3].set_xlabel("offset (sensor pixels)")
        axes[3].set_ylabel("ghost strength (% of the image)")
        axes[3].set_title("Ghost search (a circle marks a ghost found)", fontsize=9)
        axes[3].legend(fontsize=7)
    return _png(fig)


def _table(rows: list[list[Any]], header: list[str]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows
    )
    return f"<table><tr>{head}</tr>{body}</table>"


def _fmt(value: Any) -> str:
    """A value as a person reads it: 4 significant digits, lists and dicts flattened."""
    if isinstance(value, bool) or value is None:
        return {True: "yes", False: "no", None: "—"}[value]
    if isinstance(value, float | np.floating):
        return f"{float(value):.4g}"
    if isinstance(value, list | tuple):
        return "(" + ", ".join(_fmt(v) for v in value) + ")"
    if isinstance(value, dict):
        return "; ".join(f"{k}: {_fmt(v)}" for k, v in value.items())
    return str(value)


def _failures(outcome: CalibrationOutcome) -> str:
    if outcome.verdict is None or not outcome.verdict.failures:
        return ""
    items = "".join(f"<li><b>{html.escape(f.what)}</b>: {html.escape(f.detail)}<br><i>Suggested fix:</i> "
                    f"{html.escape(f.fix)}</li>" for f in outcome.verdict.failures)
    return f"<ul>{items}</ul>"


def _selection_text(outcome: CalibrationOutcome) -> str:
    sel = outcome.selection
    if sel is None:
        return "<p>No τ selection was run.</p>"
    rows = [[name, f"{tau:.4g}", f"{sel.cross_validation[name].held_out_mean_db:.2f}"
             if name in sel.cross_validation else "—"] for name, tau in sel.decoder_taus.items()]
    chosen = {c.criterion: c for c in sel.curves}
    crit = [[c.criterion, f"{c.tau:.4g}" if np.isfinite(c.tau) else "none", c.note] for c in chosen.values()]
    return (f"<p>Recommended decoder <b>{html.escape(sel.decoder)}</b> with τ = {sel.tau:.4g} DN², chosen by "
            f"<b>{html.escape(sel.criterion)}</b>. Cross-validation tunes τ on one fold of the validation "
            "scenes and scores the other fold with it, so no scene is scored with a τ tuned on it.</p>"
            + _table(rows, ["decoder", "τ (DN²)", "held-out mean PSNR (dB)"])
            + _channel_tau_text(outcome) + _prior_text(outcome)
            + "<p>τ each criterion would choose:</p>" + _table(crit, ["criterion", "τ (DN²)", "note"]))


def _prior_text(outcome: CalibrationOutcome) -> str:
    """The scene-prior check: each candidate prior's cross-validated τ and held-out mean PSNR
    against plain Tikhonov's, and what the bundle uses."""
    sel = outcome.selection
    if sel is None:
        return ""
    parts = []
    for name, cv in sel.cross_validation.items():
        if not cv.prior_curves:
            continue
        rows = [["plain Tikhonov", "", "", f"{cv.plain_held_out_db:.2f}", "" if cv.prior else "used"]]
        rows += [[f"{p.alpha:g}", f"{p.k0:g}", f"{c.tau:.4g}", f"{cv.prior_held_out_db[p]:.2f}",
                  "used" if p == cv.prior else ""] for p, c in cv.prior_curves]
        verdict = (f"the bundle uses α {cv.prior.alpha:g}, k0 {cv.prior.k0:g} at τ {cv.curve.tau:.4g} DN²"
                   if cv.prior is not None else "the bundle uses plain Tikhonov")
        parts.append(
            f"<p>Scene prior for <b>{html.escape(name)}</b>: generalised Tikhonov τ‖W_L X W_Rᵀ‖² with DCT "
            "weights (1 + k/k0)^α per axis, solved by the same closed form. Each candidate's τ is "
            "cross-validated like plain τ (tuned on one fold, the other fold scored with it); the "
            f"candidate with the best held-out mean PSNR is deployed: {verdict}.</p>"
            + _table(rows, ["α", "k0", "τ (DN²)", "held-out mean PSNR (dB)", ""]))
    return "".join(parts)


def _channel_tau_text(outcome: CalibrationOutcome) -> str:
    """The per-channel τ check: each fold's τ per channel, the held-out means with one τ and
    with a τ per channel, and what the bundle uses."""
    sel = outcome.selection
    if sel is None:
        return ""
    rows = []
    for name, cv in sel.cross_validation.items():
        if not cv.channel_fold_tau:
            continue
        used = ("per channel: " + ", ".join(f"{t:.4g}" for t in cv.channel_tau)) if cv.channel_tau else "one τ"
        tuned = np.asarray(cv.channel_fold_tau)
        ranges = ", ".join(f"{lo:.3g}–{hi:.3g}" for lo, hi in zip(tuned.min(axis=0), tuned.max(axis=0), strict=True))
        gain = cv.held_out_channel_db - cv.held_out_shared_db
        rows.append([name, ranges, f"{cv.held_out_shared_db:.2f}", f"{cv.held_out_channel_db:.2f}",
                     f"{gain:+.2f} ± {cv.channel_gain_se_db:.2f}", used])
    if not rows:
        return ""
    return ("<p>τ per channel: leaving out one distinct validation scene at a time, one τ and one τ per "
            "channel are tuned on the others and the left-out scene is scored with both; the bundle "
            "keeps a τ per channel only when the mean gain exceeds its standard error.</p>"
            + _table(rows, ["decoder", "τ per channel tuned without each scene (DN², range)",
                            "held out, one τ (dB)", "held out, τ per channel (dB)", "gain ± s.e. (dB)",
                            "bundle uses"]))


def _validation_table(outcome: CalibrationOutcome) -> str:
    if not outcome.validation:
        return "<p>No validation frames in the recording: nothing to judge the unit by.</p>"
    checks = {c.label: c for c in outcome.verdict.scenes} if outcome.verdict else {}
    margin = outcome.verdict.margin_db if outcome.verdict else float("nan")
    rows = []
    for v in outcome.validation:
        c = checks.get(v.label)
        if c is None:
            note = "no prediction"
        elif c.shortfall_db > margin:
            note = f"FAIL: PSNR {c.shortfall_db:.2f} dB below prediction (allowed {margin:g} dB)"
        else:
            note = f"pass: PSNR within {margin:g} dB of prediction"
        if v.saturated_fraction > 0:
            note += f"; saturated: {100 * v.saturated_fraction:.2f} % of pixels"
        rows.append([v.label, f"{v.psnr_db:.2f}", "—" if c is None else f"{c.predicted_db:.2f}",
                     "—" if c is None else f"{c.shortfall_db:+.2f}", f"{v.ssim:.3f}", note])
    return _table(rows, ["scene", "PSNR (dB)", "predicted PSNR (dB)", "shortfall (dB)", "SSIM", "verdict"])


def _health_section(outcome: CalibrationOutcome, profile: Profile) -> list[str]:
    h = outcome.health
    if h is None:
        return []
    n = h.noise
    out = ["<h2>Health</h2>",
           f"<p>Mean slit-fit residual r²/σ² = {h.mean_chi2:.3f} (1 is pure noise). Noise measured on "
           "the slit residuals against the profile's:</p>",
           _table([["read noise (DN, per capture)", f"{n.read_noise_dn:.3g}", f"{n.profile_read_noise_dn:.3g}"],
                   ["electrons per DN", f"{n.electrons_per_dn:.3g}", f"{n.profile_electrons_per_dn:.3g}"]],
                  ["", "measured", "profile"])]
    if h.defects:
        out.append("<p><b>Defects located:</b></p><ul>" + "".join(
            f"<li>{html.escape(d.describe())}</li>" for d in h.defects) + "</ul>")
    else:
        out.append("<p>No defect located: no structure beyond noise in the slit residuals, no dim or "
                   "bright sensor line, no ghost, no shading blemish in the flat and validation frames.</p>")
    if h.ghost_scans:
        out.append("<p>Ghost search: a faint displaced copy of the image is looked for in the slit frames "
                   "(not separable: the copy widens the slits' column/row space) and as an echo of the "
                   "design's coding pattern in the calibrated matrices (separable: absorbed by them). "
                   "Strongest candidate of each scan:</p>"
                   + _table([[g.name, f"{g.lag:+d}" if g.lags else "-",
                               f"{100 * (g.estimate if np.isfinite(g.estimate) else g.value):.2f} %" if g.lags else "-",
                               "yes" if g.significant else "no"]
                             for g in h.ghost_scans], ["scan", "offset (px)", "strength", "ghost"]))
    fig = _health_figure(outcome, profile)
    if fig:
        out.append(f"<img src='{fig}'>")
    return out


def write_report(outcome: CalibrationOutcome, profile: Profile, path: str | Path) -> Path:
    """Write ``report.html`` for ``outcome``; returns its path."""
    import matplotlib

    matplotlib.use("Agg")
    meta = outcome.bundle.meta
    metrics = meta.get("metrics", {})
    verdict = "PASS" if outcome.passed else "FAIL"
    color = "#1a7f37" if outcome.passed else "#cf222e"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>ThinTact calibration</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}"
        "table{border-collapse:collapse}td,th{border:1px solid #ccc;padding:3px 8px}"
        "img{max-width:100%}</style></head><body>",
        f"<h1>Calibration of {html.escape(profile.name)}</h1>",
        f"<p style='font-size:1.4em;color:{color}'><b>{verdict}</b> — mean held-out PSNR "
        f"{metrics.get('mean_psnr_db', float('nan')):.2f} dB, mean SSIM "
        f"{metrics.get('mean_ssim', float('nan')):.3f}</p>",
        _failures(outcome),
        _table(
            [[k, _fmt(meta.get(k))] for k in ("created", "source", "profile_hash", "software_version",
                                               "decoder", "tau", "tau_t2s_closed_form", "exposure_us")]
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
        "<h2>Decoder and τ, chosen on this unit's frames</h2>",
        _selection_text(outcome),
    ]
    tau_fig = _tau_figure(outcome)
    if tau_fig:
        parts.append(f"<img src='{tau_fig}'>")
    parts.append("<h2>Validation against this design's prediction</h2>")
    parts.append(_validation_table(outcome))
    fig = _validation_figure(outcome)
    if fig:
        parts.append(f"<img src='{fig}'>")
    parts += _health_section(outcome, profile)
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
        parts.append(_table([[k, _fmt(v)] for k, v in reg.items()], ["field", "value"]))
    if metrics.get("saturated_frames"):
        parts.append("<h2>Saturation</h2>")
        parts.append(_table([[k, f"{100 * v:.3f} %"] for k, v in metrics["saturated_frames"].items()],
                            ["frame", "saturated pixels"]))
    if metrics.get("stages"):
        parts.append("<h2>Stages: time and memory</h2>")
        parts.append("<p>Wall time of each stage after the capture and the process's peak resident "
                     "memory at its end (the bundle's own writing, this report included, is in "
                     "calibration.json). A resumed stage was loaded from its checkpoint.</p>")
        parts.append(_table([[s_["stage"], f"{s_['seconds']:.1f}", f"{s_['peak_rss_mib']:.0f}",
                              "yes" if s_.get("resumed") else ""] for s_ in metrics["stages"]],
                            ["stage", "wall time (s)", "peak memory (MiB)", "resumed"]))
    parts.append("</body></html>")
    p = Path(path)
    p.write_text("\n".join(parts), encoding="utf-8")
    return p
