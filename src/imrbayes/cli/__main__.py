"""``python -m imrbayes.cli``: the ``imrbayes`` command."""

import sys

from imrbayes.cli import main

sys.exit(main())
