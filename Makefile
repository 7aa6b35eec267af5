# Two commands do all set-up: `make demo` and `make test` (each creates .venv if missing).
PYTHON ?= python3
VENV   ?= .venv
PY     := $(VENV)/bin/python
STAMP  := $(VENV)/.installed-$(shell cksum pyproject.toml | cut -d' ' -f1)

.PHONY: demo test test-under-load bench clean

$(PY):
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[robot,test]'
	rm -f $(VENV)/.installed-* && touch $@

demo: $(STAMP)
	$(PY) -m fakes.demo

# Four workers on the 2-core machine (much of the suite waits on daemons and devices, not the CPU; a fourth
# worker fills more of those waits than it costs: docs/benchmarks.md, "Test suite"),
# whole files per worker: a module's shared daemon (the closed loops) is built once. The longest files
# go first (tests/conftest.py LONGEST_FIRST; xdist's reordering by test count off) so none starts last.
test: $(STAMP)
	$(PY) -m pytest -q -n 4 --dist loadfile --no-loadscope-reorder --durations=15

# The suite beside 2 × cores pure CPU spinners (tools/under_load.py; they stop with the suite or when it is
# killed): the check to run before a stop that the suite stays green on a busy machine (tests/README.md).
SPINNERS ?= $(shell echo $$((2 * $$(nproc))))
test-under-load: $(STAMP)
	$(PY) tools/under_load.py --spinners $(SPINNERS) -- $(MAKE) --no-print-directory test

bench: $(STAMP)
	$(PY) bench/run_all.py

clean:
	rm -rf $(VENV) demo-out .pytest_cache
