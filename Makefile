# slidewatch: `make run` starts the app on the embedded default; `make test` runs every test.
SHELL := /bin/bash
VENV ?= .venv
PYTHON := $(VENV)/bin/python
INSTALLED := $(VENV)/.installed
# Test processes (pytest-xdist): the suite is made for 2 cores; more only if the machine has them.
TEST_PROCESSES ?= 2
# Paths or options for pytest (e.g. PYTEST_ARGS=tests/e2e). The suite runs in
# TEST_PROCESSES processes with xdist's default distribution (worksteal took a third longer
# here), then the tests marked `alone` (timing bounds a second process would break) by
# themselves; exit status 5 is "none of them selected".
PYTEST_ARGS ?=
# Python writes the bytecode of what it imports, once: with PYTHONDONTWRITEBYTECODE set (some
# shells and CI images set it) and pip's --no-compile below, every process would compile
# every module it imports from source again (a worker's start 3.8 s instead of 1.6 s, the
# suite's collection 25 s instead of 10 s).
unexport PYTHONDONTWRITEBYTECODE

.PHONY: install run test lint format lock benchmark clean

# --no-compile: no bytecode compiled ahead for the 16 000 modules installed; Python compiles
# those imported, once, on first use.
$(INSTALLED): requirements.lock pyproject.toml scripts/install-system-packages.sh
	scripts/install-system-packages.sh
	test -x $(PYTHON) || python3 -m venv $(VENV)
	$(PYTHON) -m pip install --quiet --no-compile --requirement requirements.lock
	$(PYTHON) -m pip install --quiet --no-deps --editable .
	touch $@

# The map (frontend/): node packages exactly as package-lock.json pins them, then a Vite build
# into frontend/dist, which the API serves at `/` (not committed).
FRONTEND_BUILT := frontend/dist/index.html
FRONTEND_DEPS := frontend/node_modules/.package-lock.json
FRONTEND_SOURCES := $(shell find frontend/src -type f 2>/dev/null) frontend/index.html \
	frontend/vite.config.ts frontend/tsconfig.json

$(FRONTEND_DEPS): frontend/package.json frontend/package-lock.json
	scripts/check-node.sh
	cd frontend && npm ci --no-audit --no-fund --loglevel=error
	touch $@

$(FRONTEND_BUILT): $(FRONTEND_DEPS) $(FRONTEND_SOURCES)
	cd frontend && npm run --silent build

install: $(INSTALLED) $(FRONTEND_BUILT)

run: install
	$(VENV)/bin/slidewatch run

test: install
	$(VENV)/bin/ruff check .
	cd frontend && npm test --silent
	scripts/with-test-services.sh $(VENV)/bin/pytest --numprocesses $(TEST_PROCESSES) \
		-m "not alone" $(PYTEST_ARGS) || [ $$? -eq 5 ]
	scripts/with-test-services.sh $(VENV)/bin/pytest -m alone $(PYTEST_ARGS) || [ $$? -eq 5 ]

lint: install
	$(VENV)/bin/ruff check .
	$(VENV)/bin/ruff format --check backend worker tests benchmarks migrations

format: install
	$(VENV)/bin/ruff format backend worker tests benchmarks migrations
	$(VENV)/bin/ruff check --fix .

# Re-resolve every dependency from pyproject.toml and pin the result.
lock:
	rm -rf .lock-venv && python3 -m venv .lock-venv
	.lock-venv/bin/pip install --quiet --editable '.[test]'
	( echo "# Exact versions installed by make; regenerate with 'make lock'."; \
	  .lock-venv/bin/pip freeze --exclude-editable | sed 's|^torch @ .*|torch==2.13.0|' ) > requirements.lock
	rm -rf .lock-venv

benchmark: install
	$(PYTHON) benchmarks/comparison.py --size 2000 --json benchmarks/results/comparison.json

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache frontend/node_modules frontend/dist test-artifacts
