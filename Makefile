# Quick start: `make demo` (set up + flagship study) and `make test` (set up + tests).
PYTHON ?= python3.11
VENV   ?= .venv
PY      = $(VENV)/bin/python
OUT    ?= results

.PHONY: setup demo test test-sweeps lint typecheck format bench clean

$(VENV)/.installed: pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "$(PYTHON) not found; run make PYTHON=python3"; exit 1; }
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e ".[dev]"
	@touch $@

setup: $(VENV)/.installed

demo: setup
	$(VENV)/bin/encdesign study run cramer --out $(OUT)/cramer --json $(OUT)/cramer/cramer.json
	$(VENV)/bin/encdesign study run reference-head --out $(OUT)/reference-head --json $(OUT)/reference-head/reference-head.json
	@echo "figures and JSON written under $(OUT)/"

test: setup
	$(VENV)/bin/ruff check encdesign studies tests benchmarks
	$(VENV)/bin/ruff format --check encdesign studies tests benchmarks
	$(VENV)/bin/basedpyright --pythonpath $(PY)
	# single-threaded BLAS: the finders' many small least-squares solves run far slower
	# with threads competing for 2 cores; two pytest workers (pytest-xdist), one per core;
	# worksteal: an idle worker takes tests queued on the other (no idle tail); JAX's persistent
	# compilation cache under .cache/jax lets the workers and the tests' subprocesses (two-process
	# diagnoses, the notebook's kernel, CLI runs) reuse each other's compiled programs
	# (compilation is most of a quick study's time; about 14 % less CPU on the slowest files);
	# every program is cached, however quick its compile (a second process on the same tests:
	# 12-14 % less CPU than with a 0.2 s floor, the first process within 4 %). No XLA_FLAGS
	# (session 25): --xla_backend_optimization_level=0 gave NaN in the SDS seed instruments'
	# forward-mode Jacobian (tests/test_seed_calibration.py) and --xla_cpu_use_fusion_emitters=false
	# made the Monte Carlo drivers' values depend on the chunking (tests/test_drivers.py), each
	# on a fresh clone's CI, and the latter saved no wall time there (pytest 909 s)
	JAX_COMPILATION_CACHE_DIR=$(CURDIR)/.cache/jax JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 \
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest -q -p no:cacheprovider -n 2 --dist worksteal --durations=25 -m "not sweep" tests

# the verdict guards' further seeds and settings (pytest marker `sweep`, docs/DEVELOPING.md
# "Test tiers"): not in `make test` (CI time); run them before merging a change to the finder
test-sweeps: setup
	JAX_COMPILATION_CACHE_DIR=$(CURDIR)/.cache/jax JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 \
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest -q -p no:cacheprovider -n 2 --dist worksteal --durations=25 -m sweep tests

lint: setup
	$(VENV)/bin/ruff check encdesign studies tests benchmarks

# static types of the package ([tool.basedpyright] in pyproject.toml, docs/DEVELOPING.md)
typecheck: setup
	$(VENV)/bin/basedpyright --pythonpath $(PY)

format: setup
	$(VENV)/bin/ruff format encdesign studies tests benchmarks
	$(VENV)/bin/ruff check --fix encdesign studies tests benchmarks

bench: setup
	$(PY) benchmarks/kinematics.py --json $(OUT)/bench-kinematics.json

clean:
	rm -rf $(VENV) $(OUT)
