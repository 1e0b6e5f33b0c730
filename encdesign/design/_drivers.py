"""Drivers: the solvers a design problem is handed to, as objects that hold their settings.

Every driver is a final :class:`equinox.Module` with one set of defaults (the optimistix
pattern); its invariants are checked when it is built (``__check_init__``), so a bad
setting is an :class:`~encdesign.EncdesignInputError` naming the driver's field:

* gradient solvers for :func:`optimise`: :class:`BFGS` (optimistix),
  :class:`LevenbergMarquardt` (optimistix; the function returns a residual vector) and
  :class:`LBFGSB` (jaxopt; bounds always hold) — ``optimise(fn, BFGS(), y0, ...)``;
* design of experiments: :class:`Grid` and :class:`LatinHypercube` (both
  :class:`AbstractDOE`) give the points, :func:`doe` evaluates them;
* :class:`MonteCarlo` — :func:`monte_carlo` over builds with common random numbers: build
  ``i`` of key ``k`` is always the same standard-normal vector ``normal(fold_in(k, i))``,
  whatever the chunking, so expected objectives are smooth, deterministic functions of the
  design and can be differentiated;
* :func:`enumerate_designs` — enumeration of discrete variables wrapped around a
  continuous solve (it takes no settings).

A driver's result never hides a bad number: it carries a :class:`DriverStatus` (one
enumeration, a message each) and ``.ok``, which means the same everywhere: the status is an
answer (:attr:`DriverStatus.ok`: ``success`` or ``at_bound``). ``at_bound`` is a converged
optimum with a variable on its bound: a valid answer of the bounded problem, marked (the
bound decided it), so ``.ok`` is true and ``encdesign optimize`` exits 0 while printing the
status. With ``throw=True`` a result that is not ok raises :class:`OptimisationError`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import numbers
import warnings
from collections.abc import Callable
from typing import Any, ClassVar, final

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jax.typing import ArrayLike

from .._distributed import (
    chunk_plan,
    gather_chunks,
    is_main_process,
    n_build_shards,
    shard_builds,
)
from .._errors import OptimisationError as OptimisationError
from .._errors import input_error
from .._progress import progress_bar
from ._sampling import MC_CHUNK, VECTOR_BUILDS, grid_points, latin_hypercube, local_builds
from ._status import (
    AT_BOUND,
    BOUNDS_VIOLATED,
    FAILED,
    MAX_STEPS,
    NONFINITE,
    STALLED,
    SUCCESS,
    DriverStatus,
    finish,
)

with warnings.catch_warnings():
    warnings.filterwarnings(
        "ignore", message="JAXopt is no longer maintained", category=DeprecationWarning
    )
    import jaxopt


STEP_COLLAPSE = 1e-12
"""A final line-search step size (or trust-region radius) below this: the search collapsed."""
STALL_FACTOR = 1e3
"""A "converged" BFGS stop is stalled when its quasi-Newton step still predicts a decrease
over ``STALL_FACTOR`` times the stopping tolerance ``atol + rtol * |f|``."""
BOUND_RTOL = 1e-9
"""A variable within ``BOUND_RTOL * max(1, bound width)`` of a bound is at that bound."""
INT_MAX = 10_000_000
"""Largest step cap, build count, point count or chunk a driver takes."""
TOL_MAX = 1e12
"""Largest tolerance a driver takes (larger is a typing slip)."""


# ---------------------------------------------------------------------------------------
# the driver objects


def check_setting(where: str, value: object, kind: type, lo: float, hi: float) -> None:
    """Refuse a driver setting that is not a number of ``kind`` in range: integers in
    ``lo … hi``, floats finite in ``(lo, hi]``; ``where`` names it in the error."""
    if kind is int:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral):
            raise input_error(
                where, f"{value!r} is not an integer", f"an integer {lo:.0f} … {hi:.0f}"
            )
        if not lo <= int(value) <= hi:
            raise input_error(where, f"{value!r}", f"an integer {lo:.0f} … {hi:.0f}")
        return
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise input_error(where, f"{value!r} is not a number", f"a number in ({lo:g}, {hi:g}]")
    try:
        x = float(value)
    except OverflowError:  # an integer beyond the float range
        x = math.inf
    if not (math.isfinite(x) and lo < x <= hi):
        raise input_error(where, f"{value!r}", f"a finite number in ({lo:g}, {hi:g}]")


class AbstractDriver(eqx.Module):
    """A driver: its settings are its fields (static, each with one default).

    ``kind`` is the driver's name in a problem file's ``[driver] kind``; ``limits`` maps
    each field to ``(int or float, lower, upper)``, checked in ``__check_init__``.
    """

    kind: ClassVar[str]
    limits: ClassVar[dict[str, tuple[type, float, float]]]

    def __check_init__(self) -> None:
        for name, (kind, lo, hi) in self.limits.items():
            check_setting(f"{type(self).__name__}.{name}", getattr(self, name), kind, lo, hi)

    def settings(self) -> dict[str, Any]:
        """``{"kind": ..., field: value, ...}`` (JSON-able; what a summary records)."""
        return {
            "kind": self.kind,
            **{f.name: getattr(self, f.name) for f in dataclasses.fields(self)},
        }


class AbstractGradientSolver(AbstractDriver):
    """A gradient solver for :func:`optimise`."""

    max_steps: eqx.AbstractVar[int]

    def run(
        self, fn: Callable[[jax.Array, Any], jax.Array], y0: jax.Array, lo: np.ndarray,
        hi: np.ndarray, args: Any,
    ) -> tuple[np.ndarray, float, DriverStatus, str, int]:  # fmt: skip
        """Minimise ``fn`` from ``y0``: ``(value, objective, status, message, n_steps)``
        (the objective re-evaluated at ``value``; bounds are checked by :func:`optimise`)."""
        raise NotImplementedError


_TOLERANCES: dict[str, tuple[type, float, float]] = {
    "rtol": (float, 0.0, TOL_MAX),
    "atol": (float, 0.0, TOL_MAX),
    "max_steps": (int, 1, INT_MAX),
}


@final
class BFGS(AbstractGradientSolver):
    """optimistix BFGS on a scalar ``fn(y, args)``; bounds are only checked (a solution
    outside them is ``bounds_violated``, one on them ``at_bound``).

    Attributes:
        rtol, atol: optimistix convergence tolerances (relative; absolute in the units of
            ``y`` and of ``fn``), on steps and values.
        max_steps: iteration limit (``max_steps_reached`` when hit).
    """

    rtol: float = eqx.field(default=1e-10, static=True)
    atol: float = eqx.field(default=1e-14, static=True)
    max_steps: int = eqx.field(default=256, static=True)
    kind: ClassVar[str] = "bfgs"
    limits: ClassVar[dict[str, tuple[type, float, float]]] = _TOLERANCES

    def run(self, fn, y0, lo, hi, args):
        fn = _scalar_fn(fn)
        sol, out = _optx(fn, self)(y0, args)
        objective = float(out)
        status, message, n_steps = _optx_status(sol, self, objective)
        return np.asarray(sol.value, dtype=np.float64), objective, status, message, n_steps


@final
class LevenbergMarquardt(AbstractGradientSolver):
    """optimistix Levenberg–Marquardt: ``fn(y, args)`` returns a residual vector and
    ``0.5 * sum(r**2)`` is minimised; bounds are only checked, as for :class:`BFGS`.

    Attributes:
        rtol, atol: optimistix convergence tolerances.
        max_steps: iteration limit.
    """

    rtol: float = eqx.field(default=1e-10, static=True)
    atol: float = eqx.field(default=1e-14, static=True)
    max_steps: int = eqx.field(default=256, static=True)
    kind: ClassVar[str] = "lm"
    limits: ClassVar[dict[str, tuple[type, float, float]]] = _TOLERANCES

    def run(self, fn, y0, lo, hi, args):
        sol, out = _optx(fn, self)(y0, args)
        objective = float(0.5 * jnp.sum(out**2))
        status, message, n_steps = _optx_status(sol, self, objective)
        return np.asarray(sol.value, dtype=np.float64), objective, status, message, n_steps


@final
class LBFGSB(AbstractGradientSolver):
    """jaxopt L-BFGS-B on a scalar ``fn(y, args)``: iterates always stay inside the bounds.

    Attributes:
        gtol: convergence on the projected-gradient norm (units of ``fn`` per unit of
            ``y``).
        max_steps: iteration limit.
    """

    gtol: float = eqx.field(default=1e-7, static=True)
    max_steps: int = eqx.field(default=256, static=True)
    kind: ClassVar[str] = "lbfgsb"
    limits: ClassVar[dict[str, tuple[type, float, float]]] = {
        "gtol": (float, 0.0, TOL_MAX),
        "max_steps": (int, 1, INT_MAX),
    }

    def run(self, fn, y0, lo, hi, args):
        fn = _scalar_fn(fn)
        y0 = jnp.clip(y0, lo, hi)
        run = _lbfgsb(fn, self.max_steps, self.gtol)
        value, state, out = run(y0, (jnp.asarray(lo), jnp.asarray(hi)), args)
        status, message, n_steps = _lbfgsb_status(state, self.gtol, self.max_steps)
        return np.asarray(value, dtype=np.float64), float(out), status, message, n_steps


class AbstractDOE(AbstractDriver):
    """A design of experiments: points in a box, evaluated by :func:`doe`."""

    chunk_size: eqx.AbstractVar[int]

    def points(self, lower: np.ndarray, upper: np.ndarray, key: jax.Array) -> np.ndarray:
        """The ``[n, d]`` points between ``lower`` and ``upper`` (``key``: its randomness)."""
        raise NotImplementedError


DOE_CHUNK = 256
"""Default points per compiled DOE evaluation."""


@final
class Grid(AbstractDOE):
    """Full-factorial grid (:func:`grid_points`), ``points_per_dim`` per variable."""

    points_per_dim: int = eqx.field(default=11, static=True)
    chunk_size: int = eqx.field(default=DOE_CHUNK, static=True)
    kind: ClassVar[str] = "grid"
    limits: ClassVar[dict[str, tuple[type, float, float]]] = {
        "points_per_dim": (int, 2, INT_MAX),
        "chunk_size": (int, 1, INT_MAX),
    }

    def points(self, lower, upper, key):
        return grid_points(lower, upper, self.points_per_dim)


@final
class LatinHypercube(AbstractDOE):
    """Latin hypercube of ``n`` points (:func:`latin_hypercube`)."""

    n: int = eqx.field(default=64, static=True)
    chunk_size: int = eqx.field(default=DOE_CHUNK, static=True)
    kind: ClassVar[str] = "lhs"
    limits: ClassVar[dict[str, tuple[type, float, float]]] = {
        "n": (int, 1, INT_MAX),
        "chunk_size": (int, 1, INT_MAX),
    }

    def points(self, lower, upper, key):
        return latin_hypercube(key, lower, upper, self.n)


@final
class MonteCarlo(AbstractDriver):
    """Monte Carlo over ``n_builds`` builds (:func:`monte_carlo`).

    Attributes:
        n_builds: builds (>= 1; ``MonteCarlo(n_builds=0)`` is refused).
        chunk_size: builds per device in one compiled chunk (memory per device).
    """

    n_builds: int = eqx.field(static=True)
    chunk_size: int = eqx.field(default=MC_CHUNK, static=True)
    kind: ClassVar[str] = "monte_carlo"
    limits: ClassVar[dict[str, tuple[type, float, float]]] = {
        "n_builds": (int, 1, 2**62),
        "chunk_size": (int, 1, INT_MAX),
    }

    def run(
        self,
        fn: Callable[[Any, jax.Array], jax.Array],
        theta: Any,
        *,
        key: jax.Array,
        dim: int,
        progress: bool = False,
        throw: bool = False,
    ) -> MonteCarloResult:
        """:func:`monte_carlo` with these settings."""
        return monte_carlo(
            fn, theta, key=key, n=self.n_builds, dim=dim, chunk_size=self.chunk_size,
            progress=progress, throw=throw,
        )  # fmt: skip


DRIVERS: dict[str, type[AbstractDriver]] = {
    c.kind: c for c in (BFGS, LBFGSB, LevenbergMarquardt, Grid, LatinHypercube)
}
"""The drivers a problem file's ``[driver] kind`` names."""


# ---------------------------------------------------------------------------------------
# gradient solvers


@dataclasses.dataclass(frozen=True)
class Solution:
    """Result of :func:`optimise`.

    Attributes:
        value: the solution (1-D float64 array, in the units of ``y0``).
        objective: the objective at ``value`` (for :class:`LevenbergMarquardt`: half the
            sum of squared residuals).
        status: a :class:`DriverStatus`.
        n_steps: solver iterations taken.
        solver: the driver's ``kind`` (``"bfgs"``, ``"lm"`` or ``"lbfgsb"``).
        message: a human-readable account of the status.
        at_bounds: the components on a bound at ``value``, as ``"lower[i]"`` /
            ``"upper[i]"`` (empty when none).
    """

    value: np.ndarray
    objective: float
    status: DriverStatus
    n_steps: int
    solver: str
    message: str = ""
    at_bounds: tuple[str, ...] = ()

    @property
    def ok(self) -> bool:
        """True when the status is an answer (``success`` or ``at_bound``)."""
        return self.status.ok

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the status and the key numbers."""
        from ._display import solution_html

        return solution_html(self)


def _as_bounds(bound: ArrayLike | None, n: int, fill: float) -> np.ndarray:
    if bound is None:
        return np.full(n, fill)
    return np.broadcast_to(np.asarray(bound, dtype=np.float64), (n,)).copy()


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
def _optx(fn: Callable[[jax.Array, Any], jax.Array], driver: BFGS | LevenbergMarquardt):
    """The optimistix solve of ``fn`` and ``fn`` at its solution, compiled as one program
    once per ``fn`` and driver and cached (``equinox.filter_jit``: non-array ``args`` are
    static, as in ``optimistix``)."""
    rtol, atol, max_steps = float(driver.rtol), float(driver.atol), int(driver.max_steps)

    @eqx.filter_jit
    def run(y0, args):
        if isinstance(driver, BFGS):
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
    solver: AbstractGradientSolver,
    y0: ArrayLike,
    args: Any = None,
    *,
    lower: ArrayLike | None = None,
    upper: ArrayLike | None = None,
    throw: bool = False,
) -> Solution:
    """Minimise ``fn(y, args)`` from ``y0`` with a gradient solver.

    Args:
        fn: ``fn(y, args)``: a scalar for :class:`BFGS` / :class:`LBFGSB`, a residual
            vector for :class:`LevenbergMarquardt` (which minimises ``0.5 * sum(r**2)``).
            Must be JAX-differentiable.
        solver: the driver with its settings, e.g. ``BFGS(rtol=1e-8, max_steps=500)``.
        y0: start point, 1-D (any units; ``fn`` defines them).
        args: passed through to ``fn``.
        lower, upper: bounds (scalar or per component; ``None`` = unbounded).
            :class:`LBFGSB` enforces them; for the others a solution outside them gets
            status ``bounds_violated``.
        throw: raise :class:`OptimisationError` unless the status is an answer
            (``success`` or ``at_bound``).

    Statuses (:class:`DriverStatus`): ``success`` (converged, no variable on a bound);
    ``at_bound`` (converged with components on a bound, listed in ``at_bounds``: for
    L-BFGS-B the box, for the others a solution that touches a bound);
    ``max_steps_reached``; ``line_search_stalled`` (a line-search step size or
    trust-region radius below :data:`STEP_COLLAPSE`: no decrease found along the search
    direction; a failed L-BFGS-B line search or an L-BFGS-B stop before the cap without
    convergence, or a BFGS stop on a small step whose quasi-Newton step still predicts a
    decrease over :data:`STALL_FACTOR` times the stopping tolerance); ``nonfinite``;
    ``bounds_violated``; ``failed``.

    Passing the same ``fn`` again (with other ``args``, bounds or start) reuses the
    compiled solver; put anything that changes between solves into ``args``.

    Returns:
        A :class:`Solution`; its ``objective`` is re-evaluated at ``value`` and a
        non-finite value or objective gives status ``nonfinite``.
    """
    if not isinstance(solver, AbstractGradientSolver):
        raise input_error(
            "optimise: solver",
            f"{solver!r} is not a gradient solver",
            "BFGS(...), LBFGSB(...) or LevenbergMarquardt(...) (encdesign.design)",
        )
    y0 = jnp.atleast_1d(jnp.asarray(y0, dtype=jnp.float64))
    n = y0.shape[0]
    lo, hi = _as_bounds(lower, n, -np.inf), _as_bounds(upper, n, np.inf)
    value, objective, status, message, n_steps = solver.run(fn, y0, lo, hi, args)
    at = at_bounds(value, lo, hi)
    if status in (SUCCESS, MAX_STEPS, STALLED):
        if not (np.all(np.isfinite(value)) and math.isfinite(objective)):
            status, message = NONFINITE, "non-finite solution or objective"
        elif status == SUCCESS and (np.any(value < lo) or np.any(value > hi)):
            status, message = BOUNDS_VIOLATED, f"solution {value} outside [{lo}, {hi}]"
        elif at:
            if status == SUCCESS:
                status, message = AT_BOUND, f"converged on the bound: {', '.join(at)}"
            else:
                message = f"{message}; on the bound: {', '.join(at)}"
    res = Solution(value, objective, status, n_steps, solver.kind, message, tuple(at))
    return finish(res, throw)


def at_bounds(value: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list[str]:
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


def _lbfgsb_status(state: Any, gtol: float, max_steps: int) -> tuple[DriverStatus, str, int]:
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


def _optx_status(
    sol: optx.Solution, driver: BFGS | LevenbergMarquardt, f: float
) -> tuple[DriverStatus, str, int]:
    """Status of an optimistix run: its result, then a collapsed line-search step size
    (trust-region radius for Levenberg–Marquardt) as stalled, and for BFGS a "converged"
    stop whose quasi-Newton step still predicts a decrease over :data:`STALL_FACTOR` times
    the stopping tolerance (the step, not the objective, became small) as stalled."""
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
    if status == SUCCESS and isinstance(driver, BFGS) and hasattr(info, "hessian_inv"):
        g = info.grad
        pred = 0.5 * float(jnp.vdot(g, info.hessian_inv.mv(g)))
        tol = driver.atol + driver.rtol * abs(f)
        if not math.isfinite(pred) or pred > STALL_FACTOR * tol:
            return (
                STALLED,
                f"stopped on a small step, but the quasi-Newton step still predicts a decrease "
                f"of {pred:.3g} (> {STALL_FACTOR:g} x tolerance {tol:.3g}) after {n_steps} steps",
                n_steps,
            )
    return status, message, n_steps


# ---------------------------------------------------------------------------------------
# Monte Carlo


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
    status: DriverStatus
    n_nonfinite: int = 0
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when the status is an answer (``success``)."""
        return self.status.ok

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile (0–100) of the per-build values."""
        return float(np.percentile(self.values, q))

    def yield_fraction(self, spec: float) -> tuple[float, float]:
        """Fraction of builds with value ``<= spec`` and its binomial standard error."""
        p = float(np.mean(self.values <= spec))
        return p, math.sqrt(max(p * (1.0 - p), 0.0) / self.n)

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the status and the key numbers."""
        from ._display import monte_carlo_html

        return monte_carlo_html(self)


@functools.lru_cache(maxsize=64)
def _mc_chunk(fn: Callable[[Any, jax.Array], jax.Array], chunk: int, dim: int, block: int):
    """Jitted values of one chunk of builds, left on the devices that computed them (no
    collective: :func:`gather_chunks` collects them at the end). Cached per ``fn``: reruns
    don't recompile."""

    @jax.jit
    def run_chunk(key, c, th):
        return shard_builds(
            lambda off, m: local_builds(
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
    chunk_size: int = MC_CHUNK,
    progress: bool = False,
    throw: bool = False,
) -> MonteCarloResult:
    """Evaluate ``fn(theta, z)`` on ``n`` Monte Carlo builds ``z ~ N(0, I_dim)``.

    ``fn`` maps the design ``theta`` (any pytree) and one build's standard-normal vector
    ``z`` (``[dim]``) to a scalar. The builds come from :func:`build_normals` (common random
    numbers: the same ``key`` gives the same builds for every ``theta``). Work is done in
    jitted chunks of at most ``chunk_size`` builds per device, the builds spread evenly over
    the chunks (``chunk_plan`` in :mod:`encdesign._distributed`), each chunk split
    over the devices of the ``"builds"`` mesh. The values stay on the devices that computed
    them until the last chunk is done; then one gather collects them (``gather_chunks``):
    processes never wait for each other while they compute. With ``progress`` a progress
    line is shown (by process 0 only, for the whole run, when several processes share the
    work).
    """
    MonteCarlo(n_builds=n, chunk_size=chunk_size)  # refuses n < 1 by name
    if isinstance(dim, bool) or not isinstance(dim, numbers.Integral) or dim < 1:
        raise input_error("monte_carlo: dim", f"{dim!r}", "an integer >= 1")
    # host copies of the inputs: the chunks take the shard_map path, which needs inputs
    # that are not laid out on a mesh (theta may be the output of a sharded solver); plain
    # numbers become arrays too, so a design given as floats and the same design as arrays
    # (a solver's output) share one compiled chunk
    theta = jax.tree.map(
        lambda x: np.asarray(x) if isinstance(x, (jax.Array, np.generic, float, int)) else x,
        theta,
    )
    host_key: jax.Array | np.ndarray  # not laid out on a mesh
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        host_key = jax.random.wrap_key_data(
            jnp.asarray(np.asarray(jax.random.key_data(key))), impl=jax.random.key_impl(key)
        )
    else:
        host_key = np.asarray(key)
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
            out.append(run_chunk(host_key, c, theta))  # dispatched; runs while the next is queued
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
    return finish(res, throw)


# ---------------------------------------------------------------------------------------
# design of experiments


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
    statuses: tuple[DriverStatus, ...]
    best_index: int
    status: DriverStatus
    message: str = ""

    @property
    def ok(self) -> bool:
        """True when the status is an answer (``success``)."""
        return self.status.ok

    @property
    def best_point(self) -> np.ndarray:
        """The point with the smallest finite value."""
        return self.points[self.best_index]

    @property
    def best_value(self) -> float:
        """The smallest finite value."""
        return float(self.values[self.best_index])

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the status and the key numbers."""
        from ._display import doe_html

        return doe_html(self)


def doe(
    fn: Callable[[jax.Array, Any], jax.Array],
    points: ArrayLike,
    args: Any = None,
    *,
    chunk_size: int = DOE_CHUNK,
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
    return finish(DOEResult(pts, values, statuses, best, status, msg), throw)
