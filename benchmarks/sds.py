"""Benchmark of the SDS timing model: JAX against a plain NumPy implementation.

* edge times per second: 10,000 marks × 6 sensors (3 fixed + 3 moving) × 100 revolutions
  of the reference motor (17 ripple orders), Newton inversion of θ(t) in both;
* SDS readings per second: the measurement step (edge windows → φ per pair, pair average)
  for the same 100 revolutions, JAX (jit) against NumPy;
* peak RSS of a fresh process simulating 1,000 revolutions of readings (edges + SDS,
  chunked over revolutions) against one simulating 100: memory stays bounded.

Run: ``.venv/bin/python benchmarks/sds.py --json results/bench-sds.json``
"""

from __future__ import annotations

import argparse
import json
import platform
import resource
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign as ed
from encdesign.io._study import write_json
from encdesign.physics._sds import _revolution

N_MARKS = 10_000
N_REVS = 100


def _design():
    return ed.reference_design(3, 3, marks_per_rev=N_MARKS)


# ----------------------------------------------------------------------------- NumPy


def numpy_edge_times(design, phi: float, n_revs: int, n_newton: int = 2) -> np.ndarray:
    """The same physics as ``ed.edge_times`` (no error sources), in plain NumPy."""
    m = design.motor
    orders = np.asarray(m.orders, dtype=float)
    c, s = (np.asarray(x) for x in m.speed_ripple())
    w = float(m.speed_rad_s)
    drift = float(m.speed_drift_per_s)

    def theta_omega(t):
        th = w * (t + 0.5 * drift * t * t) + np.sum(s / orders)
        om = 1.0 + drift * t
        for n, cn, sn in zip(orders, c, s):
            x = n * w * t
            sx, cx = np.sin(x), np.cos(x)
            th += (cn * sx - sn * cx) / n
            om += cn * cx + sn * sx
        return th, w * om

    def mark_angles(disk):
        n = disk.marks_per_rev
        x = 2 * np.pi * np.arange(n) / n
        err = np.asarray(disk.random_rad).copy()
        for i, (a, b) in enumerate(
            zip(np.asarray(disk.harmonic_cos_rad), np.asarray(disk.harmonic_sin_rad))
        ):
            err += a * np.cos((i + 1) * x) + b * np.sin((i + 1) * x)
        return float(disk.index_angle_rad) + x + err

    mu_a, mu_b = mark_angles(design.disk_a), mark_angles(design.disk_b)
    psi = np.concatenate(
        [np.asarray(design.fixed_azimuths_rad), np.asarray(design.moving_azimuths_rad) + phi]
    )
    mus = [mu_a] * design.n_fixed + [mu_b] * design.n_moving
    out = np.empty((len(psi), n_revs, N_MARKS))
    revs = np.arange(n_revs)[:, None]
    for i, (p, mu) in enumerate(zip(psi, mus)):
        target = np.mod(p, 2 * np.pi) + mu[None, :] + 2 * np.pi * revs
        x = target / w
        t = 2 * x / (1 + np.sqrt(1 + 2 * drift * x))
        t = t - (theta_omega(t)[0] - target) / w
        for _ in range(n_newton + 1):
            th, om = theta_omega(t)
            t = t - (th - target) / om
        out[i] = t
    return out


def numpy_sds(alpha, period, k_f, tau, k_m, offsets):
    """Shifted delta sum per pair and pair average (seed eqs. 23–24), plain NumPy."""
    n = tau.shape[-1]
    t0 = alpha[:, :1, :1]
    diff = np.sum(tau - t0, axis=-1)[:, None, :] - np.sum(alpha - t0, axis=-1)[:, :, None]
    s = 2 * np.pi * diff / period[:, :, None]
    k = k_m[:, None, :] - k_f[:, :, None]
    phi = s / n + 2 * np.pi * k / n - offsets
    ref = phi[:, :1, :1]
    return ref[:, 0, 0] + np.mean(np.mod(phi - ref + np.pi, 2 * np.pi) - np.pi, axis=(1, 2))


# ----------------------------------------------------------------------------- helpers


def _best_of(fn, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _rss_child(n_revs: int) -> None:
    d = _design()
    f = jax.jit(lambda d: ed.simulate_readings(d, 0.7, n_revs).error_rad)
    t0 = time.perf_counter()
    err = np.asarray(f(d))
    dt = time.perf_counter() - t0
    rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(
        json.dumps(
            {
                "n_revs": n_revs,
                "peak_rss_mb": rss_mb,
                "seconds": dt,
                "max_abs_error_rad": float(np.max(np.abs(err))),
            }
        )
    )


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--skip-rss", action="store_true")
    p.add_argument("--rss-child", type=int, default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.rss_child is not None:
        _rss_child(args.rss_child)
        return 0

    d = _design()
    phi = 0.7
    n_edges = (d.n_fixed + d.n_moving) * N_REVS * N_MARKS
    jax_edges = jax.jit(lambda d: ed.edge_times(d, phi, N_REVS))
    jax.block_until_ready(jax_edges(d))
    t_jax = _best_of(lambda: jax.block_until_ready(jax_edges(d)), args.repeats)
    t_np = _best_of(lambda: numpy_edge_times(d, phi, N_REVS), args.repeats)
    f_j, m_j = (np.asarray(x) for x in jax_edges(d))
    e_np = numpy_edge_times(d, phi, N_REVS)
    dev_edges = float(np.max(np.abs(np.concatenate([f_j, m_j]) - e_np)))
    print(
        f"edge times: JAX {n_edges / t_jax:.3g}/s, NumPy {n_edges / t_np:.3g}/s, "
        f"ratio {t_np / t_jax:.2f}, max |Δt| {dev_edges:.2e} s",
        flush=True,
    )

    # SDS readings: windows of N_REVS revolutions (prepared once), then measurement only
    win = jax.jit(jax.vmap(lambda r: _revolution(d, ed.SDSErrors(), jnp.asarray(phi), r, None, 1)))
    alpha, period, k_f, tau, k_m = (np.asarray(x) for x in win(jnp.arange(N_REVS, dtype=float)))
    offsets = np.asarray(d.zero_offsets_rad())

    @jax.jit
    def jax_sds(alpha, period, k_f, tau, k_m):
        phis = ed.sds_from_edges(alpha, period, k_f, tau, k_m, offsets)
        ref = phis[:, :1, :1]
        return ref[:, 0, 0] + jnp.mean(jnp.mod(phis - ref + jnp.pi, 2 * jnp.pi) - jnp.pi, (1, 2))

    arrays = tuple(jnp.asarray(x) for x in (alpha, period, k_f, tau, k_m))
    jax.block_until_ready(jax_sds(*arrays))
    t_sds_jax = _best_of(lambda: jax.block_until_ready(jax_sds(*arrays)), args.repeats + 1)
    t_sds_np = _best_of(lambda: numpy_sds(alpha, period, k_f, tau, k_m, offsets), args.repeats + 1)
    dev_sds = float(
        np.max(
            np.abs(np.asarray(jax_sds(*arrays)) - numpy_sds(alpha, period, k_f, tau, k_m, offsets))
        )
    )
    print(
        f"SDS readings: JAX {N_REVS / t_sds_jax:.3g}/s, NumPy {N_REVS / t_sds_np:.3g}/s, "
        f"ratio {t_sds_np / t_sds_jax:.2f}, max |Δφ| {dev_sds:.2e} rad",
        flush=True,
    )

    # end to end (edges + SDS per revolution, chunked)
    sim = jax.jit(lambda d: ed.simulate_readings(d, phi, N_REVS).error_rad)
    jax.block_until_ready(sim(d))
    t_sim = _best_of(lambda: jax.block_until_ready(sim(d)), args.repeats)
    print(f"simulated readings end to end: {N_REVS / t_sim:.3g} revolutions/s", flush=True)

    rss = {}
    if not args.skip_rss:
        for n in (100, 1000):
            out = subprocess.run(
                [sys.executable, __file__, "--rss-child", str(n)],
                capture_output=True,
                text=True,
                check=True,
            )
            rss[n] = json.loads(out.stdout.strip().splitlines()[-1])
            print(
                f"{n} revolutions: peak RSS {rss[n]['peak_rss_mb']:.0f} MB, "
                f"{rss[n]['seconds']:.1f} s",
                flush=True,
            )

    summary = {
        "benchmark": "sds",
        "machine": platform.platform(),
        "jax_backend": jax.default_backend(),
        "marks_per_rev": N_MARKS,
        "sensors": d.n_fixed + d.n_moving,
        "revolutions": N_REVS,
        "motor_orders": len(d.motor.orders),
        "edge_times": {
            "n_edges": n_edges,
            "jax_per_s": n_edges / t_jax,
            "numpy_per_s": n_edges / t_np,
            "speedup_jax_over_numpy": t_np / t_jax,
            "max_abs_difference_s": dev_edges,
        },
        "sds_readings": {
            "n_readings": N_REVS,
            "pairs_per_reading": d.n_fixed * d.n_moving,
            "jax_per_s": N_REVS / t_sds_jax,
            "numpy_per_s": N_REVS / t_sds_np,
            "speedup_jax_over_numpy": t_sds_np / t_sds_jax,
            "max_abs_difference_rad": dev_sds,
        },
        "end_to_end_revolutions_per_s": N_REVS / t_sim,
        "peak_rss": {str(k): v for k, v in rss.items()},
        "note": "best of --repeats runs; the machine may be shared, timings are noisy",
    }
    if args.json is not None:
        write_json(args.json, summary)
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
