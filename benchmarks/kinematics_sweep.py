"""Sweep: CPU devices per core and chunk sizes of the kinematic Monte Carlo.

The defaults of ``encdesign/_cpu.py`` (``DEVICES_PER_CORE``), of
``encdesign/physics/_kinematics.py`` (``_CHUNK_READINGS``, readings per chunk of
:func:`encdesign.head_errors_batch`) and of the Monte Carlo drivers' ``chunk_size``
(builds per device and chunk of :func:`encdesign.design.monte_carlo`) are read off this
sweep, not set by hand. Every device count runs in a subprocess of its own (the count is
fixed before JAX starts: ``ENCDESIGN_CPU_DEVICES``); within it every chunk size is timed
(best of ``--repeats``) on

* the forward pass of ``--designs`` designs x 4 heads x ``--angles`` angles, orders 1-8
  (the population of ``benchmarks/kinematics.py``), and
* the Monte Carlo yield of ``--builds`` builds (3+1 heads, ``--yield-angles`` angles,
  orders 1-16, ``benchmarks/optimize.py``'s tolerances) through ``monte_carlo``.

The fastest setting of each is printed as ``chosen``; the load average before and after
each device count is recorded (a loaded machine blurs the differences).

    python benchmarks/kinematics_sweep.py --json benchmarks/kinematics_sweep.json \
        --write-defaults

``--write-defaults`` rewrites ``encdesign/_tuning.json`` (the defaults' one source) from the
result, only when the load average stayed below the core count (``--force`` otherwise).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import encdesign  # noqa: F401
from encdesign.physics import _kinematics


def _best(f, repeats: int) -> float:
    f()
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        f()
        best = min(best, time.perf_counter() - t0)
    return best


def _child(args) -> dict:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from kinematics import make_population
    from optimize import design, tolerances

    from encdesign.design import monte_carlo
    from encdesign.objectives import Tolerances, n_build_normals, residual_rms

    models = make_population(jax.random.key(0), args.designs, 4, 8)
    theta = jnp.arange(args.angles) * (2 * np.pi / args.angles)
    t_s = theta / (2 * np.pi)
    n = args.designs * 4 * args.angles
    fwd = {}
    for r in [int(x) for x in args.chunk_readings.split(",")]:
        chunk = max(1, r // (4 * args.angles))
        f = jax.jit(lambda m, c=chunk: _kinematics.head_errors_batch(m, theta, t_s, chunk=c))
        fwd[str(r)] = n / _best(lambda f=f: f(models).block_until_ready(), args.repeats)
    d = design(args.yield_angles)
    tv = tolerances().vector()
    fn = lambda t, z: residual_rms(d, Tolerances.from_vector(t), z)
    mc = {}
    for c in [int(x) for x in args.mc_chunks.split(",")]:
        run = lambda c=c: monte_carlo(
            fn, tv, key=jax.random.key(0), n=args.builds, dim=n_build_normals(d), chunk_size=c
        )
        mc[str(c)] = args.builds / _best(run, max(1, args.repeats // 2))
    return {"devices": jax.device_count(), "forward_readings_per_s": fwd, "mc_builds_per_s": mc}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--json", type=Path, default=None)
    p.add_argument("--devices-per-core", default="1,2", help="device counts, per core")
    p.add_argument("--chunk-readings", default="4096,16384,32768,131072")
    p.add_argument("--mc-chunks", default="1024,4096")
    p.add_argument("--designs", type=int, default=256)
    p.add_argument("--angles", type=int, default=2048)
    p.add_argument("--builds", type=int, default=8192)
    p.add_argument("--yield-angles", type=int, default=256)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument(
        "--write-defaults",
        action="store_true",
        help="write the chosen devices per core and chunk to encdesign/_tuning.json (only "
        "when the load average stayed below the core count, unless --force)",
    )
    p.add_argument("--force", action="store_true", help="write the defaults under load too")
    p.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.child is not None:
        Path(args.child).write_text(json.dumps(_child(args)))
        return 0
    cores = len(os.sched_getaffinity(0))
    counts = sorted({1, *(cores * int(k) for k in args.devices_per_core.split(","))})
    rows = []
    keep = [a for a in (sys.argv[1:] if argv is None else argv)]
    if "--json" in keep:
        i = keep.index("--json")
        del keep[i : i + 2]
    for dcount in counts:
        out = Path(f"/tmp/kinematics-sweep-{os.getpid()}-{dcount}.json")
        env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "OMP_NUM_THREADS")}
        env["ENCDESIGN_CPU_DEVICES"] = str(dcount)
        load0 = os.getloadavg()[0]
        print(f"  {dcount} device(s) ...", file=sys.stderr, flush=True)
        cmd = [sys.executable, str(Path(__file__).resolve()), *keep, "--child", str(out)]
        subprocess.run(cmd, env=env, check=True)
        row = json.loads(out.read_text())
        out.unlink()
        row["load_average_before"], row["load_average_after"] = load0, os.getloadavg()[0]
        rows.append(row)
        print(f"    {json.dumps(row)}", file=sys.stderr)
    fbest = max(
        ((r["devices"], int(c), v) for r in rows for c, v in r["forward_readings_per_s"].items()),
        key=lambda x: x[2],
    )
    mbest = max(
        ((r["devices"], int(c), v) for r in rows for c, v in r["mc_builds_per_s"].items()),
        key=lambda x: x[2],
    )
    res = {
        "cores": cores,
        "designs": args.designs,
        "angles": args.angles,
        "builds": args.builds,
        "yield_angles": args.yield_angles,
        "rows": rows,
        "chosen": {
            "forward": {
                "devices": fbest[0],
                "chunk_readings": fbest[1],
                "readings_per_s": fbest[2],
            },
            "monte_carlo": {"devices": mbest[0], "chunk_size": mbest[1], "builds_per_s": mbest[2]},
            "devices_per_core": fbest[0] / cores,
        },
    }
    text = json.dumps(res, indent=2)
    print(text)
    if args.json is not None:
        args.json.write_text(text + "\n")
    if args.write_defaults:
        load = max(max(r["load_average_before"], r["load_average_after"]) for r in rows)
        if load >= cores and not args.force:
            print(
                f"not writing the defaults: load average up to {load:.1f} on {cores} cores "
                "(the machine is not quiet; --force to write anyway)",
                file=sys.stderr,
            )
            return 1
        from encdesign import _tuning

        tuning = {
            "devices_per_core": res["chosen"]["devices_per_core"],
            "chunk_readings": res["chosen"]["forward"]["chunk_readings"],
            "source": f"benchmarks/kinematics_sweep.py {' '.join(keep)} on {time.ctime()}: "
            f"the fastest forward pass (load average up to {load:.1f} on {cores} cores)",
        }
        _tuning.PATH.write_text(json.dumps(tuning, indent=2) + "\n")
        print(f"wrote {_tuning.PATH}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
