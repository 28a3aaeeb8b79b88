"""The page skeleton and helpers shared by the self-contained HTML reports (``imrbayes report``:
:mod:`imrbayes.report`; ``imrbayes diagnose``: :mod:`imrbayes.diagnosis.report`): the inline style
sheet and page wrapper (:func:`page`, :func:`write_page`), number formatting, escaping, tables and
PNG figures embedded as base64 (:func:`embed_png`, :func:`is_png`) -- no external CSS, JS or
images, so one file can be mailed or archived on its own."""

from __future__ import annotations

import base64
import html
import math
from pathlib import Path

from imrbayes.io import atomic_write_text

__all__ = ["CSS", "PNG_MAGIC", "esc", "fmt", "num", "pm", "table", "is_png", "embed_png", "page", "write_page"]

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"

CSS = """body{font-family:sans-serif;max-width:1100px;margin:auto;padding:0 12px;line-height:1.35}
td,th{border:1px solid #ccc;padding:3px 6px;vertical-align:top}
th{background:#f3f3f3;text-align:left}
table{border-collapse:collapse;font-size:13px;margin:6px 0 12px 0}
td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
.bad{background:#fde2e2}.ok{background:#e3f4e3}.undecided{background:#fff4cc}
.note{font-size:12px;color:#555}.absent{color:#8a4b00;font-weight:bold}
figure{margin:14px 0}figcaption{font-size:13px;color:#333;margin-top:4px}
code{background:#f5f5f5;padding:0 2px}
table.kv td:first-child{background:#f3f3f3;font-weight:bold;white-space:nowrap}
.conclusion{border:2px solid #4a7;border-radius:6px;padding:4px 14px;background:#f6fbf7;margin:10px 0}
.conclusion li{margin:3px 0}.caveat{color:#8a4b00}
ul.plain{margin:2px 0;padding-left:18px}
.verdict{border:2px solid #357;border-radius:6px;padding:6px 14px;background:#f4f7fb;margin:10px 0;font-size:15px}
.verdict p{margin:5px 0}"""


def esc(x) -> str:
    """HTML-escaped ``str(x)``."""
    return html.escape(str(x))


def fmt(x, spec=".4g") -> str:
    """``format(float(x), spec)``; anything that is not a number is shown escaped as it is."""
    try:
        return format(float(x), spec)
    except (TypeError, ValueError):
        return html.escape(str(x))


def num(x, spec=".5g", missing="–") -> str:
    """A number for a table cell: ``missing`` for None/NaN/non-numbers, ``±inf`` as such."""
    if x is None or isinstance(x, bool):
        return missing if x is None else str(x).lower()
    try:
        v = float(x)
    except (TypeError, ValueError):
        return html.escape(str(x))
    if math.isnan(v):
        return missing
    if math.isinf(v):
        return "∞" if v > 0 else "−∞"
    return format(v, spec)


def table(headers, rows, cls=None) -> str:
    """``<table>`` from header strings (HTML) and rows of cell HTML; a cell may be a tuple
    ``(html, attributes)`` to add e.g. ``class='n'``. ``headers`` None or empty: no header row (a
    key-value table), not an empty one."""
    head = "".join(f"<th>{h}</th>" for h in headers or ())
    body = []
    for row in rows:
        cells = []
        for c in row:
            if isinstance(c, tuple):
                cells.append(f"<td {c[1]}>{c[0]}</td>")
            else:
                cells.append(f"<td>{c}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    attr = f" class='{cls}'" if cls else ""
    head = f"<tr>{head}</tr>" if head else ""
    return f"<table{attr}>{head}{''.join(body)}</table>"


def is_png(path) -> bool:
    """Whether ``path`` can be read and starts with the PNG signature (what :func:`embed_png` embeds)."""
    try:
        with open(path, "rb") as fh:
            return fh.read(len(PNG_MAGIC)) == PNG_MAGIC
    except OSError:
        return False


def embed_png(path, caption: str | None = None, title: str | None = None) -> str:
    """A PNG file as an inline ``<img>`` (base64 data URI), optionally inside a captioned figure."""
    path = Path(path)
    b64 = base64.b64encode(path.read_bytes()).decode()
    img = f"<img src='data:image/png;base64,{b64}' alt='{esc(path.name)}' style='max-width:100%'>"
    if caption is None and title is None:
        return img
    head = f"<h3>{esc(title)}</h3>" if title else ""
    cap = f"<figcaption>{caption}</figcaption>" if caption else ""
    return f"<figure>{head}{img}{cap}</figure>"


def page(title: str, body: str) -> str:
    """A complete HTML document with the shared inline style sheet."""
    return (
        f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(title)}</title>"
        f"<style>{CSS}</style></head><body>\n{body}\n</body></html>\n"
    )


def write_page(path, title: str, body: str) -> Path:
    """:func:`page` written to ``path`` as UTF-8, atomically (folders created); returns ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return atomic_write_text(path, page(title, body))


def pm(x, se, spec=".2g") -> str:
    """``"x ± se"`` (both with ``spec``; ``–`` for a missing number)."""
    return f"{num(x, spec)} ± {num(se, spec)}"
