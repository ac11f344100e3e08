# gridfleet: `make run` starts the whole system, `make test` runs every check.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test check lint typecheck pytest firmware-test install schemas clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test]"
	@if [ -f dashboard/package.json ]; then cd dashboard && npm ci --no-audit --no-fund --loglevel=error; fi
	touch $(STAMP)

install: $(STAMP)

run: $(STAMP)
	$(BIN)/gridfleet up

test: check firmware-test pytest

check: lint typecheck

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

pytest: $(STAMP)
	$(BIN)/pytest

firmware-test:
	@if [ -f firmware/Makefile ]; then $(MAKE) -C firmware test; fi

schemas: $(STAMP)
	$(BIN)/python -m gridfleet.protocol.schemas

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache dashboard/node_modules
