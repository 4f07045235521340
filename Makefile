# The README's quick start: `make serve` and `make test`. Each makes or reuses .venv first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.sweepcast-installed
KERNELS := $(VENV)/.sweepcast-warmed
DOCS_STAMP := $(VENV)/.sweepcast-docs
BENCH_STAMP := $(VENV)/.sweepcast-bench

.PHONY: serve test docs bench openapi wheel clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# Every engine's kernels compiled once, before the first serve, into this user's kernel cache
# (~/.cache/sweepcast/kernels, which serve uses for any data folder): no first request waits for a compile.
# Kernels changed since are compiled by serve's background warm-up. Then the demo's recording, rendered into
# ~/.cache/sweepcast/demo: the first start publishes it as the demo's recording, and the first viewer does not
# wait for it.
$(KERNELS): $(STAMP)
	$(BIN)/sweepcast warmup
	touch $(KERNELS)

serve: $(KERNELS)
	$(BIN)/sweepcast serve

# The suite in TEST_PROCESSES processes (pytest-xdist; each has its own local Ray): the kernels are compiled first,
# one process each (tests/conftest.py). TEST_PROCESSES=0 runs it in this one process.
TEST_PROCESSES ?= 2
test: $(STAMP)
	$(BIN)/python -m pytest -q -n $(TEST_PROCESSES)

# The user documentation (docs/, mkdocs.yml) as a site in ./site: --strict fails on a broken link or anchor.
$(DOCS_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[docs]'
	touch $(DOCS_STAMP)

docs: $(DOCS_STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict

# One benchmark of benchmarks/, run as a module with the bench extra: make bench NAME=sweep ARGS="--only speed --quick"
# (python -m benchmarks.sweep --help / --list: its options and sections). It writes benchmarks/RESULTS.md.
$(BENCH_STAMP): $(STAMP)
	$(BIN)/python -m pip install --quiet -e '.[bench]'
	touch $(BENCH_STAMP)

bench: $(BENCH_STAMP)
	@test -n "$(NAME)" || { echo "usage: make bench NAME=<one of: $$(ls benchmarks | sed -n 's/^\([a-z][a-z_]*\)\(\.py\)\{0,1\}$$/\1/p' | grep -v '^\(results\|bd\|tests\)$$' | tr '\n' ' ')> [ARGS=...]"; exit 2; }
	$(BIN)/python -m benchmarks.$(NAME) $(ARGS)

# A wheel for `pip install` that carries every engine's kernels (compiled for x86-64-v3) and the demo recording, so
# that its first `sweepcast serve` compiles and renders nothing: dist/sweepcast-*.whl (packaging/build-wheel.sh).
wheel: $(STAMP)
	PYTHON=$(BIN)/python bash packaging/build-wheel.sh dist

openapi: $(STAMP)
	$(BIN)/sweepcast openapi

clean:
	rm -rf $(VENV) sweepcast-data .pytest_cache site dist
