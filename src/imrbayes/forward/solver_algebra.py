"""The forward kernel's linear algebra: everything its implicit integrators solve that does not
depend on the constitutive model (numba functions, compiled and cached once, not per model).

The per-model kernel (``_kernel_template.py``, copied per model by ``codegen.py``) imports these;
``codegen`` hashes this file into the kernel's name, so an edit here recompiles every model.

* The ARK integrator's implicit operator: per field block (bubble temperature, vapour fraction,
  medium temperature; :func:`field_blocks`) a tridiagonal diffusion matrix A with frozen
  coefficients, ``(I - hg A)`` factorised and solved by the Thomas algorithm.
* Small dense LU (the Woodbury capacitance matrices, a few rows).
* Radau IIA's Newton systems ``(a I - J)`` with ``J = blocks + U V^T``: 1x1 or 2x2-block
  tridiagonal over the bubble nodes (block Thomas, real and complex ``a``) plus a low-rank part
  (Woodbury identity). Block arrays ``Jl, Jd, Ju, invD, Cu, Pl`` have shape (m, bs, bs): m bubble
  nodes, bs = 1 (temperature) or 2 (temperature, vapour); the nodes' unknowns sit at state
  indices 3..3+m-1 and (bs = 2) o1..o1+m-1; every other row of M is ``a I``.

All quantities are dimensionless. State vectors have length n (the model's state size).
"""

import math

import numpy as np
from numba import njit

from imrbayes.forward.layout import F_MASS, F_MEDIUM, F_MT, F_NT, F_THERMAL, GR_D2C, GR_D2L, GR_D2U

# The integration loops' floating-point flags (no "nnan"/"ninf": the loops test for NaN and inf).
FASTMATH = {"contract", "arcp", "reassoc", "nsz"}


@njit(cache=True, error_model="numpy")
def field_blocks(flags):
    """(offset, length, coef offset) of each implicit field block; length 0 when absent."""
    nt = flags[F_NT]
    mt = flags[F_MT]
    thermal = flags[F_THERMAL]
    medium = flags[F_MEDIUM]
    mass = flags[F_MASS]
    i_tm = 3 + nt * thermal
    i_kv = i_tm + mt * medium
    out = np.zeros((3, 3), dtype=np.int64)
    if thermal:
        out[0, 0] = 3
        out[0, 1] = nt - 1          # unknowns 0..nt-2 (the wall row is not evolved)
        out[0, 2] = 0
    if mass:
        out[1, 0] = i_kv
        out[1, 1] = nt - 1
        out[1, 2] = nt
    if medium:
        out[2, 0] = i_tm + 1        # interior nodes 1..mt-2
        out[2, 1] = mt - 2
        out[2, 2] = 2 * nt + 1
    return out


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def build_tridiag(coef, blocks, grid, mgrid, lo, di, up):
    """Tridiagonal diffusion operator A (frozen coefficients) for each block, in place."""
    for b in range(3):
        off = blocks[b, 0]
        m = blocks[b, 1]
        co = blocks[b, 2]
        if m == 0:
            continue
        if b < 2:
            for k in range(m):
                c = coef[co + k]
                lo[off + k] = c * grid[GR_D2L, k] if k > 0 else 0.0
                di[off + k] = c * grid[GR_D2C, k]
                up[off + k] = c * grid[GR_D2U, k] if k < m - 1 else 0.0
        else:
            dxi = mgrid[0, 1] - mgrid[0, 0]
            for k in range(m):
                c = coef[co + k] / (dxi * dxi)
                lo[off + k] = c if k > 0 else 0.0
                di[off + k] = -2.0 * c
                up[off + k] = c if k < m - 1 else 0.0


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def apply_tridiag(blocks, lo, di, up, x, out):
    """out = A x on the block unknowns (0 elsewhere)."""
    for k in range(out.shape[0]):
        out[k] = 0.0
    for b in range(3):
        off = blocks[b, 0]
        m = blocks[b, 1]
        for k in range(m):
            s = di[off + k] * x[off + k]
            if k > 0:
                s += lo[off + k] * x[off + k - 1]
            if k < m - 1:
                s += up[off + k] * x[off + k + 1]
            out[off + k] = s


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def thomas_factor(blocks, lo, di, up, hg, cp, dp):
    """Thomas factorisation of (I - hg*A): per unknown, the modified super-diagonal (cp) and the
    inverse pivot (dp), so that a solve costs no division."""
    for b in range(3):
        off = blocks[b, 0]
        m = blocks[b, 1]
        for k in range(m):
            a = -hg * lo[off + k]
            d = 1.0 - hg * di[off + k]
            c = -hg * up[off + k]
            if k == 0:
                piv = d
            else:
                piv = d - a * cp[off + k - 1]
            inv = 1.0 / piv
            dp[off + k] = inv
            cp[off + k] = c * inv


@njit(cache=True, error_model="numpy", inline="always", fastmath=FASTMATH)
def thomas_solve(blocks, lo, hg, cp, dp, rhs_vec, x):
    """x = (I - hg*A)^-1 rhs on the block unknowns; other components x = rhs.

    The forward sweep is a chain of dependent operations, so its cost is latency: when the
    temperature and vapour blocks have the same length (the thermal bubble with mass transfer)
    they are swept together, two independent chains per iteration."""
    for k in range(rhs_vec.shape[0]):
        x[k] = rhs_vec[k]
    b0 = 0
    if blocks[0, 1] > 0 and blocks[0, 1] == blocks[1, 1]:
        o0 = blocks[0, 0]
        o1 = blocks[1, 0]
        m = blocks[0, 1]
        x[o0] = rhs_vec[o0] * dp[o0]
        x[o1] = rhs_vec[o1] * dp[o1]
        for k in range(1, m):
            x[o0 + k] = (rhs_vec[o0 + k] + hg * lo[o0 + k] * x[o0 + k - 1]) * dp[o0 + k]
            x[o1 + k] = (rhs_vec[o1 + k] + hg * lo[o1 + k] * x[o1 + k - 1]) * dp[o1 + k]
        for k in range(m - 2, -1, -1):
            x[o0 + k] -= cp[o0 + k] * x[o0 + k + 1]
            x[o1 + k] -= cp[o1 + k] * x[o1 + k + 1]
        b0 = 2
    for b in range(b0, 3):
        off = blocks[b, 0]
        m = blocks[b, 1]
        if m == 0:
            continue
        x[off] = rhs_vec[off] * dp[off]
        for k in range(1, m):
            x[off + k] = (rhs_vec[off + k] + hg * lo[off + k] * x[off + k - 1]) * dp[off + k]
        for k in range(m - 2, -1, -1):
            x[off + k] -= cp[off + k] * x[off + k + 1]


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def thomas_solve_many(blocks, lo, hg, cp, dp, R, X):
    """X[q] = (I - hg*A)^-1 R[q] for every row q: the rows' sweeps are interleaved (independent
    dependency chains), which hides the latency that dominates one sweep."""
    r = R.shape[0]
    n = R.shape[1]
    for q in range(r):
        for k in range(n):
            X[q, k] = R[q, k]
    for b in range(3):
        off = blocks[b, 0]
        m = blocks[b, 1]
        if m == 0:
            continue
        for q in range(r):
            X[q, off] = R[q, off] * dp[off]
        for k in range(1, m):
            a = hg * lo[off + k]
            d = dp[off + k]
            for q in range(r):
                X[q, off + k] = (R[q, off + k] + a * X[q, off + k - 1]) * d
        for k in range(m - 2, -1, -1):
            c = cp[off + k]
            for q in range(r):
                X[q, off + k] -= c * X[q, off + k + 1]


@njit(cache=True, error_model="numpy")
def lu_small(K, piv):
    """In-place LU with partial pivoting of a small dense matrix; False if singular."""
    r = K.shape[0]
    for c in range(r):
        p = c
        big = abs(K[c, c])
        for i in range(c + 1, r):
            if abs(K[i, c]) > big:
                big = abs(K[i, c])
                p = i
        if big == 0.0 or not math.isfinite(big):
            return False
        piv[c] = p
        if p != c:
            for k in range(r):
                tmp = K[c, k]
                K[c, k] = K[p, k]
                K[p, k] = tmp
        for i in range(c + 1, r):
            K[i, c] /= K[c, c]
            for k in range(c + 1, r):
                K[i, k] -= K[i, c] * K[c, k]
    return True


@njit(cache=True, error_model="numpy")
def lu_solve_small(K, piv, b):
    """b <- K^-1 b in place, from lu_small's factors and pivots."""
    r = K.shape[0]
    for c in range(r):
        p = piv[c]
        if p != c:
            tmp = b[c]
            b[c] = b[p]
            b[p] = tmp
    for i in range(r):
        for k in range(i):
            b[i] -= K[i, k] * b[k]
    for i in range(r - 1, -1, -1):
        for k in range(i + 1, r):
            b[i] -= K[i, k] * b[k]
        b[i] /= K[i, i]


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def bt_factor_scalar(a, m, Jl, Jd, Ju, invD, Cu, Pl):
    """Block-Thomas pivots of M = a I - blocks for 1x1 blocks (no vapour field; the 2x2 case is
    bt_factor_pair): invD_i = (a - Jd_i + Jl_i C_{i-1})^-1, C_i = -invD_i Ju_i and the forward
    multipliers Pl_i = invD_i Jl_i (Pl_0 = 0). False if a pivot is singular."""
    cprev = 0.0 * a
    for i in range(m):
        d = a - Jd[i, 0, 0]
        if i > 0:
            d += Jl[i, 0, 0] * cprev
        if d == 0.0:
            return False
        inv = 1.0 / d
        invD[i, 0, 0] = inv
        Pl[i, 0, 0] = inv * Jl[i, 0, 0] if i > 0 else 0.0 * inv
        cprev = -inv * Ju[i, 0, 0]
        Cu[i, 0, 0] = cprev
    return True


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def bt_solve(a, o1, bs, m, Pl, invD, Cu, b, x, gv):
    """x = M^-1 b for M = a I - blocks on the field nodes and a I on every other row. ``Pl`` =
    invD_i Jl_i (from the factorisation): the forward sweep g_i = invD_i b_i + Pl_i g_{i-1}
    carries one block product per node along its chain of dependent operations instead of two."""
    n = b.shape[0]
    ia = 1.0 / a
    for k in range(n):
        x[k] = b[k] * ia
    if bs == 1:
        gp = 0.0 * a
        for i in range(m):
            gp = invD[i, 0, 0] * b[3 + i] + Pl[i, 0, 0] * gp
            gv[i, 0] = gp
        xn = gv[m - 1, 0]
        x[3 + m - 1] = xn
        for i in range(m - 2, -1, -1):
            xn = gv[i, 0] - Cu[i, 0, 0] * xn
            x[3 + i] = xn
        return
    g0 = 0.0 * a
    g1 = g0
    for i in range(m):
        r0 = b[3 + i]
        r1 = b[o1 + i]
        n0 = invD[i, 0, 0] * r0 + invD[i, 0, 1] * r1 + (Pl[i, 0, 0] * g0 + Pl[i, 0, 1] * g1)
        n1 = invD[i, 1, 0] * r0 + invD[i, 1, 1] * r1 + (Pl[i, 1, 0] * g0 + Pl[i, 1, 1] * g1)
        g0 = n0
        g1 = n1
        gv[i, 0] = g0
        gv[i, 1] = g1
    x0 = gv[m - 1, 0]
    x1 = gv[m - 1, 1]
    x[3 + m - 1] = x0
    x[o1 + m - 1] = x1
    for i in range(m - 2, -1, -1):
        y0 = gv[i, 0] - (Cu[i, 0, 0] * x0 + Cu[i, 0, 1] * x1)
        y1 = gv[i, 1] - (Cu[i, 1, 0] * x0 + Cu[i, 1, 1] * x1)
        x0 = y0
        x1 = y1
        x[3 + i] = x0
        x[o1 + i] = x1


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def bt_solve_many(a, o1, bs, m, kk, Pl, invD, Cu, B, X, gm):
    """X[q] = M^-1 B[q] for q < kk in one sweep (the kk right-hand sides share each block's
    loads, and the innermost loop over them vectorises); ``gm`` (m, bs, >= kk) scratch."""
    n = B.shape[1]
    ia = 1.0 / a
    for q in range(kk):
        for k in range(n):
            X[q, k] = B[q, k] * ia
    if bs == 1:
        for i in range(m):
            d0 = invD[i, 0, 0]
            p0 = Pl[i, 0, 0]
            for q in range(kk):
                r0 = d0 * B[q, 3 + i]
                if i > 0:
                    r0 += p0 * gm[i - 1, 0, q]
                gm[i, 0, q] = r0
        for q in range(kk):
            X[q, 3 + m - 1] = gm[m - 1, 0, q]
        for i in range(m - 2, -1, -1):
            c0 = Cu[i, 0, 0]
            for q in range(kk):
                X[q, 3 + i] = gm[i, 0, q] - c0 * X[q, 4 + i]
        return
    for i in range(m):
        i00 = invD[i, 0, 0]
        i01 = invD[i, 0, 1]
        i10 = invD[i, 1, 0]
        i11 = invD[i, 1, 1]
        if i == 0:
            for q in range(kk):
                r0 = B[q, 3] + 0.0 * a
                r1 = B[q, o1] + 0.0 * a
                gm[0, 0, q] = i00 * r0 + i01 * r1
                gm[0, 1, q] = i10 * r0 + i11 * r1
        else:
            p00 = Pl[i, 0, 0]
            p01 = Pl[i, 0, 1]
            p10 = Pl[i, 1, 0]
            p11 = Pl[i, 1, 1]
            for q in range(kk):
                g0 = gm[i - 1, 0, q]
                g1 = gm[i - 1, 1, q]
                r0 = B[q, 3 + i]
                r1 = B[q, o1 + i]
                gm[i, 0, q] = i00 * r0 + i01 * r1 + (p00 * g0 + p01 * g1)
                gm[i, 1, q] = i10 * r0 + i11 * r1 + (p10 * g0 + p11 * g1)
    for q in range(kk):
        X[q, 3 + m - 1] = gm[m - 1, 0, q]
        X[q, o1 + m - 1] = gm[m - 1, 1, q]
    for i in range(m - 2, -1, -1):
        c00 = Cu[i, 0, 0]
        c01 = Cu[i, 0, 1]
        c10 = Cu[i, 1, 0]
        c11 = Cu[i, 1, 1]
        for q in range(kk):
            x0 = X[q, 4 + i]
            x1 = X[q, o1 + i + 1]
            X[q, 3 + i] = gm[i, 0, q] - (c00 * x0 + c01 * x1)
            X[q, o1 + i] = gm[i, 1, q] - (c10 * x0 + c11 * x1)


@njit(cache=True, error_model="numpy")
def woodbury_factor(a, kk, vidx, vval, vcnt, Z, K, piv):
    """LU of K = I - V^T Z (Woodbury capacitance matrix) for Z = M^-1 U."""
    Kv = K[:kk, :kk]
    for r in range(kk):
        for q in range(kk):
            s = (1.0 if r == q else 0.0) + 0.0 * a
            for e in range(vcnt[r]):
                s -= vval[r, e] * Z[q, vidx[r, e]]
            Kv[r, q] = s
    return lu_small(Kv, piv[:kk])


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def woodbury_correct(kk, Z, K, piv, vidx, vval, vcnt, x, sv):
    """x += Z (K^-1 V^T x): the low-rank correction of a block solve (see radau_factor_pair)."""
    for r in range(kk):
        s = 0.0 * sv[0]
        for e in range(vcnt[r]):
            s += vval[r, e] * x[vidx[r, e]]
        sv[r] = s
    lu_solve_small(K[:kk, :kk], piv[:kk], sv[:kk])
    for q in range(kk):
        s = sv[q]
        Zq = Z[q]
        for j in range(x.shape[0]):
            x[j] += Zq[j] * s


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def radau_solve(a, o1, bs, m, kk, Pl, invD, Cu, Z, K, piv, vidx, vval, vcnt, b, x, gv, sv):
    """x = (a I - J)^-1 b from the factorisation of radau_factor_pair."""
    bt_solve(a, o1, bs, m, Pl, invD, Cu, b, x, gv)
    if kk > 0:
        woodbury_correct(kk, Z, K, piv, vidx, vval, vcnt, x, sv)


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def bt_factor_pair(ar, ac, m, Jl, Jd, Ju, invD_r, Cu_r, Pl_r, invD_c, Cu_c, Pl_c):
    """Block-Thomas pivots of M = a I - blocks (2x2 blocks) for the real (ar) and the complex (ac)
    system in one loop, for the same reason as bt_solve_pair: invD_i = (a I - Jd_i +
    Jl_i C_{i-1})^-1, C_i = -invD_i Ju_i and the forward multipliers Pl_i = invD_i Jl_i (Pl_0 = 0;
    off the chain of dependent operations, so they come almost free). The complex pivot's
    reciprocal is formed in real arithmetic (one real division). False if a pivot is singular."""
    c00 = 0.0
    c01 = 0.0
    c10 = 0.0
    c11 = 0.0
    e00 = 0.0j
    e01 = 0.0j
    e10 = 0.0j
    e11 = 0.0j
    for i in range(m):
        j00 = Jd[i, 0, 0]
        j01 = Jd[i, 0, 1]
        j10 = Jd[i, 1, 0]
        j11 = Jd[i, 1, 1]
        m00 = ar - j00
        m01 = -j01
        m10 = -j10
        m11 = ar - j11
        n00 = ac - j00
        n01 = -j01 + 0.0j
        n10 = -j10 + 0.0j
        n11 = ac - j11
        if i > 0:
            l00 = Jl[i, 0, 0]
            l01 = Jl[i, 0, 1]
            l10 = Jl[i, 1, 0]
            l11 = Jl[i, 1, 1]
            m00 += l00 * c00 + l01 * c10
            m01 += l00 * c01 + l01 * c11
            m10 += l10 * c00 + l11 * c10
            m11 += l10 * c01 + l11 * c11
            n00 += l00 * e00 + l01 * e10
            n01 += l00 * e01 + l01 * e11
            n10 += l10 * e00 + l11 * e10
            n11 += l10 * e01 + l11 * e11
        det = m00 * m11 - m01 * m10
        dec = n00 * n11 - n01 * n10
        dr = dec.real
        di = dec.imag
        dd = dr * dr + di * di
        if det == 0.0 or dd == 0.0:
            return False
        inv = 1.0 / det
        ri = 1.0 / dd
        inc = complex(dr * ri, -di * ri)
        i00 = m11 * inv
        i01 = -m01 * inv
        i10 = -m10 * inv
        i11 = m00 * inv
        k00 = n11 * inc
        k01 = -n01 * inc
        k10 = -n10 * inc
        k11 = n00 * inc
        invD_r[i, 0, 0] = i00
        invD_r[i, 0, 1] = i01
        invD_r[i, 1, 0] = i10
        invD_r[i, 1, 1] = i11
        invD_c[i, 0, 0] = k00
        invD_c[i, 0, 1] = k01
        invD_c[i, 1, 0] = k10
        invD_c[i, 1, 1] = k11
        if i > 0:
            Pl_r[i, 0, 0] = i00 * l00 + i01 * l10
            Pl_r[i, 0, 1] = i00 * l01 + i01 * l11
            Pl_r[i, 1, 0] = i10 * l00 + i11 * l10
            Pl_r[i, 1, 1] = i10 * l01 + i11 * l11
            Pl_c[i, 0, 0] = k00 * l00 + k01 * l10
            Pl_c[i, 0, 1] = k00 * l01 + k01 * l11
            Pl_c[i, 1, 0] = k10 * l00 + k11 * l10
            Pl_c[i, 1, 1] = k10 * l01 + k11 * l11
        else:
            Pl_r[0, 0, 0] = 0.0
            Pl_r[0, 0, 1] = 0.0
            Pl_r[0, 1, 0] = 0.0
            Pl_r[0, 1, 1] = 0.0
            Pl_c[0, 0, 0] = 0.0
            Pl_c[0, 0, 1] = 0.0
            Pl_c[0, 1, 0] = 0.0
            Pl_c[0, 1, 1] = 0.0
        u00 = Ju[i, 0, 0]
        u01 = Ju[i, 0, 1]
        u10 = Ju[i, 1, 0]
        u11 = Ju[i, 1, 1]
        c00 = -(i00 * u00 + i01 * u10)
        c01 = -(i00 * u01 + i01 * u11)
        c10 = -(i10 * u00 + i11 * u10)
        c11 = -(i10 * u01 + i11 * u11)
        e00 = -(k00 * u00 + k01 * u10)
        e01 = -(k00 * u01 + k01 * u11)
        e10 = -(k10 * u00 + k11 * u10)
        e11 = -(k10 * u01 + k11 * u11)
        Cu_r[i, 0, 0] = c00
        Cu_r[i, 0, 1] = c01
        Cu_r[i, 1, 0] = c10
        Cu_r[i, 1, 1] = c11
        Cu_c[i, 0, 0] = e00
        Cu_c[i, 0, 1] = e01
        Cu_c[i, 1, 0] = e10
        Cu_c[i, 1, 1] = e11
    return True


@njit(cache=True, error_model="numpy")
def radau_factor_pair(ar, ac, o1, bs, m, kk, Jl, Jd, Ju, U, vidx, vval, vcnt, invD_r, Cu_r, Pl_r, Z_r, K_r,
                       piv_r, invD_c, Cu_c, Pl_c, Z_c, K_c, piv_c, gm_r, gm_c):
    """Factor (a I - J) for the real (ar) and the complex (ac) system of a Radau step: block-Thomas
    pivots and forward multipliers, Z = M^-1 U and the LU of K = I - V^T Z (Woodbury)."""
    if bs == 2:
        if not bt_factor_pair(ar, ac, m, Jl, Jd, Ju, invD_r, Cu_r, Pl_r, invD_c, Cu_c, Pl_c):
            return False
    else:
        if not (bt_factor_scalar(ar, m, Jl, Jd, Ju, invD_r, Cu_r, Pl_r)
                and bt_factor_scalar(ac, m, Jl, Jd, Ju, invD_c, Cu_c, Pl_c)):
            return False
    bt_solve_many(ar, o1, bs, m, kk, Pl_r, invD_r, Cu_r, U, Z_r, gm_r)
    bt_solve_many(ac, o1, bs, m, kk, Pl_c, invD_c, Cu_c, U, Z_c, gm_c)
    return woodbury_factor(ar, kk, vidx, vval, vcnt, Z_r, K_r, piv_r) and \
        woodbury_factor(ac, kk, vidx, vval, vcnt, Z_c, K_c, piv_c)


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def bt_solve_pair(ar, ac, o1, m, Pl_r, invD_r, Cu_r, Pl_c, invD_c, Cu_c, br, bc, xr, xc, gv_r, gv_c):
    """bt_solve of the real (ar) and the complex (ac) system together (2x2 blocks): each sweep
    is a chain of dependent operations, and running the two independent chains in one loop lets
    the processor overlap them."""
    n = br.shape[0]
    iar = 1.0 / ar
    iac = 1.0 / ac
    for k in range(n):
        xr[k] = br[k] * iar
        xc[k] = bc[k] * iac
    p0 = 0.0
    p1 = 0.0
    q0 = 0.0j
    q1 = 0.0j
    for i in range(m):
        r0 = br[3 + i]
        r1 = br[o1 + i]
        s0 = bc[3 + i]
        s1 = bc[o1 + i]
        n0 = invD_r[i, 0, 0] * r0 + invD_r[i, 0, 1] * r1 + (Pl_r[i, 0, 0] * p0 + Pl_r[i, 0, 1] * p1)
        n1 = invD_r[i, 1, 0] * r0 + invD_r[i, 1, 1] * r1 + (Pl_r[i, 1, 0] * p0 + Pl_r[i, 1, 1] * p1)
        u0 = invD_c[i, 0, 0] * s0 + invD_c[i, 0, 1] * s1 + (Pl_c[i, 0, 0] * q0 + Pl_c[i, 0, 1] * q1)
        u1 = invD_c[i, 1, 0] * s0 + invD_c[i, 1, 1] * s1 + (Pl_c[i, 1, 0] * q0 + Pl_c[i, 1, 1] * q1)
        p0 = n0
        p1 = n1
        q0 = u0
        q1 = u1
        gv_r[i, 0] = p0
        gv_r[i, 1] = p1
        gv_c[i, 0] = q0
        gv_c[i, 1] = q1
    xr[3 + m - 1] = p0
    xr[o1 + m - 1] = p1
    xc[3 + m - 1] = q0
    xc[o1 + m - 1] = q1
    for i in range(m - 2, -1, -1):
        y0 = gv_r[i, 0] - (Cu_r[i, 0, 0] * p0 + Cu_r[i, 0, 1] * p1)
        y1 = gv_r[i, 1] - (Cu_r[i, 1, 0] * p0 + Cu_r[i, 1, 1] * p1)
        z0 = gv_c[i, 0] - (Cu_c[i, 0, 0] * q0 + Cu_c[i, 0, 1] * q1)
        z1 = gv_c[i, 1] - (Cu_c[i, 1, 0] * q0 + Cu_c[i, 1, 1] * q1)
        p0 = y0
        p1 = y1
        q0 = z0
        q1 = z1
        xr[3 + i] = p0
        xr[o1 + i] = p1
        xc[3 + i] = q0
        xc[o1 + i] = q1


@njit(cache=True, error_model="numpy", fastmath=FASTMATH)
def radau_solve_pair(ar, ac, o1, bs, m, kk, Pl_r, invD_r, Cu_r, Z_r, K_r, piv_r, Pl_c, invD_c, Cu_c, Z_c, K_c,
                      piv_c, vidx, vval, vcnt, br, bc, xr, xc, gv_r, gv_c, sv_r, sv_c):
    """xr = (ar I - J)^-1 br and xc = (ac I - J)^-1 bc, the two solves of a Newton iteration."""
    if bs == 2:
        bt_solve_pair(ar, ac, o1, m, Pl_r, invD_r, Cu_r, Pl_c, invD_c, Cu_c, br, bc, xr, xc, gv_r, gv_c)
    else:
        bt_solve(ar, o1, bs, m, Pl_r, invD_r, Cu_r, br, xr, gv_r)
        bt_solve(ac, o1, bs, m, Pl_c, invD_c, Cu_c, bc, xc, gv_c)
    if kk > 0:
        woodbury_correct(kk, Z_r, K_r, piv_r, vidx, vval, vcnt, xr, sv_r)
        woodbury_correct(kk, Z_c, K_c, piv_c, vidx, vval, vcnt, xc, sv_c)


@njit(cache=True, error_model="numpy")
def rms_norm(v, scale):
    """Root mean square of v / scale (both (n,))."""
    s = 0.0
    for k in range(v.shape[0]):
        e = v[k] / scale[k]
        s += e * e
    return math.sqrt(s / v.shape[0])
