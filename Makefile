# Two entry points for a fresh clone (only Python >= 3.11 and pip needed):
#   make demo   install into .venv and run the reference case study (calnet run examples/ninb)
#   make test   install into .venv (with test extras) and run the fast tests (before a commit)
# and for CI:
#   make test-slow  the slow and end-to-end tests (pytest markers slow, integration)
#   make lint       ruff over src, tests and benchmarks
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1
# pytest-xdist workers (auto: one per core); the tests of a file share one worker, which
# keeps each file's module-scoped fixtures built once
TEST_WORKERS ?= auto
PYTEST := $(BIN)/python -m pytest -n $(TEST_WORKERS) --dist loadfile

.PHONY: demo test test-slow lint install clean

$(BIN)/.calnet-installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

install: $(BIN)/.calnet-installed

demo: install
	$(BIN)/calnet run examples/ninb --out out/ninb

test: install
	$(PYTEST) -m "not slow and not integration"

test-slow: install
	$(PYTEST) -m "slow or integration"

lint: install
	$(BIN)/ruff check src tests benchmarks

clean:
	rm -rf $(VENV) out .pytest_cache
