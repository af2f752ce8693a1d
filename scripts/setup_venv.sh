#!/usr/bin/env bash
# Idempotent environment setup: system library for Open3D, a .venv, the CPU torch wheel first, then vtlearn.
# Usage: scripts/setup_venv.sh [extra]   (extra: "dev" installs the test tools too)
set -euo pipefail
cd "$(dirname "$0")/.."
EXTRA="${1:-}"
if ! ldconfig -p 2>/dev/null | grep -q libusb-1.0; then
    if [ "$(id -u)" = 0 ]; then
        (apt-get update -qq && apt-get install -y -qq libusb-1.0-0) >/dev/null
    else
        echo "warning: libusb-1.0-0 is missing and we are not root; Open3D may fail to import" >&2
    fi
fi
PY="${PYTHON:-python3}"
[ -x .venv/bin/python ] || "$PY" -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip >/dev/null
# torch first, pinned to the CPU wheel: an unpinned torch would pull a multi-GB CUDA build.
python -c "import torch, sys; sys.exit(0 if torch.__version__.startswith('2.13.0') else 1)" 2>/dev/null \
    || python -m pip install -q "torch==2.13.0"
if [ -n "$EXTRA" ]; then
    python -m pip install -q -e ".[$EXTRA]"
else
    python -m pip install -q -e .
fi
python -c "import torch; assert torch.__version__.startswith('2.13.0'), torch.__version__"
