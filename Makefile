# Two commands do everything on a fresh machine with Python 3.11 and pip:
#   make demo   set up .venv and run the demo job
#   make test   set up .venv and run lint + tests
# and one more shows the swarm live in a browser (docs/live.md):
#   make live   set up .venv with the live extra (rerun) and fly the demo mission live
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: demo live test lint bench clean chromium

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

# Plus rerun's SDK and web viewer (about 500 MB), for --live, --record and `swarmraft view`.
$(VENV)/.installed-live: pyproject.toml | $(BIN)/python
	$(BIN)/pip install --quiet -e '.[live]'
	touch $(VENV)/.installed $@

demo: $(VENV)/.installed
	$(BIN)/swarmraft demo

# The demo mission (9 drones) at real-time speed with its viewer on 127.0.0.1:$(LIVE_PORT)
# (the URL is printed); Ctrl-C stops it.
LIVE_PORT ?= 9090
live: $(VENV)/.installed-live
	$(BIN)/swarmraft mission --scenario demo --live --port $(LIVE_PORT)

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
