#!/usr/bin/env bash
# Set up ravenmem from scratch in ./.venv: torch pinned to the CPU build first (an unpinned torch
# pulls gigabytes of CUDA packages), then the package with the extras named in $RAVENMEM_EXTRAS.
# The `clip` extra (open_clip) is left out by default: it needs torchvision, and PyPI has no
# torchvision that runs on torch's CPU-only build; add it where a matched pair is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
EXTRAS=${RAVENMEM_EXTRAS:-dev,docs,sim,hf,milvus,eval,serve,api-docs,robot,view}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip
python -m pip install -q "torch==2.13.0"
# the constraint makes pip fail loudly rather than swap the CPU torch for a CUDA build
python -m pip install -q -c scripts/constraints.txt -e ".[${EXTRAS}]"
python -c "import torch, ravenmem; print('ravenmem', ravenmem.__version__, 'torch', torch.__version__)"
