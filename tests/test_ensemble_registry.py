"""The inference-method protocol: every registered method declares what the CLI, the report and
the MCMC layer ask of it, and those ask the registry, not the method's name."""

import dataclasses

import pytest

from imrbayes.ensemble import METHODS, InferenceMethod
from imrbayes.errors import InputError


def test_every_method_declares_the_protocol():
    assert list(METHODS) == ["imr", "pimr", "en4dvar", "mienks"]
    for name, m in METHODS.items():
        assert issubclass(m, InferenceMethod) and m.name == name and m.label
        assert dataclasses.is_dataclass(m.settings_class) and callable(m.fit)
        assert m.n_forward_runs(m.settings_class(), 3, 120) > 0
    assert {m.name for m in METHODS.values() if m.gaussian_posterior} == {"en4dvar", "mienks"}
    paper = METHODS["en4dvar"].settings_class(likelihood="paper")
    assert METHODS["en4dvar"].n_forward_runs(paper, 2, 120) == 3 * 5 * 48 * 2 + 4 + 96
    # the default likelihood adds one run per experiment per cycle (the residual at the centre) and the
    # screened start (the prior mean and 96 draws per experiment; at most one more start in cycle 1)
    # (and 24 members, not the paper's 48; at least 3 iterations in cycles 2-3, not 5)
    e4 = METHODS["en4dvar"].settings_class
    assert (
        METHODS["en4dvar"].n_forward_runs(e4(req_tail="mean"), 2, 120)
        == (5 + 2 * 3) * 24 * 2 + 4 + 96 + 6 + (97 + 5 * 24 + 2) * 2
    )
    # auto (thermal: inline): the model's tail after cycle 1
    assert (
        METHODS["en4dvar"].n_forward_runs(e4(), 2, 120)
        == (5 + 2 * 3) * 24 * 2 + 4 + 96 + 6 + (97 + 5 * 24 + 2) * 2 + 3 * 2
    )
    assert (
        METHODS["en4dvar"].n_forward_runs(e4(n_ens=48, n_iter_later=5, req_tail="mean"), 2, 120)
        == 3 * 5 * 48 * 2 + 4 + 96 + 6 + (97 + 5 * 48 + 2) * 2
    )
    assert e4().resolved().n_ens == 24 and e4(likelihood="paper").resolved().n_ens == 48
    assert e4(n_ens=12, likelihood="paper").resolved().n_ens == 12
    assert e4().resolved().n_iter_later == 3 and e4(likelihood="paper").resolved().n_iter_later == 5
    assert e4(n_iter=2).resolved().n_iter_later == 2 and e4(n_iter_later=5).resolved().n_iter_later == 5
    with pytest.raises(InputError, match="n_ens"):
        e4(n_ens=0).check()
    cls = METHODS["mienks"].settings_class  # default likelihood: a pilot pass, then the reported one
    # the default likelihood: the pilot (24 members) and the reported pass (48); an upper bound,
    # windows whose cost settles stop before n_iter (min_iter)
    assert METHODS["mienks"].n_forward_runs(cls(), 2, 120) == 18 * 6 * (48 + 24) * 2
    assert METHODS["mienks"].n_forward_runs(cls(pilot_n_ens=None), 2, 120) == 2 * 18 * 6 * 48 * 2
    assert METHODS["mienks"].n_forward_runs(cls(likelihood="paper"), 2, 120) == 18 * 6 * 48 * 2


def test_cli_choices_come_from_the_registry():
    from imrbayes.cli.fit import fit_cmd

    opt = next(p for p in fit_cmd.params if p.name == "method")
    assert list(opt.type.choices) == list(METHODS)


def test_mcmc_refuses_a_method_without_gaussian_posterior():
    from imrbayes.ensemble import FitResult
    from imrbayes.mcmc.fit import fit_window_specs

    res = FitResult("imr", "nhkv", ("G", "mu"), {}, None, None)
    with pytest.raises(InputError, match="en4dvar or mienks"):
        fit_window_specs(None, None, None, res)
