#!/usr/bin/env bash
# bench/pareto.py on a GPU machine that has torch but no nerfstudio (the lent H100/H200):
#
#   bench/gpu_pareto.sh OUT [pareto.py args...]
#
# Installs .whl/ and the project (bench/gpu_install.sh), generates the streets with every core, then
# runs bench/pareto.py with the arguments given; OUT receives pareto.log (each point's row as it
# finishes) and whatever --table / --plot name there. open3d does not fit a device call, so
# instances come from tracks exported here (--import-tracks DIR: idsplat-preprocess --data STREET
# --export DIR/<street>.json). gsplat is compiled first (minutes) unless --camera-backend torch is given.
#
#   bench/gpu_pareto.sh OUT --seeds 100 --import-tracks .gpu/tracks --camera-backend torch \
#       --points "steps-1500 (idsplat-fast)" --table OUT/gpu_pareto.md --plot OUT/gpu_pareto.png
set -u
OUT=${1:?usage: bench/gpu_pareto.sh OUT [pareto.py args...]}
shift
PY=${PYTHON:-python3}
mkdir -p "$OUT"
T0=$(date +%s)
stamp() { echo "[$(( $(date +%s) - T0 )) s] $*" | tee -a "$OUT/summary.log"; }

. "$(dirname "$0")/gpu_install.sh"
$PY -c "import torch; print('device:', torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'cpu', 'torch', torch.__version__)"

WORK=${PARETO_WORK:-/tmp/pareto}
PRESET=small SEEDS=100
prev=""
for a in "$@"; do  # the streets pareto.py will train on, to generate them here with every core
    case "$prev" in --preset) PRESET=$a ;; esac
    prev=$a
done
SEEDS=$(printf '%s\n' "$@" | awk '/^--/ {on = ($0 == "--seeds"); next} on')
for seed in ${SEEDS:-100}; do
    [ -d "$WORK/streets/synth_${PRESET}_$seed" ] && continue
    $PY -m idsplat_ns.data.synthetic.cli --preset "$PRESET" --seed "$seed" --out "$WORK/streets" \
        --workers "$(nproc)" --quiet || exit 1
    stamp "street $PRESET $seed generated"
done
case " $* " in
    *" --camera-backend torch "*) ;;
    *)  export MAX_JOBS=${MAX_JOBS:-$(nproc)} TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0}
        $PY -c "from gsplat.cuda._backend import _C; print('gsplat compiled:', _C is not None)" || exit 1
        stamp "gsplat compiled" ;;
esac
PYTHONUNBUFFERED=1 $PY -m bench.pareto --work "$WORK" "$@" 2>&1 | tee "$OUT/pareto.log"
stamp "pareto.py ended with ${PIPESTATUS[0]}"
