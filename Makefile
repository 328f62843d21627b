# Two commands for a new user: `make demo` and `make test`. Both (re)create .venv and
# install everything from PyPI by name when pyproject.toml changed. Setup includes the `train`
# extra (CPU PyTorch) so the posture-training tests run; the services themselves do not need it.
PYTHON ?= $(shell command -v python3.11 || command -v python3)
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
# Real mocap clips, read at run time from beside the repo (shared/paths.py reads the same setting).
MIMIC_MOCAP_DIR ?= ../shared/data/mocap

.PHONY: setup demo test test-docker lint format bench eval clean

setup: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev,train]"
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
