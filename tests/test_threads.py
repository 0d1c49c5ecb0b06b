"""The ``aibo`` command runs with one BLAS thread per process unless the user sets otherwise (aibo/__init__.py)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from aibo import BLAS_THREAD_VARS

ROOT = Path(__file__).resolve().parents[1]
SHOW = "import aibo.cli, os, numpy; print(' '.join(os.environ.get(v, '-') for v in aibo.BLAS_THREAD_VARS))"


@pytest.mark.parametrize("user, expected", [(None, "1"), ("3", "3")])
def test_one_blas_thread_unless_the_user_says_otherwise(user, expected):
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARS}
    env["PYTHONPATH"] = str(ROOT)
    if user:
        env.update({v: user for v in BLAS_THREAD_VARS})
    out = subprocess.run([sys.executable, "-c", SHOW], env=env, capture_output=True, text=True, check=True).stdout
    assert out.split() == [expected] * len(BLAS_THREAD_VARS)
