# Quick start: `make run` and `make test` work on a fresh machine (they create .venv first).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
COMPILED := $(VENV)/.compiled

.PHONY: run test test-unit lint format docs clean

# uv installs the same versions as pip in a third of the time (wheels fetched in parallel). uv
# comes from the machine's own pip into a folder of the venv, so the venv is made without a pip of
# its own (ensurepip takes longer than fetching uv); uv is one binary with no dependencies and
# nothing of it is imported, so pip neither resolves nor compiles anything for it. Should uv not
# install or run here, the venv gets its pip after all and installs with it.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv --without-pip $(VENV)
	( PIP_ROOT_USER_ACTION=ignore $(PYTHON) -m pip install --quiet --disable-pip-version-check \
	    --upgrade --no-deps --no-compile --target $(VENV)/uv uv && \
	  $(VENV)/uv/bin/uv pip install --quiet --python $(BIN)/python -e '.[dev,cluster]' ) || \
	( $(BIN)/python -m ensurepip --default-pip && \
	  $(BIN)/python -m pip install --quiet -e '.[dev,cluster]' )
	touch $(STAMP)

# Byte-code for every process a run or the suite launches, compiled once up front: where
# PYTHONDONTWRITEBYTECODE is set (CI's image sets it) each process would compile the project again.
COMPILE := $(BIN)/python -m compileall -q common services deploy

# The installed packages' byte-code, for the suite only: its hundreds of Python processes would
# each compile numpy, pydantic and the rest again where PYTHONDONTWRITEBYTECODE is set, while the
# few processes of a run gain less than compiling everything costs (docs/performance.md). Only a
# speed-up: a package file that does not compile (a template, another Python's syntax) is said
# and left to be compiled, if ever, when it is imported.
$(COMPILED): $(STAMP)
	$(BIN)/python -m compileall -qq -j 0 $(VENV)/lib || \
	  echo "some installed files did not compile to byte-code; they compile when imported"
	touch $(COMPILED)

# A run writes the byte-code of what it imports (project and packages) as it first imports it,
# even where PYTHONDONTWRITEBYTECODE is set: its services' process then reuses what the CLI
# compiled, and the next run compiles nothing; compiling everything up front would cost more.
run: export PYTHONDONTWRITEBYTECODE =
run: $(STAMP)
	$(BIN)/umay run --result out/result.json

# Two pytest workers (pytest-xdist), as many as CI's cores; every test has its own key prefix,
# port and temporary directory, so they never cross.
test: $(COMPILED)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	@$(COMPILE)
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
