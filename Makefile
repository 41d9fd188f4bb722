# Two commands do everything on a fresh machine with Python 3.11 and pip:
#   make demo   set up .venv and run the demo job
#   make test   set up .venv and run lint + tests
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test lint bench clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip

# The package and what it needs to run.
$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e .
	touch $@

# Plus the test tools (pytest, hypothesis, ruff) and Dask for the executor tests.
$(VENV)/.installed-test: pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e '.[test]'
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	$(BIN)/swarmraft demo

lint: $(VENV)/.installed-test
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks

test: lint
	$(BIN)/python -m pytest -q

bench: $(VENV)/.installed
	$(BIN)/python benchmarks/bench_paper.py
	$(BIN)/python benchmarks/bench_detectors.py
	$(BIN)/python benchmarks/bench_raft.py
	$(BIN)/python benchmarks/bench_mission.py
	$(BIN)/python benchmarks/bench_crypto.py
	$(BIN)/python benchmarks/bench_wire.py
	$(BIN)/python benchmarks/bench_net.py
	$(BIN)/python benchmarks/bench_hostile.py

clean:
	rm -rf $(VENV) results
