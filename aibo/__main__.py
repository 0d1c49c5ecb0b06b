"""``python -m aibo``: the ``aibo`` command (``aibo/cli.py``), for an environment whose scripts folder is not on the
PATH, or to run it under a profiler (``python -m cProfile -m aibo ...``)."""

import sys

from aibo.cli import main

sys.exit(main())
