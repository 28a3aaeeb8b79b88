"""What the forward kernel's three integration loops (Radau IIA, ARK, explicit pair) share: R on
the output grid, the time pieces of piecewise-constant parameters, the step control, and the
member's final status.

numba functions; ``codegen`` hashes this file into the per-model kernel's name. The loop helpers
are inlined into the loops in numba's IR (``inline="always"``): as separate compiled functions they
changed Radau's dense output in the last bit; inlined, Radau's R* is bit-identical to the loops with
these lines written out. Times are dimensionless (t*); ``t_eval`` (m,) is the
increasing output grid and ``r_out`` (m,) the member's R* there, written in order: ``k_eval`` is
the first output not written yet.
"""

import math

import numpy as np
from numba import njit

from imrbayes.forward.layout import FAIL_MAXSTEPS, FAIL_NONFINITE, FAIL_RADIUS, FAIL_STEP, OK
from imrbayes.forward.solver_algebra import FASTMATH

# Steps below this (in t*) mean the step control has collapsed (status FAIL_STEP).
MIN_STEP = 1e-13
# Output times within this of a step end are that end (no interpolation).
T_EVAL_SLACK = 1e-12
# A step that ends within this of a piece boundary is cut to end on it.
T_BREAK_SLACK = 1e-14


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def before_end(t, t1):
    """True while the member has not reached t1 (to round-off)."""
    return t < t1 - T_BREAK_SLACK * max(1.0, abs(t1))


@njit(cache=True, error_model="numpy")
def parameter_piece(t, breaks):
    """Index of the parameter piece holding time t: the number of ``breaks`` (n_pieces-1,) <= t."""
    k = 0
    while k < breaks.shape[0] and t >= breaks[k]:
        k += 1
    return k


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def piece_end(t1, piece, breaks):
    """Where the current piece's step sequence must stop: its break, or t1 if that comes first."""
    if piece < breaks.shape[0] and breaks[piece] < t1:
        return breaks[piece]
    return t1


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def clip_step(t, h, t_stop):
    """(h, last): the step from t shortened to land on t_stop when it would reach it."""
    if t + h >= t_stop - T_BREAK_SLACK:
        return t_stop - t, True
    return h, False


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def step_failure(nsteps, max_steps, h):
    """The status that stops the loop before its next attempt: FAIL_MAXSTEPS once ``nsteps``
    accepted steps reach ``max_steps``, FAIL_STEP once the step size h (t*) is below MIN_STEP,
    else OK."""
    if nsteps >= max_steps:
        return FAIL_MAXSTEPS
    if h < MIN_STEP:
        return FAIL_STEP
    return OK


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def next_step(t, h, t1, piece, breaks):
    """(t_stop, h, last): the end of the current piece's step sequence (:func:`piece_end`) and the
    step from t clipped to it (:func:`clip_step`)."""
    t_stop = piece_end(t1, piece, breaks)
    h, last = clip_step(t, h, t_stop)
    return t_stop, h, last


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def rejected_step_factor(ok, err, expo):
    """Factor on the step size after a rejected attempt: 1/4 when the attempt failed outright
    (``ok`` false: non-finite or R <= 0), else from the error norm ``err`` > 1 and the exponent
    ``expo`` = -1/order, no smaller than 1/5."""
    return 0.25 if not ok else max(0.2, 0.9 * err ** expo)


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def accepted_step_factor(err, expo):
    """Factor on the step size after an accepted step with error norm ``err`` <= 1 and exponent
    ``expo`` = -1/order: between 1/5 and 5."""
    return 5.0 if err == 0.0 else min(5.0, max(0.2, 0.9 * err ** expo))


@njit(cache=True, error_model="numpy", inline="always")
def all_finite(x):
    """True when every entry of ``x`` (n,) is finite (a rate at an accepted state must be)."""
    for k in range(x.shape[0]):
        if not math.isfinite(x[k]):
            return False
    return True


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def crossed_break(last, t, piece, breaks):
    """True when the step just accepted (ending at t; ``last``: it was cut to the piece's end)
    ended on the current piece's break: the caller moves to the next piece's parameters."""
    return last and piece < breaks.shape[0] and t >= breaks[piece] - T_BREAK_SLACK


@njit(cache=True, error_model="numpy")
def hermite5(t, t0, t1, r0, v0, a0, r1, v1, a1):
    """Quintic Hermite interpolant of R from R, Rdot, Rddot at both ends of a step."""
    h = t1 - t0
    s = (t - t0) / h
    s2 = s * s
    s3 = s2 * s
    s4 = s3 * s
    s5 = s4 * s
    h00 = 1.0 - 10.0 * s3 + 15.0 * s4 - 6.0 * s5
    h10 = s - 6.0 * s3 + 8.0 * s4 - 3.0 * s5
    h20 = 0.5 * s2 - 1.5 * s3 + 1.5 * s4 - 0.5 * s5
    h01 = 10.0 * s3 - 15.0 * s4 + 6.0 * s5
    h11 = -4.0 * s3 + 7.0 * s4 - 3.0 * s5
    h21 = 0.5 * s3 - s4 + 0.5 * s5
    return h00 * r0 + h10 * h * v0 + h20 * h * h * a0 + h01 * r1 + h11 * h * v1 + h21 * h * h * a1


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def outputs_at_start(t_eval, t0, r0, r_out):
    """Outputs before t0 are NaN, those at t0 are R(t0) = r0; returns k_eval."""
    neval = t_eval.shape[0]
    k_eval = 0
    while k_eval < neval and t_eval[k_eval] < t0 - T_EVAL_SLACK:
        r_out[k_eval] = np.nan
        k_eval += 1
    while k_eval < neval and t_eval[k_eval] <= t0 + T_EVAL_SLACK:
        r_out[k_eval] = r0
        k_eval += 1
    return k_eval


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def outputs_in_step(t_eval, k_eval, t, t_new, r0, v0, a0, r1, v1, a1, r_out):
    """Dense output on (t, t_new] after an accepted step, from R, Rdot, Rddot at both ends
    (:func:`hermite5`); returns the new k_eval."""
    neval = t_eval.shape[0]
    while k_eval < neval and t_eval[k_eval] <= t_new + T_EVAL_SLACK:
        if t_eval[k_eval] >= t_new - T_EVAL_SLACK:
            r_out[k_eval] = r1
        else:
            r_out[k_eval] = hermite5(t_eval[k_eval], t, t_new, r0, v0, a0, r1, v1, a1)
        k_eval += 1
    return k_eval


@njit(cache=True, error_model="numpy", inline="always")
def final_status(status, y, r_out, k_eval):
    """The member's status once its loop has ended: a failed loop's outputs from k_eval on are NaN;
    a finished one fails after all if its end state ``y`` (n,) is non-finite or has R <= 0."""
    if status != OK:
        for k in range(k_eval, r_out.shape[0]):
            r_out[k] = np.nan
        return status
    for k in range(y.shape[0]):
        if not math.isfinite(y[k]):
            status = FAIL_NONFINITE
    if not (y[0] > 0.0):
        status = FAIL_RADIUS
    return status


@njit(cache=True, error_model="numpy")
def batch_outputs(Y0, n_out):
    """What a batch driver fills: (Y, R, status, nsteps, nrejected) for the N members of ``Y0``
    (N, n): a copy of Y0 to advance in place, R* (N, n_out) all NaN, and zero counts (N,)."""
    n_members = Y0.shape[0]
    return (Y0.copy(), np.full((n_members, n_out), np.nan), np.zeros(n_members, dtype=np.int64),
            np.zeros(n_members, dtype=np.int64), np.zeros(n_members, dtype=np.int64))
