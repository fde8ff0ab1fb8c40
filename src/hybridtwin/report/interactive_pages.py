"""The interactive figures as HTML pages (issue 55, item 1): one figure per page, or every figure in one page with
one copy of plotly.js.

plotly.js is about 4.9 MB. A page per figure that carries its own copy stands alone (it opens offline, mailed or
from results/), but Snakemake's single-file report embeds every report file (base64, a third larger), so 25 such
pages made a 209 MB report. The report therefore embeds one page, ``write_gallery``'s: plotly.js once and each
figure's data (its JSON, parsed and drawn only when chosen), with a menu (grouped per variant) to choose the figure
shown; the URL's fragment (``#<key>``) chooses one too. A figure behaves there as in its own page: the same data,
layout and plotly options (``CONFIG``), so the same zoom, hover and legend clicks.

Each page is ours, not plotly's ``write_html``, and stores its text compressed (``pack``: gzip, then base64): plotly.js
(4.9 MB -> 1.9 MB) in a ``<script type="application/gzip-base64" id="plotly-js">`` element and each figure's JSON
(its float arrays in single precision, ``single_precision``) in one such element per figure, which the browser
inflates (``DecompressionStream``, Chrome 80, Firefox 113, Safari 16.4) as the page opens (plotly.js) or a figure is
chosen (its JSON). A report embeds its files base64-encoded and a browser's time to open it grows with its bytes
(about 0.14 s a MB in headless Chromium): the main job's page 10.4 -> 3.3 MB, its report 24.7 -> 15 MB (issue 55;
benchmarks/README.md). ``read_figure`` and ``read_gallery`` read the pages back, the exact inverses of
``write_figure`` and ``write_gallery`` (``unpack`` of ``pack``). Same figure, same bytes (a fixed element id, no
random names, gzip without a time stamp): the workflow's reruns compare results.
"""

from __future__ import annotations

import base64
import gzip
import html
import json
import re
from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
import plotly.io as pio
from plotly.offline import get_plotlyjs

#: the plotly.js options of every figure: no plotly logo; the camera button saves a PNG of the current view; the
#: figure follows the window's width
CONFIG = {"displaylogo": False, "toImageButtonOptions": {"format": "png", "scale": 2}, "responsive": True}
#: the element the figure is drawn in (also the id plotly's own pages use for a fixed div_id)
FIGURE_ID = "figure"
#: a figure's element: its key, label and packed JSON (``pack``)
_DATA = re.compile(r'<script type="application/gzip-base64" class="figure-data" data-key="([^"]*)" '
                   r'data-label="([^"]*)">([A-Za-z0-9+/=]*)</script>')
#: a figure's element in a page written before the packing (its JSON as it is): still read, so that a rerun of the
#: report's page from figures' own pages of an earlier version works
_PLAIN_DATA = re.compile(r'<script type="application/json" class="figure-data" data-key="([^"]*)" '
                         r'data-label="([^"]*)">(.*?)</script>', re.DOTALL)
#: the packed plotly.js (``pack``)
_PLOTLY = re.compile(r'<script type="application/gzip-base64" id="plotly-js">([A-Za-z0-9+/=]*)</script>')


def pack(text: str) -> str:
    """``text`` (UTF-8) gzip-compressed (level 9, no time stamp: the same text, the same bytes), then base64: the
    form a page stores plotly.js and each figure's JSON in, which the page's script inflates in the browser
    (``_DRAW``). ``unpack`` is its inverse."""
    return base64.b64encode(gzip.compress(text.encode("utf-8"), compresslevel=9, mtime=0)).decode("ascii")


def unpack(packed: str) -> str:
    """The text ``pack`` packed."""
    return gzip.decompress(base64.b64decode(packed, validate=True)).decode("utf-8")


@lru_cache(maxsize=1)
def plotly_js() -> str:
    """The plotly.js bundle of the installed plotly package (minified, offline)."""
    return get_plotlyjs()


@lru_cache(maxsize=1)
def packed_plotly_js() -> str:
    """``plotly_js`` as a page stores it (``pack``)."""
    return pack(plotly_js())


def figure_json(fig: go.Figure) -> str:
    """``fig``'s data and layout as JSON that can sit inside a <script> element: every "<" as "\\u003c" (it occurs
    only inside strings, as in "<br>", and json.loads gives it back); its float arrays in single precision
    (``single_precision``)."""
    return single_precision(fig.to_json(validate=False)).replace("<", "\\u003c")


#: a float array as plotly writes it: typed binary data, base64 (its "/" written as the JSON escape "\\u002f")
_FLOATS = re.compile(r'\{"dtype":\s*"(f8|f4)",\s*"bdata":\s*"([^"]*)"')


def single_precision(text: str) -> str:
    """A figure's JSON ``text`` with its float64 arrays (plotly's ``{"dtype":"f8","bdata":...}``) as float32:
    7 significant digits, more than a screen or the hover's 4 show, in half the bytes (the main job's report: its
    figures' data 11.5 -> 6.1 MB, issue 55; base64's "/" written plainly, not as plotly's 6-byte escape);
    plotly.js draws float32 arrays as it draws float64 ones. Plotly < 6 writes arrays as JSON lists, which are left
    as they are. Idempotent: what a page stores reads back
    (``read_figure``) and writes again to the same text."""
    def shorter(match: re.Match) -> str:
        values = np.frombuffer(base64.b64decode(match[2].replace("\\u002f", "/")), "<" + match[1]).astype("<f4")
        return '{"dtype":"f4","bdata":"' + base64.b64encode(values.tobytes()).decode("ascii") + '"'
    return _FLOATS.sub(shorter, text)


def _read_json(text: str) -> go.Figure:
    return pio.from_json(text, skip_invalid=False)


_HEAD = """<!DOCTYPE html>
<html>
<head>
<meta charset="utf-8">
<title>{title}</title>
<style>
body {{ margin: 0; font-family: sans-serif; }}
#bar {{ padding: 6px 10px; border-bottom: 1px solid #ddd; font-size: 14px; }}
#bar select {{ font-size: 14px; max-width: 90vw; }}
#bar span {{ color: #666; font-size: 12px; margin-left: 1em; }}
</style>
</head>
<body>
<script type="text/javascript">window.PlotlyConfig = {{MathJaxConfig: 'local'}};</script>
<script type="application/gzip-base64" id="plotly-js">{plotly}</script>
"""

_DRAW = """<script type="text/javascript">
(function () {
  var config = %s;
  var gd = document.getElementById('%s');
  if (typeof DecompressionStream === 'undefined' || typeof Response === 'undefined') {
    gd.textContent = 'This page stores plotly.js and its figures compressed; this browser cannot inflate them ' +
      '(it needs DecompressionStream: Chrome 80, Firefox 113, Safari 16.4 or later).';
    return;
  }
  function inflate(el) {  // pack's inverse: base64, then gzip
    var text = atob(el.textContent), bytes = new Uint8Array(text.length);
    for (var i = 0; i < text.length; i++) { bytes[i] = text.charCodeAt(i); }
    return new Response(new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'))).text();
  }
  var ready = inflate(document.getElementById('plotly-js')).then(function (js) {
    var script = document.createElement('script');
    script.text = js;  // an inline script runs as it is added: plotly.js defines window.Plotly
    document.head.appendChild(script);
  });
  var blocks = {};
  document.querySelectorAll('script.figure-data').forEach(function (el) { blocks[el.dataset.key] = el; });
  var choose = document.getElementById('choose');
  var latest = 0;  // the figure last asked for: one asked for earlier and inflated later is not drawn over it
  function show(key) {
    if (!(key in blocks)) { key = Object.keys(blocks)[0]; }
    var asked = ++latest;
    if (choose) { choose.value = key; }
    document.title = blocks[key].dataset.label;
    return Promise.all([inflate(blocks[key]), ready]).then(function (done) {
      if (asked !== latest) { return; }
      var spec = JSON.parse(done[0]);
      Plotly.purge(gd);
      return Plotly.newPlot(gd, spec.data, spec.layout, config);
    }).catch(function (e) { gd.textContent = 'The figure could not be drawn: ' + e; });
  }
  if (choose) {
    choose.addEventListener('change', function () {
      try { history.replaceState(null, '', '#' + encodeURIComponent(choose.value)); } catch (e) { }
      show(choose.value);
    });
  }
  window.addEventListener('hashchange', function () { show(decodeURIComponent(location.hash.slice(1))); });
  show(decodeURIComponent(location.hash.slice(1)));
})();
</script>
</body>
</html>
"""


def _block(key: str, label: str, fig: go.Figure) -> str:
    return (f'<script type="application/gzip-base64" class="figure-data" data-key="{html.escape(key)}" '
            f'data-label="{html.escape(label)}">{pack(figure_json(fig))}</script>\n')


def _page(entries: Sequence[tuple[str, str, go.Figure]], title: str, menu: bool) -> str:
    keys = [key for key, _, _ in entries]
    if not entries or len(set(keys)) != len(keys):
        raise ValueError(f"a page needs figures with distinct keys, got {keys}")
    parts = [_HEAD.format(title=html.escape(title), plotly=packed_plotly_js())]
    if menu:
        groups: dict[str, list[tuple[str, str]]] = {}
        for key, label, _ in entries:
            groups.setdefault(key.split("/")[0] if "/" in key else "", []).append((key, label))
        options = []
        for group, items in groups.items():
            inner = "".join(f'<option value="{html.escape(k)}">{html.escape(lab)}</option>' for k, lab in items)
            options.append(f'<optgroup label="{html.escape(group)}">{inner}</optgroup>' if group else inner)
        parts.append(f'<div id="bar"><label for="choose">figure </label><select id="choose">{"".join(options)}'
                     f'</select><span>{len(entries)} figures; hover a point for its value, drag to zoom, a legend '
                     'entry shows or hides its group</span></div>\n')
    parts.append(f'<div id="{FIGURE_ID}" class="plotly-graph-div" style="width:100%;"></div>\n')
    parts += [_block(key, label, fig) for key, label, fig in entries]
    parts.append(_DRAW % (json.dumps(CONFIG), FIGURE_ID))
    return "".join(parts)


def write_figure(fig: go.Figure, path: str | Path, title: str = "figure") -> None:
    """``fig`` as one self-contained HTML page at ``path``: plotly.js inside (opens offline), the figure drawn on
    load. ``read_figure`` reads it back."""
    Path(path).write_text(_page([("figure", title, fig)], title, menu=False), encoding="utf-8")


def read_figure(path: str | Path) -> go.Figure:
    """The figure of a page written by ``write_figure`` (or the first of a gallery's)."""
    return read_gallery(path)[0][2]


def write_gallery(entries: Sequence[tuple[str, str, go.Figure]], path: str | Path,
                  title: str = "interactive figures") -> None:
    """Every figure of ``entries`` (key, label, figure) in one HTML page at ``path`` with one copy of plotly.js: a
    menu chooses the figure drawn (the first on opening, or the one the URL's fragment ``#<key>`` names). Keys:
    distinct; "<group>/<name>" puts the figure in the menu's group <group> (a variant)."""
    Path(path).write_text(_page(entries, title, menu=True), encoding="utf-8")


def read_gallery(path: str | Path) -> list[tuple[str, str, go.Figure]]:
    """The (key, label, figure) entries of a page written by ``write_gallery`` or ``write_figure``, in order (or by
    their versions before the packing, whose figures' JSON is stored as it is)."""
    text = Path(path).read_text(encoding="utf-8")
    found = [(html.unescape(key), html.unescape(label), _read_json(unpack(data)))
             for key, label, data in _DATA.findall(text)]
    found = found or [(html.unescape(key), html.unescape(label), _read_json(data))
                      for key, label, data in _PLAIN_DATA.findall(text)]
    if not found:
        raise ValueError(f"{path}: no figure data in it (not a page of hybridtwin.report.interactive_pages)")
    return found


def read_plotly_js(path: str | Path) -> str:
    """The plotly.js a page written by ``write_gallery`` or ``write_figure`` carries (``unpack``)."""
    found = _PLOTLY.findall(Path(path).read_text(encoding="utf-8"))
    if len(found) != 1:
        raise ValueError(f"{path}: {len(found)} copies of plotly.js in it, a page of ours has one")
    return unpack(found[0])
