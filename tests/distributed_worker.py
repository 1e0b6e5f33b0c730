"""A Monte Carlo yield run as one process of a distributed run (driven by
``tests/test_distributed.py``): ``python tests/distributed_worker.py OUT.json [launch flags]``.

Process 0 writes the per-build values, the yield and the gradient of the mean metric with
respect to the tolerances to ``OUT.json``. ``--die`` makes process 1 exit with status 7
right after joining, while process 0 waits for it in a collective.
"""

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from helpers import SCALE_BUILDS, SCALE_DESIGN, SCALE_TOLERANCES  # noqa: E402

from encdesign.design import _distributed as dist  # noqa: E402


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("out", type=Path)
    p.add_argument("--die", action="store_true")
    dist.add_launch_flags(p)
    args = p.parse_args()
    dist.initialize(dist.launch_from_args(args), timeout_s=60, heartbeat_s=10)
    import jax
    import jax.numpy as jnp
    import numpy as np

    from encdesign.design._drivers import monte_carlo
    from encdesign.objectives import (
        EncoderDesign,
        SDSTolerances,
        Tolerances,
        build_metric,
        build_metrics,
        n_build_normals,
        sds_residuals,
    )

    if args.die:
        if dist.process_index() == 1:
            os._exit(7)
        dist.barrier("never-complete")
    design = EncoderDesign(**SCALE_DESIGN)
    tol = Tolerances(**SCALE_TOLERANCES)
    key = jax.random.key(7)

    def metric(t, z):
        return build_metric(design, t, z)

    mc = monte_carlo(
        metric,
        tol,
        key=key,
        n=SCALE_BUILDS,
        dim=n_build_normals(design),
        chunk_size=32,
    )
    spec = float(np.median(mc.values))
    y, y_se = mc.yield_fraction(spec)

    def mean_metric(s):
        t = Tolerances(**dict(zip(SCALE_TOLERANCES, s)))
        return jnp.mean(build_metrics(design, t, key=key, n_builds=101, chunk_size=16))

    sig = jnp.asarray(list(SCALE_TOLERANCES.values()))
    grad = jax.jit(jax.grad(mean_metric))(sig)
    # a solver step: the next point is computed from an output that lives on the mesh
    again = jax.jit(mean_metric)(sig * (1.0 + 1e3 * grad * sig))
    # monte_carlo of a design that lives on the mesh (the output of a sharded step)
    t_mesh = Tolerances(**dict(zip(SCALE_TOLERANCES, sig * (1.0 + 0.0 * grad))))
    mc_mesh = monte_carlo(
        metric, t_mesh, key=key, n=SCALE_BUILDS, dim=n_build_normals(design), chunk_size=32
    )
    sds = sds_residuals(3, 2, SDSTolerances(), key=key, n_builds=5, marks_per_rev=60, n_phi=8)
    tasks = [{"task": i, "by": dist.process_index()} for i in range(5) if dist.is_my_task(i)]
    out = {
        "tasks": sorted(dist.allgather_objects(tasks), key=lambda t: t["task"]),
        "sds": np.asarray(sds).tolist(),
        "devices": jax.device_count(),
        "processes": jax.process_count(),
        "values": mc.values.tolist(),
        "mean": mc.mean,
        "spec": spec,
        "yield": y,
        "yield_stderr": y_se,
        "grad": np.asarray(grad).tolist(),
        "again": float(again),
        "mean_mesh_input": mc_mesh.mean,
    }
    if dist.is_main_process():
        args.out.write_text(json.dumps(out))
    dist.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
