"""posterior.nc (``imrbayes.ensemble.output.posterior_tree``): every coordinate of a FitResult, the
tuple ones (``(dims, values)``, e.g. MIEnKS's ``window_start``) included, survives netCDF."""

import numpy as np

from imrbayes.ensemble import Observations
from imrbayes.ensemble.output import write_posterior
from imrbayes.ensemble.result import FitResult


def _windowed_result(n_win=4, n_draw=5):
    """A hand-made time-resolved result shaped like ``fit_mienks``'s."""
    rng = np.random.default_rng(0)
    t = np.arange(41) * 0.025
    starts = t[np.arange(n_win) * 10]
    return (
        FitResult(
            method="mienks",
            model="nhkv",
            param_names=("G", "mu"),
            estimate={},
            fitted=np.zeros((2, t.size)),
            fit_mask=np.ones((2, t.size), bool),
            posterior={"G": rng.normal(size=(1, n_draw, n_win)), "mu": rng.normal(size=(1, n_draw, n_win))},
            posterior_dims={"G": ["window"], "mu": ["window"]},
            coords={
                "window": np.arange(n_win),
                "bound": ["lower", "upper"],
                "window_start": ("window", starts),
                "window_span": (("window", "bound"), np.stack([starts, starts + 0.5], axis=1)),
            },
        ),
        t,
        starts,
    )


def test_tuple_coordinates_round_trip_through_posterior_nc(tmp_path):
    import xarray as xr

    res, t, starts = _windowed_result()
    obs = Observations(
        t, np.ones((2, t.size)), np.full(t.size, 1e-4), np.full(2, 300e-6), np.full(2, 40e-6), names=["a", "b"]
    )
    path = write_posterior(tmp_path / "posterior.nc", res, obs)
    post = xr.open_datatree(path)["posterior"]
    assert post["window_start"].dims == ("window",)
    np.testing.assert_array_equal(post["window_start"].values, starts)
    assert post["window_span"].dims == ("window", "bound")
    np.testing.assert_array_equal(post["window_span"].values[:, 1], starts + 0.5)
    assert list(post["bound"].values) == ["lower", "upper"]
    assert post["G"].dims == ("chain", "draw", "window")
    import arviz as az

    s = az.summary(az.from_netcdf(path), kind="stats", round_to="none")  # ArviZ still reads it
    assert np.all(np.isfinite(s["mean"]))
