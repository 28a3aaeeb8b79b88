"""Runge-Kutta tableaux used by the forward kernel (facts from the cited papers).

Each tableau is a dict of float64 arrays: ``AE`` (explicit), ``AI`` (diagonally implicit, zero for a
purely explicit method), ``b``, ``bhat`` (embedded), ``c``, and ``order`` (of the embedded pair's
lower member + 1, for the step-size exponent). Order conditions are checked in the tests.
"""

from fractions import Fraction as Fr

import numpy as np


def _arr(rows, s):
    a = np.zeros((s, s))
    for i, row in enumerate(rows):
        for j, v in row.items():
            a[i, j] = float(v)
    return a


def ark324():
    """ARK3(2)4L[2]SA, Kennedy & Carpenter (2003)."""
    g = Fr(1767732205903, 4055673282236)
    AE = _arr([{}, {0: Fr(1767732205903, 2027836641118)},
               {0: Fr(5535828885825, 10492691773637), 1: Fr(788022342437, 10882634858940)},
               {0: Fr(6485989280629, 16251701735622), 1: Fr(-4246266847089, 9704473918619),
                2: Fr(10755448449292, 10357097424841)}], 4)
    b = [Fr(1471266399579, 7840856788654), Fr(-4482444167858, 7529755066697),
         Fr(11266239266428, 11593286722821), g]
    AI = _arr([{}, {0: g, 1: g},
               {0: Fr(2746238789719, 10658868560708), 1: Fr(-640167445237, 6845629431997), 2: g},
               {0: b[0], 1: b[1], 2: b[2], 3: g}], 4)
    bhat = [Fr(2756255671327, 12835298489170), Fr(-10771552573575, 22201958757719),
            Fr(9247589265047, 10645013368117), Fr(2193209047091, 5459859503100)]
    c = [0, 2 * g, Fr(3, 5), 1]
    return dict(AE=AE, AI=AI, b=np.array(b, float), bhat=np.array(bhat, float), c=np.array(c, float),
                gamma=float(g), order=3)


def ark548():
    """ARK5(4)8L[2]SA, Kennedy & Carpenter (2003)."""
    g = Fr(41, 200)
    b = {0: Fr(-872700587467, 9133579230613), 3: Fr(22348218063261, 9555858737531),
         4: Fr(-1143369518992, 8141816002931), 5: Fr(-39379526789629, 19018526304540),
         6: Fr(32727382324388, 42900044865799), 7: g}
    AE = _arr([{}, {0: Fr(41, 100)},
               {0: Fr(367902744464, 2072280473677), 1: Fr(677623207551, 8224143866563)},
               {0: Fr(1268023523408, 10340822734521), 2: Fr(1029933939417, 13636558850479)},
               {0: Fr(14463281900351, 6315353703477), 2: Fr(66114435211212, 5879490589093),
                3: Fr(-54053170152839, 4284798021562)},
               {0: Fr(14090043504691, 34967701212078), 2: Fr(15191511035443, 11219624916014),
                3: Fr(-18461159152457, 12425892160975), 4: Fr(-281667163811, 9011619295870)},
               {0: Fr(19230459214898, 13134317526959), 2: Fr(21275331358303, 2942455364971),
                3: Fr(-38145345988419, 4862620318723), 4: Fr(-1, 8), 5: Fr(-1, 8)},
               {0: Fr(-19977161125411, 11928030595625), 2: Fr(-40795976796054, 6384907823539),
                3: Fr(177454434618887, 12078138498510), 4: Fr(782672205425, 8267701900261),
                5: Fr(-69563011059811, 9646580694205), 6: Fr(7356628210526, 4942186776405)}], 8)
    AI = _arr([{}, {0: g, 1: g},
               {0: Fr(41, 400), 1: Fr(-567603406766, 11931857230679), 2: g},
               {0: Fr(683785636431, 9252920307686), 2: Fr(-110385047103, 1367015193373), 3: g},
               {0: Fr(3016520224154, 10081342136671), 2: Fr(30586259806659, 12414158314087),
                3: Fr(-22760509404356, 11113319521817), 4: g},
               {0: Fr(218866479029, 1489978393911), 2: Fr(638256894668, 5436446318841),
                3: Fr(-1179710474555, 5321154724896), 4: Fr(-60928119172, 8023461067671), 5: g},
               {0: Fr(1020004230633, 5715676835656), 2: Fr(25762820946817, 25263940353407),
                3: Fr(-2161375909145, 9755907335909), 4: Fr(-211217309593, 5846859502534),
                5: Fr(-4269925059573, 7827059040749), 6: g},
               {**b}], 8)
    bv = np.array([float(b.get(i, 0)) for i in range(8)])
    bh = {0: Fr(-975461918565, 9796059967033), 3: Fr(78070527104295, 32432590147079),
          4: Fr(-548382580838, 3424219808633), 5: Fr(-33438840321285, 15594753105479),
          6: Fr(3629800801594, 4656183773603), 7: Fr(4035322873751, 18575991585200)}
    bhv = np.array([float(bh.get(i, 0)) for i in range(8)])
    c = [0, Fr(41, 100), Fr(2935347310677, 11292855782101), Fr(1426016391358, 7196633302097),
         Fr(92, 100), Fr(24, 100), Fr(3, 5), 1]
    return dict(AE=AE, AI=AI, b=bv, bhat=bhv, c=np.array(c, float), gamma=float(g), order=5)


def dopri5():
    """Dormand-Prince 5(4), explicit (AI = 0): for the polytropic bubble, which is not stiff."""
    AE = _arr([{}, {0: Fr(1, 5)}, {0: Fr(3, 40), 1: Fr(9, 40)},
               {0: Fr(44, 45), 1: Fr(-56, 15), 2: Fr(32, 9)},
               {0: Fr(19372, 6561), 1: Fr(-25360, 2187), 2: Fr(64448, 6561), 3: Fr(-212, 729)},
               {0: Fr(9017, 3168), 1: Fr(-355, 33), 2: Fr(46732, 5247), 3: Fr(49, 176), 4: Fr(-5103, 18656)},
               {0: Fr(35, 384), 2: Fr(500, 1113), 3: Fr(125, 192), 4: Fr(-2187, 6784), 5: Fr(11, 84)}], 7)
    b = np.array([35 / 384, 0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84, 0])
    bhat = np.array([5179 / 57600, 0, 7571 / 16695, 393 / 640, -92097 / 339200, 187 / 2100, 1 / 40])
    c = np.array([0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1, 1])
    return dict(AE=AE, AI=np.zeros((7, 7)), b=b, bhat=bhat, c=c, gamma=0.0, order=5)


def dop853():
    """Dormand-Prince 8(5,3), explicit, with scipy's coefficients (Hairer's DOP853), written as a
    13-stage first-same-as-last pair: stage 13 is f(y_new) (row A[12] = b), and b - bhat is the
    5th-order error estimate E5 (Hairer's combined 5/3 estimate is not used)."""
    from scipy.integrate._ivp import dop853_coefficients as d

    ns = d.N_STAGES + 1
    AE = np.zeros((ns, ns))
    AE[:d.N_STAGES, :d.N_STAGES] = d.A[:d.N_STAGES, :d.N_STAGES]
    b = np.zeros(ns)
    b[:d.N_STAGES] = d.B
    AE[d.N_STAGES, :] = b
    c = np.zeros(ns)
    c[:d.N_STAGES] = d.C[:d.N_STAGES]
    c[d.N_STAGES] = 1.0
    bhat = b - d.E5
    return dict(AE=AE, AI=np.zeros((ns, ns)), b=b, bhat=bhat, c=c, gamma=0.0, order=8)


TABLEAUX = {"ark324": ark324, "ark548": ark548, "dopri5": dopri5, "dop853": dop853}
