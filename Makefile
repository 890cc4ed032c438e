# The two commands of the README. Each creates .venv when missing and (re)installs the project when
# pyproject.toml is newer than the last install, then runs.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Lightning/W&B must never try to reach the network from here; tests disable W&B entirely.
export WANDB_MODE ?= offline

.PHONY: run test test-fast lint bench clean-data reproduce

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e ".[metaworld,dev]"
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/icprl fit --config configs/icpo_metaworld.yaml

test: $(STAMP)
	WANDB_MODE=disabled $(BIN)/python -m pytest -q

test-fast: $(STAMP)
	WANDB_MODE=disabled $(BIN)/python -m pytest -q -m "not slow"

# make reproduce TABLE=darkroom_ipref: train 3 seeds per method and write docs/results/<TABLE>* (icprl reproduce --list)
reproduce: $(STAMP)
	$(BIN)/icprl reproduce $(TABLE)

lint: $(STAMP)
	$(BIN)/ruff check icprl_lightning tests benchmarks

bench: $(STAMP)
	$(BIN)/python benchmarks/darkroom_generation.py
