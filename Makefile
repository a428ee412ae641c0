# ddbench: every target sets up its own virtual environment first.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: demo test test-slow test-vcan bench bench-big lint format clean eds docs

# the requirements the compiled RK4 step builds against (pyproject.toml's own specifiers)
BUILD_DEPS = import tomllib; deps = tomllib.load(open("pyproject.toml", "rb"))["project"]["dependencies"]; \
	print(" ".join(d for d in deps if d.startswith(("numpy", "pin", "cmeel-"))))

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	# Pinocchio and its headers first; then the n-joint plant's compiled RK4 step (about 50 s
	# of CPU) builds once into the cache on one core while pip installs the rest on the other.
	# The build never fails setup: without it the plant runs its Python step and says why
	$(BIN)/python -m pip install --quiet $$($(BIN)/python -c '$(BUILD_DEPS)')
	{ timeout 900 $(BIN)/python -m virtual_robot.compiled_step > $(VENV)/compiled-step.log 2>&1; \
	  true; } & \
	$(BIN)/python -m pip install --quiet -e '.[test,dask]'; installed=$$?; \
	wait; cat $(VENV)/compiled-step.log; exit $$installed
	# the host's compiled open-loop sub-step (about 1 s); the same: Python step without it
	timeout 300 $(BIN)/python -m hil.model.compiled_openloop || true
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/hil demo

# PYTHONDONTWRITEBYTECODE emptied: where the environment sets it, every process (each test
# worker's assertion rewriting, each of the suite's `hil` and `virtual-robot` subprocesses)
# compiled every module of the tree from source again (~30 s of the suite's CPU, 3 %); the
# .pyc files go to the tree's __pycache__ (ignored by git). --dist loadgroup: a module marked
# xdist_group (those with costly module fixtures) runs on one worker, which builds its
# fixtures once; the rest is shared out test by test as --dist load does
test: $(STAMP)
	$(BIN)/ruff check hil drivers virtual_robot profiles plots tests
	PYTHONDONTWRITEBYTECODE= $(BIN)/python -m pytest -q -m "not slow" -n 2 --dist loadgroup

test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

# the vcan/SocketCAN tests on a real Linux kernel in a QEMU guest (docs/vcan.md); skips, with the
# reason, where it cannot run
test-vcan: $(STAMP)
	tests/vcan/run.sh

bench: $(STAMP)
	$(BIN)/python tests/benchmarks/bench_simulate.py
	$(BIN)/python tests/benchmarks/bench_hil.py
	$(BIN)/python tests/benchmarks/bench_identify.py
	$(BIN)/python tests/benchmarks/bench_jitter.py
	$(BIN)/python tests/benchmarks/bench_diagnose.py --long
	$(BIN)/python tests/benchmarks/bench_sweep.py
	$(BIN)/python tests/benchmarks/bench_slcan_sdo.py
	$(BIN)/python tests/benchmarks/bench_urdf.py
	$(BIN)/python tests/benchmarks/bench_control.py
	$(BIN)/python tests/benchmarks/bench_identify_memory.py --seconds 60 --tile-mb 7 --stages

# issue 13's target, opt-in: a 700 MB CSV (10 M rows) through `hil identify --from`, < 4 GB
# and issue 26's: `hil diagnose --reference` on two 60 s Panda recordings, <= 30 s CPU and 1 GB
bench-big: $(STAMP)
	$(BIN)/python tests/benchmarks/bench_identify_memory.py --seconds 60 --tile-mb 700
	$(BIN)/python tests/benchmarks/bench_diagnose_reference.py

lint: $(STAMP)
	$(BIN)/ruff check hil drivers virtual_robot profiles plots tests
	$(BIN)/ruff format --check hil drivers virtual_robot profiles plots tests

format: $(STAMP)
	$(BIN)/ruff format hil drivers virtual_robot profiles plots tests
	$(BIN)/ruff check --fix hil drivers virtual_robot profiles plots tests

# the docs site (mkdocs.yml) into site/, strict: a broken link, anchor or missing page fails
DOCS_STAMP := $(VENV)/.docs-stamp
$(DOCS_STAMP): $(STAMP) pyproject.toml
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# EDS and DBC from the object map (drivers/protocol/export.py); tests/test_interop.py checks them
eds: $(STAMP)
	$(BIN)/python -m drivers.protocol.export

clean:
	rm -rf $(VENV) runs build site *.egg-info
