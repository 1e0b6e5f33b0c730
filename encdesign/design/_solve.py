"""Hand a :class:`~encdesign.Problem` to its driver: optimise, sweep, check gradients.

Continuous variables are normalised for the solvers, ``x = start + scale * u`` (``scale`` =
bound width, or ``|start|``), so angles in rad and tolerances in µm are equally well
conditioned. Discrete variables are enumerated (:func:`~encdesign.enumerate_designs`)
around the continuous solve. Constraints enter gradient solves as a quadratic penalty and are
checked on the answer (status ``"infeasible"`` when violated). Every evaluation that the
driver reports is recorded as a case (:mod:`encdesign.design._cases`).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import itertools
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from .._distributed import (
    allgather_rows,
    is_main_process,
    process_count,
    process_index,
    split_range,
    use_local_devices,
)
from .._errors import input_error
from .._progress import progress_bar
from ._cases import CaseRecorder
from ._drivers import (
    AbstractDOE,
    AbstractGradientSolver,
    Grid,
    LatinHypercube,
    LevenbergMarquardt,
    at_bounds,
    optimise,
)
from ._enumerate import enumerate_designs
from ._problem import Problem
from ._status import AT_BOUND, FAILED, INFEASIBLE, MAX_STEPS, NONFINITE, SUCCESS, DriverStatus
from ._validate import Z_SIGNIFICANT, fresh_seeds, paired_comparison


@dataclasses.dataclass(frozen=True)
class DesignResult:
    """The answer for one combination of discrete values.

    Attributes:
        discrete: discrete variable -> value.
        inputs: continuous variable -> value, SI.
        outputs: output name -> value (scalars), SI.
        objective: the minimised quantity (the objective output, negated for
            ``sense = "maximize"``).
        status: driver status (:class:`~encdesign.design.DriverStatus`: ``success``,
            ``infeasible``, ``max_steps_reached``, …).
        n_steps: solver steps (DOE: points evaluated).
        message: account of the status.
    """

    discrete: dict[str, Any]
    inputs: dict[str, float]
    outputs: dict[str, float]
    objective: float
    status: DriverStatus
    n_steps: int = 0
    message: str = ""


@dataclasses.dataclass(frozen=True)
class ProblemResult:
    """Result of :func:`solve_problem` (``best`` is ``None`` when nothing succeeded)."""

    problem: Problem
    results: tuple[DesignResult, ...]
    best: DesignResult | None
    status: DriverStatus
    message: str = ""
    fresh: dict[str, Any] | None = None
    """Out-of-sample check of ``best`` against the baseline (the start point at the first
    discrete values) on fresh builds (:func:`~encdesign.design.validate_problem`), or
    ``None`` (not asked for, nothing solved, or no Monte Carlo in the objective)."""

    @property
    def ok(self) -> bool:
        """True when the best design is an answer (:attr:`DriverStatus.ok`: ``success`` or
        ``at_bound``; ``encdesign optimize`` exits 0 exactly then)."""
        return self.status.ok

    def _repr_html_(self) -> str:
        """Jupyter's rich display: the status and the key numbers."""
        from ._display import problem_html

        return problem_html(self)

    def summary(self) -> dict[str, Any]:
        """A JSON-able summary (SI values, plus the file's display units)."""
        p = self.problem

        def one(r: DesignResult) -> dict[str, Any]:
            return {
                "discrete": r.discrete,
                "inputs": r.inputs,
                "inputs_display": {
                    v.name: v.display(r.inputs[v.name]) for v in p.continuous if v.name in r.inputs
                },
                "outputs": _finite_or_none(r.outputs),
                "status": r.status,
                "n_steps": r.n_steps,
                "message": r.message,
            }

        return {
            "problem": p.name,
            "objective": p.objective.name,
            "sense": p.sense,
            "driver": {**p.driver.settings(), **_penalty_of(p)},
            "seed": p.seed,
            "status": self.status,
            "message": self.message,
            "units": {v.name: v.units for v in p.variables},
            "best": None if self.best is None else one(self.best),
            "results": [one(r) for r in self.results],
            "fresh": self.fresh,
            "resampled_between_rounds": False,
            "rounds_note": "the penalty rounds (and the discrete combinations) of one run "
            "share the problem's builds (its seed): nothing is re-sampled between them; "
            "the fresh check above uses independent builds",
            "win_significant": None if self.fresh is None else self.fresh["win_significant"],
        }


def _penalty_of(p: Problem) -> dict[str, float]:
    """``{"penalty": ...}`` for a driver whose solve penalises constraints, else ``{}``."""
    drv = p.driver
    penalised = isinstance(drv, AbstractGradientSolver) and not isinstance(drv, LevenbergMarquardt)
    return {"penalty": p.penalty} if penalised else {}


def _finite_or_none(d: dict[str, float]) -> dict[str, float | None]:
    return {k: (v if math.isfinite(v) else None) for k, v in d.items()}


def _assemble(variables: tuple, flat: dict[str, Any]) -> dict[str, Any]:
    """Objective inputs from per-element values: the elements ``name[i]`` of a vector
    variable are stacked into one 1-D array ``name`` (scalars pass through)."""
    out: dict[str, Any] = {}
    groups: dict[str, list[Any]] = {}
    for v in variables:
        if v.group is None:
            out[v.name] = flat[v.name]
        else:
            groups.setdefault(v.group, []).append(flat[v.name])
    for g, parts in groups.items():
        out[g] = jnp.stack([jnp.asarray(p, dtype=jnp.float64) for p in parts])
    return out


class _Evaluator:
    """Normalised view of a problem for one discrete combination."""

    def __init__(self, problem: Problem, discrete: dict[str, Any], check: bool = True):
        """``check``: run the objective's own check at the start point (off for a rebuild
        of an already checked problem under a trace, e.g. a traced fresh seed)."""
        self.problem = problem
        self.discrete = discrete
        self.vars = problem.continuous
        self.start = np.array([v.start for v in self.vars], dtype=np.float64)
        self.scale = np.array([v.scale for v in self.vars], dtype=np.float64)
        self.lower = np.array([v.lower for v in self.vars], dtype=np.float64)
        self.upper = np.array([v.upper for v in self.vars], dtype=np.float64)
        raw = problem.objective.build(problem, dict(discrete))
        self.evaluate = lambda flat: raw(_assemble(self.vars, flat))
        if check and problem.objective.check is not None:
            start = {v.name: float(v.start) for v in self.vars}
            problem.objective.check(problem, dict(discrete), _assemble(self.vars, start))
        self.name = problem.objective.outputs[0]
        self.sign = -1.0 if problem.sense == "maximize" else 1.0

    def x_of(self, u: jax.Array) -> dict[str, jax.Array]:
        x = jnp.asarray(self.start) + jnp.asarray(self.scale) * u
        return {v.name: x[i] for i, v in enumerate(self.vars)}

    def outputs(self, u: jax.Array) -> dict[str, jax.Array]:
        return self.evaluate(self.x_of(u))

    @functools.cached_property
    def compiled_outputs(self) -> Callable[[jax.Array], dict[str, jax.Array]]:
        """:meth:`outputs` compiled once (the start and the solution are evaluated with it:
        an eager call compiles the objective's loops and scans anew on every call)."""
        return jax.jit(self.outputs)

    def u_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return (self.lower - self.start) / self.scale, (self.upper - self.start) / self.scale

    def scalar_outputs(self, u: jax.Array | np.ndarray) -> dict[str, float]:
        out = self.compiled_outputs(jnp.asarray(u, dtype=jnp.float64))
        return {k: float(v) for k, v in out.items() if jnp.ndim(v) == 0}

    def inputs_of(self, u: np.ndarray) -> dict[str, float]:
        x = self.start + self.scale * np.asarray(u)
        return {v.name: float(x[i]) for i, v in enumerate(self.vars)}

    def violation(self, outputs: dict[str, float]) -> float:
        worst = 0.0
        for c in self.problem.constraints:
            g = outputs[c.output]
            for bound, excess in ((c.upper, g - c.upper), (c.lower, c.lower - g)):
                if math.isfinite(bound):
                    worst = max(worst, excess / max(abs(bound), 1e-300))
        return worst


def _penalised(ev: _Evaluator):
    """``f(u, (weight, fscale))``: the penalised objective over ``fscale``; the weight and
    the scale are arguments, so that the rounds of increasing weight reuse one compiled
    solver."""
    cons = ev.problem.constraints

    def f(u: jax.Array, args: jax.Array) -> jax.Array:
        weight, fscale = args[0], args[1]
        out = ev.outputs(u)
        val = ev.sign * out[ev.name]
        pen = 0.0
        for c in cons:
            g = out[c.output]
            if math.isfinite(c.upper):
                pen = pen + (jax.nn.relu(g - c.upper) / max(abs(c.upper), 1e-300)) ** 2
            if math.isfinite(c.lower):
                pen = pen + (jax.nn.relu(c.lower - g) / max(abs(c.lower), 1e-300)) ** 2
        return (val + weight * pen) / fscale

    return f


def _finish_design(
    ev: _Evaluator, u: np.ndarray, status: DriverStatus, n_steps: int, message: str
) -> DesignResult:
    outs = ev.scalar_outputs(u)
    val = outs.get(ev.name, math.nan)
    if status.ok and not all(math.isfinite(v) for v in outs.values()):
        status, message = NONFINITE, "non-finite output at the solution"
    if status.ok and ev.violation(outs) > 1e-6:
        status = INFEASIBLE
        message = f"constraint violated by {ev.violation(outs):.3g} (relative)"
    return DesignResult(
        dict(ev.discrete), ev.inputs_of(u), outs, ev.sign * val, status, n_steps, message
    )


def _solve_combo(
    problem: Problem, discrete: dict[str, Any], recorder: CaseRecorder | None, progress: bool
) -> DesignResult:
    ev = _Evaluator(problem, discrete)
    drv = problem.driver
    n_cont = len(ev.vars)
    if n_cont == 0:
        res = _finish_design(ev, np.zeros(0), SUCCESS, 0, "evaluated (no continuous variable)")
        _record(recorder, problem, res)
        return res
    ulo, uhi = ev.u_bounds()
    if isinstance(drv, AbstractDOE):
        return _doe_combo(ev, drv, recorder, progress)
    if not isinstance(drv, AbstractGradientSolver):
        raise input_error(
            f"{problem.path or problem.name}: driver",
            f"{drv!r} cannot solve a problem",
            "a gradient solver or a design of experiments",
        )
    u0 = np.zeros(n_cont)
    f0 = float(ev.sign * ev.compiled_outputs(jnp.asarray(u0))[ev.name])
    if not math.isfinite(f0):
        res = _finish_design(ev, u0, NONFINITE, 0, "objective not finite at the start point")
        _record(recorder, problem, res)
        return res
    fscale = max(abs(f0), 1e-300)
    weight = float(problem.penalty) * fscale
    if isinstance(drv, LevenbergMarquardt):
        sol = optimise(lambda u, a: ev.outputs(u)["residuals"], drv, u0, lower=ulo, upper=uhi)
    else:
        # quadratic penalty with increasing weight (one round without constraints)
        weights = [weight] if not problem.constraints else [weight * 10.0**k for k in (-2, 0, 2, 4)]
        u, n_steps = u0, 0
        f = _penalised(ev)
        sol = None
        for w in weights:
            sol = optimise(f, drv, u, jnp.array([w, fscale]), lower=ulo, upper=uhi)
            n_steps += sol.n_steps
            if sol.status not in (SUCCESS, MAX_STEPS, AT_BOUND):
                break
            u = sol.value
        assert sol is not None
        sol = dataclasses.replace(sol, n_steps=n_steps)
    res = _finish_design(ev, sol.value, sol.status, sol.n_steps, sol.message)
    _record(recorder, problem, res)
    return res


def _doe_combo(
    ev: _Evaluator, drv: AbstractDOE, recorder: CaseRecorder | None, progress: bool
) -> DesignResult:
    problem = ev.problem
    kind = drv.kind
    if not (np.all(np.isfinite(ev.lower)) and np.all(np.isfinite(ev.upper))):
        raise input_error(
            f"{problem.path or problem.name}: driver.kind",
            f"{kind!r} needs lower and upper bounds on every continuous variable",
        )
    ulo, uhi = ev.u_bounds()
    pts = drv.points(ulo, uhi, jax.random.fold_in(jax.random.key(problem.seed), 1))
    rows = _doe_rows(ev, pts, drv.chunk_size, recorder, progress, kind)
    best_i, best_val = -1, math.inf
    for i, (u, outs) in enumerate(zip(pts, rows)):
        val = ev.sign * outs[ev.name]
        status = _point_status(ev, outs)
        if recorder is not None:
            recorder.record({**ev.discrete, **ev.inputs_of(u)}, outs, status, seed=problem.seed)
        if status == SUCCESS and val < best_val:
            best_i, best_val = i, val
    if best_i < 0:
        return DesignResult(
            dict(ev.discrete), {}, {}, math.nan, FAILED, len(pts), "no feasible finite point"
        )
    outs = rows[best_i]
    status, message = SUCCESS, f"best of {len(pts)} {kind} points"
    edge = at_bounds(pts[best_i], ulo, uhi)
    if edge:  # the best point is on the box: the optimum may lie outside it
        names = ", ".join(f"{s.split('[')[0]} {ev.vars[int(s[s.index('[') + 1 : -1])].name}"
                          for s in edge)  # fmt: skip
        status, message = AT_BOUND, f"{message}; the best is on the bound ({names})"
    return DesignResult(
        dict(ev.discrete), ev.inputs_of(pts[best_i]), outs, best_val, status, len(pts), message
    )


def _point_status(ev: _Evaluator, outs: dict[str, float]) -> DriverStatus:
    if not all(math.isfinite(v) for v in outs.values()):
        return NONFINITE
    return INFEASIBLE if ev.violation(outs) > 1e-6 else SUCCESS


def _doe_rows(
    ev: _Evaluator,
    pts: np.ndarray,
    chunk: int,
    recorder: CaseRecorder | None,
    progress: bool,
    kind: str,
) -> list[dict[str, float]]:
    """Scalar outputs of every DOE point, skipping points the ``recorder`` already holds
    (``--resume``: their recorded outputs are used).

    Under a distributed run the points still to evaluate are split between the processes
    (:func:`~encdesign.design.split_range`); each evaluates its share on its own devices
    (Monte Carlo builds sharded over them), records it in its shard file, and the outputs
    are gathered so that every process holds the whole table.
    """
    problem = ev.problem
    f = jax.jit(jax.vmap(lambda u: ev.outputs(u)))
    shapes = jax.eval_shape(f, jax.ShapeDtypeStruct((1, pts.shape[1]), jnp.float64))
    names = [k for k, v in shapes.items() if len(v.shape) == 1]
    inputs = [{**ev.discrete, **ev.inputs_of(u)} for u in pts]
    rows: list[dict[str, float] | None] = [None] * len(pts)
    todo = []
    for i, x in enumerate(inputs):
        prev = None if recorder is None else recorder.lookup(x, problem.seed)
        if prev is not None:
            rows[i] = {k: float(prev.outputs.get(k, math.nan)) for k in names}
        else:
            todo.append(i)
    nproc, pid = process_count(), process_index()
    start, stop = split_range(len(todo), nproc, pid)
    mine = todo[start:stop]
    chunk = max(1, min(chunk, len(pts)))
    vals = np.zeros((len(mine), len(names)))
    label = f"{kind} {ev.discrete or ''}".strip()
    scope = use_local_devices() if nproc > 1 else contextlib.nullcontext()
    with (
        scope,
        progress_bar(label, len(todo), enabled=progress and is_main_process()) as bar,
    ):
        for s in range(0, len(mine), chunk):
            idx = mine[s : s + chunk]
            # always a full chunk (the last point repeated): one compiled shape, so a
            # point's outputs do not depend on which others share its chunk (--resume)
            padded = pts[idx + [idx[-1]] * (chunk - len(idx))]
            out = f(jnp.asarray(padded))
            block = np.stack([np.asarray(out[k], dtype=np.float64) for k in names], axis=1)
            block = block[: len(idx)]
            vals[s : s + len(idx)] = block
            if recorder is not None and nproc > 1:
                recorder.record_part(
                    (inputs[i], o, _point_status(ev, o), problem.seed)
                    for i, o in ((i, dict(zip(names, r))) for i, r in zip(idx, block.tolist()))
                )
            bar.update(min(len(idx) * nproc, len(todo) - bar.n))
    everything = allgather_rows(vals, len(todo))
    for i, r in zip(todo, everything.tolist()):
        rows[i] = dict(zip(names, r))
    return rows  # type: ignore[return-value]


def _record(recorder: CaseRecorder | None, problem: Problem, r: DesignResult) -> None:
    if recorder is not None:
        recorder.record({**r.discrete, **r.inputs}, r.outputs, r.status, seed=problem.seed)


def solve_problem(
    problem: Problem,
    *,
    recorder: CaseRecorder | None = None,
    progress: bool = False,
    throw: bool = False,
    fresh_replicates: int = 0,
) -> ProblemResult:
    """Solve ``problem`` with its ``[driver]``, enumerating discrete variables.

    Args:
        problem: a validated problem.
        recorder: where to record the cases (``None``: not recorded).
        progress: progress line on stderr.
        throw: raise :class:`~encdesign.design._drivers.OptimisationError` unless successful.
        fresh_replicates: with ``R >= 2`` and a Monte Carlo objective, the best design and
            the baseline (every continuous variable at its start, the first discrete
            values) are evaluated on ``R`` fresh replicates of the objective's builds
            (:func:`~encdesign.design.validate_problem`, ``ProblemResult.fresh``).

    Returns:
        A :class:`ProblemResult`; ``best`` is the successful design with the smallest
        (sense-adjusted) objective.
    """
    choices = {v.name: list(v.choices) for v in problem.discrete}
    enum = enumerate_designs(
        lambda combo: _solve_combo(problem, combo, recorder, progress and not choices),
        choices,
        progress=progress and bool(choices),
        throw=throw,
    )
    best = enum.best_solution if enum.ok else None
    fresh = None
    if best is not None and fresh_replicates:
        first = {v.name: v.choices[0] for v in problem.discrete}
        start = {v.name: float(v.start) for v in problem.continuous}
        fresh = validate_problem(
            problem, (best.discrete, best.inputs), (first, start), replicates=fresh_replicates
        )
    return ProblemResult(problem, tuple(enum.solutions), best, enum.status, enum.message, fresh)


def sweep_problem(
    problem: Problem,
    *,
    kind: str | None = None,
    recorder: CaseRecorder | None = None,
    progress: bool = False,
    fresh_replicates: int = 0,
) -> ProblemResult:
    """Evaluate ``problem`` on its ``[sweep]`` design of experiments (no optimisation).

    ``kind`` (``"grid"``/``"lhs"``) overrides ``[sweep] kind``. Every point is a case.
    ``fresh_replicates``: the best point against the start on fresh builds, as for
    :func:`solve_problem`.
    """
    sweep = problem.sweep
    if kind is not None and kind != sweep.kind:  # the other design, its own defaults
        sweep = (
            LatinHypercube(chunk_size=sweep.chunk_size)
            if kind == "lhs"
            else Grid(chunk_size=sweep.chunk_size)
        )
    p = dataclasses.replace(problem, driver=sweep)
    return solve_problem(p, recorder=recorder, progress=progress, fresh_replicates=fresh_replicates)


@dataclasses.dataclass(frozen=True)
class GradientRow:
    """One line of :func:`check_gradients` (derivative of ``output`` w.r.t. ``variable``,
    in output units per SI unit of the variable)."""

    output: str
    variable: str
    at: float
    ad: float
    fd: float
    abs_error: float
    rel_error: float
    ok: bool
    atol: float = 0.0
    basis: str = "relative"
    """``"relative"``: judged by ``rtol``; ``"absolute"``: both derivatives are at most
    ``atol`` (a relative error between two near-zero numbers says nothing), judged by
    ``|ad - fd| <= atol``."""


def check_gradients(
    problem: Problem,
    *,
    discrete: dict[str, Any] | None = None,
    at: dict[str, float] | None = None,
    rel_step: float = 1e-5,
    rtol: float = 1e-4,
    atol: float | None = None,
) -> list[GradientRow]:
    """Compare AD gradients with central finite differences for the objective and every
    constrained output, at the start point (or ``at``, SI) and the first discrete values.

    The FD step of variable ``i`` is ``rel_step * scale_i`` (``scale`` as in the module
    docstring). The absolute tolerance of a row is ``atol`` (output units per SI unit of
    the variable) or, by default, ``1e-3 * rtol * (|f| + tiny) / scale_i`` (a derivative that
    small moves the output by less than ``1e-3 * rtol`` of itself over the variable's
    scale). Where both derivatives are at most that tolerance the row is judged on the
    absolute error, ``|ad - fd| <= atol``, and says so (``basis = "absolute"``); elsewhere
    it is ``ok`` when ``|ad - fd| <= rtol * max(|ad|, |fd|) + atol``.
    """
    combo = {v.name: v.choices[0] for v in problem.discrete}
    combo.update(discrete or {})
    ev = _Evaluator(problem, combo)
    names = [problem.objective.outputs[0]] + [
        c.output for c in problem.constraints if c.output != problem.objective.outputs[0]
    ]
    x = {v.name: v.start for v in ev.vars}
    x.update(at or {})
    x0 = np.array([x[v.name] for v in ev.vars], dtype=np.float64)

    def f(xv):  # the checked outputs stacked; compiled once, with its Jacobian
        out = ev.evaluate({v.name: xv[i] for i, v in enumerate(ev.vars)})
        return jnp.stack([jnp.reshape(out[name], ()) for name in names])

    fj, jac = jax.jit(f), jax.jit(jax.jacrev(f))
    vals = np.asarray(fj(jnp.asarray(x0)))
    grads = np.asarray(jac(jnp.asarray(x0)))
    fds = []
    for i in range(len(ev.vars)):
        h = rel_step * ev.scale[i]
        e = np.zeros_like(x0)
        e[i] = h
        fds.append(
            (np.asarray(fj(jnp.asarray(x0 + e))) - np.asarray(fj(jnp.asarray(x0 - e)))) / (2 * h)
        )
    rows = []
    for k, name in enumerate(names):
        val, g = float(vals[k]), grads[k]
        for i, v in enumerate(ev.vars):
            fd = float(fds[i][k])
            err = abs(g[i] - fd)
            tol = (
                float(atol) if atol is not None else 1e-3 * rtol * (abs(val) + 1e-300) / ev.scale[i]
            )
            big = max(abs(g[i]), abs(fd))
            rel = err / max(big, 1e-300)
            if big <= tol:
                basis, ok = "absolute", bool(np.isfinite(g[i]) and err <= tol)
            else:
                basis, ok = "relative", bool(np.isfinite(g[i]) and err <= rtol * big + tol)
            rows.append(
                GradientRow(
                    name, v.name, float(x0[i]), float(g[i]), fd, err, rel, ok, float(tol), basis
                )
            )
    return rows


def discrete_combinations(problem: Problem) -> list[dict[str, Any]]:
    """All combinations of the discrete variables' values (``[{}]`` when there are none)."""
    names = [v.name for v in problem.discrete]
    return [dict(zip(names, c)) for c in itertools.product(*(v.choices for v in problem.discrete))]


def _monte_carlo_builds(problem: Problem) -> int:
    """The problem's Monte Carlo builds per evaluation (0: deterministic)."""
    yt = problem.yield_target
    if yt is not None:
        return int(yt.n_builds)
    return int(problem.model.get("n_builds", 0) or 0)


def validate_problem(
    problem: Problem,
    chosen: tuple[dict[str, Any], dict[str, float]],
    baseline: tuple[dict[str, Any], dict[str, float]],
    *,
    replicates: int = 8,
    z_threshold: float = Z_SIGNIFICANT,
) -> dict[str, Any] | None:
    """Re-evaluate a problem's chosen design and its baseline on fresh builds.

    The whole estimator (the problem's objective over its own ``n_builds`` builds) is
    evaluated for ``replicates`` fresh seeds (:func:`fresh_seeds` of ``problem.seed``), the
    same seeds for both designs; each replicate is one paired sample entry. Returns
    ``None`` when the objective is not a Monte Carlo one (no ``n_builds`` in its model, or
    ``n_builds = 0``), else the JSON-able report: :meth:`FreshComparison.as_dict` of the
    objective (sense-adjusted: ``"lower is better"``), plus ``fresh_seeds``,
    ``builds_per_replicate``, ``total_fresh_builds`` and per-output means on the fresh
    replicates of both designs.

    Args:
        problem: the :class:`~encdesign.Problem`.
        chosen, baseline: ``(discrete values, continuous inputs (SI))`` of the two designs
            (a continuous variable missing from the inputs is at its start).
        replicates: fresh replicates (>= 2).
        z_threshold: see :func:`paired_comparison`.
    """
    n_builds = _monte_carlo_builds(problem)
    if n_builds <= 0:
        return None
    if int(replicates) < 2:
        raise input_error("fresh replicates", f"{replicates!r}", "an integer >= 2")
    seeds = fresh_seeds(problem.seed, int(replicates))
    name = problem.objective.outputs[0]
    sign = -1.0 if problem.sense == "maximize" else 1.0
    rows = _fresh_rows(problem, {"chosen": chosen, "baseline": baseline}, seeds)
    va = np.array([sign * r[name] for r in rows["chosen"]])
    vb = np.array([sign * r[name] for r in rows["baseline"]])
    cmp = paired_comparison(va, vb, unit="replicates", z_threshold=z_threshold)
    out = {
        **cmp.as_dict(),
        "chosen_design": {"discrete": dict(chosen[0]), "inputs": dict(chosen[1])},
        "baseline_design": {"discrete": dict(baseline[0]), "inputs": dict(baseline[1])},
        "objective": name,
        "sense_adjusted": sign < 0,
        "fresh_seeds": seeds,
        "builds_per_replicate": n_builds,
        "total_fresh_builds": n_builds * len(seeds),
        "outputs_fresh": {
            label: {
                k: float(np.mean([r[k] for r in rs]))
                for k in rs[0]
                if all(math.isfinite(r[k]) for r in rs)
            }
            for label, rs in rows.items()
        },
    }
    return out


def _design_u(ev: _Evaluator, x: dict[str, float]) -> np.ndarray:
    xv = np.array([x.get(v.name, v.start) for v in ev.vars], dtype=np.float64)
    return (xv - ev.start) / ev.scale if ev.vars else np.zeros(0)


def _fresh_rows(
    problem: Problem, designs: dict[str, tuple[dict[str, Any], dict[str, float]]], seeds: list[int]
) -> dict[str, list[dict[str, float]]]:
    """Scalar outputs of each design for every fresh seed, from **one** compiled program:
    the seed is a traced input (``problem.seed`` replaced by the traced value while the
    objective is built, so its key is ``jax.random.key(seed)`` as in a solve) and
    ``lax.map`` runs the replicates one after another (memory of one replicate), every
    design of a replicate on the same seed (common random numbers)."""

    def one(seed):
        fresh = dataclasses.replace(problem, seed=seed)
        evs: dict[str, _Evaluator] = {}
        out = {}
        for label, (disc, x) in designs.items():
            k = repr(sorted(disc.items()))
            if k not in evs:  # one evaluator per discrete combination (checked by the solve)
                evs[k] = _Evaluator(fresh, dict(disc), check=False)
            ev = evs[k]
            vals = ev.outputs(jnp.asarray(_design_u(ev, x)))
            out[label] = {n: v for n, v in vals.items() if jnp.ndim(v) == 0}
        return out

    run = jax.jit(lambda ss: jax.lax.map(one, ss))
    res = run(jnp.asarray(np.array(seeds, dtype=np.int64)))
    return {
        label: [{n: float(v[i]) for n, v in outs.items()} for i in range(len(seeds))]
        for label, outs in res.items()
    }


def _fresh_rows_per_replicate(
    problem: Problem, designs: dict[str, tuple[dict[str, Any], dict[str, float]]], seeds: list[int]
) -> dict[str, list[dict[str, float]]]:
    """:func:`_fresh_rows` the old way, one compilation per replicate (kept to test that
    the single program gives the same values)."""
    rows: dict[str, list[dict[str, float]]] = {label: [] for label in designs}
    for s in seeds:
        fresh = dataclasses.replace(problem, seed=s)
        evs: dict[str, _Evaluator] = {}
        for label, (disc, x) in designs.items():
            k = repr(sorted(disc.items()))
            if k not in evs:
                evs[k] = _Evaluator(fresh, dict(disc))
            rows[label].append(evs[k].scalar_outputs(_design_u(evs[k], x)))
    return rows
