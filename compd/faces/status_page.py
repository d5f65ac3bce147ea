"""The operator page: one HTML document, its style and script inline.

No external asset (a shop PC has no internet): the plot is a canvas drawn by
the inline script from /status.json's history. The first document is
inlined as JSON so that the page shows the state before its first fetch;
the script then fetches /status.json every ``refresh_s`` and redraws. A
fetch that fails marks the page "no answer from compd" instead of showing
old values as live; so does a snapshot older than three periods (a stalled
loop). With ``[output.axes]`` a table shows each axis's line: in force or
not (and why), its value and slope (and what the controller holds when it
differs) at its reference position, and for an axis written as one offset at
its read position the offset sent and the position it was evaluated at. A
fleet's document (``machines``: `compd run DIR`) shows one section per machine,
the same as one machine's.
"""

from __future__ import annotations

import html
import json
from typing import Any

__all__ = ["render_page"]

_STYLE = """
body{font-family:sans-serif;margin:0;padding:1em 2em;background:#f4f4f4;color:#111}
h1{font-size:1.3em;font-weight:normal;margin:.6em 0 .4em 0}
section{border-bottom:2px solid #ccc;padding-bottom:1em;margin-bottom:1em}
.state{font-size:5em;font-weight:bold;padding:.1em .4em;border-radius:.15em;
 display:inline-block;color:#fff;background:#777}
.state.on{background:#1b7a2e}.state.holding,.state.limited{background:#b8860b}
.state.ramping{background:#c05a00}.state.degraded{background:#8a6d00}.state.off{background:#b00020}
.state.dry-run{background:#fff;color:#2a4d8f;border:.08em dashed #2a4d8f}
.why{font-size:1.5em;margin:.4em 0 .8em 0}
.big{font-size:2.2em}
table{border-collapse:collapse;font-size:1.3em;margin:.5em 0}
td,th{padding:.2em .8em;border-bottom:1px solid #ccc;text-align:left}
.bad{color:#b00020;font-weight:bold}.good{color:#1b7a2e}
#stale{color:#b00020;font-weight:bold;font-size:1.3em}
canvas{background:#fff;border:1px solid #ccc;width:100%;max-width:1000px;height:260px}
.small{color:#555;font-size:.9em}
"""

_SCRIPT = """
const REFRESH_MS = Math.max(1000, REFRESH_S * 1000);
function fmt(x, d){ return (x === null || x === undefined) ? "\\u2014" : Number(x).toFixed(d); }
const UNITS = {degC: "\\u00b0C", um: "\\u00b5m", K: "K"};
function unit(u){ return UNITS[u] || u; }
function digits(u){ return u === "rpm" ? 0 : 2; }
function niceStep(span, n){ const raw = span / n, p = Math.pow(10, Math.floor(Math.log10(raw)));
  for (const m of [1, 2, 2.5, 5, 10]) if (m * p >= raw) return m * p; return 10 * p; }
function ticks(lo, hi, n){ const s = niceStep(hi - lo, n), out = [];
  for (let v = Math.ceil(lo / s) * s; v <= hi + s * 1e-9; v += s)
    out.push(Math.abs(v) < s * 1e-9 ? 0 : v);
  return {step: s, values: out}; }
function stepDigits(step){ let d = 0;
  while (d < 10 && Math.abs(step * Math.pow(10, d) - Math.round(step * Math.pow(10, d))) >
    1e-6 * step * Math.pow(10, d)) d++;
  return d; }
function two(n){ return String(n).padStart(2, "0"); }
function clock(s){ const d = new Date(s * 1000);
  return two(d.getHours()) + ":" + two(d.getMinutes()) + ":" + two(d.getSeconds()); }
function stamp(s){ const d = new Date(s * 1000);
  return d.getFullYear() + "-" + two(d.getMonth() + 1) + "-" + two(d.getDate()) + " " + clock(s); }
function add(parent, tag, cls, text){ const e = document.createElement(tag);
  if (cls) e.className = cls; if (text !== undefined) e.textContent = text;
  parent.appendChild(e); return e; }
function row(tbody, cells){ const tr = add(tbody, "tr");
  for (const [text, cls] of cells) add(tr, "td", cls || "", text); }
function section(i){ let s = document.getElementById("m" + i); if (s) return s;
  s = add(document.getElementById("machines"), "section"); s.id = "m" + i;
  for (const [tag, cls] of [["h1", "machine"], ["div", "state"], ["div", "why"],
      ["div", "out"], ["div", "small modelref"],
      ["h2", ""], ["table", "channels"], ["h2", "axeslabel"], ["table", "axes"],
      ["h2", "plotlabel"],
      ["canvas", "plot"], ["h2", ""], ["table", "alarms"], ["p", "small updated"]])
    add(s, tag, cls);
  const h = s.querySelectorAll("h2"); h[0].textContent = "Channels";
  h[1].textContent = "Axes"; h[2].textContent = "Offset and model output";
  h[3].textContent = "Last alarms";
  for (const t of ["channels", "axes", "alarms"]) add(s.querySelector("table." + t), "tbody");
  return s; }
function showMachine(s, m){
  const q = c => s.querySelector(c);
  q(".machine").textContent = (m.machine || "compd") + " \\u00b7 model " + (m.model || "?")
    + (m.fallback_for ? " \\u00b7 FALLBACK without " + m.fallback_for : "");
  const st = q(".state"); st.textContent = m.state; st.className = "state " + m.state;
  q(".why").textContent = m.why + (m.cause && m.healthy === false ? " [" + m.cause + "]" : "");
  const out = q(".out"); out.textContent = "";
  add(out, "span", "big offset", fmt(m.offset_um, 2) + " \\u00b5m");
  if (!m.recorder_only && m.confirmed_um !== m.offset_um)
    add(out, "span", "confirmed", " (sent; the controller holds " +
      (m.confirmed_um === null || m.confirmed_um === undefined ? "an unconfirmed offset"
       : fmt(m.confirmed_um, 2) + " \\u00b5m") + ")");
  add(out, "span", "limit", "   limit \\u00b1" + fmt(m.limit_um, 1) + " \\u00b5m \\u00b7");
  add(out, "span", "model_um", " model output " + fmt(m.model_um, 2) + " \\u00b5m");
  if (m.pending_um !== null && m.pending_um !== undefined)
    add(out, "span", "pending", " \\u00b7 " + fmt(m.pending_um, 2) +
      " \\u00b5m pending (waiting for permission)");
  const ref = m.reference && m.reference.temperatures_c ?
    Object.entries(m.reference.temperatures_c).map(([k, v]) => k + " " + fmt(v, 2) +
      " \\u00b0C").join(", ") : "";
  q(".modelref").textContent = (m.recorder_only ? "recorder only: nothing is written" +
      " \\u00b7 " : "") + (m.model_start ? "model started: " + m.model_start : "") +
    (ref ? " \\u00b7 reference (" + (m.reference.source || "?") + "): " + ref : "") +
    (m.zero_um !== null && m.zero_um !== undefined ? " \\u00b7 re-zeroed at " +
      fmt(m.zero_um, 2) + " \\u00b5m" : "");
  const tb = q("table.channels tbody"); tb.textContent = "";
  for (const c of m.channels || []) row(tb, [[c.name, "name"],
    [fmt(c.value, digits(c.unit)) + " " + unit(c.unit), "value"],
    [c.valid ? "valid" : ("invalid: " + c.reason), c.valid ? "good valid" : "bad valid"]]);
  const axes = Object.entries(m.axes || {}), ax = q("table.axes tbody");
  ax.textContent = "";
  q("table.axes").style.display = q(".axeslabel").style.display = axes.length ? "" : "none";
  for (const [name, a] of axes) row(ax, [[name.toUpperCase(), "name"],
    [a.in_force ? "in force" : "not in force", a.in_force ? "good inforce" : "bad inforce"],
    [a.state + (a.in_force ? "" : " [" + a.cause + "]"), "axisstate"],
    [fmt(a.value_um, 2) + " \u00b5m" + (a.value_confirmed_um !== a.value_um ?
      " (holds " + fmt(a.value_confirmed_um, 2) + ")" : ""), "value"],
    [fmt(a.slope_um_m, 2) + " \u00b5m/m" + (a.slope_confirmed_um_m !== a.slope_um_m ?
      " (holds " + fmt(a.slope_confirmed_um_m, 2) + ")" : ""), "slope"],
    ["at " + fmt(a.reference_mm, 1) + " mm", "reference"],
    ...(a.position_mm === undefined ? [] : [[fmt(a.offset_um, 2) + " \u00b5m at " +
      fmt(a.position_mm, 1) + " mm", "position"]])]);
  const al = q("table.alarms tbody"); al.textContent = "";
  const alarms = (m.alarms || []).slice().reverse();
  if (!alarms.length) row(al, [["none"]]);
  for (const a of alarms) row(al, [[stamp(a.wall_s)],
    [a.event, a.level === "error" ? "bad" : ""],
    [Object.entries(a.detail || {}).map(([k, v]) => k + "=" + v).join(" ")]]);
  const late = m.age_s !== null && m.age_s !== undefined && m.period_s &&
    m.age_s > 3 * m.period_s + 2;
  q(".updated").textContent = (m.wall_s ? "cycle " + m.sequence + " at " +
    clock(m.wall_s) : "") +
    (late ? " \u2014 NO CYCLE FOR " + fmt(m.age_s, 0) + " s: the values are old" : "");
  q(".updated").className = late ? "bad updated" : "small updated";
  const cv = q("canvas.plot"), shown = m.history !== null && m.history !== undefined;
  cv.style.display = q(".plotlabel").style.display = shown ? "" : "none";
  if (shown) plot(cv, m.history, m.limit_um);
}
function plot(cv, h, limit){
  const W = cv.width = cv.clientWidth, H = cv.height = cv.clientHeight;
  const g = cv.getContext("2d"); g.clearRect(0, 0, W, H);
  const L = 60, R = 10, T = 24, B = 25, t = h.wall_s;
  g.font = "12px sans-serif"; g.fillStyle = "#333";
  if (!t.length) { g.fillText(h.error || "no history yet", L, H / 2); return; }
  const vals = h.offset_um.concat(h.model_um).filter(v => v !== null);
  let lo = Math.min(0, ...vals), hi = Math.max(0, ...vals);
  if (hi - lo < 1) { hi += 0.5; lo -= 0.5; }
  const pad = (hi - lo) * 0.1; lo -= pad; hi += pad;
  const t0 = t[0], t1 = Math.max(t[t.length - 1], t0 + 1);
  const X = v => L + (v - t0) / (t1 - t0) * (W - L - R);
  const Y = v => T + (hi - v) / (hi - lo) * (H - T - B);
  g.strokeStyle = "#ddd"; g.beginPath();
  const yt = ticks(lo, hi, 5), yd = stepDigits(yt.step);
  for (const v of yt.values) { g.moveTo(L, Y(v)); g.lineTo(W - R, Y(v));
    g.fillText(v.toFixed(yd), 5, Y(v) + 4); }
  g.stroke(); g.fillText("\\u00b5m", 5, 12);
  for (let i = 0; i <= 4; i++) { const v = t0 + (t1 - t0) * i / 4;
    g.textAlign = i === 0 ? "left" : (i === 4 ? "right" : "center");
    g.fillText(clock(v), i === 4 ? W - R : X(v), H - 6); }
  g.textAlign = "left";
  function line(ys, color, dash){ g.strokeStyle = color; g.lineWidth = 2; g.setLineDash(dash);
    g.beginPath(); let up = false;
    for (let i = 0; i < t.length; i++) { const y = ys[i];
      if (y === null) { up = false; continue; }
      if (up) g.lineTo(X(t[i]), Y(y)); else g.moveTo(X(t[i]), Y(y)); up = true; }
    g.stroke(); g.setLineDash([]); }
  g.strokeStyle = "#b00020"; g.lineWidth = 1; g.setLineDash([2, 3]); g.beginPath();
  let drawn = 0;
  for (const v of [limit, -limit])
    if (v > lo && v < hi) { g.moveTo(L, Y(v)); g.lineTo(W - R, Y(v)); drawn++; }
  g.stroke(); g.setLineDash([]);
  line(h.model_um, "#e07000", [6, 4]); line(h.offset_um, "#0050c0", []);
  const keys = [["\\u2014 offset confirmed", "#0050c0"], ["- - model output", "#e07000"]];
  if (limit !== null && limit !== undefined) keys.push([drawn ? ".... \\u00b1 limit" :
    "\\u00b1 limit " + fmt(limit, 1) + " \\u00b5m: off scale", "#b00020"]);
  g.textAlign = "right"; let x = W - R;
  for (const [text, color] of keys.reverse()) {
    g.fillStyle = color; g.fillText(text, x, 12); x -= g.measureText(text).width + 16; }
  g.textAlign = "left";
}
function show(doc){ const list = doc.machines || [doc];
  list.forEach((m, i) => showMachine(section(i), m));
  for (let i = list.length; document.getElementById("m" + i); i++)
    document.getElementById("m" + i).remove();
  document.body.dataset.updates = String(Number(document.body.dataset.updates || 0) + 1); }
async function refresh(){
  try { const r = await fetch("status.json", {cache: "no-store"});
    if (!r.ok) throw new Error("HTTP " + r.status);
    show(await r.json()); document.getElementById("stale").textContent = ""; }
  catch (e) { document.getElementById("stale").textContent =
    "no answer from compd (" + e.message + ") \\u2014 the values below are old"; }
}
show(FIRST); refresh(); setInterval(refresh, REFRESH_MS);
"""

_BODY = """<div id="stale"></div>
<div id="machines"></div>
<p class="small">Read-only, refreshed every <span id="every"></span> s ·
<a href="status.json">status.json</a> · <a href="metrics">metrics</a></p>
"""


def _inline_json(value: Any) -> str:
    """JSON safe inside a <script> element (no "</script>", no HTML comment)."""
    text = json.dumps(value)
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def render_page(document: dict[str, Any], refresh_s: float) -> str:
    """The page, with `document` (one machine's or a fleet's) shown before the first fetch."""
    if "machines" in document:
        title = f"{len(document['machines'])} machines"
    else:
        title = str(document.get("machine") or "starting")
    body = _BODY.replace('<span id="every"></span>', f"{float(refresh_s):g}")
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>compd · {html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body>"
            f"{body}"
            f"<script>const FIRST = {_inline_json(document)};\n"
            f"const REFRESH_S = {float(refresh_s)!r};\n{_SCRIPT}</script></body></html>\n")
