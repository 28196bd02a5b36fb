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
 header {{ height: {header_px}px; display: flex; align-items: center; gap: 12px; padding: 0 8px;
          white-space: nowrap; overflow: hidden; box-sizing: border-box; }}
 .live {{ display: block; }}
 button {{ background: #33333b; color: #ebebeb; border: 1px solid #555; padding: 4px 10px; }}
 button.on {{ background: #a02828; }}
 .stats, .msg {{ font-family: monospace; }}
</style></head>
<body>
{groups}
<script nonce="{nonce}">
const TOKEN = document.querySelector('meta[name="thintact-token"]').content;
function post(path) {{
  return fetch(path, {{method: "POST", headers: {{"X-ThinTact-Token": TOKEN}}, cache: "no-store"}});
}}
async function act(k, path, done) {{
  const msg = document.getElementById("msg-" + k);
  try {{
    const r = await post(path + "?sensor=" + k);
    const text = await r.text();
    let body = null;
    try {{ body = JSON.parse(text); }} catch (e) {{ }}
    msg.textContent = !r.ok ? (body && body.error ? body.error : text) : done(body);
    return r.ok;
  }} catch (e) {{ msg.textContent = "viewer stopped"; return false; }}
}}
function setup(k) {{
  const img = document.getElementById("live-" + k);
  const stats = document.getElementById("stats-" + k);
  const rec = document.getElementById("record-" + k);
  let seq = -1;
  async function next() {{
    try {{
      const r = await fetch("/frame.jpg?sensor=" + k + "&after=" + seq, {{cache: "no-store"}});
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
      const s = await (await fetch("/stats.json?sensor=" + k, {{cache: "no-store"}})).json();
      const f = v => v === null ? "-" : v.toFixed(1);
      stats.textContent = s.error ? s.error :
        `frame ${{s.frame_id}} | sensor ${{f(s.sensor_fps)}} fps | served ${{f(s.served_fps)}} fps` +
        ` | latency ${{f(s.latency_ms)}} ms | processing ${{f(s.processing_ms)}} ms`;
      const active = !!(s.recording && s.recording.active);
      rec.classList.toggle("on", active);
      rec.textContent = active ? `stop recording (${{s.recording.frames}})` : "record";
    }} catch (e) {{ stats.textContent = "viewer stopped"; }}
    setTimeout(poll, 500);
  }}
  document.getElementById("reset-" + k).onclick = () => act(k, "/reset", () => "reference reset");
  document.getElementById("snapshot-" + k).onclick =
    () => act(k, "/snapshot", b => "saved " + b.files.join(", "));
  rec.onclick = () => rec.classList.contains("on")
    ? act(k, "/record/stop", b => `saved ${{b.frames}} frames in ${{b.path}}`)
    : act(k, "/record/start", b => "recording into " + b.path).then(ok => ok && rec.classList.add("on"));
  img.addEventListener("load", () => {{ if (seq < 0) {{ seq = 0; next(); }} }}, {{once: true}});
  poll();
}}
for (let k = 0; k < {count}; k++) setup(k);
</script>
</body></html>
"""

_GROUP = """<section id="sensor-{k}">
<header><strong>{title}</strong>
<button id="reset-{k}" title="the membrane must be free">reset reference</button>
<button id="snapshot-{k}" title="reconstruction PNG and depth .npy">snapshot</button>
<button id="record-{k}" title="record the live frames">record</button>
<span class="msg" id="msg-{k}"></span><span class="stats" id="stats-{k}">connecting…</span></header>
<img class="live" id="live-{k}" src="/frame.jpg?sensor={k}" alt="live tactile dashboard of {title}">
</section>"""


def page_html(titles: str | list[str], token: str, nonce: str) -> str:
    """The page showing one panel group per sensor, titled ``titles`` (one per sensor).

    ``token`` is the server's secret, which the page's script sends back in the
    ``X-ThinTact-Token`` header of every state-changing request; ``nonce`` is the
    Content-Security-Policy nonce of the page's inline script and style. Sensor ``k``'s
    dashboard image (``id="live-k"``) sits :data:`HEADER_PX` below its group's top, the
    groups one under the other.
    """
    names = [titles] if isinstance(titles, str) else list(titles)
    groups = "\n".join(_GROUP.format(k=k, title=html.escape(t)) for k, t in enumerate(names))
    return _PAGE.format(title=html.escape(" | ".join(names)), header_px=HEADER_PX, groups=groups,
                        count=len(names), token=html.escape(token, quote=True),
                        nonce=html.escape(nonce, quote=True))
