"""How many CPU devices JAX gets: one per core by default (``docs/scale.md``).

XLA:CPU runs one program on one device; its own thread pool parallelises only parts of a
program (measured on 2 cores: 1.2-1.5x at best, and slower than one pinned core under
load). Several CPU devices run the slices of a split program side by side, one per core:
the Monte Carlo drivers (:func:`encdesign.design.shard_builds`) and
:func:`encdesign.head_errors_batch` split their builds or designs over them. So at import,
before JAX starts its backend, encdesign asks for one CPU device per core this process may
run on (``os.sched_getaffinity``; the number per core is read from ``_tuning.json``,
written from a measured sweep: ``benchmarks/kinematics_sweep.py``), unless

* the user chose already: ``--xla_force_host_platform_device_count`` in ``XLA_FLAGS``,
  ``JAX_NUM_CPU_DEVICES`` or ``jax.config.jax_num_cpu_devices`` set, or the JAX backend
  already started (then nothing is changed, silently);
* ``ENCDESIGN_CPU_DEVICES=N`` is set: N devices (an integer >= 1);
* ``OMP_NUM_THREADS=N`` is set: at most N devices (the usual "threads per process" of a
  job that runs several processes side by side, e.g. ``pytest -n 2`` with
  ``OMP_NUM_THREADS=1``: one device each, exactly as before).

Values do not depend on the count: every design or build is computed by the same
per-item program wherever it runs (agreement with one device to 1e-13 relative is tested).
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import jax

from . import _tuning

ENV = "ENCDESIGN_CPU_DEVICES"
DEVICES_PER_CORE = _tuning.DEVICES_PER_CORE  # measured: _tuning.json says where from


def _positive_int(env: Mapping[str, str], name: str) -> int | None:
    text = env.get(name, "").strip()
    if not text:
        return None
    if not text.isdigit() or int(text) < 1:
        from ._errors import input_error

        raise input_error(f"environment variable {name}", f"{text!r}", "an integer >= 1")
    return int(text)


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def choose_cpu_devices(env: Mapping[str, str], n_cores: int) -> int | None:
    """The CPU device count for environment ``env`` on ``n_cores`` cores, or ``None`` when
    the user chose already (``XLA_FLAGS``' device count or ``JAX_NUM_CPU_DEVICES``). An
    ``ENCDESIGN_CPU_DEVICES`` or ``OMP_NUM_THREADS`` that is not an integer >= 1 is an
    input error naming the variable."""
    if "xla_force_host_platform_device_count" in env.get("XLA_FLAGS", ""):
        return None
    if env.get("JAX_NUM_CPU_DEVICES", "").strip():
        return None
    chosen = _positive_int(env, ENV)
    if chosen is not None:
        return chosen
    n = max(1, round(max(int(n_cores), 1) * DEVICES_PER_CORE))
    omp = _positive_int(env, "OMP_NUM_THREADS")
    return n if omp is None else min(n, omp)


def default_cpu_devices() -> int | None:
    """The CPU device count encdesign asks for here and now, or ``None`` when it leaves JAX
    alone (the user chose, or the backend has started)."""
    from jax._src import xla_bridge

    if jax.config.jax_num_cpu_devices >= 0 or xla_bridge.backends_are_initialized():
        return None
    return choose_cpu_devices(os.environ, cores())


def configure() -> None:
    """Set ``jax_num_cpu_devices`` from :func:`default_cpu_devices` (at import)."""
    n = default_cpu_devices()
    if n is not None and n > 1:
        jax.config.update("jax_num_cpu_devices", n)
