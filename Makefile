# poise — developer entry points. Everything runs inside .venv (created on demand).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: help install demo test test-all bench bench-quick lint clean

help:
	@echo "make demo    - create .venv, install, solve an example deck, print a summary"
	@echo "make test    - run the test suite (creates .venv if needed)"
	@echo "make bench   - run the benchmarks, write bench/results.jsonl and docs/performance.md"
	@echo "make bench-quick - reduced ladder and sizes (~2-3 min), same outputs"
	@echo "make lint    - ruff and lint-imports (the import contracts in pyproject.toml)"

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev,all]'
	@touch $(STAMP)

install: $(STAMP)

demo: install
	$(VENV)/bin/poise solve decks/pendulum_multiturn.xml -o demo_results.h5
	$(VENV)/bin/poise show demo_results.h5

# slow tests are skipped locally (pyproject addopts) and included in CI (CI=true), where they fit
test: install
	$(PY) -m pytest -q $(if $(CI),-m "slow or not slow",) $(PYTEST_ARGS)

test-all: install
	$(PY) -m pytest -q -m "slow or not slow" $(PYTEST_ARGS)

BENCH_STAMP := $(VENV)/.bench-installed
$(BENCH_STAMP): pyproject.toml $(STAMP)
	$(PY) -m pip install --quiet -e '.[dev,all,bench]'
	@touch $(BENCH_STAMP)

# benchmarks/ (not installed): chain bench + issue 7 (work-precision ladders, Exudyn peer,
# scaling); <= 20 min on 2 cores
bench: install $(BENCH_STAMP)
	$(PY) -m benchmarks --out bench/results.jsonl --markdown docs/performance.md

bench-quick: install $(BENCH_STAMP)
	$(PY) -m benchmarks --quick --sizes 10,100,1000 --repeat 1 --cli-repeat 3 \
	    --out bench/results-quick.jsonl --markdown bench/performance-quick.md

lint: install
	$(VENV)/bin/ruff check src cli tests benchmarks
	$(VENV)/bin/lint-imports --no-cache

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info src/*.egg-info demo_results.h5
