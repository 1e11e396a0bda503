# Sourced by the GPU scripts (bench/gpu_ns_train.sh, bench/gpu_pareto.sh): on a machine that has torch
# but no nerfstudio, install the wheels of .whl/ (bench/gpu_wheels.sh makes them here; WHEELS=none
# where the environment has everything) and the project into $IDSPLAT_SITE (default /tmp/site), put
# both on PYTHONPATH and check that the run's imports work. Expects PY and a stamp function.
SITE=${IDSPLAT_SITE:-/tmp/site}
WHEELS=${WHEELS:-.whl}
if [ "$WHEELS" != none ] && ls "$WHEELS"/*.whl >/dev/null 2>&1; then
    $PY -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" "$WHEELS"/*.whl || exit 1
fi
export PYTHONPATH="$SITE:$PWD${PYTHONPATH:+:$PYTHONPATH}"
# The project itself, for nerfstudio's entry points (method and dataparsers).
$PY -m pip install -q --no-index --no-deps --no-build-isolation --no-cache-dir --upgrade --target "$SITE" . || exit 1
# That build leaves build/ and an egg-info here; a stale egg-info in the working directory would
# shadow the installed entry points (a new preset) for every Python started from it.
rm -rf build idsplat_ns.egg-info
stamp "installed"
# Fail in seconds, not after a build or a training, where this Python lacks something the run imports.
$PY -c "import method_configs.idsplat, nerfstudio.scripts.train, nerfstudio.scripts.eval" || exit 1
