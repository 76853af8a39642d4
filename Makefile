# Two entry points that bootstrap their own virtual environment: `make demo`, `make test`.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin

.PHONY: demo test lint bench clean

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

demo: $(VENV)/.installed
	$(BIN)/restore demo

# One file per worker (--dist loadfile): a module-scoped fixture (a benchmark run, a shared
# sample) is then computed once, not once per worker. Files go out in collection order
# (--no-loadscope-reorder), so tests/docs, whose one long test builds the site and runs
# the notebooks, starts first instead of running alone at the end.
test: $(VENV)/.installed
	$(BIN)/pytest -n 2 --dist loadfile --no-loadscope-reorder -q

# ruff (style and likely bugs), mypy (types) and import-linter (the layers and no import cycles)
lint: $(VENV)/.installed
	$(BIN)/ruff check restore targets tests examples/*.py
	$(BIN)/mypy
	$(BIN)/lint-imports

bench: $(VENV)/.installed
	$(BIN)/python examples/benchmark_speed.py
	$(BIN)/python examples/benchmark_core.py
	$(BIN)/python examples/benchmark_general.py

clean:
	rm -rf $(VENV) restore-demo.png .jax-cache
