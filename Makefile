# poise — developer entry points. Everything runs inside .venv (created on demand).
PYTHON ?= python3
VENV   := .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed

.PHONY: help install demo test test-all bench lint clean

help:
	@echo "make demo    - create .venv, install, solve an example deck, print a summary"
	@echo "make test    - run the test suite (creates .venv if needed)"
	@echo "make bench   - run the benchmarks, write bench/results.jsonl and docs/performance.md"
	@echo "make lint    - ruff"

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
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

bench: install
	$(PY) -m poise.bench --out bench/results.jsonl --markdown docs/performance.md

lint: install
	$(VENV)/bin/ruff check src cli tests

clean:
	rm -rf $(VENV) .pytest_cache build *.egg-info src/*.egg-info demo_results.h5
