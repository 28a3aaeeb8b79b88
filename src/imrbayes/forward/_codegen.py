"""Write (once) and import the compiled kernel module of a constitutive model.

numba caches compiled code per source file, and cannot cache a kernel that receives the stress
function as an argument. So each model gets its own copy of ``_kernel_template.py`` whose PLUGIN
import names that model's functions; the copy is written to a per-user cache directory under a
name that hashes every source it depends on, so a second process reuses the machine code and an
edit of any of those sources gives a new file.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import os
import re
import sys
import tempfile
from pathlib import Path

_TEMPLATE = Path(__file__).with_name("_kernel_template.py")
_LOADED: dict = {}


def cache_dir() -> Path:
    """Where generated kernels live: ``$IMRBAYES_CACHE_DIR`` or ``~/.cache/imrbayes``."""
    root = os.environ.get("IMRBAYES_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(Path.home(), ".cache"), "imrbayes")
    return Path(root) / "kernels"


def kernel_module(module_name: str):
    """The kernel module for the constitutive model implemented in ``module_name``."""
    if module_name in _LOADED:
        return _LOADED[module_name]
    plugin = importlib.import_module(module_name)
    # numba does not notice edits of the modules a cached function calls into, so the file name
    # hashes the template, the layout and every constitutive module (models import each other).
    here = Path(__file__).parent
    sources = [_TEMPLATE.read_text(), inspect.getsource(plugin), (here / "_layout.py").read_text()]
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
        fd, tmp = tempfile.mkstemp(dir=directory, suffix=".tmp")
        with os.fdopen(fd, "w") as fh:
            fh.write(src)
        os.replace(tmp, path)  # atomic: concurrent processes never see half a file
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    _LOADED[module_name] = module
    return module
