"""One self-contained HTML page: headings, words, tables and interactive plots, all inline.

No file beside it, no network: the style sheet and the script are in the page, each plot's data
is a JSON island the script draws as SVG (hover shows the values under the pointer, dragging
across a plot zooms its time axis, a double click resets it). The page is readable in any
browser offline; without a script it still shows the words and tables.
"""

from __future__ import annotations

import html
import math
import re
from collections.abc import Sequence
from typing import Any

from drivers.recording import dumps_strict

__all__ = ["MAX_POINTS", "Page", "decimate"]

# At most this many points a series is drawn with: a long recording is cut into buckets and
# each keeps its minimum and maximum, so peaks survive (the page stays small).
MAX_POINTS = 2000
# A table cell that reads as a number (or numbers: "0.26 % / 0.57 %", "n/i") is right-aligned.
NUMBER = re.compile(r"^(n/i|–|[-+]?[\d.]+)")

STYLE = """
body{font:15px/1.45 system-ui,sans-serif;margin:0 auto;max-width:1100px;padding:1em 2em;
color:#1b1b1b}
h1{font-size:1.6em;margin-bottom:.2em}h2{margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
td,th{border:1px solid #ccc;padding:.2em .55em;text-align:right;vertical-align:top}
th{background:#f2f2f2}td.t,th.t{text-align:left}
.plot{position:relative;margin:.8em 0 1.4em}.plot svg{width:100%;height:auto;
border:1px solid #ddd;background:#fff;user-select:none}
.plot .tip{position:absolute;pointer-events:none;background:rgba(255,255,255,.95);
border:1px solid #999;padding:.2em .45em;font-size:.85em;display:none;white-space:nowrap}
.legend span{margin-right:1.2em;font-size:.9em}.legend i{display:inline-block;width:1.4em;
height:.25em;vertical-align:middle;margin-right:.3em}
.note{color:#555;font-size:.9em}details{margin:.6em 0}pre{white-space:pre-wrap}
"""

# Draws every <figure class="plot"> from its JSON island; hover and zoom. Errors go to the
# console (and so fail the report's test), nothing is fetched.
SCRIPT = r"""
(function(){
const NS='http://www.w3.org/2000/svg',W=900,H=300,L=70,R=15,T=12,B=42;
const COLORS=['#1f77b4','#d62728','#2ca02c','#ff7f0e','#9467bd','#8c564b','#e377c2','#17becf'];
function el(n,a,p){const e=document.createElementNS(NS,n);for(const k in a)e.setAttribute(k,a[k]);
if(p)p.appendChild(e);return e;}
function ticks(lo,hi,n){const s=Math.pow(10,Math.floor(Math.log10((hi-lo)/n||1)));
const st=[1,2,5,10].map(m=>m*s).find(x=>(hi-lo)/x<=n)||10*s;const out=[];
for(let v=Math.ceil(lo/st)*st;v<=hi+1e-9*st;v+=st)out.push(+v.toPrecision(12));return out;}
function fmt(v){return Math.abs(v)>=1e4||(v!==0&&Math.abs(v)<1e-3)?v.toExponential(3):
+v.toPrecision(4)+'';}
function draw(fig){
 const d=JSON.parse(fig.querySelector('script').textContent);
 const svg=el('svg',{viewBox:`0 0 ${W} ${H}`},null);fig.insertBefore(svg,fig.firstChild);
 const tip=document.createElement('div');tip.className='tip';fig.appendChild(tip);
 const all=d.series.flatMap(s=>s.x);const x0=Math.min(...all),x1=Math.max(...all);
 const pd=d.kind==='points'?0.5:0,full=[x0-pd,x1+pd];let view=full.slice();
 function render(){
  while(svg.firstChild)svg.removeChild(svg.firstChild);
  let ylo=Infinity,yhi=-Infinity;
  for(const s of d.series)for(let i=0;i<s.x.length;i++)if(s.x[i]>=view[0]&&s.x[i]<=view[1]&&
   s.y[i]!==null){ylo=Math.min(ylo,s.y[i]);yhi=Math.max(yhi,s.y[i]);}
  if(!isFinite(ylo)){ylo=-1;yhi=1;}if(ylo===yhi){ylo-=1;yhi+=1;}
  const pad=(yhi-ylo)*0.05;ylo-=pad;yhi+=pad;
  const sx=x=>L+(x-view[0])/(view[1]-view[0]||1)*(W-L-R),sy=y=>H-B-(y-ylo)/(yhi-ylo)*(H-T-B);
  for(const v of ticks(ylo,yhi,6)){el('line',{x1:L,x2:W-R,y1:sy(v),y2:sy(v),stroke:'#eee'},svg);
   el('text',{x:L-6,y:sy(v)+4,'text-anchor':'end','font-size':11},svg).textContent=fmt(v);}
  for(const v of ticks(view[0],view[1],9).filter(v=>!pd||Number.isInteger(v))){
   el('line',{x1:sx(v),x2:sx(v),y1:T,y2:H-B,stroke:'#eee'},svg);el('text',{x:sx(v),y:H-B+15,'text-anchor':'middle','font-size':11},svg)
   .textContent=fmt(v);}
  el('rect',{x:L,y:T,width:W-L-R,height:H-T-B,fill:'none',stroke:'#999'},svg);
  el('text',{x:(L+W-R)/2,y:H-6,'text-anchor':'middle','font-size':12},svg).textContent=d.x_label;
  el('text',{x:14,y:(T+H-B)/2,'text-anchor':'middle','font-size':12,
   transform:`rotate(-90 14 ${(T+H-B)/2})`},svg).textContent=d.y_label;
  const clip='c'+Math.random().toString(36).slice(2);
  el('rect',{x:L,y:T,width:W-L-R,height:H-T-B},el('clipPath',{id:clip},el('defs',{},svg)));
  d.series.forEach((s,k)=>{const pts=[];for(let i=0;i<s.x.length;i++)if(s.y[i]!==null)
   pts.push(sx(s.x[i]).toFixed(1)+','+sy(s.y[i]).toFixed(1));
   el('polyline',{points:pts.join(' '),fill:'none',
   stroke:COLORS[k%COLORS.length],'stroke-width':d.kind==='points'?0:1.3,
   'clip-path':`url(#${clip})`},svg);
   if(d.kind==='points')for(const p of pts){const [a,b]=p.split(',');el('circle',{cx:a,cy:b,r:3.5,
    fill:COLORS[k%COLORS.length]},svg);}});
  const cur=el('line',{y1:T,y2:H-B,stroke:'#555','stroke-dasharray':'3,3',visibility:'hidden'},svg);
  const sel=el('rect',{y:T,height:H-T-B,fill:'rgba(31,119,180,.15)',visibility:'hidden'},svg);
  let start=null;
  const toX=e=>{const r=svg.getBoundingClientRect();return (e.clientX-r.left)/r.width*W;};
  const val=px=>view[0]+(px-L)/(W-L-R)*(view[1]-view[0]);
  svg.onmousemove=e=>{const px=toX(e);if(px<L||px>W-R){cur.setAttribute('visibility','hidden');
   tip.style.display='none';return;}const x=val(px);cur.setAttribute('x1',px);
   cur.setAttribute('x2',px);cur.setAttribute('visibility','visible');
   const rows=[`${d.x_label}: ${fmt(x)}`];
   d.series.forEach(s=>{let lo=0,hi=s.x.length-1;while(hi-lo>1){const m=(lo+hi)>>1;
    if(s.x[m]<x)lo=m;else hi=m;}const i=Math.abs(s.x[lo]-x)<=Math.abs(s.x[hi]-x)?lo:hi;
    if(s.y[i]!==null)rows.push(`${s.name}: ${fmt(s.y[i])}`);});
   tip.textContent='';rows.forEach(r=>{const div=document.createElement('div');div.textContent=r;
    tip.appendChild(div);});tip.style.display='block';
   const r=svg.getBoundingClientRect();tip.style.left=(px/W*r.width+12)+'px';tip.style.top='8px';
   if(start!==null){sel.setAttribute('x',Math.min(start,px));
    sel.setAttribute('width',Math.abs(px-start));sel.setAttribute('visibility','visible');}};
  svg.onmouseleave=()=>{cur.setAttribute('visibility','hidden');tip.style.display='none';};
  svg.onmousedown=e=>{start=toX(e);};
  svg.onmouseup=e=>{if(start===null)return;const a=val(Math.min(start,toX(e))),
   b=val(Math.max(start,toX(e)));start=null;if(b-a>(view[1]-view[0])*0.01){view=[a,b];render();}
   else sel.setAttribute('visibility','hidden');};
  svg.ondblclick=()=>{view=full.slice();render();};
 }
 render();
 const lg=document.createElement('div');lg.className='legend';
 d.series.forEach((s,k)=>{const sp=document.createElement('span');
  const i=document.createElement('i');i.style.background=COLORS[k%COLORS.length];
  sp.appendChild(i);sp.appendChild(document.createTextNode(s.name));lg.appendChild(sp);});fig.insertBefore(lg,svg.nextSibling);
}
document.querySelectorAll('figure.plot').forEach(draw);
document.body.dataset.plots=String(document.querySelectorAll('figure.plot svg').length);
})();
"""


def _cell(value: Any) -> str:
    """A table cell's text: numbers to 4 significant digits, None as a dash."""
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return "–" if not math.isfinite(value) else f"{value:.4g}"
    if isinstance(value, list) and all(isinstance(v, int | float) for v in value):
        return " / ".join(_cell(v) for v in value)
    return str(value)


def decimate(x: Sequence[float], y: Sequence[float | None]) -> tuple[list, list]:
    """At most :data:`MAX_POINTS` points of (x, y): each bucket's minimum and maximum of y, in
    time order (so a peak is kept however long the recording)."""
    n = len(x)
    if n <= MAX_POINTS:
        return list(x), list(y)
    buckets = MAX_POINTS // 2
    xs: list[float] = []
    ys: list[float | None] = []
    for b in range(buckets):
        lo, hi = b * n // buckets, (b + 1) * n // buckets
        part = [(y[i], i) for i in range(lo, hi) if y[i] is not None]
        if not part:
            continue
        for i in sorted({min(part)[1], max(part)[1]}):
            xs.append(x[i])
            ys.append(y[i])
    return xs, ys


def _number(v: Any) -> float | None:
    f = float(v)
    return round(f, 9) if math.isfinite(f) else None


class Page:
    """An HTML page built section by section; :meth:`render` returns the whole file."""

    def __init__(self, title: str) -> None:
        self.title = title
        self.parts: list[str] = [f"<h1>{html.escape(title)}</h1>"]

    def heading(self, text: str) -> None:
        self.parts.append(f"<h2>{html.escape(text)}</h2>")

    def paragraph(self, text: str, *, note: bool = False) -> None:
        cls = ' class="note"' if note else ""
        self.parts.append(f"<p{cls}>{html.escape(text)}</p>")

    def bullets(self, items: Sequence[str]) -> None:
        if items:
            lis = "".join(f"<li>{html.escape(i)}</li>" for i in items)
            self.parts.append(f"<ul>{lis}</ul>")

    def table(self, headers: Sequence[str], rows: Sequence[Sequence[Any]]) -> None:
        """A table; the first column left-aligned (a name), the others right (numbers)."""

        def cls(k: int, value: Any = None) -> str:
            words = isinstance(value, str) and not NUMBER.match(value)
            return ' class="t"' if k == 0 or words else ""

        head = "".join(f"<th{cls(k)}>{html.escape(str(h))}</th>" for k, h in enumerate(headers))
        body = "".join(
            "<tr>"
            + "".join(f"<td{cls(k, v)}>{html.escape(_cell(v))}</td>" for k, v in enumerate(row))
            + "</tr>"
            for row in rows
        )
        self.parts.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")

    def plot(
        self,
        title: str,
        x_label: str,
        y_label: str,
        series: Sequence[tuple[str, Sequence[float], Sequence[float]]],
        *,
        points: bool = False,
    ) -> None:
        """An interactive plot of ``(name, x, y)`` series (lines; ``points``: markers only)."""
        data = {"x_label": x_label, "y_label": y_label, "kind": "points" if points else "line"}
        data["series"] = []
        for name, x, y in series:
            xs, ys = decimate([float(v) for v in x], [_number(v) for v in y])
            data["series"].append({"name": name, "x": [round(v, 9) for v in xs], "y": ys})
        island = dumps_strict(data, separators=(",", ":")).replace("<", "\\u003c")  # no tag inside
        self.parts.append(
            f'<figure class="plot"><figcaption>{html.escape(title)}</figcaption>'
            f'<script type="application/json">{island}</script></figure>'
        )

    def preformatted(self, text: str) -> None:
        self.parts.append(f"<pre>{html.escape(text)}</pre>")

    def document(self, doc: Any, summary: str = "The whole JSON document") -> None:
        """The command's JSON document, folded: nested tables of every field."""
        self.parts.append(f"<details><summary>{html.escape(summary)}</summary>")
        self.parts.append(_nested(doc))
        self.parts.append("</details>")

    def render(self) -> str:
        return (
            '<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{html.escape(self.title)}</title><style>{STYLE}</style></head><body>"
            + "\n".join(self.parts)
            + f"<script>{SCRIPT}</script></body></html>\n"
        )


def _nested(value: Any, depth: int = 0) -> str:
    """A JSON value as nested two-column tables; long numeric lists shortened."""
    if isinstance(value, dict):
        rows = "".join(
            f'<tr><th class="t">{html.escape(str(k))}</th><td class="t">{_nested(v, depth + 1)}'
            "</td></tr>"
            for k, v in value.items()
        )
        return f"<table>{rows}</table>"
    if isinstance(value, list):
        if all(isinstance(v, int | float) and not isinstance(v, bool) for v in value):
            shown = " / ".join(_cell(v) for v in value[:12])
            more = f" … ({len(value)} values)" if len(value) > 12 else ""
            return html.escape(shown + more)
        if len(value) > 50:
            value = [*value[:50], f"… {len(value) - 50} more"]
        return "".join(f"<div>{_nested(v, depth + 1)}</div>" for v in value) or "[]"
    return html.escape(_cell(value))
