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
        st = fm.initial_state(rmax[i : i + 1], req[i : i + 1])
        alone = fm.propagate(st, theta[i : i + 1], float(rows.max()), rows[i]).R_star[0]
        np.testing.assert_allclose(out.R_star[i], alone, rtol=0, atol=1e-12)
    shared = fm.simulate(theta, rmax, req, base).R_star
    assert np.max(np.abs(shared - out.R_star)) > 1e-3  # the rows really were used


def test_bad_shape_is_refused():
    fm = ForwardModel("nhkv")
    with pytest.raises(InputError):
        fm.simulate(np.array([[5e3, 0.05]] * 2), np.full(2, 3e-4), np.full(2, 4e-5), np.ones((3, 5)))


def test_one_compiled_signature_per_entry_point():
    """Shared or per-member times, one member or many, polytropic or thermal: the kernel sees one
    argument type per entry point. A second type (a read-only view, say) would be compiled in the
    calling process instead of loaded from the cache the compiling child wrote, and its results
    differ in the last bits from another process's (codegen.py) -- resumed runs would not match."""
    for bubble in ("polytropic", "thermal"):
        fm = ForwardModel("nhkv", options={"bubble": bubble})
        theta = np.array([[5e3, 0.05], [8e3, 0.1]])
        rmax, req = np.array([300e-6, 320e-6]), np.array([40e-6, 38e-6])
        base = np.linspace(0.05, 0.5, 5)
        fm.simulate(theta, rmax, req, base)
        fm.simulate(theta[:1], rmax[:1], req[:1], base)
        fm.simulate(theta, rmax, req, np.stack([base, base * 1.01]))
        st = fm.initial_state(rmax[:1], req[:1])
        fm.propagate(st, theta[:1], 0.5, base)
        fm.propagate(st, np.repeat(theta[:1, None, :], 2, axis=1), 0.5, base, breaks_star=np.array([0.2]))
        Runner(fm).simulate(theta, rmax, req, base)
    # every batch, serial or threaded, goes through the one threaded entry point (next test)
    assert len(fm.kernel.integrate_batch_parallel.signatures) == 1, fm.kernel.integrate_batch_parallel.signatures
    assert len(fm.kernel.integrate_batch.signatures) == 0, fm.kernel.integrate_batch.signatures


_ONE_PROCESS = """
import hashlib, sys
import numpy as np
from imrbayes.forward.model import ForwardModel
theta = np.array([[5e3, 0.05], [8e3, 0.1], [12e3, 0.15]])
out = []
for mode in sys.argv[1]:
    fm = ForwardModel("nhkv", parallel=mode == "p")
    R = fm.simulate(theta, np.full(3, 300e-6), np.full(3, 40e-6), np.linspace(0.05, 2.0, 40)).R_star
    out.append(hashlib.sha1(R.tobytes()).hexdigest())
print(" ".join(out))
"""


def test_serial_and_threaded_batches_agree_bitwise_in_any_process():
    """A batch run serially (worker processes, --workers N) and one spread over threads (the
    default, one process) give the same bits, whichever the process ran first. The serial and the
    threaded compilations of the member loop differed by ~1e-10 relative through a collapse, a
    process used whichever it loaded first, and (through MIEnKS-MDA's digest-seeded units, since
    fixed) that became 11 % of one bubble's G between --workers 1 and 2 (docs/open-work.md,
    sessions 57-58)."""
    import subprocess
    import sys

    hashes = {}
    for order in ("p", "s", "sp"):
        done = subprocess.run([sys.executable, "-c", _ONE_PROCESS, order], capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        hashes[order] = done.stdout.split()
    assert hashes["p"] == hashes["s"] == hashes["sp"][:1] == hashes["sp"][1:], hashes
