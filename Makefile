# Two commands: `make demo` runs the main job, `make test` runs the tests. Each sets up .venv first.
# `make mutation` (not in CI: hours on 2 vCPUs) runs mutmut over the core modules and writes
# mutation-report.txt; MUTATION_ARGS passes options, e.g. MUTATION_ARGS="safety --budget-scale 0.5"
# or MUTATION_ARGS="wbc --sample 200 --seed 1".
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
export OMP_NUM_THREADS ?= 1
export OPENBLAS_NUM_THREADS ?= 1

.PHONY: demo test bench install clean mutation

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,train,video,ray,plot,foxglove,dds]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/giwbc demo

test: $(STAMP)
	$(BIN)/lint-imports --no-cache
	$(BIN)/python -m pytest -q tests

bench: $(STAMP)
	@for b in benchmarks/*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

mutation: $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[mutation]'
	$(BIN)/python tools/mutation.py $(MUTATION_ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .hypothesis .mutation mutants
