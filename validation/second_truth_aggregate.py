"""MIEnKS-MDA's aggregate on the second truth (G 2 kPa, mu 0.05 Pa s, Rmax/Req 9; the validation
suite's ``second-truth`` case, polytropic bubble, default likelihood), seeds 0-4: the relative
error, the relative sd and whether the 95 % interval holds the truth, with the reported covariance
(``aggregate_cov=chain``) and with the normalised precision weighting's (kept as
``details.alternative_estimates.aggregate_precision_weighted``). About 10 s per seed.

Usage: python validation/second_truth_aggregate.py [--seeds 5]
"""

import argparse

from imrbayes.ensemble import MIEnKSSettings, ParamSpace, fit_mienks
from imrbayes.forward import ForwardModel
from imrbayes.validation.suite import RATIO_2, TRUTH_2, verification_data


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    args = ap.parse_args(argv)
    fm = ForwardModel("nhkv", options={"bubble": "polytropic"})
    space = ParamSpace.for_model(fm.constitutive)
    for seed in range(args.seeds):
        obs = verification_data(fm, seed, truth=TRUTH_2, ratio=RATIO_2)
        mi = fit_mienks(fm, obs, space, MIEnKSSettings(n_draws=1, aggregate_cov="chain"), seed=seed)
        w = mi.details["alternative_estimates"]["aggregate_precision_weighted"]
        line = f"seed {seed}:"
        for n, true in TRUTH_2.items():
            e = mi.estimate[n]
            line += (f"  {n} {e['mean'] / true - 1:+.3f} sd {e['sd'] / e['mean']:.3f} "
                     f"holds {e['hdi95'][0] <= true <= e['hdi95'][1]}"
                     f" (weighting sd {w[n]['sd'] / w[n]['mean']:.3f} holds {w[n]['hdi95'][0] <= true <= w[n]['hdi95'][1]})")
        print(line, flush=True)


if __name__ == "__main__":
    main()
