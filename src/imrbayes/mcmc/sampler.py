"""emcee sampling of a window target: independent ensembles, stop on convergence, HDF5 resume, ArviZ output.

:func:`run_mcmc` runs ``n_chains`` (2 by default, at least 2) *independent* emcee ensembles of
``n_walkers`` walkers each, every ensemble from its own seed and its own start drawn from
N(start_mean, init_scale^2 start_cov) (typically the ensemble smoother's Gaussian posterior,
over-dispersed by ``init_scale`` = 2 so that R-hat can see chains that have not forgotten their
start). Walkers of one ensemble are not independent chains (arviz issues #2156, #977), so every
convergence number here treats **one ensemble as one chain**:

* R-hat, bulk/tail ESS and MCSE come from ArviZ on a posterior whose ``chain`` is the ensemble and
  whose ``draw`` runs over the kept (step, walker) pairs **walker by walker** (draw = walker * k +
  step index): each walker's trajectory is contiguous, so the autocorrelation that ESS uses is
  each walker's own, and the split halves of R-hat are two halves of the walkers;
* emcee's integrated autocorrelation time tau (per ensemble and parameter, on the last 3/4 of the
  chain) with the rule of at least 50 tau steps (``tau_ok``);
* burn-in (default: max(n/4, 3 tau), at most n/2) and thinning (default: tau/2, more if needed to
  keep at most ``max_draws`` draws per ensemble).

Stopping (``stop="converged"``, the default): the ensembles advance together to a check point,
where the draws that would be kept are diagnosed exactly as :func:`imrbayes.mcmc.compare.compare_window`
diagnoses them (same burn-in, thinning, ArviZ R-hat and bulk/tail ESS); sampling stops at the first
check where max R-hat <= ``rhat_max``, min bulk and tail ESS >= ``ess_min`` and every ensemble is
at least ``tau_rule`` tau long (emcee's guidance: check every few tau, stop when the estimates are
trustworthy). Checks start at ``min_steps`` and follow every :data:`CHECK_EVERY_TAU` tau (at least 10 steps),
jumping ahead (at most doubling the length) to where the tau rule or the ESS would be met.
``n_steps`` is the **hard cap**: a run that reaches it unconverged says so (``stop_reason = "cap"``,
``cap_hit``), and its comparison is undecided (``agree: null``). ``stop="fixed"`` runs exactly
``n_steps`` (the earlier behaviour). The check schedule depends only on the chain, so it is
replayed from the HDF5 file on resume and a resumed run stops where the uninterrupted one did.

Moves (``moves``): a weighted mixture of emcee moves named ``stretch``, ``de`` (differential
evolution), ``snooker`` (the DE snooker, corrected: :func:`snooker_move`), ``walk``, ``indep``
(independence Metropolis-Hastings from a Student-t on the start Gaussian: :func:`independence_move`),
``blocks`` and ``ridge`` (per-experiment nuisance blocks and the parameters with the nuisances'
regression: :mod:`imrbayes.mcmc.blocks`), e.g. ``"indep:0.7,de:0.3"``. The default ``"auto"``
is ``"indep:0.7,de:0.3"`` (with ``indep_adapt`` = 50: each ensemble's independence
proposal re-placed once on its own draws; before it
``"de:0.8,snooker:0.2"``) and ``"ridge:0.5,blocks:0.5"`` on windows with sampled nuisances. On those, the start Gaussian is first
placed on the target (``place``, :mod:`imrbayes.mcmc.laplace`), and a window with one nuisance per
experiment whose placed fit is Gaussian (:data:`LAPLACE_MAX_RESIDUAL`) is sampled by independent
walkers on it instead (:data:`LAPLACE_INDEP`). The
choice is measured by evaluations to convergence and ESS per forward solve (docs/methods.md).

Sampling is seeded: ensemble c uses ``emcee.State(p0_c, random_state=RandomState(seed_c).get_state())``
with seeds spawned from ``seed`` by ``numpy.random.SeedSequence``. With an HDF5 file every step of
ensemble c is written to the group ``{name}/chain_{c}`` (``emcee.backends.HDFBackend``); calling
:func:`run_mcmc` again with the same file and name **resumes**: each ensemble continues from its
last saved step and random state (``run_mcmc(None, n)`` semantics: steps are appended), so an
interrupted run plus its resumption gives the same chains as one uninterrupted run.

``lockstep=True`` (default) runs the ensembles in threads that share one batched forward call per
round (all ensembles' walker batches x experiments in one ``propagate``); the chains are the same
as running the ensembles one after the other (``lockstep=False``).
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import threading
import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imrbayes.errors import InputError
from imrbayes.mcmc.laplace import quadratic_placement

__all__ = [
    "MCMCSettings",
    "MCMCRun",
    "run_mcmc",
    "integrated_tau",
    "parse_moves",
    "emcee_moves",
    "snooker_move",
    "convergence_check",
    "resolve_moves",
    "AUTO_MOVES",
    "MOVE_NAMES",
    "STOP_REASONS",
]

_H5_LOCK = threading.RLock()


def _hdf_backend(path, name, read_only=False):
    """An ``emcee.backends.HDFBackend`` whose file accesses are serialised (threads share the file)."""
    import emcee

    class _Locked(emcee.backends.HDFBackend):
        @contextlib.contextmanager
        def open(self, mode="r"):
            with _H5_LOCK:
                f = super().open(mode)
                try:
                    yield f
                finally:
                    f.close()

    return _Locked(str(path), name=name, read_only=read_only)


#: emcee moves by name (``MCMCSettings.moves``). ``snooker`` is :func:`snooker_move` (the corrected
#: DE snooker), not emcee 3.1.6's ``DESnookerMove``, which does not sample the target (docs/methods.md).
#: ``blocks`` and ``ridge`` (:mod:`imrbayes.mcmc.blocks`) use the target's per-experiment nuisance structure.
MOVE_NAMES = ("stretch", "de", "snooker", "walk", "indep", "blocks", "ridge")

#: ``moves="auto"`` (the default): the mixture for windows without sampled nuisances, and for those
#: with them (per-experiment Rmax / time of the maximum / Req: 5.7x fewer evaluations to convergence
#: on a 20-coordinate camera window, docs/methods.md)
AUTO_MOVES = {"plain": "indep:0.7,de:0.3", "nuisances": "ridge:0.5,blocks:0.5"}
#: On a window with sampled nuisances ``moves="auto"`` first places the start Gaussian on the target
#: (``place="auto"`` -> ``"laplace"``); when the quadratic fit of its last round leaves a residual sd of
#: at most :data:`LAPLACE_MAX_RESIDUAL` [nats] and no experiment has more than
#: :data:`LAPLACE_MAX_BLOCK` nuisances, the window is sampled by independent walkers on the placed
#: proposal (:data:`LAPLACE_INDEP`), else by :data:`AUTO_MOVES` ``["nuisances"]`` from the placed start.
#: Measured (docs/methods.md, "The MCMC check"): on the verification window (Rmax alone per experiment, d = 7)
#: residual 0.18-0.48 nats, the independent walkers' draws as the block moves' (sds within 6 %) on
#: 13-22x fewer evaluations; on a camera window (Rmax, time of the maximum and Req, d = 20) 0.45-0.68
#: nats, acceptance 0.4, and G's sd 15 % short of the block moves' (the alignment's non-Gaussian
#: conditional posterior: a tail the fixed proposal under-samples in a finite run) -- so not there.
LAPLACE_MAX_RESIDUAL = 0.6
LAPLACE_MAX_BLOCK = 1
LAPLACE_INDEP = {"moves": "indep", "indep_dof": 20.0, "indep_scale": 1.1, "indep_adapt": 0}
#: rounds of the quadratic placement of the start (``place="laplace"``)
PLACE_ROUNDS = 3
#: after a failed convergence check the next comes this many tau later (emcee: check every few tau)
CHECK_EVERY_TAU = 5.0


def nuisances_per_experiment(target) -> int:
    """The most sampled nuisances any one experiment of ``target`` has (0 without nuisance blocks)."""
    return max((np.size(b) for b in getattr(target, "nuisance_blocks", None) or ()), default=0)


def resolve_moves(spec: str, target) -> str:
    """``spec``, or for ``"auto"`` the :data:`AUTO_MOVES` mixture that suits ``target``."""
    if spec.strip().lower() != "auto":
        return spec
    blocks = getattr(target, "nuisance_blocks", None)
    return AUTO_MOVES["nuisances" if blocks is not None and any(np.size(b) for b in blocks) else "plain"]


#: stop reasons reported in ``MCMCRun.stop`` / ``diagnostics()["stop_reason"]``
STOP_REASONS = ("converged", "cap", "fixed")


def independent_walkers(spec: str) -> bool:
    """True when every move of ``spec`` is ``indep``: each walker is then an independent
    Metropolis-Hastings chain with a fixed proposal, so the walker count does not need to span the
    parameter space (the >= 2 d rule of the ensemble moves does not apply)."""
    return spec.strip().lower() != "auto" and all(n == "indep" for n, _ in parse_moves(spec))


def parse_moves(spec: str) -> list:
    """``"de:0.8,snooker:0.2"`` -> ``[(name, weight)]`` with weights summing to 1 (a bare name has weight 1)."""
    if not isinstance(spec, str) or not spec.strip():
        raise InputError("moves", f"expected e.g. 'de:0.8,snooker:0.2' or 'stretch', got {spec!r}")
    out = []
    for part in spec.split(","):
        name, _, w = part.strip().partition(":")
        name = name.strip().lower()
        if name not in MOVE_NAMES:
            raise InputError("moves", f"unknown move {name!r} (known: {', '.join(MOVE_NAMES)})")
        try:
            weight = float(w) if w.strip() else 1.0
        except ValueError:
            raise InputError("moves", f"weight of {name!r} must be a number, got {w!r}") from None
        if not (math.isfinite(weight) and weight > 0):
            raise InputError("moves", f"weight of {name!r} must be positive, got {w!r}")
        out.append((name, weight))
    total = sum(w for _, w in out)
    return [(n, w / total) for n, w in out]


def snooker_move(gammas: float = 1.7):
    """The differential-evolution snooker move of ter Braak & Vrugt (2008) as an emcee move.

    emcee 3.1.6's ``DESnookerMove`` divides the direction by the square root of its length (not a
    unit vector: the step becomes a multiplicative one whose reverse is not proposed with the same
    density) and applies half the Jacobian exponent; it does not leave the target invariant -- on a
    2-D Gaussian its walkers have 0.6-0.7 of the true sd, and 0.95 when mixed 20 % with DE
    (``tests/test_mcmc_sampler.py``; fixed upstream in dfm/emcee#531, after 3.1.6). This is the
    published move: the walker moves along the line through it and a third walker z by gamma
    times the difference of the projections of two others, accepted with the extra factor
    (|x' - z| / |x - z|)^(d - 1).
    """
    import emcee

    class _Snooker(emcee.moves.RedBlueMove):
        def __init__(self):
            self.gammas = float(gammas)
            super().__init__(nsplits=4)

        def get_proposal(self, s, c, random):
            ns, nc, d = len(s), [len(x) for x in c], s.shape[1]
            q = np.empty_like(s)
            metropolis = np.empty(ns, dtype=np.float64)
            for i in range(ns):
                w = np.array([c[j][random.randint(nc[j])] for j in range(3)])
                random.shuffle(w)
                z, z1, z2 = w
                delta = s[i] - z
                norm = np.linalg.norm(delta)
                u = delta / norm
                q[i] = s[i] + u * self.gammas * (np.dot(u, z1) - np.dot(u, z2))
                metropolis[i] = np.log(np.linalg.norm(q[i] - z)) - np.log(norm)
            return q, (d - 1.0) * metropolis

    return _Snooker()


class _StudentTProposal:
    """Independence proposal from a multivariate Student-t; ``place`` moves it (between steps)."""

    def __init__(self, center, cov, scale: float, dof: float):
        self.scale, self.nu = float(scale), float(dof)
        self.place(center, cov)

    def place(self, center, cov):
        self.m = np.asarray(center, dtype=np.float64).ravel()
        cov = np.asarray(cov, dtype=np.float64).reshape(self.m.size, self.m.size)
        self.L = self.scale * np.linalg.cholesky(0.5 * (cov + cov.T))

    def log_q(self, x):  # up to a constant: the constant cancels
        u = np.linalg.solve(self.L, (np.atleast_2d(x) - self.m).T)
        return -0.5 * (self.nu + self.m.size) * np.log1p(np.sum(u * u, axis=0) / self.nu)

    def __call__(self, x0, random):
        k, d = x0.shape[0], self.m.size
        z = random.standard_normal((k, d))
        w = np.sqrt(self.nu / random.chisquare(self.nu, size=k))
        q = self.m + (z * w[:, None]) @ self.L.T
        return q, self.log_q(x0) - self.log_q(q)


def independence_move(center, cov, scale: float = 1.5, dof: float = 4.0):
    """Independence Metropolis-Hastings as an emcee move: every walker proposes a fresh draw from a
    fixed multivariate Student-t (``dof`` degrees of freedom, location ``center`` (d,), scale matrix
    ``scale**2 cov`` (d, d), internal coordinates), accepted with the ratio of proposal densities.

    The proposal does not depend on the chain, so the move leaves any target invariant whatever
    ``center`` and ``cov`` are; they decide only its efficiency. Placed on the ensemble smoother's
    Gaussian (the start), a window that is close to Gaussian is sampled with an autocorrelation time
    of a few steps, where differential evolution needs 7-10 (docs/methods.md); the t's tails keep the
    ratio p/q bounded when the Gaussian is too narrow or off-centre, and the DE moves mixed with it
    still explore what the proposal covers poorly. ``move.proposal.place(center, cov)`` re-places it
    between steps (``MCMCSettings.indep_adapt``).
    """
    import emcee

    prop = _StudentTProposal(center, cov, scale, dof)
    move = emcee.moves.MHMove(prop, ndim=prop.m.size)
    move.proposal = prop
    return move


def emcee_moves(
    spec: str, center=None, cov=None, indep_scale: float = 1.5, indep_dof: float = 4.0, target=None
) -> list:
    """emcee move objects with weights for ``EnsembleSampler(moves=...)``; ``indep`` needs ``center``
    and ``cov`` (the start Gaussian, :func:`independence_move`), ``blocks`` and ``ridge`` the
    ``target`` (a :class:`~imrbayes.mcmc.target.WindowTarget`; ``blocks`` one with sampled nuisances)."""
    import emcee

    from imrbayes.mcmc.blocks import BlockMove, RidgeMove

    def need_target(name):
        if target is None or not hasattr(target, "nuisance_blocks"):
            raise InputError("moves", f"the {name!r} move needs a window target with per-experiment nuisances")
        if name == "blocks" and not any(b.size for b in target.nuisance_blocks):
            raise InputError(
                "moves", "the 'blocks' move needs sampled nuisances; this window has none (use e.g. 'indep:0.7,de:0.3')"
            )
        return target

    make = {
        "stretch": emcee.moves.StretchMove,
        "de": emcee.moves.DEMove,
        "snooker": snooker_move,
        "walk": emcee.moves.WalkMove,
        "indep": lambda: independence_move(center, cov, indep_scale, indep_dof),
        "blocks": lambda: BlockMove(need_target("blocks")),
        "ridge": lambda: RidgeMove(need_target("ridge").prior.n),
    }
    return [(make[n](), w) for n, w in parse_moves(spec)]


@dataclass
class MCMCSettings:
    """emcee settings of :func:`run_mcmc` (the stop rule, moves and placement: module docstring)."""

    n_walkers: int = 8
    """Walkers per ensemble (even, >= 2 d unless the walkers are independent; default 8)."""
    n_steps: int = 5000
    """Hard cap on steps per ensemble (``stop="fixed"``: exactly these; default 5000)."""
    n_chains: int = 2
    """Independent ensembles, >= 2, across which R-hat is computed (default 2)."""
    stop: str = "converged"
    """``"converged"`` (stop at the first check where the criteria hold; default) or ``"fixed"``."""
    min_steps: int = 100
    """Steps at the first convergence check (default 100)."""
    rhat_max: float = 1.01
    """Largest R-hat of a converged run (default 1.01, as ``compare.THRESHOLDS``)."""
    ess_min: float = 400.0
    """Smallest bulk and tail ESS of a converged run (default 400)."""
    moves: str = "auto"
    """emcee move mixture, e.g. ``"indep:0.7,de:0.3"`` (default ``"auto"``: :data:`AUTO_MOVES`)."""
    burn: int | None = None
    """Steps discarded (default None: automatic, module docstring)."""
    thin: int | None = None
    """Keep every ``thin``-th step (default None: automatic, module docstring)."""
    max_draws: int = 1000
    """Most draws kept per ensemble (thinning is raised to respect it; default 1000)."""
    init_scale: float = 2.0
    """Start spread in start-covariance sd (> 1: over-dispersed; default 2)."""
    indep_scale: float = 1.5
    """Scale of the ``indep`` move's Student-t proposal, in start sd (default 1.5)."""
    indep_dof: float = 4.0
    """Degrees of freedom of the ``indep`` move's Student-t proposal (default 4)."""
    indep_adapt: int = 50
    """Step at which each ensemble re-places its ``indep`` proposal once on its own draws (0: never; default 50)."""
    place: str = "auto"
    """Start placement: ``"start"``, ``"laplace"`` (quadratic fit to the target) or ``"auto"`` (default)."""
    tau_rule: float = 50.0
    """A converged chain is at least this many autocorrelation times long (default 50)."""
    lockstep: bool = True
    """Share forward batches between the ensembles (threads); False runs them one by one (default on)."""
    loglik: bool = True
    """Recompute the pointwise log-likelihood of the kept draws for the DataTree (default on)."""
    quadrature: bool = False
    """Also compute the exact grid posterior of 2-parameter windows (default off)."""

    def check(self, ndim: int):
        need = 2 if independent_walkers(self.moves) else 2 * ndim
        if self.n_walkers < need or self.n_walkers % 2:
            raise InputError(
                "n_walkers",
                f"needs an even number >= {need}"
                + ("" if need == 2 else f" (2 x {ndim} parameters)")
                + f", got {self.n_walkers}",
            )
        if self.n_chains < 2:
            raise InputError("n_chains", f"R-hat needs at least 2 independent ensembles, got {self.n_chains}")
        if self.n_steps < 4:
            raise InputError("n_steps", f"must be at least 4, got {self.n_steps}")
        if self.stop not in ("converged", "fixed"):
            raise InputError("stop", f"must be 'converged' or 'fixed', got {self.stop!r}")
        if not 4 <= self.min_steps:
            raise InputError("min_steps", f"must be at least 4, got {self.min_steps}")
        if not self.rhat_max >= 1.0:
            raise InputError("rhat_max", f"must be >= 1, got {self.rhat_max}")
        if not self.ess_min > 0:
            raise InputError("ess_min", f"must be positive, got {self.ess_min}")
        if self.burn is not None and not 0 <= self.burn < self.n_steps:
            raise InputError("burn", f"must lie in [0, n_steps), got {self.burn}")
        if self.thin is not None and self.thin < 1:
            raise InputError("thin", f"must be >= 1, got {self.thin}")
        if not self.init_scale > 0:
            raise InputError("init_scale", "must be positive")
        if not (math.isfinite(self.indep_scale) and self.indep_scale > 0):
            raise InputError("indep_scale", f"must be positive, got {self.indep_scale}")
        if not (math.isfinite(self.indep_dof) and self.indep_dof > 0):
            raise InputError("indep_dof", f"must be positive, got {self.indep_dof}")
        if self.place not in ("auto", "start", "laplace"):
            raise InputError("place", f"must be 'auto', 'start' or 'laplace', got {self.place!r}")
        if not (self.indep_adapt == 0 or self.indep_adapt >= 4):
            raise InputError("indep_adapt", f"must be 0 (never) or a step >= 4, got {self.indep_adapt}")
        moves = [
            m
            for spec in (AUTO_MOVES.values() if self.moves.strip().lower() == "auto" else [self.moves])
            for m in parse_moves(spec)
        ]
        if any(n in ("de", "snooker") for n, _ in moves) and self.n_walkers < 6:
            raise InputError(
                "n_walkers",
                f"differential-evolution moves need >= 6 walkers (3 per half: "
                f"more than one difference vector), got {self.n_walkers}",
            )


def integrated_tau(chain) -> np.ndarray:
    """emcee's integrated autocorrelation time of ``chain`` (n_steps, n_walkers, d) -> (d,) [steps],
    never raising (the estimate is returned even for chains shorter than 50 tau)."""
    import emcee

    with np.errstate(invalid="ignore", divide="ignore"):
        tau = np.asarray(emcee.autocorr.integrated_time(np.asarray(chain), tol=0, quiet=True), dtype=np.float64)
    return np.where(np.isnan(tau), np.inf, tau)  # a coordinate that never moved: no finite tau


def burn_thin(n: int, tau_max: float, s: MCMCSettings, n_walkers: int) -> tuple:
    """(burn, thin) of a chain of n steps (module docstring; the same at every check and at the end;
    a chain without a finite tau keeps its second half, unthinned)."""
    finite = math.isfinite(tau_max)
    burn = (
        s.burn if s.burn is not None else (int(min(n // 2, max(n // 4, math.ceil(3 * tau_max)))) if finite else n // 2)
    )
    burn = min(burn, n - 1)
    thin = s.thin if s.thin is not None else (max(1, int(tau_max // 2)) if finite else 1)
    thin = max(thin, math.ceil((n - burn) / max(1, s.max_draws // n_walkers)))  # at most max_draws per chain
    return int(burn), int(thin)


def walker_major(chain, burn: int, thin: int) -> np.ndarray:
    """(C, n, W, d) chain -> (C, W k, d) kept draws, walker by walker (draw = walker * k + kept step)."""
    x = np.asarray(chain)[:, burn::thin]  # (C, k, W, d)
    C, k, W, d = x.shape
    return x.transpose(0, 2, 1, 3).reshape(C, W * k, d)


def convergence_check(chain, s: MCMCSettings) -> dict:
    """Diagnose a (C, n, W, d) chain as the final run would be: tau per ensemble (last 3/4), burn-in
    and thinning, ArviZ R-hat and bulk/tail ESS of the walker-major kept draws (one chain per
    ensemble), the tau rule. ``ok`` when every criterion of :class:`MCMCSettings` holds."""
    from imrbayes.mcmc.compare import mcmc_summary

    chain = np.asarray(chain)
    C, n, W, d = chain.shape
    tau = np.stack([integrated_tau(chain[c, n // 4 :]) for c in range(C)])  # (C, d)
    tau_max = float(np.max(tau)) if np.all(np.isfinite(tau)) else float("inf")
    out = {
        "n": int(n),
        "tau_max": tau_max,
        "n_over_tau": float(n / tau_max) if tau_max > 0 else float("inf"),
        "rhat_max": float("inf"),
        "ess_bulk_min": 0.0,
        "ess_tail_min": 0.0,
    }
    if math.isfinite(tau_max):
        burn, thin = burn_thin(n, tau_max, s, W)
        x = walker_major(chain, burn, thin)
        if x.shape[1] >= 4 and C >= 2:
            import arviz as az

            names = [f"x{i}" for i in range(d)]
            dt = az.from_dict({"posterior": {v: x[:, :, i] for i, v in enumerate(names)}})
            with np.errstate(all="ignore"):
                summ = mcmc_summary(dt, names)
            vals = lambda col: [
                v if np.isfinite(v) else (np.inf if col == "r_hat" else 0.0)  # noqa: E731
                for v in summ[col].values()
            ]
            out.update(
                {
                    "burn": burn,
                    "thin": thin,
                    "rhat_max": float(max(vals("r_hat"))),
                    "ess_bulk_min": float(min(vals("ess_bulk"))),
                    "ess_tail_min": float(min(vals("ess_tail"))),
                }
            )
    crit = {
        "rhat": out["rhat_max"] <= s.rhat_max,
        "ess_bulk": out["ess_bulk_min"] >= s.ess_min,
        "ess_tail": out["ess_tail_min"] >= s.ess_min,
        "tau_rule": bool(np.all(n >= s.tau_rule * tau.max(axis=1))) if math.isfinite(tau_max) else False,
    }
    out["criteria"] = crit
    out["ok"] = bool(all(crit.values()))
    return out


def check_line(chk: dict, s: MCMCSettings, n_evals: int | None = None, resumed: bool = False) -> str:
    """One line on a convergence check: where each criterion stands against its threshold
    (``n_evals``: evaluations made by this call, so only since the resume of a resumed run)."""
    miss = [k for k, v in chk["criteria"].items() if not v]
    evals = (f", {n_evals:,} evaluations" + (" since the resume" if resumed else "")) if n_evals is not None else ""
    if not math.isfinite(chk["tau_max"]):  # too few steps for emcee's estimate: nothing else is either
        return f"{chk['n']} steps{evals}: too short to estimate tau yet -- not yet: " + ", ".join(miss)
    return (
        f"{chk['n']} steps{evals}: tau {chk['tau_max']:.1f} ({chk['n_over_tau']:.1f} tau, needs "
        f"{s.tau_rule:g}), R-hat {chk['rhat_max']:.3f} (<= {s.rhat_max:g}), ESS bulk {chk['ess_bulk_min']:.0f} "
        f"tail {chk['ess_tail_min']:.0f} (>= {s.ess_min:g}) -- "
        + ("converged" if chk["ok"] else "not yet: " + ", ".join(miss))
    )


def _next_check(n: int, chk: dict, s: MCMCSettings) -> int:
    """The next check point after a failed check at n steps (module docstring), capped at n_steps."""
    tau = chk["tau_max"] if math.isfinite(chk["tau_max"]) else float(n)
    step = max(10, math.ceil(CHECK_EVERY_TAU * tau))
    want = n + step
    if not chk["criteria"]["tau_rule"]:
        want = max(want, math.ceil(s.tau_rule * tau))
    ess = min(chk["ess_bulk_min"], chk["ess_tail_min"])
    if 0 < ess < s.ess_min:  # ESS grows about linearly with the kept length
        burn = chk.get("burn", n // 4)
        want = max(want, burn + math.ceil(1.1 * (n - burn) * s.ess_min / ess))
    return int(min(s.n_steps, n + min(max(step, want - n), n)))  # at most double the length


class _Batcher:
    """Lets K samplers, each in its own thread, share one vectorised log-prob call per round.

    Every active party submits a batch; when all have (or the others have left), one thread
    evaluates the concatenation and hands the pieces back. Parties leave when their chain ends, so
    chains of different lengths (a resumed run) never deadlock. An exception in the evaluation is
    raised in every party.
    """

    def __init__(self, fn, parties: int):
        self.fn = fn
        self.active = int(parties)
        self._cond = threading.Condition()
        self._inbox: dict = {}
        self._outbox: dict = {}
        self._error: BaseException | None = None
        self.n_rounds = 0

    def _flush(self):
        keys = sorted(self._inbox)
        sizes = [len(self._inbox[k]) for k in keys]
        X = np.concatenate([self._inbox[k] for k in keys], axis=0)
        self._inbox.clear()
        try:
            lp = np.asarray(self.fn(X), dtype=np.float64)
        except BaseException as exc:  # noqa: BLE001 - re-raised in every party
            self._error = exc
        else:
            for k, part in zip(keys, np.split(lp, np.cumsum(sizes)[:-1])):
                self._outbox[k] = part
            self.n_rounds += 1
        self._cond.notify_all()

    def call(self, key, x):
        x = np.atleast_2d(np.asarray(x, dtype=np.float64))
        with self._cond:
            if self._error is None:
                self._inbox[key] = x
                if len(self._inbox) >= self.active:
                    self._flush()
                while key not in self._outbox and self._error is None:
                    self._cond.wait()
            if self._error is not None:
                raise self._error
            return self._outbox.pop(key)

    def leave(self):
        with self._cond:
            self.active -= 1
            if self._inbox and len(self._inbox) >= self.active and self._error is None:
                self._flush()

    def abort(self, exc: BaseException):
        with self._cond:
            self._error = exc
            self._cond.notify_all()


@dataclass
class MCMCRun:
    """Chains of ``n_chains`` independent emcee ensembles and their diagnostics.

    Attributes
    ----------
    names : tuple of str                  parameter names (SI)
    internal_names : list of str          sampled coordinates (``log_G`` ...)
    positive : (d,) bool                  log-transformed parameters
    chain : (n_chains, n_steps, n_walkers, d)   internal coordinates, every step
    log_prob : (n_chains, n_steps, n_walkers)   log-posterior of every walker and step
    acceptance : (n_chains,)              mean acceptance fraction per ensemble
    tau : (n_chains, d)                   integrated autocorrelation time [steps], last 3/4 of the chain
    burn, thin : int                      steps discarded / thinning used for the draws
    seeds : list of int                   emcee RandomState seed of each ensemble
    runtime_s : float                     wall time of this call (sampling + diagnostics)
    n_evals : int                         parameter sets evaluated by this call
    steps_run : list of int               steps each ensemble ran in this call (0 if complete)
    backend : dict or None                {"path", "name"} of the HDF5 file
    settings : dict
    failed_chains : dict                  ensemble index (of the requested ones) -> error, for
                                          ensembles that raised and were left out (contained)
    stop : dict                           how sampling ended: ``rule`` (settings.stop), ``reason``
                                          ("converged", "cap" or "fixed"), ``cap`` (n_steps),
                                          ``cap_hit``, ``checks`` (every convergence check: n, tau_max,
                                          rhat_max, ess_bulk_min, ess_tail_min, criteria, ok)
    """

    names: tuple
    internal_names: list
    positive: np.ndarray
    chain: np.ndarray
    log_prob: np.ndarray
    acceptance: np.ndarray
    tau: np.ndarray
    burn: int
    thin: int
    seeds: list
    runtime_s: float
    n_evals: int
    steps_run: list
    backend: dict | None = None
    settings: dict = field(default_factory=dict)
    failed_chains: dict = field(default_factory=dict)
    stop: dict = field(default_factory=dict)

    @property
    def n_chains(self) -> int:
        return self.chain.shape[0]

    @property
    def n_steps(self) -> int:
        return self.chain.shape[1]

    @property
    def n_walkers(self) -> int:
        return self.chain.shape[2]

    @property
    def tau_max(self) -> float:
        return float(np.max(self.tau))

    @property
    def tau_ok(self) -> np.ndarray:
        """(n_chains,) True where n_steps >= tau_rule x max tau of that ensemble."""
        rule = float(self.settings.get("tau_rule", 50.0))
        return self.n_steps >= rule * self.tau.max(axis=1)

    def kept_steps(self) -> np.ndarray:
        return np.arange(self.burn, self.n_steps, self.thin)

    def draws(self):
        """Kept draws, walker-major: ``(samples (n_chains, n_draws, d), lp (n_chains, n_draws),
        walker (n_draws,), step (n_draws,))`` with draw index = walker * k + kept-step index."""
        steps = self.kept_steps()
        k = steps.size
        x = self.chain[:, steps]  # (C, k, W, d)
        lp = self.log_prob[:, steps]
        C, W, d = self.n_chains, self.n_walkers, self.chain.shape[-1]
        samples = x.transpose(0, 2, 1, 3).reshape(C, W * k, d)
        lpf = lp.transpose(0, 2, 1).reshape(C, W * k)
        return samples, lpf, np.repeat(np.arange(W), k), np.tile(steps, W)

    def diagnostics(self) -> dict:
        """JSON-able per-run diagnostics (tau, the 50-tau rule, acceptance, burn/thin)."""
        rule = float(self.settings.get("tau_rule", 50.0))
        return {
            "n_chains": self.n_chains,
            "n_walkers": self.n_walkers,
            "n_steps": self.n_steps,
            "burn": self.burn,
            "thin": self.thin,
            "draws_per_chain": int(self.kept_steps().size * self.n_walkers),
            "tau": {n: self.tau[:, i].tolist() for i, n in enumerate(self.internal_names)},
            "tau_max": self.tau_max,
            "n_steps_over_tau": float(self.n_steps / self.tau_max),
            "tau_rule": rule,
            "tau_ok": [bool(v) for v in self.tau_ok],
            "all_tau_ok": bool(np.all(self.tau_ok)),
            "acceptance": self.acceptance.tolist(),
            "seeds": list(self.seeds),
            "runtime_s": self.runtime_s,
            "n_evals": self.n_evals,
            "steps_run": list(self.steps_run),
            "backend": self.backend,
            "failed_chains": {str(k): v for k, v in self.failed_chains.items()},
            "moves": self.settings.get("moves"),
            "stop_rule": self.stop.get("rule"),
            "stop_reason": self.stop.get("reason"),
            "cap": self.stop.get("cap"),
            "cap_hit": bool(self.stop.get("cap_hit", False)),
            "checks": list(self.stop.get("checks", [])),
            "evals_per_chain": int(self.n_steps * self.n_walkers),
            **({"placement": self.settings["placement"]} if "placement" in self.settings else {}),
            "chain_definition": "one chain = one independent emcee ensemble; draws walker-major",
        }

    def to_datatree(self, target=None, loglik: bool = True):
        """ArviZ DataTree with (chain, draw) arrays (``az.from_dict``).

        ``posterior``: every parameter in SI (``G``, ``mu``) and the sampled coordinates
        (``log_G``, ``log_mu``); ``sample_stats``: ``lp`` (log-posterior), ``walker``, ``step``.
        With a ``target``: ``observed_data`` ``R`` (experiment, time), ``constant_data`` ``P`` and
        ``weight``, and (``loglik``) ``log_likelihood`` ``R`` (chain, draw, experiment, time), the
        pointwise log-likelihood recomputed (vectorised) for every kept draw on the used samples.
        """
        import arviz as az

        samples, lp, walker, step = self.draws()
        C, D, d = samples.shape
        theta = np.where(self.positive, np.exp(np.where(self.positive, samples, 0.0)), samples)
        post = {}
        for i, n in enumerate(self.names):
            post[n] = theta[:, :, i]
            if self.positive[i]:
                post[self.internal_names[i]] = samples[:, :, i]
        for i in range(len(self.names), d):  # nuisance coordinates of the default likelihood
            post[self.internal_names[i]] = samples[:, :, i]
        data = {
            "posterior": post,
            "sample_stats": {
                "lp": lp,
                "walker": np.broadcast_to(walker, (C, D)).copy(),
                "step": np.broadcast_to(step, (C, D)).copy(),
            },
        }
        dims, coords = {}, {}
        if target is not None:
            cols = target.use_time
            coords = {"experiment": list(target.names), "time": target.t_used}
            data["observed_data"] = {"R": target.y[:, cols]}
            data["constant_data"] = {"P": target.P[:, cols], "weight": target.weight[:, cols]}
            dims = {"R": ["experiment", "time"], "P": ["experiment", "time"], "weight": ["experiment", "time"]}
            if loglik:
                ll = target.pointwise(samples.reshape(C * D, d))
                data["log_likelihood"] = {"R": ll.reshape(C, D, *ll.shape[1:])}
        attrs = {
            "inference_library": "emcee",
            "sampler": "imrbayes.mcmc",
            "diagnostics_json": json.dumps(self.diagnostics()),
            "settings_json": json.dumps(self.settings),
        }
        if target is not None:
            attrs["target_json"] = json.dumps(target.describe(), default=float)
        return az.from_dict(data, dims=dims, coords=coords, attrs={"/": attrs})


def _progress_bar(progress, total):
    if progress is None:
        progress = sys.stderr.isatty()
    if not progress or total <= 0:
        return None
    try:
        from tqdm.auto import tqdm
    except ImportError:  # pragma: no cover
        return None
    return tqdm(total=total, desc="emcee", unit="step", leave=False)


def _place_start(
    target, s: MCMCSettings, start_mean, start_cov, seed: int, auto: bool, nuisances: bool, name: str, log
) -> tuple:
    """The start Gaussian moved onto the target by a quadratic fit (``place="laplace"``) and, on a
    window with sampled nuisances whose fit is Gaussian, the independent-walker settings; takes the
    given start mean (d,) and cov (d, d), returns (settings, mean, cov, placement or None)."""
    placement = None
    if s.place == "laplace":  # its own seed stream: the chains' seeds are those of place="start"
        start_mean, start_cov, placement = quadratic_placement(
            target.log_prob,
            start_mean,
            start_cov,
            rounds=PLACE_ROUNDS,
            seed=int(np.random.SeedSequence([int(seed), 7919]).generate_state(1)[0]),
        )
        last = placement["rounds"][-1] if placement["rounds"] else {}
        per_exp = nuisances_per_experiment(target)
        if (
            auto
            and nuisances
            and last.get("fitted")
            and last["residual_sd_nats"] <= LAPLACE_MAX_RESIDUAL
            and per_exp <= LAPLACE_MAX_BLOCK
        ):
            # the window is Gaussian to within the bound over the placed cloud: independent walkers on
            # the placed proposal (docs/methods.md: 13-22x fewer evaluations on the verification window)
            s = replace(s, **LAPLACE_INDEP)
            placement["moves_rule"] = (
                f"residual sd {last['residual_sd_nats']:.3g} <= {LAPLACE_MAX_RESIDUAL} nats: "
                f"{LAPLACE_INDEP['moves']} on the placed Gaussian"
            )
        elif auto and nuisances:
            placement["moves_rule"] = (
                f"residual sd {last.get('residual_sd_nats', float('nan')):.3g} nats (bound "
                f"{LAPLACE_MAX_RESIDUAL}), {per_exp} nuisance(s) per experiment (bound "
                f"{LAPLACE_MAX_BLOCK}): {s.moves} from the placed Gaussian"
            )
    if placement is not None and log is not None:
        fits = [r for r in placement["rounds"] if r.get("fitted")]
        log(
            f"{name}: start placed on the target in {placement['n_evals']} evaluations (quadratic fit's residual sd "
            f"{', '.join(f'{r["residual_sd_nats"]:.2f}' for r in fits) or 'none'} nats by round)"
            + (f"; {placement['moves_rule']}" if "moves_rule" in placement else "")
        )
    return s, start_mean, start_cov, placement


def _open_backends(backend, name: str, C: int, W: int, d: int, resume: bool, n_steps: int) -> tuple:
    """One emcee backend per ensemble (in memory, or the HDF5 group ``{name}/chain_{c}``, resumed when
    it holds this run's shape); returns (backends, steps each already holds)."""
    import emcee

    backends, done = [], []
    for c in range(C):
        if backend is None:
            be = emcee.backends.Backend()
            be.reset(W, d)
        else:
            be = _hdf_backend(backend, f"{name}/chain_{c}")
            if not resume or not be.initialized:
                be.reset(W, d)
            elif be.shape != (W, d):
                raise InputError(
                    str(backend),
                    f"group {name}/chain_{c} holds {be.shape} walkers x parameters, "
                    f"this run needs {(W, d)} (use resume=False or another name)",
                )
        backends.append(be)
        done.append(int(be.iteration))
    if any(n > n_steps for n in done):
        raise InputError(str(backend), f"the file already holds {max(done)} steps, more than n_steps = {n_steps}")
    return backends, done


def _initial_states(
    target, fresh: list, children: list, seeds: list, start_mean, Lc, init_scale: float, W: int, d: int
) -> dict:
    """emcee states of the fresh ensembles ``fresh``: W starts each from N(start_mean, init_scale^2 Lc Lc^T)
    in one batched evaluation, starts with a -inf log-density redrawn; returns {c: emcee.State}."""
    import emcee

    rngs = {c: np.random.default_rng(children[c]) for c in fresh}
    P0 = {c: start_mean + init_scale * rngs[c].standard_normal((W, d)) @ Lc.T for c in fresh}
    LP = {c: np.full(W, -np.inf) for c in fresh}
    for _ in range(100):
        todo = [(c, i) for c in fresh for i in np.flatnonzero(~np.isfinite(LP[c]))]
        if not todo:
            break
        X = np.array([P0[c][i] for c, i in todo])
        lp = np.asarray(target.log_prob(X), dtype=np.float64)
        for (c, i), v in zip(todo, lp):
            if np.isfinite(v):
                LP[c][i] = v
            else:
                P0[c][i] = start_mean + init_scale * Lc @ rngs[c].standard_normal(d)
    else:
        raise RuntimeError("could not find starting points with a finite log-posterior in 100 rounds")
    return {
        c: emcee.State(P0[c], log_prob=LP[c], random_state=np.random.RandomState(seeds[c]).get_state()) for c in fresh
    }


class _Ensembles:
    """The C ensembles of one run as they advance: their backends, moves, samplers, lengths and the
    failed ones (index -> error); :meth:`advance` takes them to a step count."""

    def __init__(self, target, s: MCMCSettings, backends: list, done: list, states: list, moves: list, start_cov, bar):
        self.target, self.s, self.backends, self.states, self.moves = target, s, backends, states, moves
        self.C, self.W, self.d = len(backends), s.n_walkers, int(target.ndim)
        self.start_cov, self.bar = start_cov, bar
        # independent walkers (indep alone): fewer walkers than coordinates are fine, so emcee's check
        # that the start spans the space does not apply
        self.solo = independent_walkers(s.moves)
        self.placed = [False] * self.C
        self.samplers = [None] * self.C
        self.route = [None] * self.C  # the batcher each ensemble's log-prob calls go through (None: direct)
        self.lengths = list(done)
        self.failed = {}
        self.bar_lock = threading.Lock()

    def place_proposal(self, c):
        """Once ensemble c holds ``indep_adapt`` steps: its independence proposal moves to the mean
        and covariance of its own draws in the second half of them (a replay on resume). One
        adaptation at a fixed step leaves every later step a fixed, target-invariant kernel."""
        n_a, d = int(self.s.indep_adapt), self.d
        if not n_a or self.placed[c] or self.lengths[c] < n_a:
            return
        x = np.asarray(self.backends[c].get_chain()[n_a // 2 : n_a], dtype=np.float64).reshape(-1, d)
        cov = np.cov(x.T).reshape(d, d) + 1e-12 * np.diag(np.diag(self.start_cov))
        for mv, _ in self.moves[c]:
            if hasattr(mv, "proposal"):
                mv.proposal.place(x.mean(axis=0), cov)
        self.placed[c] = True

    def run_one(self, c, upto, batcher):
        """Advance ensemble c to ``upto`` steps in total."""
        import emcee

        try:
            if upto <= self.lengths[c]:
                return
            self.route[c] = batcher
            if self.samplers[c] is None:
                route, target = self.route, self.target
                fn = lambda x, c=c: route[c].call(c, x) if route[c] is not None else target.log_prob(x)  # noqa: E731
                self.samplers[c] = emcee.EnsembleSampler(
                    self.W, self.d, fn, vectorize=True, backend=self.backends[c], moves=self.moves[c]
                )
                if self.states[c] is None:
                    self.states[c] = self.samplers[c].get_last_sample()
            self.place_proposal(c)
            n_a = int(self.s.indep_adapt)
            stops = ([n_a] if self.lengths[c] < n_a < upto else []) + [upto]
            for stop in stops:
                for st in self.samplers[c].sample(
                    self.states[c],
                    iterations=stop - self.lengths[c],
                    store=True,
                    skip_initial_state_check=self.lengths[c] > 0 or self.solo,
                ):
                    self.states[c] = st
                    self.lengths[c] += 1
                    if self.bar is not None:
                        with self.bar_lock:
                            self.bar.update(1)
                self.place_proposal(c)
        finally:
            if batcher is not None:
                batcher.leave()

    def advance(self, upto):
        """Every surviving ensemble to ``upto`` steps. A failed ensemble (an exception in emcee or in
        its part of the evaluation) is contained: left out, recorded in ``failed``; the others go on.
        KeyboardInterrupt and the like still stop everything."""
        failed = self.failed
        todo = [c for c in range(self.C) if c not in failed and self.lengths[c] < upto]
        if not todo:
            return
        if not self.s.lockstep:
            for c in todo:
                try:
                    self.run_one(c, upto, None)
                except Exception as exc:  # noqa: BLE001
                    failed[c] = f"{type(exc).__name__}: {exc}"
            return
        batcher = _Batcher(self.target.log_prob, len(todo))
        errors = []

        def worker(c):
            try:
                self.run_one(c, upto, batcher)
            except Exception as exc:  # noqa: BLE001
                failed[c] = f"{type(exc).__name__}: {exc}"
            except BaseException as exc:  # noqa: BLE001
                errors.append(exc)
                batcher.abort(exc)

        threads = [threading.Thread(target=worker, args=(c,), daemon=True) for c in todo]
        for th in threads:
            th.start()
        try:
            for th in threads:
                while th.is_alive():
                    th.join(0.2)
        except BaseException as exc:  # KeyboardInterrupt: stop the others
            batcher.abort(exc)
            for th in threads:
                th.join()
            raise
        if errors:
            raise errors[0]

    def alive(self) -> list:
        """Indices of the ensembles that have not failed."""
        return [c for c in range(self.C) if c not in self.failed]

    def stacked(self, n):
        """(C_alive, n, W, d) first n steps of the surviving ensembles."""
        return np.stack([self.backends[c].get_chain()[:n] for c in self.alive()])


def _sample_to_stop(ens: _Ensembles, s: MCMCSettings, target, name: str, log, resumed: bool, evals0: int) -> tuple:
    """The check schedule (module docstring): replayed on what the backends hold, then sampled on
    until converged, the cap, or ``n_steps`` (``stop="fixed"``); returns (checks, stop reason, steps)."""
    checks, reason, n_chk = [], None, s.n_steps
    if s.stop == "converged":
        n_chk = min(s.min_steps, s.n_steps)
        while n_chk <= min(ens.lengths):  # replay (resume): no forward run
            chk = convergence_check(ens.stacked(n_chk), s)
            checks.append(chk)
            if chk["ok"] or n_chk >= s.n_steps:
                reason = "converged" if chk["ok"] else "cap"
                break
            n_chk = _next_check(n_chk, chk, s)
    try:
        while reason is None:
            ens.advance(n_chk)
            if len(ens.alive()) < 2:
                break
            if s.stop == "fixed":
                reason = "fixed"
                break
            chk = convergence_check(ens.stacked(n_chk), s)
            checks.append(chk)
            if log is not None:
                made = int(getattr(target, "n_evals", 0)) - evals0
                log(f"{name}: " + check_line(chk, s, made or None, resumed=resumed))
            if chk["ok"]:
                reason = "converged"
            elif n_chk >= s.n_steps:
                reason = "cap"
                if log is not None:
                    log(
                        f"{name}: stopped at the cap of {s.n_steps} steps, not converged (agree = null; "
                        "raise it with --mcmc-set n_steps=N, a resumed run continues)"
                    )
            else:
                n_chk = _next_check(n_chk, chk, s)
    finally:
        if ens.bar is not None:
            ens.bar.close()
    return checks, reason, n_chk


def run_mcmc(
    target,
    start_mean=None,
    start_cov=None,
    settings: MCMCSettings | None = None,
    seed: int = 0,
    backend=None,
    name: str = "mcmc",
    progress=None,
    resume: bool = True,
    log=None,
) -> MCMCRun:
    """Sample ``target`` with ``n_chains`` independent emcee ensembles (module docstring).

    Parameters
    ----------
    target : WindowTarget (or anything with ``log_prob(Z (n, d)) -> (n,)``, ``ndim``, ``prior``)
    start_mean, start_cov : (d,), (d, d)
        Gaussian the starts are drawn from, internal coordinates (default: the target's prior
        when it is stated on z). Starts with log-density -inf are redrawn.
    settings : MCMCSettings
    seed : int
    backend : path of an HDF5 file, or None (in memory, no resume)
    name : HDF5 group prefix, e.g. ``"window_03"``; ensemble c is ``{name}/chain_{c}``.
    progress : show a progress bar (None: only when stderr is a terminal).
    resume : continue ensembles already in the file (False: start them afresh).
    log : None, or a callable taking one line of text, called after every convergence check
        (:func:`check_line`, prefixed by ``name``): the progress of a run without a terminal.
    """
    s = settings or MCMCSettings()
    d = int(target.ndim)
    auto = s.moves.strip().lower() == "auto"
    nuisances = resolve_moves("auto", target) == AUTO_MOVES["nuisances"]
    place = s.place if s.place != "auto" else ("laplace" if auto and nuisances else "start")
    s = replace(s, moves=resolve_moves(s.moves, target), place=place)
    t0 = time.perf_counter()
    if start_mean is None:
        if getattr(target.prior, "scale", "internal") != "internal":
            raise InputError("start_mean", "give the start Gaussian for a prior stated on the natural scale")
        start_mean, start_cov = target.prior.prior_mean, target.prior.prior_cov
    start_mean = np.asarray(start_mean, dtype=np.float64).reshape(d)
    start_cov = np.asarray(start_cov, dtype=np.float64).reshape(d, d)
    given = (start_mean, start_cov)
    evals0 = int(getattr(target, "n_evals", 0))
    s, start_mean, start_cov, placement = _place_start(
        target, s, start_mean, start_cov, seed, auto, nuisances, name, log
    )
    if s.n_walkers < 2 * d and not independent_walkers(s.moves):
        # the default likelihood samples each experiment's nuisances too: at least 2 walkers per coordinate
        # (fewer with the block and ridge moves did not pay: docs/methods.md)
        s = replace(s, n_walkers=2 * d)
    s.check(d)
    Lc = np.linalg.cholesky(0.5 * (start_cov + start_cov.T))
    C, W = s.n_chains, s.n_walkers
    children = np.random.SeedSequence(int(seed)).spawn(C)
    seeds = [int(ch.generate_state(1)[0]) for ch in children]
    backends, done = _open_backends(backend, name, C, W, d, resume, s.n_steps)
    states = [None] * C
    fresh = [c for c in range(C) if done[c] == 0]
    if fresh:
        for c, st in _initial_states(target, fresh, children, seeds, start_mean, Lc, s.init_scale, W, d).items():
            states[c] = st
    # one move list per ensemble: an adapted independence proposal must see only its own ensemble
    moves = [emcee_moves(s.moves, start_mean, start_cov, s.indep_scale, s.indep_dof, target) for _ in range(C)]
    ens = _Ensembles(
        target,
        s,
        backends,
        done,
        states,
        moves,
        start_cov,
        _progress_bar(progress, sum(max(0, s.n_steps - n) for n in done)),
    )
    checks, reason, n_chk = _sample_to_stop(ens, s, target, name, log, any(done), evals0)
    # ----- collect, diagnose
    alive = ens.alive()
    if len(alive) < 2:
        raise RuntimeError(
            f"emcee: {len(ens.failed)} of {C} ensembles failed, fewer than the 2 that R-hat needs; "
            f"first error: {next(iter(ens.failed.values()))}"
        )
    backends = [backends[c] for c in alive]
    seeds = [seeds[c] for c in alive]
    steps_run = [max(0, n_chk - done[c]) for c in alive]
    C = len(alive)
    chain = np.stack([be.get_chain()[:n_chk] for be in backends])  # (C, n, W, d)
    logp = np.stack([be.get_log_prob()[:n_chk] for be in backends])  # (C, n, W)
    n = chain.shape[1]
    acc = np.array([float(np.mean(be.accepted)) / max(1, be.iteration) for be in backends])
    tau = np.stack([integrated_tau(chain[c, n // 4 :]) for c in range(C)])
    burn, thin = burn_thin(n, float(np.max(tau)), s, W)
    prior = target.prior
    stop = {"rule": s.stop, "reason": reason, "cap": int(s.n_steps), "cap_hit": reason == "cap", "checks": checks}
    return MCMCRun(
        names=tuple(prior.names),
        internal_names=list(getattr(target, "internal_names", prior.names)),
        positive=np.concatenate([np.asarray(prior.positive, dtype=bool), np.zeros(d - prior.n, dtype=bool)]),
        chain=chain,
        log_prob=logp,
        acceptance=acc,
        tau=tau,
        burn=burn,
        thin=thin,
        seeds=seeds,
        runtime_s=time.perf_counter() - t0,
        n_evals=int(getattr(target, "n_evals", 0)) - evals0,
        steps_run=steps_run,
        backend=None if backend is None else {"path": str(backend), "name": name},
        failed_chains=dict(sorted(ens.failed.items())),
        stop=stop,
        settings={
            **asdict(s),
            "seed": int(seed),
            "start_mean": start_mean.tolist(),
            "start_cov": start_cov.tolist(),
            **(
                {}
                if placement is None
                else {"given_mean": given[0].tolist(), "given_cov": given[1].tolist(), "placement": placement}
            ),
        },
    )
