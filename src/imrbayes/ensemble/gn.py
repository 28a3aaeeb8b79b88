"""Ensemble-space Gauss–Newton analysis (methods.md §3; Bocquet & Sakov 2014), for many
independent groups (experiments) at once.

For one group with prior ensemble E0 (N members x d, internal coordinates), mean xbar and
normalised anomalies A = (E0 - xbar)/sqrt(N-1) (N x d), the control variable is w (N,):
x = xbar + A^T w. With Yhat_k^(i) the model output of member i at observation k,
ybar_k its ensemble mean and Y'_k = (Yhat_k^(i) - ybar_k)/sqrt(N-1) (normalised anomalies),

    J(w) = 1/2 sum_k c_k ||y_k - ybar_k - Y'_k w||^2 / P_k + 1/2 w^T w,
    grad = w - sum_k Y'_k^T (c_k/P_k) (y_k - ybar_k),    H = I + sum_k Y'_k^T (c_k/P_k) Y'_k,
    w <- w - H^-1 grad,

where c_k is the observation weight (En4D-Var: 1/N_t; MIEnKS: beta_jk/L). methods.md writes H and
grad with (N_En - 1) I and (N_En - 1) w: that is the same algorithm written for *unnormalised*
anomalies (w_unnorm = w/sqrt(N-1)); every iterate and the posterior are identical. Each iteration
evaluates the ensemble shifted to the current w, E = E0 + (A^T w) 1^T, in one batch. After
``n_iter`` iterations the posterior is N(xbar + A^T w, A^T H^-1 A) and its ensemble is
xbar + A^T w + sqrt(N-1) H^-1/2 A (symmetric square root: the mean is kept).

The output anomalies Y' are taken from a linear regression of the outputs on the ensemble
anomalies (:func:`linearise`), and by default the ensemble is rescaled to the current posterior
spread at every iteration (the transform variant: E = xbar + A^T w + sqrt(N-1) H^-1/2 A, with Y'
mapped back to w by the same transform). The regression equals the raw anomalies whenever the ensemble anomalies have
full rank N - 1 and removes the nonlinear remainder otherwise (parameter-only ensembles, N > d + 1).

Failed members: at w = 0 (the prior ensemble) they are redrawn from the Gaussian of the valid
members and re-run (counted). Members that fail later get the regression prediction of their
output (counted). A group with fewer than ``min_valid`` valid members
stops iterating (flagged).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["GNResult", "gauss_newton", "linearise"]


@dataclass
class GNResult:
    """Posterior of every group. Shapes: G groups, N members, d state size, m observations.

    mean (G, d); anoms (G, N, d) normalised posterior anomalies (cov = anoms^T anoms);
    cov (G, d, d); ensemble (G, N, d) the posterior ensemble; prior_anoms (G, N, d) the normalised
    prior anomalies (after any redraw); prior_ensemble (G, N, d); w (G, N); cost (G, n_iter) J at
    each evaluated iterate; n_failed (G, n_iter) failed members per iteration; n_redrawn (G,);
    stopped (G,) True where a group stopped early; yhat_mean (G, m) ensemble-mean output at the
    best evaluated iterate; n_backtracked (G,) rejected iterates.
    """

    mean: np.ndarray
    anoms: np.ndarray
    cov: np.ndarray
    ensemble: np.ndarray
    prior_anoms: np.ndarray
    prior_ensemble: np.ndarray
    w: np.ndarray
    cost: np.ndarray
    n_failed: np.ndarray
    n_redrawn: np.ndarray
    stopped: np.ndarray
    yhat_mean: np.ndarray
    n_backtracked: np.ndarray | None = None


def linearise(A, Yhat, ok, sq, rcond: float = 1e-9, A_out=None):
    """Output mean and anomalies ``(ybar (m,), Y' (N, m))`` by linear regression on the ensemble.

    The valid members' outputs are regressed on their (column-scaled) anomalies A (N, d):
    Y'_i = A_i B with B the minimum-norm least-squares fit, ybar the fitted output at the ensemble
    centre. With every member valid and rank(A) = N - 1 (state-augmented ensembles) this is exactly
    the raw anomaly (Yhat_i - mean)/sqrt(N-1). When rank(A) = d < N - 1 (a parameter-only ensemble)
    it drops the part of the output anomalies that no linear function of the parameters explains:
    that part, from nonlinearity alone, otherwise drives w along directions that do not move the
    parameters (the prior term grew without bound in our tests) and shrinks the posterior spread
    spuriously. Failed members get the regression prediction (never a NaN).
    ``A_out``: return the sensitivities for these anomalies instead (the transform variant
    regresses on the evaluated ensemble T A and needs Y' for A).
    """
    A_out = A if A_out is None else A_out
    Av = A[ok]
    Yv = Yhat[ok]
    scale = np.sqrt(np.mean(A * A, axis=0))
    scale = np.where(scale > 0, scale, 1.0)
    Xs = Av / scale
    xm = Xs.mean(axis=0)
    ym = Yv.mean(axis=0)
    B, *_ = np.linalg.lstsq(Xs - xm, (Yv - ym) / sq, rcond=rcond)
    Yp = (A_out / scale) @ B
    ybar = ym - sq * (xm @ B)
    return ybar, Yp


def _sqrt_inv(H):
    """H^-1 and H^-1/2 of SPD matrices (..., N, N) by eigen-decomposition."""
    lam, V = np.linalg.eigh(H)
    lam = np.maximum(lam, 1e-12)
    Hi = (V / lam[..., None, :]) @ np.swapaxes(V, -1, -2)
    Hs = (V / np.sqrt(lam)[..., None, :]) @ np.swapaxes(V, -1, -2)
    return Hi, Hs


def gauss_newton(
    E0,
    evaluate,
    y,
    weight,
    n_iter: int = 5,
    rng=None,
    max_redraw: int = 5,
    min_valid: int | None = None,
    project: bool = True,
    transform: bool = True,
    backtrack: bool = True,
    max_iter: int | None = None,
    rtol: float = 0.01,
    patience: int | None = None,
    min_iter: int | None = None,
    step_tol: float | None = None,
) -> GNResult:
    """Run the ensemble Gauss–Newton analysis for G groups at once.

    Parameters
    ----------
    E0 : (G, N, d) prior ensembles (internal coordinates).
    evaluate : callable(groups (M,) int, E (M, d)) -> (Yhat (M, m), failed (M,) bool)
        Runs the forward model for M members (rows of E) of the given groups; one batch call.
    y : (G, m) observations; weight : (G, m) or (m,) c_k / P_k (>= 0).
    n_iter : Gauss–Newton iterations (forward batches).
    rng : numpy Generator for redraws of failed prior members.
    min_valid : fewest valid members to keep iterating (default max(2, N // 2)).
    project : use the regression linearisation of :func:`linearise` (default) instead of the raw
        output anomalies.
    transform : the transform variant of Bocquet & Sakov (2014): iteration i evaluates
        xbar + A^T w + sqrt(N-1) T A with T = H^-1/2 of the previous iteration, so the ensemble
        shrinks to the posterior's size and the linearisation is taken at that scale (default);
        False evaluates the prior ensemble shifted by A^T w (the literal form of methods.md).
    backtrack : when an iterate's cost exceeds the best so far, or fewer than ``min_valid`` of
        its members run, the next evaluation is halfway back towards the best iterate (no extra
        forward runs); the posterior is always the Gauss–Newton update from the best evaluated
        iterate -- except where the steps from it could not be run, which end at that iterate.
        Without it (or on the prior ensemble) too few valid members stop the group.
    max_iter : iterate past ``n_iter`` (up to ``max_iter`` evaluations) for every group whose last
        accepted iterate still lowered the cost by more than ``rtol`` (relative): on stiff
        records (tiny noise, large misfit) five iterations stop far from the optimum, and where
        they stop depends on the draws. Default: exactly ``n_iter``. Converged groups drop out of
        the batch; ``cost`` then has ``max_iter`` columns, NaN after a group's last evaluation.
    patience : the fewest evaluations of a group none of whose steps has lowered the cost yet
        (default ``n_iter``): with ``n_iter`` small, a first step that overshoots is halved this
        many times before the group gives up on it (on stiff PA with 3 iterations and no patience,
        one bubble's last cycle stopped after two rejected steps and ended 0.9 sd away, own RMSE
        0.0136 -> 0.0163).
    min_iter : from evaluation ``min_iter`` on, a group stops at an accepted iterate whose cost
        fell by no more than ``rtol`` (relative); the Gauss-Newton update from it is the
        posterior, as after the last iteration. Rejected steps do not stop it before ``n_iter``
        (a later halved step may be accepted). Why: in a sliding-window smoother many windows
        start next to their optimum (their prior is the previous window's posterior and 30 of 35
        samples are shared) and repeat the same cost to 1 % (docs/validation.md). Default None:
        never before ``n_iter``.
    step_tol : from evaluation ``min_iter`` (else ``n_iter``) on, a group also stops at an accepted
        iterate whose next step is shorter than ``step_tol`` posterior sd: sqrt(g^T H^-1 g), the
        Newton decrement (the step's length in the metric of the posterior it defines; half its
        square is the decrease the step predicts). The step is still taken in the returned update.
        Why: a step that short moves the answer by less than that, and evaluating it is where the
        transform variant's comparisons of costs at different ensemble sizes reject it (stiff PA:
        costs like 1.88, 1.95, 1.97, 1.99 after the first step, every one rejected). Default None.
    """
    E0 = np.array(E0, dtype=np.float64)
    G, N, d = E0.shape
    y = np.atleast_2d(np.asarray(y, dtype=np.float64))
    m = y.shape[1]
    Wt = np.broadcast_to(np.asarray(weight, dtype=np.float64), (G, m))
    rng = np.random.default_rng(0) if rng is None else rng
    min_valid = min_valid or max(2, N // 2)
    sq = np.sqrt(N - 1.0)

    Yhat, failed, n_redrawn = _run_prior(E0, evaluate, rng, max_redraw, m)
    xbar = E0.mean(axis=1)  # (G, d)
    A = (E0 - xbar[:, None, :]) / sq  # (G, N, d)
    patience = n_iter if patience is None else int(patience)
    n_max = max(n_iter, patience) if max_iter is None else max(n_iter, patience, int(max_iter))
    st = _GNState.start(G, N, m, n_max)
    stop_from = n_iter if min_iter is None else min(int(min_iter), n_iter)
    opts = _GNOptions(n_iter, min_valid, project, transform, backtrack, rtol, patience, stop_from, step_tol)

    for it in range(n_max):
        if it > 0:
            act = np.flatnonzero(st.active)
            if act.size == 0:
                break
            shift = np.einsum("gnd,gn->gd", A[act], st.w[act])  # A^T w
            if transform:  # xbar + A^T w + sqrt(N-1) T A
                E = (xbar[act] + shift)[:, None, :] + sq * (st.T[act] @ A[act])
            else:
                E = E0[act] + shift[:, None, :]
            Yn, fn = evaluate(np.repeat(act, N), E.reshape(act.size * N, d))
            Yhat[act] = Yn.reshape(act.size, N, m)
            failed[act] = fn.reshape(act.size, N)
        for g in np.flatnonzero(st.active):
            _update_group(st, opts, g, it, A[g], Yhat[g], failed[g], y[g], Wt[g], sq)
    return _posterior(st, xbar, A, E0, sq, n_redrawn)


@dataclass
class _GNOptions:
    """The iteration controls of :func:`gauss_newton` (see its parameters); ``stop_from`` is the
    evaluation count from which a group may stop early."""

    n_iter: int
    min_valid: int
    project: bool
    transform: bool
    backtrack: bool
    rtol: float
    patience: int
    stop_from: int
    step_tol: float | None


@dataclass
class _GNState:
    """Per-group iteration state of :func:`gauss_newton` (G groups, N members, m observations).

    w (G, N) the control variable to evaluate next; H, T (G, N, N) the Hessian and its inverse
    square root at the last accepted iterate; best (G,) the lowest cost so far and w_best (G, N)
    its iterate; w_upd (G, N) the Gauss-Newton update from the best iterate; n_back, n_accepted
    (G,) rejected and accepted iterates; unrunnable (G,) True where the update from the best
    iterate failed to run; ybar_last (G, m) the output mean at the best iterate; cost, nfail
    (G, n_max) per evaluation; stopped, active (G,) flags.
    """

    w: np.ndarray
    H: np.ndarray
    T: np.ndarray
    best: np.ndarray
    w_best: np.ndarray
    w_upd: np.ndarray
    n_back: np.ndarray
    n_accepted: np.ndarray
    unrunnable: np.ndarray
    ybar_last: np.ndarray
    cost: np.ndarray
    nfail: np.ndarray
    stopped: np.ndarray
    active: np.ndarray

    @classmethod
    def start(cls, G, N, m, n_max):
        """The state before the first evaluation: w = 0, H = T = I, nothing accepted."""
        H = np.broadcast_to(np.eye(N), (G, N, N)).copy()
        return cls(
            w=np.zeros((G, N)),
            H=H,
            T=H.copy(),
            best=np.full(G, np.inf),
            w_best=np.zeros((G, N)),
            w_upd=np.zeros((G, N)),
            n_back=np.zeros(G, dtype=int),
            n_accepted=np.zeros(G, dtype=int),
            unrunnable=np.zeros(G, dtype=bool),
            ybar_last=np.full((G, m), np.nan),
            cost=np.full((G, n_max), np.nan),
            nfail=np.zeros((G, n_max), dtype=int),
            stopped=np.zeros(G, dtype=bool),
            active=np.ones(G, dtype=bool),
        )


def _run_prior(E0, evaluate, rng, max_redraw, m):
    """Evaluate the prior ensemble, redrawing failed members from the Gaussian of the valid ones.

    E0 (G, N, d) is updated in place with the redrawn members. Returns ``(Yhat (G, N, m),
    failed (G, N) bool, n_redrawn (G,) int)``.
    """
    G, N, d = E0.shape
    Yhat, failed = evaluate(np.repeat(np.arange(G), N), E0.reshape(G * N, d))
    Yhat = Yhat.reshape(G, N, m).copy()
    failed = failed.reshape(G, N).copy()
    n_redrawn = np.zeros(G, dtype=int)
    for _ in range(max_redraw):
        if not failed.any():
            break
        rows = []
        for g in np.flatnonzero(failed.any(axis=1)):
            ok = ~failed[g]
            if ok.sum() < 2:
                continue
            xv = E0[g, ok]
            mu = xv.mean(axis=0)
            Av = (xv - mu) / np.sqrt(ok.sum() - 1.0)
            bad = np.flatnonzero(failed[g])
            E0[g, bad] = mu + rng.standard_normal((bad.size, ok.sum())) @ Av
            n_redrawn[g] += bad.size
            rows.extend((g, i) for i in bad)
        if not rows:
            break
        gs, ii = np.array(rows).T
        Yn, fn = evaluate(gs, E0[gs, ii])
        Yhat[gs, ii] = Yn
        failed[gs, ii] = fn
    return Yhat, failed, n_redrawn


def _reject(st, opts, g, it):
    """Send group g halfway back towards its best iterate; past ``n_iter`` a rejected step ends its
    iterations once one has succeeded (not from ``min_iter`` on: a later halved step may still be
    accepted and move the answer, by 100 sd on the nonlinear test problem)."""
    st.w[g] = st.w_best[g] + 0.5 * (st.w[g] - st.w_best[g])
    st.n_back[g] += 1
    if it >= opts.n_iter - 1 and (st.n_accepted[g] > 1 or it >= opts.patience - 1):
        st.active[g] = False


def _update_group(st, opts, g, it, A, Yhat, failed, y, Wt, sq):
    """Judge group g's evaluation ``it`` and, when accepted, take the Gauss-Newton step from it.

    A (N, d) prior anomalies, Yhat (N, m) outputs, failed (N,) bool, y (m,) observations, Wt (m,)
    weights of group g; ``st`` is updated in place (cost, acceptance, next w, H, T, flags).
    """
    N = A.shape[0]
    ok = ~failed & np.all(np.isfinite(Yhat), axis=1)
    st.nfail[g, it] = N - ok.sum()
    if ok.sum() < opts.min_valid:
        if opts.backtrack and it > 0 and st.n_accepted[g] > 0:
            # a step into parameters the model cannot run is a rejected step, not the end
            # (stiff PA, qkv: a full step to alpha < 0 made the deep collapse singular, and
            # 12 of 20 bubbles stopped with the prior as their answer)
            _reject(st, opts, g, it)
            st.unrunnable[g] = True
            return
        st.stopped[g] = True
        st.active[g] = False
        return
    At = st.T[g] @ A if opts.transform else A  # anomalies of the evaluated ensemble
    if opts.project:
        ybar, Yp = linearise(At, Yhat, ok, sq, A_out=A)
    else:
        ybar = Yhat[ok].mean(axis=0)
        Yp = np.where(ok[:, None], Yhat - ybar, 0.0) / sq  # (N, m)
        if opts.transform:
            Yp = np.linalg.solve(st.T[g], Yp)
    d_in = y - ybar
    c = 0.5 * np.sum(Wt * d_in**2) + 0.5 * st.w[g] @ st.w[g]
    st.cost[g, it] = c
    if opts.backtrack and it > 0 and not c <= st.best[g] * (1.0 + 1e-9):
        _reject(st, opts, g, it)  # the step increased the cost
        return

    st.n_accepted[g] += 1
    st.unrunnable[g] = False
    prev = st.best[g]
    st.best[g] = c
    st.w_best[g] = st.w[g]
    # past n_iter (min_iter), a group stops once its accepted cost no longer falls by rtol
    done = it >= opts.stop_from - 1 and not (prev - c) > opts.rtol * abs(c)
    grad = st.w[g] - Yp @ (Wt * d_in)
    Hg = np.eye(N) + (Yp * Wt) @ Yp.T
    st.H[g] = Hg
    step = np.linalg.solve(Hg, grad)
    st.w[g] = st.w[g] - step
    if opts.step_tol is not None and it >= opts.stop_from - 1 and not grad @ step > opts.step_tol**2:
        done = True
    st.w_upd[g] = st.w[g]
    if opts.transform:
        st.T[g] = _sqrt_inv(Hg)[1]
    st.ybar_last[g] = ybar
    if done:
        st.active[g] = False


def _posterior(st, xbar, A, E0, sq, n_redrawn):
    """The :class:`GNResult` of the final state: mean, anomalies, covariance and ensemble of
    N(xbar + A^T w, A^T H^-1 A) with w the update from each group's best iterate.

    xbar (G, d), A (G, N, d) the prior mean and normalised anomalies, E0 (G, N, d) the prior
    ensemble after redraws, sq = sqrt(N - 1), n_redrawn (G,).
    """
    # a group whose last steps from its best iterate could not be run ends at that iterate, not at
    # the update its members failed on (the next cycle would start where nothing runs)
    st.w_upd[st.unrunnable] = st.w_best[st.unrunnable]
    w = st.w_upd
    Hi, Hs = _sqrt_inv(st.H)
    mean = xbar + np.einsum("gnd,gn->gd", A, w)
    anoms = Hs @ A  # (G, N, d)
    cov = np.einsum("gnd,gne->gde", A, Hi @ A)
    ens = mean[:, None, :] + sq * anoms
    return GNResult(
        mean,
        anoms,
        0.5 * (cov + np.swapaxes(cov, 1, 2)),
        ens,
        A,
        E0,
        w,
        st.cost,
        st.nfail,
        n_redrawn,
        st.stopped,
        st.ybar_last,
        st.n_back,
    )
