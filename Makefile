# teamkf — set-up and checks. Needs only python3 (>= 3.11) and pip access to PyPI.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: venv test test-fast lint demo bench typecheck clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP) lint
	$(BIN)/python -m pytest -q $(PYTEST_ARGS)
	$(BIN)/python -m mypy

lint: $(STAMP)
	$(BIN)/ruff check src tests examples benchmarks
	$(BIN)/ruff format --check src tests examples benchmarks
	$(BIN)/lint-imports

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" -x

demo: $(STAMP)
	$(BIN)/teamkf demo

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_design.py --only platoon-finite --only uav --uav-sizes 10 100 300 --scipy-max 300
	$(BIN)/python benchmarks/bench_monte_carlo.py
	$(BIN)/python benchmarks/bench_bulk.py --sizes 1000 --repeat 1

typecheck: $(STAMP)
	$(BIN)/python -m mypy

clean:
	rm -rf $(VENV) build dist src/*.egg-info .pytest_cache .mypy_cache results
