#!/usr/bin/env bash
# Sets up everything the tests need on a fresh machine, then runs all of them:
#   1. Debian packages: LLVM 19 for Dr.Jit's CPU backend (mitransient's llvm_ad_mono)
#      (Umbra itself needs no system library: its HDF5 is pure Rust, rust-hdf5);
#   2. a Python venv in .venv with the peers (python/requirements-test.txt);
#   3. cargo test --release (Rust unit, integration and fuzz tests);
#   4. the `umbra` Python package (python/, maturin) into .venv, and PyTorch unless
#      UMBRA_SKIP_TORCH=1 (the torch tests are then skipped, with that reason), and Ray
#      (umbra.distributed) unless UMBRA_SKIP_RAY=1 (likewise);
#   5. the Python suite (python/tests): the package, umbra.torch, Umbra against mitransient.
# Each install step runs only when its check fails, so reruns are fast.
set -euo pipefail
cd "$(dirname "$0")"

# Debian packages: LLVM 19 for Dr.Jit (the peers' CPU backend). y-tal's HDF5 captures need
# none: Umbra reads and writes them with rust-hdf5 (pure Rust), h5py brings its own libhdf5.
if ! ls /usr/lib/x86_64-linux-gnu/libLLVM.so.19* >/dev/null 2>&1; then
    echo "== installing libllvm19 (apt)"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq && $SUDO apt-get install -y -qq libllvm19
fi
export DRJIT_LIBLLVM_PATH="${DRJIT_LIBLLVM_PATH:-$(ls /usr/lib/x86_64-linux-gnu/libLLVM.so.19* | head -n1)}"

# (find_spec, not import: mitransient refuses to import before a Mitsuba variant is set)
if ! .venv/bin/python -c "import importlib.util as u, sys; sys.exit(any(u.find_spec(m) is None for m in ['mitsuba', 'drjit', 'mitransient', 'numpy', 'pytest', 'h5py', 'maturin', 'mypy']))" 2>/dev/null; then
    echo "== creating .venv with the peers"
    python3 -m venv .venv
    .venv/bin/pip install -q --upgrade pip
    .venv/bin/pip install -q -r python/requirements-test.txt
fi

echo "== cargo test --release"
cargo build --release --locked
cargo test --release --locked

echo "== the umbra Python package"
.venv/bin/pip install -q --no-build-isolation ./python
if [ "${UMBRA_SKIP_TORCH:-0}" != "1" ] && ! .venv/bin/python -c "import importlib.util as u, sys; sys.exit(u.find_spec('torch') is None)"; then
    echo "== installing torch (CPU use; UMBRA_SKIP_TORCH=1 skips it and its tests)"
    .venv/bin/pip install -q torch
fi
if [ "${UMBRA_SKIP_RAY:-0}" != "1" ] && ! .venv/bin/python -c "import importlib.util as u, sys; sys.exit(u.find_spec('ray') is None)"; then
    echo "== installing ray (umbra.distributed; UMBRA_SKIP_RAY=1 skips it and its tests)"
    .venv/bin/pip install -q "ray>=2.9"
fi

# y-tal (pins numpy < 2) gets its own venv: python/tests/test_ytal.py reads Umbra's .hdf5
# renders with y-tal's own reader through .venv-ytal/bin/python.
if ! .venv-ytal/bin/python -c "import tal" 2>/dev/null; then
    echo "== creating .venv-ytal with y-tal"
    python3 -m venv .venv-ytal
    .venv-ytal/bin/pip install -q --upgrade pip
    .venv-ytal/bin/pip install -q y-tal==0.20.0
fi

echo "== python tests"
UMBRA_BIN="$PWD/target/release/umbra" .venv/bin/python -m pytest -q python/tests "$@"
