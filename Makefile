# The README's quick start: `make serve` and `make test`. Each makes or reuses .venv first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.sweepcast-installed
KERNELS := sweepcast-data/cache/numba/.warmed

.PHONY: serve test bench openapi clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# Every engine's kernels compiled once, before the first serve, into ./sweepcast-data/cache/numba (the cache
# serve and the tests use): no first request waits for a compile. Kernels changed since are compiled by
# serve's background warm-up. Then the demo's recording, rendered into ./sweepcast-data/cache/demo: the first
# start publishes it as the demo's recording, and the first viewer does not wait for it.
$(KERNELS): $(STAMP)
	$(BIN)/sweepcast warmup
	touch $(KERNELS)

serve: $(KERNELS)
	$(BIN)/sweepcast serve

test: $(STAMP)
	$(BIN)/python -m pytest -q

openapi: $(STAMP)
	$(BIN)/sweepcast openapi

clean:
	rm -rf $(VENV) sweepcast-data .pytest_cache
