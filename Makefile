# hitch-planner: two commands for a new user.
#   make run   -- set up .venv (if missing) and run the main job on embedded defaults
#   make test  -- set up .venv with the test extra (if missing) and run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin

.PHONY: run test clean

$(BIN)/hitch-installed: pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

run: $(BIN)/hitch-installed
	$(BIN)/hitch serve

test: $(BIN)/hitch-installed
	$(BIN)/python -m pytest

clean:
	rm -rf $(VENV) build *.egg-info
