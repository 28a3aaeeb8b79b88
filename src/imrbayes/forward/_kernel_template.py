# The compiled forward kernel of one constitutive model. This file is a *template*:
# imrbayes.forward.codegen writes one copy per constitutive model with the line marked PLUGIN
# replaced by an import of that model's compiled `stress`/`dissipation_q`, so that numba can cache
# every model's kernel on disk (numba cannot cache a kernel that receives the stress function as an
# argument). Only what calls the model lives here: the right-hand side (Keller-Miksis and the
# bubble's fields), the finite-difference Jacobians and the three integration loops. The linear
# algebra they solve (Thomas / block Thomas sweeps, Woodbury, small LU) is in solver_algebra.py and
# what the loops share (dense output, parameter pieces, step control, final status) in integration_common.py,
# both compiled once for all models; codegen hashes them into this copy's name.
#
# Physics: shared/docs/methods.md (IMRv2, in our words). Everything here is dimensionless.
# Time stepping, three loops: (1) Radau IIA order 5 (integrate_member_radau; default for the
# thermal bubble in a cold medium) with a finite-difference Jacobian in the problem's structure,
# 2x2-block tridiagonal over the bubble nodes plus a few low-rank columns, solved by block Thomas
# + Woodbury; (2) an additive Runge-Kutta pair (integrate_member; tableaux.py, ARK5(4)8L[2]SA)
# whose implicit part is the fields' diffusion with coefficients frozen over the step plus
# coupling columns (warm medium); (3) an explicit pair for the polytropic bubble
# (integrate_member_explicit). Step size from the embedded error estimate in all three.
import math

import numpy as np
from numba import njit, prange

from imrbayes.forward.constitutive.nhkv import dissipation_q as _dissipation_q, stress as _stress  # PLUGIN
from imrbayes.forward.integration_common import (
    MIN_STEP,
    T_BREAK_SLACK,
    accepted_step_factor,
    all_finite,
    batch_outputs,
    before_end,
    clip_step,
    crossed_break,
    final_status,
    next_step,
    outputs_at_start,
    outputs_in_step,
    parameter_piece,
    piece_end,
    rejected_step_factor,
    step_failure,
)
from imrbayes.forward.layout import (
    F_MASS,
    F_MEDIUM,
    F_MT,
    F_NAUX,
    F_NT,
    F_PDOT,
    F_RADIAL,
    F_THERMAL,
    FAIL_MAXSTEPS,
    FAIL_NONFINITE,
    FAIL_RADIUS,
    FAIL_STEP,
    G_ALPHA_G,
    G_ALPHA_V,
    G_BETA_G,
    G_BETA_V,
    G_BR,
    G_CHI,
    G_CSTAR,
    G_FOH,
    G_FOM,
    G_INV_WE,
    G_IOTA,
    G_KAPPA,
    G_KV0,
    G_LSTAR,
    G_LT,
    G_P8,
    G_PB0,
    G_PV,
    G_REQ,
    G_RG,
    G_RV,
    G_T8,
    G_TAIT_B,
    G_TAIT_N,
    GR_D1C,
    GR_D1L,
    GR_D1U,
    GR_D2C,
    GR_D2L,
    GR_D2U,
    GR_WALL,
    GR_Y,
    OK,
)
from imrbayes.forward.solver_algebra import (
    FASTMATH,
    apply_tridiag,
    build_tridiag,
    field_blocks,
    lu_small,
    lu_solve_small,
    radau_factor_pair,
    radau_solve,
    radau_solve_pair,
    rms_norm,
    thomas_factor,
    thomas_solve,
    thomas_solve_many,
)


@njit(cache=True, error_model="numpy")
def _temperature(theta, alpha):
    return (alpha - 1.0 + math.sqrt(1.0 + 2.0 * alpha * theta)) / alpha


@njit(cache=True, error_model="numpy")
def _psat_star(T, g):
    return 1.17e11 * math.exp(-5200.0 / (T * g[G_T8])) / g[G_P8]


@njit(cache=True, error_model="numpy")
def _kv_wall(p, T, g):
    return 1.0 / (1.0 + (g[G_RV] / g[G_RG]) * (p / _psat_star(T, g) - 1.0))


@njit(cache=True, error_model="numpy")
def _wall_residual(thw, p, th, kv, tm, g, grid, dxi, nt, mass, kv0):
    """Heat-flux balance at the bubble wall (forward-model.md §4.4); returns (F, Tw)."""
    chi = g[G_CHI]
    if mass:
        alpha = kv0 * g[G_ALPHA_V] + (1.0 - kv0) * g[G_ALPHA_G]
    else:
        alpha = g[G_ALPHA_G]
    arg = 1.0 + 2.0 * alpha * thw
    if arg < 0.0:
        return np.nan, np.nan
    Tw = (alpha - 1.0 + math.sqrt(arg)) / alpha
    w0 = grid[GR_WALL, 0]
    w1 = grid[GR_WALL, 1]
    w2 = grid[GR_WALL, 2]
    F = (2.0 * chi * g[G_IOTA] / dxi) * (-1.5 * Tw + 2.0 * tm[1] - 0.5 * tm[2]) \
        + chi * (w0 * thw + w1 * th[nt - 2] + w2 * th[nt - 3])
    if mass:
        kvw = _kv_wall(p, Tw, g)
        dkv = w0 * kvw + w1 * kv[nt - 2] + w2 * kv[nt - 3]
        F += g[G_FOM] * g[G_LSTAR] * p / ((kvw * (g[G_RV] - g[G_RG]) + g[G_RG]) * Tw * (1.0 - kvw)) * dkv
    return F, Tw


@njit(cache=True, error_model="numpy")
def _wall_root(guess, p, th, kv, tm, g, grid, dxi, nt, mass, kv0):
    """Wall value of the auxiliary temperature variable: bracket, then Illinois regula falsi."""
    if mass:
        alpha = kv0 * g[G_ALPHA_V] + (1.0 - kv0) * g[G_ALPHA_G]
    else:
        alpha = g[G_ALPHA_G]
    lo_dom = -0.5 / alpha + 1e-12
    x0 = guess if (guess > lo_dom and math.isfinite(guess)) else 0.0
    f0, _ = _wall_residual(x0, p, th, kv, tm, g, grid, dxi, nt, mass, kv0)
    if not math.isfinite(f0):
        x0 = 0.0
        f0, _ = _wall_residual(x0, p, th, kv, tm, g, grid, dxi, nt, mass, kv0)
        if not math.isfinite(f0):
            return np.nan
    if f0 == 0.0:
        return x0
    step = 1e-3 * max(1.0, abs(x0))
    a = x0
    fa = f0
    b = x0
    fb = f0
    found = False
    for _ in range(200):
        b = a + step if f0 < 0.0 else a - step
        if b < lo_dom:
            b = lo_dom
        fb, _ = _wall_residual(b, p, th, kv, tm, g, grid, dxi, nt, mass, kv0)
        if math.isfinite(fb) and fb * f0 <= 0.0:
            found = True
            break
        if b == lo_dom:
            break
        a = b
        fa = fb if math.isfinite(fb) else fa
        step *= 2.0
    if not found:
        return np.nan
    # Illinois on [a, b] with fa*fb <= 0.
    side = 0
    for _ in range(100):
        if fb == fa:
            break
        c = (a * fb - b * fa) / (fb - fa)
        fc, _ = _wall_residual(c, p, th, kv, tm, g, grid, dxi, nt, mass, kv0)
        if not math.isfinite(fc):
            c = 0.5 * (a + b)
            fc, _ = _wall_residual(c, p, th, kv, tm, g, grid, dxi, nt, mass, kv0)
        if fc * fb > 0.0:
            b = c
            fb = fc
            if side == -1:
                fa *= 0.5
            side = -1
        else:
            a = b
            fa = fb
            b = c
            fb = fc
            side = 1
        if abs(b - a) <= 1e-14 * (1.0 + abs(b)) or fc == 0.0:
            return c
    return b


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def rhs(t, y, g, p, flags, grid, mgrid, out, coef, work):
    """Right-hand side ``out = dy/dt`` for one member; fills ``coef`` with the diffusion
    coefficients of the fields (multipliers of their second-difference operators).

    ``y`` (n,): [R, Rdot, p_b, theta (nt), T_m (mt), k_v (nt), stress states]; ``g`` groups;
    ``p`` dimensionless material parameters (p[0] = 1/Ca, p[1] = 1/Re, then model-specific);
    ``work`` scratch (>= 7 nt + 2 mt + 2); work[0] carries the warm start of the wall root.
    """
    nt = flags[F_NT]
    mt = flags[F_MT]
    thermal = flags[F_THERMAL]
    medium = flags[F_MEDIUM]
    mass = flags[F_MASS]
    naux = flags[F_NAUX]
    i_th = 3
    i_tm = i_th + nt * thermal
    i_kv = i_tm + mt * medium
    i_z = i_kv + nt * mass
    # Only the frozen wall/far-field rows are never written below.
    if thermal:
        out[i_th + nt - 1] = 0.0
        if mass:
            out[i_kv + nt - 1] = 0.0
        if medium:
            out[i_tm] = 0.0
            out[i_tm + mt - 1] = 0.0
    R = y[0]
    U = y[1]
    kappa = g[G_KAPPA]
    out[0] = U
    Tw_bubble = 1.0
    if thermal == 0:
        pv = g[G_PV]
        pb = (g[G_PB0] - pv) * R ** (-3.0 * kappa) + pv
        if flags[F_PDOT] == 0:
            pdot = -3.0 * kappa * pb * U / R       # IMRv2: total pressure, vapour included
        else:
            pdot = -3.0 * kappa * (pb - pv) * U / R  # exact rate of the algebraic pressure
    else:
        pb = y[2]
        chi = g[G_CHI]
        fom = g[G_FOM]
        kv0 = g[G_KV0]
        av = g[G_ALPHA_V]
        ag = g[G_ALPHA_G]
        bv = g[G_BETA_V]
        bg = g[G_BETA_G]
        rv = g[G_RV]
        rg = g[G_RG]
        th = work[1:1 + nt]
        kv = work[1 + nt:1 + 2 * nt]
        T = work[1 + 2 * nt:1 + 3 * nt]
        for i in range(nt):
            th[i] = y[i_th + i]
            kv[i] = y[i_kv + i] if mass else kv0
        if medium:
            tm = work[1 + 4 * nt:1 + 4 * nt + mt]
            for j in range(mt):
                tm[j] = y[i_tm + j]
            dxi = mgrid[0, 1] - mgrid[0, 0]
            thw = _wall_root(work[0], pb, th, kv, tm, g, grid, dxi, nt, mass, kv[nt - 1])
            work[0] = thw
            th[nt - 1] = thw
        sq = work[1 + 3 * nt:1 + 4 * nt]       # sqrt(1 + 2 alpha_m theta), reused below
        for i in range(nt):
            am = kv[i] * av + (1.0 - kv[i]) * ag
            sq[i] = math.sqrt(1.0 + 2.0 * am * th[i])
            T[i] = (am - 1.0 + sq[i]) / am
        Tw_bubble = T[nt - 1]
        if mass:
            kv[nt - 1] = _kv_wall(pb, T[nt - 1], g)
        w0 = grid[GR_WALL, 0]
        w1 = grid[GR_WALL, 1]
        w2 = grid[GR_WALL, 2]
        inv_r = 1.0 / R
        inv_r2 = inv_r * inv_r
        inv_pb = 1.0 / pb
        dth_w = w0 * th[nt - 1] + w1 * th[nt - 2] + w2 * th[nt - 3]
        bracket = chi * (kappa - 1.0) * inv_r * dth_w - kappa * pb * U
        if mass:
            dkv_w = w0 * kv[nt - 1] + w1 * kv[nt - 2] + w2 * kv[nt - 3]
            rmix_w = kv[nt - 1] * rv + (1.0 - kv[nt - 1]) * rg
            bracket += kappa * pb * fom * rv * dkv_w / (T[nt - 1] * R * rmix_w * (1.0 - kv[nt - 1]))
        # work[-1]: a shift of the pressure rate, zero except when the Radau Jacobian probes df/d(pdot).
        pdot = 3.0 * inv_r * bracket + work[work.shape[0] - 1]
        out[2] = pdot
        ckap = (kappa - 1.0) / kappa
        c_u1 = chi * (kappa - 1.0) * inv_r / (kappa * pb)      # u = c_u1 * theta' - y * c_u2 (+ mass part)
        c_u2 = R * pdot / (3.0 * kappa * pb)
        c_fom = fom * inv_r2
        c_chi = chi * inv_r2
        # The node values go to scratch in ``work`` first and are copied out after: a loop whose
        # reads and writes all lie in one buffer (plus the read-only grid) passes LLVM's runtime
        # alias checks and is vectorised; writing ``out`` and ``coef`` directly needs more checks
        # than LLVM allows and leaves the loop scalar (measured: 280 -> 120 ns per call, nt = 64).
        ob = 1 + 4 * nt + 2 * mt
        oth = work[ob:ob + nt]
        okv = work[ob + nt:ob + 2 * nt]
        cth = work[ob + 2 * nt:ob + 3 * nt]
        # Centre node (i = 0): the first derivatives vanish by symmetry.
        d2 = grid[GR_D2C, 0] * th[0] + grid[GR_D2U, 0] * th[1]
        K = kv[0] * (av * T[0] + bv) + (1.0 - kv[0]) * (ag * T[0] + bg)
        ckt = ckap * K * T[0] * inv_pb
        cth[0] = ckt * c_chi
        if mass:
            k2 = grid[GR_D2C, 0] * kv[0] + grid[GR_D2U, 0] * kv[1]
            okv[0] = c_fom * k2
        oth[0] = ckt * pdot + cth[0] * d2
        if mass:
            for i in range(1, nt - 1):
                yi = grid[GR_Y, i]
                d1 = grid[GR_D1L, i] * th[i - 1] + grid[GR_D1C, i] * th[i] + grid[GR_D1U, i] * th[i + 1]
                d2 = grid[GR_D2L, i] * th[i - 1] + grid[GR_D2C, i] * th[i] + grid[GR_D2U, i] * th[i + 1]
                Ti = T[i]
                kvi = kv[i]
                K = kvi * (av * Ti + bv) + (1.0 - kvi) * (ag * Ti + bg)
                ckt = ckap * K * Ti * inv_pb
                cdiff = ckt * c_chi
                k1 = grid[GR_D1L, i] * kv[i - 1] + grid[GR_D1C, i] * kvi + grid[GR_D1U, i] * kv[i + 1]
                k2 = grid[GR_D2L, i] * kv[i - 1] + grid[GR_D2C, i] * kvi + grid[GR_D2U, i] * kv[i + 1]
                gam = (rv - rg) * k1 / (kvi * rv + (1.0 - kvi) * rg)
                u = c_u1 * d1 - yi * c_u2 + fom * inv_r * gam
                adv = (u - yi * U) * inv_r
                oth[i] = -adv * d1 + ckt * pdot + cdiff * d2 + c_fom * gam * d1
                okv[i] = c_fom * (k2 - k1 * (d1 / (sq[i] * Ti) + gam)) - adv * k1
                cth[i] = cdiff
            for i in range(nt - 1):
                out[i_kv + i] = okv[i]
                coef[nt + i] = c_fom
        else:
            for i in range(1, nt - 1):
                yi = grid[GR_Y, i]
                d1 = grid[GR_D1L, i] * th[i - 1] + grid[GR_D1C, i] * th[i] + grid[GR_D1U, i] * th[i + 1]
                d2 = grid[GR_D2L, i] * th[i - 1] + grid[GR_D2C, i] * th[i] + grid[GR_D2U, i] * th[i + 1]
                Ti = T[i]
                K = kv0 * (av * Ti + bv) + (1.0 - kv0) * (ag * Ti + bg)
                ckt = ckap * K * Ti * inv_pb
                cdiff = ckt * c_chi
                u = c_u1 * d1 - yi * c_u2
                oth[i] = -(u - yi * U) * inv_r * d1 + ckt * pdot + cdiff * d2
                cth[i] = cdiff
        for i in range(nt - 1):
            out[i_th + i] = oth[i]
            coef[i] = cth[i]
    # Constitutive stress integral S, its rate without the Rddot part, and J.
    S, Sdot, J = _stress(R, U, y[i_z:i_z + naux], p, g[G_REQ], out[i_z:i_z + naux])
    if medium:
        foh = g[G_FOH]
        lt = g[G_LT]
        br = g[G_BR]
        dxi = mgrid[0, 1] - mgrid[0, 0]
        tm = work[1 + 4 * nt:1 + 4 * nt + mt]
        tm[0] = Tw_bubble
        rq3 = (g[G_REQ] / R) ** 3
        for j in range(1, mt - 1):
            xi = mgrid[0, j]
            yj = mgrid[1, j]
            dT = (tm[j + 1] - tm[j - 1]) / (2.0 * dxi)
            d2T = (tm[j + 1] - 2.0 * tm[j] + tm[j - 1]) / (dxi * dxi)
            adv = U * (1.0 - yj ** 3) / (2.0 * yj * yj) + foh / R * ((1.0 + xi) / (2.0 * lt) - 1.0 / yj)
            cdm = foh / (R * R) * (1.0 + xi) ** 4 / (4.0 * lt * lt)
            xj = (yj ** 3 - 1.0 + rq3) ** (1.0 / 3.0)
            ur = U / R
            phi = 12.0 * br * p[1] * ur * ur * yj ** -6 \
                + 2.0 * br * p[0] * yj ** -3 * ur * (yj * yj / (xj * xj) - xj ** 4 / yj ** 4) \
                * _dissipation_q(xj, yj, p)
            out[i_tm + j] = (1.0 + xi) ** 2 / (lt * R) * adv * dT + cdm * d2T + phi
            coef[2 * nt + j] = cdm
    out[1] = _rddot(R, U, pb, pdot, S, Sdot, J, g, flags[F_RADIAL])


@njit(cache=True, error_model="numpy", inline="always")
def _rddot(R, U, pb, pdot, S, Sdot, J, g, radial):
    """Wall acceleration from the radial equation (1 RP, 2 KM in pressure, 3/4 enthalpy forms)."""
    W = g[G_INV_WE]
    if radial == 1:
        return (pb - 1.0 - W / R + S - 1.5 * U * U) / R
    if radial == 2:
        c = g[G_CSTAR]
        num = (1.0 + U / c) * (pb - 1.0 - W / R + S) + R / c * (pdot + W * U / (R * R) + Sdot) \
            - 1.5 * (1.0 - U / (3.0 * c)) * U * U
        return num / ((1.0 - U / c) * R + J / c)
    n = g[G_TAIT_N]
    bt = g[G_TAIT_B]
    sig = 1.0 + bt
    nu = (n - 1.0) / n
    pw = pb - W / R + bt + S
    hb = sig / nu * ((pw / sig) ** nu - 1.0)
    hh = (sig / pw) ** (1.0 / n)
    if radial == 3:
        c = g[G_CSTAR]
    else:
        c = math.sqrt(n * pw / (pw / sig) ** (1.0 / n))
    num = (1.0 + U / c) * hb + R / c * hh * (pdot + W * U / (R * R) + Sdot) \
        - 1.5 * (1.0 - U / (3.0 * c)) * U * U
    return num / ((1.0 - U / c) * R + J * hh / c)


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def _rhs_gas(y, g, p, flags, out):
    """``out = dy/dt`` for the polytropic bubble (no fields): rhs() with thermal = 0, lean enough
    for the explicit integrator, whose cost is a few RHS evaluations per step."""
    R = y[0]
    U = y[1]
    kappa = g[G_KAPPA]
    pv = g[G_PV]
    pb = (g[G_PB0] - pv) * R ** (-3.0 * kappa) + pv
    if flags[F_PDOT] == 0:
        pdot = -3.0 * kappa * pb * U / R       # IMRv2: total pressure, vapour included
    else:
        pdot = -3.0 * kappa * (pb - pv) * U / R  # exact rate of the algebraic pressure
    naux = flags[F_NAUX]
    S, Sdot, J = _stress(R, U, y[3:3 + naux], p, g[G_REQ], out[3:3 + naux])
    out[0] = U
    out[2] = 0.0
    out[1] = _rddot(R, U, pb, pdot, S, Sdot, J, g, flags[F_RADIAL])


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def integrate_member_explicit(y, t0, t1, t_eval, g, ptab, breaks, flags, rtol, atol, h_init, max_steps, r_out,
                              A, B, BH, C, order):
    """integrate_member() for the polytropic bubble with an explicit pair (AI = 0): same step
    control, dense output and status codes, without the implicit machinery, and with the last
    stage reused as the next step's first when the pair is FSAL (Dormand-Prince)."""
    n = y.shape[0]
    ns = B.shape[0]
    expo = -1.0 / order
    fsal = C[ns - 1] == 1.0
    for j in range(ns):
        if A[ns - 1, j] != B[j]:
            fsal = False
    F = np.zeros((ns, n))
    Y = np.zeros(n)
    ynew = np.zeros(n)
    fnew = np.zeros(n)
    k_eval = outputs_at_start(t_eval, t0, y[0], r_out)
    t = t0
    piece = parameter_piece(t + T_BREAK_SLACK, breaks)
    _rhs_gas(y, g, ptab[piece], flags, F[0])
    h = h_init if h_init > 0.0 else 1e-4
    nsteps = 0
    nrej = 0
    status = OK
    # Gustafsson's predictive step control on top of the standard one (as in Hairer's RADAU5):
    # when the step must shrink step after step (the approach to a collapse) it anticipates the
    # trend instead of overshooting and rejecting every other step.
    h_acc = -1.0
    err_acc = 1.0
    while before_end(t, t1):
        status = step_failure(nsteps, max_steps, h)
        if status != OK:
            break
        t_stop, h, last = next_step(t, h, t1, piece, breaks)
        pr = ptab[piece]
        ok = True
        for s in range(1, ns):
            for k in range(n):
                acc = y[k]
                for j in range(s):
                    acc += h * A[s, j] * F[j, k]
                Y[k] = acc
            if not (Y[0] > 0.0) or not math.isfinite(Y[1]):
                ok = False
                break
            _rhs_gas(Y, g, pr, flags, F[s])
        err = 0.0
        if ok:
            for k in range(n):
                yn = y[k]
                e = 0.0
                for j in range(ns):
                    yn += h * B[j] * F[j, k]
                    e += h * (B[j] - BH[j]) * F[j, k]
                ynew[k] = yn
                sc = atol + rtol * max(abs(y[k]), abs(yn))
                err += (e / sc) ** 2
            err = math.sqrt(err / n)
            if not math.isfinite(err) or not (ynew[0] > 0.0):
                ok = False
        if not ok or err > 1.0:
            h *= rejected_step_factor(ok, err, expo)
            nrej += 1
            continue
        t_new = t_stop if last else t + h
        if fsal:
            for k in range(n):
                fnew[k] = F[ns - 1, k]
        else:
            _rhs_gas(ynew, g, pr, flags, fnew)
        if not all_finite(fnew):
            h *= 0.25
            nrej += 1
            continue
        k_eval = outputs_in_step(t_eval, k_eval, t, t_new, y[0], y[1], F[0, 1], ynew[0], ynew[1], fnew[1], r_out)
        for k in range(n):
            y[k] = ynew[k]
            F[0, k] = fnew[k]
        t = t_new
        nsteps += 1
        if crossed_break(last, t, piece, breaks):
            # New parameters from here: the dense output above used the left limit.
            piece += 1
            _rhs_gas(y, g, ptab[piece], flags, F[0])
        fac = accepted_step_factor(err, expo)
        if not last:
            if h_acc > 0.0 and err > 0.0:
                fac = min(fac, max(0.2, min(5.0, 0.9 * (h / h_acc) * (err * err / err_acc) ** expo)))
            h_acc = h
            err_acc = max(1e-2, err)
        h *= fac
    return final_status(status, y, r_out, k_eval), nsteps, nrej


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def _coupling(t, y, f0, cols, g, pr, flags, grid, mgrid, work, scratch, fp, coef_tmp,
              blocks, di, lo, up, W):
    """Finite-difference Jacobian columns of the coupling variables ``cols`` minus the frozen
    tridiagonal part: W[q] = J[:, cols[q]] - T[:, cols[q]].

    These columns carry the stiff feedback that the tridiagonal diffusion operator misses: the
    bubble pressure rate depends on the wall gradients of temperature and vapour (weights ~1/dy
    at the wall) and every field rate depends on the pressure rate.
    """
    n = y.shape[0]
    for q in range(cols.shape[0]):
        j = cols[q]
        for k in range(n):
            scratch[k] = y[k]
        d = 1.5e-8 * max(abs(y[j]), 1e-3)
        scratch[j] = y[j] + d
        d = scratch[j] - y[j]
        w0 = work[0]
        rhs(t, scratch, g, pr, flags, grid, mgrid, fp, coef_tmp, work)
        work[0] = w0
        for k in range(n):
            W[q, k] = (fp[k] - f0[k]) / d
        for b in range(3):
            off = blocks[b, 0]
            m = blocks[b, 1]
            if off <= j < off + m:
                kk = j - off
                W[q, j] -= di[j]
                if kk > 0:
                    W[q, j - 1] -= up[j - 1]
                if kk < m - 1:
                    W[q, j + 1] -= lo[j + 1]


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def integrate_member(y, t0, t1, t_eval, g, ptab, breaks, flags, grid, mgrid,
                     rtol, atol, h_init, max_steps, r_out, AE, AI, B, BH, C, gamma, order, cols):
    """Advance one member's state ``y`` (in place) from t0 to t1; R at ``t_eval`` -> r_out.

    Returns (status, accepted steps, rejected steps). ``ptab`` (n_pieces, n_p): parameters per time
    piece; ``breaks`` (n_pieces-1,): piece boundaries in t*. The step never crosses a boundary.
    The Runge-Kutta pair is (AE, AI, B, BH, C): explicit and diagonally implicit tables sharing
    B, C, with diagonal ``gamma`` (0 for a purely explicit method); ``order`` sets the step exponent.
    The implicit operator is the frozen tridiagonal diffusion plus the Jacobian columns of the
    coupling variables ``cols`` (a low-rank correction solved by the Woodbury identity).
    """
    n = y.shape[0]
    ns = B.shape[0]
    implicit = gamma > 0.0
    expo = -1.0 / order
    nt = flags[F_NT]
    mt = flags[F_MT]
    blocks = field_blocks(flags)
    work = np.zeros(7 * nt + 2 * mt + 2)
    coef = np.zeros(2 * nt + mt + 1)
    coef_new = np.zeros(2 * nt + mt + 1)
    F = np.zeros((ns, n))
    FI = np.zeros((ns, n))
    Y = np.zeros(n)
    rhs_vec = np.zeros(n)
    ynew = np.zeros(n)
    fnew = np.zeros(n)
    lo = np.zeros(n)
    di = np.zeros(n)
    up = np.zeros(n)
    cp = np.zeros(n)
    dp = np.zeros(n)
    r = cols.shape[0] if implicit else 0
    Wc = np.zeros((r, n))
    Z = np.zeros((r, n))
    K = np.zeros((r, r))
    piv = np.zeros(r, dtype=np.int64)
    sv = np.zeros(r)
    scratch = np.zeros(n)
    fp = np.zeros(n)
    k_eval = outputs_at_start(t_eval, t0, y[0], r_out)
    t = t0
    piece = parameter_piece(t + T_BREAK_SLACK, breaks)
    rhs(t, y, g, ptab[piece], flags, grid, mgrid, F[0], coef, work)
    h = h_init
    if h <= 0.0:
        h = 1e-4
    # The warm-medium wall root is warm-started from the last accepted state's root, never from a
    # trial state, so that a wild trial stage cannot move the search onto another branch.
    root_acc = work[0]
    nsteps = 0
    nrej = 0
    consecutive_rej = 0
    cols_off = 0          # accepted steps left with the coupling columns switched off
    jac_age = -1
    status = OK
    while before_end(t, t1):
        status = step_failure(nsteps, max_steps, h)
        if status != OK:
            break
        t_stop, h, last = next_step(t, h, t1, piece, breaks)
        pr = ptab[piece]
        hg = h * gamma
        if implicit:
            build_tridiag(coef, blocks, grid, mgrid, lo, di, up)
            thomas_factor(blocks, lo, di, up, hg, cp, dp)
            apply_tridiag(blocks, lo, di, up, y, FI[0])
            if r > 0 and cols_off == 0:
                # The coupling columns are refreshed every few steps and after a rejection; any
                # frozen operator keeps the scheme consistent, it only has to hold the stiffness.
                if jac_age >= 8 or jac_age < 0:
                    _coupling(t, y, F[0], cols, g, pr, flags, grid, mgrid, work, scratch, fp, coef_new,
                              blocks, di, lo, up, Wc)
                    jac_age = 0
                thomas_solve_many(blocks, lo, hg, cp, dp, Wc, Z)
                for q in range(r):
                    for k in range(n):
                        # Z decays geometrically away from the wall: flush what would become
                        # subnormal numbers, whose arithmetic is ~100x slower on x86.
                        if abs(Z[q, k]) < 1e-150:
                            Z[q, k] = 0.0
                        FI[0, k] += Wc[q, k] * y[cols[q]]
                for a in range(r):
                    for q in range(r):
                        K[a, q] = (1.0 if a == q else 0.0) - hg * Z[q, cols[a]]
                if not lu_small(K, piv):
                    cols_off = 50
                    continue
        ok = True
        for s in range(1, ns):
            for k in range(n):
                rhs_vec[k] = y[k]
            # Column-wise accumulation (contiguous inner loops; zero coefficients skipped).
            for j in range(s):
                ae = h * AE[s, j]
                ai = h * (AI[s, j] - AE[s, j])
                if ae != 0.0:
                    Fj = F[j]
                    for k in range(n):
                        rhs_vec[k] += ae * Fj[k]
                if implicit and ai != 0.0:
                    FIj = FI[j]
                    for k in range(n):
                        rhs_vec[k] += ai * FIj[k]
            if implicit:
                thomas_solve(blocks, lo, hg, cp, dp, rhs_vec, Y)
                if r > 0 and cols_off == 0:
                    for a in range(r):
                        sv[a] = Y[cols[a]]
                    lu_solve_small(K, piv, sv)
                    for q in range(r):
                        for k in range(n):
                            Y[k] += hg * Z[q, k] * sv[q]
                for k in range(n):
                    FI[s, k] = (Y[k] - rhs_vec[k]) / hg
            else:
                for k in range(n):
                    Y[k] = rhs_vec[k]
            for k in range(n):
                if abs(Y[k]) < 1e-150:
                    Y[k] = 0.0
            if not (Y[0] > 0.0) or not math.isfinite(Y[1]):
                ok = False
                break
            work[0] = root_acc
            rhs(t + C[s] * h, Y, g, pr, flags, grid, mgrid, F[s], coef_new, work)
        err = 0.0
        if ok:
            for k in range(n):
                ynew[k] = y[k]
                rhs_vec[k] = 0.0
            for j in range(ns):
                bj = h * B[j]
                ej = h * (B[j] - BH[j])
                Fj = F[j]
                for k in range(n):
                    ynew[k] += bj * Fj[k]
                    rhs_vec[k] += ej * Fj[k]
            for k in range(n):
                sc = atol + rtol * max(abs(y[k]), abs(ynew[k]))
                e = rhs_vec[k] / sc
                err += e * e
            err = math.sqrt(err / n)
            if not math.isfinite(err) or not (ynew[0] > 0.0):
                ok = False
        if not ok or err > 1.0:
            h *= rejected_step_factor(ok, err, expo)
            if not ok:
                jac_age = -1
            nrej += 1
            consecutive_rej += 1
            # A linearisation that fails repeatedly (an unstable or non-smooth coupling, e.g.
            # the warm-medium wall root near collapse) is dropped for a while: the plain
            # tridiagonal splitting is always consistent, only less stable.
            if consecutive_rej >= 8 and r > 0 and cols_off == 0:
                cols_off = 50
                consecutive_rej = 0
            continue
        t_new = t_stop if last else t + h
        work[0] = root_acc
        rhs(t_new, ynew, g, pr, flags, grid, mgrid, fnew, coef_new, work)
        if not all_finite(fnew):
            h *= 0.25
            nrej += 1
            continue
        # Dense output of R on (t, t_new].
        k_eval = outputs_in_step(t_eval, k_eval, t, t_new, y[0], y[1], F[0, 1], ynew[0], ynew[1], fnew[1], r_out)
        for k in range(n):
            # Diffusion spreads exponentially small values into the bubble interior; flushing
            # them (far below any tolerance) keeps subnormal arithmetic (~100x slower) away.
            y[k] = ynew[k] if abs(ynew[k]) > 1e-150 else 0.0
            F[0, k] = fnew[k] if abs(fnew[k]) > 1e-150 else 0.0
        for k in range(coef.shape[0]):
            coef[k] = coef_new[k]
        t = t_new
        root_acc = work[0]
        nsteps += 1
        jac_age += 1
        consecutive_rej = 0
        if cols_off > 0:
            cols_off -= 1
            if cols_off == 0:
                jac_age = -1
        if crossed_break(last, t, piece, breaks):
            piece += 1
        fac = accepted_step_factor(err, expo)
        h *= fac
    return final_status(status, y, r_out, k_eval), nsteps, nrej


# ----------------------------------------------------------------------------------------------
# Radau IIA (order 5, 3 stages) for the thermal bubble with a cold medium.
#
# Why: the additive Runge-Kutta pair above treats only the field diffusion (and a few coupling
# columns) implicitly, and needs ~2,500 steps over t* in [0, 3] on the converged grid; a fully
# implicit, stiffly accurate collocation method with the whole Jacobian needs ~600 at the same
# tolerance (~350 at 10x looser, still 20x inside the 1e-4 bound on R). The algorithm (simplified
# Newton on the transformed collocation system, Jacobian reuse, the embedded error estimate and
# predictive step control) is Hairer & Wanner's RADAU5 (Solving ODEs II, IV.8) as scipy's
# `Radau` implements it; the linear algebra is ours: the Jacobian is a 2x2-block tridiagonal
# matrix over the bubble nodes (temperature, vapour) plus a few dense columns (R, Rdot, p_b, the
# two field values next to the wall, stress states), so (a I - J) is solved by block Thomas
# sweeps and the Woodbury identity, O(nt) per solve, in real and complex arithmetic.
_S6 = 6.0 ** 0.5
RADAU_C = np.array([(4.0 - _S6) / 10.0, (4.0 + _S6) / 10.0, 1.0])
RADAU_E = np.array([-13.0 - 7.0 * _S6, -13.0 + 7.0 * _S6, -1.0]) / 3.0
RADAU_MU_REAL = 3.0 + 3.0 ** (2.0 / 3.0) - 3.0 ** (1.0 / 3.0)
RADAU_MU_COMPLEX = complex(3.0 + 0.5 * (3.0 ** (1.0 / 3.0) - 3.0 ** (2.0 / 3.0)),
                           -0.5 * (3.0 ** (5.0 / 6.0) + 3.0 ** (7.0 / 6.0)))
RADAU_T = np.array([[0.09443876248897524, -0.14125529502095421, 0.03002919410514742],
                    [0.25021312296533332, 0.20412935229379994, -0.38294211275726192],
                    [1.0, 1.0, 0.0]])
RADAU_TI = np.array([[4.17871859155190428, 0.32768282076106237, 0.52337644549944951],
                     [-4.17871859155190428, -0.32768282076106237, 0.47662355450055044],
                     [0.50287263494578682, -2.57192694985560522, 0.59603920482822492]])
RADAU_P = np.array([[13.0 / 3.0 + 7.0 * _S6 / 3.0, -23.0 / 3.0 - 22.0 * _S6 / 3.0, 10.0 / 3.0 + 5.0 * _S6],
                    [13.0 / 3.0 - 7.0 * _S6 / 3.0, -23.0 / 3.0 + 22.0 * _S6 / 3.0, 10.0 / 3.0 - 5.0 * _S6],
                    [1.0 / 3.0, -8.0 / 3.0, 10.0 / 3.0]])
_NEWTON_MAXITER = 6
_THET = 1e-3
_QUOT1 = 0.0
_QUOT2 = 1.2


@njit(cache=True, error_model="numpy")
def _radau_jacobian(t, y, f0, g, pr, flags, grid, mgrid, cols, in_cols, o1, bs, m, Jl, Jd, Ju, U, vidx, vval,
                    vcnt, ypert, fp, coef, work):
    """Finite-difference Jacobian in the solver's structure, J = blocks + U V^T:

    * blocks: the 2x2-block tridiagonal part over the bubble nodes 0..m-1 (fields temperature,
      vapour; Jl couples node i to i-1, Jd to itself, Ju to i+1; [row field, column field]),
      from 3*bs coloured evaluations;
    * U V^T: one term per non-field column in ``cols`` (R, Rdot, p_b, stress states: the whole
      column, V = that unit vector) and one rank-one term w g^T for the field values next to the
      wall in ``cols``: they reach every other row only through the bubble pressure rate, so
      w = df/d(pdot) (one evaluation with pdot shifted through ``work[-1]``) and g = d(pdot)/dy
      on those cells (row 2 of their columns). The wall cells are perturbed in the coloured
      evaluations with the rest (the 3-colouring puts at most one of them in each evaluation);
      subtracting w times the change of row 2 leaves their local columns for the blocks.

    ``in_cols`` (n,) marks the state indices in ``cols``.
    Returns the number of low-rank terms."""
    n = y.shape[0]
    for k in range(n):
        ypert[k] = y[k]
    for i in range(m):
        for a in range(bs):
            for b in range(bs):
                Jl[i, b, a] = 0.0
                Jd[i, b, a] = 0.0
                Ju[i, b, a] = 0.0
    nf = 0
    nw = 0
    for q in range(cols.shape[0]):
        j = cols[q]
        if (3 <= j < 3 + m) or (bs == 2 and o1 <= j < o1 + m):
            nw += 1
        else:
            nf += 1
    kw = nf
    if nw > 0:
        dp = 1.5e-8 * max(abs(f0[2]), 1.0)
        last = work.shape[0] - 1
        work[last] = dp
        rhs(t, y, g, pr, flags, grid, mgrid, fp, coef, work)
        work[last] = 0.0
        inv = 1.0 / dp
        for k in range(n):
            U[kw, k] = (fp[k] - f0[k]) * inv
    e = 0
    for a in range(bs):
        off = 3 if a == 0 else o1
        for c in range(3):
            if c >= m:
                continue
            jw = -1
            for i in range(c, m, 3):
                j = off + i
                ypert[j] = y[j] + 1.5e-8 * max(abs(y[j]), 1e-3)
                if nw > 0 and in_cols[j]:
                    jw = j
            rhs(t, ypert, g, pr, flags, grid, mgrid, fp, coef, work)
            if jw >= 0:
                # The wall cell's reach through the pressure rate is the low-rank term's job.
                dpd = fp[2] - f0[2]
                for b in range(bs):
                    ob = 3 if b == 0 else o1
                    for r in range(ob, ob + m):
                        fp[r] -= U[kw, r] * dpd
                vidx[kw, e] = jw
                vval[kw, e] = dpd / (ypert[jw] - y[jw])
                e += 1
            for i in range(c, m, 3):
                j = off + i
                inv = 1.0 / (ypert[j] - y[j])
                for b in range(bs):
                    ob = 3 if b == 0 else o1
                    Jd[i, b, a] = (fp[ob + i] - f0[ob + i]) * inv
                    if i + 1 < m:
                        Jl[i + 1, b, a] = (fp[ob + i + 1] - f0[ob + i + 1]) * inv
                    if i > 0:
                        Ju[i - 1, b, a] = (fp[ob + i - 1] - f0[ob + i - 1]) * inv
                ypert[j] = y[j]
    if nw > 0:
        vcnt[kw] = e
    kk = 0
    for q in range(cols.shape[0]):
        j = cols[q]
        if (3 <= j < 3 + m) or (bs == 2 and o1 <= j < o1 + m):
            continue
        ypert[j] = y[j] + 1.5e-8 * max(abs(y[j]), 1e-3)
        inv = 1.0 / (ypert[j] - y[j])
        rhs(t, ypert, g, pr, flags, grid, mgrid, fp, coef, work)
        ypert[j] = y[j]
        for k in range(n):
            U[kk, k] = (fp[k] - f0[k]) * inv
        vidx[kk, 0] = j
        vval[kk, 0] = 1.0
        vcnt[kk] = 1
        kk += 1
    if nw > 0:
        kk += 1
    # Non-finite entries (a probe across a singularity) are zeroed. One pass of products with
    # zero finds out whether there are any: 0 * x is 0 for finite x and NaN otherwise.
    probe = 0.0
    for r in range(kk):
        for k in range(n):
            probe += 0.0 * U[r, k]
        for e in range(vcnt[r]):
            probe += 0.0 * vval[r, e]
    for i in range(m):
        for a in range(bs):
            for b in range(bs):
                probe += 0.0 * (Jl[i, b, a] + Jd[i, b, a] + Ju[i, b, a])
    if probe == 0.0:
        return kk
    for r in range(kk):
        for k in range(n):
            if not math.isfinite(U[r, k]):
                U[r, k] = 0.0
        for e in range(vcnt[r]):
            if not math.isfinite(vval[r, e]):
                vval[r, e] = 0.0
    for i in range(m):
        for a in range(bs):
            for b in range(bs):
                if not math.isfinite(Jl[i, b, a]):
                    Jl[i, b, a] = 0.0
                if not math.isfinite(Jd[i, b, a]):
                    Jd[i, b, a] = 0.0
                if not math.isfinite(Ju[i, b, a]):
                    Ju[i, b, a] = 0.0
    return kk


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def integrate_member_radau(y, t0, t1, t_eval, g, ptab, breaks, flags, grid, mgrid, rtol, atol, h_init,
                           max_steps, r_out, dense):
    """Advance one member's state ``y`` (in place) from t0 to t1 with Radau IIA (order 5); R at
    ``t_eval`` -> r_out. ``dense``: state indices whose Jacobian columns are kept whole (every
    other entry of the Jacobian lies in the 2x2-block tridiagonal pattern of the bubble fields).
    Returns (status, accepted steps, rejected steps)."""
    n = y.shape[0]
    nt = flags[F_NT]
    m = nt - 1
    bs = 2 if flags[F_MASS] else 1
    nc = dense.shape[0]
    o1 = 3 + nt * flags[F_THERMAL] + flags[F_MT] * flags[F_MEDIUM]
    in_cols = np.zeros(n, dtype=np.bool_)
    for q in range(nc):
        in_cols[dense[q]] = True
    work = np.zeros(7 * nt + 2 * flags[F_MT] + 2)
    coef = np.zeros(2 * nt + flags[F_MT] + 1)
    Jl = np.zeros((m, bs, bs))
    Jd = np.zeros((m, bs, bs))
    Ju = np.zeros((m, bs, bs))
    U = np.zeros((nc, n))
    vidx = np.zeros((nc, nc), dtype=np.int64)
    vval = np.zeros((nc, nc))
    vcnt = np.zeros(nc, dtype=np.int64)
    invD_r = np.zeros((m, bs, bs))
    Cu_r = np.zeros((m, bs, bs))
    Pl_r = np.zeros((m, bs, bs))
    Z_r = np.zeros((nc, n))
    K_r = np.zeros((nc, nc))
    piv_r = np.zeros(nc, dtype=np.int64)
    invD_c = np.zeros((m, bs, bs), dtype=np.complex128)
    Cu_c = np.zeros((m, bs, bs), dtype=np.complex128)
    Pl_c = np.zeros((m, bs, bs), dtype=np.complex128)
    Z_c = np.zeros((nc, n), dtype=np.complex128)
    K_c = np.zeros((nc, nc), dtype=np.complex128)
    piv_c = np.zeros(nc, dtype=np.int64)
    gv_r = np.zeros((m, bs))
    gv_c = np.zeros((m, bs), dtype=np.complex128)
    gm_r = np.zeros((m, bs, nc))
    gm_c = np.zeros((m, bs, nc), dtype=np.complex128)
    sv_r = np.zeros(nc)
    sv_c = np.zeros(nc, dtype=np.complex128)
    ypert = np.zeros(n)
    fp = np.zeros(n)
    f = np.zeros(n)
    fnew = np.zeros(n)
    ynew = np.zeros(n)
    yold = np.zeros(n)
    ystage = np.zeros(n)
    Zs = np.zeros((3, n))
    Z0 = np.zeros((3, n))
    Wn = np.zeros((3, n))
    F = np.zeros((3, n))
    Q = np.zeros((n, 3))
    fr = np.zeros(n)
    fc = np.zeros(n, dtype=np.complex128)
    xr = np.zeros(n)
    xc = np.zeros(n, dtype=np.complex128)
    scale = np.zeros(n)
    iscale = np.zeros(n)
    err = np.zeros(n)
    k_eval = outputs_at_start(t_eval, t0, y[0], r_out)
    newton_tol = max(10.0 * 2.220446049250313e-16 / rtol, min(0.03, rtol ** 0.5))
    t = t0
    piece = parameter_piece(t + T_BREAK_SLACK, breaks)
    pr = ptab[piece]
    rhs(t, y, g, pr, flags, grid, mgrid, f, coef, work)
    h = h_init if h_init > 0.0 else 1e-4
    h_old = -1.0
    err_old = -1.0
    have_sol = False
    t_old = t
    hsol = 1.0
    nrank = _radau_jacobian(t, y, f, g, pr, flags, grid, mgrid, dense, in_cols, o1, bs, m, Jl, Jd, Ju, U, vidx, vval, vcnt,
                         ypert, fp, coef, work)
    current_jac = True
    lu_ok = False
    nsteps = 0
    nrej = 0
    status = OK
    while before_end(t, t1):
        if nsteps >= max_steps:
            status = FAIL_MAXSTEPS
            break
        t_stop = piece_end(t1, piece, breaks)
        rejected = False
        accepted = False
        last = False
        safety = 0.9
        n_iter = 0
        rate = -1.0
        err_norm = 0.0
        while not accepted:
            if h < MIN_STEP:
                status = FAIL_STEP
                break
            h, last = clip_step(t, h, t_stop)
            ar = RADAU_MU_REAL / h
            ac = RADAU_MU_COMPLEX / h
            for i in range(3):
                if have_sol:
                    x = (t + RADAU_C[i] * h - t_old) / hsol
                    for kk in range(n):
                        Z0[i, kk] = ((Q[kk, 2] * x + Q[kk, 1]) * x + Q[kk, 0]) * x + yold[kk] - y[kk]
                else:
                    for kk in range(n):
                        Z0[i, kk] = 0.0
            for kk in range(n):
                iscale[kk] = 1.0 / (atol + abs(y[kk]) * rtol)
            converged = False
            finite = True
            h_fail = 0.5
            while not converged:
                if not lu_ok:
                    lu_ok = radau_factor_pair(ar, ac, o1, bs, m, nrank, Jl, Jd, Ju, U, vidx, vval, vcnt, invD_r, Cu_r,
                                               Pl_r, Z_r, K_r, piv_r, invD_c, Cu_c, Pl_c, Z_c, K_c, piv_c, gm_r, gm_c)
                    if not lu_ok:
                        break
                # Simplified Newton on the transformed system (W = TI Z).
                for i in range(3):
                    for kk in range(n):
                        Wn[i, kk] = RADAU_TI[i, 0] * Z0[0, kk] + RADAU_TI[i, 1] * Z0[1, kk] + RADAU_TI[i, 2] * Z0[2, kk]
                        Zs[i, kk] = Z0[i, kk]
                dw_old = -1.0
                rate = -1.0
                finite = True
                for it in range(_NEWTON_MAXITER):
                    n_iter = it + 1
                    for i in range(3):
                        for kk in range(n):
                            ystage[kk] = y[kk] + Zs[i, kk]
                        if not (ystage[0] > 0.0):
                            finite = False
                            break
                        # A non-finite rate propagates into the norm of the Newton update below.
                        rhs(t + RADAU_C[i] * h, ystage, g, pr, flags, grid, mgrid, F[i], coef, work)
                    if not finite:
                        break
                    for kk in range(n):
                        fr[kk] = (RADAU_TI[0, 0] * F[0, kk] + RADAU_TI[0, 1] * F[1, kk] + RADAU_TI[0, 2] * F[2, kk]
                                  - ar * Wn[0, kk])
                        fc[kk] = complex(RADAU_TI[1, 0] * F[0, kk] + RADAU_TI[1, 1] * F[1, kk] + RADAU_TI[1, 2] * F[2, kk],
                                         RADAU_TI[2, 0] * F[0, kk] + RADAU_TI[2, 1] * F[1, kk] + RADAU_TI[2, 2] * F[2, kk]) \
                            - ac * complex(Wn[1, kk], Wn[2, kk])
                    radau_solve_pair(ar, ac, o1, bs, m, nrank, Pl_r, invD_r, Cu_r, Z_r, K_r, piv_r, Pl_c, invD_c, Cu_c,
                                      Z_c, K_c, piv_c, vidx, vval, vcnt, fr, fc, xr, xc, gv_r, gv_c, sv_r, sv_c)
                    # W += dW and Z = T W before the convergence test on the norm of dW: a diverging
                    # iteration breaks out below and the retry starts again from Z0, so the update is
                    # harmless. Three simple loops rather than one: each passes LLVM's alias checks and
                    # is vectorised (the fused loop stayed scalar: 287 -> 137 ns at n = 131).
                    s2 = 0.0
                    for kk in range(n):
                        isc = iscale[kk]
                        s2 += (xr[kk] * isc) ** 2 + (xc[kk].real * isc) ** 2 + (xc[kk].imag * isc) ** 2
                    for kk in range(n):
                        Wn[0, kk] += xr[kk]
                        Wn[1, kk] += xc[kk].real
                        Wn[2, kk] += xc[kk].imag
                    for kk in range(n):
                        w0 = Wn[0, kk]
                        w1 = Wn[1, kk]
                        w2 = Wn[2, kk]
                        Zs[0, kk] = RADAU_T[0, 0] * w0 + RADAU_T[0, 1] * w1 + RADAU_T[0, 2] * w2
                        Zs[1, kk] = RADAU_T[1, 0] * w0 + RADAU_T[1, 1] * w1 + RADAU_T[1, 2] * w2
                        Zs[2, kk] = w0 + w1
                    dw = math.sqrt(s2 / (3 * n))
                    if not math.isfinite(dw):
                        finite = False
                        break
                    if dw_old >= 0.0:
                        rate = dw / dw_old
                    if rate >= 0.0 and (rate >= 1.0 or rate ** (_NEWTON_MAXITER - it) / (1.0 - rate) * dw > newton_tol):
                        # RADAU5's step reduction after a Newton failure: the further from
                        # convergence the iteration is predicted to end, the smaller the retry
                        # (a fixed halving undershot, and the next step doubled back into failure).
                        if rate < 0.99:
                            q = max(1e-4, min(20.0, rate ** (_NEWTON_MAXITER - it) / (1.0 - rate) * dw / newton_tol))
                            h_fail = 0.8 * q ** (-1.0 / (2.0 + _NEWTON_MAXITER - it))
                        break
                    if dw == 0.0 or (rate >= 0.0 and rate / (1.0 - rate) * dw < newton_tol):
                        converged = True
                        break
                    dw_old = dw
                if converged or not finite:
                    break
                if current_jac:
                    break
                nrank = _radau_jacobian(t, y, f, g, pr, flags, grid, mgrid, dense, in_cols, o1, bs, m, Jl, Jd, Ju, U, vidx,
                                     vval, vcnt, ypert, fp, coef, work)
                current_jac = True
                lu_ok = False
            if not converged:
                h *= h_fail if finite else 0.25
                lu_ok = False
                rejected = True
                nrej += 1
                continue
            for kk in range(n):
                ynew[kk] = y[kk] + Zs[2, kk]
            if not (ynew[0] > 0.0):
                h *= 0.25
                lu_ok = False
                nrej += 1
                continue
            for kk in range(n):
                fr[kk] = f[kk] + (RADAU_E[0] * Zs[0, kk] + RADAU_E[1] * Zs[1, kk] + RADAU_E[2] * Zs[2, kk]) / h
            radau_solve(ar, o1, bs, m, nrank, Pl_r, invD_r, Cu_r, Z_r, K_r, piv_r, vidx, vval, vcnt, fr, err, gv_r, sv_r)
            for kk in range(n):
                scale[kk] = atol + max(abs(y[kk]), abs(ynew[kk])) * rtol
            err_norm = rms_norm(err, scale)
            safety = 0.9 * (2 * _NEWTON_MAXITER + 1) / (2 * _NEWTON_MAXITER + n_iter)
            if rejected and err_norm > 1.0:
                for kk in range(n):
                    ystage[kk] = y[kk] + err[kk]
                rhs(t, ystage, g, pr, flags, grid, mgrid, fp, coef, work)
                for kk in range(n):
                    fr[kk] = fp[kk] + (RADAU_E[0] * Zs[0, kk] + RADAU_E[1] * Zs[1, kk] + RADAU_E[2] * Zs[2, kk]) / h
                radau_solve(ar, o1, bs, m, nrank, Pl_r, invD_r, Cu_r, Z_r, K_r, piv_r, vidx, vval, vcnt, fr, err, gv_r, sv_r)
                err_norm = rms_norm(err, scale)
            if not math.isfinite(err_norm):
                h *= 0.25
                lu_ok = False
                nrej += 1
                rejected = True
                continue
            if err_norm > 1.0:
                if err_old < 0.0 or h_old < 0.0:
                    mult = 1.0
                else:
                    mult = h / h_old * (err_old / err_norm) ** 0.25
                fac = min(1.0, mult) * err_norm ** -0.25
                h *= max(0.2, safety * fac)
                lu_ok = False
                rejected = True
                nrej += 1
            else:
                accepted = True
        if status != OK:
            break
        recompute_jac = n_iter > 2 and rate > _THET
        if err_norm == 0.0:
            fac = 10.0
        else:
            if err_old < 0.0 or h_old < 0.0:
                mult = 1.0
            else:
                mult = h / h_old * (err_old / err_norm) ** 0.25
            fac = min(10.0, safety * min(1.0, mult) * err_norm ** -0.25)
        if rejected:
            fac = min(fac, 1.0)      # RADAU5: no growth right after a rejected attempt
        if not recompute_jac and _QUOT1 <= fac < _QUOT2:
            fac = 1.0
        else:
            lu_ok = False
        t_new = t_stop if last else t + h
        rhs(t_new, ynew, g, pr, flags, grid, mgrid, fnew, coef, work)
        # Dense output of R on (t, t_new].
        k_eval = outputs_in_step(t_eval, k_eval, t, t_new, y[0], y[1], f[1], ynew[0], ynew[1], fnew[1], r_out)
        # The collocation polynomial of this step predicts the next step's stages.
        for kk in range(n):
            for j in range(3):
                Q[kk, j] = Zs[0, kk] * RADAU_P[0, j] + Zs[1, kk] * RADAU_P[1, j] + Zs[2, kk] * RADAU_P[2, j]
            yold[kk] = y[kk]
        t_old = t
        hsol = t_new - t
        have_sol = True
        for kk in range(n):
            y[kk] = ynew[kk] if abs(ynew[kk]) > 1e-150 else 0.0
            f[kk] = fnew[kk]
        h_old = h
        err_old = err_norm
        t = t_new
        nsteps += 1
        h = h * fac
        if crossed_break(last, t, piece, breaks):
            # New parameters from here: fresh rate, Jacobian and no extrapolation across the jump.
            piece += 1
            pr = ptab[piece]
            rhs(t, y, g, pr, flags, grid, mgrid, f, coef, work)
            recompute_jac = True
            have_sol = False
            lu_ok = False
            h_old = -1.0
            err_old = -1.0
        if recompute_jac:
            nrank = _radau_jacobian(t, y, f, g, pr, flags, grid, mgrid, dense, in_cols, o1, bs, m, Jl, Jd, Ju, U, vidx,
                                 vval, vcnt, ypert, fp, coef, work)
            current_jac = True
        else:
            current_jac = False
    return final_status(status, y, r_out, k_eval), nsteps, nrej


@njit(cache=True, error_model="numpy")
def _integrate_into(m, Y, R, status, nsteps, nrej, t0, t1, t_eval, G, P, breaks, flags, grid, mgrid,
                    rtol, atol, h_init, max_steps, AE, AI, B, BH, C, gamma, order, cols, radau):
    """Integrate member m of a batch in place (shared by the serial and threaded drivers)."""
    ym = Y[m]
    finite = True
    for k in range(ym.shape[0]):
        if not math.isfinite(ym[k]):
            finite = False
    if not finite or not (ym[0] > 0.0):
        status[m] = FAIL_NONFINITE if not finite else FAIL_RADIUS
        return
    te = t_eval[m]
    if radau:
        st, ns, nr = integrate_member_radau(ym, t0, t1, te, G[m], P[m], breaks[m], flags, grid, mgrid, rtol,
                                            atol, h_init, max_steps, R[m], cols)
    elif flags[F_THERMAL] == 0 and gamma == 0.0:
        st, ns, nr = integrate_member_explicit(ym, t0, t1, te, G[m], P[m], breaks[m], flags, rtol, atol,
                                               h_init, max_steps, R[m], AE, B, BH, C, order)
    else:
        st, ns, nr = integrate_member(ym, t0, t1, te, G[m], P[m], breaks[m], flags, grid, mgrid,
                                      rtol, atol, h_init, max_steps, R[m], AE, AI, B, BH, C, gamma, order, cols)
    status[m] = st
    nsteps[m] = ns
    nrej[m] = nr


@njit(cache=True, error_model="numpy")
def integrate_batch(Y0, t0, t1, t_eval, G, P, breaks, flags, grid, mgrid,
                    rtol, atol, h_init, max_steps, AE, AI, B, BH, C, gamma, order, cols, radau):
    """Propagate N members. Y0 (N, n) is copied; returns (Y_end, R (N, m), status, nsteps, nrejected).
    ``t_eval`` (N, m): each member's own output times (rows may differ, e.g. per-member time offsets).

    ``G`` (N, n_groups) per-member groups; ``P`` (N, n_pieces, n_p) parameters, whose pieces
    change at the member's ``breaks`` (N, n_pieces - 1) in t*.
    """
    N = Y0.shape[0]
    Y, R, status, nsteps, nrej = batch_outputs(Y0, t_eval.shape[1])
    for m in range(N):
        _integrate_into(m, Y, R, status, nsteps, nrej, t0, t1, t_eval, G, P, breaks, flags, grid, mgrid,
                        rtol, atol, h_init, max_steps, AE, AI, B, BH, C, gamma, order, cols, radau)
    return Y, R, status, nsteps, nrej


@njit(cache=True, error_model="numpy", parallel=True)
def integrate_batch_parallel(Y0, t0, t1, t_eval, G, P, breaks, flags, grid, mgrid,
                             rtol, atol, h_init, max_steps, AE, AI, B, BH, C, gamma, order, cols,
                             radau):
    """As integrate_batch, with the members spread over numba threads (prange)."""
    N = Y0.shape[0]
    Y, R, status, nsteps, nrej = batch_outputs(Y0, t_eval.shape[1])
    for m in prange(N):
        _integrate_into(m, Y, R, status, nsteps, nrej, t0, t1, t_eval, G, P, breaks, flags, grid, mgrid,
                        rtol, atol, h_init, max_steps, AE, AI, B, BH, C, gamma, order, cols, radau)
    return Y, R, status, nsteps, nrej
