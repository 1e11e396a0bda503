#!/usr/bin/env bash
# Download, here, the Python 3.12 wheels that `ns-train idsplat` needs on a GPU machine whose image has
# torch, numpy, scipy, pandas, scikit-learn, OpenCV, onnxruntime, transformers and tensorboard but
# not nerfstudio (the lent H100/H200 machines): nerfstudio and what it imports, gsplat, GTSAM and the
# project's other pure-Python dependencies. open3d (about 400 MB) is left out: registration and
# amodal centres need it, so a run there uses the oracle instance mode or a copied cache.
#
#   bench/gpu_wheels.sh [DIR]        # default .whl (about 60 MiB); then bench/gpu_ns_train.sh there
set -eu
DIR=${1:-.whl}
PY=${PYTHON:-.venv/bin/python}
mkdir -p "$DIR"
# Versions as this environment has them, so that the GPU run uses what the tests here use.
NAMES="nerfstudio tyro docstring_parser typeguard viser msgspec websockets nerfacc pathos dill multiprocess
ppft rawpy tensorly torch_fidelity gtsam colorcet pyquaternion pytorch_msssim splines appdirs janus truststore
nest_asyncio pydantic pydantic_core annotated_types typing_inspection lpips motmetrics xmltodict plyfile
google-crc32c gsplat"
PLATFORMS=""
for p in manylinux1_x86_64 manylinux2014_x86_64 manylinux_2_17_x86_64 manylinux_2_24_x86_64 manylinux_2_27_x86_64 \
         manylinux_2_28_x86_64 manylinux_2_31_x86_64 manylinux_2_34_x86_64 manylinux_2_35_x86_64; do
    PLATFORMS="$PLATFORMS --platform $p"
done
fetch() { $PY -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp $PLATFORMS -d "$DIR" "$@"; }
for name in $NAMES; do
    version=$($PY -m pip show "$name" 2>/dev/null | awk '/^Version:/ {print $2}')
    if [ -z "$version" ]; then
        echo "error: $name is not installed in $PY's environment; run make install first" >&2
        exit 1
    fi
    fetch "$name==$version" 2>/dev/null || fetch "$name"
done
# fpsample has no Python 3.12 wheel of the version used here; nerfstudio only imports it.
fetch fpsample
du -sh "$DIR"
