"""Figure helpers shared by every figure module (data, ensemble, mcmc, diagnosis).

Matplotlib's object API on the Agg canvas, attached here and nowhere else: no pyplot, no global
backend switch, so plotting works headless and never changes the caller's matplotlib state.

* :func:`figure` -- a new ``Figure`` (size in inches) with an Agg canvas;
* :func:`save` -- PNG written atomically (:func:`imrbayes.io.atomic_write`), figure released;
* :func:`scale` / :func:`label` -- the display unit of a parameter or axis quantity: multiply SI
  values by ``scale(name)`` and label the axis ``label(name)`` (``G`` in kPa, ``mu`` in Pa s).
"""

from __future__ import annotations

from pathlib import Path

from imrbayes.io import atomic_write

__all__ = ["DPI", "figure", "save", "scale", "label", "plain_log_axis", "time_axis_us"]

DPI = 110
"""Resolution [dots per inch] of the saved PNGs (``imrbayes inspect``'s radius figure uses 120)."""

# name -> (factor from SI to the display unit, axis label with the unit)
_DISPLAY = {
    "G": (1e-3, "G [kPa]"),
    "mu": (1.0, r"$\mu$ [Pa s]"),
    "t_star": (1.0, r"$t^*$"),
    "R_star": (1.0, r"$R^* = R/R_{max}$"),
}


def figure(width: float, height: float, layout: str | None = "constrained"):
    """A ``matplotlib.figure.Figure`` of ``width`` x ``height`` inches on an Agg canvas.

    ``layout``: matplotlib's layout engine (``"constrained"``; ``None`` for figures that call
    ``fig.tight_layout()`` themselves).
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), layout=layout)
    FigureCanvasAgg(fig)
    return fig


def save(fig, path, dpi: int = DPI) -> Path:
    """Write ``fig`` as PNG to ``path`` (folders created, atomically) and release it; returns ``path``.

    The figure is cleared after writing: figures are made for one file, and a loop over windows
    should not keep every figure's artists alive.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=dpi))
    fig.clear()
    return path


def scale(name: str) -> float:
    """Factor from SI to the display unit of ``name`` (1 for names without one)."""
    return _DISPLAY.get(name, (1.0, name))[0]


def label(name: str) -> str:
    """Axis label with the display unit of ``name`` (``"G"`` -> ``"G [kPa]"``; the name itself for
    names without one)."""
    return _DISPLAY.get(name, (1.0, name))[1]


def plain_log_axis(ax, which: str = "y") -> None:
    """Tick labels of a log axis as plain numbers (``7``, ``10``, ``20``), not ``7 x 10^0``."""
    from matplotlib.ticker import FuncFormatter, LogLocator

    fmt = FuncFormatter(lambda v, _: f"{v:.3g}")
    axis = ax.yaxis if which == "y" else ax.xaxis
    axis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    axis.set_major_formatter(fmt)
    axis.set_minor_formatter(FuncFormatter(lambda v, _: ""))


def time_axis_us(ax, tc_s: float, label_text: str | None = None):
    """A second x axis on top of ``ax`` in microseconds (t = t* x ``tc_s``); returns it (None when the
    time scale is unknown)."""
    import math

    if tc_s is None or not math.isfinite(tc_s) or tc_s <= 0:
        return None
    f = tc_s * 1e6
    sec = ax.secondary_xaxis("top", functions=(lambda t: t * f, lambda u: u / f))
    sec.set_xlabel(label_text or "t [µs]", fontsize=8)
    sec.tick_params(labelsize=7)
    return sec
