# Two commands from a fresh clone (python3 + pip, ../shared beside the clone):
#   make run    - install into .venv, `dvc pull`, then `dvc repro` (the default profile) with one stage per core
#                 at a time (python -m motionsynth.repro; JOBS=1 runs one at a time, as plain `dvc repro`)
#   make test   - install into .venv (with test extras) and run the whole test suite
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
export DVC_NO_ANALYTICS := 1
export PATH := $(abspath $(BIN)):$(PATH)

.PHONY: install run test bench data-bench clean-outputs ui

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -qq --upgrade pip
	$(BIN)/python -m pip install -qq -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

JOBS ?= auto

run: install
	$(BIN)/dvc pull --allow-missing
	$(BIN)/python -m motionsynth.repro -j $(JOBS)

test: install
	$(BIN)/python -m pytest -q

# every benchmark the README's Benchmarks section lists (tests/test_docs.py checks the two agree)
bench: install
	$(BIN)/python bench/ingest.py
	$(BIN)/python bench/pipeline.py
	$(BIN)/python bench/train.py
	$(BIN)/python bench/generate.py
	$(BIN)/python bench/metrics.py
	$(BIN)/python bench/acLSTM_units_check.py
	$(BIN)/python bench/concurrency.py
	$(BIN)/python bench/allocator.py
	$(BIN)/python bench/stability.py

ui: install
	$(BIN)/motionsynth ui

clean-outputs:
	rm -rf data/interim data/processed data/splits reports/data reports/figures/data reports/data.md reports/metrics/data.json
