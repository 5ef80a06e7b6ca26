# Quick start: `make run` and `make test` work on a fresh machine (they create .venv first).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
COMPILED := $(VENV)/.compiled

.PHONY: run test test-unit lint format docs clean lock

# The packages come from uv.lock (versions and hashes, resolved once with `make lock`): uv then
# installs them without asking the index anything, and CI gets the versions the suite passed with.
# uv sync makes the venv exactly the lock: a package installed into it by hand goes at the next
# install. uv itself is fetched by the machine's own pip, on Linux as one pinned wheel named by
# its address, into a folder of the venv: pip then neither reads uv's index page of thousands of
# files nor compiles anything, and the venv is made without a pip of its own (ensurepip takes
# longer than fetching uv). Where that wheel does not fit (another OS or libc), pip picks uv by
# version; where uv cannot be had or does not run, the venv gets its pip after all and installs
# the project's ranges (pyproject.toml), not the lock, and says so (pip fetches uv's build backend
# for the project then).
UV_VERSION := 0.13.9
UV_WHEELS := https://files.pythonhosted.org/packages
UV_WHEEL_x86_64 := $(UV_WHEELS)/3d/aa/26d64642d808de4a652579ef950d7cd2d37f080a8babf9c67c6b75fc4c3f/uv-0.13.9-py3-none-manylinux_2_17_x86_64.manylinux2014_x86_64.whl\#sha256=d7f459fe4fd247d830351c75686d3996ace3c6f3f728eb0e85a30b7ada0cef19
UV_WHEEL_aarch64 := $(UV_WHEELS)/57/15/94b6cd62ac3ff6550288328e8035288875197cbc183f51554b266a69877b/uv-0.13.9-py3-none-manylinux_2_17_aarch64.manylinux2014_aarch64.musllinux_1_1_aarch64.whl\#sha256=5435c5ce14a56431208ca0996416d310f1598e8c2c8ba707688985a16bb82dbe
UV_WHEEL := $(if $(filter Linux,$(shell uname -s)),$(UV_WHEEL_$(shell uname -m)))
UV := $(VENV)/uv/bin/uv
PIP_UV := PIP_ROOT_USER_ACTION=ignore $(PYTHON) -m pip install --quiet --disable-pip-version-check \
	--upgrade --no-deps --no-compile --target $(VENV)/uv
# Succeeds once uv runs from .venv/uv at its pinned version, fetched now unless it was there.
FETCH_UV := { $(UV) --version 2>/dev/null | grep -q '^uv $(subst .,\.,$(UV_VERSION)) ' || \
	{ { $(if $(UV_WHEEL),$(PIP_UV) "uv @ $(UV_WHEEL)" ||) $(PIP_UV) uv==$(UV_VERSION); } && \
	  $(UV) --version >/dev/null; }; }
EXTRAS := --extra dev --extra cluster

$(STAMP): pyproject.toml uv.lock
	$(PYTHON) -m venv --without-pip $(VENV)
	if $(FETCH_UV); then \
	  UV_PROJECT_ENVIRONMENT=$(VENV) UV_PYTHON_DOWNLOADS=never $(UV) sync --quiet --locked $(EXTRAS) || \
	  { echo "make: installing from uv.lock failed (above); if pyproject.toml changed since the lock, run: make lock" >&2; exit 1; }; \
	else \
	  echo "make: no uv here; pip installs pyproject.toml's ranges instead of uv.lock" >&2; \
	  $(BIN)/python -m ensurepip --default-pip && \
	  $(BIN)/python -m pip install --quiet -e '.[dev,cluster]'; \
	fi
	touch $(STAMP)

# uv.lock again from pyproject.toml's ranges, after changing them (until then the install stops:
# the lock needs updating). Needs only uv, not the install the stale lock refuses.
lock:
	$(FETCH_UV)
	UV_PYTHON_DOWNLOADS=never $(UV) lock

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
