"""Tolerance budgets: sweeps, contribution ranking, cost and allocation.

Everything here works on a *values function* ``values_fn(sigmas) -> [n]``: the per-build
error metric (e.g. RMS residual, rad) of ``n`` fixed Monte Carlo builds (common random
numbers) for tolerance standard deviations ``sigmas`` (SI, one per tolerance). It must be
JAX-differentiable in ``sigmas``; :func:`encdesign.objectives.build_metrics` provides one.

* :func:`sweep_scales` — scale all tolerances (1-D) or two groups (2-D) and tabulate yield
  and percentile error; :func:`plot_sweep` draws the contour plots.
* :func:`contributions` — each tolerance's *variance share* of the expected mean-square
  error ``V(sigma) = E[ms]``: ``share_i = sigma_i dV/dsigma_i / sum_j sigma_j dV/dsigma_j``.
  For a term ``a_i sigma_i^2`` (one tolerance acting alone, linear error) this is exactly its
  share of the variance; a product term ``sigma_i^2 sigma_j^2`` (e.g. placement × centring
  leakage) is split equally between the two. Shares sum to 1. Also the *gradient
  sensitivity* ``d P_q / d ln sigma_i`` of the ``q``-th percentile.
* :func:`tolerance_cost` — ``C(sigma) = sum_i c_i ref_i / sigma_i`` (tighter costs more).
* :func:`allocate` — the cheapest tolerances meeting a yield target: minimise
  ``C(sigma)`` subject to a smooth yield surrogate ``Y_s(sigma) >= target + margin``
  (BFGS in ``ln sigma``, boxed through a sigmoid, with a quadratic penalty of increasing
  weight), then a common
  scale factor is tightened by bisection until the *exact* yield of the training builds
  meets the target with margin; :func:`check_yield` then counts an independent Monte Carlo
  population (fresh seed) and reports the binomial standard error.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike

from .._errors import input_error
from .._progress import progress_bar
from ._drivers import BFGS, optimise
from ._status import MAX_STEPS, SUCCESS, DriverStatus

ValuesFn = Callable[[jax.Array], jax.Array]


def tolerance_cost(
    sigmas: ArrayLike, reference: ArrayLike, weights: ArrayLike | None = None
) -> jax.Array:
    """``sum_i c_i ref_i / sigma_i`` (dimensionless); ``ref_i`` is the tolerance that costs
    ``c_i`` (default 1). Entries with ``ref_i = 0`` are not under design and cost nothing."""
    s = jnp.asarray(sigmas, dtype=jnp.float64)
    ref = jnp.asarray(reference, dtype=jnp.float64)
    c = jnp.ones_like(s) if weights is None else jnp.asarray(weights, dtype=jnp.float64)
    active = ref > 0
    return jnp.sum(jnp.where(active, c * ref / jnp.where(active, s, 1.0), 0.0))


def yield_stats(values: ArrayLike, spec: float) -> tuple[float, float]:
    """Fraction of ``values <= spec`` and its binomial standard error ``sqrt(p(1-p)/n)``."""
    v = np.asarray(values)
    if not np.all(np.isfinite(v)):
        raise FloatingPointError(f"{int(np.sum(~np.isfinite(v)))} non-finite build values")
    p = float(np.mean(v <= spec))
    return p, math.sqrt(max(p * (1.0 - p), 0.0) / v.size)


def smooth_yield(values: jax.Array, spec: float | jax.Array, width: float | jax.Array) -> jax.Array:
    """Mean of ``sigmoid((spec - v) / width)``: a differentiable yield surrogate."""
    return jnp.mean(jax.nn.sigmoid((spec - values) / width))


@dataclasses.dataclass(frozen=True)
class SweepTable:
    """Yield and percentile error over tolerance scale factors.

    Attributes:
        scales_a: scale factors of group A (1-D sweeps: of all tolerances).
        scales_b: scale factors of group B (``None`` for a 1-D sweep).
        group_a, group_b: names in each group.
        yield_: ``[len(a)]`` or ``[len(a), len(b)]`` fraction of builds within ``spec``.
        yield_stderr: binomial standard errors, same shape.
        percentile: the ``q``-th percentile of the metric, same shape (metric units).
        q: percentile level (0–100).
        spec: accuracy spec (metric units).
    """

    scales_a: np.ndarray
    scales_b: np.ndarray | None
    group_a: tuple[str, ...]
    group_b: tuple[str, ...]
    yield_: np.ndarray
    yield_stderr: np.ndarray
    percentile: np.ndarray
    q: float
    spec: float

    def rows(self) -> list[dict[str, float]]:
        """The table as a list of dicts (one per scale point)."""
        out = []
        for idx in np.ndindex(self.yield_.shape):
            r = {"scale_a": float(self.scales_a[idx[0]])}
            if self.scales_b is not None:
                r["scale_b"] = float(self.scales_b[idx[1]])
            r.update(
                yield_=float(self.yield_[idx]),
                yield_stderr=float(self.yield_stderr[idx]),
                percentile=float(self.percentile[idx]),
            )
            out.append({k.rstrip("_"): v for k, v in r.items()})
        return out


def sweep_scales(
    values_fn: ValuesFn,
    sigmas: ArrayLike,
    names: Sequence[str],
    spec: float,
    scales_a: Sequence[float],
    *,
    group_a: Sequence[str] | None = None,
    group_b: Sequence[str] | None = None,
    scales_b: Sequence[float] | None = None,
    q: float = 99.0,
    progress: bool = False,
) -> SweepTable:
    """Tabulate yield and the ``q``-th percentile while scaling tolerances.

    1-D (``group_b`` is ``None``): tolerances in ``group_a`` (default: all) are multiplied
    by each of ``scales_a``. 2-D: ``group_a`` by ``scales_a`` and ``group_b`` by
    ``scales_b`` on a grid (the rest stay at ``sigmas``).
    """
    names = list(names)
    sig = np.asarray(sigmas, dtype=np.float64)
    ga = tuple(group_a) if group_a is not None else tuple(names)
    gb = tuple(group_b) if group_b is not None else ()
    for g in (*ga, *gb):
        if g not in names:
            raise input_error("sweep_scales", f"unknown tolerance {g!r}", f"one of {names}")
    ma = np.array([n in ga for n in names], dtype=np.float64)
    mb = np.array([n in gb for n in names], dtype=np.float64)
    sa = np.asarray(scales_a, dtype=np.float64)
    sb = None if not gb else np.asarray(scales_b, dtype=np.float64)
    shape = (len(sa),) if sb is None else (len(sa), len(sb))
    y, ye, pc = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    f = _jitted_values(values_fn)
    with progress_bar("tolerance sweep", int(np.prod(shape)), enabled=progress) as bar:
        for idx in np.ndindex(shape):
            fac = 1.0 + ma * (sa[idx[0]] - 1.0)
            if sb is not None:
                fac = fac * (1.0 + mb * (sb[idx[1]] - 1.0))
            vals = np.asarray(f(jnp.asarray(sig * fac)))
            y[idx], ye[idx] = yield_stats(vals, spec)
            pc[idx] = np.percentile(vals, q)
            bar.update()
    return SweepTable(sa, sb, ga, gb, y, ye, pc, float(q), float(spec))


def plot_sweep(
    table: SweepTable, out: str | Path, filename: str, *, units: str = "urad", factor: float = 1e6
) -> Path:
    """Contour plot (2-D) or line plot (1-D) of yield and percentile error; PNG path."""
    from ..io._study import new_figure, save_figure

    fig, axes = new_figure(1, 2, figsize=(10, 4))
    if table.scales_b is None:
        axes[0].plot(table.scales_a, table.yield_, "o-")
        axes[0].set_xlabel("tolerance scale")
        axes[0].set_ylabel("yield")
        axes[1].plot(table.scales_a, table.percentile * factor, "o-")
        axes[1].axhline(table.spec * factor, color="k", ls="--", label="spec")
        axes[1].set_xlabel("tolerance scale")
        axes[1].set_ylabel(f"P{table.q:g} error ({units})")
        axes[1].legend()
    else:
        xa, xb = np.meshgrid(table.scales_b, table.scales_a)
        c0 = axes[0].contourf(xa, xb, table.yield_, levels=12)
        fig.colorbar(c0, ax=axes[0], label="yield")
        c1 = axes[1].contourf(xa, xb, table.percentile * factor, levels=12)
        fig.colorbar(c1, ax=axes[1], label=f"P{table.q:g} error ({units})")
        axes[1].contour(xa, xb, table.percentile, levels=[table.spec], colors="k")
        for ax in axes:
            ax.set_xlabel(f"scale of {', '.join(table.group_b)}")
            ax.set_ylabel(f"scale of {', '.join(table.group_a)}")
            ax.set_xscale("log")
            ax.set_yscale("log")
    return save_figure(fig, out, filename)


@dataclasses.dataclass(frozen=True)
class Contributions:
    """Contribution ranking of tolerances.

    Attributes:
        names: tolerance names.
        variance_share: share of the expected mean-square error (sums to 1).
        gradient_sensitivity: ``d P_q / d ln sigma_i`` (metric units): how much the
            percentile error grows for a 100 % (e-fold) looser tolerance.
        expected_ms: ``E[ms]`` at ``sigmas`` (metric units squared).
        order: indices sorted by decreasing variance share.
    """

    names: tuple[str, ...]
    variance_share: np.ndarray
    gradient_sensitivity: np.ndarray
    expected_ms: float
    order: tuple[int, ...]

    def as_dict(self) -> dict[str, float]:
        """``{name: variance share}``."""
        return {n: float(s) for n, s in zip(self.names, self.variance_share)}


def contributions(
    ms_fn: ValuesFn,
    values_fn: ValuesFn,
    sigmas: ArrayLike,
    names: Sequence[str],
    *,
    q: float = 99.0,
) -> Contributions:
    """Rank tolerances by variance share and gradient sensitivity (module docstring).

    Args:
        ms_fn: per-build mean-square error ``[n]`` as a function of ``sigmas``.
        values_fn: per-build metric ``[n]`` (for the percentile sensitivity).
        sigmas: tolerances (SI), one per name; tolerances at zero get share 0.
        names: their names.
        q: percentile level (0–100).
    """
    s = jnp.asarray(sigmas, dtype=jnp.float64)

    def both(x):  # one compiled program (eagerly, every loop or scan in it compiles anew)
        ev_g = jax.value_and_grad(lambda y: jnp.mean(ms_fn(y)))(x)
        return ev_g, jax.grad(lambda y: jnp.percentile(values_fn(y), q))(x)

    (ev, g), g_p = jax.jit(both)(s)
    el = np.asarray(s * g)
    total = float(np.sum(el))
    if not (math.isfinite(total) and total > 0):
        raise FloatingPointError(f"contributions: total elasticity {total} (expected > 0)")
    share = el / total
    gp = np.asarray(g_p) * np.asarray(s)
    order = tuple(int(i) for i in np.argsort(-share))
    return Contributions(tuple(names), share, gp, float(ev), order)


@dataclasses.dataclass(frozen=True)
class Allocation:
    """Result of :func:`allocate`.

    Attributes:
        sigmas: allocated tolerances (SI), one per name.
        names: their names.
        cost: :func:`tolerance_cost` of ``sigmas``.
        train_yield: exact yield of the training builds at ``sigmas``.
        smooth_yield: surrogate yield at the optimiser's answer (before the final scale).
        scale: common factor applied after the optimiser (``<= 1`` tightens).
        status: ``"success"`` or the failing driver status (``"max_steps_reached"`` when
            the last penalty round hit ``max_steps``: the tolerances are then scaled to the
            goal as usual, but the allocation is not converged).
        message: account of the status.
        n_steps: optimiser iterations (all penalty rounds).
        rare: with ``rare_metric``: the importance-sampling estimate at ``sigmas``
            (:meth:`~encdesign.design.RareEventResult.as_dict`), else ``None``.
    """

    sigmas: np.ndarray
    names: tuple[str, ...]
    cost: float
    train_yield: float
    smooth_yield: float
    scale: float
    status: DriverStatus
    message: str
    n_steps: int
    rare: dict[str, Any] | None = None

    @property
    def ok(self) -> bool:
        """True when the status is an answer (:attr:`DriverStatus.ok`: ``success``)."""
        return self.status.ok


@functools.lru_cache(maxsize=64)
def _jitted_values(values_fn: ValuesFn) -> ValuesFn:
    """``values_fn`` compiled, once per function (the allocations of a Pareto front share
    it)."""
    if callable(getattr(values_fn, "lower", None)):  # compiled already
        return values_fn
    return jax.jit(values_fn)


@functools.lru_cache(maxsize=64)
def _allocation_objective(values_fn: ValuesFn, didx: tuple[int, ...]):
    """:func:`allocate`'s penalised objective ``f(v, a)``, the same function for every
    allocation of one ``values_fn`` (the settings and the target are in ``a``), so the
    allocations of a Pareto front share one compiled solver."""
    idx = np.asarray(didx, dtype=np.int64)

    def objective(v: jax.Array, a: dict[str, jax.Array]) -> jax.Array:
        u = a["lo"] + (a["hi"] - a["lo"]) * jax.nn.sigmoid(v)  # box through a sigmoid
        s = a["ref"].at[idx].set(a["ref"][idx] * jnp.exp(u))
        c = tolerance_cost(s, a["cost_ref"], a["weights"]) / a["cref"]
        ys = smooth_yield(values_fn(s), a["spec"], a["width"])
        return c + a["mu"] * jax.nn.relu(a["goal"] - ys) ** 2

    return objective


def allocate(
    values_fn: ValuesFn,
    reference: ArrayLike,
    names: Sequence[str],
    spec: float,
    target: float,
    *,
    weights: ArrayLike | None = None,
    margin: float | None = None,
    width: float | None = None,
    fixed: ArrayLike | None = None,
    bounds: tuple[float, float] = (1e-3, 1e3),
    penalties: Sequence[float] = (1e2, 1e4, 1e6),
    max_steps: int = 200,
    throw: bool = False,
    rare_metric: Callable[[jax.Array, jax.Array], jax.Array] | None = None,
    rare_dim: int | None = None,
    rare_key: jax.Array | None = None,
    rare_n: int = 4000,
    start: ArrayLike | None = None,
) -> Allocation:
    """Cheapest tolerances with ``target`` of the training builds within ``spec``.

    Args:
        values_fn: per-build metric ``[n]`` of the training builds (metric units).
        reference: reference tolerances ``ref_i`` (SI): the cost is ``sum c_i ref_i/sigma_i``
            and the search starts from them; zero entries are not designed (kept zero).
        names: tolerance names.
        spec: accuracy spec (metric units).
        target: required yield (0 < target < 1).
        weights: cost weights ``c_i`` (default 1).
        margin: yield margin added to the target for the training builds (default two
            binomial standard errors of ``n`` builds), against the optimism of optimising
            on the same builds that are counted.
        width: sigmoid width of the smooth yield (default ``0.05 * spec``).
        fixed: per tolerance, ``True`` to keep it at ``reference`` (not designed).
        bounds: range of ``sigma / ref`` searched.
        penalties: increasing penalty weights (relative to the reference cost).
        max_steps: BFGS iterations per penalty round.
        throw: raise :class:`~encdesign.design._drivers.OptimisationError` on failure.
        rare_metric: ``rare_metric(z, sigmas)``, the per-build metric of a standard-normal
            vector ``z [rare_dim]`` at tolerances ``sigmas``. When given, the yield goal is
            shown by importance sampling (:func:`~encdesign.design.importance_yield`,
            ``rare_n`` samples, key ``rare_key``) rather than by the training builds, so
            targets such as 99.99 % are practical: the optimiser shapes the tolerances on
            the training builds at the highest target they can show (``1 - 10/n``), then the
            common scale is bisected until the importance-sampling yield minus two standard
            errors meets ``target``. Raises :class:`~encdesign.EncdesignInputError` when
            importance sampling cannot reach the target within the bounds, or its standard
            error is too large to show it.
        rare_dim, rare_key, rare_n: see ``rare_metric``.
        start: tolerances (SI) to start the optimiser from (a warm start, e.g. the
            allocation at a neighbouring target, as :func:`pareto_front` does); default
            the reference (the middle of the box, in ``ln sigma``).
    """
    if not 0.0 < target < 1.0:
        raise input_error(
            "allocate.target", f"infeasible yield target {target!r}", "0 < target < 1"
        )
    ref = np.asarray(reference, dtype=np.float64)
    k = ref.size
    fixed_m = np.zeros(k, bool) if fixed is None else np.asarray(fixed, dtype=bool)
    design = (ref > 0) & ~fixed_m
    if not design.any():
        raise input_error("allocate.reference", "no tolerance to design", "some ref_i > 0")
    cref = float(tolerance_cost(ref, np.where(design, ref, 0.0), weights))
    n = int(np.asarray(jax.eval_shape(values_fn, jnp.asarray(ref)).shape[0]))
    final_target = target
    if rare_metric is not None:
        if rare_dim is None or rare_key is None:
            raise input_error("allocate.rare_metric", "given without rare_dim and rare_key")
        target = min(target, 1.0 - 10.0 / n)  # what the training builds can show
    if margin is None:
        margin = 2.0 * math.sqrt(target * (1.0 - target) / n)
    goal = min(target + margin, 1.0 - 0.5 / n)
    if width is None:
        width = 0.05 * spec
    didx = np.flatnonzero(design)

    lo, hi = math.log(bounds[0]), math.log(bounds[1])

    def u_of(v: jax.Array) -> jax.Array:  # box [lo, hi] through a sigmoid: bounds hold
        return lo + (hi - lo) * jax.nn.sigmoid(v)

    def sig_of(u: jax.Array) -> jax.Array:
        return jnp.asarray(ref).at[didx].set(jnp.asarray(ref[didx]) * jnp.exp(u))

    objective = _allocation_objective(values_fn, tuple(int(i) for i in didx))
    obj_args = {
        "lo": lo,
        "hi": hi,
        "ref": ref,
        "cost_ref": np.where(design, ref, 0.0),
        "weights": np.ones(k) if weights is None else np.asarray(weights, dtype=np.float64),
        "cref": cref,
        "spec": float(spec),
        "width": float(width),
        "goal": float(goal),
    }

    v = np.full(didx.size, math.log(-lo / hi)) if lo < 0 < hi else np.zeros(didx.size)
    if start is not None:
        s0 = np.asarray(start, dtype=np.float64)
        if s0.shape != ref.shape or not np.all(np.isfinite(s0)) or np.any(s0[didx] <= 0):
            raise input_error(
                "allocate.start", f"{s0!r}", f"{k} finite tolerances > 0 where designed"
            )
        frac = (np.log(s0[didx] / ref[didx]) - lo) / (hi - lo)  # position in the box
        frac = np.clip(frac, 1e-9, 1.0 - 1e-9)
        v = np.log(frac) - np.log1p(-frac)  # inverse of the sigmoid in u_of
    steps, status, msg = 0, SUCCESS, "converged"
    capped: list[str] = []
    for mu in penalties:
        a = jax.tree.map(lambda x: jnp.asarray(x, dtype=jnp.float64), {**obj_args, "mu": mu})
        sol = optimise(objective, BFGS(rtol=1e-6, atol=1e-9, max_steps=max_steps), v, a)
        steps += sol.n_steps
        if sol.status == MAX_STEPS:  # go on to the next round from here, but never "success"
            capped.append(f"penalty {mu:g}: {sol.n_steps} of {max_steps} steps")
        elif sol.status != SUCCESS:
            status, msg = sol.status, f"penalty {mu:g}: {sol.message}"
            break
        v = sol.value
    if status == SUCCESS and capped and capped[-1].startswith(f"penalty {penalties[-1]:g}:"):
        # the last (deciding) round hit its step cap: not converged
        status, msg = MAX_STEPS, "step cap hit (" + "; ".join(capped) + ")"
    elif status == SUCCESS and capped:
        msg = "converged in the last round (step cap hit earlier: " + "; ".join(capped) + ")"
    u = np.asarray(u_of(jnp.asarray(v)))
    # final common scale: largest factor (<= 1.5) whose exact training yield meets the goal
    f = _jitted_values(values_fn)
    ys_opt = float(smooth_yield(f(sig_of(jnp.asarray(u))), spec, width))

    def exact(fac: float) -> float:
        s = np.asarray(sig_of(jnp.asarray(u + math.log(fac))))
        return yield_stats(np.asarray(f(jnp.asarray(s))), spec)[0]

    scale = 1.0
    rare_out = None
    usable = status in (SUCCESS, MAX_STEPS)  # a capped answer is scaled too, but stays marked
    if usable and rare_metric is not None and rare_dim is not None and rare_key is not None:
        scale, rare_out = _rare_scale(
            rare_metric, rare_dim, rare_key, rare_n, lambda fac: np.asarray(
                sig_of(jnp.asarray(u + math.log(fac)))), spec, final_target,
        )  # fmt: skip
    elif usable:
        a, b = 1e-3, 1.5
        if exact(a) < goal:
            status, msg = (
                DriverStatus.INFEASIBLE,
                f"yield target {goal:.4g} unreachable within bounds",
            )
        else:
            if exact(b) >= goal:
                scale = b
            else:
                for _ in range(40):
                    mid = math.sqrt(a * b)
                    if exact(mid) >= goal:
                        a = mid
                    else:
                        b = mid
                    if b / a < 1 + 1e-4:
                        break
                scale = a
    sig = np.asarray(sig_of(jnp.asarray(u + math.log(scale))))
    train_y = yield_stats(np.asarray(f(jnp.asarray(sig))), spec)[0]
    cost = float(tolerance_cost(sig, np.where(design, ref, 0.0), weights))
    res = Allocation(sig, tuple(names), cost, train_y, ys_opt, scale, status, msg, steps, rare_out)
    if throw and not status.ok:
        from .._errors import OptimisationError

        raise OptimisationError(f"allocate: {status}: {msg}")
    return res


def _rare_scale(
    metric: Callable[[jax.Array, jax.Array], jax.Array],
    dim: int,
    key: jax.Array,
    n: int,
    sig_at: Callable[[float], np.ndarray],
    spec: float,
    target: float,
) -> tuple[float, dict[str, Any]]:
    """Largest common factor (``1e-3 … 1.5``) whose importance-sampling yield, minus two
    standard errors, meets ``target``; and the estimate there."""
    from ._rare import importance_yield

    def shown(fac: float):
        r = importance_yield(metric, dim, spec, key=key, n=n, args=jnp.asarray(sig_at(fac)))
        if r.status == DriverStatus.NO_FAILURE_FOUND:
            return True, r
        if not r.ok:
            return False, r
        return r.failure_prob + 2.0 * r.failure_stderr <= 1.0 - target, r

    a, b = 1e-3, 1.5
    ok, r = shown(a)
    if not ok:
        raise input_error(
            "allocate.target",
            f"yield target {target!r} unreachable by importance sampling: with every "
            f"tolerance at 1e-3 of the allocation the estimate is "
            f"{1.0 - r.failure_prob:.6g} +- {r.failure_stderr:.2g} ({r.status}: {r.message})",
            "a lower target, a looser spec or a lower bound below 1e-3",
        )
    ok, rb = shown(b)
    if ok:
        a, r = b, rb
    else:
        for _ in range(12):
            mid = math.sqrt(a * b)
            ok, rm = shown(mid)
            if ok:
                a, r = mid, rm
            else:
                b = mid
            if b / a < 1 + 1e-2:
                break
    if r.ok and r.failure_stderr > 0.5 * (1.0 - target):
        raise input_error(
            "allocate.rare_n",
            f"importance sampling cannot show yield target {target!r}: standard error "
            f"{r.failure_stderr:.2g} with {n} samples",
            "more samples (rare_n)",
        )
    return a, r.as_dict()


def fresh_vs_reference(
    values: ArrayLike, reference_values: ArrayLike, spec: float
) -> dict[str, Any]:
    """An allocation against the reference tolerances on the same fresh builds
    (:func:`~encdesign.design.paired_comparison`): the failure fraction (builds over
    ``spec``) of both, with standard errors, and the paired difference (reference minus
    allocation: positive when the allocation fails less), plus the mean metric of both
    (``mean_metric``, same form). JSON-able."""
    from ._validate import paired_comparison

    v, r = np.asarray(values, dtype=np.float64), np.asarray(reference_values, dtype=np.float64)
    fail = paired_comparison((v > spec).astype(np.float64), (r > spec).astype(np.float64))
    return {**fail.as_dict(), "figure": "failure fraction", "mean_metric": paired_comparison(
        v, r).as_dict()}  # fmt: skip


def check_yield(
    values: ArrayLike, spec: float, target: float, *, n_sigma: float = 2.0
) -> dict[str, Any]:
    """Independent check of a yield: fraction within ``spec``, binomial standard error, and
    whether the target is reached within ``n_sigma`` standard errors."""
    p, se = yield_stats(values, spec)
    return {
        "checked_yield": p,
        "checked_yield_stderr": se,
        "n_builds": int(np.asarray(values).size),
        "meets_target": bool(p + n_sigma * max(se, 1e-12) >= target),
    }


@dataclasses.dataclass(frozen=True)
class ParetoFront:
    """Cost against yield target: one :func:`allocate` per target (:func:`pareto_front`).

    Attributes:
        targets: yield targets, increasing.
        allocations: the :class:`Allocation` at each target.
        warm_from: per point, the target whose allocation it started from (``None``: cold,
            from the reference tolerances).
        checked: per point, the independent check (:func:`check_yield` of fresh builds)
            or ``None`` when no ``check_fn`` was given.
    """

    targets: tuple[float, ...]
    allocations: tuple[Allocation, ...]
    warm_from: tuple[float | None, ...]
    checked: tuple[dict[str, Any] | None, ...]

    @property
    def ok(self) -> bool:
        """True when every point's allocation succeeded."""
        return all(a.ok for a in self.allocations)

    @property
    def monotone(self) -> bool:
        """True when the cost does not fall as the target rises (over successful points)."""
        c = [a.cost for a in self.allocations if a.ok]
        return all(b >= a * (1.0 - 1e-9) for a, b in zip(c, c[1:]))

    def rows(self) -> list[dict[str, Any]]:
        """One dict per point: target, cost, yields, status, steps, warm start, tolerances."""
        out = []
        for t, a, w, c in zip(self.targets, self.allocations, self.warm_from, self.checked):
            r = {
                "target_yield": t,
                "cost": a.cost,
                "train_yield": a.train_yield,
                "status": a.status,
                "converged": a.ok,
                "message": a.message,
                "n_steps": a.n_steps,
                "warm_start_from_target": w,
                "tolerances": {n: float(v) for n, v in zip(a.names, a.sigmas)},
            }
            if c is not None:
                r.update(
                    checked_yield=c["checked_yield"],
                    checked_yield_stderr=c["checked_yield_stderr"],
                    n_check=c["n_builds"],
                    meets_target=c["meets_target"],
                    fresh_vs_reference=c.get("fresh"),
                )
            out.append(r)
        return out


def pareto_front(
    values_fn: ValuesFn,
    reference: ArrayLike,
    names: Sequence[str],
    spec: float,
    targets: Sequence[float],
    *,
    anchor: Allocation | None = None,
    anchor_target: float | None = None,
    check_fn: ValuesFn | None = None,
    warm: bool = True,
    progress: bool = False,
    **allocate_kw: Any,
) -> ParetoFront:
    """Pareto front of tolerance cost against yield target by re-allocating along it.

    Each target gets its own :func:`allocate` (same ``values_fn``, ``reference``, ``spec``
    and keywords). With ``warm`` the allocation at a target starts from the tolerances of its
    neighbour on the front (the points are solved outward from the first one, or from
    ``anchor``, an allocation already made at ``anchor_target``), so each solve begins close
    to its answer and runs only the last (stiffest) penalty round of :func:`allocate`
    instead of the whole sequence; the anchor itself is reused as the point at
    ``anchor_target``. A failed
    point is kept with its status and the next one starts from the last good point.

    Args:
        values_fn, reference, names, spec: as for :func:`allocate`.
        targets: yield targets (0 < t < 1); sorted and de-duplicated.
        anchor, anchor_target: an existing allocation and its target (optional).
        check_fn: ``check_fn(sigmas) -> values`` of *fresh* builds (another seed): each point
            (also one that hit its step cap, marked ``converged = False`` in the rows) is
            checked with :func:`check_yield` (binomial standard error) and compared with the
            reference tolerances on the same fresh builds (:func:`fresh_vs_reference`).
        warm: start each point from its neighbour (``False``: every point cold).
        progress: progress bar.
        allocate_kw: passed to :func:`allocate` (not ``start``).
    """
    if "start" in allocate_kw:
        raise input_error("pareto_front", "'start' given", "warm starts chosen by the front")
    anchor_t = None if anchor_target is None else float(anchor_target)
    ts = sorted(
        {float(t) for t in targets} | ({anchor_t} if anchor and anchor_t is not None else set())
    )
    if not ts:
        raise input_error("pareto_front.targets", "empty", "at least one yield target")
    for t in ts:
        if not 0.0 < t < 1.0:
            raise input_error("pareto_front.targets", f"yield target {t!r}", "0 < target < 1")
    if anchor is not None and anchor_target is None:
        raise input_error("pareto_front.anchor", "given without anchor_target", "both")
    allocs: dict[float, Allocation] = {}
    warm_from: dict[float, float | None] = {}
    i0 = ts.index(anchor_t) if anchor is not None and anchor_t is not None else 0
    order = [i0, *range(i0 + 1, len(ts)), *range(i0 - 1, -1, -1)]
    with progress_bar("pareto front", len(ts), enabled=progress) as bar:
        for i in order:
            t = ts[i]
            if anchor is not None and i == i0:
                allocs[t], warm_from[t] = anchor, None
                bar.update()
                continue
            # neighbour towards the first point: the last usable allocation on that side (one
            # that hit its step cap is still scaled to its yield goal: a start, not a result)
            side = range(i - 1, i0 - 1, -1) if i > i0 else range(i + 1, i0 + 1)
            prev = next(
                (
                    ts[j]
                    for j in side
                    if ts[j] in allocs and allocs[ts[j]].status in (SUCCESS, MAX_STEPS)
                ),
                None,
            )
            start = allocs[prev].sigmas if (warm and prev is not None) else None
            kw = dict(allocate_kw)
            if start is not None:  # already near the front: only the final (stiff) penalty
                kw["penalties"] = tuple(kw.get("penalties", (1e2, 1e4, 1e6)))[-1:]
            allocs[t] = allocate(values_fn, reference, names, spec, t, start=start, **kw)
            warm_from[t] = prev if start is not None else None
            bar.update()
    checked = []
    ref_fresh = None if check_fn is None else np.asarray(check_fn(jnp.asarray(reference)))
    for t in ts:
        a = allocs[t]
        if check_fn is None or ref_fresh is None or a.status not in (SUCCESS, MAX_STEPS):
            checked.append(None)
        else:
            fresh = np.asarray(check_fn(jnp.asarray(a.sigmas)))
            checked.append(
                {**check_yield(fresh, spec, t), "fresh": fresh_vs_reference(fresh, ref_fresh, spec)}
            )
    return ParetoFront(
        tuple(ts), tuple(allocs[t] for t in ts), tuple(warm_from[t] for t in ts), tuple(checked)
    )


def plot_pareto(front: ParetoFront, out: str | Path, filename: str) -> Path:
    """Cost against yield (training and independently checked, with 2-s.e. bars); PNG."""
    from ..io._study import new_figure, save_figure

    fig, ax = new_figure(figsize=(6, 4))
    rows = [r for r in front.rows() if r["status"] == SUCCESS]
    loss = [1.0 - r["target_yield"] for r in rows]
    ax.plot(loss, [r["cost"] for r in rows], "o-", label="allocation (target)")
    chk = [r for r in rows if "checked_yield" in r]
    if chk:
        ax.errorbar(
            [max(1.0 - r["checked_yield"], 1e-6) for r in chk],
            [r["cost"] for r in chk],
            xerr=[2 * r["checked_yield_stderr"] for r in chk],
            fmt="s",
            mfc="none",
            label="independent check (2 s.e.)",
        )
    ax.set_xscale("log")
    ax.invert_xaxis()
    ax.set_xlabel("1 - yield")
    ax.set_ylabel("tolerance cost")
    ax.set_title("Cost against yield (Pareto front)")
    ax.legend()
    return save_figure(fig, out, filename)
