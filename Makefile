# NewtPhys: every target creates .venv inside the repo and installs what it needs.
PYTHON ?= $(shell command -v python3.11 2>/dev/null || command -v python3)
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
TORCH  := torch==2.14.1 torchvision==0.29.1
PYTEST_ARGS ?=

.PHONY: install test test-all demo bench mutate clean

$(STAMP): pyproject.toml
	$(PYTHON) -c 'import sys; assert sys.version_info[:2] >= (3, 11), "NewtPhys needs Python >= 3.11, found " + sys.version'
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet $(TORCH)
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

install: $(STAMP)

## The default test run (CI): everything but tests marked slow.
test: install
	WANDB_MODE=offline HF_HUB_OFFLINE=1 $(PY) -m pytest -m "not slow" $(PYTEST_ARGS)

test-all: install
	WANDB_MODE=offline HF_HUB_OFFLINE=1 $(PY) -m pytest $(PYTEST_ARGS)

## The main job on the embedded default: see README.
demo: install
	$(PY) demo.py

bench: install
	for b in bench/bench_*.py; do $(PY) $$b --quick || exit 1; done

## Plant each label bug of tools/mutants.py in a temporary copy and run its tests: see README, "Tests".
mutate: install
	WANDB_MODE=offline HF_HUB_OFFLINE=1 $(PY) tools/mutate.py --json bench/results/mutate.json

clean:
	rm -rf $(VENV) demo_out outputs multirun .pytest_cache
