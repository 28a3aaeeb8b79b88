"""emcee sampling of a window target: independent ensembles, HDF5 resume, diagnostics, ArviZ output.

:func:`run_mcmc` runs ``n_chains`` (>= 4 by default) *independent* emcee ensembles of
``n_walkers`` walkers each, every ensemble from its own seed and its own start drawn from
N(start_mean, init_scale^2 start_cov) (typically the ensemble smoother's Gaussian posterior).
Walkers of one ensemble are not independent chains (arviz issues #2156, #977), so every
convergence number here treats **one ensemble as one chain**:

* R-hat, bulk/tail ESS and MCSE come from ArviZ on a posterior whose ``chain`` is the ensemble and
  whose ``draw`` runs over the kept (step, walker) pairs **walker by walker** (draw = walker * k +
  step index): each walker's trajectory is contiguous, so the autocorrelation that ESS uses is
  each walker's own, and the split halves of R-hat are two halves of the walkers;
* emcee's integrated autocorrelation time tau (per ensemble and parameter, on the last 3/4 of the
  chain) with the rule of at least 50 tau steps (``tau_ok``);
* burn-in (default: max(n/4, 3 tau), at most n/2) and thinning (default: tau/2, more if needed to
  keep at most ``max_draws`` draws per ensemble).

Sampling is seeded: ensemble c uses ``emcee.State(p0_c, random_state=RandomState(seed_c).get_state())``
with seeds spawned from ``seed`` by ``numpy.random.SeedSequence``. With an HDF5 file every step of
ensemble c is written to the group ``{name}/chain_{c}`` (``emcee.backends.HDFBackend``); calling
:func:`run_mcmc` again with the same file and name **resumes**: each ensemble continues from its
last saved step and random state (``run_mcmc(None, n)`` semantics: steps are appended) up to
``n_steps`` in total, so an interrupted run plus its resumption gives the same chains as one
uninterrupted run.

``lockstep=True`` (default) runs the ensembles in threads that share one batched forward call per
round (all ensembles' half-walker batches x experiments in one ``propagate``); the chains are the
same as running the ensembles one after the other (``lockstep=False``).
"""

from __future__ import annotations

import contextlib
import json
import math
import sys
import threading
import time
from dataclasses import asdict, dataclass, field

import numpy as np

from imrbayes.errors import InputError

__all__ = ["MCMCSettings", "MCMCRun", "run_mcmc", "integrated_tau"]

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


@dataclass
class MCMCSettings:
    """emcee settings.

    n_walkers : walkers per ensemble (>= 2 d; default 32).
    n_steps : total steps per ensemble (a resumed run continues to this total).
    n_chains : independent ensembles (>= 2; 4 by default; R-hat is computed across them).
    burn, thin : steps discarded / kept every ``thin`` steps; None = automatic (module docstring).
    max_draws : most draws kept per ensemble in the DataTree (thinning is increased to respect it).
    init_scale : start spread, in units of the start covariance's standard deviations.
    tau_rule : the chain should be at least ``tau_rule`` tau long (emcee's advice: 50).
    lockstep : share forward batches between the ensembles (threads); False runs them one by one.
    loglik : recompute the pointwise log-likelihood of the kept draws for the DataTree.
    """

    n_walkers: int = 32
    n_steps: int = 2000
    n_chains: int = 4
    burn: int | None = None
    thin: int | None = None
    max_draws: int = 1000
    init_scale: float = 1.0
    tau_rule: float = 50.0
    lockstep: bool = True
    loglik: bool = True

    def check(self, ndim: int):
        if self.n_walkers < 2 * ndim or self.n_walkers % 2:
            raise InputError("n_walkers", f"needs an even number >= 2 x {ndim} parameters, got {self.n_walkers}")
        if self.n_chains < 2:
            raise InputError("n_chains", f"R-hat needs at least 2 independent ensembles, got {self.n_chains}")
        if self.n_steps < 4:
            raise InputError("n_steps", f"must be at least 4, got {self.n_steps}")
        if self.burn is not None and not 0 <= self.burn < self.n_steps:
            raise InputError("burn", f"must lie in [0, n_steps), got {self.burn}")
        if self.thin is not None and self.thin < 1:
            raise InputError("thin", f"must be >= 1, got {self.thin}")
        if not self.init_scale > 0:
            raise InputError("init_scale", "must be positive")


def integrated_tau(chain) -> np.ndarray:
    """emcee's integrated autocorrelation time of ``chain`` (n_steps, n_walkers, d) -> (d,) [steps],
    never raising (the estimate is returned even for chains shorter than 50 tau)."""
    import emcee

    return np.asarray(emcee.autocorr.integrated_time(np.asarray(chain), tol=0, quiet=True), dtype=np.float64)


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
        except BaseException as exc:                    # noqa: BLE001 - re-raised in every party
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
        x = self.chain[:, steps]                                    # (C, k, W, d)
        lp = self.log_prob[:, steps]
        C, W, d = self.n_chains, self.n_walkers, self.chain.shape[-1]
        samples = x.transpose(0, 2, 1, 3).reshape(C, W * k, d)
        lpf = lp.transpose(0, 2, 1).reshape(C, W * k)
        return samples, lpf, np.repeat(np.arange(W), k), np.tile(steps, W)

    def diagnostics(self) -> dict:
        """JSON-able per-run diagnostics (tau, the 50-tau rule, acceptance, burn/thin)."""
        rule = float(self.settings.get("tau_rule", 50.0))
        return {"n_chains": self.n_chains, "n_walkers": self.n_walkers, "n_steps": self.n_steps,
                "burn": self.burn, "thin": self.thin, "draws_per_chain": int(self.kept_steps().size * self.n_walkers),
                "tau": {n: self.tau[:, i].tolist() for i, n in enumerate(self.internal_names)},
                "tau_max": self.tau_max, "n_steps_over_tau": float(self.n_steps / self.tau_max),
                "tau_rule": rule, "tau_ok": [bool(v) for v in self.tau_ok], "all_tau_ok": bool(np.all(self.tau_ok)),
                "acceptance": self.acceptance.tolist(), "seeds": list(self.seeds), "runtime_s": self.runtime_s,
                "n_evals": self.n_evals, "steps_run": list(self.steps_run), "backend": self.backend,
                "failed_chains": {str(k): v for k, v in self.failed_chains.items()},
                "chain_definition": "one chain = one independent emcee ensemble; draws walker-major"}

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
        for i in range(len(self.names), d):          # nuisance coordinates of the default likelihood
            post[self.internal_names[i]] = samples[:, :, i]
        data = {"posterior": post,
                "sample_stats": {"lp": lp, "walker": np.broadcast_to(walker, (C, D)).copy(),
                                 "step": np.broadcast_to(step, (C, D)).copy()}}
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
        attrs = {"inference_library": "emcee", "sampler": "imrbayes.mcmc",
                 "diagnostics_json": json.dumps(self.diagnostics()),
                 "settings_json": json.dumps(self.settings)}
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
    except ImportError:                                    # pragma: no cover
        return None
    return tqdm(total=total, desc="emcee", unit="step", leave=False)


def run_mcmc(target, start_mean=None, start_cov=None, settings: MCMCSettings | None = None, seed: int = 0,
             backend=None, name: str = "mcmc", progress=None, resume: bool = True) -> MCMCRun:
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
    """
    import emcee

    s = settings or MCMCSettings()
    d = int(target.ndim)
    s.check(d)
    t0 = time.perf_counter()
    if start_mean is None:
        if getattr(target.prior, "scale", "internal") != "internal":
            raise InputError("start_mean", "give the start Gaussian for a prior stated on the natural scale")
        start_mean, start_cov = target.prior.prior_mean, target.prior.prior_cov
    start_mean = np.asarray(start_mean, dtype=np.float64).reshape(d)
    start_cov = np.asarray(start_cov, dtype=np.float64).reshape(d, d)
    Lc = np.linalg.cholesky(0.5 * (start_cov + start_cov.T))
    C, W = s.n_chains, s.n_walkers
    children = np.random.SeedSequence(int(seed)).spawn(C)
    seeds = [int(ch.generate_state(1)[0]) for ch in children]
    evals0 = int(getattr(target, "n_evals", 0))

    # ----- backends and where each ensemble stands
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
                raise InputError(str(backend), f"group {name}/chain_{c} holds {be.shape} walkers x parameters, "
                                               f"this run needs {(W, d)} (use resume=False or another name)")
        backends.append(be)
        done.append(int(be.iteration))
    if any(n > s.n_steps for n in done):
        raise InputError(str(backend), f"the file already holds {max(done)} steps, more than n_steps = {s.n_steps}")

    # ----- starting states of fresh ensembles: one batched evaluation, -inf starts redrawn
    states = [None] * C
    fresh = [c for c in range(C) if done[c] == 0]
    if fresh:
        rngs = {c: np.random.default_rng(children[c]) for c in fresh}
        P0 = {c: start_mean + s.init_scale * rngs[c].standard_normal((W, d)) @ Lc.T for c in fresh}
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
                    P0[c][i] = start_mean + s.init_scale * Lc @ rngs[c].standard_normal(d)
        else:
            raise RuntimeError("could not find starting points with a finite log-posterior in 100 rounds")
        for c in fresh:
            states[c] = emcee.State(P0[c], log_prob=LP[c],
                                    random_state=np.random.RandomState(seeds[c]).get_state())

    remaining = [s.n_steps - n for n in done]
    bar = _progress_bar(progress, sum(remaining))
    bar_lock = threading.Lock()
    batcher = _Batcher(target.log_prob, sum(1 for r in remaining if r > 0)) if s.lockstep else None

    def run_one(c):
        if remaining[c] <= 0:
            return
        fn = (lambda x, c=c: batcher.call(c, x)) if batcher is not None else target.log_prob
        sampler = emcee.EnsembleSampler(W, d, fn, vectorize=True, backend=backends[c])
        state = states[c] if states[c] is not None else sampler.get_last_sample()
        try:
            for _ in sampler.sample(state, iterations=remaining[c], store=True):
                if bar is not None:
                    with bar_lock:
                        bar.update(1)
        finally:
            if batcher is not None:
                batcher.leave()

    # A failed ensemble (an exception in emcee or in its part of the evaluation) is contained: it
    # is left out, recorded in ``failed_chains``, and the others go on. KeyboardInterrupt and the
    # like still stop everything.
    failed = {}
    try:
        if batcher is None:
            for c in range(C):
                try:
                    run_one(c)
                except Exception as exc:                        # noqa: BLE001
                    failed[c] = f"{type(exc).__name__}: {exc}"
        else:
            errors = []

            def worker(c):
                try:
                    run_one(c)
                except Exception as exc:                        # noqa: BLE001
                    failed[c] = f"{type(exc).__name__}: {exc}"
                except BaseException as exc:                    # noqa: BLE001
                    errors.append(exc)
                    batcher.abort(exc)

            threads = [threading.Thread(target=worker, args=(c,), daemon=True) for c in range(C)]
            for th in threads:
                th.start()
            try:
                for th in threads:
                    while th.is_alive():
                        th.join(0.2)
            except BaseException as exc:                        # KeyboardInterrupt: stop the others
                batcher.abort(exc)
                for th in threads:
                    th.join()
                raise
            if errors:
                raise errors[0]
    finally:
        if bar is not None:
            bar.close()

    # ----- collect, diagnose
    alive = [c for c in range(C) if c not in failed]
    if len(alive) < 2:
        raise RuntimeError(f"emcee: {len(failed)} of {C} ensembles failed, fewer than the 2 that R-hat needs; "
                           f"first error: {next(iter(failed.values()))}")
    backends = [backends[c] for c in alive]
    seeds = [seeds[c] for c in alive]
    remaining = [remaining[c] for c in alive]
    C = len(alive)
    chain = np.stack([be.get_chain() for be in backends])            # (C, n, W, d)
    logp = np.stack([be.get_log_prob() for be in backends])          # (C, n, W)
    n = chain.shape[1]
    acc = np.array([float(np.mean(be.accepted)) / max(1, be.iteration) for be in backends])
    tau = np.stack([integrated_tau(chain[c, n // 4:]) for c in range(C)])
    tau_max = float(np.max(tau))
    burn = s.burn if s.burn is not None else int(min(n // 2, max(n // 4, math.ceil(3 * tau_max))))
    thin = s.thin if s.thin is not None else max(1, int(tau_max // 2))
    thin = max(thin, math.ceil((n - burn) / max(1, s.max_draws // W)))        # at most max_draws per chain
    prior = target.prior
    return MCMCRun(names=tuple(prior.names), internal_names=list(getattr(target, "internal_names", prior.names)),
                   positive=np.concatenate([np.asarray(prior.positive, dtype=bool), np.zeros(d - prior.n, dtype=bool)]),
                   chain=chain, log_prob=logp, acceptance=acc,
                   tau=tau, burn=burn, thin=thin, seeds=seeds, runtime_s=time.perf_counter() - t0,
                   n_evals=int(getattr(target, "n_evals", 0)) - evals0, steps_run=remaining,
                   backend=None if backend is None else {"path": str(backend), "name": name},
                   failed_chains=dict(sorted(failed.items())),
                   settings={**asdict(s), "seed": int(seed), "start_mean": start_mean.tolist(),
                             "start_cov": start_cov.tolist()})
