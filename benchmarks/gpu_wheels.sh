#!/usr/bin/env bash
# Download the CPython 3.12 manylinux x86_64 wheels that benchmarks/gpu.py needs on a machine that
# has only Python 3.12 and a CUDA torch (no package registry), into a folder, and list their sizes.
#
#   benchmarks/gpu_wheels.sh [FOLDER]          # default: gpu_wheels/ (git-ignored)
#
# Two tiers (each wheel without its dependencies; the lists are the complete sets the imports need):
#   train   what `import compensation` needs beside torch: enough for the training part;
#   render  mitsuba/drjit and what `import sim` needs for a render of a suite setup.
# On the GPU machine:
#   python -m pip install --no-index --no-deps FOLDER/train/*.whl [FOLDER/render/*.whl]
#   python benchmarks/gpu.py
# Without the render tier gpu.py skips the render and transport parts with a message.
set -euo pipefail
DEST=${1:-gpu_wheels}
PY=${PYTHON:-python3}
TRAIN=(numpy scipy tqdm)
RENDER=(mitsuba==3.9.1 drjit==1.5.0 colour-science opencv-python-headless imageio tomli-w
        matplotlib cycler fonttools kiwisolver pyparsing python-dateutil six packaging pillow
        scikit-image lazy-loader charset-normalizer)
fetch() {  # fetch TIER PACKAGE...
    local tier=$1; shift
    mkdir -p "$DEST/$tier"
    "$PY" -m pip download --quiet --no-deps --only-binary=:all: --dest "$DEST/$tier" \
        --python-version 3.12 --implementation cp --abi cp312 --abi abi3 --abi none \
        --platform manylinux2014_x86_64 --platform manylinux_2_17_x86_64 \
        --platform manylinux_2_28_x86_64 --platform any "$@"
}
fetch train "${TRAIN[@]}"
fetch render "${RENDER[@]}"
for tier in train render; do
    echo "== $tier: $(du -cb "$DEST/$tier"/*.whl | tail -1 | cut -f1 | awk '{printf "%.1f MiB", $1 / 1048576}')"
    ls -l "$DEST/$tier"/*.whl | awk '{printf "%8.1f MiB  %s\n", $5 / 1048576, $9}' | sort -rn
done
