# The README's quick start: `make serve` and `make test`. Each makes or reuses .venv first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.sweepcast-installed

.PHONY: serve test bench openapi clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	# every engine's kernels compiled once, here, into ./sweepcast-data/cache/numba (serve's and the tests'):
	# no first request waits for a compile
	$(BIN)/sweepcast warmup
	touch $(STAMP)

serve: $(STAMP)
	$(BIN)/sweepcast serve

test: $(STAMP)
	$(BIN)/python -m pytest -q

openapi: $(STAMP)
	$(BIN)/sweepcast openapi

clean:
	rm -rf $(VENV) sweepcast-data .pytest_cache
