"""The report's HTML page: one self-contained file (inline CSS, images as data URIs, no network).

The video is the file ``compare.mp4`` beside the page. A small inline script records whether
every image and the video loaded into ``<pre id="load-status">`` (used by the browser test).
"""

from __future__ import annotations

import base64
import html
import math
from typing import Any

__all__ = ["render_page"]

_CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', sans-serif; margin: 0 auto;
       max-width: 1500px; padding: 0 24px 48px; color: #1d1d1f; background: #fafafa; }
h1 { font-size: 1.6em; margin: 24px 0 4px; }
h2 { font-size: 1.25em; margin-top: 36px; border-bottom: 1px solid #ddd; padding-bottom: 4px; }
p.lead { color: #555; margin-top: 0; }
p.note, figcaption { color: #444; font-size: 0.92em; max-width: 1100px; }
img, video { max-width: 100%; height: auto; display: block; border-radius: 4px; }
video { background: #111; }
table { border-collapse: collapse; margin: 8px 0 4px; font-size: 0.93em; }
th, td { border: 1px solid #d6d6d6; padding: 4px 10px; text-align: right; }
th:first-child, td:first-child, td.text, th.text { text-align: left; }
td.meaning { text-align: left; color: #555; max-width: 520px; }
thead th { background: #eef1f5; }
tr.better td.fused { font-weight: 600; }
.kv td { text-align: left; }
#load-status { display: none; }
"""

_SCRIPT = """
(function () {
  var errors = [];
  window.addEventListener('error', function (e) { errors.push(String(e.message)); }, true);
  function report() {
    var imgs = Array.prototype.slice.call(document.images);
    var vids = Array.prototype.slice.call(document.querySelectorAll('video'));
    var s = {
      images: imgs.length,
      images_ok: imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; }).length,
      videos: vids.length,
      videos_ok: vids.filter(function (v) { return v.readyState >= 2 && !v.error; }).length,
      video_error: vids.map(function (v) { return v.error ? v.error.code : 0; }),
      errors: errors
    };
    document.getElementById('load-status').textContent = JSON.stringify(s);
  }
  window.addEventListener('load', report);
  document.querySelectorAll('video').forEach(function (v) {
    v.addEventListener('loadeddata', report);
    v.addEventListener('error', report);
  });
})();
"""


def _data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _fmt(value: Any, digits: int = 4) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "n/a"
    if isinstance(value, float):
        return f"{value:.{digits}g}"
    return html.escape(str(value))


def _figure(png: bytes, alt: str, caption: str) -> str:
    return (
        f'<figure><img src="{_data_uri(png)}" alt="{html.escape(alt)}">'
        f"<figcaption>{caption}</figcaption></figure>"
    )


def _metrics_table(rows: list[dict[str, Any]], names: list[str]) -> str:
    head = "".join(f"<th>{html.escape(n)}</th>" for n in names)
    out = [
        (
            f"<table><thead><tr><th>metric</th>{head}<th class='text'>unit</th>"
            "<th class='text'>what it means</th>"
            "</tr></thead><tbody>"
        )
    ]
    for row in rows:
        cells = "".join(
            f'<td class="{html.escape(n)}">{_fmt(row["values"].get(n), row.get("digits", 4))}</td>'
            for n in names
        )
        out.append(
            f"<tr><td>{html.escape(row['name'])}</td>{cells}"
            f"<td class='text'>{html.escape(row['unit'])}</td>"
            f"<td class='meaning'>{html.escape(row['meaning'])}</td></tr>"
        )
    out.append("</tbody></table>")
    return "".join(out)


def _kv_table(items: dict[str, Any]) -> str:
    rows = "".join(
        f"<tr><td>{html.escape(str(k))}</td><td>{_fmt(v)}</td></tr>" for k, v in items.items()
    )
    return f'<table class="kv"><tbody>{rows}</tbody></table>'


def render_page(
    *,
    title: str,
    subtitle: str,
    video_file: str,
    video_note: str,
    figures: dict[str, tuple[bytes, str]],
    metric_rows: list[dict[str, Any]],
    method_names: list[str],
    summary: str,
    facts: dict[str, Any],
    params: dict[str, Any] | None,
) -> str:
    """Assemble the HTML page.

    Parameters
    ----------
    title, subtitle : str
        Heading and the line under it (plain text, escaped here).
    video_file : str
        Relative path of the MP4 beside the page.
    video_note : str
        Caption of the video (HTML allowed: written by fuse4d, not by users).
    figures : dict of str to (png bytes, caption HTML)
        Keys ``regions``, ``xt``, ``flicker``, ``timeseries``, ``roughness``, ``support``,
        ``cloud`` (shown in this order after the metrics table).
    metric_rows : list of dict
        ``name``, ``values`` (method -> number), ``unit``, ``meaning``, optional ``digits``.
    method_names : list of str
        Table columns.
    summary : str
        One-paragraph headline (HTML allowed).
    facts : dict
        Input facts (frames, size, timing ...), shown as a key/value table.
    params : dict or None
        Fusion parameters used; None when the fused input does not record them.
    """
    sections = [
        ("regions", "Where the numbers come from", ""),
        (
            "xt",
            "x–t slice",
            (
                "One image line stacked over time. Trails show as smears along a motion; flicker "
                "as speckle along time (bottom row: frame-to-frame change)."
            ),
        ),
        (
            "flicker",
            "Temporal flicker (temporal precision)",
            (
                "The per-pixel std of depth over time on static pixels, headlined by its mean "
                "over them (as fuse4d metrics): the median reads 0 mm for quantised depth whose "
                "pixels mostly never leave their level, however far the others jump."
            ),
        ),
        ("timeseries", "Depth over time at a few pixels", ""),
        ("roughness", "Surface roughness (paper Eq. 7)", ""),
        ("support", "Temporal support and hole filling", ""),
        ("cloud", "Point cloud of one frame", ""),
    ]
    body = [
        f"<h1>{html.escape(title)}</h1><p class='lead'>{html.escape(subtitle)}</p>",
        f"<p>{summary}</p>",
        "<h2>Raw vs fused video</h2>",
        (
            f'<video controls loop muted autoplay playsinline preload="auto" src="{video_file}">'
            f'<a href="{video_file}">{video_file}</a></video>'
        ),
        f"<p class='note'>{video_note}</p>",
        "<h2>Metrics</h2>",
        _metrics_table(metric_rows, method_names),
    ]
    for key, heading, intro in sections:
        if key not in figures:
            continue
        png, caption = figures[key]
        body.append(f"<h2>{html.escape(heading)}</h2>")
        if intro:
            body.append(f"<p class='note'>{html.escape(intro)}</p>")
        body.append(_figure(png, heading, caption))
    body.append("<h2>Input and timing</h2>")
    body.append(_kv_table(facts))
    body.append("<h2>Parameters used</h2>")
    if params:
        body.append(_kv_table(params))
    else:
        body.append(
            "<p class='note'>Not recorded in the fused input (<code>fuse4d run</code> records "
            "them in its .npz and folder outputs).</p>"
        )
    return (
        "<!DOCTYPE html>\n<html lang='en'><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width, initial-scale=1'>"
        f"<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>"
        + "\n".join(body)
        + '<pre id="load-status">pending</pre>'
        + f"<script>{_SCRIPT}</script></body></html>\n"
    )
