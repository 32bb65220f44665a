# antalate: `make demo` flies a simulated swarm, `make test` runs the whole suite.
# Both create .venv and install everything they need first (system packages via apt where allowed).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: setup sysdeps demo demo-headless test lint gen bench clean

setup: $(STAMP)

sysdeps:
	@bash tools/install-system-deps.sh

$(STAMP): pyproject.toml
	@bash tools/install-system-deps.sh
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	@touch $(STAMP)

demo: setup
	$(VENV)/bin/antalate demo --agents 5

demo-headless: setup
	$(VENV)/bin/antalate demo --headless --agents 5

# Four workers on two cores: the suite mostly waits (vehicles climbing, firmware booting, links timing
# out; load stayed under 3 with four), so more workers than cores shorten it. A module's tests stay on
# one worker, in order (--dist loadfile): its module-scoped fixtures (a built wheel, a booted SITL
# vehicle) are made once, and tests that build on the one before keep their order. The modules go out
# longest first from tests/harness/module_times.json (tests/harness/scheduling.py), the SITL swarms as one unit.
TEST_WORKERS ?= 4

test: setup sysdeps
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

lint: setup
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check .
	$(VENV)/bin/mypy --cache-dir $(VENV)/.mypy_cache

gen: setup
	$(PY) -m antalate_lcm.tools.codegen

bench: setup
	$(PY) benchmarks/bus.py
	$(PY) benchmarks/agents.py
	$(PY) benchmarks/station.py
	$(PY) benchmarks/tui.py

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache build *.egg-info
