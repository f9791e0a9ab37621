# sqpmpc: `make demo` runs the distributed demo, `make test` the checks.
# Both create the virtual environment .venv from pyproject.toml on first use.
# The tests run the compiled kernels with bounds checks (an index error instead of a crash).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
# bounds-checked kernels, cached apart from the fast ones (numba's cache ignores the flag)
CHECKED := NUMBA_BOUNDSCHECK=1 NUMBA_CACHE_DIR=$(VENV)/numba-cache-checked

.PHONY: demo test docs lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e ".[test,bench,video,physics]"
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/python -m sqpmpc.kernels
	$(BIN)/python -m services.launch --scenario paper-s2 --scheme decentralized --out runs/demo

test: $(STAMP)
	$(BIN)/ruff check sqpmpc services tests benchmarks examples docs
	$(BIN)/mkdocs build --strict --quiet --site-dir site
	$(CHECKED) $(BIN)/python -m sqpmpc.kernels
	$(CHECKED) $(BIN)/pytest -q

# the API reference (from the docstrings) and the reports, into site/ (mkdocs.yml)
docs: $(STAMP)
	$(BIN)/mkdocs build --strict --site-dir site

bench: $(STAMP)
	$(BIN)/python -m benchmarks.compare_ipopt
	$(BIN)/python -m benchmarks.liveness
	$(BIN)/python -m benchmarks.random_scenarios
	$(BIN)/python -m benchmarks.decomposition
	$(BIN)/python -m benchmarks.qp_backends
	$(BIN)/python -m benchmarks.fleet
	$(BIN)/python -m benchmarks.fleet_services
	$(BIN)/python -m benchmarks.real_plants
	$(BIN)/python -m benchmarks.bench_services
	$(BIN)/python -m benchmarks.faults
	$(BIN)/python -m benchmarks.lifecycle
	$(BIN)/python -m benchmarks.security
	$(BIN)/python -m benchmarks.physical

clean:
	rm -rf $(VENV) runs site .pytest_cache .ruff_cache
