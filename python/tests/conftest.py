"""Fixtures for Umbra's Python-side validation tests.

- `mt`: (mi, mitr) with mitransient 1.3.1 / Mitsuba 3.9.1 loaded in variant llvm_ad_mono,
  DRJIT_LIBLLVM_PATH pointing at LLVM 19, 2 threads (override with UMBRA_TEST_THREADS).
- `umbra_bin`: path of the Umbra CLI from env UMBRA_BIN (default
  <repo>/target/release/umbra). A missing binary FAILS the tests that need it (never skips).
  The special value UMBRA_BIN=mitransient-self substitutes mitransient itself (other seeds)
  for Umbra: a calibration run of the statistics in test_vs_mitransient.py.
"""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

PY_DIR = Path(__file__).resolve().parents[1]          # <repo>/python
REPO = PY_DIR.parent
VALIDATION = PY_DIR / "validation"
sys.path.insert(0, str(VALIDATION))

SELF_CHECK = "mitransient-self"


@pytest.fixture(scope="session")
def mt():
    import mtutil

    return mtutil.setup(threads=int(os.environ.get("UMBRA_TEST_THREADS", "2")))


def require_umbra(path: str) -> str:
    """Fail (not skip, not error) the calling test if the Umbra binary is missing."""
    if path == SELF_CHECK:
        return path
    if not (os.path.isfile(path) and os.access(path, os.X_OK)):
        pytest.fail(
            f"Umbra binary not found or not executable: {path!r}. Build it with "
            "`cargo build --release` (-> target/release/umbra) or point UMBRA_BIN at it "
            f"(UMBRA_BIN={SELF_CHECK} runs the statistics against mitransient itself).",
            pytrace=False,
        )
    return path


@pytest.fixture(scope="session")
def umbra_bin() -> str:
    """Path of the Umbra CLI (UMBRA_BIN or <repo>/target/release/umbra); tests call
    require_umbra() on it so that a missing binary is a test FAILURE with a clear message."""
    return os.environ.get("UMBRA_BIN", str(REPO / "target" / "release" / "umbra"))


@pytest.fixture(scope="session")
def cache_dir() -> Path:
    d = VALIDATION / "cache"
    d.mkdir(exist_ok=True)
    return d


YTAL_PYTHON = os.environ.get("UMBRA_YTAL_PYTHON", str(REPO / ".venv-ytal" / "bin" / "python"))


def require_ytal() -> str:
    """Fail (not skip) the calling test unless y-tal 0.20.0's venv (`.venv-ytal`, or the
    interpreter UMBRA_YTAL_PYTHON names) imports `tal`; its Python."""
    import subprocess
    ok = os.path.isfile(YTAL_PYTHON) and subprocess.run(
        [YTAL_PYTHON, "-c", "import tal"], capture_output=True).returncode == 0
    if not ok:
        pytest.fail(
            f"y-tal's venv not found or without y-tal: {YTAL_PYTHON!r}. Create it with "
            "`python3 -m venv .venv-ytal && .venv-ytal/bin/pip install y-tal==0.20.0` "
            "(test.sh does) or point UMBRA_YTAL_PYTHON at a Python with y-tal 0.20.0.",
            pytrace=False,
        )
    return YTAL_PYTHON
