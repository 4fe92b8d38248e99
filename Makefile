# Two commands do all the set-up on a fresh machine:
#   make run    creates .venv, installs corridor, runs the default batch (scenarios/merging.yaml)
#   make test   creates .venv, installs corridor[dev], runs ruff, the import contracts, mypy and the test suite
#               (tests/docs builds the documentation site strictly and runs the docs' runnable blocks)
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev
RUNS ?= 8
OUT ?= results/merging

.PHONY: run test test-all lint bench docs clean chromium

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

# the report's browser test drives Debian's Chromium (playwright, no browser download)
chromium:
	@test -x /usr/bin/chromium || (apt-get update -qq && apt-get install -y -qq chromium)

test: $(DEV_STAMP) chromium
	$(BIN)/ruff check .
	$(BIN)/python tools/lint_imports.py
	$(BIN)/mypy
	$(BIN)/pytest -q -n 2

test-all: $(DEV_STAMP) chromium
	$(BIN)/pytest -q -n 2 -m ''

# ruff, the import contracts (and no kernel import cycle), mypy (strict on the kernel: [tool.mypy])
lint: $(DEV_STAMP)
	$(BIN)/ruff check .
	$(BIN)/python tools/lint_imports.py
	$(BIN)/mypy

# make bench: every benchmark in benchmarks/, short settings, under 10 minutes on 2 cores (one command a line)
bench: $(STAMP)
	$(BIN)/python benchmarks/kernel_overhead.py --duration 120 --repeat 1
	$(BIN)/python benchmarks/v2x_cost.py --duration 120 --seeds 1
	$(BIN)/python benchmarks/mpc_solve.py --quick
	$(BIN)/python benchmarks/batch_speedup.py --quick
	$(BIN)/python benchmarks/avoidance_solve.py --duration 20
	$(BIN)/python benchmarks/overtaking_solve.py --seeds 2 --duration 10
	$(BIN)/python benchmarks/stl_robustness.py --sizes 100000 --rtamt-budget 20
	$(BIN)/python benchmarks/uav_fleet.py --n 10 --sim-s 10
	$(BIN)/python benchmarks/uav_swarm_rtf.py --quick
	$(BIN)/python benchmarks/parking_plan.py --repeats 1

# make docs: the documentation site (docs/, mkdocs.yml) into site/, warnings are errors
docs: $(DEV_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

clean:
	rm -rf $(VENV) results build site *.egg-info .cache
