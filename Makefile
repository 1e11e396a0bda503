# idsplat_ns: `make demo` (install, train on the built-in street, evaluate) and `make test`.
PYTHON ?= python3.11
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.idsplat-installed
DEMO   := outputs/demo

.PHONY: install browser test test-fast demo bench clean

# torch is installed first and alone: `torch==2.13.0` takes the CPU wheel where one is provided,
# so no later requirement can pull the multi-GB CUDA build.
$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(0 if (3, 10) <= sys.version_info[:2] < (3, 13) else 1)' \
		|| { echo "error: $(PYTHON) is not Python 3.10-3.12; run make with PYTHON=python3.11 (or 3.10/3.12)"; exit 2; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip setuptools wheel
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -e ".[test]"
	$(BIN)/idsplat-install-compat
	touch $(STAMP)

install: $(STAMP)

# The viewer's browser test drives a headless Chromium (the Debian package; nothing is downloaded).
# Installed here where apt can do it; elsewhere that test says in one line what to install.
browser:
	@command -v chromium >/dev/null 2>&1 || command -v chromium-browser >/dev/null 2>&1 \
		|| { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1 \
		     && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium >/dev/null; } \
		|| echo "note: no Chromium (apt-get install -y chromium); tests/test_viewer_browser.py will fail"

test: install browser
	$(BIN)/python -m pytest -q -p no:cacheprovider --durations=25

test-fast: install
	$(BIN)/python -m pytest -q -p no:cacheprovider -m "not slow"

demo: install
	$(BIN)/ns-train idsplat-fast --vis tensorboard --output-dir outputs --experiment-name demo --timestamp run
	$(BIN)/ns-eval --load-config $(DEMO)/idsplat-fast/run/config.yml \
		--output-path $(DEMO)/eval.json --render-output-path $(DEMO)/renders
	$(BIN)/idsplat-report $(DEMO)/eval.json --renders $(DEMO)/renders \
		--checkpoint-dir $(DEMO)/idsplat-fast/run/nerfstudio_models

bench: install
	$(BIN)/python -m bench.bench_rasterizer

clean:
	rm -rf $(VENV) outputs .pytest_cache
