"""The progress bar of long commands: it draws on terminals that report no size, and
``fit`` counts the whole run (windows x experiments) from the start, with an ETA."""

import os
import re
import select

import pytest
from click.testing import CliRunner

from imrbayes.cli import main
from imrbayes.execution.progress import plan, progress_bar, terminal_size


def _read_all(fd) -> str:
    out = b""
    while select.select([fd], [], [], 0.2)[0]:
        try:
            chunk = os.read(fd, 65536)
        except OSError:
            break
        if not chunk:
            break
        out += chunk
    return out.decode("utf-8", "replace")


@pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs a pseudo-terminal")
def test_bar_draws_on_a_terminal_that_reports_no_size():
    master, slave = os.openpty()  # a fresh pty: 0 x 0 window, as under script(1) or docker exec -t
    try:
        with os.fdopen(os.dup(slave), "w", encoding="utf-8") as fh:
            assert fh.isatty()
            assert terminal_size(fh)[0] > 0 and terminal_size(fh)[1] > 0
            bar = progress_bar(total=3, desc="fit", file=fh)
            for _ in range(3):
                bar.update(1)
            bar.close()
            fh.flush()
        text = _read_all(master)
    finally:
        os.close(master)
        os.close(slave)
    assert "3/3" in text and "100%" in text, repr(text)


def test_plan_sets_the_total_once_and_a_short_plan_grows():
    import io

    from imrbayes.execution import Execution, Unit

    buf = io.StringIO()
    bar = progress_bar(total=None, desc="fit", file=buf)
    plan(bar, 6, "fit")
    ex = Execution(bar=bar)
    for j in range(3):
        ex.run([Unit(f"w={j}/e={i}", i) for i in range(2)], _identity, 0, desc=f"window {j + 1}/3")
        assert bar.total == 6
    ex.run([Unit("extra", 0)], _identity, 0, desc="beyond the plan")
    assert bar.total == 7 and bar.n == 7
    bar.close()


def _identity(unit, rng):
    return unit.data


@pytest.fixture(scope="module")
def tiny_ds(tmp_path_factory):
    ds = tmp_path_factory.mktemp("progress") / "ds"
    r = CliRunner().invoke(
        main,
        [
            "simulate",
            "--model",
            "nhkv",
            "--param",
            "G=7.29e3",
            "--param",
            "mu=0.088",
            "--n-exp",
            "2",
            "--forward",
            "bubble=polytropic",
            "--t-end",
            "1.0",
            "--seed",
            "0",
            "--out",
            str(ds),
            "--quiet",
        ],
    )
    assert r.exit_code == 0, r.output
    return ds


@pytest.mark.slow
def test_fit_bar_counts_windows_times_experiments_from_the_start(tiny_ds, tmp_path, monkeypatch):
    import imrbayes.cli.options as opts

    monkeypatch.setattr(opts, "_isatty", lambda stream: True)  # CliRunner's stderr is no terminal
    r = CliRunner().invoke(
        main,
        [
            "fit",
            str(tiny_ds),
            "--method",
            "mienks",
            "--forward",
            "bubble=polytropic",
            "--set",
            "n_ens=8",
            "--set",
            "n_iter=2",
            "--set",
            "L=10",
            "--set",
            "h=5",
            "--n-steps",
            "40",
            "--out",
            str(tmp_path / "fit"),
        ],
    )
    assert r.exit_code == 0, r.output
    err = r.stderr
    # 40 steps, L=10, h=5: 7 windows; 2 experiments; the default likelihood's pilot pass, then the reported one
    assert "28 units (2 passes x 7 windows x 2 experiments)" in err
    totals = {int(m) for m in re.findall(r"\d+/(\d+) units", err)}
    assert totals == {28}, err  # one total from the first draw to the last
    assert "0/28 units" in err and "28/28 units" in err
    assert re.search(r"\[\d\d:\d\d<\d\d:\d\d\]", err), err  # elapsed < remaining (the ETA)
    assert "mienks window 7/7" in err


def test_stage_log_writes_one_line_per_stage_with_the_elapsed_time():
    """Output that is not a terminal: one line per batch with the elapsed time, never silence."""
    import io

    from imrbayes.execution import Execution, Unit
    from imrbayes.execution.progress import StageLog

    now = [0.0]
    buf = io.StringIO()
    log = StageLog(desc="mienks", file=buf, clock=lambda: now[0])
    plan(log, 4, "mienks")
    ex = Execution(bar=log)
    for j in range(2):
        now[0] += 65.0
        ex.run([Unit(f"w={j}/e={i}", i) for i in range(2)], _identity, 0, desc=f"mienks window {j + 1}/2")
    log.close()
    assert buf.getvalue().splitlines() == [
        "imrbayes: mienks [1:05] mienks window 1/2 (0/4 units done)",
        "imrbayes: mienks [2:10] mienks window 2/2 (2/4 units done)",
        "imrbayes: mienks [2:10] finished (4/4 units done)",
    ]
