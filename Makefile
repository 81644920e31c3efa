# Set-up is part of every target: a fresh machine with python3 needs nothing else.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
TEST_STAMP := $(VENV)/.installed-test

.PHONY: demo test test-fast lint bench clean

$(PY):
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e .
	touch $@

$(TEST_STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q -e '.[test]'
	touch $(STAMP) $@

demo: $(STAMP)
	$(VENV)/bin/fsid demo

# everything: the README's command and CI's
test: $(TEST_STAMP) lint
	$(PY) -m pytest -q -n 2 --dist loadfile --durations=15

# the edit loop: what is not marked slow (tests/conftest.py; closed_loop/ is slow whole,
# so not even collected), under a minute on 2 cores
test-fast: $(TEST_STAMP)
	$(PY) -m pytest -q -n 2 --dist loadfile -m "not slow" --ignore=tests/closed_loop

# the architecture's rules (pyproject.toml: [tool.ruff], [tool.importlinter]) before the tests
lint: $(TEST_STAMP)
	$(VENV)/bin/ruff check --quiet .
	$(VENV)/bin/ruff format --check --quiet .
	$(VENV)/bin/lint-imports --no-cache

bench: $(STAMP)
	$(PY) benchmarks/oem_speed.py
	$(PY) benchmarks/oem_efficiency.py

clean:
	rm -rf $(VENV) runs .pytest_cache
