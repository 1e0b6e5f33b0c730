"""Benchmark: head readings per second of the kinematic model, encdesign (JAX) vs NumPy.

A Monte Carlo batch of encoder builds (default 1,000 designs x 4 heads x 2,048 angles,
grating orders 1-8, with eccentricity, tilt, placement errors, beam tilts, axial motion
and non-synchronous runout all switched on) is evaluated by
:func:`encdesign.physics.head_errors_batch` (jit, chunked ``lax.map``) and by a plain NumPy
implementation of the same equations in this file (vectorised, chunked; the fastest of a
few chunk sizes is reported).
Both results are compared, then timed (best of ``--repeats``; JAX after a warm-up
compile).

    python benchmarks/kinematics.py --json results/bench-kinematics.json
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign  # noqa: F401  (float64 on)
from encdesign.physics._kinematics import EncoderModel, head_errors_batch, make_model


def make_population(key, n_designs: int, n_heads: int, n_orders: int) -> EncoderModel:
    """Random builds around a nominal design with ``n_heads`` equally spaced heads."""
    ks = jax.random.split(key, 9)
    nrm = jax.random.normal

    def one(k):
        kk = jax.random.split(k, 9)
        return make_model(
            0.0254,
            jnp.arange(n_heads) * (2 * jnp.pi / n_heads),
            eccentricity_m=5e-6 * nrm(kk[0], (2,)),
            tilt_rad=3e-3 * nrm(kk[1], (2,)),
            grating_sin_rad=1e-6 * nrm(kk[2], (n_orders,)),
            grating_cos_rad=1e-6 * nrm(kk[3], (n_orders,)),
            placement_error_rad=20e-6 * nrm(kk[4], (n_heads,)),
            beam_tilt_rad=1e-3 * nrm(kk[5], (n_heads,)),
            axial_cos_m=1e-6 * nrm(kk[6], (2,)),
            axial_sin_m=1e-6 * nrm(kk[7], (2,)),
            runout_amplitude_m=1e-6 * jnp.abs(nrm(kk[8], ())),
            runout_ratio=0.4,
            runout_phase_rad=0.3,
        )

    del ks
    return jax.vmap(one)(jax.random.split(key, n_designs))


# ----------------------------------------------------------------------------- NumPy


def numpy_head_errors(p: dict, theta: np.ndarray, time_s: np.ndarray | None, chunk: int):
    """The kinematic model in plain NumPy: ``p`` holds the batched parameters as arrays
    (leading axis = design). Returns errors ``(B, n, H)`` in rad."""
    b = p["radius"].shape[0]
    out = np.empty((b, theta.shape[0], p["angles"].shape[1]))
    for s in range(0, b, chunk):
        sl = slice(s, s + chunk)
        out[sl] = _np_chunk({k: v[sl] for k, v in p.items()}, theta, time_s)
    return out


def _np_chunk(p, theta, time_s):
    e = lambda x: x[:, None, None]  # (B,) -> (B, 1, 1)
    radius = e(p["radius"])
    tx, ty = np.tan(p["tilt"][:, 0]), np.tan(p["tilt"][:, 1])
    nn = np.sqrt(1 + tx * tx + ty * ty)
    n0x, n0y, n0z = e(tx / nn), e(ty / nn), e(1 / nn)
    ln = np.sqrt(1 - n0x * n0x)
    l0x, l0y, l0z = (1 - n0x * n0x) / ln, -n0x * n0y / ln, -n0x * n0z / ln
    c0x, c0y = e(p["ecc"][:, 0]), e(p["ecc"][:, 1])
    th = theta[None, :, None]
    ct, st = np.cos(th), np.sin(th)
    nx, ny, nz = ct * n0x - st * n0y, st * n0x + ct * n0y, n0z
    lx, ly, lz = ct * l0x - st * l0y, st * l0x + ct * l0y, l0z
    cx, cy = ct * c0x - st * c0y, st * c0x + ct * c0y
    phase = e(p["ratio"]) * th + e(p["rphase"])
    if time_s is not None:
        phase = phase + 2 * np.pi * e(p["rfreq"]) * time_s[None, :, None]
    cx = cx + e(p["runout"]) * np.cos(phase)
    cy = cy + e(p["runout"]) * np.sin(phase)
    k = p["ax_c"].shape[1]
    j = np.arange(1, k + 1)
    arg = theta[:, None] * j
    cz = (np.cos(arg) @ p["ax_c"].T + np.sin(arg) @ p["ax_s"].T).T[:, :, None]
    beta = p["angles"] + p["place"]
    cb, sb = np.cos(beta)[:, None, :], np.sin(beta)[:, None, :]
    tg = np.tan(p["beam"])[:, None, :]
    un = np.sqrt(1 + tg * tg)
    ux, uy, uz = -tg * sb / un, tg * cb / un, -1 / un
    rx, ry, rz = radius * cb, radius * sb, e(p["gap"])
    wx, wy, wz = cx - rx, cy - ry, cz - rz
    s = (wx * nx + wy * ny + wz * nz) / (ux * nx + uy * ny + uz * nz)
    vx, vy, vz = s * ux - wx, s * uy - wy, s * uz - wz
    crx, cry, crz = vy * lz - vz * ly, vz * lx - vx * lz, vx * ly - vy * lx
    sp = crx * nx + cry * ny + crz * nz
    cp = vx * lx + vy * ly + vz * lz
    rho = np.sqrt(sp * sp + cp * cp)
    s1, c1 = sp / rho, cp / rho
    ca, sa = np.cos(p["angles"])[:, None, :], np.sin(p["angles"])[:, None, :]
    cd, sd = ct * ca + st * sa, st * ca - ct * sa
    geom = np.arctan2(s1 * cd - c1 * sd, c1 * cd + s1 * sd)
    gs, gc = p["gs"], p["gc"]
    sj, cj = s1, c1
    g = e(gs[:, 0]) * sj + e(gc[:, 0]) * cj
    for i in range(1, gs.shape[1]):
        sj, cj = sj * c1 + cj * s1, cj * c1 - sj * s1
        g = g + e(gs[:, i]) * sj + e(gc[:, i]) * cj
    return geom + g


def numpy_params(m: EncoderModel) -> dict:
    d, h, mo = m.disk, m.heads, m.motion
    a = lambda x: np.asarray(x, dtype=np.float64)
    return {
        "radius": a(d.optical_radius_m),
        "ecc": a(d.eccentricity_m),
        "tilt": a(d.tilt_rad),
        "gs": a(d.grating_sin_rad),
        "gc": a(d.grating_cos_rad),
        "angles": a(h.angles_rad),
        "place": a(h.placement_error_rad),
        "beam": a(h.beam_tilt_rad),
        "gap": a(h.gap_m),
        "ax_c": a(mo.axial_cos_m),
        "ax_s": a(mo.axial_sin_m),
        "runout": a(mo.runout_amplitude_m),
        "ratio": a(mo.runout_ratio),
        "rphase": a(mo.runout_phase_rad),
        "rfreq": a(mo.runout_freq_hz),
    }


def _best_time(f, repeats: int) -> float:
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    p.add_argument("--designs", type=int, default=1000)
    p.add_argument("--heads", type=int, default=4)
    p.add_argument("--angles", type=int, default=2048)
    p.add_argument("--orders", type=int, default=8)
    p.add_argument(
        "--chunk", type=int, default=None, help="designs per chunk for JAX (default: auto)"
    )
    p.add_argument(
        "--numpy-chunks",
        type=str,
        default="4,100",
        help="NumPy chunk sizes to try; the fastest is reported",
    )
    p.add_argument("--repeats", type=int, default=5, help="timings per version (best kept)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)

    models = make_population(jax.random.key(args.seed), args.designs, args.heads, args.orders)
    theta = np.arange(args.angles) * (2 * np.pi / args.angles)
    t_s = theta / (2 * np.pi)  # one revolution per second
    n_readings = args.designs * args.heads * args.angles

    run_jax = jax.jit(lambda m, th, t: head_errors_batch(m, th, t, chunk=args.chunk))
    th_j, t_j = jnp.asarray(theta), jnp.asarray(t_s)
    print("compiling ...", file=sys.stderr, flush=True)
    e_jax = np.asarray(run_jax(models, th_j, t_j).block_until_ready())
    params = numpy_params(models)
    np_chunks = [int(c) for c in args.numpy_chunks.split(",")]
    e_np = numpy_head_errors(params, theta, t_s, np_chunks[0])
    max_diff = float(np.max(np.abs(e_jax - e_np)))
    print(f"max |jax - numpy| = {max_diff:.3e} rad", file=sys.stderr)

    print("timing encdesign (JAX) ...", file=sys.stderr, flush=True)
    t_jax = _best_time(lambda: run_jax(models, th_j, t_j).block_until_ready(), args.repeats)
    np_times = {}
    for c in np_chunks:
        print(f"timing NumPy, chunk {c} ...", file=sys.stderr, flush=True)
        np_times[c] = _best_time(lambda c=c: numpy_head_errors(params, theta, t_s, c), args.repeats)
    np_chunk = min(np_times, key=np_times.get)
    t_np = np_times[np_chunk]

    res = {
        "benchmark": "kinematics",
        "designs": args.designs,
        "heads": args.heads,
        "angles": args.angles,
        "grating_orders": args.orders,
        "chunk_designs": args.chunk or "auto (2**15 readings)",
        "numpy_chunk_designs": np_chunk,
        "numpy_seconds_by_chunk": {str(k): v for k, v in np_times.items()},
        "readings": n_readings,
        "seconds": t_jax,
        "numpy_seconds": t_np,
        "readings_per_s": n_readings / t_jax,
        "numpy_readings_per_s": n_readings / t_np,
        "speedup": t_np / t_jax,
        "max_abs_difference_rad": max_diff,
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "jax": jax.__version__,
            "numpy": np.__version__,
            "jax_device": str(jax.devices()[0]),
        },
    }
    if max_diff > 1e-12:
        print("error: JAX and NumPy disagree", file=sys.stderr)
        return 1
    text = json.dumps(res, indent=2)
    print(text)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        tmp = args.json.with_name(f".tmp-{args.json.name}")
        tmp.write_text(text + "\n")
        os.replace(tmp, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
