"""SDS residual error vs motor pole pairs (3…12) and sensors per disk (1…4).

Seed 001 (Mikkelson): the motor's speed error has orders set by its construction (pole
pairs p and multiples, commutation steps p·6 per turn, cogging lcm(2p, 3p), low orders from
coil mismatch); the marks have effective errors at orders 1, 2 (eccentricity, ellipticity)
and a decaying higher-order spectrum. An error of φ at order n needs the speed error and
the mark errors to share order n (eqs. 46–53), and with M equally spaced moving sensors the
orders that are not multiples of M cancel in the average. Hence the seed's rule: pick a
pole count that is not a multiple of the sensor count (5 pole pairs with 3 sensors).

For every pole-pair count the motor is the seed's family (3·p coils, six-step drive, the
same torque-ripple recipe, inertia corner order 4) and the disks are the same; M sensors
are equally spaced on each disk. The residual is the RMS over a full platform turn of the
φ error minus its mean (the instrument is zeroed at one position).
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

import encdesign as ed
from encdesign.io import new_figure, save_figure, study_parser, write_results
from encdesign.physics import ARCSEC

NAME = "sds-poles"
POLE_PAIRS = tuple(range(3, 13))
SENSORS = (1, 2, 3, 4)
MAX_ORDER = 48  # the reference disks carry mark-error orders 1…48


def main(argv: list[str] | None = None) -> int:
    p = study_parser(NAME, __doc__)
    p.add_argument("--marks", type=int, default=None, help="marks per revolution")
    args = p.parse_args(argv)
    n_marks = args.marks or (120 if args.quick else 1000)
    n_phi = 16 if args.quick else 64
    key = jax.random.PRNGKey(args.seed)
    phi = 2 * jnp.pi * jnp.arange(n_phi) / n_phi
    disk_key = jax.random.split(key)[0]
    base = ed.reference_design(1, 1, marks_per_rev=n_marks, key=disk_key)
    phi_error = jax.jit(ed.sds_phi_error)
    t0 = time.time()
    residual = np.zeros((len(POLE_PAIRS), len(SENSORS)))
    rows = []
    for i, pp in enumerate(POLE_PAIRS):
        motor = ed.physics.reference_motor(pp)
        dense = motor.as_dense(MAX_ORDER)  # same shapes for every p: one compile per M
        orders = [n for n in motor.orders if n <= MAX_ORDER]
        for j, m in enumerate(SENSORS):
            d = ed.SDSDesign(
                dense,
                base.disk_a,
                base.disk_b,
                ed.physics.equally_spaced(m),
                ed.physics.equally_spaced(m),
            )
            err = np.asarray(phi_error(d, phi))
            err_c = err - err.mean()
            res = float(np.sqrt(np.mean(err_c**2)))
            residual[i, j] = res
            spec = np.abs(np.fft.rfft(err_c)) * 2 / n_phi
            top = np.argsort(spec)[::-1][:3]
            rows.append(
                {
                    "pole_pairs": pp,
                    "sensors_per_disk": m,
                    "residual_rms_arcsec": res / ARCSEC,
                    "peak_to_peak_arcsec": float(np.ptp(err) / ARCSEC),
                    "dominant_orders": [int(n) for n in top],
                    "dominant_amplitudes_arcsec": [float(spec[n] / ARCSEC) for n in top],
                    "surviving_motor_orders": [n for n in orders if n % m == 0],
                    "cancelled_motor_orders": [n for n in orders if n % m != 0],
                }
            )
        print(
            f"[{NAME}] pole pairs {pp}: residual "
            + ", ".join(f'M={m}: {residual[i, j] / ARCSEC:.4g}"' for j, m in enumerate(SENSORS))
            + f" ({time.time() - t0:.0f} s)",
            file=sys.stderr,
            flush=True,
        )

    rule = {}
    for j, m in enumerate(SENSORS):
        if m == 1:
            continue
        multiple = [residual[i, j] for i, pp in enumerate(POLE_PAIRS) if pp % m == 0]
        other = [residual[i, j] for i, pp in enumerate(POLE_PAIRS) if pp % m != 0]
        rule[f"sensors_{m}"] = {
            "mean_residual_pole_multiple_arcsec": float(np.mean(multiple) / ARCSEC),
            "mean_residual_pole_not_multiple_arcsec": float(np.mean(other) / ARCSEC),
        }
    i5, i6, j3 = POLE_PAIRS.index(5), POLE_PAIRS.index(6), SENSORS.index(3)
    best = np.unravel_index(np.argmin(residual), residual.shape)
    summary = {
        "study": NAME,
        "marks_per_rev": n_marks,
        "platform_angles": n_phi,
        "max_motor_order": MAX_ORDER,
        "pole_pairs": list(POLE_PAIRS),
        "sensors_per_disk": list(SENSORS),
        "residual_rms_arcsec": (residual / ARCSEC).tolist(),
        "table": rows,
        "rule_pole_count_not_multiple_of_sensors": rule,
        "five_pole_pairs_three_sensors_arcsec": float(residual[i5, j3] / ARCSEC),
        "six_pole_pairs_three_sensors_arcsec": float(residual[i6, j3] / ARCSEC),
        "best": {
            "pole_pairs": POLE_PAIRS[best[0]],
            "sensors_per_disk": SENSORS[best[1]],
            "residual_rms_arcsec": float(residual[best] / ARCSEC),
        },
        "seconds": time.time() - t0,
    }
    figures = [] if args.no_plots else [_heatmap(args.out, residual)]
    write_results(args, NAME, summary, figures)
    return 0


def _heatmap(out, residual):
    from matplotlib.patches import Rectangle

    mas = residual / ARCSEC * 1000
    fig, ax = new_figure(figsize=(9, 4.2))
    logv = np.log10(mas.T)
    im = ax.imshow(logv, origin="lower", aspect="auto", cmap="viridis")
    lo, hi = float(logv.min()), float(logv.max())
    ax.set_xticks(range(len(POLE_PAIRS)))
    ax.set_xticklabels(POLE_PAIRS)
    ax.set_yticks(range(len(SENSORS)))
    ax.set_yticklabels(SENSORS)
    ax.set_xlabel("motor pole pairs p")
    ax.set_ylabel("sensors per disk M")
    ax.set_title("SDS residual over a platform turn (mas, RMS); boxed: p multiple of M")
    for i, pp in enumerate(POLE_PAIRS):
        for j, m in enumerate(SENSORS):
            v = mas[i, j]
            txt = f"{v:.3g}"
            light = (np.log10(v) - lo) > 0.6 * (hi - lo)
            ax.text(i, j, txt, ha="center", va="center", color="k" if light else "w", fontsize=7)
            if m > 1 and pp % m == 0:
                ax.add_patch(
                    Rectangle((i - 0.5, j - 0.5), 1, 1, fill=False, edgecolor="red", lw=1.5)
                )
    fig.colorbar(im, ax=ax, label="log10 residual (mas)")
    return save_figure(fig, out, "sds-poles-heatmap.png")


if __name__ == "__main__":
    raise SystemExit(main())
