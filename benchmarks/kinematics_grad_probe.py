"""Probe: where the value-and-gradient of the kinematic model spends its time (one core).

The hand-written reverse pass (``encdesign.physics._reading_math._readings_bwd``) forms ~35
per-reading cotangent terms and sums each over the shaft angles in ONE variadic reduction
(``_sums``), so that XLA computes what the terms share once per reading. This probe swaps
that reduction for variants that do the same elementwise work (or less) and times the
value-and-gradient of the benchmark's loss (``benchmarks/kinematics.py``: mean squared head
error over every design) against the loss alone, each variant in its own process pinned to
one core with one CPU device and XLA's own threads off:

* ``as-is``: the library's variadic reduction (the only variant whose gradient is right);
* ``one-sum``: all terms added elementwise, then ONE single-output sum (same elementwise
  work, one reduction output: what a vectorised variadic reduction could cost at best);
* ``per-term``: one ``jnp.sum`` per term (XLA may merge or recompute);
* ``barrier``: the terms materialised (``lax.optimization_barrier``), then one sum each;
* ``first-row``: only the first angle of each term kept (XLA drops most of the reverse
  pass: the forward pass, the stored errors and the loop's plumbing).

Every variant but ``as-is`` returns WRONG gradients: this measures time only.

    python benchmarks/kinematics_grad_probe.py --json results/grad-probe.json
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

VARIANTS = ("as-is", "one-sum", "per-term", "barrier", "first-row")
ONE_THREAD = "--xla_cpu_multi_thread_eigen=false"


def _install(variant: str) -> None:
    """Replace ``_reading_math._sums`` by ``variant`` (timing only; see the module doc)."""
    import jax
    import jax.numpy as jnp

    from encdesign.physics import _reading_math as rm

    if variant == "as-is":
        return

    def forward(xs):
        if variant == "one-sum":
            total = jnp.sum(sum(xs[1:], xs[0]), axis=0)
            return (total,) * len(xs)
        if variant == "per-term":
            return tuple(jnp.sum(x, axis=0) for x in xs)
        if variant == "barrier":
            return tuple(jnp.sum(x, axis=0) for x in jax.lax.optimization_barrier(tuple(xs)))
        return tuple(x[0] for x in xs)  # first-row

    probe = jax.custom_vjp(forward)
    probe.defvjp(
        lambda xs: (probe(xs), xs[0].shape),
        lambda shape, bars: (tuple(jnp.broadcast_to(b, shape) for b in bars),),
    )
    rm._sums = probe


def _child(args) -> dict:
    import jax
    import jax.numpy as jnp
    import numpy as np

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from kinematics import _best_time, make_population

    from encdesign.physics._kinematics import head_errors_batch

    _install(args.child)
    models = make_population(jax.random.key(args.seed), args.designs, args.heads, args.orders)
    theta = np.arange(args.angles) * (2 * np.pi / args.angles)
    th, t_s = jnp.asarray(theta), jnp.asarray(theta / (2 * np.pi))

    def loss(m):
        return jnp.mean(head_errors_batch(m, th, t_s) ** 2)

    f_loss, f_vg = jax.jit(loss), jax.jit(jax.value_and_grad(loss))
    jax.block_until_ready((f_loss(models), f_vg(models)))
    t_loss = _best_time(lambda: f_loss(models).block_until_ready(), args.repeats)
    t_vg = _best_time(lambda: jax.block_until_ready(f_vg(models)), args.repeats)
    return {
        "variant": args.child,
        "devices": jax.device_count(),
        "loss_s": t_loss,
        "value_and_grad_s": t_vg,
        "grad_over_forward": t_vg / t_loss,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=None, help="write the results here")
    p.add_argument("--designs", type=int, default=1000)
    p.add_argument("--heads", type=int, default=4)
    p.add_argument("--angles", type=int, default=2048)
    p.add_argument("--orders", type=int, default=8)
    p.add_argument("--repeats", type=int, default=5, help="timings per variant (best kept)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--core", type=int, default=-1, help="core to pin to (default: lowest)")
    p.add_argument("--variants", default=",".join(VARIANTS), help=f"subset of {','.join(VARIANTS)}")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child is not None:
        print(json.dumps(_child(args)))
        return 0
    variants = [v for v in args.variants.split(",") if v]
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        p.error(f"--variants: unknown {unknown}, expected a subset of {list(VARIANTS)}")
    core = min(os.sched_getaffinity(0)) if args.core < 0 else args.core
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(XLA_FLAGS=ONE_THREAD, ENCDESIGN_CPU_DEVICES="1", OMP_NUM_THREADS="1")
    passed = list(argv if argv is not None else sys.argv[1:])
    rows = []
    for v in variants:
        print(f"  {v} (core {core}) ...", file=sys.stderr, flush=True)
        load0 = os.getloadavg()[0]
        t0 = time.perf_counter()
        out = subprocess.run(
            [sys.executable, str(Path(__file__).resolve()), *passed, "--child", v],
            env=env,
            check=True,
            capture_output=True,
            text=True,
            preexec_fn=lambda: os.sched_setaffinity(0, {core}),
        )
        row = json.loads(out.stdout.strip().splitlines()[-1])
        row.update(core=core, load_average_before=load0, child_wall_s=time.perf_counter() - t0)
        rows.append(row)
    print(f"{'variant':10s} {'loss s':>8s} {'value+grad s':>13s} {'ratio':>6s}  load")
    for r in rows:
        print(
            f"{r['variant']:10s} {r['loss_s']:8.4f} {r['value_and_grad_s']:13.4f} "
            f"{r['grad_over_forward']:6.2f}  {r['load_average_before']:.1f}"
        )
    result = {
        "benchmark": "kinematics_grad_probe",
        "designs": args.designs,
        "heads": args.heads,
        "angles": args.angles,
        "grating_orders": args.orders,
        "note": "only 'as-is' has correct gradients; the others time variants of the sum",
        "variants": rows,
    }
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
