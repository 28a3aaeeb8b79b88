#!/usr/bin/env python3
"""Render an imrbayes ``report.html`` in a real headless browser and check what a reader sees.

    python scripts/check_report_browser.py RUN_DIR/report.html [--png out.png] [--width 1280]

Uses Chromium (or Google Chrome) from the system packages (``apt-get install chromium``); when none
is installed it prints a message and exits 0 (``--require`` makes that exit 3). Checks, on the
rendered page (``document.body.innerText`` and ``document.images`` after the load event):

* every image loaded (``complete`` and a non-zero natural size);
* no raw JSON in the visible text (``{"key": ...}``, ``["...", ...``) and no escapes
  (``\\u00a7``, ``\\n``, ``&amp;`` shown as text);
* the page opens with the conclusion block.

The report itself has no scripts: the checks run in a temporary copy with one script appended.
Exit status 0 when every check passes (or no browser), 1 when one fails, 2 for bad usage.
With ``--png`` it also writes a full-page screenshot.
"""

from __future__ import annotations

import argparse
import html
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

BROWSERS = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome")

_PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = Array.prototype.slice.call(document.images);
  var bad = imgs.filter(function (i) { return !(i.complete && i.naturalWidth > 0 && i.naturalHeight > 0); })
                .map(function (i) { return i.alt || i.src.slice(0, 40); });
  var first = document.querySelector('h2');
  var out = {n_images: imgs.length, broken: bad, text: document.body.innerText,
             height: Math.max(document.body.scrollHeight, document.documentElement.scrollHeight),
             first_h2: first ? first.id : null};
  var pre = document.createElement('pre');
  pre.id = 'imrbayes-probe';
  pre.setAttribute('data-probe', JSON.stringify(out));
  document.body.appendChild(pre);
});
</script>"""

# raw JSON / escapes a reader must not see in the rendered text
_BAD_TEXT = [
    (re.compile(r"\{\s*\"[^\"]+\"\s*:"), "a JSON object"),
    (re.compile(r"\[\s*\"[^\"]*\"\s*,"), "a JSON list of strings"),
    (re.compile(r"\\u[0-9a-fA-F]{4}"), "a \\u escape"),
    (re.compile(r"\\[nt\"]"), "a backslash escape"),
    (re.compile(r"&(amp|lt|gt|quot|#\d+);"), "an HTML entity shown as text"),
]


def find_browser() -> str | None:
    for name in BROWSERS:
        path = shutil.which(name)
        if path:
            return path
    return None


def _run(browser, args, timeout=120) -> str:
    cmd = [
        browser,
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--hide-scrollbars",
        "--no-first-run",
        "--disable-extensions",
        "--virtual-time-budget=10000",
        *args,
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"{Path(browser).name} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return proc.stdout


def check(report: Path, png: Path | None = None, width: int = 1280, browser: str | None = None) -> dict:
    """Render ``report`` and check it; returns ``{"ok": bool, "problems": [...], "n_images": n, ...}``."""
    browser = browser or find_browser()
    if browser is None:
        raise FileNotFoundError("no Chromium/Chrome found (" + ", ".join(BROWSERS) + ")")
    page = report.read_text(encoding="utf-8")
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.html"
        probe.write_text(
            page.replace("</body>", _PROBE + "</body>") if "</body>" in page else page + _PROBE, encoding="utf-8"
        )
        dom = _run(browser, [f"--window-size={width},1000", "--dump-dom", probe.as_uri()])
        m = re.search(r"id=\"imrbayes-probe\" data-probe=\"([^\"]*)\"", dom)
        if not m:
            return {"ok": False, "problems": ["the page did not finish loading (no probe result)"], "n_images": 0}
        res = json.loads(html.unescape(m.group(1)))
        if png is not None:
            height = max(600, min(int(res.get("height") or 4000) + 40, 30000))
            png.parent.mkdir(parents=True, exist_ok=True)
            _run(
                browser, [f"--window-size={width},{height}", f"--screenshot={png.resolve()}", report.resolve().as_uri()]
            )
    problems = []
    if res["broken"]:
        problems.append(f"{len(res['broken'])} of {res['n_images']} image(s) did not load: {res['broken'][:5]}")
    text = res["text"]
    for rx, what in _BAD_TEXT:
        hit = rx.search(text)
        if hit:
            a = max(hit.start() - 60, 0)
            problems.append(f"{what} in the visible text: …{text[a : hit.end() + 60]!r}…")
    if res.get("first_h2") != "conclusion":
        problems.append(f"the page does not open with the conclusion block (first section: {res.get('first_h2')!r})")
    return {
        "ok": not problems,
        "problems": problems,
        "n_images": res["n_images"],
        "height": res.get("height"),
        "browser": browser,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("report", type=Path, help="report.html (or a run directory holding one)")
    ap.add_argument("--png", type=Path, default=None, help="write a full-page screenshot here")
    ap.add_argument("--width", type=int, default=1280, help="browser window width [px] (default 1280)")
    ap.add_argument("--require", action="store_true", help="exit 3 when no browser is installed (default: skip)")
    a = ap.parse_args(argv)
    report = a.report / "report.html" if a.report.is_dir() else a.report
    if not report.is_file():
        print(f"check_report_browser: {report}: no such file", file=sys.stderr)
        return 2
    if find_browser() is None:
        print("check_report_browser: skipped: no Chromium/Chrome installed (apt-get install chromium)")
        return 3 if a.require else 0
    res = check(report, a.png, a.width)
    for p in res["problems"]:
        print(f"check_report_browser: {report}: {p}", file=sys.stderr)
    if res["ok"]:
        extra = f"; screenshot {a.png}" if a.png else ""
        print(f"check_report_browser: {report}: ok ({res['n_images']} image(s) loaded, no raw JSON or escapes{extra})")
    return 0 if res["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
