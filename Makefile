# Quick start: `make run` and `make test` work on a fresh machine (they create .venv first).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test test-unit lint format docs clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,cluster]'
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/umay run --result out/result.json

# Two pytest workers (pytest-xdist), as many as CI's cores; every test has its own key prefix,
# port and temporary directory, so they never cross.
test: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/python -m pytest -n 2 --dist loadgroup --no-loadscope-reorder

# The fast target: tests/unit only (pure and in-process; no service, no Zenoh session).
test-unit: $(STAMP)
	$(BIN)/python -m pytest -n 2 --dist worksteal tests/unit

lint: $(STAMP)
	$(BIN)/ruff check .

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

docs: $(STAMP)
	$(BIN)/umay docs

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache *.egg-info
