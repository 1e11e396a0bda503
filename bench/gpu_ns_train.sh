#!/usr/bin/env bash
# ns-train idsplat (the paper's settings) and ns-eval on a GPU machine that has torch but no
# nerfstudio, with a wall-clock limit on the training:
#
#   bench/gpu_ns_train.sh OUT [TRAIN_SECONDS] [PRESET] [SEED] [MODE] [ns-train args...]
#
# The wheels the machine lacks (nerfstudio, gsplat, GTSAM...: bench/gpu_wheels.sh makes them here)
# are expected in .whl/ (WHEELS=none where the environment has everything). open3d does not fit a
# device call, so the instance mode defaults to oracle (annotation boxes: no registration, which
# needs open3d).
# gsplat's CUDA code is compiled while the street is generated (GSPLAT=0: no build, and the camera
# through the tile rasterizer, --pipeline.model.camera-backend torch). The run saves a checkpoint
# every 500 steps (SAVE_EVERY); when TRAIN_SECONDS have passed it is stopped (SIGINT) and the last
# checkpoint is evaluated. OUT receives train.log, eval.json, gpu_memory.csv and summary.json.
# AGAINST_TREE=DIR (another revision's idsplat_ns and method_configs: git archive REV idsplat_ns
# method_configs | tar -x -C DIR) trains and evaluates that engine the same way first, into
# OUT/against/ (run from inside DIR, whose packages `python -m` then imports first).
# LIDAR_AGAINST=DIR (a source tree of another revision, see bench/bench_lidar_render.py) times a
# training lidar batch of both beside each other (lidar_render.md) while gsplat builds (it needs no
# gsplat; the build then leaves two cores to it). GPU_TESTS=1 runs gsplat's parity tests once it is
# built (pytest.log).
set -u
OUT=${1:?usage: bench/gpu_ns_train.sh OUT [TRAIN_SECONDS] [PRESET] [SEED] [MODE] [ns-train args...]}
SECS=${2:-300}
PRESET=${3:-bench}
SEED=${4:-100}
MODE=${5:-oracle}
shift $(( $# < 5 ? $# : 5 ))
PY=${PYTHON:-python3}
mkdir -p "$OUT"
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*" | tee -a "$OUT/summary.log"; }

. "$(dirname "$0")/gpu_install.sh"

BACKEND=()
[ "${GSPLAT:-1}" = 0 ] && BACKEND=(--pipeline.model.camera-backend torch)
if [ "${GSPLAT:-1}" = 1 ] && $PY -c 'import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)'; then
    JOBS=$(nproc); [ -n "${LIDAR_AGAINST:-}" ] && JOBS=$(( JOBS > 4 ? JOBS - 2 : JOBS ))
    export MAX_JOBS=${MAX_JOBS:-$JOBS} TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
    $PY -c "from gsplat.cuda._backend import _C; print('gsplat compiled:', _C is not None)" >"$OUT/gsplat_build.log" 2>&1 &
    BUILD=$!
    (while sleep 2; do nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits; done) >"$OUT/gpu_memory.csv" 2>/dev/null &
    SMI=$!
fi

export IDSPLAT_CACHE=${IDSPLAT_CACHE:-/tmp/idsplat_cache}
$PY -m idsplat_ns.data.synthetic.cli --preset "$PRESET" --seed "$SEED" --out "$IDSPLAT_CACHE/synthetic" \
    --workers "$(nproc)" --quiet || exit 1
stamp "street $PRESET $SEED generated"
if [ -n "${LIDAR_AGAINST:-}" ]; then  # a source tree of another revision: time its lidar batch beside this one
    $PY -m bench.bench_lidar_render --method idsplat --preset "$PRESET" --seed "$SEED" --threads 2 \
        --rounds "${LIDAR_ROUNDS:-2}" --batches "${LIDAR_BATCHES:-6}" \
        --against-tree "$LIDAR_AGAINST" --out "$OUT/lidar_render.md" >"$OUT/lidar_render.log" 2>&1
    stamp "lidar batch bench ended with $?"
fi
if [ -n "${BUILD:-}" ]; then
    wait "$BUILD" || { stamp "gsplat build failed"; tail -30 "$OUT/gsplat_build.log"; exit 1; }
    stamp "$(tail -1 "$OUT/gsplat_build.log")"
fi
if [ "${GPU_TESTS:-0}" = 1 ]; then
    $PY -m pytest -q -p no:cacheprovider tests/test_render_gsplat.py >"$OUT/pytest.log" 2>&1
    stamp "gsplat parity tests ended with $? ($(tail -1 "$OUT/pytest.log"))"
fi

OUT=$(cd "$OUT" && pwd)
# train_and_eval DIR TAG: ns-train then ns-eval from inside DIR (its packages first), results in
# $OUT/$TAG (. for this checkout).
train_and_eval() {
    local dir=$1 tag=$2 run=/tmp/idsplat_runs/$2 res=$OUT/$2
    mkdir -p "$res"
    local t0; t0=$(date +%s)
    (cd "$dir" && timeout -s INT "$SECS" $PY -c 'import sys; from nerfstudio.scripts.train import entrypoint; sys.argv[0] = "ns-train"; entrypoint()' \
        idsplat --vis tensorboard --output-dir "$run" --experiment-name gpu --timestamp run --steps-per-save "${SAVE_EVERY:-500}" \
        --pipeline.datamanager.instance-mode "$MODE" "${BACKEND[@]}" "${TRAIN_ARGS[@]}" \
        idsplat-builtin --preset "$PRESET" --seed "$SEED" >"$res/train.log" 2>&1)
    local rc=$?
    TRAIN_S=$(( $(date +%s) - t0 ))
    stamp "$tag: ns-train ended with $rc after $TRAIN_S s"
    CONFIG="$run/gpu/idsplat/run/config.yml"
    LAST=$(ls "$run/gpu/idsplat/run/nerfstudio_models" 2>/dev/null | sort | tail -1)
    stamp "$tag: last checkpoint: ${LAST:-none}"
    [ -n "$LAST" ] || { tail -40 "$res/train.log"; return 1; }
    (cd "$dir" && $PY -c 'import sys; from nerfstudio.scripts.eval import entrypoint; sys.argv[0] = "ns-eval"; entrypoint()' \
        --load-config "$CONFIG" --output-path "$res/eval.json" >"$res/eval.log" 2>&1)
    stamp "$tag: ns-eval ended with $?"
}

TRAIN_ARGS=("$@")
if [ -n "${AGAINST_TREE:-}" ]; then
    [ -d "$AGAINST_TREE/idsplat_ns" ] || { stamp "AGAINST_TREE=$AGAINST_TREE has no idsplat_ns/"; exit 1; }
    train_and_eval "$AGAINST_TREE" against
fi
train_and_eval "$PWD" . || exit 1
[ -n "${SMI:-}" ] && kill "$SMI"
$PY - "$OUT" "$LAST" "$TRAIN_S" "$PRESET" "$SEED" "$MODE" <<'EOF'
import json, sys, torch
out, last, train_s, preset, seed, mode = sys.argv[1:]
summary = {"checkpoint": last, "train_wall_s": int(train_s), "street": f"{preset} {seed}", "instance_mode": mode,
           "device": torch.cuda.get_device_name(0) if torch.cuda.is_available() else "cpu",
           "torch": torch.__version__}
try:
    mem = [int(x) for x in open(f"{out}/gpu_memory.csv").read().split()]
    summary["peak_gpu_memory_mib"] = max(mem)
except (OSError, ValueError):
    pass
json.dump(summary, open(f"{out}/summary.json", "w"), indent=1)
print(json.dumps(summary))
EOF
tail -25 "$OUT/eval.log"
