# Quick start: `make demo` (set up + flagship study) and `make test` (set up + tests).
PYTHON ?= python3.11
VENV   ?= .venv
PY      = $(VENV)/bin/python
OUT    ?= results

.PHONY: setup demo test lint typecheck format bench clean

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
	# 12-14 % less CPU than with a 0.2 s floor, the first process within 4 %); XLA's CPU backend
	# emits fusions without its MLIR fusion emitters (--xla_cpu_use_fusion_emitters=false):
	# compiling is most of the suite's CPU (session 25, s25-ci25b, paired runs, fresh JAX cache,
	# jaxlib 0.10.2: -18 % over the four heaviest files, measured beside the flag named below; alone
	# 20.3 -> 16.9 s on a head-layout test); the same operations, up to round-off (five
	# diagnoses: verdicts and reports equal, effects to 4e-11 relative); the tests' children
	# that choose their own device count keep it (tests/helpers.py env_without_device_count).
	# Not --xla_backend_optimization_level=0 (LLVM's passes off; s25-ci25: -22-24 % on the
	# design files): under it the SDS seed instruments' forward-mode Jacobian had NaN entries
	# (tests/test_seed_calibration.py, a fresh clone's CI, session 25), so it changes results.
	# A jaxlib that does not know a flag aborts at start-up, so each flag is first tried on a
	# one-line program and left out where that fails (slower, not red)
	flags=""; for f in --xla_cpu_use_fusion_emitters=false; do \
	  XLA_FLAGS="$$flags $$f" $(PY) -c "import jax; jax.jit(lambda x: x + 1)(1.0)" >/dev/null 2>&1 \
	    && flags="$$flags $$f" || echo "XLA flag $$f unknown to this jaxlib: left out"; \
	done; echo "tests compile with XLA_FLAGS=$$flags"; \
	JAX_COMPILATION_CACHE_DIR=$(CURDIR)/.cache/jax JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS=0 \
	XLA_FLAGS="$$flags" \
	OPENBLAS_NUM_THREADS=1 OMP_NUM_THREADS=1 $(PY) -m pytest -q -p no:cacheprovider -n 2 --dist worksteal --durations=25 tests

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
