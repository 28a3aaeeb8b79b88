#!/usr/bin/env bash
# Create .venv with Python >= 3.12 (ArviZ 1.x needs it) and install imrbayes with its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=""
for cand in python3.12 python3.13 python3 python; do
    if command -v "$cand" >/dev/null 2>&1 && "$cand" -c 'import sys; sys.exit(sys.version_info < (3, 12))' 2>/dev/null; then
        PY="$cand"; break
    fi
done
if [ -z "$PY" ] && command -v pyenv >/dev/null 2>&1; then
    PY="$(PYENV_VERSION=3.12.1 pyenv which python 2>/dev/null || true)"
fi
if [ -z "$PY" ]; then
    echo "install.sh: no Python >= 3.12 found (ArviZ 1.x needs it); install one or use pyenv" >&2
    exit 1
fi
if [ ! -x .venv/bin/python ] || ! .venv/bin/python -c 'import sys; sys.exit(sys.version_info < (3, 12))'; then
    rm -rf .venv
    "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -e ".[test]"
.venv/bin/python -c "import imrbayes, arviz; print('imrbayes', imrbayes.__version__, '| arviz', arviz.__version__)"
