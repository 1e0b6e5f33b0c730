"""Best motor pole pairs x sensor count for a shifted-delta-sum instrument under a tolerance set.

Seed 001 (Mikkelson): the SDS reading of the platform angle is exact at constant speed, but
the motor's speed ripple interacts with the disks' mark errors; the orders the ripple and
the mark errors share survive the average over equally spaced sensors unless the sensor
count cancels them, hence the rule "pole count not a multiple of the sensor count". This
study enumerates pole pairs x sensors per disk (the discrete design variables, with the
enumeration driver :func:`encdesign.design.enumerate_designs`), and for each combination
evaluates the SDS residual over the platform turn
(:func:`encdesign.objectives.sds_residuals`: RMS of the phi error minus its mean) on Monte
Carlo builds whose disks draw their mark errors from the tolerance set (common random
numbers: every combination sees the same disks). The objective is the mean residual over
builds; ties within 1 % go to fewer sensors (cheaper).

Second stage, the sensor azimuths as continuous design variables: for every combination
the moving sensors' azimuths (sensor 0 at 0: a common rotation only shifts φ) are optimised
by BFGS (:func:`encdesign.design.optimise`, gradient by JAX through the edge-time
solve) on ``log`` of the mean residual, from ``--starts`` *random* layouts (never from the
equally spaced one). The fixed sensors stay equally spaced: they see every mark at the
same shaft angles for every φ, so they add a constant that the zeroing removes (their
gradient is reported: ~1e-12 of the moving ones in the quick run). The pole-count rule is
then read off the optimised residuals: for each sensor count S >= 3,
``rule_from_optimiser`` says whether every pole count that is a multiple of S ends worse
than every pole count that is not, and ``best_optimised`` is the optimiser's best
combination. With S = 2 the order-2 (ellipticity × coil-mismatch ripple) term, which no
two-sensor layout can cancel together with order 1, dominates, so the rule is not
expected there.

Out of sample (issue 27): the optimiser's best combination with its optimised azimuths and
its baseline, the same combination with equally spaced sensors (what the optimiser
replaces), are evaluated on ``--fresh-builds`` fresh builds (an independent key,
:func:`encdesign.design.fresh_key`, the same disks for both: common random numbers);
``fresh_check`` gives both mean residuals with standard errors, the paired difference and
``win_significant`` (the optimised layout is better by more than two standard errors).

Outputs: ``pole-sensor-opt.json`` (``table``, ``best``, ``optimised``,
``rule_from_optimiser``, ``best_optimised``, ``gradient_check``, ``fresh_check``),
``pole_sensor_opt.png``
(residual grid, equally spaced and optimised) and the cases in ``cases.jsonl``.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import sys
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from encdesign.design import (
    BFGS,
    NONFINITE,
    SUCCESS,
    CaseRecorder,
    enumerate_designs,
    fresh_key,
    optimise,
    paired_comparison,
)
from encdesign.io import int_arg, new_figure, save_figure, study_parser, write_results
from encdesign.objectives import SDSTolerances, sds_motor, sds_residuals
from encdesign.physics import equally_spaced

NAME = "pole-sensor-opt"
ARCSEC = math.pi / 180 / 3600


class _Eval(NamedTuple):
    objective: float
    status: str
    values: tuple[float, ...]


def _residuals(n_sensors, tol, key, n_builds, marks, n_phi):
    """``r(y, fixed, motor)``: the SDS residuals (rad) of the builds with moving sensors at
    ``[0, *y]`` rad, fixed sensors at ``fixed`` (rad) and ``motor`` (a dense
    :func:`~encdesign.objectives.sds_motor`: an argument, so that one compiled program
    serves every pole count)."""

    def r(y, fixed, motor):
        moving = jnp.concatenate([jnp.zeros(1), y])
        return sds_residuals(
            0,  # not used: the motor is given
            n_sensors,
            tol,
            key=key,
            n_builds=n_builds,
            marks_per_rev=marks,
            n_phi=n_phi,
            fixed_azimuths_rad=fixed,
            moving_azimuths_rad=moving,
            motor=motor,
        )

    return r


def _log_residual(n_sensors, tol, key, n_builds, marks, n_phi):
    """``f(y, args)``: log of the mean SDS residual (rad) with moving sensors at
    ``[0, *y]`` rad (``args``: the fixed sensors' azimuths, rad, and the motor, as
    :func:`_residuals`)."""
    r = _residuals(n_sensors, tol, key, n_builds, marks, n_phi)
    return lambda y, args: jnp.log(jnp.mean(r(y, *args)))


def _log_mean(vals) -> float:
    return math.log(float(np.mean(np.asarray(vals))))


def _gaps_deg(moving_rad: np.ndarray) -> list[float]:
    a = np.sort(np.mod(moving_rad, 2 * math.pi))
    return [float(g) for g in np.degrees(np.diff(np.append(a, a[0] + 2 * math.pi)))]


def _optimise_azimuths(c, rj, f, motor, starts, max_steps, seed):
    """Best of ``starts`` BFGS runs from random moving-sensor layouts for one combination
    (``rj``: its residuals compiled, :func:`_residuals`, for the start values; ``f``: the
    sensor count's :func:`_log_residual`, one function for every pole count: ``optimise``
    reuses its compiled solver; ``motor``: the combination's dense motor)."""
    pp, ns = c["pole_pairs"], c["n_sensors"]
    fixed = np.asarray(equally_spaced(ns))
    rng = np.random.default_rng([seed, pp, ns])
    runs = []
    for _ in range(starts):
        y0 = rng.uniform(0.0, 2 * math.pi, ns - 1)
        sol = optimise(f, BFGS(rtol=1e-7, atol=1e-10, max_steps=max_steps), y0,
                       (jnp.asarray(fixed), motor))  # fmt: skip
        f0 = _log_mean(rj(jnp.asarray(y0), jnp.asarray(fixed)))
        runs.append((float(sol.objective), sol, y0, f0))
    ok = [r for r in runs if math.isfinite(r[0])]
    best = min(ok, key=lambda r: r[0]) if ok else runs[0]
    obj, sol, y0, f0 = best
    moving = np.concatenate([[0.0], np.asarray(sol.value)])
    return {
        "pole_pairs": pp,
        "n_sensors": ns,
        "status": sol.status,
        "n_steps": int(sol.n_steps),
        "residual_mean_rad": math.exp(obj) if math.isfinite(obj) else math.nan,
        "residual_start_rad": math.exp(f0),
        "start_moving_azimuths_deg": [0.0, *(float(v) for v in np.degrees(y0))],
        "moving_azimuths_deg": [float(v) for v in np.degrees(np.mod(moving, 2 * math.pi))],
        "moving_gaps_deg": _gaps_deg(moving),
        "max_gap_deviation_from_equal_deg": float(
            np.max(np.abs(np.array(_gaps_deg(moving)) - 360.0 / ns))
        ),
        "fixed_azimuths_deg": [float(v) for v in np.degrees(fixed)],
        "starts": [
            {"status": r[1].status, "residual_mean_rad": math.exp(r[0]), "n_steps": r[1].n_steps}
            for r in runs
        ],
        "pole_multiple_of_sensors": pp % ns == 0,
    }, (sol.value, fixed)


def _gradient_check(f, motor, rj, y, fixed, h: float = 1e-5) -> dict[str, float]:
    """AD gradient of ``f`` (log residual, with ``motor``) in the moving and fixed azimuths
    against central differences (step ``h`` rad) of the log mean of ``rj`` (the residuals,
    compiled)."""
    g_m, g_f = (
        np.asarray(g)
        for g in jax.jit(jax.grad(lambda y, fx: f(y, (fx, motor)), argnums=(0, 1)))(
            jnp.asarray(y), jnp.asarray(fixed)
        )
    )
    fd = np.array(
        [
            (
                _log_mean(rj(jnp.asarray(y + h * e), jnp.asarray(fixed)))
                - _log_mean(rj(jnp.asarray(y - h * e), jnp.asarray(fixed)))
            )
            / (2 * h)
            for e in np.eye(y.size)
        ]
    )
    scale = max(float(np.max(np.abs(fd))), 1e-300)
    return {
        "step_rad": h,
        "max_abs_error": float(np.max(np.abs(g_m - fd))),
        "max_rel_error": float(np.max(np.abs(g_m - fd)) / scale),
        "grad_moving_per_rad": [float(v) for v in g_m],
        "fd_moving_per_rad": [float(v) for v in fd],
        "grad_fixed_per_rad": [float(v) for v in g_f],
    }


def _fresh_check(row, motor, tol, key, n_fresh, marks, n_phi) -> dict:
    """The optimised azimuths of ``row`` and equally spaced sensors (same combination,
    ``motor`` its dense motor) on ``n_fresh`` fresh builds, the same for both: the paired
    comparison of the residuals."""
    pp, ns = row["pole_pairs"], row["n_sensors"]
    r = jax.jit(_residuals(ns, tol, fresh_key(key), n_fresh, marks, n_phi))
    fixed = jnp.asarray(np.asarray(equally_spaced(ns)))
    y_opt = jnp.asarray(np.radians(row["moving_azimuths_deg"][1:]))
    va, vb = np.asarray(r(y_opt, fixed, motor)), np.asarray(r(fixed[1:], fixed, motor))
    base = {"pole_pairs": pp, "n_sensors": ns, "chosen": "optimised moving azimuths",
            "baseline": "equally spaced sensors", "n_fresh_builds": n_fresh}  # fmt: skip
    if not (np.all(np.isfinite(va)) and np.all(np.isfinite(vb))):
        return {**base, "residual_fresh_rad": None, "baseline_residual_fresh_rad": None,
                "comparison": None, "win_significant": False, "verdict": "non-finite",
                "summary": "fresh builds: non-finite residuals"}  # fmt: skip
    c = paired_comparison(va, vb)
    return {
        **base,
        "residual_fresh_rad": c.chosen,
        "residual_fresh_stderr_rad": c.chosen_stderr,
        "baseline_residual_fresh_rad": c.baseline,
        "baseline_residual_fresh_stderr_rad": c.baseline_stderr,
        "comparison": c.as_dict(),
        "win_significant": c.win_significant,
        "verdict": c.verdict,
        "summary": f"{pp} pole pairs x {ns} sensors, optimised vs equally spaced: "
        + c.describe("arcsec", 1.0 / ARCSEC),
    }


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--starts", type=int, default=None, help="random starts per combination")
    p.add_argument("--max-steps", type=int, default=None, help="BFGS steps per start")
    p.add_argument(
        "--no-optimise", action="store_true", help="enumeration only (equally spaced sensors)"
    )
    p.add_argument(
        "--fresh-builds",
        type=int_arg(2, 10**6),
        default=None,
        help="fresh builds for the out-of-sample check (32; quick 8)",
    )
    args = p.parse_args(argv)
    n_fresh = args.fresh_builds or (8 if args.quick else 32)
    poles = [5, 6] if args.quick else [4, 5, 6, 7, 8]
    sensors = [3] if args.quick else [2, 3, 4, 5]
    n_builds = 2 if args.quick else 6
    marks = 500 if args.quick else 2000
    n_phi = 16 if args.quick else 32
    tol = SDSTolerances()
    key = jax.random.key(args.seed)
    rec = CaseRecorder(args.out / "cases.jsonl")
    # every motor dense to the highest order of the largest pole count (zeros above a
    # motor's own orders): one shape for all, so the motor is an argument of one compiled
    # program per sensor count (residuals, optimiser), not a constant of one per combination
    max_order = 12 * max(poles)
    motors = {pp: sds_motor(pp, tol, max_order) for pp in poles}
    compiled = {}  # sensors -> residuals, compiled once for both stages and all pole counts
    objectives = {}  # sensors -> log residual (one compiled optimiser each)

    def residuals_of(c):
        ns, motor = c["n_sensors"], motors[c["pole_pairs"]]
        if ns not in compiled:
            compiled[ns] = jax.jit(_residuals(ns, tol, key, n_builds, marks, n_phi))
        return lambda y, fixed: compiled[ns](y, fixed, motor)

    def objective_of(c):
        ns = c["n_sensors"]
        if ns not in objectives:
            objectives[ns] = _log_residual(ns, tol, key, n_builds, marks, n_phi)
        return objectives[ns]

    def solve(c):
        # a strong float64 array, as in the second stage: one compilation serves both
        eq = jnp.asarray(np.asarray(equally_spaced(c["n_sensors"])))
        vals = np.asarray(residuals_of(c)(eq[1:], eq))
        ok = bool(np.all(np.isfinite(vals)))
        mean = float(np.mean(vals)) if ok else math.nan
        rec.record(
            dict(c),
            {
                "residual_mean_rad": mean,
                "residual_max_rad": float(np.max(vals)) if ok else math.nan,
            },
            SUCCESS if ok else NONFINITE,
            seed=args.seed,
        )
        return _Eval(mean, SUCCESS if ok else NONFINITE, tuple(float(v) for v in vals))

    res = enumerate_designs(solve, {"pole_pairs": poles, "n_sensors": sensors}, progress=True)
    rec.close()
    if not res.ok:
        print(f"[{NAME}] {res.message}", file=sys.stderr)
        return 1
    table = []
    for c, s in zip(res.choices, res.solutions):
        table.append(
            {
                **c,
                "status": s.status,
                "residual_mean_rad": s.objective,
                "residual_mean_arcsec": s.objective / ARCSEC,
                "residual_max_rad": max(s.values),
                "pole_multiple_of_sensors": c["pole_pairs"] % c["n_sensors"] == 0,
            }
        )
    ok_rows = [r for r in table if r["status"] == SUCCESS]
    best_val = min(r["residual_mean_rad"] for r in ok_rows)
    near = [r for r in ok_rows if r["residual_mean_rad"] <= best_val * 1.01]
    best = min(near, key=lambda r: (r["n_sensors"], r["residual_mean_rad"]))
    optimised, grad_check = [], None
    if not args.no_optimise:
        starts = args.starts or (2 if args.quick else 3)
        max_steps = args.max_steps or (40 if args.quick else 100)
        eq = {(r["pole_pairs"], r["n_sensors"]): r["residual_mean_rad"] for r in table}
        combos = [c for c in res.choices if c["n_sensors"] >= 2]
        for i, c in enumerate(combos):
            motor = motors[c["pole_pairs"]]
            row, (y, fixed) = _optimise_azimuths(
                c, residuals_of(c), objective_of(c), motor, starts, max_steps, args.seed
            )
            row["residual_mean_arcsec"] = row["residual_mean_rad"] / ARCSEC
            row["residual_equal_spacing_rad"] = eq[(c["pole_pairs"], c["n_sensors"])]
            optimised.append(row)
            print(
                f"[{NAME}] optimised {i + 1}/{len(combos)}: {c['pole_pairs']} pole pairs x "
                f"{c['n_sensors']} sensors -> {row['residual_mean_arcsec']:.3g} arcsec "
                f"({row['status']}, start {row['residual_start_rad'] / ARCSEC:.3g}, equal "
                f"spacing {row['residual_equal_spacing_rad'] / ARCSEC:.3g}; gaps "
                f"{[round(g, 2) for g in row['moving_gaps_deg']]} deg)",
                file=sys.stderr,
            )
            if grad_check is None:  # one combination: AD against central differences
                grad_check = {
                    **c,
                    **_gradient_check(
                        objective_of(c), motor, residuals_of(c), np.asarray(y), fixed
                    ),
                }
    rule, best_opt = {}, None
    good = [r for r in optimised if math.isfinite(r["residual_mean_rad"])]
    for ns in sorted({r["n_sensors"] for r in good}):
        of_ns = [r for r in good if r["n_sensors"] == ns]
        m = [r["residual_mean_rad"] for r in of_ns if r["pole_multiple_of_sensors"]]
        nm = [r["residual_mean_rad"] for r in of_ns if not r["pole_multiple_of_sensors"]]
        rule[str(ns)] = {
            "worst_not_multiple_rad": max(nm) if nm else None,
            "best_multiple_rad": min(m) if m else None,
            "ratio_best_multiple_to_worst_not_multiple": min(m) / max(nm) if m and nm else None,
            "holds": bool(m and nm and min(m) > max(nm)),
        }
    if good:
        bv = min(r["residual_mean_rad"] for r in good)
        best_opt = min(
            (r for r in good if r["residual_mean_rad"] <= 1.01 * bv),
            key=lambda r: (r["n_sensors"], r["residual_mean_rad"]),
        )
    fresh_check = None
    if best_opt is not None:
        motor = motors[best_opt["pole_pairs"]]
        fresh_check = _fresh_check(best_opt, motor, tol, key, n_fresh, marks, n_phi)
        print(f"[{NAME}] {fresh_check['summary']}", file=sys.stderr)
    mult = [r["residual_mean_rad"] for r in ok_rows if r["pole_multiple_of_sensors"]]
    nonmult = [r["residual_mean_rad"] for r in ok_rows if not r["pole_multiple_of_sensors"]]
    figures = []
    if not args.no_plots:
        panels = [("equally spaced sensors", table)]
        if optimised:
            panels.append(("optimised moving azimuths", optimised))
        fig, axes = new_figure(1, len(panels), figsize=(6 * len(panels), 4), squeeze=False)
        for ax, (title, rows) in zip(axes[0], panels):
            val = {(r["pole_pairs"], r["n_sensors"]): r["residual_mean_rad"] / ARCSEC
                   for r in rows}  # fmt: skip
            grid = np.array([[val.get((pp, ns), np.nan) for ns in sensors] for pp in poles])
            im = ax.imshow(np.log10(grid), origin="lower", aspect="auto")
            for (i, pp), (j, ns) in itertools.product(enumerate(poles), enumerate(sensors)):
                if pp % ns == 0:
                    ax.text(j, i, "x", ha="center", va="center", color="w")
            ax.set_xticks(range(len(sensors)), [str(s) for s in sensors])
            ax.set_yticks(range(len(poles)), [str(q) for q in poles])
            ax.set_xlabel("sensors per disk")
            ax.set_ylabel("motor pole pairs")
            fig.colorbar(im, ax=ax, label="log10 mean residual (arcsec)")
            ax.set_title(f"SDS residual: {title} (x: poles multiple of sensors)", fontsize=9)
        figures.append(save_figure(fig, args.out, "pole_sensor_opt.png"))
    summary = {
        "study": NAME,
        "seed": args.seed,
        "quick": args.quick,
        "tolerances": {f.name: getattr(tol, f.name) for f in dataclasses.fields(tol)},
        "marks_per_rev": marks,
        "n_builds": n_builds,
        "n_phi": n_phi,
        "table": table,
        "best": best,
        "median_residual_pole_multiple_rad": float(np.median(mult)) if mult else None,
        "median_residual_not_multiple_rad": float(np.median(nonmult)) if nonmult else None,
        "cases_file": str(rec.path),
        "optimised": optimised,
        "rule_from_optimiser": rule,
        "best_optimised": best_opt,
        "gradient_check": grad_check,
        "fresh_builds": n_fresh,
        "fresh_check": fresh_check,
        "win_significant": None if fresh_check is None else fresh_check["win_significant"],
    }
    print(
        f"[{NAME}] best: {best['pole_pairs']} pole pairs x {best['n_sensors']} sensors -> "
        f"{best['residual_mean_arcsec']:.3g} arcsec",
        file=sys.stderr,
    )
    if best_opt is not None:
        print(
            f"[{NAME}] optimiser's best: {best_opt['pole_pairs']} pole pairs x "
            f"{best_opt['n_sensors']} sensors -> {best_opt['residual_mean_arcsec']:.3g} arcsec; "
            f"rule (poles not a multiple of sensors) from the optimiser: "
            f"{ {k: v['holds'] for k, v in rule.items()} }",
            file=sys.stderr,
        )
    write_results(args, NAME, summary, figures)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
