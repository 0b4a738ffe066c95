# heurtune: `make run` sets up and runs the main job, `make test` sets up and runs the tests.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: setup run test test-long test-all portability lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# numba's cache filled once with the shipped experiments' kernels (seconds when it is full), so
# that runs, tests and worker processes load them instead of each compiling its own.
PRECOMPILE := $(BIN)/python -m heurtune.precompile --quiet

setup: $(STAMP)
	$(PRECOMPILE)

# Main job: the thesis' CS/FOLQI experiment on the QTP (8 seeded runs per case), results and
# figures in results/cs_folqi_qtp/; re-running resumes.
JOBS ?= $(shell nproc 2>/dev/null || echo 1)
run: $(STAMP)
	$(BIN)/python -m heurtune.experiment cs_folqi_qtp --jobs $(JOBS)

# Two worker processes, each test file on one of them (pytest-xdist; `--dist loadfile` keeps a
# file's module-level caches and compiled kernels in one process), the longest files first
# (tests/conftest.py). TEST_WORKERS=0 runs in-process; PYTEST_ARGS adds options (--durations=20).
# `make test` is the five-minute suite: every test but those marked `long` (a fresh compilation of
# every kernel, the papers' and the sampled release's end-to-end reproductions, the densest
# references); `make test-long` runs those, `make test-all` both tiers in one call. CI runs
# `make test` and `make test-long` (docs/testing.md, "Two tiers").
TEST_WORKERS ?= 2
PYTEST_ARGS ?=
PYTEST := $(BIN)/pytest -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder
test: $(STAMP)
	$(PRECOMPILE)
	$(PYTEST) -m "not long" $(PYTEST_ARGS)

test-long: $(STAMP)
	$(PRECOMPILE)
	$(PYTEST) -m long $(PYTEST_ARGS)

test-all: $(STAMP)
	$(PRECOMPILE)
	$(PYTEST) $(PYTEST_ARGS)

# The numerical tests with numba's generic x86-64 target (no AVX, no FMA) and a cache of their
# own, in a fresh process: a test that holds only on this CPU's instruction set fails here
# (docs/testing.md). The first call compiles every kernel into .numba-generic/.
PORTABLE_CACHE ?= $(CURDIR)/.numba-generic
portability: $(STAMP)
	NUMBA_CPU_NAME=generic NUMBA_CACHE_DIR=$(PORTABLE_CACHE) $(BIN)/python -m heurtune.precompile --quiet
	NUMBA_CPU_NAME=generic NUMBA_CACHE_DIR=$(PORTABLE_CACHE) $(BIN)/pytest -n $(TEST_WORKERS) --dist loadfile \
		--no-loadscope-reorder \
		-p no:cacheprovider tests/objectives tests/core tests/algorithms tests/plugins tests/runner/test_sampled_release.py

# ruff with the rule set of pyproject.toml ([tool.ruff]); .ci/run lints before it tests.
lint: $(STAMP)
	$(BIN)/ruff check .

bench: $(STAMP)
	$(BIN)/python benchmarks/bench_evaluate.py
	$(BIN)/python benchmarks/bench_study_candidates.py
	$(BIN)/python benchmarks/bench_engine.py
	$(BIN)/python benchmarks/bench_robust.py
	$(BIN)/python benchmarks/bench_tito_margins.py
	$(BIN)/python benchmarks/bench_qtp_margins.py
	$(BIN)/python benchmarks/work_precision_tito.py
	$(BIN)/python benchmarks/bench_batch.py --gpu
	$(BIN)/python benchmarks/work_precision.py
	$(BIN)/python benchmarks/step_rule.py
	# the tree's continuous kernels against the last commit's, bit for bit and side by side (REV=... for another)
	$(BIN)/python benchmarks/kernels_side_by_side.py --rev $(or $(REV),HEAD)
	if $(BIN)/python -c "import pymoo" 2>/dev/null; then $(BIN)/python benchmarks/bench_sms_emoa.py; \
	else echo "bench_sms_emoa: skipped (pymoo not installed: pip install 'heurtune[pymoo]')"; fi

clean:
	rm -rf $(VENV) results build *.egg-info .numba-generic
