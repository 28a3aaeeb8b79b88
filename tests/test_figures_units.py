"""Figures in physical units: the MCMC pair plot in kPa and Pa s, G(t)/mu(t) with the prior
band, a µs axis, a strain-rate axis and the windows the data barely moved, fit panels with the legend
off the data and sized for a screen, pIMR's curve labelled as fitting the collapse time only.

Each figure is captured before it is written (``save`` patched) and its artists inspected."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

import imrbayes.ensemble.figures as efig
import imrbayes.mcmc.figures as mfig


@pytest.fixture
def captured(monkeypatch, tmp_path):
    figs = []

    def keep(fig, path, dpi=None):
        figs.append(fig)
        return path

    monkeypatch.setattr(efig, "save", keep)
    monkeypatch.setattr(mfig, "save", keep)
    return figs


def _texts(fig):
    out = []
    for ax in fig.axes:
        out += [ax.get_xlabel(), ax.get_ylabel(), ax.get_title()]
    out += [t.get_text() for t in fig.texts]
    if fig._suptitle is not None:
        out.append(fig._suptitle.get_text())
    for lg in fig.legends:
        out += [t.get_text() for t in lg.get_texts()]
    return out


PRIOR = {
    "names": ["G", "mu"],
    "log_space": {"G": True, "mu": True},
    "prior_internal_mean": [8.601, -1.647],
    "prior_internal_cov": [[0.197, 0.0], [0.0, 0.163]],
}


def _mienks_result(n=41, n_exp=2):
    t = 0.025 * np.arange(n)
    R = np.stack([0.15 + 0.85 * np.cos(0.5 * np.pi * np.minimum(t / 0.9, 1.0)) for _ in range(n_exp)])
    est = lambda g, m, sg=1000.0, sm=0.02: {
        "G": {"mean": g, "sd": sg, "hdi95": [g - 2 * sg, g + 2 * sg]},  # noqa: E731
        "mu": {"mean": m, "sd": sm, "hdi95": [m - 2 * sm, m + 2 * sm]},
    }
    wins = []
    for j, (a, b) in enumerate([(0.0, 0.25), (0.125, 0.375), (0.25, 0.5), (0.375, 1.0)]):
        little = j < 2  # the first two windows: posterior as wide as the prior
        cov = [[0.19, 0.0], [0.0, 0.16]] if little else [[0.01, 0.0], [0.0, 0.01]]
        wins.append({"index": j, "t_star": [a, b], "cov_internal": cov, **est(7000.0 + 100 * j, 0.1)})
    tr = [{"t_star": float(x), **est(7000.0, 0.1)} for x in t[:-1]]
    return SimpleNamespace(
        method="mienks",
        param_names=("G", "mu"),
        windows=wins,
        time_resolved=tr,
        details={"parameter_space": PRIOR},
        fitted=R,
        fit_mask=np.ones_like(R, bool),
        rmse=0.01,
        per_experiment=[],
        time_scale_s=[27e-6, 28e-6],
    )


def test_time_resolved_figure_has_prior_band_us_axis_strain_rate_and_barely_moved_windows(captured, tmp_path):
    efig.time_resolved_figure(_mienks_result(), tmp_path / "p.png")
    fig = captured[0]
    texts = _texts(fig)
    assert "prior 95%" in texts and "data barely moved the prior" in texts
    assert "G [kPa]" in texts and r"$\mu$ [Pa s]" in texts
    # a µs axis on top and a strain-rate panel on a log axis covering 1e3..1e8 1/s
    subs = [c for ax in fig.axes for c in ax.child_axes]
    assert any("µs" in a.get_xlabel() for a in subs), [a.get_xlabel() for a in subs]
    rate = [ax for ax in fig.axes if "1/s" in ax.get_ylabel()]
    assert len(rate) == 1 and rate[0].get_yscale() == "log"
    lo, hi = rate[0].get_ylim()
    assert lo <= 1e3 and hi >= 1e8
    # the hatched spans cover the two barely-moved windows (merged: they overlap), not the others
    hatched = [p for ax in fig.axes for p in ax.patches if p.get_hatch()]
    xs = {round(float(p.get_x()), 3) for p in hatched} | {round(float(p.get_x() + p.get_width()), 3) for p in hatched}
    assert xs == {0.0, 0.375}, xs
    # the legend is off the data: a figure legend, none inside the panels
    assert fig.legends and all(ax.get_legend() is None for ax in fig.axes)


def test_time_resolved_figure_hatches_the_prior_dominated_windows_when_reported(captured, tmp_path):
    """Results that report ``windows[].prior_dominated`` (the chained prior weight) hatch exactly
    those windows, whatever their width says."""
    res = _mienks_result()
    for w in res.windows:
        w["prior_dominated"] = w["index"] in (0, 3)
        w["prior_weight"] = {"G": 0.3 if w["prior_dominated"] else 0.01, "mu": 0.01}
    efig.time_resolved_figure(res, tmp_path / "p.png")
    fig = captured[0]
    assert "prior-dominated window (prior weight > 5%)" in _texts(fig)
    hatched = [p for ax in fig.axes for p in ax.patches if p.get_hatch()]
    spans = {(round(float(p.get_x()), 3), round(float(p.get_x() + p.get_width()), 3)) for p in hatched}
    assert spans == {(0.0, 0.25), (0.375, 1.0)}, spans


def test_fit_figure_legend_off_the_data_and_screen_sized(captured, tmp_path):
    res = _mienks_result(n_exp=6)
    obs = SimpleNamespace(
        n_exp=6,
        t_star=0.025 * np.arange(41),
        R_star=res.fitted + 0.01,
        names=[f"e{i}" for i in range(6)],
        t_collapse_star=np.full(6, 0.9),
    )
    efig.fit_figure(obs, res, tmp_path / "fit.png")
    fig = captured[0]
    w, h = fig.get_size_inches()
    assert w <= 10.5 and h <= 8.0
    assert fig.legends and all(ax.get_legend() is None for ax in fig.axes)
    assert any("µs" in c.get_xlabel() for ax in fig.axes for c in ax.child_axes)


def test_pimr_fit_figure_says_collapse_time_only(captured, tmp_path):
    res = _mienks_result()
    res.method = "pimr"
    res.per_experiment = [{"t_collapse_fitted": 0.91}, {"t_collapse_fitted": 0.9}]
    obs = SimpleNamespace(
        n_exp=2,
        t_star=0.025 * np.arange(41),
        R_star=res.fitted,
        names=["a", "b"],
        t_collapse_star=np.array([0.9, 0.905]),
    )
    efig.fit_figure(obs, res, tmp_path / "fit.png")
    texts = " ".join(_texts(captured[0]))
    assert "collapse time only" in texts and "fitted collapse time" in texts and "measured collapse time" in texts


def test_mcmc_pair_figure_in_kpa_and_pa_s(captured, tmp_path):
    import xarray as xr

    rng = np.random.default_rng(0)
    d = rng.multivariate_normal([9.0, -2.0], [[0.02, 0.01], [0.01, 0.05]], size=(2, 500))
    node = xr.DataTree(
        children={
            "posterior": xr.DataTree(
                xr.Dataset({"log_G": (("chain", "draw"), d[..., 0]), "log_mu": (("chain", "draw"), d[..., 1])})
            )
        }
    )
    C = [[0.02, 0.01], [0.01, 0.05]]
    entry = {
        "index": 3,
        "t_star": [0.5, 0.75],
        "parameters": ["G", "mu"],
        "internal": ["log_G", "log_mu"],
        "ensemble": {"mean_internal": {"log_G": 9.05, "log_mu": -2.0}, "cov_internal": C},
        "mcmc": {"mean_internal": {"log_G": 9.0, "log_mu": -2.0}, "cov_internal": C},
        "agree": True,
        "kl_sym": 0.01,
        "kl_sample": 0.02,
        "w2": 0.1,
    }
    mfig.pair_figure(entry, node, tmp_path / "pair.png")
    fig = captured[0]
    texts = _texts(fig)
    assert "G [kPa]" in texts and r"$\mu$ [Pa s]" in texts
    assert not any("log_" in t for t in texts)
    scatter = [ax for ax in fig.axes if ax.get_visible() and ax.get_xscale() == "log" and ax.get_yscale() == "log"]
    assert len(scatter) == 1
    x = scatter[0].lines[0].get_xdata()  # the draws, in kPa: exp(9) Pa = 8.1 kPa
    assert math.isclose(float(np.median(x)), math.exp(9.0) * 1e-3, rel_tol=0.05)
