"""README.md as written: its size, its links, the test command CI runs, every ``imrbayes ...`` line
parsed by the real command-line parser, and the five-minute walk-through run on the shared dataset
it names, with the files it promises checked and what its prose says of the result checked against
the run's summary.json.

The walk-through's ``runs/...`` folders are put under pytest's ``tmp_path`` and ``../shared`` is
resolved from the repository root; without the shared data the run tests skip.
"""

from __future__ import annotations

import json
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
SHARED = ROOT / ".." / "shared"
#: The largest README a user should have to read before the first command [bytes].
README_MAX_BYTES = 8 * 1024


def _blocks(lang: str) -> list[str]:
    """The fenced blocks of README.md whose info string is ``lang`` ("" for a bare fence)."""
    fences = re.findall(r"^```([A-Za-z]*)\n(.*?)^```", README.read_text(), flags=re.S | re.M)
    return [body for info, body in fences if info == lang]


def _imrbayes_lines() -> list[str]:
    """Every ``imrbayes ...`` command line of the README's shell blocks, continuation lines joined."""
    lines = []
    for block in _blocks("") + _blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("imrbayes "):
                lines.append(line)
    return lines


def _walkthrough() -> list[list[str]]:
    """The walk-through's commands as argument lists (without the leading ``imrbayes``)."""
    return [shlex.split(line)[1:] for line in _imrbayes_lines() if "../shared/" in line or " runs/" in line]


def _localise(argv: list[str], runs: Path) -> list[str]:
    """``argv`` with ``runs/...`` under ``runs`` and ``../shared/...`` from the repository root."""
    out = []
    for arg in argv:
        if arg.startswith("runs/"):
            arg = str(runs / arg.removeprefix("runs/"))
        elif arg.startswith("../shared/"):
            arg = str(ROOT / arg)
        out.append(arg)
    return out


def _run(argv: list[str], runs: Path) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "imrbayes.cli", *_localise(argv, runs), "--quiet"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, f"{shlex.join(cmd)} failed:\n{proc.stderr[-2000:]}"
    return proc


needs_shared = pytest.mark.skipif(
    not (SHARED / "data" / "lic").is_dir(), reason="shared data (../shared/data/lic) not present"
)


def test_readme_is_short_and_gives_the_ci_test_command():
    assert len(README.read_bytes()) <= README_MAX_BYTES
    assert ".venv/bin/python -m pytest\n" in "".join(_blocks("bash"))
    assert "bash scripts/example.sh\n" in "".join(_blocks("bash"))


def test_readme_links_resolve():
    """Every relative link to a file the repository keeps (docs, figures, the changelog) exists;
    validation/results/ is written by ``python -m validation`` and is not checked."""
    targets = re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", README.read_text())
    local = [t for t in targets if not t.startswith(("http://", "https://", "validation/results/"))]
    assert local, "README links to nothing"
    missing = [t for t in local if not (ROOT / t).exists()]
    assert not missing, f"README links to missing files: {missing}"


def test_readme_walkthrough_is_inspect_fit_report_diagnose():
    assert [argv[0] for argv in _walkthrough()] == ["inspect", "fit", "report", "diagnose"]


@pytest.mark.parametrize("line", _imrbayes_lines())
def test_command_line_parses(line):
    from imrbayes.cli import main

    argv = shlex.split(line)[1:]
    cmd = main.get_command(None, argv[0])
    assert cmd is not None, f"README names an unknown command: {line}"
    ctx = cmd.make_context(argv[0], argv[1:], parent=None)  # raises click.UsageError on a bad option
    assert ctx.params


@needs_shared
def test_walkthrough_inspect_fit_report(tmp_path):
    """The first three commands as written (polytropic, three bubbles: well under a minute with a
    compiled kernel): the files the README's table names exist, and the result is what its prose
    says -- a liquid whose G is consistent with 0, and NHKV flagged as not describing the records."""
    inspect, fit, report, _ = _walkthrough()
    for argv in (inspect, fit, report):
        _run(argv, tmp_path)
    out = tmp_path / "fit"
    assert (tmp_path / "inspect" / "dataset.json").is_file()
    assert (tmp_path / "inspect" / "figures" / "radius.png").is_file()
    for name in ("summary.json", "estimate.csv", "posterior.nc", "report.html"):
        assert (out / name).is_file(), name
    assert list((out / "figures").glob("*.png"))
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_experiments"] == 3
    assert summary["estimate"]["G"]["consistent_with_zero"] is True
    assert summary["fit_check"]["described"] is False
    assert summary["prior"]["name"] == "wide"

    import imrbayes

    run = imrbayes.load_run(out)
    assert run.estimates["mu"]["unit"] == "Pa s" and run.estimates["mu"]["mean"] > 0
    _conclusion_reads_right(out / "report.html")


def _conclusion_reads_right(report):
    """The report of a real dataset in a headless browser (Chromium, where installed): every image
    loads, the page opens with the conclusion, and the conclusion holds no JSON path and no number
    for a range the data do not bound; without a browser, the same checks on the page's text."""
    import html as html_lib
    import importlib.util

    spec = importlib.util.spec_from_file_location("check_report_browser", ROOT / "scripts" / "check_report_browser.py")
    chk = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(chk)
    if chk.find_browser() is not None:
        assert chk.main([str(report)]) == 0
    page = report.read_text()
    conclusion = page[page.index("Conclusion") : page.index("Estimate (SI units)")]
    text = html_lib.unescape(re.sub(r"<[^>]+>", " ", conclusion))
    assert "does not describe these records" in text
    assert "G consistent with 0" in text
    assert not re.search(r"\w+\[\]\.\w+|summary\.json\[", text), "a JSON path in the conclusion"
    assert "not bounded by the data" in text or "consistent with 0" in text
    assert not re.search(r"G sd [0-9.e+]+ kPa \(95 %", text), "a number for an unbounded between-bubble G"


@pytest.mark.slow
@needs_shared
def test_walkthrough_diagnose(tmp_path):
    """The walk-through's ``diagnose`` as written (several minutes: its candidates include the
    thermal bubble): diagnosis.json with a verdict, and its report."""
    diagnose = _walkthrough()[-1]
    _run(diagnose, tmp_path)
    out = tmp_path / "diagnose"
    result = json.loads((out / "diagnosis.json").read_text())
    assert result["cause"]
    assert (out / "report.html").is_file()
