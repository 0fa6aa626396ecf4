# hitch-planner: two commands for a new user.
#   make run   -- set up .venv (if missing) and run the service on embedded defaults
#   make test  -- set up .venv with the test extra (if missing), check style and types, run every test
# Also: make lint (ruff + mypy only), make quick (lint + tests not marked slow), make help (this, and where to look).
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: run test lint quick clean help

$(BIN)/hitch-installed: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	# the kinematics' hot paths compiled to C once per machine (planner.model.compiled, built by planner.warm_compiled; the
	# CasADi virtual machine, same values, when no C compiler is found)
	$(BIN)/python -m planner.warm_compiled
	touch $@

run: $(BIN)/hitch-installed
	$(BIN)/hitch serve

lint: $(BIN)/hitch-installed
	$(BIN)/ruff check planner bridge tests bench examples
	$(BIN)/ruff format --check planner bridge tests bench examples
	$(BIN)/mypy

test: lint
	$(BIN)/python -m pytest

quick: lint
	$(BIN)/python -m pytest -m "not slow"

clean:
	rm -rf $(VENV) build *.egg-info

help:
	@echo "make run    set up .venv (if missing) and run the service on embedded defaults (hitch serve)"
	@echo "make test   lint, then the whole test suite (about 20-25 minutes on 2 cores)"
	@echo "make quick  lint, then the tests not marked slow"
	@echo "make lint   ruff check, ruff format --check and mypy (planner, bridge, examples)"
	@echo "make clean  remove .venv and the build files"
	@echo "one test file:  $(BIN)/python -m pytest tests/planner/model/test_kinematics.py [-k NAME]"
	@echo "a bench:        $(BIN)/python bench/model_bench.py   (one script per area in bench/, figures in docs/benchmarks.md)"
	@echo "an example:     $(BIN)/python examples/04_trajectory.py   (one concept per script in examples/)"
	@echo "where things live: README.md (Layout), docs/architecture.md (each folder and module, each thesis equation)"
