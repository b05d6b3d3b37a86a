#!/usr/bin/env bash
# Create .venv and install hrtc with everything it needs (CPU only). Safe to run again.
# torch goes first and pinned: its CPU wheel is what the project machine serves for 2.13.0, and anything unpinned
# (or a package asking for torch) would otherwise pull a multi-GB CUDA build.
set -euo pipefail
cd "$(dirname "$0")/.."
PYTHON=${PYTHON:-python3}
[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip
python -m pip install -q torch==2.13.0
python -m pip install -q -e ".[test]"
python -m pip check
