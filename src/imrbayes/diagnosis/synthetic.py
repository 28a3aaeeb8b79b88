"""Synthetic datasets with a hidden mechanism (tests, ``scripts/diagnosis_confusion.py``).

Two generators: :func:`synthetic_obs` (R* on the analysis grid, noise added there, true Rmax and Req
known; the older tests) and :func:`camera_obs` (camera frames processed exactly as measured data, by
a finer forward model than the fitted one, with :data:`DESIGNS` and the bubble classes; see there).
The rest of this docstring is about :func:`synthetic_obs`.

Parameters are drawn (seeded) from realistic ranges: G 3-12 kPa, mu 0.04-0.15 Pa s (log-uniform),
Rmax ~ N(300, 30) µm, Rmax/Req ~ N(7.5, 0.4) (methods.md §6), and the mechanism's own parameters
from its candidate's ``synthetic`` ranges (:mod:`imrbayes.diagnosis.candidates`), where the effect
is of the size seen in real gels. Noise: the paper's verification noise (methods.md §5) times
``noise_scale``, independent per sample; P_k is the across-experiment sample variance, as for
measured data.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from imrbayes.data.noise import noise_variance, paper_sigma
from imrbayes.diagnosis.candidates import BASELINE, CANDIDATES, Range
from imrbayes.diagnosis.lsq import predict
from imrbayes.diagnosis.models import make_candidate
from imrbayes.diagnosis.phases import phases_of
from imrbayes.ensemble import Observations

__all__ = [
    "GENERATORS",
    "BASELINE_TRUTH",
    "synthetic_obs",
    "Design",
    "DESIGNS",
    "STRENGTH_DESIGNS",
    "design_of",
    "BUBBLE_GENERATORS",
    "camera_mechanisms",
    "camera_obs",
    "fine_options",
    "data_options",
    "clean_curves",
    "bubble_effect",
]

#: True (G, mu) of every synthetic dataset [Pa, Pa s]; the mechanism's own come from its candidate.
BASELINE_TRUTH = {"G": Range(3e3, 12e3, log=True), "mu": Range(0.04, 0.15, log=True)}


def _generators() -> dict:
    out = {BASELINE.mechanism: BASELINE.key}
    for c in CANDIDATES.values():
        if c.synthetic is not None:
            out.setdefault(c.mechanism, c.key)
    return out


#: mechanism -> key of the candidate that simulates it (the first registered one with ``synthetic``),
#: in registry order (``scripts/diagnosis_confusion.py`` derives its seeds from this order).
GENERATORS = _generators()


def synthetic_obs(
    mechanism: str,
    seed: int,
    options,
    n_exp: int = 5,
    noise_scale: float = 1.0,
    n_steps: int = 120,
    dt_star: float = 0.025,
):
    """(Observations, truth dict) of ``n_exp`` noisy experiments with the hidden ``mechanism``."""
    rng = np.random.default_rng(seed)
    key = GENERATORS[mechanism]
    cand = make_candidate(key, options)
    theta = {n: r.draw(rng) for n, r in {**BASELINE_TRUTH, **cand.spec.synthetic}.items()}
    rmax = np.clip(rng.normal(300e-6, 30e-6, n_exp), 220e-6, 400e-6)
    ratio = np.clip(rng.normal(7.5, 0.4, n_exp), 6.5, 8.5)
    req = rmax / ratio
    t = np.arange(n_steps + 1) * dt_star
    z = cand.to_internal([theta[n] for n in cand.names])
    blank = Observations(t, np.ones((n_exp, t.size)), np.ones(t.size), rmax, req)
    minima = None
    if cand.piecewise:  # breaks at the collapses of the baseline bubble's curve, then refined once
        base = make_candidate(BASELINE.key, options)
        R0 = predict(base, z[None, :2], blank, np.arange(n_exp), None, n_steps)[0]
        minima = phases_of(Observations(t, np.maximum(R0, 1e-3), np.ones(t.size), rmax, req)).minima
        R1 = predict(cand, z[None], blank, np.arange(n_exp), minima, n_steps)[0]
        minima = phases_of(Observations(t, np.maximum(R1, 1e-3), np.ones(t.size), rmax, req)).minima
    R = predict(cand, z[None], blank, np.arange(n_exp), minima, n_steps)[0]
    if not np.all(np.isfinite(R)):
        raise RuntimeError(f"forward solve failed for the synthetic truth {theta}")
    Y = R + noise_scale * paper_sigma(t, R) * rng.standard_normal(R.shape)
    Y[:, 0] = 1.0
    Y = np.maximum(Y, 1e-3)
    P, _ = noise_variance(t, Y)
    obs = Observations(t, Y, P, rmax, req, names=[f"exp_{i + 1:03d}" for i in range(n_exp)])
    return obs, {
        "mechanism": mechanism,
        "model": key,
        "theta": theta,
        "rmax_m": rmax.tolist(),
        "req_m": req.tolist(),
        "noise_scale": noise_scale,
        "seed": seed,
    }


# ----------------------------------------------------------------------------------------------------
# Camera-style datasets, processed as real data
# ----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Design:
    """How a synthetic dataset is recorded (what a lab chooses, not the material).

    n_exp : bubbles (records).
    frame_s : camera frame interval [s].
    noise : radius noise, :func:`imrbayes.data.synthetic.parse_noise` syntax (``"2um"``: Gaussian,
        sd 2 µm on every frame, the maximum included; ``"2um+paper"`` adds the paper's model).
    pre_max : frames recorded before the maximum (the growth, taken as the mirror of the collapse).
    t_end_star : end of each record after the true maximum [t*] (default 4: 3-4 collapses and some
        tail, past the analysis grid's t* = 3 so that the estimated maximum's shift never truncates it;
        Req is estimated from the record's last 20 frames, as for measured data).
    rmax_um : (mean, sd) of the bubbles' Rmax [µm] (normal, clipped to mean +- 3 sd).
    ratio : (mean, sd) of Rmax/Req (normal, clipped to mean +- 3 sd and >= 2).
    scatter : bubble-to-bubble material scatter, name -> relative sd (log-normal around the
        dataset's value, :func:`imrbayes.data.synthetic.draw_scatter`), e.g. ``{"G": 0.1}``.
    dt_star, n_steps : the analysis grid of the preprocessing (``imrbayes diagnose``'s defaults).
    material : name -> :class:`Range` replacing :data:`BASELINE_TRUTH`'s range of G or mu (a design
        for gels where a mechanism is strong, :data:`STRENGTH_DESIGNS`); empty: the baseline ranges.
    """

    name: str = "1Mfps-2um-5"
    n_exp: int = 5
    frame_s: float = 1e-6
    noise: str = "2um"
    pre_max: int = 6
    t_end_star: float = 4.0
    rmax_um: tuple = (300.0, 30.0)
    ratio: tuple = (7.5, 0.4)
    scatter: Mapping = field(default_factory=dict)
    dt_star: float = 0.025
    n_steps: int = 120
    material: Mapping = field(default_factory=dict)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["scatter"] = dict(self.scatter)
        d["material"] = {k: asdict(v) for k, v in self.material.items()}
        return d


#: Realistic, varied recording designs (the null / false-alarm runs cycle through them). Frame rates
#: and noise as in the labs' data: 1-2 Mfps with ~1-3 µm edge noise (Shimadzu HPV-X2), 270 kfps
#: (the paper's Phantom) with a few frames per collapse.
DESIGNS = {
    "1Mfps-2um-5": Design(),
    # a coarse camera: ~8 frames per t* unit, records long enough for 20 tail frames after the collapses
    "270kfps-2um-3": Design("270kfps-2um-3", n_exp=3, frame_s=1 / 270e3, noise="2um", pre_max=2, t_end_star=8.0),
    "2Mfps-4um-8": Design("2Mfps-4um-8", n_exp=8, frame_s=0.5e-6, noise="4um", pre_max=10),
    "1Mfps-1um-5-scatterG": Design(
        "1Mfps-1um-5-scatterG", n_exp=5, frame_s=1e-6, noise="1um", pre_max=6, scatter={"G": 0.1}
    ),
    "500kfps-3um-6-small": Design(
        "500kfps-3um-6-small", n_exp=6, frame_s=2e-6, noise="3um", pre_max=4, rmax_um=(220.0, 25.0), ratio=(6.5, 0.4)
    ),
}

#: Designs where a mechanism that is at the noise level in :data:`DESIGNS` is strong enough to be
#: found (not in the null cycle). Liquid compressibility matters at violent collapses: low viscosity
#: and large Rmax/Req (soft, weakly viscous gels; the paper's second truth is G 2 kPa, mu 0.05 Pa s,
#: Rmax/Req 9) filmed with little noise. Gilmore against Keller-Miksis, noise-free, thermal, t* <= 3,
#: seeds 6000-6003: 5.6-8.1 µm RMS (max 39-52 µm) here against 0.4-2.9 µm (max 2-23 µm) on the
#: default design (`bubble_effect`-style comparison).
STRENGTH_DESIGNS = {
    "1Mfps-1um-5-violent": Design(
        "1Mfps-1um-5-violent", noise="1um", ratio=(9.5, 0.3), material={"mu": Range(0.02, 0.05, log=True)}
    ),
}


def design_of(design) -> Design:
    """A :class:`Design`, a name in :data:`DESIGNS` or :data:`STRENGTH_DESIGNS`, or None (the default)."""
    if isinstance(design, str):
        if design in DESIGNS:
            return DESIGNS[design]
        if design in STRENGTH_DESIGNS:
            return STRENGTH_DESIGNS[design]
        raise KeyError(f"unknown design {design!r}; known: {', '.join([*DESIGNS, *STRENGTH_DESIGNS])}")
    return design or Design()


# Bubble classes: the data come from the baseline NHKV material with a different *bubble* model than
# the fitted one (forward-option overrides of the fitted options, :data:`BUBBLE_GENERATORS`).
# Effect sizes, measured with ``bubble_effect`` (noise-free, same material and geometry, t* <= 3,
# 3 bubbles of the default design, RMS of R*(class) - R*(none) over t* and bubbles, in units of a
# 2 µm noise sd; seeds 0-4 unless said):
#   bubble-thermal, fitted polytropic -> data thermal:   43-54 sd (86-108 µm RMS, max 180-250 µm)
#   bubble-thermal, fitted thermal -> data warm medium:  15-22 sd (31-44 µm RMS, max 114-154 µm;
#       seeds 0-1 only: the warm medium is step-limited, ~1.8e5 steps and 10-50 s per bubble, and its
#       first rebound is ~30 % higher than the cold medium's, which looks large for water-like gels:
#       worth checking in the forward model before trusting this class)
#   bubble-compressibility, km -> gilmore (polytropic): 0.6-2.0 sd (1.2-3.9 µm RMS, max 5-27 µm)
#   bubble-compressibility, km -> gilmore (thermal):    0.25-1.6 sd (0.5-3.2 µm RMS, max 3-28 µm)
# Compressibility matters only at the violent collapses (low mu) and is at the noise level; after a
# refit of (G, mu) (polytropic, 2 µm, 5 bubbles, seeds 0-2) the RMS residual on the analysis grid is
# 1.9-2.3 noise sd against 1.9-2.0 for ``none`` (mu absorbs it, ~-7 %): practically undetectable, so
# its right answer is arguably ``none``. A realistic strength knob would be a design with less noise
# (1 µm) and violent bubbles (mu 0.02-0.05 Pa s, Rmax/Req 9-10). The thermal class after the refit:
# 3.1-4.7 sd (clearly detectable). (Constant-NHKV data refit to ~2 sd, not 1: interpolation of the
# frames across the collapses and the estimated maximum add misfit beyond the frame noise.)


def _bubble_thermal(options) -> dict:
    """The bubble-thermal candidate's alternative (:mod:`imrbayes.diagnosis.candidates`): heat in
    the bubble when the fit is polytropic; else vapour mass transfer switched. (The warm medium,
    measured above, is not used: the solver needs ~1.8e5 steps for it.)"""
    return CANDIDATES["bubble-thermal"].forward_options(options)


def _bubble_compressibility(options) -> dict:
    """Liquid compressibility: Gilmore (or Keller-Miksis when the fit is already Gilmore)."""
    return CANDIDATES["bubble-gilmore"].forward_options(options)


#: mechanism -> (material candidate key, fitted options -> forward-option overrides of the data).
BUBBLE_GENERATORS = {
    "bubble-thermal": (BASELINE.key, _bubble_thermal),
    "bubble-compressibility": (BASELINE.key, _bubble_compressibility),
}


def camera_mechanisms() -> dict:
    """Every class :func:`camera_obs` generates: mechanism -> (candidate key, overrides function or
    None): the material mechanisms of :data:`GENERATORS`, then the bubble classes."""
    out = {m: (k, None) for m, k in GENERATORS.items()}
    out.update(BUBBLE_GENERATORS)
    return out


_METHOD_KEYS = ("bubble", "medium")
#: integrator steps allowed per synthetic solve: the warm medium takes ~1.8e5 (its medium diffusion
#: limits the explicit part's step) on the default grid, more on finer ones
MAX_STEPS = 2_000_000
#: at most this many times ``n_exp`` bubbles are recorded to get ``n_exp`` the preprocessing accepts
MAX_BUBBLE_FACTOR = 4


def fine_options(options):
    """The default data-generating discretisation for a fit on ``options``: 1.5x the points inside
    the bubble and in the medium and 10x tighter integrator tolerances, so a fit never sees data
    made by its own discretisation."""
    nt, mt = options.resolution
    return replace(
        options,
        nt=int(math.ceil(1.5 * nt)),
        mt=int(math.ceil(1.5 * mt)),
        rtol=options.rtol / 10,
        atol=options.atol / 10,
    )


def data_options(options, mechanism: str, truth_options=None):
    """The ForwardOptions the data of ``mechanism`` are generated with (fitted ``options``,
    ``truth_options`` default :func:`fine_options`, plus the bubble class's overrides)."""
    _, over = camera_mechanisms()[mechanism]
    changes = over(options) if over is not None else {}
    base = truth_options
    if changes and any(k in changes for k in _METHOD_KEYS):
        # the integrator and its default tolerances depend on the bubble model: pick them afresh
        src = options if truth_options is None else truth_options
        new = replace(src, **{**changes, "integrator": None, "rtol": None, "atol": None})
        # the warm medium already runs on another integrator than the fit (and costs ~10-50 s a bubble
        # on the default grid): it is not refined further
        return fine_options(new) if truth_options is None and new.medium == "cold" else new
    if base is None:
        base = fine_options(options)
    return replace(base, **changes) if changes else base


def _true_minima(fm, prm, rmax, req, t_end, breaks=None, dt=0.002):
    """Collapse times [t*] of a noise-free curve (local minima of prominence >= 0.01 R*)."""
    from scipy.signal import find_peaks

    t = np.arange(0.0, t_end + dt / 2, dt)
    o = fm.simulate(
        prm,
        np.array([rmax]),
        np.array([req]),
        t,
        max_steps=MAX_STEPS,
        **({"breaks_star": np.asarray(breaks, float)[None]} if breaks is not None else {}),
    )
    if o.failed[0]:
        raise RuntimeError("forward solve failed while locating the true collapses")
    idx, _ = find_peaks(-o.R_star[0], prominence=0.01)
    return t[idx]


def _clean_record(cand, fm, theta: dict, rmax, req, ts, peer=None):
    """Noise-free R* of one bubble at its frame times ``ts`` (t* from the maximum; mirror before it)
    and the break times used (piecewise candidates: the bubble's own true collapses). ``peer``: a
    :class:`~imrbayes.forward.peers.PyIMRModel` that makes the curve instead (another code)."""
    z = cand.to_internal([theta[n] for n in cand.names])
    t_abs, back = np.unique(np.abs(np.asarray(ts, float)), return_inverse=True)
    if peer is not None:
        if cand.piecewise:
            raise ValueError(f"generator pyimr: the piecewise model {cand.key!r} has no PyIMR counterpart")
        return peer.simulate_radius({n: theta[n] for n in cand.names}, rmax, req, t_abs)[back], []
    breaks = None
    if cand.piecewise:
        t_end = float(t_abs[-1])
        base = cand.forward_params(z, n_pieces=1)  # piece 0 everywhere: the undamaged bubble
        br = _true_minima(fm, base, rmax, req, t_end)
        for _ in range(2):  # the losses move the later collapses
            br = _true_minima(
                fm, cand.forward_params(z, n_pieces=br.size + 1), rmax, req, t_end, breaks=br if br.size else None
            )
        breaks = br
    prm = cand.forward_params(z, n_pieces=(breaks.size + 1) if breaks is not None else 1)
    kw = {"breaks_star": breaks[None]} if breaks is not None and breaks.size else {}
    o = fm.simulate(prm, np.array([rmax]), np.array([req]), t_abs, max_steps=MAX_STEPS, **kw)
    if o.failed[0] or not np.all(np.isfinite(o.R_star[0])):
        raise RuntimeError(f"forward solve failed for the synthetic truth {theta} (Rmax {rmax:g} m, Req {req:g} m)")
    return o.R_star[0][back], ([] if breaks is None else breaks.tolist())


def _draw_clipped(rng, mean, sd, n, low=None):
    x = np.clip(rng.normal(mean, sd, n), mean - 3 * sd, mean + 3 * sd)
    return x if low is None else np.maximum(x, low)


def _camera_record(i, rm, ratio, d, cand, fm, parameters, phase, noise_d, uc, rng, peer, source):
    """Record bubble ``i`` (0-based) of a camera dataset: frames of the clean curve plus noise.

    rm [m] Rmax, ratio Rmax/Req, d the :class:`Design`, parameters the bubble's material, phase [s]
    its sub-frame phase, noise_d the parsed noise model, uc [m/s] the velocity scale, ``rng`` the
    noise stream, ``peer`` another forward code (or None). Returns ``(Experiment, truth entry)``.
    """
    from imrbayes.data import synthetic as syn
    from imrbayes.data.records import Experiment

    rq, tc = float(rm / ratio), float(rm / uc)
    name = f"exp_{i + 1:03d}"
    ts = syn.camera_times(tc, d.frame_s, d.t_end_star, d.pre_max * d.frame_s, phase)
    Rs, breaks = _clean_record(cand, fm, parameters, rm, rq, ts, peer=peer)
    Rn, redrawn = syn.noisy(ts, Rs, noise_d, rng, rmax_m=rm)
    exp = Experiment(name, (ts - ts[0]) * tc, Rn * rm, source=f"{source}:{name}")
    sd = syn.noise_sd(ts, Rs, noise_d, rm)
    entry = {
        "name": name,
        "rmax_m": rm,
        "req_m": rq,
        "rmax_over_req": float(ratio),
        "t_max_s": float(-ts[0] * tc),
        "tc_s": tc,
        "phase_s": phase,
        "n_frames": int(ts.size),
        "noise_sd_m": float(np.median(sd) * rm),
        "noise_sd_at_max_r_star": float(syn.noise_sd(np.zeros(1), np.ones(1), noise_d, rm)[0]),
        "n_redrawn_nonpositive": int(redrawn),
        "parameters": parameters,
        "breaks_star": breaks,
    }
    return exp, entry


def _camera_truth(mechanism, key, theta, seed, d, noise_d, options, dopts, peer, truth_exp, obs, discarded, pre):
    """The truth dict of :func:`camera_obs` (see there) for the kept records of ``obs``."""
    kept = {e["name"]: e for e in truth_exp}
    return {
        "mechanism": mechanism,
        "model": key,
        "theta": theta,
        "seed": seed,
        "design": d.to_dict(),
        "noise": noise_d,
        "fitted_forward": options.to_dict(),
        "data_forward": dopts.to_dict(),
        "forward_overrides": {k: v for k, v in dopts.to_dict().items() if options.to_dict().get(k) != v},
        "generator": peer.describe() if peer is not None else {"code": "imrbayes"},
        "experiments": truth_exp,
        "names": list(obs.names),
        "rmax_m": [kept[nm]["rmax_m"] for nm in obs.names],
        "req_m": [kept[nm]["req_m"] for nm in obs.names],
        "t_max_s": [kept[nm]["t_max_s"] for nm in obs.names],
        "discarded": discarded,
        "warnings": pre.warnings,
    }


def camera_obs(
    mechanism: str,
    seed: int,
    options,
    n_exp: int | None = None,
    design=None,
    truth_options=None,
    noise: str | None = None,
    frame_s: float | None = None,
    scatter: Mapping | None = None,
    physics=None,
    generator: str = "imrbayes",
):
    """(Observations, truth dict): camera-style records with the hidden ``mechanism``, processed
    exactly as measured data.

    mechanism : ``none``, a material mechanism of :data:`GENERATORS`, or a bubble class of
        :data:`BUBBLE_GENERATORS` (``bubble-thermal``, ``bubble-compressibility``).
    options : the ForwardOptions the diagnosis will fit with (the bubble classes change it).
    design : a :class:`Design`, a :data:`DESIGNS` name, or None (the default design);
        ``n_exp``, ``noise``, ``frame_s``, ``scatter`` override its fields.
    truth_options : ForwardOptions of the data (default :func:`fine_options` of ``options``,
        with the bubble class's overrides applied in either case).
    generator : ``imrbayes`` (our forward model with ``truth_options``) or ``pyimr`` (another code,
        :mod:`imrbayes.forward.peers`, with the same physics options; its own discretisation).

    Draws (one ``default_rng(seed)``): the material as :func:`synthetic_obs` (G, mu log-uniform,
    the mechanism's parameters from its candidate's ``synthetic`` ranges), Rmax and Rmax/Req per
    bubble, then each record's noise; the sub-frame phases and the material scatter from the
    streams of :mod:`imrbayes.data.synthetic`. Each record: frames every ``frame_s`` from
    ``pre_max`` frames before the maximum (random sub-frame phase; the growth is the mirror of the
    collapse) to ``t_end_star``; noise on every frame; the camera clock starts at the first frame.
    The records then go through :func:`imrbayes.data.preprocess_dataset` (``skip_failed``, the
    ``imrbayes diagnose`` defaults) and :meth:`Observations.from_preprocessed`: Rmax, the time of
    the maximum and Req are estimated from the noisy frames (Req from the record's tail), and the
    Observations carry noise_sd, nuisance_sd, t0_s, tc_s and frame_t as for a dataset read from disk.
    A record the preprocessing refuses (at coarse frame rates a damped bubble's small rebound may be
    missed) is discarded and another bubble recorded, as a lab would (numbered on, listed in
    ``truth["discarded"]``; at most ``MAX_BUBBLE_FACTOR * n_exp`` bubbles).

    truth : mechanism, model (candidate key), theta (material), seed, design, noise, fitted_forward
    and data_forward (ForwardOptions dicts), forward_overrides (what differs), experiments (per
    recorded bubble: true rmax_m, req_m, t_max_s in the camera clock, tc_s, phase_s, noise sd,
    parameters after scatter, breaks_star of a piecewise material), names (kept, in the order of
    ``obs``), rmax_m / req_m / t_max_s (kept, in that order), discarded, warnings.
    """
    from imrbayes.data import synthetic as syn
    from imrbayes.data.pipeline import preprocess_dataset
    from imrbayes.data.records import Dataset
    from imrbayes.forward.constants import Physics

    d = design_of(design)
    over = {
        k: v
        for k, v in {"n_exp": n_exp, "noise": noise, "frame_s": frame_s, "scatter": scatter}.items()
        if v is not None
    }
    if over:
        d = replace(d, **over)
    classes = camera_mechanisms()
    if mechanism not in classes:
        raise KeyError(f"unknown mechanism {mechanism!r}; known: {', '.join(classes)}")
    key, _ = classes[mechanism]
    physics = physics if physics is not None else Physics()
    dopts = data_options(options, mechanism, truth_options)
    cand = make_candidate(key, dopts, physics=physics)
    fm = cand.fm
    if generator not in ("imrbayes", "pyimr"):
        raise ValueError(f"generator must be 'imrbayes' or 'pyimr', got {generator!r}")
    peer = None
    if generator == "pyimr":
        from imrbayes.forward.peers import PyIMRModel

        peer = PyIMRModel(fm)
    rng = np.random.default_rng(seed)
    theta = {n: r.draw(rng) for n, r in {**BASELINE_TRUTH, **d.material, **cand.spec.synthetic}.items()}
    n = int(d.n_exp)
    n_max = n * MAX_BUBBLE_FACTOR
    uc = physics.velocity_scale
    phases = syn.draw_phases(seed, n_max, d.frame_s, True)
    per_exp = syn.draw_scatter(seed, theta, dict(d.scatter), n_max) if d.scatter else [dict(theta)] * n_max
    noise_d = syn.parse_noise(d.noise)
    exps, truth_exp, discarded = [], [], []
    want, recorded = n, 0
    while True:
        # the lab records ``want`` more bubbles; records the preprocessing refuses are discarded and
        # replaced (e.g. a damped bubble at 270 kfps whose rebound no frame resolves)
        rmax = _draw_clipped(rng, d.rmax_um[0], d.rmax_um[1], want) * 1e-6
        ratio = _draw_clipped(rng, d.ratio[0], d.ratio[1], want, low=2.0)
        for j in range(want):
            i = recorded + j
            exp, entry = _camera_record(
                i,
                float(rmax[j]),
                float(ratio[j]),
                d,
                cand,
                fm,
                per_exp[i],
                float(phases[i]),
                noise_d,
                uc,
                rng,
                peer,
                f"synthetic:{mechanism}:{seed}",
            )
            exps.append(exp)
            truth_exp.append(entry)
        recorded += want
        ds = Dataset(
            f"camera-{mechanism}-{seed}",
            "<synthetic>",
            "synthetic-camera",
            exps,
            material=f"synthetic ({mechanism})",
            physics=physics.to_dict(),
        )
        pre = preprocess_dataset(ds, dt_star=d.dt_star, n_steps=d.n_steps, skip_failed=True)
        if pre.skipped:
            bad = {s["name"] for s in pre.skipped}
            why = {sk["name"]: sk["error"] for sk in pre.skipped}
            discarded += [{**e, "error": why[e["name"]]} for e in truth_exp if e["name"] in bad]
            exps = [e for e in exps if e.name not in bad]
            truth_exp = [e for e in truth_exp if e["name"] not in bad]
            want = n - len(exps)
            if recorded + want > n_max:
                raise RuntimeError(
                    f"{len(discarded)} of {len(exps) + len(discarded)} synthetic records refused by "
                    f"the preprocessing (design {d.name}); first: {discarded[0]['error']}"
                )
            continue
        break
    obs = Observations.from_preprocessed(pre)
    truth = _camera_truth(mechanism, key, theta, seed, d, noise_d, options, dopts, peer, truth_exp, obs, discarded, pre)
    return obs, truth


def clean_curves(mechanism: str, seed: int, options, t_star, design=None, truth_options=None, n_exp: int = 3):
    """Noise-free R* (n_exp, len(t_star)) of ``mechanism``'s data on one grid, with the material and
    bubbles :func:`camera_obs` draws for ``seed`` (no scatter); for effect sizes and tests."""
    from imrbayes.forward.constants import Physics

    d = design_of(design)
    key, _ = camera_mechanisms()[mechanism]
    physics = Physics()
    cand = make_candidate(key, data_options(options, mechanism, truth_options), physics=physics)
    rng = np.random.default_rng(seed)
    theta = {n: r.draw(rng) for n, r in {**BASELINE_TRUTH, **d.material, **cand.spec.synthetic}.items()}
    rmax = _draw_clipped(rng, d.rmax_um[0], d.rmax_um[1], d.n_exp) * 1e-6
    ratio = _draw_clipped(rng, d.ratio[0], d.ratio[1], d.n_exp, low=2.0)
    return np.array(
        [
            _clean_record(cand, cand.fm, theta, float(rmax[i]), float(rmax[i] / ratio[i]), t_star)[0]
            for i in range(min(n_exp, d.n_exp))
        ]
    ), rmax[:n_exp]


def bubble_effect(
    mechanism: str, seed: int, options, noise_um: float = 2.0, t_end: float = 3.0, truth_options=None, design=None
) -> dict:
    """RMS over t* in [0, t_end] and bubbles of R*(data of ``mechanism``) - R*(data of ``none``), same
    material and geometry (``design``'s): in R*, in µm, and in units of a ``noise_um`` noise sd."""
    t = np.linspace(0.0, t_end, 601)
    Rb, rmax = clean_curves(mechanism, seed, options, t, design=design, truth_options=truth_options)
    R0, _ = clean_curves("none", seed, options, t, design=design, truth_options=truth_options)
    diff_um = (Rb - R0) * rmax[:, None] * 1e6
    rms_um = float(np.sqrt(np.mean(diff_um**2)))
    return {
        "mechanism": mechanism,
        "seed": seed,
        "rms_r_star": float(np.sqrt(np.mean((Rb - R0) ** 2))),
        "rms_um": rms_um,
        "rms_over_noise": rms_um / noise_um,
        "max_abs_um": float(np.max(np.abs(diff_um))),
    }
