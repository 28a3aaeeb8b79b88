"""Per-member output times: each row of a (N, m) ``t_eval`` gives what a run of that member alone
on that row gives (the nuisance time offsets of the methods rely on it)."""

import numpy as np
import pytest

from imrbayes.errors import InputError
from imrbayes.forward import ForwardModel, Runner


@pytest.mark.parametrize("bubble", ["polytropic", "thermal"])
def test_rows_match_single_member_runs(bubble):
    fm = ForwardModel("nhkv", options={"bubble": bubble})
    theta = np.array([[5e3, 0.05], [8e3, 0.1], [2e3, 0.02]])
    rmax = np.array([300e-6, 320e-6, 280e-6])
    req = rmax / 8.0
    base = np.linspace(0.05, 2.5, 40)
    rows = np.stack([base * 1.03, base + 0.011, base * 0.97 + 0.004])
    out = Runner(fm).simulate(theta, rmax, req, rows)
    assert out.R_star.shape == (3, 40)
    for i in range(3):
        # the same end time: a run that ends at its own last output lands its last step there
        st = fm.initial_state(rmax[i:i + 1], req[i:i + 1])
        alone = fm.propagate(st, theta[i:i + 1], float(rows.max()), rows[i]).R_star[0]
        np.testing.assert_allclose(out.R_star[i], alone, rtol=0, atol=1e-12)
    shared = fm.simulate(theta, rmax, req, base).R_star
    assert np.max(np.abs(shared - out.R_star)) > 1e-3      # the rows really were used


def test_bad_shape_is_refused():
    fm = ForwardModel("nhkv")
    with pytest.raises(InputError):
        fm.simulate(np.array([[5e3, 0.05]] * 2), np.full(2, 3e-4), np.full(2, 4e-5), np.ones((3, 5)))
