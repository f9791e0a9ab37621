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

EXTRAS := test,bench,video,physics
# every set-up step says what it does, then a line every 8 s while it runs (pip adds its own
# lines, one per package), then how long it took: nothing waits silently
STEP = @echo "== $(1)"; start=$$(date +%s); \
	( while sleep 8; do echo "   ... $(1): $$(( $$(date +%s) - start )) s"; done ) & tick=$$!; \
	$(2); status=$$?; kill $$tick 2>/dev/null; \
	if [ $$status -eq 0 ]; then echo "== $(1): done in $$(( $$(date +%s) - start )) s"; \
	else echo "== $(1): failed (status $$status)"; exit $$status; fi

$(STAMP): pyproject.toml
	$(call STEP,creating $(VENV),$(PYTHON) -m venv $(VENV))
	$(call STEP,upgrading pip,$(BIN)/pip install --progress-bar off --upgrade pip)
	$(call STEP,installing sqpmpc and its dependencies,\
		$(BIN)/pip install --progress-bar off -e ".[$(EXTRAS)]")
	touch $(STAMP)

# a new run folder each time: runs/paper-s2-decentralized-lockstep-<time>
demo: $(STAMP)
	$(call STEP,compiling the kernels (once; later loaded from the cache),\
		$(BIN)/python -m sqpmpc.kernels)
	$(call STEP,the demo: paper-s2 as a plant and 4 robot processes over Zenoh,\
		$(BIN)/python -m services.launch --scenario paper-s2 --scheme decentralized)

# the tests in one worker per core (pytest-xdist): most wait on a process or use one core
test: $(STAMP)
	$(BIN)/ruff check sqpmpc services tests benchmarks examples docs
	$(BIN)/python docs/build.py --quiet --site-dir site
	$(call STEP,compiling the bounds-checked kernels,$(CHECKED) $(BIN)/python -m sqpmpc.kernels)
	$(CHECKED) $(BIN)/pytest -q -n auto

# the site (tutorial, how-to guides, reference, explanation and reports) into site/;
# docs/build.py fails on any warning, also with --quiet
docs: $(STAMP)
	$(BIN)/python docs/build.py --site-dir site

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
