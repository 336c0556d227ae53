# The README's two commands: `make demo` and `make test`. Both build/reuse .venv first.
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed
DEMO_DIR ?= demo-out
TEST_WORKERS ?= 2  # pytest-xdist workers; tests/conftest.py says why

.PHONY: setup demo test check clean

setup: $(STAMP)

# torch==2.13.0 first: on these machines it is the CPU build that lies on disk.
$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q torch==2.13.0
	$(PY) -m pip install -q -e '.[train,test,robot,peers,record,sim]'
	touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/edgepick demo --workdir $(DEMO_DIR)

# Lint and type-check first (seconds), then the suite; it ends with
# its 15 slowest tests.
test: $(STAMP)
	$(PY) -m ruff check edgepick benchmarks tests
	$(PY) -m mypy edgepick
	$(PY) -m pytest -q -p no:cacheprovider -n $(TEST_WORKERS) --dist loadfile --durations=15

# The inner loop: lint, type-check and the tests that train no model (no training run, nothing marked slow).
check: $(STAMP)
	$(PY) -m ruff check edgepick benchmarks tests
	$(PY) -m mypy edgepick
	$(PY) -m pytest -q -p no:cacheprovider -n $(TEST_WORKERS) --dist loadfile -m "not slow and not trained" --durations=10

clean:
	rm -rf $(VENV) $(DEMO_DIR) build *.egg-info
