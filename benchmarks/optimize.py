"""Benchmark: Monte Carlo yield of encoder builds, and the cost of its gradient.

Configuration: 3+1 heads (reference at 18.09 deg), r = 2.54 cm, nominal tilt 6 mrad,
``--angles`` samples per revolution (default 2,048), grating and self-compensation orders
1-16, the tolerance set of ``studies/tolerance_budget.py``'s reference. Each build: kinematic
model -> head errors -> symmetry average -> self-compensation -> RMS residual
(:func:`encdesign.objectives.residual_rms`); yield = fraction with RMS <= 1 urad.

Measured:

* wall time and peak resident memory of the yield estimate over ``--builds`` builds
  (default 100,000), streamed in jitted chunks of ``--chunk`` builds, ``--vector`` of them
  vectorised together (memory bounded by one chunk, independent of the number of builds;
  run with ``--builds 1000000`` to see it);
* time of the expected RMS residual over ``--grad-builds`` builds
  (:func:`encdesign.objectives.build_metrics`, ``--grad-chunk`` builds per chunk,
  vectorised 8 at a time) and of its gradient with respect to the seven tolerances
  (reverse mode), and their ratio, in wall time and in process CPU time (the minimum of
  ``--grad-reps`` interleaved repetitions; CPU time is the fairer measure of cost on a
  shared machine);
* a plain NumPy implementation of the same physics (ray-plane kinematics, head average,
  DFT + cotangent equations, map) on ``--numpy-builds`` builds: its time per build and
  its agreement with the JAX values for the same builds.

* ``--rare``: rare-event yield of a 3+1 case near 99.9 % (``--rare-angles`` 256 samples per
  revolution, RMS residual spec ``--rare-spec-rad`` 7.3 urad, the same tolerances) by
  FORM + defensive-mixture importance sampling (:func:`encdesign.design.importance_yield`,
  ``--rare-is-builds`` samples) against crude Monte Carlo of ``--rare-crude-builds``
  (10^6) builds: both estimates, standard errors, builds used (FORM evaluations included),
  wall times, the z-score of their difference, and the likelihood-ratio gradient of the
  failure probability with respect to each tolerance. ``--rare-crude-values FILE.npy``
  reuses the per-build values of an earlier crude run of this same function (its first
  4,096 builds are recomputed and must agree to 1e-12, else the benchmark stops);
  ``--rare-save-values FILE.npy`` writes them.

Usage: ``python benchmarks/optimize.py --json results/bench-optimize.json``;
``python benchmarks/optimize.py --rare --skip-yield --skip-gradient --json
results/bench-rare.json``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import resource
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign  # noqa: F401  (float64)
from encdesign import _distributed as dist
from encdesign.design import deviation_sizes
from encdesign.design._rare import importance_yield
from encdesign.design._sampling import VECTOR_BUILDS, build_normals, values_of_normals
from encdesign.objectives import (
    TOLERANCE_NAMES,
    EncoderDesign,
    Tolerances,
    build_metrics,
    n_build_normals,
    residual_rms,
)

SPEC_RAD = 1e-6
TOL_SI = dict(
    eccentricity=5e-6,
    tilt=1e-3,
    placement=2e-4,
    grating=5e-6,
    beam_tilt=1e-3,
    axial_runout=2e-6,
    noise=2e-7,
)
"""The benchmark's tolerances (SI); made into :class:`Tolerances` only inside ``main``, after
the distributed runtime is joined (a JAX array at import would start the backend first)."""


def tolerances() -> Tolerances:
    """The benchmark's :class:`Tolerances` (standard deviations, SI)."""
    return Tolerances(**TOL_SI)


def peak_rss_mb() -> float:
    """Peak resident set size of this process so far, MB (Linux ru_maxrss is in kB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def design(n_angles: int) -> EncoderDesign:
    return EncoderDesign(
        radius_m=0.0254,
        reference_angle_rad=math.radians(18.09),
        tilt_rad=6e-3,
        n_heads=3,
        max_order=16,
        grating_orders=16,
        axial_orders=2,
        n_angles=n_angles,
    )


# ----------------------------------------------------------------------------- NumPy


def numpy_rms(d: EncoderDesign, tol: Tolerances, z: np.ndarray) -> np.ndarray:
    """The same physics in plain NumPy for builds ``z [B, dim]``: RMS residual per build."""
    b = z.shape[0]
    h = d.n_heads + 1
    mg, ka = d.grating_orders, d.axial_orders
    i = 0

    def take(n):
        nonlocal i
        out = z[:, i : i + n]
        i += n
        return out

    ecc = float(tol.eccentricity) * take(2)
    tilt = float(tol.tilt) * take(2) + np.array([float(d.tilt_rad), 0.0])
    place = float(tol.placement) * take(h)
    j = np.arange(1, mg + 1)
    gs = float(tol.grating) * take(mg) / j
    gc = float(tol.grating) * take(mg) / j
    beam = float(tol.beam_tilt) * take(h)
    ac = float(tol.axial_runout) * take(ka)
    asn = float(tol.axial_runout) * take(ka)
    radius, gap = float(d.radius_m), float(d.gap_m)
    alpha = np.asarray(d.head_angles_rad)
    n = d.n_angles
    th = np.arange(n) * (2 * np.pi / n)
    # disk at theta = 0 (rotor frame)
    tx, ty = np.tan(tilt[:, 0]), np.tan(tilt[:, 1])
    nn = np.sqrt(1 + tx**2 + ty**2)
    n0 = np.stack([tx / nn, ty / nn, 1 / nn], -1)  # [B,3]
    ln = np.sqrt(1 - n0[:, 0] ** 2)
    l0 = np.stack(
        [(1 - n0[:, 0] ** 2) / ln, -n0[:, 0] * n0[:, 1] / ln, -n0[:, 0] * n0[:, 2] / ln], -1
    )
    c, s = np.cos(th), np.sin(th)

    def rot(v):  # [B,3] -> [B,n,3] rotated by theta about z
        return np.stack(
            [
                c * v[:, :1] - s * v[:, 1:2],
                s * v[:, :1] + c * v[:, 1:2],
                np.broadcast_to(v[:, 2:3], (b, n)),
            ],
            -1,
        )

    nv, lv = rot(n0), rot(l0)
    cv = rot(np.concatenate([ecc, np.zeros((b, 1))], 1))
    kk = np.arange(1, ka + 1)
    cz = np.cos(th[:, None] * kk) @ ac.T + np.sin(th[:, None] * kk) @ asn.T  # [n,B]
    cv[..., 2] = cz.T
    beta = alpha + place  # [B,H]
    cb, sb = np.cos(beta), np.sin(beta)
    tg = np.tan(beam)
    un = np.sqrt(1 + tg**2)
    u = np.stack([-tg * sb / un, tg * cb / un, -1 / un], -1)  # [B,H,3]
    r = np.stack([radius * cb, radius * sb, np.full_like(cb, gap)], -1)  # [B,H,3]
    w = cv[:, :, None, :] - r[:, None, :, :]  # [B,n,H,3]
    nvb = nv[:, :, None, :]
    t = np.sum(w * nvb, -1) / np.sum(u[:, None] * nvb, -1)
    v = t[..., None] * u[:, None] - w
    lvb = lv[:, :, None, :]
    cr = np.cross(v, lvb)
    sin_part = np.sum(cr * nvb, -1)
    cos_part = np.sum(v * lvb, -1)
    psi = np.arctan2(sin_part, cos_part)  # [B,n,H]
    arg = psi[..., None] * j
    g = np.sum(gs[:, None, None, :] * np.sin(arg) + gc[:, None, None, :] * np.cos(arg), -1)
    err = np.remainder(psi + alpha - th[None, :, None] + np.pi, 2 * np.pi) - np.pi + g
    ns = d.n_heads
    avg = err[..., :ns].mean(-1)  # [B,n]
    # self-compensation: DFT of the differences, cotangent equations, averaged over pairs
    diff = err[..., :ns] - err[..., ns:]  # [B,n,P]
    m = np.arange(1, d.max_order + 1)
    e = np.exp(-1j * th[:, None] * m)  # [n,M]
    a = 2.0 / n * np.einsum("bnp,nm->bpm", diff, e)  # complex C' - i S'
    h_off = alpha[ns] - alpha[:ns]
    k = 1.0 / (np.exp(1j * m[None, :] * h_off[:, None]) - 1.0)  # [P,M]
    est = np.mean(a * k[None], axis=1)  # reference head's complex coefficients C - i S
    transfer = np.mean(np.exp(1j * m[:, None] * h_off[None, :]), axis=1)  # [M]
    amp = est * transfer
    mp = np.real(amp @ np.exp(1j * m[:, None] * th[None, :]))  # map m(theta)
    res = avg - mp
    res = res - res.mean(1, keepdims=True)
    # expected calibration-noise mean square (same formula as objectives)
    kk2 = np.abs(k) ** 2
    var = kk2.sum(0) / ns**2 + np.abs(k.mean(0)) ** 2
    ms_noise = np.sum(np.abs(transfer) ** 2 * var) * float(tol.noise) ** 2 * 2.0 / n
    return np.sqrt(np.mean(res**2, 1) + ms_noise)


# ----------------------------------------------------------------------------- main


RARE_CRUDE_KEY = 11
RARE_IS_KEY = 5
RARE_CHUNK = 4096


def rare_event(args: argparse.Namespace) -> dict:
    """Importance-sampling yield against crude Monte Carlo (module docstring)."""
    tol = tolerances()
    d = design(args.rare_angles)
    dim = n_build_normals(d)
    spec = args.rare_spec_rad
    ckey = jax.random.key(RARE_CRUDE_KEY)
    chunk = jax.jit(
        lambda first: build_metrics(
            d, tol, key=ckey, n_builds=RARE_CHUNK, first_build=first, chunk_size=512
        )
    )
    n = args.rare_crude_builds
    t0 = time.perf_counter()
    if args.rare_crude_values is not None:
        vals = np.load(args.rare_crude_values)
        if vals.size < n:
            raise SystemExit(f"{args.rare_crude_values}: {vals.size} values < {n} builds")
        vals = vals[:n]
        check = np.asarray(chunk(0))[: min(RARE_CHUNK, n)]
        if not np.allclose(check, vals[: check.size], rtol=1e-12, atol=0):
            raise SystemExit(f"{args.rare_crude_values}: not the values of this function")
        crude_source = f"{args.rare_crude_values} (first {check.size} builds recomputed: equal)"
        crude_wall = None
    else:
        vals = np.empty(n)
        for s0 in range(0, n, RARE_CHUNK):
            vals[s0 : s0 + RARE_CHUNK] = np.asarray(chunk(s0))[: n - s0]
            if s0 % (RARE_CHUNK * 16) == 0:
                print(f"\r  crude: {s0}/{n} {time.perf_counter() - t0:7.1f} s", end="",
                      file=sys.stderr, flush=True)  # fmt: skip
        print(file=sys.stderr)
        crude_wall = time.perf_counter() - t0
        crude_source = "computed in this run"
        if args.rare_save_values is not None:
            np.save(args.rare_save_values, vals)
    pf_c = float(np.mean(vals > spec))
    se_c = math.sqrt(pf_c * (1 - pf_c) / n)
    group_of = {"eccentricity": 0, "tilt": 1, "placement": 2, "grating_sin": 3,
                "grating_cos": 3, "beam_tilt": 4, "axial_cos": 5, "axial_sin": 5}  # fmt: skip
    groups = [group_of[k] for k, m in deviation_sizes(d).items() for _ in range(m)]
    res = importance_yield(
        lambda z: residual_rms(d, tol, z),
        dim,
        spec,
        key=jax.random.key(RARE_IS_KEY),
        n=args.rare_is_builds,
        groups=groups,
        sigmas=np.asarray(tol.vector()),
        names=TOLERANCE_NAMES,
    )
    is_d = res.as_dict()
    comb = math.hypot(se_c, res.failure_stderr)
    crude_se_same = math.sqrt(pf_c * (1 - pf_c) / res.n_builds_total)
    return {
        "case": f"3+1, {args.rare_angles} angles, orders 1-16, RMS residual spec {spec:g} rad",
        "spec_rad": spec,
        "crude": {
            "builds": n,
            "failure_prob": pf_c,
            "failure_stderr": se_c,
            "yield": 1 - pf_c,
            "wall_s": crude_wall,
            "source": crude_source,
            "key": RARE_CRUDE_KEY,
        },
        "importance_sampling": {**is_d, "key": RARE_IS_KEY},
        "difference": res.failure_prob - pf_c,
        "combined_stderr": comb,
        "z_score": (res.failure_prob - pf_c) / comb,
        "agree_within_2_combined_stderr": abs(res.failure_prob - pf_c) <= 2 * comb,
        "is_builds_fraction_of_crude": res.n_builds_total / n,
        "variance_gain_vs_crude_same_builds": (crude_se_same / res.failure_stderr) ** 2,
        "note_lr_gradient": "dP_f/dsigma per SI unit of each tolerance; noise is not sampled "
        "(enters through its expected mean square), so it has no likelihood-ratio gradient",
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--builds", type=int, default=100_000)
    p.add_argument("--angles", type=int, default=2048)
    p.add_argument("--chunk", type=int, default=512, help="builds per jitted call")
    p.add_argument("--vector", type=int, default=VECTOR_BUILDS, help="builds vectorised together")
    p.add_argument("--grad-builds", type=int, default=1024)
    p.add_argument("--grad-chunk", type=int, default=256, help="builds per chunk (memory bound)")
    p.add_argument("--grad-reps", type=int, default=5)
    p.add_argument("--numpy-builds", type=int, default=64)
    p.add_argument("--skip-yield", action="store_true", help="only gradient and NumPy parts")
    p.add_argument(
        "--time-limit-s",
        type=float,
        default=0.0,
        help="stop the yield loop after this long (report builds done; 0 = no limit)",
    )
    p.add_argument("--skip-gradient", action="store_true", help="skip the gradient part")
    p.add_argument("--rare", action="store_true", help="rare-event yield: IS vs crude MC")
    p.add_argument("--rare-angles", type=int, default=256)
    p.add_argument("--rare-spec-rad", type=float, default=7.3e-6)
    p.add_argument("--rare-crude-builds", type=int, default=1_000_000)
    p.add_argument("--rare-is-builds", type=int, default=8000)
    p.add_argument("--rare-crude-values", type=Path, default=None)
    p.add_argument("--rare-save-values", type=Path, default=None)
    dist.add_launch_flags(p)
    args = p.parse_args(argv)
    if args.vector < 1 or args.chunk % args.vector:
        p.error(f"--chunk {args.chunk} must be a multiple of --vector {args.vector} (>= 1)")
    # scale-out (docs/scale.md): the yield's chunks are dealt over the processes, and the
    # counts summed; the gradient, NumPy and rare-event parts run in one process only
    launch = dist.launch_from_args(args)
    if launch.spawns:
        argv_list = list(sys.argv[1:] if argv is None else argv)
        return dist.spawn_local(
            dist.strip_launch_flags(argv_list),
            launch.processes,
            program=[sys.executable, str(Path(__file__).resolve())],
        )
    dist.initialize(launch)
    tol = tolerances()
    if dist.process_count() > 1 and not (args.skip_gradient and not args.rare):
        p.error("on several processes only the yield part runs: add --skip-gradient (no --rare)")
    d = design(args.angles)
    dim = n_build_normals(d)
    key = jax.random.key(0)
    out: dict = {
        "config": {
            "layout": "3+1",
            "n_angles": args.angles,
            "orders": "1-16",
            "chunk": args.chunk,
            "vector": args.vector,
            "builds": args.builds,
            "spec_rad": SPEC_RAD,
        },
        "machine": {
            "python": platform.python_version(),
            "jax": jax.__version__,
            "devices": [str(x) for x in jax.devices()],
        },
    }
    rss0 = peak_rss_mb()

    @jax.jit
    def chunk_counts(tv, first):
        idx = first + jnp.arange(args.chunk)
        z = build_normals(key, idx, dim)
        v = values_of_normals(
            lambda zi: residual_rms(d, Tolerances.from_vector(tv), zi), z, args.vector
        )
        live = idx < args.builds  # the last chunk may run past the requested count
        return (
            jnp.sum(live & (v <= SPEC_RAD)),
            jnp.sum(jnp.where(live, v, 0.0)),
            jnp.sum(live & ~jnp.isfinite(v)),
        )

    tv = tol.vector()
    if not args.skip_yield:
        t0 = time.perf_counter()
        jax.block_until_ready(chunk_counts(tv, 0))
        compile_s = time.perf_counter() - t0
        n_chunks = -(-args.builds // args.chunk)
        passed, total, bad, n_mine = 0, 0.0, 0, 0
        t0 = time.perf_counter()
        for c in range(n_chunks):
            if args.time_limit_s and time.perf_counter() - t0 > args.time_limit_s:
                break
            if not dist.is_my_task(c):  # chunk c belongs to process c mod N
                continue
            a, s, nb = chunk_counts(tv, c * args.chunk)
            passed += int(a)
            total += float(s)
            bad += int(nb)
            n_mine += min(args.chunk, args.builds - c * args.chunk)
            if c % 10 == 0 or c == n_chunks - 1:
                el = time.perf_counter() - t0
                print(
                    f"\r  yield: {c + 1}/{n_chunks} chunks, {el:7.1f} s, "
                    f"peak RSS {peak_rss_mb():7.1f} MB",
                    end="",
                    file=sys.stderr,
                    flush=True,
                )
        print(file=sys.stderr)
        wall = time.perf_counter() - t0
        # one collective: every process's counts, summed (one process: its own)
        rows = dist.allgather_rows(
            np.array([[passed, total, bad, n_mine, wall]]), dist.process_count()
        )
        passed, total, bad, n = (
            int(rows[:, 0].sum()),
            float(rows[:, 1].sum()),
            int(rows[:, 2].sum()),
            int(rows[:, 3].sum()),
        )
        wall = float(rows[:, 4].max())  # the slowest process
        y = passed / n
        out["yield"] = {
            "builds_requested": args.builds,
            "processes": dist.process_count(),
            "builds": n,
            "complete": n == args.builds,
            "wall_s_extrapolated_to_requested": wall * args.builds / n,
            "yield": y,
            "yield_stderr": math.sqrt(y * (1 - y) / n),
            "mean_rms_rad": total / n,
            "nonfinite_builds": bad,
            "wall_s": wall,
            "compile_s": compile_s,
            "us_per_build": wall / n * 1e6,
            "peak_rss_mb": peak_rss_mb(),
            "peak_rss_before_mb": rss0,
        }
        print(json.dumps(out["yield"], indent=1), file=sys.stderr)

    # gradient of the expected objective vs one forward evaluation
    if not args.skip_gradient:
        nb = args.grad_builds
        gkey = jax.random.key(1)

        def expected(tv):
            return jnp.mean(
                build_metrics(
                    d,
                    Tolerances.from_vector(tv),
                    key=gkey,
                    n_builds=nb,
                    chunk_size=args.grad_chunk,
                )
            )

        fwd = jax.jit(expected)
        grad = jax.jit(jax.grad(expected))
        jax.block_until_ready(fwd(tv))
        jax.block_until_ready(grad(tv))
        # interleaved repetitions; the minimum of each is the least disturbed by other load
        walls: dict[str, list[float]] = {"f": [], "g": []}
        cpus: dict[str, list[float]] = {"f": [], "g": []}
        for _ in range(args.grad_reps):
            for name, f in (("f", fwd), ("g", grad)):
                t0, c0 = time.perf_counter(), time.process_time()
                jax.block_until_ready(f(tv))
                walls[name].append(time.perf_counter() - t0)
                cpus[name].append(time.process_time() - c0)
        tf, tg = min(walls["f"]), min(walls["g"])
        cf, cg = min(cpus["f"]), min(cpus["g"])
        out["gradient"] = {
            "builds": nb,
            "chunk": args.grad_chunk,
            "reps": args.grad_reps,
            "forward_s": tf,
            "gradient_s": tg,
            "ratio": tg / tf,
            "forward_cpu_s": cf,
            "gradient_cpu_s": cg,
            "ratio_cpu": cg / cf,
            "gradient": np.asarray(grad(tv)).tolist(),
        }
        print(json.dumps(out["gradient"], indent=1), file=sys.stderr)

    if args.rare:
        out["rare_event"] = rare_event(args)
        print(json.dumps(out["rare_event"], indent=1), file=sys.stderr)

    if dist.process_count() > 1:  # the yield was the distributed part; process 0 reports
        if dist.is_main_process() and args.json is not None:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(out, indent=2) + "\n")
            print(f"wrote {args.json}")
        return 0

    # plain NumPy implementation of the same physics
    zn = np.asarray(build_normals(key, jnp.arange(args.numpy_builds), dim))
    t0 = time.perf_counter()
    v_np = numpy_rms(d, tol, zn)
    t_np = time.perf_counter() - t0
    v_jax = np.asarray(jax.jit(jax.vmap(lambda zi: residual_rms(d, tol, zi)))(jnp.asarray(zn)))
    out["numpy"] = {
        "builds": args.numpy_builds,
        "us_per_build": t_np / args.numpy_builds * 1e6,
        "max_rel_diff_vs_jax": float(np.max(np.abs(v_np - v_jax) / v_jax)),
    }
    print(json.dumps(out["numpy"], indent=1), file=sys.stderr)
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
