"""Drivers: the solvers a design problem is handed to.

A driver takes a function and returns a result with a ``status``; it never returns a bad
number silently. Statuses are plain strings (:data:`SUCCESS`, :data:`MAX_STEPS`,
:data:`STALLED`, :data:`AT_BOUND`, :data:`NONFINITE`, :data:`BOUNDS_VIOLATED`,
:data:`INFEASIBLE`, :data:`FAILED`); with ``throw=True`` a result that is not an answer
(anything but :data:`SUCCESS` and :data:`AT_BOUND`) raises :class:`OptimisationError`
instead. :data:`AT_BOUND` is a converged answer with a variable on its bound (a valid
optimum of the bounded problem, but never reported as plain success: the bound decides it);
:data:`STALLED` is a line search that made no progress (no decrease from the start, a step
size collapsed to nothing, or a "converged" stop with a quasi-Newton step that still
predicts a real decrease).

* :func:`optimise` — gradient solvers: optimistix BFGS (``"bfgs"``), optimistix
  Levenberg–Marquardt (``"lm"``, the function returns a residual vector) and jaxopt
  L-BFGS-B (``"lbfgsb"``, bounds always hold).
* :func:`monte_carlo` / :func:`expected_value` — Monte Carlo over builds with common random
  numbers: build ``i`` of key ``k`` is always the same standard-normal vector
  ``normal(fold_in(k, i))``, whatever the chunking, so expected objectives are smooth,
  deterministic functions of the design and can be differentiated.
* :func:`grid_points`, :func:`latin_hypercube`, :func:`doe` — design of experiments.
* :func:`enumerate_designs` — enumeration of discrete variables wrapped around a
  continuous solve.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._errors import OptimisationError as OptimisationError
from .._progress import progress_bar
from ._distributed import chunk_plan, gather_chunks, is_main_process, n_build_shards, shard_builds

with warnings.catch_warnings():
    warnings.filterwarnings(
        "ignore", message="JAXopt is no longer maintained", category=DeprecationWarning
    )
    import jaxopt

SUCCESS = "success"
MAX_STEPS = "max_steps_reached"
NONFINITE = "nonfinite"
BOUNDS_VIOLATED = "bounds_violated"
INFEASIBLE = "infeasible"
FAILED = "failed"
STALLED = "line_search_stalled"
AT_BOUND = "at_bound"
STATUSES = (SUCCESS, MAX_STEPS, STALLED, AT_BOUND, NONFINITE, BOUNDS_VIOLATED, INFEASIBLE, FAILED)
ANSWERS = (SUCCESS, AT_BOUND)
"""Statuses whose value is a converged answer (an at-bound optimum is one, marked)."""
STEP_COLLAPSE = 1e-12
"""A final line-search step size (or trust-region radius) below this: the search collapsed."""
STALL_FACTOR = 1e3
"""A "converged" BFGS stop is stalled when its quasi-Newton step still predicts a decrease
over ``STALL_FACTOR`` times the stopping tolerance ``atol + rtol * |f|``."""
BOUND_RTOL = 1e-9
"""A variable within ``BOUND_RTOL * max(1, bound width)`` of a bound is at that bound."""
SOLVERS = ("bfgs", "lbfgsb", "lm")


def _finish(result: Any, throw: bool) -> Any:
    if throw and result.status not in ANSWERS:
        raise OptimisationError(f"{type(result).__name__}: {result.status}: {result.message}")
    return result


# ---------------------------------------------------------------------------------------
# gradient solvers


@dataclasses.dataclass(frozen=True)
class Solution:
    """Result of :func:`optimise`.

    Attributes:
        value: the solution (1-D float64 array, in the units of ``y0``).
        objective: the objective at ``value`` (for ``"lm"``: half the sum of squared
            residuals).
        status: one of :data:`STATUSES`.
        n_steps: solver iterations taken.
        solver: ``"bfgs"``, ``"lm"`` or ``"lbfgsb"``.
        message: a human-readable account of the status.
        at_bounds: the components on a bound at ``value``, as ``"lower[i]"`` /
            ``"upper[i]"`` (empty when none).
    """

    value: np.ndarray
    objective: float
    status: str
    n_steps: int
    solver: str
    message: str = ""
    at_bounds: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when ``status == "success"``."""
        return self.status == SUCCESS


def _as_bounds(bound: Any, n: int, fill: float) -> np.ndarray:
    if bound is None:
        return np.full(n, fill)
    b = np.broadcast_to(np.asarray(bound, dtype=np.float64), (n,)).copy()
    return b


@functools.lru_cache(maxsize=128)
def _scalar_fn(fn: Callable[[jax.Array, Any], jax.Array]) -> Callable[[jax.Array, Any], jax.Array]:
    """``fn`` with its output reshaped to a scalar (cached, so jit caches stay warm when
    the same ``fn`` is optimised again with other ``args`` or bounds)."""
    return lambda y, a: jnp.reshape(fn(y, a), ())


@functools.lru_cache(maxsize=128)
def _lbfgsb(fn: Callable[[jax.Array, Any], jax.Array], max_steps: int, gtol: float):
    """The L-BFGS-B solve of ``fn`` and ``fn`` at its solution, compiled as one program
    once per ``fn`` and cached: new bounds, starts or ``args`` (of the same shapes) never
    recompile (run eagerly, jaxopt's while-loop is compiled again on every run, and an
    eager evaluation of ``fn`` compiles its loops and scans again on every call)."""
    solver = jaxopt.LBFGSB(
        fun=jax.value_and_grad(fn), value_and_grad=True, maxiter=max_steps, tol=gtol
    )

    def run(y0, bounds, args):
        value, state = solver.run(y0, bounds, args)
        return value, state, fn(value, args)

    return jax.jit(run)


@functools.lru_cache(maxsize=128)
def _optx(fn: Callable[[jax.Array, Any], jax.Array], solver: str, rtol, atol, max_steps: int):
    """The optimistix solve of ``fn`` and ``fn`` at its solution, compiled as one program
    once per ``fn`` and settings and cached (``equinox.filter_jit``: non-array ``args``
    are static, as in ``optimistix``)."""

    @eqx.filter_jit
    def run(y0, args):
        if solver == "bfgs":
            sol = optx.minimise(
                fn, optx.BFGS(rtol=rtol, atol=atol), y0, args, max_steps=max_steps, throw=False
            )
        else:
            sol = optx.least_squares(
                fn,
                optx.LevenbergMarquardt(rtol=rtol, atol=atol),
                y0,
                args,
                max_steps=max_steps,
                throw=False,
            )
        return sol, fn(sol.value, args)

    return run


def optimise(
    fn: Callable[[jax.Array, Any], jax.Array],
    solver: str,
    y0: Any,
    args: Any = None,
    *,
    lower: Any = None,
    upper: Any = None,
    max_steps: int = 256,
    rtol: float = 1e-8,
    atol: float = 1e-12,
    gtol: float = 1e-8,
    throw: bool = False,
) -> Solution:
    """Minimise ``fn(y, args)`` from ``y0`` with a gradient solver.

    Args:
        fn: ``fn(y, args)``: a scalar for ``"bfgs"`` / ``"lbfgsb"``, a residual vector for
            ``"lm"`` (which minimises ``0.5 * sum(r**2)``). Must be JAX-differentiable.
        solver: ``"bfgs"`` (optimistix BFGS), ``"lm"`` (optimistix Levenberg–Marquardt) or
            ``"lbfgsb"`` (jaxopt L-BFGS-B; iterates always stay inside the bounds).
        y0: start point, 1-D (any units; ``fn`` defines them).
        args: passed through to ``fn``.
        lower, upper: bounds (scalar or per component; ``None`` = unbounded). ``"lbfgsb"``
            enforces them; for ``"bfgs"``/``"lm"`` a solution outside them gets status
            ``"bounds_violated"``.
        max_steps: iteration limit (status ``"max_steps_reached"`` when hit).
        rtol, atol: optimistix convergence tolerances (relative/absolute, on steps and
            values).
        gtol: L-BFGS-B convergence: projected-gradient norm (units of ``fn`` per unit of
            ``y``).
        throw: raise :class:`OptimisationError` unless the status is ``"success"`` or
            ``"at_bound"``.

    Statuses: ``"success"`` (converged, no variable on a bound); ``"at_bound"`` (converged
    with components on a bound, listed in ``at_bounds``: for ``"lbfgsb"`` the box, for the
    others a solution that touches a bound); ``"max_steps_reached"``;
    ``"line_search_stalled"`` (a line-search step size or trust-region radius below
    :data:`STEP_COLLAPSE`: no decrease found along the search direction; a failed L-BFGS-B
    line search or an L-BFGS-B stop before the cap without convergence, or a BFGS stop on a small
    step whose quasi-Newton step still predicts a decrease over :data:`STALL_FACTOR` times
    the stopping tolerance); ``"nonfinite"``; ``"bounds_violated"``; ``"failed"``.

    Passing the same ``fn`` again (with other ``args``, bounds or start) reuses the
    compiled solver; put anything that changes between solves into ``args``.

    Returns:
        A :class:`Solution`; its ``objective`` is re-evaluated at ``value`` and a
        non-finite value or objective gives status ``"nonfinite"``.
    """
    if solver not in SOLVERS:
        from .._errors import input_error

        raise input_error("solver", f"unknown solver {solver!r}", f"one of {', '.join(SOLVERS)}")
    y0 = jnp.atleast_1d(jnp.asarray(y0, dtype=jnp.float64))
    n = y0.shape[0]
    lo, hi = _as_bounds(lower, n, -np.inf), _as_bounds(upper, n, np.inf)
    if solver != "lm":
        fn = _scalar_fn(fn)
    if solver == "lbfgsb":
        y0 = jnp.clip(y0, lo, hi)
        run = _lbfgsb(fn, int(max_steps), float(gtol))
        value, state, out = run(y0, (jnp.asarray(lo), jnp.asarray(hi)), args)
        status, message, n_steps = _lbfgsb_status(state, gtol, int(max_steps))
    else:
        sol, out = _optx(fn, solver, float(rtol), float(atol), int(max_steps))(y0, args)
        value = sol.value
    value_np = np.asarray(value, dtype=np.float64)
    objective = float(0.5 * jnp.sum(out**2)) if solver == "lm" else float(out)
    if solver != "lbfgsb":
        status, message, n_steps = _optx_status(sol, solver, objective, rtol, atol)
    at = _at_bounds(value_np, lo, hi)
    if status in (SUCCESS, MAX_STEPS, STALLED):
        if not (np.all(np.isfinite(value_np)) and math.isfinite(objective)):
            status, message = NONFINITE, "non-finite solution or objective"
        elif status == SUCCESS and (np.any(value_np < lo) or np.any(value_np > hi)):
            status, message = BOUNDS_VIOLATED, f"solution {value_np} outside [{lo}, {hi}]"
        elif at:
            if status == SUCCESS:
                status, message = AT_BOUND, f"converged on the bound: {', '.join(at)}"
            else:
                message = f"{message}; on the bound: {', '.join(at)}"
    res = Solution(value_np, objective, status, n_steps, solver, message, tuple(at))
    return _finish(res, throw)


def _at_bounds(value: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[str]:
    """The components of ``value`` within :data:`BOUND_RTOL` of a finite bound."""
    width = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    tol = BOUND_RTOL * np.maximum(1.0, width)
    out = []
    for i in range(value.size):
        if math.isfinite(lo[i]) and value[i] - lo[i] <= tol[i]:
            out.append(f"lower[{i}]")
        elif math.isfinite(hi[i]) and hi[i] - value[i] <= tol[i]:
            out.append(f"upper[{i}]")
    return out


def _lbfgsb_status(state: Any, gtol: float, max_steps: int) -> tuple[str, str, int]:
    """Status of a jaxopt L-BFGS-B run: converged (projected gradient <= ``gtol``), a
    failed line search or a collapsed step size (stalled), the step cap, or non-finite."""
    n_steps = int(state.iter_num)
    err = float(state.error)
    if not math.isfinite(err):
        return NONFINITE, "non-finite projected gradient", n_steps
    if err <= gtol:
        return SUCCESS, "converged", n_steps
    detail = f"{n_steps} steps, projected-gradient norm {err:.3g} > gtol {gtol:.3g}"
    step = float(state.stepsize)
    if bool(state.failed_linesearch) or (0 < step < STEP_COLLAPSE):
        return STALLED, f"line search failed (step size {step:.3g}): {detail}", n_steps
    if n_steps < max_steps:
        return STALLED, f"stopped before the step cap without converging: {detail}", n_steps
    return MAX_STEPS, detail, n_steps


_OPTX_STATUS = {
    "nonlinear_max_steps_reached": MAX_STEPS,
    "max_steps_reached": MAX_STEPS,
    "nonfinite": NONFINITE,
    "nonfinite_input": NONFINITE,
}


def _optx_status(sol: Any, solver: str, f: float, rtol: float, atol: float) -> tuple[str, str, int]:
    """Status of an optimistix run: its result, then a collapsed line-search step size
    (trust-region radius for ``"lm"``) as stalled, and for BFGS a "converged" stop whose
    quasi-Newton step still predicts a decrease over :data:`STALL_FACTOR` times the
    stopping tolerance (the step, not the objective, became small) as stalled."""
    n_steps = int(sol.stats.get("num_steps", -1))
    status, message = SUCCESS, "converged"
    if sol.result != optx.RESULTS.successful:
        name = next(
            (k for k in _OPTX_STATUS if hasattr(optx.RESULTS, k)
             and sol.result == getattr(optx.RESULTS, k)),
            None,
        )  # fmt: skip
        status = _OPTX_STATUS.get(name or "", FAILED)
        message = f"optimistix: {name or 'failed'} after {n_steps} steps"
    state = getattr(sol, "state", None)
    if status not in (SUCCESS, MAX_STEPS) or state is None:
        return status, message, n_steps
    step = float(state.search_state.step_size)
    if step < STEP_COLLAPSE:
        return (
            STALLED,
            f"line search collapsed (step size {step:.3g}) after {n_steps} steps",
            n_steps,
        )
    info = state.f_info
    if status == SUCCESS and solver == "bfgs" and hasattr(info, "hessian_inv"):
        g = info.grad
        pred = 0.5 * float(jnp.vdot(g, info.hessian_inv.mv(g)))
        tol = atol + rtol * abs(f)
        if not math.isfinite(pred) or pred > STALL_FACTOR * tol:
            return (
                STALLED,
                f"stopped on a small step, but the quasi-Newton step still predicts a decrease "
                f"of {pred:.3g} (> {STALL_FACTOR:g} x tolerance {tol:.3g}) after {n_steps} steps",
                n_steps,
            )
    return status, message, n_steps


# ---------------------------------------------------------------------------------------
# Monte Carlo with common random numbers


def build_normals(key: jax.Array, index: jax.Array, dim: int) -> jax.Array:
    """Standard-normal vectors of builds ``index`` (any shape) for ``key``: ``[..., dim]``.

    Build ``i`` is ``normal(fold_in(key, i), (dim,))``: the same for any chunking, which
    is what makes the random numbers common between designs.
    """
    flat = jnp.ravel(index)
    z = jax.vmap(lambda i: jax.random.normal(jax.random.fold_in(key, i), (dim,)))(flat)
    # materialise z: without the barrier XLA may fuse the random-number generation into
    # every elementwise consumer and recompute it per reading (measured: the Monte Carlo
    # objective ran 1.8x slower)
    return jax.lax.optimization_barrier(z.reshape((*jnp.shape(index), dim)))


VECTOR_BUILDS = 8  # builds vectorised together: a working set that stays in the CPU caches


def values_of_normals(fn_z: Callable[[jax.Array], jax.Array], z: jax.Array, vector: int):
    """``fn_z`` on every row of ``z [B, dim]`` (``B`` a multiple of ``vector``): ``lax.map``
    over groups of ``vector`` rows, ``vmap`` within a group; returns ``[B]``."""
    groups = z.reshape(-1, vector, z.shape[-1])
    return jax.lax.map(jax.vmap(fn_z), groups).reshape(-1)


def map_builds(
    fn_z: Callable[[jax.Array], jax.Array],
    key: jax.Array,
    n: int,
    dim: int,
    *,
    first: int = 0,
    block: int = 512,
    vector: int = VECTOR_BUILDS,
    manual: bool = False,
) -> jax.Array:
    """Traceable per-build values ``fn_z(z_i)`` for builds ``first … first + n - 1`` of
    ``key`` (:func:`build_normals`), ``[n]``.

    Memory is bounded at any ``n``: the random numbers are drawn ``block`` builds at a
    time (rounded up to a multiple of ``vector``) and the builds are vectorised ``vector``
    at a time (small groups keep the working set in the CPU caches: measured fastest for
    values and gradients alike). Drawing the numbers per block rather than inside the
    innermost loop matters: XLA compiles that loop markedly slower (1.8x) when it also
    draws random numbers.

    The builds are split over the devices of the ``"builds"`` mesh (all devices of all
    processes, or the one set with :func:`jax.set_mesh`;
    :func:`encdesign.design.shard_builds`): each device evaluates ``ceil(n / D)``
    consecutive builds in the same blocks, and the values are gathered in build order.
    Build ``i`` depends only on ``fold_in(key, first + i)``, so the result is that of one
    device (to rounding in the compiled code). With one device nothing changes.
    ``manual``: the ``shard_map`` path of :func:`~encdesign.design.shard_builds` (only when
    ``fn_z`` closes over no array that lives on a mesh).
    """
    return shard_builds(
        lambda offset, m: _local_builds(fn_z, key, m, dim, first + offset, block, vector),
        n,
        manual=manual,
    )


def _local_builds(fn_z, key, n: int, dim: int, first: Any, block: int, vector: int):
    """:func:`map_builds` on one device: builds ``first … first + n - 1`` (``first`` may be
    traced)."""
    vector = int(max(1, min(vector, n)))
    n_groups = -(-n // vector)
    per_block = int(max(1, min(n_groups, -(-int(block) // vector))))
    size = per_block * vector
    n_blocks = -(-n // size)

    def one_block(b):
        z = build_normals(key, first + b * size + jnp.arange(size), dim)
        return values_of_normals(fn_z, z, vector)

    return jax.lax.map(one_block, jnp.arange(n_blocks)).reshape(-1)[:n]


def _chunked_values(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int,
) -> jax.Array:
    """Per-build values ``fn(theta, z_i)`` for builds ``0 … n-1`` (:func:`map_builds`:
    random numbers drawn ``chunk_size`` builds at a time, so memory is bounded by one
    chunk)."""
    return map_builds(lambda z: fn(theta, z), key, n, dim, block=chunk_size)


@dataclasses.dataclass(frozen=True)
class MonteCarloResult:
    """Monte Carlo estimate over ``n`` builds.

    Attributes:
        mean, std: sample mean and standard deviation of the per-build values (units of
            the function).
        stderr: ``std / sqrt(n)``.
        n: number of builds.
        values: per-build values (1-D float64), build ``i`` first-to-last.
        status: ``"success"`` or ``"nonfinite"`` (then ``n_nonfinite`` says how many).
        n_nonfinite: builds whose value was not finite (excluded from nothing: they make
            the status fail).
        message: account of the status.
    """

    mean: float
    std: float
    stderr: float
    n: int
    values: np.ndarray
    status: str
    n_nonfinite: int = 0
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when ``status == "success"``."""
        return self.status == SUCCESS

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile (0–100) of the per-build values."""
        return float(np.percentile(self.values, q))

    def yield_fraction(self, spec: float) -> tuple[float, float]:
        """Fraction of builds with value ``<= spec`` and its binomial standard error."""
        p = float(np.mean(self.values <= spec))
        return p, math.sqrt(max(p * (1.0 - p), 0.0) / self.n)


@functools.lru_cache(maxsize=64)
def _mc_chunk(fn: Callable[[Any, jax.Array], jax.Array], chunk: int, dim: int, block: int):
    """Jitted values of one chunk of builds, left on the devices that computed them (no
    collective: :func:`gather_chunks` collects them at the end). Cached per ``fn``: reruns
    don't recompile."""

    @jax.jit
    def run_chunk(key, c, th):
        return shard_builds(
            lambda off, m: _local_builds(
                lambda zi: fn(th, zi), key, m, dim, c * chunk + off, block, VECTOR_BUILDS
            ),
            chunk,
            manual=True,
            gather=False,
        )

    return run_chunk


def monte_carlo(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    *,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int = 4096,
    progress: bool = False,
    throw: bool = False,
) -> MonteCarloResult:
    """Evaluate ``fn(theta, z)`` on ``n`` Monte Carlo builds ``z ~ N(0, I_dim)``.

    ``fn`` maps the design ``theta`` (any pytree) and one build's standard-normal vector
    ``z`` (``[dim]``) to a scalar. The builds come from :func:`build_normals` (common random
    numbers: the same ``key`` gives the same builds for every ``theta``). Work is done in
    jitted chunks of at most ``chunk_size`` builds per device, the builds spread evenly over
    the chunks (``chunk_plan`` in :mod:`encdesign.design._distributed`), each chunk split
    over the devices of the ``"builds"`` mesh. The values stay on the devices that computed
    them until the last chunk is done; then one gather collects them (``gather_chunks``):
    processes never wait for each other while they compute. With ``progress`` a progress
    line is shown (by process 0 only, for the whole run, when several processes share the
    work).
    """
    if n < 1 or dim < 1:
        from .._errors import input_error

        raise input_error("monte_carlo", f"n={n}, dim={dim}", "n >= 1 and dim >= 1")
    # host copies of the inputs: the chunks take the shard_map path, which needs inputs
    # that are not laid out on a mesh (theta may be the output of a sharded solver); plain
    # numbers become arrays too, so a design given as floats and the same design as arrays
    # (a solver's output) share one compiled chunk
    theta = jax.tree.map(
        lambda x: np.asarray(x) if isinstance(x, (jax.Array, np.generic, float, int)) else x,
        theta,
    )
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.wrap_key_data(
            np.asarray(jax.random.key_data(key)), impl=jax.random.key_impl(key)
        )
    else:
        key = np.asarray(key)
    # every device of every process evaluates its block of each chunk; nothing crosses
    # devices or processes until all chunks are done (gather_chunks), so no process waits
    # for another while it computes
    shards = n_build_shards()
    block, n_chunks = chunk_plan(n, chunk_size, shards, VECTOR_BUILDS)
    run_chunk = _mc_chunk(fn, block * shards, int(dim), block)
    out = []
    show = progress and is_main_process()
    with progress_bar("monte carlo", n_chunks, enabled=show) as bar:
        for c in range(n_chunks):
            out.append(run_chunk(key, c, theta))  # dispatched; runs while the next is queued
            if c:
                out[c - 1].block_until_ready()
                bar.update()
        out[-1].block_until_ready()
        bar.update()
    values = gather_chunks(out)[:n].astype(np.float64)
    bad = int(np.sum(~np.isfinite(values)))
    mean = float(np.mean(values))
    std = float(np.std(values, ddof=1)) if n > 1 else 0.0
    status, msg = (SUCCESS, f"{n} builds") if bad == 0 else (NONFINITE, f"{bad} non-finite builds")
    res = MonteCarloResult(mean, std, std / math.sqrt(n), n, values, status, bad, msg)
    return _finish(res, throw)


def expected_value(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    *,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int = 4096,
) -> jax.Array:
    """Differentiable Monte Carlo mean of ``fn(theta, z)`` over builds ``0 … n-1`` of ``key``.

    Traceable (use inside ``jax.grad``/``jax.jit``); chunked with ``lax.map`` so memory is
    bounded by one chunk. The builds are common random numbers (see
    :func:`build_normals`), so the estimate is a smooth function of ``theta``.
    """
    return jnp.mean(_chunked_values(fn, theta, key, n, dim, chunk_size))


def expected_values(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    *,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int = 4096,
) -> jax.Array:
    """Traceable per-build values ``[n]`` of ``fn(theta, z_i)`` (see :func:`expected_value`)."""
    return _chunked_values(fn, theta, key, n, dim, chunk_size)


# ---------------------------------------------------------------------------------------
# design of experiments


def grid_points(lower: Sequence[float], upper: Sequence[float], n_per_dim: Any) -> np.ndarray:
    """Full-factorial grid ``[prod(n), d]`` between ``lower`` and ``upper`` (inclusive)."""
    lo = np.atleast_1d(np.asarray(lower, dtype=np.float64))
    hi = np.atleast_1d(np.asarray(upper, dtype=np.float64))
    ns = np.broadcast_to(np.asarray(n_per_dim, dtype=int), lo.shape)
    axes = [np.linspace(a, b, int(k)) for a, b, k in zip(lo, hi, ns)]
    return np.array(list(itertools.product(*axes)), dtype=np.float64).reshape(-1, lo.size)


def latin_hypercube(
    key: jax.Array, lower: Sequence[float], upper: Sequence[float], n: int
) -> np.ndarray:
    """Latin hypercube sample ``[n, d]``: each variable's range cut into ``n`` equal strata,
    one point per stratum, strata paired at random (``key``), uniform inside a stratum."""
    lo = np.atleast_1d(np.asarray(lower, dtype=np.float64))
    hi = np.atleast_1d(np.asarray(upper, dtype=np.float64))
    d = lo.size
    k_perm, k_u = jax.random.split(key)
    perms = jax.vmap(lambda k: jax.random.permutation(k, n))(jax.random.split(k_perm, d))
    u = jax.random.uniform(k_u, (d, n), dtype=jnp.float64)
    frac = (np.asarray(perms).astype(np.float64) + np.asarray(u)) / n
    return lo + frac.T * (hi - lo)


@dataclasses.dataclass(frozen=True)
class DOEResult:
    """Result of :func:`doe`.

    Attributes:
        points: ``[n, d]`` evaluated points.
        values: ``[n]`` objective values (NaN where the evaluation failed).
        statuses: per-point status (``"success"`` or ``"nonfinite"``).
        best_index: index of the smallest finite value (``-1`` if none).
        status: ``"success"`` if at least one point succeeded, else ``"failed"``.
        message: account of the status.
    """

    points: np.ndarray
    values: np.ndarray
    statuses: tuple[str, ...]
    best_index: int
    status: str
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when ``status == "success"``."""
        return self.status == SUCCESS

    @property
    def best_point(self) -> np.ndarray:
        """The point with the smallest finite value."""
        return self.points[self.best_index]

    @property
    def best_value(self) -> float:
        """The smallest finite value."""
        return float(self.values[self.best_index])


def doe(
    fn: Callable[[jax.Array, Any], jax.Array],
    points: Any,
    args: Any = None,
    *,
    chunk_size: int = 256,
    progress: bool = False,
    throw: bool = False,
) -> DOEResult:
    """Evaluate ``fn(x, args)`` (scalar) at every row of ``points`` (vmapped, in chunks)."""
    pts = np.atleast_2d(np.asarray(points, dtype=np.float64))
    f = jax.jit(jax.vmap(lambda x: fn(x, args)))
    vals = []
    starts = list(range(0, pts.shape[0], chunk_size))
    with progress_bar("doe", pts.shape[0], enabled=progress) as bar:
        for s in starts:
            vals.append(np.asarray(f(jnp.asarray(pts[s : s + chunk_size]))))
            bar.update(min(chunk_size, pts.shape[0] - s))
    values = np.concatenate(vals).astype(np.float64)
    finite = np.isfinite(values)
    statuses = tuple(SUCCESS if ok else NONFINITE for ok in finite)
    if finite.any():
        best = int(np.flatnonzero(finite)[np.argmin(values[finite])])
        status, msg = SUCCESS, f"{int(finite.sum())}/{len(values)} points finite"
    else:
        best, status, msg = -1, FAILED, "no point gave a finite value"
    return _finish(DOEResult(pts, values, statuses, best, status, msg), throw)


# ---------------------------------------------------------------------------------------
# enumeration of discrete variables


@dataclasses.dataclass(frozen=True)
class EnumerationResult:
    """Result of :func:`enumerate_designs`.

    Attributes:
        choices: the discrete combinations tried, as dicts, in order.
        solutions: the inner result for each combination (anything with ``status`` and
            ``objective``).
        best_index: index of the best combination whose status is an answer
            (:data:`ANSWERS`: ``"success"`` or ``"at_bound"``; ``-1`` if none).
        status: ``"success"`` when at least one combination succeeded and the best is a
            plain success; the best one's status (``"at_bound"``) when it is marked; else
            ``"failed"``.
        message: account of the status.
    """

    choices: tuple[dict[str, Any], ...]
    solutions: tuple[Any, ...]
    best_index: int
    status: str
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when the best combination is an answer (``"success"`` or ``"at_bound"``)."""
        return self.status in ANSWERS

    @property
    def best_choice(self) -> dict[str, Any]:
        """The best discrete combination."""
        return self.choices[self.best_index]

    @property
    def best_solution(self) -> Any:
        """The inner solution at the best combination."""
        return self.solutions[self.best_index]


def enumerate_designs(
    solve: Callable[[dict[str, Any]], Any],
    choices: Mapping[str, Sequence[Any]],
    *,
    progress: bool = False,
    throw: bool = False,
) -> EnumerationResult:
    """Solve the continuous problem for every combination of discrete values.

    Args:
        solve: ``solve(combination) -> result`` with ``.status`` and ``.objective`` (e.g. a
            closure calling :func:`optimise` for fixed discrete values).
        choices: variable name -> allowed values; the full product is enumerated.
        progress: show a progress line.
        throw: raise unless some combination succeeded.

    Returns:
        An :class:`EnumerationResult`; the best combination is the successful one with
        the smallest ``objective``. Failed combinations stay in the table with their status.
    """
    names = list(choices)
    combos = [dict(zip(names, vals)) for vals in itertools.product(*choices.values())]
    sols = []
    with progress_bar("enumerate", len(combos), enabled=progress) as bar:
        for c in combos:
            sols.append(solve(c))
            bar.update()
    okidx = [i for i, s in enumerate(sols) if s.status in ANSWERS and math.isfinite(s.objective)]
    if okidx:
        best = min(okidx, key=lambda i: sols[i].objective)
        status, msg = SUCCESS, f"{len(okidx)}/{len(combos)} combinations solved"
        if sols[best].status != SUCCESS:  # the best answer is marked (e.g. on a bound)
            status = sols[best].status
            msg = f"{msg}; the best is {status}: {getattr(sols[best], 'message', '')}"
    else:
        best, status, msg = -1, FAILED, "no combination solved"
    return _finish(EnumerationResult(tuple(combos), tuple(sols), best, status, msg), throw)
