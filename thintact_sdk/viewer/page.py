"""The viewer's HTML page (no external resources: it works offline on loopback).

The page carries the server's token (``<meta name="thintact-token">``) and its script
sends it back on every state-changing request (docs/viewer.md#security).

The dashboard image sits at the page's left edge, :data:`HEADER_PX` below its top.
"""

from __future__ import annotations

import html

HEADER_PX = 40

_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<meta name="thintact-token" content="{token}">
<style nonce="{nonce}">
 body {{ margin: 0; background: #18181c; color: #ebebeb; font: 14px sans-serif; }}
 header {{ height: {header_px}px; display: flex; align-items: center; gap: 16px; padding: 0 8px;
          white-space: nowrap; overflow: hidden; box-sizing: border-box; }}
 #live {{ display: block; }}
 button {{ background: #33333b; color: #ebebeb; border: 1px solid #555; padding: 4px 10px; }}
 #stats {{ font-family: monospace; }}
</style></head>
<body>
<header><strong>{title}</strong><span id="stats">connecting…</span>
<button id="reset" title="the membrane must be free">reset reference</button></header>
<img id="live" src="/frame.jpg" alt="live tactile dashboard">
<script nonce="{nonce}">
const TOKEN = document.querySelector('meta[name="thintact-token"]').content;
const img = document.getElementById("live");
const stats = document.getElementById("stats");
let seq = -1;
async function next() {{
  try {{
    const r = await fetch("/frame.jpg?after=" + seq, {{cache: "no-store"}});
    if (r.ok) {{
      seq = parseInt(r.headers.get("X-Frame-Seq"));
      const url = URL.createObjectURL(await r.blob());
      img.onload = () => URL.revokeObjectURL(url);
      img.src = url;
    }} else {{ await new Promise(ok => setTimeout(ok, 500)); }}
  }} catch (e) {{ await new Promise(ok => setTimeout(ok, 1000)); }}
  setTimeout(next, 0);
}}
async function poll() {{
  try {{
    const s = await (await fetch("/stats.json", {{cache: "no-store"}})).json();
    const f = v => v === null ? "-" : v.toFixed(1);
    stats.textContent = s.error ? s.error :
      `frame ${{s.frame_id}} | sensor ${{f(s.sensor_fps)}} fps | served ${{f(s.served_fps)}} fps` +
      ` | latency ${{f(s.latency_ms)}} ms | processing ${{f(s.processing_ms)}} ms`;
  }} catch (e) {{ stats.textContent = "viewer stopped"; }}
  setTimeout(poll, 500);
}}
function post(path) {{
  return fetch(path, {{method: "POST", headers: {{"X-ThinTact-Token": TOKEN}}, cache: "no-store"}});
}}
document.getElementById("reset").onclick = () => post("/reset");
img.addEventListener("load", () => {{ if (seq < 0) {{ seq = 0; next(); }} }}, {{once: true}});
poll();
</script>
</body></html>
"""


def page_html(title: str, token: str, nonce: str) -> str:
    """The page for a viewer titled ``title``.

    ``token`` is the server's secret, which the page's script sends back in the
    ``X-ThinTact-Token`` header of every state-changing request; ``nonce`` is the
    Content-Security-Policy nonce of the page's inline script and style.
    """
    return _PAGE.format(title=html.escape(title), header_px=HEADER_PX,
                        token=html.escape(token, quote=True), nonce=html.escape(nonce, quote=True))
