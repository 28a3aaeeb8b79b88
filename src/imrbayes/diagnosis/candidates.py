"""The diagnosis candidates: one declaration per candidate mechanism, one registry.

A candidate is either a constitutive model that nests the baseline NHKV (G, mu) with a few extra
fitted parameters (its *extension*; ``kind="material"``) or the baseline material on another bubble
model (``kind="bubble"``: the bubble physics, not the gel, is what the data contradict), the
mechanism it stands for, the rule that says whether a fitted
extension points the way of that mechanism, and how synthetic data with the mechanism hidden are
drawn. Everything else in :mod:`imrbayes.diagnosis` (the fits, the ranking, the synthetic data,
figure and report labels, the command line's ``--candidates``) reads :data:`CANDIDATES`.

Adding one: write a :class:`CandidateSpec` below and add it to :data:`CANDIDATES` (docs/methods.md).

This module is light (numpy only): the command line imports it to list the candidates.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Extension",
    "Range",
    "CandidateSpec",
    "BASELINE",
    "CANDIDATES",
    "DEFAULT_CANDIDATES",
    "MECHANISMS",
    "spec_of",
]


@dataclass(frozen=True)
class Extension:
    """A fitted parameter beyond (G, mu), with its Gaussian prior N(mean, sd) in the internal
    coordinate: log of the SI value when ``log`` (so mean = log of the prior median), else the SI
    value itself."""

    name: str
    mean: float
    sd: float
    log: bool = False


@dataclass(frozen=True)
class Range:
    """True values in synthetic data: uniform on [low, high] (SI), log-uniform when ``log``."""

    low: float
    high: float
    log: bool = False

    def draw(self, rng) -> float:
        if self.log:
            return float(np.exp(rng.uniform(np.log(self.low), np.log(self.high))))
        return float(rng.uniform(self.low, self.high))


@dataclass(frozen=True)
class CandidateSpec:
    """One diagnosis candidate.

    key : its name in ``--candidates``, results and unit ids.
    mechanism : what it stands for; the diagnosis ``cause`` when it wins.
    forward_model : constitutive model of :mod:`imrbayes.forward` it runs on.
    extension : fitted parameters after (G, mu), in order (:class:`Extension`).
    fixed : forward parameters held at a value (SI), e.g. Zener's lambda2 = 0.
    pieces : None for constant parameters; else ``pieces(values, n_pieces)`` maps the fitted SI
        values (name -> (M,)) to forward parameters per piece (name -> (M, n_pieces)); piece j
        follows the j-th measured collapse of the experiment, whose times become the forward
        model's breaks.
    points_right_way : rule on the fitted SI medians (name -> float): True when the extension
        points the way of the mechanism (None: always); ``wrong_way`` says why when it does not.
        A candidate failing it is ranked after the others and never named the cause.
    interval_right_way : rule on the lower and upper ends of the fitted 95 % intervals (two dicts
        name -> float): False when the data exclude the mechanism's direction for some parameter
        (None: no such rule); ``interval_wrong_way`` says why. Checked where an interval is known.
    synthetic : the true values of the extension in synthetic data with this mechanism hidden
        (:class:`Range` per extension name, drawn in this order; sizes of the effect seen in real
        gels). None: no generator (the mechanism is simulated by another candidate).
    default : in the default candidate set of ``diagnose``.
    label : the model's name in results, figures and reports (default: ``key``).
    kind : ``material`` (the gel) or ``bubble`` (the bubble model).
    forward_options : None, or ``forward_options(options)`` -> the ForwardOptions fields to change
        from the baseline's ``options`` (dict), or None when the alternative does not apply to them
        (e.g. the warm medium when the baseline already has it); the candidate then is left out.
    """

    key: str
    mechanism: str
    forward_model: str
    extension: tuple = ()
    fixed: Mapping = field(default_factory=dict)
    pieces: Callable | None = None
    points_right_way: Callable | None = None
    wrong_way: str = ""
    synthetic: Mapping | None = None
    default: bool = True
    label: str = ""
    kind: str = "material"
    forward_options: Callable | None = None
    interval_right_way: Callable | None = None
    interval_wrong_way: str = ""

    def options_for(self, options):
        """The ForwardOptions this candidate runs on given the baseline's, or None (not applicable)."""
        if self.forward_options is None:
            return options
        from dataclasses import replace

        change = self.forward_options(options)
        return None if change is None else replace(options, **change)

    @property
    def model(self) -> str:
        return self.label or self.key

    def consistent(self, medians: Mapping, estimate: Mapping | None = None) -> tuple:
        """(ok, note): does the fitted extension (SI medians, name -> float) point the right way, and
        (with ``estimate``, name -> {"hdi95": [lo, hi], ...}) does its 95 % interval allow it?"""
        ok = self.points_right_way is None or bool(self.points_right_way(medians))
        if not ok:
            return False, self.wrong_way
        if self.interval_right_way is not None and estimate is not None:
            names = [e.name for e in self.extension]
            if all(n in estimate and "hdi95" in estimate[n] for n in names):
                lo = {n: float(estimate[n]["hdi95"][0]) for n in names}
                hi = {n: float(estimate[n]["hdi95"][1]) for n in names}
                if not self.interval_right_way(lo, hi):
                    return False, self.interval_wrong_way
        return True, ""


def _retention(values, n_pieces):
    """Damage: piece j (after j collapses) has G a_G^j and mu a_mu^j -> nhkv's (G, mu) per piece."""
    j = np.arange(n_pieces)[None, :]
    return {
        "G": values["G"][:, None] * values["a_G"][:, None] ** j,
        "mu": values["mu"][:, None] * values["a_mu"][:, None] ** j,
    }


#: The constant-parameter model every candidate nests; synthetic data of mechanism ``none``.
BASELINE = CandidateSpec("nhkv", "none", "nhkv", synthetic={})

QKV = CandidateSpec(
    "qkv",
    "strain-stiffening",
    "qkv",
    extension=(Extension("alpha", 0.0, 0.5),),
    points_right_way=lambda m: m["alpha"] > 0.0,
    wrong_way="fitted alpha <= 0: strain softening, not stiffening",
    synthetic={"alpha": Range(0.2, 0.5)},
)

# Fung: the same mechanism as qkv with another stiffening law; qkv is the default and generates the data.
FUNG = CandidateSpec(
    "fung",
    "strain-stiffening",
    "fung",
    extension=(Extension("alpha", 0.0, 0.3),),
    points_right_way=lambda m: m["alpha"] > 0.0,
    wrong_way="fitted alpha <= 0: strain softening, not stiffening",
    default=False,
)

# lambda2 = 0: elastic and viscous stress relax together over lambda1; lambda1 -> 0 is NHKV (with
# the default zener_j=consistent; IMRv2's J counts the viscous term twice there). No
# direction rule: any lambda1 > 0 is relaxation.
ZENER = CandidateSpec(
    "zener",
    "viscoelastic-relaxation",
    "zener",
    extension=(Extension("lambda1", float(np.log(1e-6)), 1.5, log=True),),
    fixed={"lambda2": 0.0},
    synthetic={"lambda1": Range(2e-6, 8e-6, log=True)},
)

# mu_inf = 0; n = 1 or lambda_c -> 0 is NHKV. Shear thinning is n < 1.
CARREAU = CandidateSpec(
    "carreau",
    "rate-dependent-viscosity",
    "carreau",
    extension=(
        Extension("lambda_c", float(np.log(1e-6)), 2.0, log=True),
        Extension("n", float(np.log(0.7)), 0.6, log=True),
    ),
    fixed={"mu_inf": 0.0},
    points_right_way=lambda m: m["n"] < 1.0,
    wrong_way="fitted Carreau n >= 1: shear thickening, not the shear thinning of the mechanism",
    synthetic={"lambda_c": Range(5e-6, 3e-5, log=True), "n": Range(0.25, 0.5)},
)

# NHKV whose G and mu lose a fraction at every measured collapse (retention factors, median 1 = NHKV).
# Damage softens; it never stiffens. Either factor may stay at 1 (the viscous or the elastic network
# alone damaged), but one whose 95 % interval lies above 1 says that modulus grows from collapse to
# collapse: the piecewise fit is then standing in for a rate-dependent mechanism (on camera-style
# relaxation data, seeds 2002 and 2003, it fitted a_G 1.35 and 1.79 with a_mu 0.7-0.76 and was named
# the cause), not describing damage.
DAMAGE = CandidateSpec(
    "damage",
    "damage-softening",
    "nhkv",
    label="nhkv-piecewise",
    extension=(Extension("a_G", 0.0, 0.7, log=True), Extension("a_mu", 0.0, 0.7, log=True)),
    pieces=_retention,
    points_right_way=lambda m: m["a_G"] < 1.0 or m["a_mu"] < 1.0,
    wrong_way="fitted a_G, a_mu >= 1: stiffening across collapses, not damage",
    interval_right_way=lambda lo, hi: lo["a_G"] <= 1.0 and lo["a_mu"] <= 1.0,
    interval_wrong_way="a retention factor's 95 % interval lies above 1: that modulus stiffens from collapse to "
    "collapse, which damage cannot do",
    synthetic={"a_G": Range(0.25, 0.5), "a_mu": Range(0.6, 1.0)},
)


def _thermal_alternative(o):
    """The heat and mass exchange of the bubble's contents, changed: a polytropic bubble -> the
    thermal bubble (heat conduction in the gas, vapour); a thermal bubble -> the same with vapour
    mass transfer switched (on <-> off). The warm medium (the gel's temperature field) would be the
    natural alternative to a cold one, but our solver does not finish it on the default grid (too
    many steps at every tried grid; docs/methods.md), so it is not offered."""
    if o.bubble == "polytropic":  # the polytropic options drop mass transfer; the thermal bubble keeps it
        return {"bubble": "thermal", "integrator": None, "mass_transfer": bool(o.vapor)}
    if o.vapor:
        return {"mass_transfer": not o.mass_transfer}
    return None


def _compressible_alternative(o):
    """The other compressible radial equation: Keller-Miksis (pressure form) <-> Gilmore (enthalpy,
    Tait liquid: the liquid's compressibility at the high pressures of the collapse)."""
    return {"gilmore": {"radial": "km"}}.get(o.radial, {"radial": "gilmore"})


# Bubble-model alternatives: the baseline NHKV material (no extension) on other bubble physics.
BUBBLE_THERMAL = CandidateSpec(
    "bubble-thermal", "bubble-thermal", "nhkv", kind="bubble", forward_options=_thermal_alternative, synthetic={}
)
BUBBLE_COMPRESSIBILITY = CandidateSpec(
    "bubble-gilmore",
    "bubble-compressibility",
    "nhkv",
    kind="bubble",
    forward_options=_compressible_alternative,
    synthetic={},
)

#: key -> candidate: the registry every other module reads.
CANDIDATES = {c.key: c for c in (QKV, FUNG, ZENER, CARREAU, DAMAGE, BUBBLE_THERMAL, BUBBLE_COMPRESSIBILITY)}
#: The candidates ``diagnose`` fits unless told otherwise.
DEFAULT_CANDIDATES = tuple(k for k, c in CANDIDATES.items() if c.default)
#: Every possible ``cause`` (``ambiguous``: the data cannot tell the top candidates apart).
MECHANISMS = (BASELINE.mechanism, *dict.fromkeys(c.mechanism for c in CANDIDATES.values()), "unexplained", "ambiguous")


def spec_of(key: str) -> CandidateSpec:
    """The baseline (``nhkv``) or a registered candidate."""
    return BASELINE if key == BASELINE.key else CANDIDATES[key]
