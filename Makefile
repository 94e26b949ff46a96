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

# the commands write only under results/; the script then copies their JSON into docs/data/ and rewrites
# docs/results.md and docs/performance.md from docs/data/ (`python scripts/update_readme.py all`: no run)
run: $(STAMP)
	$(BIN)/bayes-mr run --out results
	$(BIN)/python scripts/update_readme.py run --out results

# one pytest worker per core, at most 4 (on an empty kernel cache each worker compiles what its tests need); worksteal
# hands a worker that runs out of tests another's, so one long test does not keep the rest waiting
PYTEST_WORKERS ?= -n auto --maxprocesses=4 --dist worksteal
test: $(STAMP)
	$(BIN)/python -m pytest $(PYTEST_WORKERS)

test-slow: $(STAMP)
	$(BIN)/python -m pytest $(PYTEST_WORKERS) -m slow

# on a quiet machine; BENCH_FLAGS="--boucwen --compare" adds the Bouc–Wen benchmark fit and the compare timing
BENCH_FLAGS ?=
bench: $(STAMP)
	$(BIN)/bayes-mr bench $(BENCH_FLAGS) --json results/bench.json
	$(BIN)/python scripts/update_readme.py bench --json results/bench.json

clean:
	rm -rf $(VENV) results .pytest_cache
