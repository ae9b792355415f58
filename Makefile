# Two commands do everything on a fresh machine: `make run` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: setup run test browser bench fuzz load lint clean

$(STAMP): pyproject.toml
	@echo "==> creating the virtual environment $(VENV)"
	$(PY) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	@echo "==> installing GSA-ISAR and what it needs (a few minutes on a fresh machine; torch is the largest)"
	@{ $(BIN)/pip install -e '.[dev]' 2>&1; echo $$? > $(VENV)/.pip-status; } | tee $(VENV)/install.log \
	  | grep --line-buffered -E '^(Collecting|Installing collected|Successfully|ERROR)' | cut -c1-100
	@[ "$$(cat $(VENV)/.pip-status)" = 0 ] || { echo "the install failed: see $(VENV)/install.log"; exit 1; }
	touch $(STAMP)
	@echo "==> installed; run $(BIN)/gsa, or source $(VENV)/bin/activate first"

setup: $(STAMP)

run: $(STAMP)
	$(BIN)/gsa serve

# Two processes, whole test files each (module fixtures are built once; the load tests keep their own servers).
test: $(STAMP) browser
	$(BIN)/python -m pytest -q -n 2 --dist loadfile

# The console's tests run in Debian's Chromium; installed once if the machine lacks it (apt, as root or with sudo).
browser:
	@command -v chromium >/dev/null 2>&1 || { echo "installing Debian's chromium for the console tests (about a minute)"; \
	  SUDO=$$( [ "$$(id -u)" = 0 ] || echo sudo ); \
	  $$SUDO apt-get install -y -qq chromium >/dev/null 2>&1 || { $$SUDO apt-get update -qq && $$SUDO apt-get install -y -qq chromium >/dev/null; }; }

bench: $(STAMP)
	$(BIN)/python -m bench.run
	$(BIN)/python -m bench.campaigns
	$(BIN)/python -m bench.trust
	$(BIN)/python -m bench.robust
	$(BIN)/python -m bench.physics
	$(BIN)/python -m bench.passes
	$(BIN)/python -m bench.so3
	$(BIN)/python -m bench.load
	$(BIN)/python -m bench.reliability
	$(BIN)/python -m bench.exports
	$(BIN)/python -m bench.jobs

# 5000+ generated requests per database (313 per route); the counts go to BENCHMARKS.md.
fuzz: $(STAMP)
	GSA_FUZZ_EXAMPLES_PER_ROUTE=313 GSA_FUZZ_REPORT=/tmp/gsa-fuzz.json $(BIN)/python -m pytest -q -p no:cacheprovider tests/app/api/test_fuzz.py
	$(BIN)/python -m bench.fuzz /tmp/gsa-fuzz.json

# A real server with 2 workers under 16 clients, on SQLite and PostgreSQL, then hostile clients (bench/reliability.py); figures to BENCHMARKS.md.
load: $(STAMP)
	$(BIN)/python -m bench.load
	$(BIN)/python -m bench.reliability
	$(BIN)/python -m bench.exports

# The house rules CI holds before the tests: lint, format and types (mypy strict on app, planner, inference, scene).
lint: $(STAMP)
	$(BIN)/ruff check app planner inference scene tests bench migrations
	$(BIN)/ruff format --check app planner inference scene tests bench migrations
	$(BIN)/mypy

clean:
	rm -rf $(VENV) data
