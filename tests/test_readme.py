"""Every README snippet runs: the Python blocks are executed, and every ``imrbayes ...`` line of the
shell blocks is parsed by the real command-line parser (command and options exist, values are of
the right type). Running those commands is what the rest of the suite does at small scale."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import numpy as np
import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def _blocks(lang: str) -> list[str]:
    """The fenced blocks of README.md whose info string is ``lang`` ("" for a bare fence)."""
    fences = re.findall(r"^```([A-Za-z]*)\n(.*?)^```", README.read_text(), flags=re.S | re.M)
    return [body for info, body in fences if info == lang]


def _imrbayes_lines() -> list[str]:
    lines = []
    for block in _blocks("") + _blocks("bash"):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.split(" #")[0].strip()
            if line.startswith("imrbayes "):
                lines.append(line)
    return lines


def test_readme_has_snippets():
    assert len(_blocks("python")) >= 1
    assert len(_imrbayes_lines()) >= 10


@pytest.mark.parametrize("index", range(len(_blocks("python"))))
def test_python_snippet_runs(index):
    namespace: dict = {}
    exec(compile(_blocks("python")[index], f"README.md python block {index}", "exec"), namespace)
    if "R_star" in namespace:     # the forward-model snippet: R* starts at 1 and collapses
        R = np.asarray(namespace["R_star"])
        assert R[0] == pytest.approx(1.0) and np.all(np.isfinite(R)) and R.min() < 0.3
        out = namespace["out"]
        assert out.R_star.shape == (48, 35) and not out.failed.any()


@pytest.mark.parametrize("line", _imrbayes_lines())
def test_command_line_parses(line):
    from imrbayes.cli import main

    argv = shlex.split(line)[1:]
    if argv == ["--help"]:
        return
    cmd = main.get_command(None, argv[0])
    assert cmd is not None, f"README names an unknown command: {line}"
    ctx = cmd.make_context(argv[0], argv[1:], parent=None)   # raises click.UsageError on a bad option
    assert ctx.params
