"""What a benchmark ran on: the CPU decides the numbers as much as the code does.

The shared 2-core VM lands on different hosts from session to session (the same code ran the
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
                    break                      # first processor only
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
    return {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count(),
            "cpu_model_name": cpu.get("model name"), "cpu_family": cpu.get("cpu family"), "cpu_model": cpu.get("model"),
            "avx2": "avx2" in flags, "avx512f": "avx512f" in flags, "numba_target_cpu": target,
            "numba_threads": os.environ.get("NUMBA_NUM_THREADS")}


def cpu_label(info: dict | None = None) -> str:
    """Short label, e.g. ``AMD EPYC, family 26 (znver5), AVX-512``."""
    info = machine_info() if info is None else info
    vec = "AVX-512" if info["avx512f"] else ("AVX2" if info["avx2"] else "no AVX2")
    return f"{info['cpu_model_name']}, family {info['cpu_family']} ({info['numba_target_cpu']}), {vec}"
