"""What a benchmark ran on: the CPU decides the numbers as much as the code does.

The shared 2-core VM lands on different hosts from run to run (the same code ran the
forward benchmark's window batch in 79 ms on one and 64 ms on another, an AMD family-26 /
znver5 with AVX-512), and numba compiles for the host it finds, so a timing is only comparable
with one taken on the same CPU. Every benchmark JSON carries :func:`machine_info`.
"""

from __future__ import annotations

import os
import platform


def _cpuinfo() -> dict:
    info = {}
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if not line.strip():
                    break  # first processor only
                key, _, value = line.partition(":")
                info[key.strip()] = value.strip()
    except OSError:
        pass
    return info


def machine_info() -> dict:
    """CPU model, family/model numbers, vector extensions, numba's target CPU, core count."""
    cpu = _cpuinfo()
    flags = set(cpu.get("flags", "").split())
    try:
        import llvmlite.binding as llvm

        target = llvm.get_host_cpu_name()
    except Exception:  # pragma: no cover - llvmlite is a numba dependency
        target = None
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpus": os.cpu_count(),
        "cpu_model_name": cpu.get("model name"),
        "cpu_family": cpu.get("cpu family"),
        "cpu_model": cpu.get("model"),
        "avx2": "avx2" in flags,
        "avx512f": "avx512f" in flags,
        "numba_target_cpu": target,
        "numba_threads": os.environ.get("NUMBA_NUM_THREADS"),
    }


def cpu_label(info: dict | None = None) -> str:
    """Short label, e.g. ``AMD EPYC, family 26 (znver5), AVX-512``."""
    info = machine_info() if info is None else info
    vec = "AVX-512" if info["avx512f"] else ("AVX2" if info["avx2"] else "no AVX2")
    return f"{info['cpu_model_name']}, family {info['cpu_family']} ({info['numba_target_cpu']}), {vec}"


# The speed targets' reference: the previous default forward row (a) -- 48 members of the LIC case,
# thermal bubble, stretch 1.5, nt 64, t* in [0, 3] -- took 113 ms on the host the speed targets
# were set on. Timing the same row beside a benchmark says how fast *this* host is, so that
# a target missed here can be told apart from a target missed by the code.
YARDSTICK_REFERENCE_MS = 113.0


def host_yardstick(repeat: int = 5) -> dict:
    """Best-of-``repeat`` wall time [ms] of the yardstick row above and its ratio to the reference
    host's 113 ms (``host_factor`` > 1: this host is slower)."""
    import time

    import numpy as np

    from imrbayes.forward import ForwardModel, ForwardOptions

    rng = np.random.default_rng(0)
    params = {"G": 7290.0 * (1 + 0.4 * rng.uniform(-1, 1, 48)), "mu": 0.088 * (1 + 0.4 * rng.uniform(-1, 1, 48))}
    fm = ForwardModel("nhkv", options=ForwardOptions(stretch=1.5, nt=64))
    t_star = np.arange(121) * 0.025
    rmax, ratio = 263e-6, 7.58
    fm.simulate({"G": 7290.0, "mu": 0.088}, rmax, rmax / ratio, t_star[:3])  # load / compile
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fm.simulate(params, rmax, rmax / ratio, t_star)
        best = min(best, time.perf_counter() - t0)
    ms = 1e3 * best
    return {
        "row": "forward (a), previous default grid (stretch 1.5, nt 64), 48 members, t* <= 3",
        "ms": ms,
        "reference_ms": YARDSTICK_REFERENCE_MS,
        "host_factor": ms / YARDSTICK_REFERENCE_MS,
    }


RESULTS_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def results_path(name: str) -> str:
    """Where a benchmark writes its JSON by default: ``benchmarks/results/<name>.json``, the name
    saying what the file holds (the host and the run's yardstick are inside it)."""
    return os.path.join(RESULTS_DIR, f"{name}.json")


def per_yardstick(seconds: float, yardstick: dict) -> float:
    """A wall time [s] as a multiple of the host yardstick's time (:func:`host_yardstick`, measured
    in the same run): the number that compares across hosts, where absolute times do not."""
    return seconds / (1e-3 * yardstick["ms"])


def add_yardstick_ratios(row: dict, yardstick: dict, seconds_keys=(), ms_keys=()) -> dict:
    """Add ``<key>_per_yardstick`` to ``row`` for each timing in it, ``seconds_keys`` in s and
    ``ms_keys`` in ms (keys absent or None are skipped); returns ``row``."""
    for keys, to_seconds in ((seconds_keys, 1.0), (ms_keys, 1e-3)):
        for key in keys:
            if row.get(key) is not None:
                row[f"{key}_per_yardstick"] = per_yardstick(to_seconds * row[key], yardstick)
    return row
