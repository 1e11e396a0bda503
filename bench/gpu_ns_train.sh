#!/usr/bin/env bash
# ns-train idsplat (the paper's settings) and ns-eval on a GPU machine that has torch but no
# nerfstudio, with a wall-clock limit on each training, engines and camera backends side by side:
#
#   bench/gpu_ns_train.sh OUT [TRAIN_SECONDS] [PRESET] [SEED] [MODE] [ns-train args...]
#
# The wheels the machine lacks (nerfstudio, gsplat, GTSAM...: bench/gpu_wheels.sh makes them here)
# are expected in .whl/ (WHEELS=none where the environment has everything). open3d does not fit a
# device call, so the instance mode defaults to oracle (annotation boxes: no registration, which
# needs open3d).
#
# BACKENDS (default "auto", or "torch" with GSPLAT=0) lists the camera backends
# (--pipeline.model.camera-backend) this checkout's engine is trained with, one whole training
# each. AGAINST_TREE=DIR (another revision's idsplat_ns and method_configs: git archive REV
# idsplat_ns method_configs | tar -x -C DIR) trains and evaluates that engine the same way, with
# the first backend, right after this engine's first training (run from inside DIR, whose packages
# `python -m` then imports first). Each training is stopped (SIGINT) after TRAIN_SECONDS and its
# last checkpoint (one every SAVE_EVERY steps) is evaluated.
# gsplat's CUDA code is compiled in the background from the start (GSPLAT=0: no build) while the
# street is generated; the trainings start once it is built (a training step is bound by the host:
# beside a compiler on 10 of 16 cores the same step took 1.5 times as long,
# docs/reports/2026-11-28-gpu-ns-train.md). TIME_DURING_BUILD=1 lets the torch-backend trainings
# run during the build, on the cores it leaves, for a call short of time. GPU_TESTS=1 runs gsplat's
# and the Triton compositor's parity tests once gsplat is built (pytest.log).
# Every step's time is logged (--logging.max-buffer-size 1) and nvidia-smi samples the GPU's
# memory every 2 s; bench/train_run_times.py then writes OUT/step_times.md: the median step over
# steps STEP_FROM..STEP_TO (default 100..400), the peak GPU memory of each training and its ns-eval.
# A training starts only while BUDGET_SECONDS (default 560) after the start leave it TRAIN_MIN
# (default 150) seconds; it is cut to end 60 s before the budget, leaving its ns-eval time (at most
# EVAL_MAX, default 100 s).
# LIDAR_AGAINST=DIR (a source tree of another revision, see bench/bench_lidar_render.py) times a
# training lidar batch of both beside each other (lidar_render.md) before the trainings.
# OUT receives summary.log, step_times.md, step_times.json and logs.tar.gz (every training's log,
# events, eval.json and eval.log).
set -u
OUT=${1:?usage: bench/gpu_ns_train.sh OUT [TRAIN_SECONDS] [PRESET] [SEED] [MODE] [ns-train args...]}
SECS=${2:-300}
PRESET=${3:-bench}
SEED=${4:-100}
MODE=${5:-oracle}
shift $(( $# < 5 ? $# : 5 ))
TRAIN_ARGS=("$@")
PY=${PYTHON:-python3}
BUDGET=${BUDGET_SECONDS:-560}
mkdir -p "$OUT/logs"
OUT=$(cd "$OUT" && pwd)
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*" | tee -a "$OUT/summary.log"; }
left() { echo $(( BUDGET - ($(date +%s) - T0) )); }
finish() {
    [ -n "${SMI:-}" ] && kill "$SMI" 2>/dev/null
    $PY -m bench.train_run_times "$OUT/logs" --steps "${STEP_FROM:-100}" "${STEP_TO:-400}" --out "$OUT" >>"$OUT/summary.log" 2>&1
    cat "$OUT/step_times.md" 2>/dev/null
    tar -czf "$OUT/logs.tar.gz" -C "$OUT" logs && rm -rf "$OUT/logs"
    stamp "done"
}
trap finish EXIT
export PYTHONUNBUFFERED=1

. "$(dirname "$0")/gpu_install.sh"

if [ "${GSPLAT:-1}" = 0 ]; then
    read -r -a BACKEND_LIST <<<"${BACKENDS:-torch}"
else
    read -r -a BACKEND_LIST <<<"${BACKENDS:-auto}"
fi
BUILD=
if $PY -c 'import torch, sys; sys.exit(0 if torch.cuda.is_available() else 1)'; then
    (while sleep 2; do echo "$(date +%s) $(nvidia-smi --query-gpu=memory.used --format=csv,noheader,nounits)"; done) \
        >"$OUT/logs/gpu_memory.txt" 2>/dev/null &
    SMI=$!
    if [ "${GSPLAT:-1}" = 1 ]; then
        # Every core, unless trainings run beside the build (their steps are bound by the host).
        JOBS=$(nproc)
        [ "${TIME_DURING_BUILD:-0}" = 1 ] && JOBS=$(( JOBS > 8 ? JOBS - 6 : JOBS ))
        export MAX_JOBS=${MAX_JOBS:-$JOBS} TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
        $PY -c "import time; t = time.time(); from gsplat.cuda._backend import _C; print('gsplat built', _C is not None, round(time.time() - t), 's')" \
            >"$OUT/logs/gsplat_build.log" 2>&1 &
        BUILD=$!
    fi
fi

export IDSPLAT_CACHE=${IDSPLAT_CACHE:-/tmp/idsplat_cache}
$PY -m idsplat_ns.data.synthetic.cli --preset "$PRESET" --seed "$SEED" --out "$IDSPLAT_CACHE/synthetic" \
    --workers "${STREET_WORKERS:-6}" --quiet >"$OUT/logs/street.log" 2>&1 || { stamp "street generation failed"; tail -20 "$OUT/logs/street.log"; exit 1; }
stamp "street $PRESET $SEED generated"
if [ -n "${LIDAR_AGAINST:-}" ]; then  # a source tree of another revision: time its lidar batch beside this one
    $PY -m bench.bench_lidar_render --method idsplat --preset "$PRESET" --seed "$SEED" --threads 2 \
        --rounds "${LIDAR_ROUNDS:-2}" --batches "${LIDAR_BATCHES:-6}" \
        --against-tree "$LIDAR_AGAINST" --out "$OUT/lidar_render.md" >"$OUT/logs/lidar_render.log" 2>&1
    stamp "lidar batch bench ended with $?"
fi

wait_for_gsplat() {
    [ -n "$BUILD" ] || return 0
    wait "$BUILD" || { stamp "gsplat build failed: $(tail -1 "$OUT/logs/gsplat_build.log")"; BUILD=; return 1; }
    BUILD=
    stamp "$(tail -1 "$OUT/logs/gsplat_build.log")"
    if [ "${GPU_TESTS:-0}" = 1 ]; then
        timeout 120 $PY -m pytest -q -p no:cacheprovider tests/test_render_gsplat.py tests/test_triton_composite.py \
            >"$OUT/logs/pytest.log" 2>&1
        stamp "gsplat and Triton parity tests ended with $? ($(tail -1 "$OUT/logs/pytest.log"))"
    fi
}

# train_and_eval DIR TAG BACKEND: ns-train then ns-eval from inside DIR (its packages first),
# results in $OUT/logs/TAG.
train_and_eval() {
    local dir=$1 tag=$2 backend=$3 run=/tmp/idsplat_runs/$2 res=$OUT/logs/$2
    local budget; budget=$(left)
    if [ "$budget" -lt "${TRAIN_MIN:-150}" ]; then stamp "$tag: skipped, $budget s left"; return 1; fi
    local secs=$(( SECS < budget - 60 ? SECS : budget - 60 ))
    mkdir -p "$res"
    local t0; t0=$(date +%s)
    (cd "$dir" && timeout -s INT "$secs" $PY -c 'import sys; from nerfstudio.scripts.train import entrypoint; sys.argv[0] = "ns-train"; entrypoint()' \
        idsplat --vis tensorboard --output-dir "$run" --experiment-name gpu --timestamp run \
        --steps-per-save "${SAVE_EVERY:-500}" --logging.max-buffer-size 1 \
        --pipeline.datamanager.instance-mode "$MODE" --pipeline.model.camera-backend "$backend" "${TRAIN_ARGS[@]}" \
        idsplat-builtin --preset "$PRESET" --seed "$SEED" >"$res/train.log" 2>&1)
    local rc=$? t1; t1=$(date +%s)
    stamp "$tag: ns-train ($backend) ended with $rc after $(( t1 - t0 )) s"
    printf '{"tag": "%s", "engine": "%s", "backend": "%s", "start": %d, "end": %d, "train_rc": %d}\n' \
        "$tag" "$dir" "$backend" "$t0" "$t1" "$rc" >"$res/run.json"
    local base="$run/gpu/idsplat/run"
    cp "$base"/events.out.tfevents.* "$res/" 2>/dev/null
    local last; last=$(ls "$base/nerfstudio_models" 2>/dev/null | sort | tail -1)
    stamp "$tag: last checkpoint: ${last:-none}"
    [ -n "$last" ] || { tail -40 "$res/train.log"; return 1; }
    local eval_secs; eval_secs=$(left); eval_secs=$(( eval_secs < ${EVAL_MAX:-100} ? eval_secs : ${EVAL_MAX:-100} ))
    (cd "$dir" && timeout "$(( eval_secs > 30 ? eval_secs : 30 ))" $PY -c 'import sys; from nerfstudio.scripts.eval import entrypoint; sys.argv[0] = "ns-eval"; entrypoint()' \
        --load-config "$base/config.yml" --output-path "$res/eval.json" >"$res/eval.log" 2>&1)
    stamp "$tag: ns-eval ended with $?"
    rm -rf "$run"  # a checkpoint at the paper's size is hundreds of MB
}

for i in "${!BACKEND_LIST[@]}"; do
    backend=${BACKEND_LIST[$i]}
    if [ "$backend" != torch ] || [ "${TIME_DURING_BUILD:-0}" != 1 ]; then
        wait_for_gsplat || [ "$backend" = torch ] || continue
    fi
    train_and_eval "$PWD" "this-$backend" "$backend"
    if [ "$i" = 0 ] && [ -n "${AGAINST_TREE:-}" ]; then
        [ -d "$AGAINST_TREE/idsplat_ns" ] || { stamp "AGAINST_TREE=$AGAINST_TREE has no idsplat_ns/"; exit 1; }
        train_and_eval "$(cd "$AGAINST_TREE" && pwd)" "against-$backend" "$backend"
    fi
done
[ "${GPU_TESTS:-0}" = 1 ] && [ -n "$BUILD" ] && wait_for_gsplat
