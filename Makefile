# Two commands do all the set-up on a fresh machine:
#   make run    creates .venv, installs corridor, runs the default batch (scenarios/merging.yaml)
#   make test   creates .venv, installs corridor[dev], runs ruff, the import contracts and the test suite
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev
RUNS ?= 4
OUT ?= results/merging

.PHONY: run test test-all lint bench clean

$(STAMP): pyproject.toml
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e .
	touch $(STAMP)

$(DEV_STAMP): $(STAMP) pyproject.toml
	$(BIN)/pip install -q -e '.[dev]'
	touch $(DEV_STAMP)

# make run replaces its own batch folder (results/merging) each time; other batches go elsewhere.
run: $(STAMP)
	$(BIN)/run_scenario scenarios/merging.yaml --runs $(RUNS) --out $(OUT) --overwrite

test: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/python tools/lint_imports.py
	$(BIN)/pytest -q -n 2

test-all: $(DEV_STAMP)
	$(BIN)/pytest -q -n 2 -m ''

lint: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/python tools/lint_imports.py

bench: $(STAMP)
	$(BIN)/python benchmarks/kernel_overhead.py
	$(BIN)/python benchmarks/parking_plan.py

clean:
	rm -rf $(VENV) results build *.egg-info .cache
