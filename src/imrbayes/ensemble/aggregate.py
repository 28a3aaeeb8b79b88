"""The covariance of MIEnKS-MDA's aggregate estimate, propagated through the window chain.

Each window j's gel-level mean is linear in the previous window's and in the experiments' window
likelihoods (:func:`imrbayes.ensemble.hierarchical.random_effects` with the chained prior):

    mu_j = F_j mu_{j-1} + sum_g D_jg eta_jg,   F_j = C_j P_j,   D_jg = C_j (I + Lambda_jg T_j)^-1

(C_j the window's gel-level covariance, P_j the precision of the prior it was chained from, T_j
its between-bubble covariance, Lambda_jg and eta_jg experiment g's likelihood precision and
information; mu_{-1} = m0, the parameter prior's mean). The aggregate is a fixed linear
combination of the window means, mu_agg = sum_j Q_j mu_j (normalised precision weighting:
Q_j = C_agg w_j C_j^-1). With the parameters constant over the record and each sample counted
once, the pieces are independent:

    m0 ~ N(z, S0),   eta_jg = Lambda_jg (z + u_g) + e_jg,   e_jg ~ N(0, Lambda_jg),   u_g ~ N(0, T)

(u_g experiment g's own deviation from the gel, the same in every window; T the record-level
between-bubble covariance). So

    Var(mu_agg) = B0 S0 B0^T + sum_jg R_j D_jg Lambda_jg D_jg^T R_j^T + sum_g V_g T V_g^T

with R_j = Q_j + R_{j+1} F_{j+1} (mu_j's weight in the aggregate, its later windows included),
B0 = R_0 F_0 and V_g = sum_j R_j D_jg Lambda_jg. Without inflation and scatter this is the last
window's posterior covariance when Q picks the last window, and never more than what the
normalised precision weighting states (that bound treats the windows as one). Why: RTPS makes
every window forget most of the windows before it, so the weighting's covariance is about one
window's, several times the aggregate's own scatter on constant-parameter data; the aggregate's
mean is a fixed linear function of data whose information the windows already state, so its
variance follows from them.
"""

from __future__ import annotations

import numpy as np

from imrbayes.ensemble.gaussian import sym


def chain_aggregate_cov(F, D, Lam, Q, S0, T=None) -> np.ndarray:
    """Var(mu_agg) (d, d) of the module doc.

    F (J, d, d): each window mean's weight on the previous one (window 0: on the prior mean);
    D: per window a dict {experiment: (d, d)} of the weights on that experiment's information;
    Lam: the same layout, the likelihood precisions; Q (J, d, d): the aggregate's weights on the
    window means; S0 (d, d): the parameter prior's covariance; T (d, d): the between-bubble
    covariance (None: no scatter). Internal coordinates throughout.
    """
    F, Q = np.asarray(F, dtype=np.float64), np.asarray(Q, dtype=np.float64)
    J, d = Q.shape[0], Q.shape[1]
    R = np.empty_like(Q)
    R[J - 1] = Q[J - 1]
    for j in range(J - 2, -1, -1):
        R[j] = Q[j] + R[j + 1] @ F[j + 1]
    B0 = R[0] @ F[0]
    var = B0 @ np.asarray(S0, dtype=np.float64) @ B0.T
    V = {}
    for j in range(J):
        for g, Dg in D[j].items():
            RD = R[j] @ Dg
            var += RD @ Lam[j][g] @ RD.T
            V[g] = V.get(g, np.zeros((d, d))) + RD @ Lam[j][g]
    if T is not None:
        for Vg in V.values():
            var += Vg @ T @ Vg.T
    return sym(var)
