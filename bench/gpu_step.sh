#!/usr/bin/env bash
# The paper configuration's training step on a lent GPU machine that has torch but no nerfstudio,
# engines side by side in one call:
#
#   bench/gpu_step.sh OUT [SEED]          # .whl/ (bench/gpu_wheels.sh) carried; WHEELS=none where all is there
#
# 1. installs the wheels and the project (bench/gpu_install.sh); gsplat's CUDA build runs in the
#    background while the built-in street is generated and stages 2-3 run;
# 2. the Triton compositor's parity tests on the GPU (tests/test_triton_composite.py);
# 3. one training lidar batch of `idsplat` (render, losses, backward) with the torch and the Triton
#    compositor (bench/bench_lidar_render.py --compositors torch triton);
# 4. gsplat's parity tests once it is built (tests/test_render_gsplat.py);
# 5. `idsplat` training steps at the paper's size on that street, from step 100: (camera rasterizer,
#    lidar compositor) pairs take turns on one trainer, ROUNDS times STEPS steps each
#    (bench/profile_train_step.py --variants; tile-torch:torch is the engine before the Triton
#    compositor); median step time, ratio and peak GPU memory; then 4 steps of the last pair under
#    torch.profiler (torch_profile.txt: device time by operator, host synchronisations a step).
#    With AGAINST_TREE=DIR, another revision's engine (DIR holds its idsplat_ns and method_configs:
#    git archive REV idsplat_ns method_configs | tar -x -C DIR) is timed first, with the same
#    variants on its own trainer of the same street and seed (step_times_against.md).
# Knobs (environment): PRESET, STEPS, ROUNDS, VARIANTS, LIDAR_COMPOSITORS ("" skips stage 3), GSPLAT=0
# (no build, stage 4 skipped), STREET_WORKERS, TORCH_PROFILE_STEPS, BUDGET_SECONDS, AGAINST_TREE.
# OUT receives summary.log, lidar_batch.md, step_times.md, step_times.json, torch_profile.txt and logs.tar.gz. Stage 5
# stops BUDGET_SECONDS (560) after the start, with the rows timed so far.
set -u
OUT=${1:?usage: bench/gpu_step.sh OUT [SEED]}
SEED=${2:-100}
PRESET=${PRESET:-small}
STEPS=${STEPS:-25}
ROUNDS=${ROUNDS:-3}
VARIANTS=${VARIANTS:-tile-torch:torch tile-torch:triton gsplat:torch gsplat:triton tile-triton:triton}
LIDAR_COMPOSITORS=${LIDAR_COMPOSITORS-torch triton}
PY=${PYTHON:-python3}
mkdir -p "$OUT" "$OUT/logs"
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*" | tee -a "$OUT/summary.log"; }
finish() { tar -czf "$OUT/logs.tar.gz" -C "$OUT" logs && rm -rf "$OUT/logs"; stamp "done"; }
trap finish EXIT
export PYTHONUNBUFFERED=1

. "$(dirname "$0")/gpu_install.sh"
$PY -c 'import torch, triton; print("torch", torch.__version__, "triton", triton.__version__, torch.cuda.get_device_name(0))' \
    | tee -a "$OUT/summary.log"

BUILD=
if [ "${GSPLAT:-1}" = 1 ]; then  # GSPLAT=0: no build (minutes), no gsplat tests; leave gsplat out of VARIANTS
    export MAX_JOBS=${MAX_JOBS:-$(( $(nproc) > 4 ? $(nproc) - 2 : $(nproc) ))} TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
    $PY -c "import time; t = time.time(); from gsplat.cuda._backend import _C; print('gsplat built', _C is not None, round(time.time() - t), 's')" \
        >"$OUT/logs/gsplat_build.log" 2>&1 &
    BUILD=$!
fi

export IDSPLAT_CACHE=${IDSPLAT_CACHE:-/tmp/idsplat_cache}
$PY -m idsplat_ns.data.synthetic.cli --preset "$PRESET" --seed "$SEED" --out "$IDSPLAT_CACHE/synthetic" \
    --workers "${STREET_WORKERS:-4}" --quiet >"$OUT/logs/street.log" 2>&1 || { stamp "street generation failed"; tail -20 "$OUT/logs/street.log"; exit 1; }
stamp "street $PRESET $SEED generated"

timeout 240 $PY -m pytest -q -p no:cacheprovider tests/test_triton_composite.py >"$OUT/logs/triton_tests.log" 2>&1
stamp "Triton compositor parity tests ended with $? ($(tail -1 "$OUT/logs/triton_tests.log"))"

if [ -n "$LIDAR_COMPOSITORS" ]; then  # LIDAR_COMPOSITORS="": no lidar batch bench
    # shellcheck disable=SC2086  # LIDAR_COMPOSITORS is a list
    timeout 240 $PY -m bench.bench_lidar_render --method idsplat --preset "$PRESET" --seed "$SEED" --threads 2 \
        --compositors $LIDAR_COMPOSITORS --rounds 2 --batches 6 --warmup 2 --out "$OUT/lidar_batch.md" >"$OUT/logs/lidar_batch.log" 2>&1
    stamp "lidar batch bench ended with $?"
    cat "$OUT/lidar_batch.md" 2>/dev/null
fi

if [ -n "$BUILD" ]; then
    wait "$BUILD"
    stamp "gsplat build: $(tail -1 "$OUT/logs/gsplat_build.log")"
    timeout 120 $PY -m pytest -q -p no:cacheprovider tests/test_render_gsplat.py >"$OUT/logs/gsplat_tests.log" 2>&1
    stamp "gsplat parity tests ended with $? ($(tail -1 "$OUT/logs/gsplat_tests.log"))"
fi

STEP_ARGS="--method idsplat --preset $PRESET --seed $SEED --start-step 100 --warmup 2 --steps $STEPS --rounds $ROUNDS"
if [ -n "${AGAINST_TREE:-}" ]; then
    [ -d "$AGAINST_TREE/idsplat_ns" ] || { stamp "AGAINST_TREE=$AGAINST_TREE has no idsplat_ns/"; exit 1; }
    # Half of what the call has left. Run from inside the tree: `python -m` puts the working
    # directory first on the path, so its idsplat_ns and method_configs are the ones imported, and
    # this checkout (on PYTHONPATH) gives the bench scripts.
    LEFT=$(( (${BUDGET_SECONDS:-560} - ($(date +%s) - T0)) / 2 ))
    OUT_ABS=$(cd "$OUT" && pwd)
    # shellcheck disable=SC2086  # STEP_ARGS and VARIANTS are lists
    (cd "$AGAINST_TREE" && timeout "$(( LEFT > 30 ? LEFT : 30 ))" $PY -m bench.profile_train_step \
        $STEP_ARGS --variants $VARIANTS --out "$OUT_ABS/logs/steps_against" >"$OUT_ABS/logs/steps_against.log" 2>&1)
    stamp "training steps of $AGAINST_TREE's engine ended with $?"
    cp "$OUT/logs/steps_against/step_times.md" "$OUT/step_times_against.md" 2>/dev/null
    cp "$OUT/logs/steps_against/step_times.json" "$OUT/step_times_against.json" 2>/dev/null
    cat "$OUT/step_times_against.md" 2>/dev/null || tail -30 "$OUT/logs/steps_against.log"
fi

# shellcheck disable=SC2086  # VARIANTS is a list
LEFT=$(( ${BUDGET_SECONDS:-560} - ($(date +%s) - T0) ))  # what the call has left; a killed run keeps its rows
timeout "$(( LEFT > 30 ? LEFT : 30 ))" $PY -m bench.profile_train_step $STEP_ARGS --variants $VARIANTS \
    --torch-profile "${TORCH_PROFILE_STEPS:-4}" --out "$OUT/logs/steps" >"$OUT/logs/steps.log" 2>&1
stamp "training steps ended with $?"
cp "$OUT/logs/steps/step_times.md" "$OUT/logs/steps/step_times.json" "$OUT/logs/steps/torch_profile.txt" "$OUT/" 2>/dev/null
cat "$OUT/step_times.md" 2>/dev/null || tail -30 "$OUT/logs/steps.log"
