# ddbench: every target sets up its own virtual environment first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: demo test test-slow bench lint format clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/hil demo --out runs/demo

test: $(STAMP)
	$(BIN)/ruff check hil drivers virtual_robot profiles tests
	$(BIN)/python -m pytest -q -m "not slow"

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

bench: $(STAMP)
	$(BIN)/python tests/benchmarks/bench_simulate.py
	$(BIN)/python tests/benchmarks/bench_hil.py
	$(BIN)/python tests/benchmarks/bench_identify.py
	$(BIN)/python tests/benchmarks/bench_jitter.py
	$(BIN)/python tests/benchmarks/bench_diagnose.py --long
	$(BIN)/python tests/benchmarks/bench_sweep.py

lint: $(STAMP)
	$(BIN)/ruff check hil drivers virtual_robot profiles tests
	$(BIN)/ruff format --check hil drivers virtual_robot profiles tests

format: $(STAMP)
	$(BIN)/ruff format hil drivers virtual_robot profiles tests
	$(BIN)/ruff check --fix hil drivers virtual_robot profiles tests

clean:
	rm -rf $(VENV) runs build *.egg-info
