# Two commands do everything on a fresh machine with Python 3.11 and pip:
#   make demo   set up .venv and run the demo job
#   make test   set up .venv and run lint + tests
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo test lint bench clean chromium

# apt-get as root, through sudo otherwise.
APT := $(if $(filter 0,$(shell id -u)),,sudo) apt-get

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

# The browser tests (live viewer, HTML report) drive Debian's chromium: Playwright's own browser
# download cannot work on a machine without internet. Installed once, when it is missing.
chromium:
	@command -v chromium >/dev/null 2>&1 || { echo "installing Debian's chromium for the browser tests"; \
	  $(APT) install -y -q chromium >/dev/null || { $(APT) update -q >/dev/null && $(APT) install -y -q chromium >/dev/null; }; }

test: lint chromium
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
