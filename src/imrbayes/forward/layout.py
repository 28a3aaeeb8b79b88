"""Index constants shared by the Python side and the compiled kernel (plain ints)."""

from imrbayes.forward.constants import GROUP_NAMES

# Per-member group vector (constants.GROUP_NAMES order).
(G_INV_WE, G_CSTAR, G_TAIT_B, G_TAIT_N, G_KAPPA, G_CHI, G_FOM, G_FOH, G_BR, G_IOTA,
 G_ALPHA_G, G_BETA_G, G_ALPHA_V, G_BETA_V, G_RV, G_RG, G_LSTAR, G_REQ, G_PV, G_KV0,
 G_T8, G_P8, G_LT, G_PB0) = range(len(GROUP_NAMES))

# Integer option flags.
F_RADIAL, F_THERMAL, F_MEDIUM, F_VAPOR, F_MASS, F_PDOT, F_NT, F_MT, F_NAUX = range(9)
N_FLAGS = 9

# Rows of the bubble-grid coefficient array (shape (N_GRID_ROWS, nt)).
GR_Y, GR_D1L, GR_D1C, GR_D1U, GR_D2L, GR_D2C, GR_D2U, GR_WALL = range(8)
N_GRID_ROWS = 8

# Member status codes.
OK, FAIL_NONFINITE, FAIL_RADIUS, FAIL_STEP, FAIL_MAXSTEPS = range(5)
STATUS_TEXT = {OK: "ok", FAIL_NONFINITE: "non-finite state", FAIL_RADIUS: "radius <= 0",
               FAIL_STEP: "step size collapsed", FAIL_MAXSTEPS: "too many steps"}
