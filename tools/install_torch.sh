#!/usr/bin/env bash
# Install torch into the venv without ever pulling a multi-GB CUDA build onto a CPU machine.
# - torch already installed: keep it.
# - NVIDIA GPU present: the default (CUDA) build from PyPI.
# - otherwise: the CPU build `torch==2.13.0+cpu` (the +cpu local label matches no CUDA wheel on PyPI),
#   from pip's configured find-links/indexes, else from PyTorch's CPU index.
set -euo pipefail
pip=${1:?usage: install_torch.sh PATH/TO/pip}
py=$(dirname "$pip")/python
if "$py" -c "import torch" 2>/dev/null; then exit 0; fi
if command -v nvidia-smi >/dev/null 2>&1 && nvidia-smi -L >/dev/null 2>&1; then
  exec "$pip" install -q torch
fi
"$pip" install -q "torch==2.13.0+cpu" 2>/dev/null \
  || "$pip" install -q "torch==2.13.0+cpu" --extra-index-url https://download.pytorch.org/whl/cpu
