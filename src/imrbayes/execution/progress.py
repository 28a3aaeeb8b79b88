"""The one progress bar of a long command (``fit``, ``diagnose``, ``validate``): a tqdm bar on stderr
that draws on every terminal and counts the whole run, with an ETA.

Two pitfalls of a bare ``tqdm(...)`` are handled here:

* terminals that report a 0 x 0 window (``script``, ``docker exec -t``, some CI and editor
  terminals): tqdm reads 0 (or -1) rows, decides the bar lies below the screen and prints nothing.
  :func:`progress_bar` gives it the size :func:`shutil.get_terminal_size` reads (``COLUMNS`` and
  ``LINES``, or 80 x 24) whenever the terminal itself does not say;
* a total that grows batch by batch (``mienks window 12/18: 100%|███| 12/12``): the commands plan
  the total up front (:func:`plan` on an :class:`~imrbayes.execution.Execution`'s bar), and a batch
  only raises it when the plan was short.
"""

from __future__ import annotations

import shutil
import sys

__all__ = ["progress_bar", "terminal_size", "plan", "finish", "BAR_FORMAT"]

#: ``mienks:  37%|███▋      | 44/120 units [02:10<03:40], mienks window 6/18`` (elapsed<remaining)
BAR_FORMAT = "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} {unit} [{elapsed}<{remaining}]{postfix}"


def terminal_size(stream=None) -> tuple:
    """(columns, rows) of the terminal behind ``stream``; where it reports nothing usable (0 x 0
    pseudo-terminals, pipes), ``COLUMNS``/``LINES`` or 80 x 24."""
    stream = stream if stream is not None else sys.stderr
    try:
        import os

        size = os.get_terminal_size(stream.fileno())
        cols, rows = size.columns, size.lines
    except (AttributeError, ValueError, OSError):
        cols = rows = 0
    fallback = shutil.get_terminal_size((80, 24))
    return (cols if cols > 0 else fallback.columns or 80), (rows if rows > 0 else fallback.lines or 24)


def progress_bar(total: int | None = None, desc: str = "", unit: str = "units", file=None, leave: bool = True,
                 position: int | None = None):
    """A tqdm bar on ``file`` (default stderr) that draws on every terminal, with the elapsed time,
    the ETA and the rate (:data:`BAR_FORMAT`). ``total`` None or 0: not known yet (:func:`plan`)."""
    from tqdm import tqdm          # the plain bar: tqdm.auto picks a notebook widget inside Jupyter kernels

    file = file if file is not None else sys.stderr
    cols, rows = terminal_size(file)
    fmt = BAR_FORMAT if total else None
    return tqdm(total=total or None, desc=desc, unit=unit, file=file, ncols=min(cols, 120), nrows=rows,
                leave=leave, position=position, mininterval=0.5, smoothing=0.1, bar_format=fmt,
                delay=0 if total else 0.5)    # no "0 units" line before the command plans the total


def plan(bar, total: int, desc: str | None = None) -> None:
    """Set the whole run's ``total`` (and its description) before the first batch; the bar restarts
    its clock so that the ETA counts from here."""
    if bar is None:
        return
    bar.reset(total=max(int(total), 0) or None)
    if total:
        bar.bar_format = BAR_FORMAT
    if desc is not None:
        bar.set_description_str(desc, refresh=False)
    bar.refresh()


def finish(bar) -> None:
    """At the end of a run that did less than planned (units left out after a failure): the total
    becomes what was done, so the bar ends at 100 %."""
    if bar is None:
        return
    if bar.total is not None and bar.n < bar.total:
        bar.total = bar.n
    bar.refresh()
