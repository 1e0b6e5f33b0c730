"""Benchmark: head readings per second of the kinematic model on 1 and all cores, vs NumPy.

A Monte Carlo batch of encoder builds (default 1,000 designs x 4 heads x 2,048 angles,
grating orders 1-8, with eccentricity, tilt, placement errors, beam tilts, axial motion
and non-synchronous runout all switched on) is evaluated by
:func:`encdesign.physics.head_errors_batch` and by a plain NumPy implementation of the same
equations in this file (vectorised, chunked; the fastest of a few chunk sizes is
reported). One run measures the scaling: each configuration is a subprocess of this
script, started with its own CPU affinity and XLA settings (they must be fixed before JAX
starts):

* ``1thread``: pinned to one core (``sched_setaffinity`` before Python starts), XLA's CPU
  thread pool off (``--xla_cpu_multi_thread_eigen=false``), one CPU device; run once per
  core (the cores of a virtual machine need not be equal), the fastest is reported and the
  others listed;
* ``xla-threads``: all cores, one CPU device: XLA's own threading only;
* ``devices``: all cores, encdesign's default (one CPU device per core, ``docs/scale.md``):
  the designs split over the devices;
* ``numpy``: the NumPy baseline, pinned to the fastest core (its agreement with encdesign
  is checked there).

For each JAX configuration: the forward pass (readings/s), value-and-gradient of the mean
squared head error with respect to every parameter of every design (time, and its ratio
to the forward pass of the same scalar), and, in a process of its own, the Monte Carlo
yield of ``--yield-builds`` builds through :func:`encdesign.design.monte_carlo` with its
default chunking (3+1 heads, ``--yield-angles`` angles, orders 1-16, the tolerances of
``benchmarks/optimize.py``): wall time and peak resident memory. Parallel efficiency =
rate(all cores) / (cores x rate(1thread)), and against the sum of the cores' one-core
rates. The machine's load average is recorded around every child: timings under load are
not the model's speed.

    python benchmarks/kinematics.py --json results/bench-kinematics.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign  # noqa: F401  (float64 on; CPU devices chosen before JAX starts)
from encdesign.physics._kinematics import EncoderModel, head_errors_batch, make_model

CONFIGS = ("1thread", "xla-threads", "devices")
ONE_THREAD = "--xla_cpu_multi_thread_eigen=false"


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


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def _inputs(args):
    models = make_population(jax.random.key(args.seed), args.designs, args.heads, args.orders)
    theta = np.arange(args.angles) * (2 * np.pi / args.angles)
    return models, theta, theta / (2 * np.pi)  # one revolution per second


# ----------------------------------------------------------------------------- children


def _child_kinematics(args) -> dict:
    """Forward pass and value-and-gradient in this process's configuration."""
    models, theta, t_s = _inputs(args)
    th_j, t_j = jnp.asarray(theta), jnp.asarray(t_s)
    n_readings = args.designs * args.heads * args.angles
    fwd = jax.jit(lambda m: head_errors_batch(m, th_j, t_j, chunk=args.chunk))
    loss = lambda m: jnp.mean(head_errors_batch(m, th_j, t_j, chunk=args.chunk) ** 2)
    f_loss = jax.jit(loss)
    f_vg = jax.jit(jax.value_and_grad(loss))
    t0 = time.perf_counter()
    jax.block_until_ready((fwd(models), f_loss(models), f_vg(models)))
    compile_s = time.perf_counter() - t0
    t_fwd = _best_time(lambda: fwd(models).block_until_ready(), args.repeats)
    t_loss = _best_time(lambda: f_loss(models).block_until_ready(), args.repeats)
    t_vg = _best_time(lambda: jax.block_until_ready(f_vg(models)), args.repeats)
    head = np.asarray(fwd(models)[: args.check_designs])
    return {
        "devices": jax.device_count(),
        "readings": n_readings,
        "forward_s": t_fwd,
        "readings_per_s": n_readings / t_fwd,
        "loss_s": t_loss,
        "value_and_grad_s": t_vg,
        "grad_over_forward": t_vg / t_loss,
        "compile_s": compile_s,
        "first_designs_errors": head.tolist(),
        "peak_rss_mb": _peak_rss_mb(),
    }


def _child_yield(args) -> dict:
    """Monte Carlo yield through the default driver (its own process: the peak memory is
    the yield's)."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from optimize import SPEC_RAD, design, tolerances

    from encdesign.design import monte_carlo
    from encdesign.objectives import Tolerances, n_build_normals, residual_rms

    d = design(args.yield_angles)
    tv = tolerances().vector()
    fn = lambda t, z: residual_rms(d, Tolerances.from_vector(t), z)
    kw = dict(key=jax.random.key(0), dim=n_build_normals(d))
    rss0 = _peak_rss_mb()
    t0 = time.perf_counter()
    monte_carlo(fn, tv, n=min(args.yield_builds, 4096), **kw)  # compiles the chunk
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = monte_carlo(fn, tv, n=args.yield_builds, **kw)
    wall = time.perf_counter() - t0
    y, se = res.yield_fraction(SPEC_RAD)
    return {
        "devices": jax.device_count(),
        "builds": args.yield_builds,
        "angles": args.yield_angles,
        "wall_s": wall,
        "builds_per_s": args.yield_builds / wall,
        "compile_and_warmup_s": compile_s,
        "yield": y,
        "yield_stderr": se,
        "mean_rms_rad": res.mean,
        "peak_rss_mb": _peak_rss_mb(),
        "peak_rss_before_mb": rss0,
    }


def _child_numpy(args) -> dict:
    """The NumPy baseline (fastest of ``--numpy-chunks``) and its agreement with encdesign."""
    models, theta, t_s = _inputs(args)
    params = numpy_params(models)
    k = args.check_designs
    e_jax = np.asarray(head_errors_batch(_first(models, k), theta, t_s))
    np_chunks = [int(c) for c in args.numpy_chunks.split(",")]
    e_np = numpy_head_errors({n: v[:k] for n, v in params.items()}, theta, t_s, np_chunks[0])
    times = {}
    for c in np_chunks:
        times[c] = _best_time(lambda c=c: numpy_head_errors(params, theta, t_s, c), args.repeats)
    best = min(times, key=times.get)
    n_readings = args.designs * args.heads * args.angles
    return {
        "numpy_chunk_designs": best,
        "numpy_seconds_by_chunk": {str(c): v for c, v in times.items()},
        "seconds": times[best],
        "readings_per_s": n_readings / times[best],
        "max_abs_difference_rad": float(np.max(np.abs(e_jax - e_np))),
    }


def _first(models: EncoderModel, k: int) -> EncoderModel:
    return jax.tree.map(lambda x: x[:k], models)


def _env(config: str) -> dict:
    env = {
        k: v
        for k, v in os.environ.items()
        if k not in ("XLA_FLAGS", "ENCDESIGN_CPU_DEVICES", "OMP_NUM_THREADS", "JAX_NUM_CPU_DEVICES")
    }
    if config in ("1thread", "numpy"):
        env["XLA_FLAGS"] = ONE_THREAD
        env["ENCDESIGN_CPU_DEVICES"] = "1"
        env["OMP_NUM_THREADS"] = "1"
    elif config == "xla-threads":
        env["ENCDESIGN_CPU_DEVICES"] = "1"
    return env  # "devices": encdesign's default


def _run_child(part: str, config: str, argv: list[str], tmp: Path, core: int = -1) -> dict:
    """One configuration in a subprocess; ``1thread`` and ``numpy`` pinned to ``core``
    (default: the lowest core this process may use)."""
    out = tmp / f"{part}-{config}-{core}.json"
    cmd = [sys.executable, str(Path(__file__).resolve()), *argv, "--child", part, str(out)]
    pin = config in ("1thread", "numpy")
    core = min(os.sched_getaffinity(0)) if core < 0 else core
    where = f" (core {core})" if pin else ""
    print(f"  {part} / {config}{where} ...", file=sys.stderr, flush=True)
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    subprocess.run(
        cmd,
        env=_env(config),
        check=True,
        preexec_fn=(lambda: os.sched_setaffinity(0, {core})) if pin else None,
    )
    res = json.loads(out.read_text())
    res["child_wall_s"] = time.perf_counter() - t0
    res["load_average_before"] = load0[0]
    res["load_average_after"] = os.getloadavg()[0]
    if pin:
        res["core"] = core
    return res


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
    p.add_argument("--yield-builds", type=int, default=1_000_000)
    p.add_argument("--yield-angles", type=int, default=256)
    p.add_argument("--skip-yield", action="store_true")
    p.add_argument("--configs", default=",".join(CONFIGS), help=f"subset of {','.join(CONFIGS)}")
    p.add_argument("--check-designs", type=int, default=16, help="designs compared")
    p.add_argument("--child", nargs=2, metavar=("PART", "OUT"), help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child is not None:
        part, out = args.child
        fn = {"kin": _child_kinematics, "yield": _child_yield, "numpy": _child_numpy}[part]
        Path(out).write_text(json.dumps(fn(args)))
        return 0
    configs = [c for c in args.configs.split(",") if c]
    bad = [c for c in configs if c not in CONFIGS]
    if bad:
        p.error(f"--configs: unknown {bad}, expected a subset of {','.join(CONFIGS)}")
    child_argv = list(sys.argv[1:] if argv is None else argv)
    drop = {"--json", "--configs"}
    clean, it = [], iter(child_argv)
    for a in it:
        if a in drop:
            next(it, None)
        elif not any(a.startswith(f"{d}=") for d in drop):
            clean.append(a)
    cores = len(os.sched_getaffinity(0))
    res: dict = {
        "benchmark": "kinematics",
        "designs": args.designs,
        "heads": args.heads,
        "angles": args.angles,
        "grating_orders": args.orders,
        "chunk_designs": args.chunk or "auto",
        "cores": cores,
        "machine": {
            "cpu_count": os.cpu_count(),
            "platform": platform.platform(),
            "jax": jax.__version__,
            "numpy": np.__version__,
        },
        "kinematics": {},
        "yield": {},
    }
    with tempfile.TemporaryDirectory() as tmp:
        best_core = min(os.sched_getaffinity(0))
        for c in configs:
            if c != "1thread":
                res["kinematics"][c] = _run_child("kin", c, clean, Path(tmp))
                continue
            # the cores of a virtual machine need not be equal (one may carry the host's
            # interrupts): the one-core rate is measured on each, the fastest is "1thread"
            per_core = {
                k: _run_child("kin", c, clean, Path(tmp), core=k)
                for k in sorted(os.sched_getaffinity(0))
            }
            res["one_core_readings_per_s"] = {
                str(k): r["readings_per_s"] for k, r in per_core.items()
            }
            best_core = max(per_core, key=lambda k: per_core[k]["readings_per_s"])
            res["kinematics"][c] = per_core[best_core]
        res["numpy"] = _run_child("numpy", "numpy", clean, Path(tmp), core=best_core)
        if not args.skip_yield:
            for c in configs:
                res["yield"][c] = _run_child("yield", c, clean, Path(tmp), core=best_core)
    kin, npr = res["kinematics"], res["numpy"]
    ref = np.asarray(next(iter(kin.values()))["first_designs_errors"]) if kin else None
    agree = {}
    for c, r in kin.items():
        e = np.asarray(r.pop("first_designs_errors"))
        agree[c] = float(np.max(np.abs(e - ref)) / np.max(np.abs(ref)))
    res["max_relative_difference_between_configs"] = agree
    summary = {}
    one = kin.get("1thread")
    for c, r in kin.items():
        row = {
            "readings_per_s": r["readings_per_s"],
            "vs_numpy": r["readings_per_s"] / npr["readings_per_s"],
            "grad_over_forward": r["grad_over_forward"],
            "load_average": r["load_average_after"],
        }
        if one is not None and c != "1thread":
            row["speedup_vs_1thread"] = r["readings_per_s"] / one["readings_per_s"]
            row["parallel_efficiency"] = row["speedup_vs_1thread"] / cores
            # against the sum of the cores' own one-core rates (equal to the above
            # when the cores are equal)
            row["efficiency_vs_sum_of_cores"] = r["readings_per_s"] / sum(
                res["one_core_readings_per_s"].values()
            )
        y = res["yield"].get(c)
        if y is not None:
            row["yield_wall_s"] = y["wall_s"]
            row["yield_peak_rss_mb"] = y["peak_rss_mb"]
            if "1thread" in res["yield"] and c != "1thread":
                row["yield_parallel_efficiency"] = (
                    res["yield"]["1thread"]["wall_s"] / y["wall_s"] / cores
                )
        summary[c] = row
    res["summary"] = summary
    lines = [
        f"{'config':<12} {'M readings/s':>13} {'x NumPy':>8} {'grad/fwd':>9} "
        f"{'efficiency':>10} {'yield s':>8} {'peak MB':>8} {'load':>5}"
    ]
    for c, r in summary.items():
        eff = r.get("parallel_efficiency")
        lines.append(
            f"{c:<12} {r['readings_per_s'] / 1e6:13.1f} {r['vs_numpy']:8.1f} "
            f"{r['grad_over_forward']:9.2f} {'' if eff is None else f'{eff:.0%}':>10} "
            f"{r.get('yield_wall_s', math.nan):8.1f} {r.get('yield_peak_rss_mb', math.nan):8.0f} "
            f"{r['load_average']:5.1f}"
        )
    per = res.get("one_core_readings_per_s", {})
    if per:
        lines.append(
            "one core, pinned: "
            + ", ".join(f"core {k} {v / 1e6:.1f}" for k, v in per.items())
            + " M readings/s (efficiency = rate / (cores x the fastest core); vs their sum: "
            + ", ".join(
                f"{c} {r['efficiency_vs_sum_of_cores']:.0%}"
                for c, r in summary.items()
                if "efficiency_vs_sum_of_cores" in r
            )
            + ")"
        )
    lines.append(
        f"{'numpy':<12} {npr['readings_per_s'] / 1e6:13.1f} {1.0:8.1f}"
        f"   (max |jax - numpy| = {npr['max_abs_difference_rad']:.2e} rad)"
    )
    print("\n".join(lines), file=sys.stderr)
    text = json.dumps(res, indent=2)
    print(text)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        tmpf = args.json.with_name(f".tmp-{args.json.name}")
        tmpf.write_text(text + "\n")
        os.replace(tmpf, args.json)
    if npr["max_abs_difference_rad"] > 1e-12 or any(v > 1e-13 for v in agree.values()):
        print("error: the configurations or NumPy disagree", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
