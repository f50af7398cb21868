# The two commands of the README: `make demo` and `make test`. Both set themselves up first.
VENV ?= .venv
PY := $(VENV)/bin/python
MFMAP := $(VENV)/bin/mfmap
WORK ?= work
# pytest-xdist workers, one test file each (a file's fixtures are built once): the suite is
# mostly whole builds that keep one core busy, so two workers use a 2-core machine's second.
TEST_WORKERS ?= 2

.PHONY: setup demo test lint typecheck pytest config

setup:
	@bash scripts/setup.sh

demo: setup
	@bash scripts/demo.sh

test: setup lint typecheck pytest

lint:
	$(VENV)/bin/ruff check mfmap pipelines tests

typecheck:
	$(VENV)/bin/mypy

# The simulated logs first, all cores busy: from a cold cache the workers would wait on each other.
pytest:
	$(PY) -m tests.simlogs --workers $(TEST_WORKERS)
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

config: setup
	$(MFMAP) config > sample_configs/default.yaml
