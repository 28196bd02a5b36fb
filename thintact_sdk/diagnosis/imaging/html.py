"""``report.html``: the figures a person needs to see the diagnosis (matplotlib Agg, PNGs
embedded as base64)."""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from thintact_sdk.diagnosis.imaging.engine import Diagnosis
from thintact_sdk.diagnosis.imaging.locate import Location


def _png(fig: Any) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _rects(ax: Any, spots: list[dict[str, Any]], color: str) -> None:
    from matplotlib.patches import Rectangle

    for h in spots:
        ax.add_patch(
            Rectangle((h["col0"] - 0.5, h["row0"] - 0.5), h["col1"] - h["col0"], h["row1"] - h["row0"],
                      fill=False, edgecolor=color, lw=1.5)
        )


def figure_residual_maps(d: Diagnosis) -> Any:
    """Mean signed residual (noise units) and excess χ² per pixel, before and after."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    for col, (loc, name) in enumerate(((d.baseline_location, "baseline"), (d.final_location, "fitted"))):
        lim = float(np.percentile(np.abs(d.baseline_location.mean_z_map), 99)) or 1.0
        im = axes[0, col].imshow(loc.mean_z_map, cmap="RdBu_r", vmin=-lim, vmax=lim)
        axes[0, col].set_title(f"{name}: mean residual / σ")
        fig.colorbar(im, ax=axes[0, col], fraction=0.04)
        ex = d.baseline_location.excess_map
        elim = float(np.percentile(np.abs(ex), 99.5)) or 1.0
        im = axes[1, col].imshow(loc.excess_map, cmap="magma", vmin=0, vmax=elim)
        axes[1, col].set_title(f"{name}: excess χ² per pixel (Σ frames, channels)")
        fig.colorbar(im, ax=axes[1, col], fraction=0.04)
    _rects(axes[1, 0], d.report["located"]["hotspots"], "cyan")
    _rects(axes[1, 1], d.report["unexplained"]["hotspots"], "lime")
    for ax in axes.ravel():
        ax.set_xlabel("sensor column")
        ax.set_ylabel("sensor row")
    fig.tight_layout()
    return fig


def figure_where(d: Diagnosis) -> Any:
    """χ² per value by channel, frame, signal level, radius and spatial frequency."""
    import matplotlib.pyplot as plt

    b, a = d.baseline_location, d.final_location
    chans = list(d.data.profile.sensor.channels)
    fig, axes = plt.subplots(2, 3, figsize=(13, 7))
    x = np.arange(len(chans))
    axes[0, 0].bar(x - 0.2, b.by_channel, 0.4, label="baseline")
    axes[0, 0].bar(x + 0.2, a.by_channel, 0.4, label="fitted")
    axes[0, 0].set_xticks(x, chans)
    axes[0, 0].set_title("by channel")
    xf = np.arange(len(d.data.labels))
    axes[0, 1].bar(xf - 0.2, b.by_frame, 0.4, label="baseline")
    axes[0, 1].bar(xf + 0.2, a.by_frame, 0.4, label="fitted")
    axes[0, 1].set_xticks(xf, d.data.labels, rotation=75, fontsize=7)
    axes[0, 1].set_title("by frame (scene)")
    panels = ((b.by_signal, a.by_signal, axes[0, 2]), (b.by_radius, a.by_radius, axes[1, 0]),
              (b.by_frequency, a.by_frequency, axes[1, 1]))
    for pb, pa, ax in panels:
        ax.plot(pb.centres, pb.chi2, "o-", label="baseline")
        ax.plot(pa.centres, pa.chi2, "s-", label="fitted")
        ax.set_xlabel(f"{pb.name} ({pb.unit})")
        ax.set_title(f"by {pb.name}")
    axes[1, 1].set_ylabel("residual power / noise power")
    for ax in axes.ravel()[:5]:
        ax.axhline(1.0, color="k", lw=0.8, ls="--")
        ax.legend(fontsize=8)
    for ax in (axes[0, 2], axes[1, 0], axes[1, 1]):
        ax.set_yscale("log")
    axes[0, 0].set_ylabel("χ² per value")
    _history_axes(axes[1, 2], d.history)
    fig.tight_layout()
    return fig


def _history_axes(ax: Any, history: list[tuple[str, float, float]]) -> None:
    names = [h[0] for h in history]
    chi = [h[2] for h in history]
    ax.bar(range(len(names)), chi, color=["tab:red"] + ["tab:green"] * (len(names) - 1))
    ax.axhline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xticks(range(len(names)), names, rotation=30, fontsize=8, ha="right")
    ax.set_title("the fit: χ²/dof as effects are added")
    for i, (_, rms, c) in enumerate(history):
        ax.text(i, c, f"{c:.3f}\n{rms:.1f} DN", ha="center", va="bottom", fontsize=7)


def figure_fit(d: Diagnosis) -> Any:
    """Measured and predicted along the row through the worst baseline frame's worst pixel."""
    import matplotlib.pyplot as plt

    loc: Location = d.baseline_location
    f = int(np.argmax(loc.by_frame))
    r = int(np.unravel_index(int(np.argmax(loc.excess_map)), loc.excess_map.shape)[0])
    meas = d.data.measured_dn[f, r]
    chans = list(d.data.profile.sensor.channels)
    fig, axes = plt.subplots(1, len(chans), figsize=(13, 3.2), squeeze=False)
    for c, ax in enumerate(axes[0]):
        ax.plot(meas[:, c], ".", ms=3, color="k", label="measured")
        ax.plot(d.baseline_pred_dn[f, r, :, c], "-", color="tab:red", lw=1, label="baseline")
        ax.plot(d.final_pred_dn[f, r, :, c], "-", color="tab:green", lw=1, label="fitted")
        ax.set_title(f"frame '{d.data.labels[f]}', row {r}, channel {chans[c]}")
        ax.set_xlabel("sensor column")
        ax.set_ylabel("DN")
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    return fig


FIGURES = (
    ("residual_maps", "Residual maps before and after (where the mismatch sits in space)", figure_residual_maps),
    ("where", "Where the mismatch sits: channel, scene, signal level, radius, spatial frequency; the fit",
     figure_where),
    ("fit_row", "The fit along one sensor row", figure_fit),
)


def write_pngs(d: Diagnosis, out_dir: Path) -> list[Path]:
    """The report's figures as PNG files ``<name>.png`` in ``out_dir``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for name, _title, make in FIGURES:
        fig = make(d)
        p = out_dir / f"{name}.png"
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=60, bbox_inches="tight")
        plt.close(fig)
        buf.seek(0)
        from PIL import Image

        # a 64-colour palette keeps the files small enough for the docs
        Image.open(buf).convert("RGB").quantize(64).save(p, optimize=True)
        paths.append(p)
    return paths


def _excess_threshold() -> float:
    """σ above its noise-only expectation beyond which a check's χ² is "in excess" (the
    unbinned stage's own threshold)."""
    from thintact_sdk.diagnosis.imaging.unbinned import EXCESS_Z

    return float(EXCESS_Z)


def _z_of(chi2_per_dof: float, n_values: int) -> float:
    """σ of ``chi2_per_dof`` over ``n_values`` values from the noise-only expectation 1."""
    return (chi2_per_dof - 1.0) * math.sqrt(max(n_values, 1) / 2.0)


def check_rows(rep: dict[str, Any], n_unbinned_values: int | None = None) -> list[dict[str, Any]]:
    """The full-size and window checks of ``report.json`` (``full_size``,
    ``binned.unbinned_stage.before``) as table rows ``{"check", "chi2_per_dof", "rms_dn",
    "z", "z_approx", "values", "where", "verdict"}``.

    ``z`` is the χ² excess in standard deviations ``√(2n)`` over ``n`` values: as reported
    (windows, the unbinned stage) or, for the whole sensor's check, from
    ``n_unbinned_values`` (frames × pixels × channels of the unbinned recording, an upper
    bound when pixels saturate: ``z_approx`` True); None when neither is known. The verdict:
    "not evaluated" (with the reason), "consistent with the noise" (|z| within the unbinned
    stage's threshold), "in excess" or, without a ``z``, the χ²/dof alone.
    """
    thr = _excess_threshold()
    rows: list[dict[str, Any]] = []

    def verdict(chi: float, z: float | None) -> str:
        if z is None:
            return f"χ²/dof {chi:.4f} (value count unknown: no σ)"
        if z > thr:
            return f"in excess: {z:.1f} σ above the noise (threshold {thr:g} σ)"
        return f"consistent with the noise ({z:+.1f} σ, threshold {thr:g} σ)"

    def add(name: str, entry: Any, z: float | None, approx: bool, values: int | None, where: str) -> None:
        if not isinstance(entry, dict):
            return
        if "not_evaluated" in entry and "chi2_per_dof" not in entry:
            rows.append({"check": name, "chi2_per_dof": None, "rms_dn": None, "z": None, "z_approx": False,
                         "values": None, "where": where, "verdict": f"not evaluated: {entry['not_evaluated']}"})
            return
        chi, rms = float(entry["chi2_per_dof"]), float(entry["rms_dn"])
        rows.append({"check": name, "chi2_per_dof": chi, "rms_dn": rms, "z": z, "z_approx": approx,
                     "values": values, "where": where, "verdict": verdict(chi, z)})

    stage = rep.get("binned", {}).get("unbinned_stage") or {}
    full = rep.get("full_size") or {}
    if stage.get("before"):
        add("whole unbinned sensor, binned model (before the unbinned stage)", stage["before"],
            float(stage["excess_z"]), False, n_unbinned_values, "every unbinned frame")
    if "final" in full:
        fin = full["final"]
        z = None if n_unbinned_values is None else _z_of(float(fin["chi2_per_dof"]), n_unbinned_values)
        add("whole unbinned sensor, final model", fin, z, z is not None, n_unbinned_values,
            "every unbinned frame")
    elif "not_evaluated" in full:
        add("whole unbinned sensor, final model", {"not_evaluated": full["not_evaluated"]}, None, False, None, "")
    win = full.get("windows")
    if isinstance(win, dict):
        if "not_evaluated" in win:
            add("windows of the unbinned sensor", win, None, False, None, "")
        else:
            add("windows of the unbinned sensor", win, float(win["excess_z"]), False,
                int(win["n_values"]), str(win.get("where", "")))
    return rows


def checks_html(rep: dict[str, Any], n_unbinned_values: int | None = None) -> str:
    """The "Full-size and window checks" section (empty when ``report.json`` has none)."""
    rows = check_rows(rep, n_unbinned_values)
    if not rows:
        return ""
    e = html.escape

    def num(v: float | None, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    body = "".join(
        f"<tr><td>{e(r['check'])}</td><td>{num(r['chi2_per_dof'], '.4f')}</td><td>{num(r['rms_dn'], '.2f')}</td>"
        f"<td>{'-' if r['z'] is None else ('≈' if r['z_approx'] else '') + format(r['z'], '+.1f')}</td>"
        f"<td>{'-' if r['values'] is None else ('≤ ' if r['z_approx'] else '') + format(r['values'], ',d')}</td>"
        f"<td>{e(r['where']) or '-'}</td><td>{e(r['verdict'])}</td></tr>"
        for r in rows
    )
    return ("<h2>Full-size and window checks</h2><p>The fit was made on binned data; these checks evaluate "
            "it on the unbinned recording (σ: the χ² excess over its noise-only expectation, in standard "
            "deviations √(2n) over n values).</p><table><tr><th>check</th><th>χ²/dof</th><th>rms (DN)</th>"
            f"<th>σ</th><th>values</th><th>where</th><th>verdict</th></tr>{body}</table>")


def _unbinned_values(d: Diagnosis) -> int | None:
    """Frames × pixels × channels of the unbinned recording of a binned diagnosis (None unbinned)."""
    if not d.report.get("binned", {}).get("factor"):
        return None
    full = d.fitted_profile.sensor  # the CLI gives a binned diagnosis the unbinned device's profile
    return int(d.data.n_frames * full.rows * full.cols * len(full.channels))


def render_html(d: Diagnosis) -> str:
    """The whole ``report.html`` as a string."""
    import matplotlib

    matplotlib.use("Agg")
    rep = d.report
    figs = [(title, make(d)) for _name, title, make in FIGURES]
    e = html.escape
    rows = "".join(
        f"<tr><td>{e(f['effect'])}</td><td><code>{e(json.dumps(f['params']))}</code></td>"
        f"<td>{f['rms_dn_after']:.2f}</td><td>{f['chi2_per_dof_after']:.3f}</td>"
        f"<td>{e(', '.join(f['alternatives']) or '-')}</td><td>{e(f['evidence'])}</td></tr>"
        for f in rep["findings"]
    ) or "<tr><td colspan=6>no effect clears the criterion: the simulation explains the recording</td></tr>"
    imgs = "".join(
        f"<h2>{e(t)}</h2><img src='data:image/png;base64,{_png(fig)}' alt='{e(t)}'>" for t, fig in figs
    )
    un = rep["unexplained"]
    timing = ", ".join(f"{k} {v:.1f}" for k, v in d.timing_s.items())
    return f"""<!doctype html><html><head><meta charset="utf-8"><title>ThinTact diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1300px;margin:auto}}td,th{{border:1px solid #ccc;
padding:4px;vertical-align:top}}table{{border-collapse:collapse}}img{{max-width:100%}}</style></head>
<body><h1>Diagnosis of {e(str(d.data.profile.name))}: {d.data.n_frames} frames</h1>
<p>Noise rms {rep['noise_rms_dn']:.2f} DN. Baseline rms {rep['baseline']['rms_dn']:.2f} DN,
χ²/dof {rep['baseline']['chi2_per_dof']:.3f} &rarr; final rms {rep['final']['rms_dn']:.2f} DN,
χ²/dof {rep['final']['chi2_per_dof']:.3f}.</p>
<h2>Where</h2><p>{e(rep['located']['summary'])}</p>
<h2>Findings</h2><table><tr><th>effect</th><th>parameters</th><th>rms after (DN)</th>
<th>χ²/dof after</th><th>alternatives</th><th>evidence</th></tr>{rows}</table>
<h2>Unexplained</h2><p><b>{'significant' if un['significant'] else 'none'}</b>: {e(un['summary'])}</p>
{checks_html(rep, _unbinned_values(d))}
{imgs}
<p><small>timing (s): {e(timing)}</small></p></body></html>
"""


def write_html(d: Diagnosis, path: Path) -> Path:
    """Write ``report.html``; returns its path."""
    path.write_text(render_html(d), encoding="utf-8")
    return path
