# Two commands on a fresh machine with only python3: `make run` and `make test`.
# Each creates .venv and installs the project (editable, with the test extra) when needed.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run check test bench docs clean

$(STAMP): pyproject.toml
	@$(PYTHON) -c 'import sys; sys.exit(sys.version_info < (3, 11))' || { echo "make: ringtrack needs Python 3.11 or newer; $(PYTHON) is $$($(PYTHON) --version 2>&1); run make PYTHON=python3.11 ..."; exit 2; }
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --upgrade pip
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -e '.[test]'
	@# The package's bytecode, written once: where PYTHONDONTWRITEBYTECODE is set, every process
	@# would otherwise compile every module it imports as it starts.
	$(BIN)/python -m compileall -q agents bus world tools scenarios __main__.py
	touch $(STAMP)

run: $(STAMP)
	$(BIN)/ringtrack spawn paper-stationary --robots 6

# The project's own checks: lint and import order, the layers contract, types. mypy reads the
# package through a link named ringtrack (the repository root is the package's folder).
check: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/lint-imports --no-cache
	@mkdir -p $(VENV)/typecheck && ln -sfn $(CURDIR) $(VENV)/typecheck/ringtrack
	$(BIN)/mypy

# The full hypothesis example counts (plain pytest runs the dev profile: 30 % of them). Then the
# multi-process tests once more, beside two CPU-burning processes (tests/burn.py): they must hold on
# a machine whose cores are all busy.
HYPOTHESIS_PROFILE ?= ci
test: check
	HYPOTHESIS_PROFILE=$(HYPOTHESIS_PROFILE) $(BIN)/python -m pytest -q
	HYPOTHESIS_PROFILE=$(HYPOTHESIS_PROFILE) $(BIN)/python -m tests.burn -q -m processes -p no:cacheprovider

bench: $(STAMP)
	$(BIN)/ringtrack bench engine

# The documentation site (mkdocs.yml, docs/) on http://127.0.0.1:8000, rebuilt on every change.
docs: $(STAMP)
	$(BIN)/python -m mkdocs serve

clean:
	rm -rf $(VENV) runs site .pytest_cache .hypothesis
