"""Write (once) and import the compiled kernel module of a constitutive model.

numba caches compiled code per source file, and cannot cache a kernel that receives the stress
function as an argument. So each model gets its own copy of ``_kernel_template.py`` whose PLUGIN
import names that model's functions; the copy is written to a per-user cache directory under a
name that hashes every source it depends on (the template, the model's module and the other
constitutive modules, and the shared modules in ``_SHARED`` -- the stress-independent linear
algebra and loop helpers, compiled once for all models), so a second process reuses the machine
code and an edit of any of those sources gives a new file.

The kernel is compiled in a child process, and every process -- the first one included -- runs
the machine code numba cached: the code numba keeps in memory after compiling differs from what
it writes to the cache in the last bits of floating-point results (measured: R* sums 1e-15 apart
for the same polytropic batch), which made a run and its resume on worker processes differ.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import os
import re
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

_TEMPLATE = Path(__file__).with_name("_kernel_template.py")
# Modules of compiled code the template imports, shared by every model's kernel (not copied).
_SHARED = ("layout.py", "solver_algebra.py", "integration_common.py")
_LOADED: dict = {}


def cache_dir() -> Path:
    """Where generated kernels live: ``$IMRBAYES_CACHE_DIR`` or ``~/.cache/imrbayes``."""
    root = os.environ.get("IMRBAYES_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache"), "imrbayes")
    return Path(root) / "kernels"


def _warm_up(module_name: str) -> None:
    """Compile ``module_name``'s kernel entry points (serial and threaded) in this process; runs in
    the child that :func:`kernel_module` starts."""
    import numpy as np

    from imrbayes.forward import ForwardModel, ForwardOptions
    from imrbayes.forward.constitutive.base import REGISTRY

    model = next(name for name, mod in REGISTRY.items() if mod == module_name)
    fm = ForwardModel(model, options=ForwardOptions(bubble="polytropic"))
    defaults = {p.name: p.default for p in fm.constitutive.parameters}
    for n in (1, 2):  # one member and a batch (both through integrate_batch_parallel)
        fm.simulate({k: np.full(n, v) for k, v in defaults.items()}, 100e-6, 20e-6, np.array([0.0, 0.01]))


def _compile_in_child(module_name: str, marker: Path) -> None:
    """Populate numba's cache from a child process (see module doc); best effort: on failure
    this process compiles for itself."""
    stamp = os.environ.get("NUMBA_CACHE_DIR", "")
    if _is_compiled(marker):
        return
    code = f"import imrbayes.forward.codegen as c; c._warm_up({module_name!r})"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          env={**os.environ, _CHILD_ENV: "1"})
    if done.returncode == 0:
        fd, tmp = tempfile.mkstemp(dir=marker.parent, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            fh.write(stamp)
        os.replace(tmp, marker)
    else:
        # Said aloud: this process then compiles for itself, and its in-memory code may differ in
        # the last bits from the cached code other processes load (a run and its resume on workers).
        tail = (done.stderr or "").strip().splitlines()[-1:] or ["no output"]
        warnings.warn(f"compiling {module_name}'s kernel in a child process failed (exit {done.returncode}: "
                      f"{tail[0]}); compiling in this process", RuntimeWarning, stacklevel=2)


def _is_compiled(marker: Path) -> bool:
    """Whether a child compiled this kernel into the numba cache this process uses."""
    return marker.exists() and marker.read_text() == os.environ.get("NUMBA_CACHE_DIR", "")


_CHILD_ENV = "IMRBAYES_KERNEL_CHILD"   # set in the compiling child, which must not start another


def _kernel_source(module_name: str) -> tuple:
    """Write (once) the kernel module's source for ``module_name``; returns (module name, path)."""
    plugin = importlib.import_module(module_name)
    # numba does not notice edits of the modules a cached function calls into, so the file name
    # hashes the template, the shared modules it imports and every constitutive module (models
    # import each other).
    here = Path(__file__).parent
    sources = [_TEMPLATE.read_text(), inspect.getsource(plugin)] + [(here / f).read_text() for f in _SHARED]
    sources += [f.read_text() for f in sorted((here / "constitutive").glob("*.py"))]
    line = f"from {module_name} import stress as _stress, dissipation_q as _dissipation_q  # PLUGIN"
    src, count = re.subn(r"^from .*# PLUGIN$", line, sources[0], flags=re.M)
    if count != 1:
        raise RuntimeError("kernel template has no PLUGIN line")
    digest = hashlib.sha256("\n".join(sources).encode()).hexdigest()[:16]
    name = f"imrbayes_kernel_{module_name.rsplit('.', 1)[-1]}_{digest}"
    directory = cache_dir()
    path = directory / f"{name}.py"
    if not path.exists():
        directory.mkdir(parents=True, exist_ok=True)
        write_once(path, src)
    return name, path


def write_once(path: Path, text: str) -> bool:
    """Create ``path`` with ``text`` unless it exists; True if this call created it.

    Atomic and never overwrites: numba's cache index is keyed by the source file's modification
    time, so a second process that replaced the file (same text, new mtime) while the first one's
    child was compiling or its main process loading would make that process's cache look stale
    and compile the kernel in memory -- the last-bit differences the module doc is about."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        try:
            os.link(tmp, path)     # fails if the file exists: concurrent writers cannot replace it
        except FileExistsError:
            return False
        except OSError:            # a file system without hard links: replace, as atomically as it allows
            if path.exists():
                return False
            os.replace(tmp, path)
            return True
        return True
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def not_compiled(module_names) -> list:
    """Those of ``module_names`` whose kernel this cache does not hold yet (their first use would
    compile it: about a minute of one CPU each)."""
    return [m for m in module_names if not _is_compiled(_kernel_source(m)[1].with_suffix(".compiled"))]


def precompile(module_names=None, workers: int | None = None) -> None:
    """Compile the kernels of several constitutive models (default: all registered), ``workers``
    child processes at a time (default: one per CPU). A model's first compile takes about a
    minute, one CPU; already compiled kernels cost nothing."""
    from concurrent.futures import ThreadPoolExecutor

    from imrbayes.forward.constitutive.base import REGISTRY

    names = list(REGISTRY.values()) if module_names is None else list(module_names)
    paths = [_kernel_source(m)[1] for m in names]
    with ThreadPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        list(pool.map(lambda mp: _compile_in_child(mp[0], mp[1].with_suffix(".compiled")), zip(names, paths)))


def kernel_module(module_name: str):
    """The kernel module for the constitutive model implemented in ``module_name``."""
    if module_name in _LOADED:
        return _LOADED[module_name]
    name, path = _kernel_source(module_name)
    if not os.environ.get(_CHILD_ENV):
        _compile_in_child(module_name, path.with_suffix(".compiled"))
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    _LOADED[module_name] = module
    return module
