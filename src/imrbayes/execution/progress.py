"""The one progress bar of a long command (``fit``, ``diagnose``, ``validate``): a tqdm bar on stderr
that draws on every terminal and counts the whole run, with an ETA.

Two pitfalls of a bare ``tqdm(...)`` are handled here:

* terminals that report a 0 x 0 window (``script``, ``docker exec -t``, some CI and editor
  terminals): tqdm reads 0 (or -1) rows, decides the bar lies below the screen and prints nothing.
  :func:`progress_bar` gives it the size :func:`shutil.get_terminal_size` reads (``COLUMNS`` and
  ``LINES``, or 80 x 24) whenever the terminal itself does not say;
* output that is not a terminal (a log file, ``nohup``, a batch job): a bar would print nothing
  until the end, so :class:`StageLog` writes one plain line per stage (batch) with the elapsed
  time instead;
* a total that grows batch by batch (``mienks window 12/18: 100%|███| 12/12``): the commands plan
  the total up front (:func:`plan` on an :class:`~imrbayes.execution.Execution`'s bar), and a batch
  only raises it when the plan was short.
"""

from __future__ import annotations

import shutil
import sys
import time

__all__ = ["progress_bar", "terminal_size", "plan", "finish", "BAR_FORMAT", "StageLog"]

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


def progress_bar(
    total: int | None = None,
    desc: str = "",
    unit: str = "units",
    file=None,
    leave: bool = True,
    position: int | None = None,
):
    """A tqdm bar on ``file`` (default stderr) that draws on every terminal, with the elapsed time,
    the ETA and the rate (:data:`BAR_FORMAT`). ``total`` None or 0: not known yet (:func:`plan`)."""
    from tqdm import tqdm  # the plain bar: tqdm.auto picks a notebook widget inside Jupyter kernels

    file = file if file is not None else sys.stderr
    cols, rows = terminal_size(file)
    fmt = BAR_FORMAT if total else None
    return tqdm(
        total=total or None,
        desc=desc,
        unit=unit,
        file=file,
        ncols=min(cols, 120),
        nrows=rows,
        leave=leave,
        position=position,
        mininterval=0.5,
        smoothing=0.1,
        bar_format=fmt,
        delay=0 if total else 0.5,
    )  # no "0 units" line before the command plans the total


def plan(bar, total: int, desc: str | None = None) -> None:
    """Set the whole run's ``total`` (and its description) before the first batch; the bar restarts
    its clock so that the ETA counts from here."""
    if bar is None:
        return
    bar.reset(total=max(int(total or 0), 0) or None)  # None: not known ahead (a method without units)
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


def _clock(seconds: float) -> str:
    """``1:05:03`` or ``4:07`` (minutes:seconds) of elapsed time."""
    m, sec = divmod(int(round(seconds)), 60)
    h, m = divmod(m, 60)
    return f"{h}:{m:02d}:{sec:02d}" if h else f"{m}:{sec:02d}"


class StageLog:
    """What a progress bar says, for output that is not a terminal: one line per stage (a batch of
    units, named by the batch's description) with the elapsed time and the units done so far, and
    one line at the end, e.g. ``imrbayes: mienks [0:42] mienks window 3/18 (12/36 units done)``.

    It offers the part of tqdm's interface that :class:`~imrbayes.execution.Execution`,
    :func:`plan` and :func:`finish` use (``total``, ``n``, ``update``, ``reset``,
    ``set_postfix_str``, ``write``, ``close``), so a command passes it where it would pass a bar.
    """

    def __init__(self, desc: str = "", file=None, clock=time.monotonic):
        self.desc, self.file, self._clock = desc, file if file is not None else sys.stderr, clock
        self.total, self.n, self.bar_format = None, 0, None
        self._t0, self._stage, self._closed = clock(), None, False

    def _line(self, text: str) -> None:
        print(f"imrbayes: {self.desc} [{_clock(self._clock() - self._t0)}] {text}", file=self.file, flush=True)

    def _done(self) -> str:
        return f"{self.n}/{self.total} units done" if self.total else f"{self.n} units done"

    def update(self, n: int = 1) -> None:
        self.n += int(n)

    def reset(self, total=None) -> None:
        self.total, self.n = total, 0

    def set_description_str(self, desc: str, refresh: bool = True) -> None:
        self.desc = desc

    def set_postfix_str(self, text: str, refresh: bool = True) -> None:
        """A new stage begins: its line, once per distinct description."""
        if text and text != self._stage:
            self._stage = text
            self._line(f"{text} ({self._done()})")

    def set_postfix(self, *args, **kwargs) -> None:
        pass

    def refresh(self) -> None:
        pass

    def write(self, text: str, file=None) -> None:
        print(text, file=file if file is not None else self.file, flush=True)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._line(f"finished ({self._done()})")
