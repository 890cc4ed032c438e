# The commands of the README. Each creates .venv when missing and (re)installs the project from the lock
# file when requirements.lock or pyproject.toml is newer than the last install, then runs.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# Exact versions of every package `make` installs (the metaworld, interop and dev extras included; the bench
# extra's transformers is not locked). Regenerate with `make lock` after changing a dependency in
# pyproject.toml, or to move to newer releases; then run `make test` and commit the lock.
LOCK := requirements.lock
EXTRAS := metaworld,interop,dev
# Lightning/W&B must never try to reach the network from here; tests disable W&B entirely.
export WANDB_MODE ?= offline

.PHONY: run test test-fast lint bench clean-data reproduce smoke lock

# The lock's pins (numpy, scipy, matplotlib, ...) need Python 3.11: say so before pip fails to find them.
$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "make: $(LOCK) needs Python \
	>= 3.11, and $(PYTHON) is $$($(PYTHON) --version 2>&1); run make PYTHON=python3.11 ..." >&2; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

# One resolve of the lock's pins and the project's own bounds: a pin that breaks a bound is an error here.
$(STAMP): $(LOCK) pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -r $(LOCK) -e ".[$(EXTRAS)]"
	touch $(STAMP)

# Resolve pyproject.toml's ranges afresh in a throwaway venv and pin what got installed. torch is written
# as the public 2.13.0 (the local "+cpu" of this machine's wheel would not resolve elsewhere), and a
# CUDA dependency (nvidia-*) in the result is an error: the lock is the CPU build's set.
lock:
	@tmp=$$(mktemp -d) && trap 'rm -rf "$$tmp"' EXIT && \
	$(PYTHON) -m venv "$$tmp/venv" && \
	"$$tmp/venv/bin/pip" install --quiet --upgrade pip && \
	"$$tmp/venv/bin/pip" install --quiet -e ".[$(EXTRAS)]" && \
	"$$tmp/venv/bin/pip" freeze --all --exclude pip --exclude-editable | sed 's/^\(torch==[^+]*\)+.*/\1/' \
		> "$$tmp/pins" && \
	if grep -i '^nvidia-' "$$tmp/pins"; then echo "make lock: the resolve pulled CUDA packages (above)" >&2; exit 1; fi && \
	{ echo "# Exact versions of every package 'make' installs: the project's dependencies with the $(EXTRAS)"; \
	  echo "# extras, resolved by 'make lock' (Python $$("$$tmp/venv/bin/python" -c 'import platform; print(platform.python_version(), platform.system(), platform.machine())'))."; \
	  echo "# Edit pyproject.toml, not this file; after a change there run 'make lock' and commit both."; \
	  cat "$$tmp/pins"; } > $(LOCK)
	@echo "wrote $(LOCK) ($$(grep -c '==' $(LOCK)) pins)"

run: $(STAMP)
	$(BIN)/icprl fit --config configs/icpo_metaworld.yaml

test: $(STAMP)
	WANDB_MODE=disabled $(BIN)/python -m pytest -q

# The whole pipeline in about two minutes: data generation, training with the held-out rollout table
# each epoch, the checkpoint, and its deployment through load_agent by `icprl evaluate` (own and flipped
# labels). Everything lands in a fresh runs/smoke/<time>-<pid>/ (the dataset under data/smoke/, reused by
# the next smoke run). One thread: the model is small, and a second one only spins on 2 shared cores.
smoke: $(STAMP)
	@run=runs/smoke/$$(date +%Y%m%d-%H%M%S)-$$$$ && \
	echo "== 1/3 data + training: icprl fit --config configs/smoke.yaml (run directory $$run) ==" && \
	OMP_NUM_THREADS=1 $(BIN)/icprl fit --config configs/smoke.yaml --trainer.default_root_dir $$run \
		--trainer.logger.init_args.save_dir $$run && \
	ckpt=$$(find $$run -name last.ckpt) && \
	if [ ! -f "$$ckpt" ]; then echo "make smoke: fit wrote no single last.ckpt under $$run" >&2; exit 1; fi && \
	echo "== 2/3 deployment: icprl evaluate loads $$ckpt through load_agent on held-out tasks ==" && \
	OMP_NUM_THREADS=1 $(BIN)/icprl evaluate --run ICPO=configs/smoke.yaml:$$ckpt --contexts own flipped_labels \
		--seeds 0 --title "make smoke: ICPO on DarkRoom I-PRL" --out $$run/evaluation > $$run/evaluation.log && \
	echo "== 3/3 held-out returns of the deployed checkpoint ($$run/evaluation.md, .json, .png) ==" && \
	cat $$run/evaluation.md && \
	echo "learning curves: icprl report $$run"

# The fast tier, the developer loop, on two pytest-xdist workers of one thread each; `make test` runs every test
# in one process, as CI does.
test-fast: $(STAMP)
	OMP_NUM_THREADS=1 WANDB_MODE=disabled $(BIN)/python -m pytest -q -n 2 -m "not slow"

# make reproduce TABLE=darkroom_ipref: train 3 seeds per method and write docs/results/<TABLE>* (icprl reproduce --list)
reproduce: $(STAMP)
	$(BIN)/icprl reproduce $(TABLE)

lint: $(STAMP)
	$(BIN)/ruff check icprl_lightning tests benchmarks

bench: $(STAMP)
	$(BIN)/python benchmarks/darkroom_generation.py

# The documentation site (mkdocs.yml): `make docs` builds it into site/ and fails on any broken link or missing
# page; `make docs-serve` serves it at http://127.0.0.1:8000 and rebuilds on every change.
.PHONY: docs docs-serve
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

docs-serve: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs serve
