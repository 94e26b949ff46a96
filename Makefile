# Two commands on a fresh machine: `make run` and `make test` (see README).
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin
STAMP   = $(VENV)/.installed-stamp

.PHONY: run test test-slow bench clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e ".[dev]"
	touch $(STAMP)

# the commands write only under results/; the script then writes README.md's measured sections from their JSON
run: $(STAMP)
	$(BIN)/bayes-mr run --out results
	$(BIN)/python scripts/update_readme.py run --out results

test: $(STAMP)
	$(BIN)/python -m pytest

test-slow: $(STAMP)
	$(BIN)/python -m pytest -m slow

bench: $(STAMP)
	$(BIN)/bayes-mr bench --json results/bench.json
	$(BIN)/python scripts/update_readme.py bench --json results/bench.json

clean:
	rm -rf $(VENV) results .pytest_cache
