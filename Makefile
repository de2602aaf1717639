# teamkf — set-up and checks. Needs only python3 (>= 3.11) and pip access to PyPI.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: venv test test-slow test-latest constraints test-fast lint demo bench typecheck docs docs-clean clean

# Installs are pinned by constraints.txt (the versions CI tests), updated on purpose with `make constraints`.
# `make test-latest` runs the same checks in .venv-latest against the newest releases.
CONSTRAINTS ?= -c constraints.txt

$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet $(CONSTRAINTS) -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

# `make demo` and `make docs` install only what they need (not the dev toolchain), each once: demo the plot and
# dask extras, which every command of the README needs (matplotlib; pandas and pyarrow for filter and sweep, Dask);
# a full dev install ($(STAMP)) already has both.
DEMO_STAMP := $(VENV)/.installed-demo-ros
DOCS_STAMP := $(VENV)/.installed-docs
$(DEMO_STAMP): pyproject.toml constraints.txt
	@test -f $(STAMP) || { $(PYTHON) -m venv $(VENV) && $(BIN)/python -m pip install --quiet --upgrade pip && $(BIN)/python -m pip install --quiet $(CONSTRAINTS) -e '.[plot,dask,ros]'; }
	touch $@
$(DOCS_STAMP): pyproject.toml constraints.txt
	@test -f $(STAMP) || { $(PYTHON) -m venv $(VENV) && $(BIN)/python -m pip install --quiet --upgrade pip && $(BIN)/python -m pip install --quiet $(CONSTRAINTS) -e '.[docs]'; }
	touch $@

# The suite runs on every core (pytest-xdist; PYTEST_ARGS="-n 0" runs it in one process), without the tests
# marked `slow` (long reproductions, T = 10^5 horizons, the documentation site built and opened in Chromium):
# `make test-slow` runs those, and CI (.ci/run) runs both. The site is built once per run (tests/test_docs.py:
# a file lock shared by the workers).
XDIST := -n auto --dist loadgroup
test: $(STAMP) lint
	$(BIN)/python -m pytest -q $(XDIST) -m "not slow" $(PYTEST_ARGS)
	$(BIN)/python -m mypy

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q $(XDIST) -m slow $(PYTEST_ARGS)

# The suite against the newest releases of every dependency (no constraints), in its own venv.
test-latest:
	$(MAKE) test VENV=.venv-latest CONSTRAINTS=

# Pin the versions of a fresh newest install into constraints.txt (review the diff, then `make test`).
constraints:
	rm -rf .venv-constraints
	$(PYTHON) -m venv .venv-constraints
	.venv-constraints/bin/python -m pip install --quiet --upgrade pip
	.venv-constraints/bin/python -m pip install --quiet -e '.[dev]'
	{ sed -n '1,2p' constraints.txt; .venv-constraints/bin/python -m pip freeze --exclude-editable | grep -v '^teamkf' | sort -f; } > constraints.txt.new
	mv constraints.txt.new constraints.txt
	rm -rf .venv-constraints

# The documentation site: docs/_build/html (warnings are errors; no network needed, to build or to read).
# A fresh clone builds in about 3 min of CPU (every gallery script runs, at reduced size); later builds about 1 min.
# -E: every page is read again, so a warning is never hidden by a cached page; sphinx-gallery still
# skips the scripts that did not change since their last run (`make docs-clean docs` runs them all).
DOCS_OUT ?= docs/_build/html
docs: $(DOCS_STAMP)
	PYTHONPATH=$(CURDIR)/src MPLBACKEND=Agg TEAMKF_PROGRESS=0 $(BIN)/python -m sphinx -E -b html -W --keep-going -q docs $(DOCS_OUT)

docs-clean:
	rm -rf docs/_build docs/api/generated docs/api/public.rst docs/api/teamkf.*.rst docs/auto_gallery docs/auto_examples docs/_examples docs/sg_execution_times.rst

lint: $(STAMP)
	$(BIN)/ruff check src tests examples benchmarks
	$(BIN)/ruff format --check src tests examples benchmarks
	$(BIN)/lint-imports

test-fast: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow" -x

demo: $(DEMO_STAMP)
	$(BIN)/teamkf demo

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_design.py --only platoon-finite --only uav --uav-sizes 10 100 300 --scipy-max 300
	$(BIN)/python benchmarks/bench_monte_carlo.py
	$(BIN)/python benchmarks/bench_bulk.py --sizes 1000 --repeat 1

typecheck: $(STAMP)
	$(BIN)/python -m mypy

clean:
	rm -rf $(VENV) .venv-latest build dist src/*.egg-info .pytest_cache .mypy_cache results
	$(MAKE) docs-clean
