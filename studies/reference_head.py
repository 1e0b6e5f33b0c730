"""Where to put the reference head: cotangent noise amplification for 2+1, 3+1 and 4+1.

Self-compensation (seed 000, section III) recovers the error modes the symmetric average
cannot remove from the differences between each head and an asymmetric reference head.
The cotangent equations divide by ``sin(j h / 2)`` (``h`` = head offset, ``j`` = order),
so some reference angles make the encoder map hypersensitive to read noise (seed III.D).
For each layout this study

* sweeps the reference-head angle over one sector ``(0, 360/N)`` deg and evaluates the
  per-order amplification ``A_j`` and its aggregate over the degenerate orders
  ``N, 2N, … <= M`` (:func:`encdesign.cotangent_sensitivity`);
* refines the best grid angle by zooming in, checks that the exact derivative (the
  sensitivity is differentiable in the reference angle) vanishes there, and lists the
  angles where it blows up;
* checks the prediction by Monte Carlo: pure white read noise through
  :func:`encdesign.self_compensate` at the best angle and at a poor one.

Outputs (``--out``): ``reference-head.json``, ``sensitivity_vs_reference_angle.png`` and
``montecarlo_check.png``.
"""

from __future__ import annotations

import functools
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

from encdesign.io import int_arg, new_figure, save_figure, study_parser, write_results
from encdesign.physics import cotangent_sensitivity, self_compensate

NAME = "reference-head"
LAYOUTS = {"2+1": 2, "3+1": 3, "4+1": 4}
POOR_OFFSET_DEG = 1.0  # the "poor" Monte Carlo angle: this far from a blind angle


def _log(msg: str) -> None:
    print(f"[reference-head] {msg}", file=sys.stderr, flush=True)


def _sym_angles(n: int) -> np.ndarray:
    return np.arange(n) * (2 * np.pi / n)


def _blind_angles_deg(n: int, max_order: int) -> list[float]:
    """Reference angles in ``(0, 360/N)`` deg where some pair is blind to a degenerate
    order ``j``: ``j (alpha_ref - alpha_k) = 0 mod 360``."""
    sector = 360.0 / n
    out = set()
    for j in range(n, max_order + 1, n):
        for k in range(1, j * n):
            a = 360.0 * k / j
            if 0 < a < sector - 1e-9:
                out.add(round(a, 9))
    return sorted(out)


def _refine(sweep, x0: float, half_width: float, n: int) -> float:
    """Zoom in on the minimum of the (jitted, vectorised) aggregate around ``x0`` (rad):
    four passes of ``n`` points over ``x0 +- half_width``, shrinking by ``n / 4`` each time;
    reuses the compiled sweep, so no recompilation."""
    x = x0
    for _ in range(4):
        grid = np.linspace(x - half_width, x + half_width, n)
        vals = np.asarray(sweep(jnp.asarray(grid))[1])
        x = float(grid[int(np.nanargmin(np.where(np.isfinite(vals), vals, np.inf)))])
        half_width *= 4.0 / n
    return x


@functools.partial(jax.jit, static_argnums=(1, 3, 4, 5))
def _mc_std(key, n_sym, ref_rad, max_order, n_samples, n_trials, sigma):
    angles = jnp.concatenate([jnp.asarray(_sym_angles(n_sym)), jnp.reshape(ref_rad, (1,))])
    theta = jnp.arange(n_samples) * (2 * jnp.pi / n_samples)

    def one(k):
        noise = sigma * jax.random.normal(k, (n_samples, n_sym + 1))
        sc = self_compensate(theta, noise, angles, n_sym, max_order)
        return sc.sin_rad, sc.cos_rad

    s, c = jax.vmap(one)(jax.random.split(key, n_trials))
    return jnp.sqrt(0.5 * (jnp.var(s, axis=0) + jnp.var(c, axis=0)))


def _monte_carlo(key, n_sym, ref_rad, max_order, n_samples, n_trials, sigma):
    """Std of recovered coefficients over trials of pure white read noise, in units of
    the single-head Fourier-coefficient noise ``sigma * sqrt(2 / n)``. Returns ``(M,)``."""
    std = _mc_std(key, n_sym, ref_rad, max_order, n_samples, n_trials, sigma)
    return np.asarray(std) / (sigma * np.sqrt(2.0 / n_samples))


def main(argv: list[str] | None = None) -> int:
    """Run the study; returns 0."""
    p = study_parser(NAME, __doc__)
    p.add_argument(
        "--max-order", type=int_arg(1, 1000), default=12, help="highest order M of the map"
    )
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    max_order = args.max_order
    n_grid = 361 if args.quick else 7201
    n_trials = 100 if args.quick else 2000
    n_samples = 64 if args.quick else 512
    key = jax.random.key(args.seed)

    results = {}
    curves = {}
    for name, n in LAYOUTS.items():
        _log(f"layout {name}: sweeping {n_grid} reference angles")
        sym = jnp.asarray(_sym_angles(n))
        sector = 360.0 / n
        grid_deg = np.linspace(0, sector, n_grid)[1:-1]

        def agg(ref_rad, sym=sym):
            return cotangent_sensitivity(ref_rad, sym, max_order)[1]

        sweep = jax.jit(jax.vmap(lambda r, sym=sym: cotangent_sensitivity(r, sym, max_order)))
        per_mode, aggregate = sweep(jnp.deg2rad(grid_deg))
        aggregate = np.asarray(aggregate)
        per_mode = np.asarray(per_mode)
        i0 = int(np.nanargmin(np.where(np.isfinite(aggregate), aggregate, np.inf)))
        step_rad = float(np.deg2rad(grid_deg[1] - grid_deg[0]))
        best_rad = _refine(sweep, float(np.deg2rad(grid_deg[i0])), 2 * step_rad, n_grid)
        best_deg = float(np.rad2deg(best_rad))
        if best_deg > sector / 2:  # report the lower of the mirror pair
            best_deg = sector - best_deg
            best_rad = float(np.deg2rad(best_deg))
        best_val = float(agg(best_rad))
        grad_at_best = float(jax.grad(agg)(best_rad))
        mirror_deg = sector - best_deg
        blind = _blind_angles_deg(n, max_order)
        poor_deg = float(blind[0] + POOR_OFFSET_DEG) if blind else sector / 2
        degenerate = list(range(n, max_order + 1, n))

        _log(f"layout {name}: Monte Carlo check, {n_trials} trials")
        mc = {}
        for label, ang in (("best", best_deg), ("poor", poor_deg)):
            key, sub = jax.random.split(key)
            meas = _monte_carlo(sub, n, np.deg2rad(ang), max_order, n_samples, n_trials, 1e-6)
            pred = np.asarray(cotangent_sensitivity(np.deg2rad(ang), sym, max_order)[0])
            mc[label] = {
                "reference_angle_deg": ang,
                "orders": degenerate,
                "predicted": pred[np.asarray(degenerate) - 1],
                "monte_carlo": meas[np.asarray(degenerate) - 1],
                "aggregate": float(agg(np.deg2rad(ang))),
            }
        ratio = np.concatenate([mc[k]["monte_carlo"] / mc[k]["predicted"] for k in mc])
        results[name] = {
            "symmetric_heads_deg": list(np.rad2deg(_sym_angles(n))),
            "degenerate_orders": degenerate,
            "best_reference_angle_deg": best_deg,
            "best_reference_angle_mirror_deg": mirror_deg,
            "best_aggregate_amplification": best_val,
            "best_per_order_amplification": np.asarray(
                cotangent_sensitivity(best_rad, sym, max_order)[0]
            )[np.asarray(degenerate) - 1],
            "gradient_at_best_per_rad": grad_at_best,
            "grid_best_deg": float(grid_deg[i0]),
            "blind_angles_deg": blind,
            "aggregate_at_grid_median": float(np.median(aggregate)),
            "monte_carlo": mc,
            "monte_carlo_over_predicted_min": float(ratio.min()),
            "monte_carlo_over_predicted_max": float(ratio.max()),
        }
        curves[name] = (grid_deg, aggregate, per_mode, degenerate, best_deg, mirror_deg, blind, mc)

    summary = {
        "study": NAME,
        "max_order": max_order,
        "noise_model": "independent white read noise on every head; amplification = std of a "
        "recovered coefficient / std of the same Fourier coefficient of one head's noise",
        "grid_points": n_grid,
        "monte_carlo_trials": n_trials,
        "monte_carlo_samples_per_rev": n_samples,
        "layouts": results,
        "runtime_s": time.perf_counter() - t0,
    }
    figures = [] if args.no_plots else _plots(args.out, curves, max_order)
    write_results(args, NAME, summary, figures)
    return 0


def _plots(out, curves, max_order):
    fig, axes = new_figure(len(curves), 1, figsize=(10, 3.4 * len(curves)))
    for ax, (name, c) in zip(np.atleast_1d(axes), curves.items()):
        grid_deg, aggregate, per_mode, degenerate, best, mirror, blind, _ = c
        for i, j in enumerate(degenerate):
            ax.plot(
                grid_deg,
                per_mode[:, j - 1],
                lw=0.8,
                alpha=0.55,
                color=f"C{i + 1}",
                label=f"order {j}",
            )
        ax.plot(grid_deg, aggregate, color="k", lw=2, label="aggregate (RMS)")
        for b in blind:
            ax.axvline(b, color="0.75", lw=0.8, ls=":")
        best_val = float(np.interp(best, grid_deg, aggregate))
        for x in (best, mirror):
            ax.axvline(x, color="C3", lw=1.2, ls="--")
            ax.plot([x], [best_val], "v", color="C3", ms=10)
        ax.annotate(
            f"best {best:.2f}° / {mirror:.2f}°\nA = {best_val:.3f}",
            xy=(best, best_val),
            xytext=(8, 25),
            textcoords="offset points",
            color="C3",
            fontsize=9,
            bbox={"boxstyle": "round", "fc": "white", "ec": "C3", "alpha": 0.9},
        )
        ax.set_yscale("log")
        ax.set_ylim(0.3, 1e3)
        ax.set_xlim(0, grid_deg[-1] + grid_deg[0])
        ax.set_ylabel("noise amplification")
        ax.set_title(
            f"{name}: symmetric heads every {360 / int(name[0]):.0f}°, "
            f"map orders {', '.join(map(str, degenerate))} (dotted: blind angles)"
        )
        ax.grid(alpha=0.3, which="both", axis="y")
        ax.legend(fontsize=7, ncol=4, loc="upper center")
    np.atleast_1d(axes)[-1].set_xlabel("reference-head azimuth (deg from head 0)")
    f1 = save_figure(fig, out, "sensitivity_vs_reference_angle.png")

    fig, axes = new_figure(1, len(curves), figsize=(11, 3.6))
    for ax, (name, c) in zip(np.atleast_1d(axes), curves.items()):
        mc = c[-1]
        for k, (label, d) in enumerate(mc.items()):
            x = np.asarray(d["orders"]) + (k - 0.5) * 0.6
            ax.plot(
                x,
                d["predicted"],
                "o",
                mfc="none",
                ms=9,
                color=f"C{3 * k}",
                label=f"{label} ({d['reference_angle_deg']:.1f}°): predicted",
            )
            ax.plot(
                x, d["monte_carlo"], "x", ms=8, color=f"C{3 * k}", label=f"{label}: Monte Carlo"
            )
        ax.set_yscale("log")
        ax.set_xticks(mc["best"]["orders"])
        ax.set_xlabel("order j")
        ax.set_title(name)
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=6.5)
    np.atleast_1d(axes)[0].set_ylabel("coefficient noise / head noise")
    f2 = save_figure(fig, out, "montecarlo_check.png")
    return [f1, f2]


if __name__ == "__main__":
    jax.config.update("jax_enable_x64", True)
    sys.exit(main())
