"""Is the preprocessing's time of the maximum the cause of the alignment conflict? (docs/diagnosis.md,
"The alignment conflict").

For every record of a dataset, the vertex of `locate_rmax`'s local fit against the vertex of a parabola
and of a cubic fitted by ``numpy.polyfit`` over 0.2, 0.35 and 0.5 t_c around it, beside the shift of the
time of the maximum that a stored En4D-Var fit made (``per_experiment[].nuisance.t0_s``):

    python validation/alignment_local_fit_check.py ../shared/data/lic/estrada2018_stiffPA_270kfps \
        docs/results/estrada2018_stiffPA/s68_en4dvar.summary.json

Prints one line per record: the local fit's sd and, per (half-width, degree), the vertex offset [ns].
"""
import glob
import json
import sys
import warnings

import numpy as np

from imrbayes.data.preprocess import estimate_noise_sd, locate_rmax


def main(data: str, summary: str, rho: float = 1064.0, p8: float = 101325.0) -> None:
    fits = json.load(open(summary))["per_experiment"]
    u_c = np.sqrt(p8 / rho)
    for n, f in enumerate(sorted(glob.glob(f"{data}/exp*.csv"))):
        t, R = np.loadtxt(f, delimiter=",", skiprows=1, unpack=True)
        r = locate_rmax(t, R, "local-fit", u_c=u_c, noise_sd_m=estimate_noise_sd(R))
        tc = R.max() / u_c
        cols = []
        for hw in (0.2, 0.35, 0.5):
            sel = np.abs(t - r.t_s) <= hw * tc
            for deg in (2, 3):
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", np.exceptions.RankWarning)
                    c = np.polyfit(t[sel] - r.t_s, R[sel], deg)
                roots = np.roots(np.polyder(c))
                roots = roots[np.isreal(roots)].real
                cols.append(f"{hw:.2f}/{deg}: {1e9 * roots[np.argmin(np.abs(roots))]:+.0f}")
        q = fits[n]["nuisance"]["t0_s"]
        print(f"{f.rsplit('/', 1)[-1]}  local fit sd {1e9 * r.t_sd_s:.0f} ns  " + "  ".join(cols)
              + f"  fit's shift {1e9 * (q['mean'] - q['prior_mean']):+.0f} ns")


if __name__ == "__main__":
    main(*sys.argv[1:3])
