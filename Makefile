# Two entry points for a fresh clone (only Python >= 3.11 and pip needed):
#   make demo   install into .venv and run the reference case study (calnet run examples/ninb)
#   make test   install into .venv (with test extras) and run the test suite
#   make lint   ruff over src, tests and benchmarks (CI runs it before make test)
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
export OPENBLAS_NUM_THREADS ?= 1
export OMP_NUM_THREADS ?= 1
export MKL_NUM_THREADS ?= 1

.PHONY: demo test lint install clean

$(BIN)/.calnet-installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[test]"
	touch $@

install: $(BIN)/.calnet-installed

demo: install
	$(BIN)/calnet run examples/ninb --out out/ninb

test: install
	$(BIN)/python -m pytest

lint: install
	$(BIN)/ruff check src tests benchmarks

clean:
	rm -rf $(VENV) out .pytest_cache
