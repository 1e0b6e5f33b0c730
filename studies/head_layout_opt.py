"""Free head placement: optimise the azimuths of 3, 4 and 5 heads under a placement tolerance.

Each layout reads the same disk; self-compensation recovers the disk's error function from
all head differences by least squares per order
(:func:`encdesign.physics.least_squares_compensate`, Cramer's cotangent equations being the
``N + 1`` special case) and the output is the average of all heads corrected by its map.
Objective: the RMS residual over Monte Carlo builds, ``sqrt(mean_builds(ms))`` with ``ms``
the build's mean-square residual plus the expected calibration-noise term
(:func:`encdesign.objectives.layout_metrics`, metric ``"ms"``), with every head misplaced by
``N(0, sigma_placement**2)`` (the builder knows only the nominal azimuths) and the other
tolerances of ``tolerance-budget``'s reference (eccentricity, tilt, grating, beam tilt, axial
runout, read noise). Common random numbers make it a smooth function of the azimuths.

For ``H`` heads the study compares

* **the best symmetric N + 1 layout** (``N = H - 1`` equally spaced heads plus a reference
  head, as in ``reference-head-opt``): the reference angle on a grid over ``(0, 180/N)`` deg,
  polished by bounded BFGS, scored by the same objective; also the reference angle that
  ``reference-head-opt`` picks (least expected cotangent sensitivity on the same grid);
* **the free optimum**: head 0 fixed at 0 (a common rotation changes nothing), the others
  boxed into ``(0, 360)`` deg through a sigmoid, BFGS from the best symmetric layout and from
  ``--starts`` random layouts; the best is kept, so it is never worse than the symmetric one.

Against overfitting (a sample-average optimum over a few fixed builds looks better on those
builds than on any others):

* every free start is trained on its **own** builds (``fold_in(key, 100 + s)``), and the
  candidates are ranked on the study's builds of ``key``, on which none of them was trained
  (the symmetric layout was, which favours it);
* ``--min-separation-deg`` (default 5°) keeps every pair of heads apart and
  ``--max-noise-ratio`` (default off) bounds the noise amplification relative to the best
  symmetric layout's; both enter the free solve as penalties and are checked on the answer;
* the chosen optimum **and** the best symmetric layout are evaluated on ``--fresh-builds``
  fresh builds (an independent key, :func:`encdesign.design.fresh_key`; the same builds for
  both), and a free layout *wins* only when the paired difference of the fresh RMS residuals
  exceeds two standard errors (:func:`encdesign.design.paired_comparison`).

The gradient of the objective at the optimum is checked against central finite differences.
JSON ``head_counts``: per ``H``, ``optimum`` and ``best_symmetric`` (and
``reference_head_opt``) with ``head_angles_deg``, ``residual_urad`` (on the study's builds),
``residual_urad_fresh`` and ``residual_urad_fresh_stderr``, ``residual_p99_urad``,
``noise_amplification`` (aggregate, :func:`encdesign.physics.layout_noise_amplification`),
``noise_amplification_per_order``, ``min_separation_deg`` and ``unobservable_orders``;
``improvement`` (symmetric / optimum residual on the study's builds), ``improvement_fresh``,
``fresh`` (the paired comparison), ``win_significant``, ``verdict``, ``free_wins`` (=
``win_significant``) and ``gradient_check``. Figure ``head_layout_opt.png``.
"""

from __future__ import annotations

import math
import sys
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from encdesign.design import BFGS, CaseRecorder, fresh_key, optimise, paired_comparison
from encdesign.io import int_arg, new_figure, progress_bar, save_figure, study_parser, write_results
from encdesign.objectives import (
    LayoutDesign,
    Tolerances,
    expected_sensitivity,
    layout_metrics,
    symmetric_angles,
)
from encdesign.physics import layout_noise_amplification, unobservable_orders

NAME = "head-layout-opt"
HEAD_COUNTS = (3, 4, 5)
REFERENCE_TOL = dict(
    eccentricity=5e-6, tilt=1e-3, grating=5e-6, beam_tilt=1e-3, axial_runout=2e-6, noise=2e-7
)


def _design(angles: Any, args: Any) -> LayoutDesign:
    return LayoutDesign(
        radius_m=0.0254,
        head_angles_rad=angles,
        tilt_rad=6e-3,
        max_order=args.max_order,
        grating_orders=args.max_order,
        axial_orders=2,
        n_angles=args.n_angles,
    )


def _min_separation(angles: Any) -> jax.Array:
    """Smallest azimuth difference between two heads, modulo 2 pi (rad)."""
    a = jnp.asarray(angles)
    d = a[:, None] - a[None, :]
    d = jnp.abs(jnp.arctan2(jnp.sin(d), jnp.cos(d)))
    return jnp.min(jnp.where(jnp.eye(a.size, dtype=bool), jnp.inf, d))


def _noise(angles: Any, max_order: int) -> jax.Array:
    """Aggregate noise amplification (large but finite where an order is unobservable)."""
    agg = layout_noise_amplification(angles, max_order)[2]
    return jnp.where(jnp.isfinite(agg), agg, 1e6)


def _describe(angles: np.ndarray, f_rms, f_p99, args: Any) -> dict[str, Any]:
    amp, _, agg = layout_noise_amplification(jnp.asarray(angles), args.max_order)
    return {
        "head_angles_deg": [float(a) for a in np.degrees(np.mod(angles, 2 * np.pi))],
        "min_separation_deg": math.degrees(float(_min_separation(jnp.asarray(angles)))),
        "residual_urad": float(f_rms(jnp.asarray(angles))) * 1e6,
        "residual_p99_urad": float(f_p99(jnp.asarray(angles))) * 1e6,
        "noise_amplification": float(agg) if math.isfinite(float(agg)) else None,
        "noise_amplification_per_order": [
            (float(a) if math.isfinite(float(a)) else None) for a in np.asarray(amp)
        ],
        "unobservable_orders": unobservable_orders(angles, args.max_order),
    }


def _gradient_check(f, angles: np.ndarray, step_rad: float = 1e-4) -> dict[str, Any]:
    """AD gradient of ``f`` (rad residual per rad azimuth) against central differences for
    every head but the fixed head 0, at the optimum moved by ``1.7 k`` deg (at the optimum
    itself the gradient vanishes and a relative comparison only sees round-off; its norm is
    reported as ``gradient_norm_at_optimum``)."""
    at = angles + np.radians(1.7 * np.arange(angles.size))
    g = np.asarray(jax.grad(f)(jnp.asarray(at)))
    g_opt = np.asarray(jax.grad(f)(jnp.asarray(angles)))
    rows, worst = [], 0.0
    for k in range(1, angles.size):
        e = np.zeros_like(angles)
        e[k] = step_rad
        fd = (float(f(jnp.asarray(at + e))) - float(f(jnp.asarray(at - e)))) / (2 * step_rad)
        err = abs(g[k] - fd) / max(abs(g[k]), abs(fd), 1e-300)
        worst = max(worst, err)
        rows.append({"head": k, "ad": float(g[k]), "fd": fd, "rel_error": err})
    return {
        "at_deg": [float(a) for a in np.degrees(at)],
        "step_rad": step_rad,
        "rows": rows,
        "max_rel_error": worst,
        "ok": worst < 1e-4,
        "gradient_norm_at_optimum": float(np.linalg.norm(g_opt[1:])),
    }


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--sigma-placement-rad", type=float, default=1e-4, help="placement std, rad")
    p.add_argument(
        "--max-order", type=int_arg(1, 1000), default=None, help="orders 1…M (16; quick 4)"
    )
    p.add_argument("--n-angles", type=int, default=None, help="samples/rev (128; quick 32)")
    p.add_argument("--builds", type=int, default=None, help="Monte Carlo builds (64; quick 4)")
    p.add_argument("--starts", type=int, default=None, help="random free starts (4; quick 1)")
    p.add_argument("--max-steps", type=int, default=None, help="BFGS steps (150; quick 25)")
    p.add_argument(
        "--heads", type=int, nargs="+", default=list(HEAD_COUNTS), help="head counts (3 4 5)"
    )
    p.add_argument(
        "--fresh-builds",
        type=int,
        default=None,
        help="fresh builds for the out-of-sample check of optimum and symmetric (2000; quick 400)",
    )
    p.add_argument(
        "--min-separation-deg",
        type=float,
        default=5.0,
        help="least azimuth between two heads of a free layout, deg (5; 0: none)",
    )
    p.add_argument(
        "--max-noise-ratio",
        type=float,
        default=None,
        help="bound on a free layout's noise amplification relative to the best symmetric "
        "layout's (default: none)",
    )
    args = p.parse_args(argv)
    from encdesign import EncdesignInputError

    def input_error(where, problem, expected):
        return EncdesignInputError(f"{where}: {problem} (expected {expected})")

    n_fresh = args.fresh_builds or (400 if args.quick else 2000)
    if n_fresh < 2:
        raise input_error("--fresh-builds", f"{n_fresh}", "an integer >= 2")
    if not 0.0 <= args.min_separation_deg < 120.0:
        raise input_error("--min-separation-deg", f"{args.min_separation_deg}", "0 <= deg < 120")
    if args.max_noise_ratio is not None and not args.max_noise_ratio > 0:
        raise input_error("--max-noise-ratio", f"{args.max_noise_ratio}", "a ratio > 0")
    min_sep = math.radians(args.min_separation_deg)
    n_builds = args.builds or (4 if args.quick else 64)
    n_starts = args.starts if args.starts is not None else (1 if args.quick else 4)
    max_steps = args.max_steps or (15 if args.quick else 150)
    args.max_order = args.max_order or (4 if args.quick else 16)
    args.n_angles = args.n_angles or (32 if args.quick else 128)
    grid_step_deg = 5.0 if args.quick else 0.25
    key = jax.random.key(args.seed)
    tol = Tolerances(placement=args.sigma_placement_rad, **REFERENCE_TOL)

    def f_ms(angles, k=key, n=n_builds):
        return layout_metrics(_design(angles, args), tol, key=k, n_builds=n, metric="ms")

    # per-build mean squares, one compiled program per build count (the study's builds,
    # shared by the RMS and the 99th percentile; the fresh builds)
    ms_jit = jax.jit(f_ms, static_argnames="n")

    def f_rms(a):
        return jnp.sqrt(jnp.mean(ms_jit(a)))

    def f_p99(a):
        return jnp.percentile(jnp.sqrt(ms_jit(a)), 99.0)

    # per-build mean squares of the fresh builds (independent key, the same for all layouts)
    def fresh_rms(angles):
        ms = np.asarray(ms_jit(jnp.asarray(angles), fresh_key(key), n_fresh))
        return ms, math.sqrt(float(np.mean(ms)))

    rec = CaseRecorder(args.out / "cases.jsonl")
    results, figures = [], []
    fig, axes = new_figure(2, len(args.heads), figsize=(4.5 * len(args.heads), 8))
    axes = np.asarray(axes).reshape(2, len(args.heads))
    for col, h in enumerate(args.heads):
        if h < 3:
            print(f"[{NAME}] head count {h} < 3 skipped (2+0 has no reference)", file=sys.stderr)
            continue
        n_sym = h - 1
        sym = np.asarray(symmetric_angles(n_sym))

        def sym_layout(ref, sym=sym):
            return jnp.concatenate([jnp.asarray(sym), jnp.atleast_1d(ref)])

        # --- best symmetric N+1: grid over the reference angle, then polish
        step = math.radians(grid_step_deg)
        grid = np.arange(step / 2, math.pi / n_sym, step)
        f_ref = jax.jit(jax.vmap(lambda r, sl=sym_layout: f_rms(sl(r))))
        gvals = np.concatenate(
            [np.asarray(f_ref(jnp.asarray(grid[i : i + 64]))) for i in range(0, grid.size, 64)]
        )
        fin = np.isfinite(gvals)
        gi = int(np.flatnonzero(fin)[np.argmin(gvals[fin])])
        lo, hi = max(grid[gi] - step, 1e-4), min(grid[gi] + step, math.pi / n_sym - 1e-4)

        def ref_obj(v, b, sl=sym_layout):
            return f_rms(sl(b[0] + (b[1] - b[0]) * jax.nn.sigmoid(v[0]))) * 1e6

        sol = optimise(
            ref_obj, BFGS(rtol=1e-8, atol=1e-12, max_steps=60), jnp.zeros(1), jnp.array([lo, hi])
        )
        r_best = float(lo + (hi - lo) * jax.nn.sigmoid(sol.value[0]))
        if not float(f_rms(sym_layout(r_best))) <= gvals[gi]:
            r_best = float(grid[gi])
        sym_best = np.asarray(sym_layout(r_best))
        # reference-head-opt's choice: least expected cotangent sensitivity on the same grid
        f_sens = jax.jit(
            jax.vmap(
                lambda r, n=n_sym: expected_sensitivity(
                    r, n, args.max_order, args.sigma_placement_rad, key=key, n_builds=n_builds
                )
            )
        )
        svals = np.asarray(f_sens(jnp.asarray(grid)))
        si = int(np.flatnonzero(np.isfinite(svals))[np.nanargmin(svals)])
        sym_rho = np.asarray(sym_layout(float(grid[si])))

        # --- free optimum: head 0 at 0, the others boxed in (0, 2 pi)
        def to_angles(v):
            return jnp.concatenate([jnp.zeros(1), 2 * jnp.pi * jax.nn.sigmoid(v)])

        noise_cap = (
            None
            if args.max_noise_ratio is None
            else args.max_noise_ratio * float(_noise(jnp.asarray(sym_best), args.max_order))
        )

        def free_obj(v, train_key, noise_cap=noise_cap):
            """RMS residual (urad) on the start's own builds plus the design penalties."""
            ang = to_angles(v)
            val = jnp.sqrt(jnp.mean(f_ms(ang, train_key))) * 1e6
            pen = 0.0
            if min_sep > 0:
                pen = pen + (jax.nn.relu(min_sep - _min_separation(ang)) / min_sep) ** 2
            if noise_cap is not None:
                pen = pen + (jax.nn.relu(_noise(ang, args.max_order) - noise_cap) / noise_cap) ** 2
            return val * (1.0 + 1e4 * pen)

        def feasible(ang, noise_cap=noise_cap) -> bool:
            ok = float(_min_separation(jnp.asarray(ang))) >= min_sep * (1 - 1e-6)
            if noise_cap is not None:
                ok = ok and float(_noise(jnp.asarray(ang), args.max_order)) <= noise_cap * (
                    1 + 1e-6
                )
            return ok

        def logit(a):
            x = np.clip(np.mod(a, 2 * np.pi) / (2 * np.pi), 1e-6, 1 - 1e-6)
            return np.log(x / (1 - x))

        starts = [("best_symmetric", logit(sym_best[1:]))]
        rk = np.random.default_rng(args.seed + 100 * h)
        for s in range(n_starts):
            starts.append((f"random_{s}", logit(np.sort(rk.uniform(0.2, 2 * np.pi - 0.2, h - 1)))))
        best = (np.asarray(sym_best), float(f_rms(jnp.asarray(sym_best))), "symmetric_kept")
        statuses: list[dict[str, Any]] = []
        with progress_bar(f"[{NAME}] {h} heads", len(starts), unit="start") as bar:
            for s_i, (label, v0) in enumerate(starts):
                # each start trains on its own builds (re-sampled between restarts); the
                # candidates are ranked on the study's builds, none of them trained on
                train_key = jax.random.fold_in(key, 100 + s_i)
                sol = optimise(
                    free_obj, BFGS(rtol=1e-8, atol=1e-10, max_steps=max_steps),
                    jnp.asarray(v0), train_key,
                )  # fmt: skip
                ang = np.asarray(to_angles(jnp.asarray(sol.value)))
                val = float(f_rms(jnp.asarray(ang)))
                status = sol.status
                if status in ("success", "max_steps_reached") and not feasible(ang):
                    status = "infeasible"
                statuses.append({"start": label, "status": status, "n_steps": sol.n_steps,
                                 "message": sol.message})  # fmt: skip
                rec.record(
                    {"n_heads": h, "start": label, "start_angles_rad": list(np.asarray(
                        to_angles(jnp.asarray(v0))).tolist())},
                    {"head_angles_rad": ang.tolist(), "residual_rad": val},
                    status,
                    seed=args.seed,
                )  # fmt: skip
                # a capped solve is a usable candidate (marked in "starts"), never "success"
                if status in ("success", "max_steps_reached") and math.isfinite(val):
                    if val < best[1]:
                        best = (ang, val, label)
                bar.update()
        opt_angles = best[0]
        entry = {
            "n_heads": h,
            "symmetric_layout": f"{n_sym}+1",
            "optimum": {**_describe(opt_angles, f_rms, f_p99, args), "from_start": best[2]},
            "best_symmetric": {
                **_describe(sym_best, f_rms, f_p99, args),
                "reference_angle_deg": math.degrees(r_best),
            },
            "reference_head_opt": {
                **_describe(sym_rho, f_rms, f_p99, args),
                "reference_angle_deg": math.degrees(float(grid[si])),
            },
            "grid_step_deg": grid_step_deg,
        }
        entry["improvement"] = (
            entry["best_symmetric"]["residual_urad"] / entry["optimum"]["residual_urad"]
        )
        entry["starts"] = statuses
        # out of sample: the same fresh builds for the optimum and the symmetric layout
        ms_opt, r_opt = fresh_rms(opt_angles)
        ms_sym, r_sym = fresh_rms(sym_best)
        same = best[2] == "symmetric_kept"
        if same:  # the free search kept the symmetric layout: nothing to compare
            cmp = None
        else:
            cmp = paired_comparison(ms_opt, ms_sym, reduce="rms")
        for which, ms, r in (("optimum", ms_opt, r_opt), ("best_symmetric", ms_sym, r_sym)):
            entry[which]["residual_urad_fresh"] = r * 1e6
            entry[which]["residual_urad_fresh_stderr"] = (
                float(np.std(ms, ddof=1)) / math.sqrt(ms.size) / (2.0 * r) * 1e6
            )
        entry["n_fresh_builds"] = n_fresh
        entry["fresh"] = None if cmp is None else cmp.as_dict()
        entry["improvement_fresh"] = r_sym / r_opt
        entry["win_significant"] = bool(cmp is not None and cmp.win_significant)
        entry["loss_significant"] = bool(cmp is not None and cmp.worse_significant)
        if cmp is None:
            entry["verdict"] = "the free search kept the symmetric layout"
        elif cmp.win_significant:
            entry["verdict"] = "free layout wins on fresh builds"
        elif cmp.worse_significant:
            entry["verdict"] = "free layout loses on fresh builds (in-sample win was overfit)"
        else:
            entry["verdict"] = "no significant difference on fresh builds"
        entry["free_wins"] = entry["win_significant"]
        entry["free_wins_in_sample"] = bool(entry["improvement"] > 1.0 + 1e-9)
        entry["no_worse_than_symmetric"] = bool(
            entry["optimum"]["residual_urad"]
            <= entry["best_symmetric"]["residual_urad"] * (1 + 1e-12)
        )
        entry["gradient_check"] = _gradient_check(f_rms, opt_angles)
        results.append(entry)
        print(
            f"[{NAME}] {h} heads: free {entry['optimum']['residual_urad']:.4f} urad at "
            f"{np.round(entry['optimum']['head_angles_deg'], 2).tolist()} deg; best {n_sym}+1 "
            f"{entry['best_symmetric']['residual_urad']:.4f} urad (ref "
            f"{math.degrees(r_best):.2f} deg); x{entry['improvement']:.3f} in sample; gradient "
            f"check max rel err {entry['gradient_check']['max_rel_error']:.2e}",
            file=sys.stderr,
        )
        print(
            f"[{NAME}] {h} heads on {n_fresh} fresh builds: free "
            f"{entry['optimum']['residual_urad_fresh']:.4f} +- "
            f"{entry['optimum']['residual_urad_fresh_stderr']:.2g} urad, {n_sym}+1 "
            f"{entry['best_symmetric']['residual_urad_fresh']:.4f} +- "
            f"{entry['best_symmetric']['residual_urad_fresh_stderr']:.2g} urad, x"
            f"{entry['improvement_fresh']:.3f}"
            + ("" if cmp is None else f", paired difference {cmp.difference * 1e6:.3g} +- "
               f"{cmp.difference_stderr * 1e6:.2g} urad")
            + f": {entry['verdict']}; noise amplification "
            f"{entry['optimum']['noise_amplification']} vs "
            f"{entry['best_symmetric']['noise_amplification']}",
            file=sys.stderr,
        )  # fmt: skip
        ax = axes[0, col]
        for ang, style, lab in (
            (opt_angles, "o-", "free optimum"),
            (sym_best, "s--", f"best {n_sym}+1"),
        ):
            ring = np.sort(np.mod(ang, 2 * np.pi))
            ring = np.r_[ring, ring[:1]]  # the heads in azimuth order, closed
            ax.plot(np.cos(ring), np.sin(ring), style, ms=8, label=lab, alpha=0.8)
        circle = np.linspace(0, 2 * np.pi, 200)
        ax.plot(np.cos(circle), np.sin(circle), "k-", lw=0.5)
        ax.set_aspect("equal")
        ax.set_xlim(-1.3, 1.3)
        ax.set_ylim(-1.3, 1.3)
        ax.set_title(f"{h} heads (placement {args.sigma_placement_rad:g} rad)")
        ax.legend(fontsize=8, loc="lower left")
        ax = axes[1, col]
        ax.semilogy(np.degrees(grid), gvals * 1e6, lw=0.8, label=f"{n_sym}+1 vs reference angle")
        ax.axhline(entry["optimum"]["residual_urad"], color="r", label="free optimum")
        ax.set_xlabel("reference angle (deg)")
        ax.set_ylabel("RMS residual over builds (urad)")
        ax.legend(fontsize=8)
    rec.close()
    if not results:
        print(f"[{NAME}] no head count >= 3", file=sys.stderr)
        return 1
    if not args.no_plots:
        figures.append(save_figure(fig, args.out, "head_layout_opt.png"))
    summary = {
        "study": NAME,
        "seed": args.seed,
        "quick": args.quick,
        "sigma_placement_rad": args.sigma_placement_rad,
        "tolerances": {**REFERENCE_TOL, "placement": args.sigma_placement_rad},
        "max_order": args.max_order,
        "n_angles": args.n_angles,
        "n_builds": n_builds,
        "n_fresh_builds": n_fresh,
        "fresh_key": "fold_in(fold_in(key(seed), FRESH_TAG), 0) (encdesign.design.fresh_key)",
        "min_separation_deg": args.min_separation_deg,
        "max_noise_ratio": args.max_noise_ratio,
        "significance": "paired difference of fresh RMS residuals > 2 standard errors",
        "head_counts": results,
        "wins_on_fresh_builds": {str(e["n_heads"]): e["verdict"] for e in results},
        "cases_file": str(rec.path),
        "all_no_worse": all(e["no_worse_than_symmetric"] for e in results),
        "all_gradients_ok": all(e["gradient_check"]["ok"] for e in results),
    }
    write_results(args, NAME, summary, figures)
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
