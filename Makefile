# Two commands for a new user: `make demo` and `make test`. Both (re)create .venv and
# install everything from PyPI by name when pyproject.toml changed. Setup includes the `train`
# extra (CPU PyTorch) so the posture-training tests run; the services themselves do not need it.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Real mocap clips, read at run time from beside the repo (shared/paths.py reads the same setting).
MIMIC_MOCAP_DIR ?= ../shared/data/mocap

.PHONY: setup demo test test-docker test-browser lint format bench eval clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev,train]"
	# Compile the solver's numba kernels into their cache now (~10 s of CPU), not in the first solver started.
	$(BIN)/python -m services.solver.hqp_kernel
	$(BIN)/python -m services.solver.tick_kernel
	touch $(STAMP)

demo: setup
	$(BIN)/mimic up --demo

test: setup
	$(BIN)/ruff check .
	$(BIN)/python -m pytest

# The stack in containers through `docker compose` (tests/docker). With podman (default) it installs
# podman, builds a local base image and mimic:latest as root; MIMIC_ENGINE=docker uses a running Docker.
test-docker: setup
	tests/docker/engine.sh

# A recording opened in the Rerun web viewer in headless Chromium (tests/logger/test_web_viewer.py).
# Installs Debian's chromium when missing (apt-get, as root); software WebGL, no display or GPU needed.
test-browser: setup
	@command -v "$${MIMIC_CHROMIUM:-chromium}" >/dev/null || { \
	  [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null \
	    || { echo "test-browser: chromium missing: install it (apt-get install chromium) or set MIMIC_CHROMIUM"; exit 1; }; \
	  DEBIAN_FRONTEND=noninteractive apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium; }
	$(BIN)/python -m pytest -p no:cacheprovider -m browser tests/logger/test_web_viewer.py

lint: setup
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: setup
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: setup
	$(BIN)/mimic bench solvers --json runs/bench_solvers.json
	$(BIN)/mimic bench pipeline --json runs/bench_pipeline.json

eval: setup
	$(BIN)/mimic eval $(MIMIC_MOCAP_DIR)/bvh/*.bvh --json runs/eval.json --plots runs/eval

clean:
	rm -rf $(VENV) runs .pytest_cache .ruff_cache
