#!/usr/bin/env bash
# A separate venv with LeRobot's own dataset loader (lerobot 0.4.4, dataset v3.0), for the tests that read simreel's
# exports with it. lerobot pins torch<2.11 and rerun-sdk<0.27, which simreel's venv cannot hold, and the only CPU
# torch build on the registry is 2.13.0+cpu: so lerobot goes in with --no-deps beside that torch, with the libraries
# its dataset code imports (no robots, no policies, no rerun). torch is pinned by a constraint so that nothing pulls
# a multi-GB CUDA build.
set -euo pipefail
venv=${1:?usage: lerobot_env.sh VENV}
python=${PYTHON:-python3}
test -x "$venv/bin/python" || "$python" -m venv "$venv"
pip="$venv/bin/pip"
"$pip" install -q --upgrade pip
tools/install_torch.sh "$pip"
torch=$("$venv/bin/python" -c "import torch; print(torch.__version__)")
pins=$(mktemp)
trap 'rm -f "$pins"' EXIT
echo "torch==$torch" > "$pins"
# torchvision matching torch 2.13 (LeRobot's dataset code imports its transforms; no compiled op is used)
"$pip" install -q --no-deps "torchvision==0.28.0"
"$pip" install -q -c "$pins" "datasets>=4,<5" "huggingface-hub>=0.34.2,<0.36" "accelerate>=1.10,<2" "av>=15,<16" \
  "jsonlines>=4,<5" "packaging>=24.2,<26" "draccus==0.10.0" "deepdiff>=7,<9" "termcolor>=2.4,<4" "einops>=0.8,<0.9" \
  "imageio[ffmpeg]>=2.34,<3" "setuptools>=71,<81" pandas pillow pytest
"$pip" install -q --no-deps "lerobot==0.4.4"
# The registry's torchvision wheels are CUDA builds: their compiled ops need libtorch_cuda, which the CPU torch lacks,
# so they do not load, and torchvision 0.28 then fails at import registering fake kernels for ops that do not
# exist ("operator torchvision::nms does not exist"). LeRobot's dataset code uses none of those ops (only
# transforms): register them only where the compiled ops loaded.
"$venv/bin/python" - <<'PY'
import importlib.util, pathlib
root = pathlib.Path(importlib.util.find_spec("torchvision").submodule_search_locations[0])
for name in ("_meta_registrations", "_autograd_registrations"):
    module, kept = root / f"{name}.py", root / f"{name}_when_ops.py"
    if not kept.exists():
        module.rename(kept)
        module.write_text(f"from torchvision.extension import _has_ops\n\nif _has_ops():\n"
                          f"    from torchvision.{name}_when_ops import *  # noqa: F403\n")
PY
"$venv/bin/python" -W ignore -c "from lerobot.datasets.lerobot_dataset import LeRobotDataset"
touch "$venv/.simreel-lerobot"
