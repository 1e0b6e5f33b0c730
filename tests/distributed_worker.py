"""A Monte Carlo yield and the traced (differentiable) builds path, run on the devices and
processes at hand (driven by ``tests/test_distributed.py``).

``python tests/distributed_worker.py OUT.json [--sds] [launch flags]``: process 0 writes
:func:`run_checks`'s results to ``OUT.json``. The test module also calls
:func:`run_checks` in its own process, on one device, for the reference. ``--die`` makes
process 1 exit with status 7 right after joining, while process 0 waits for it in a
collective. ``--mismatch`` makes the two processes make different gathers; each writes the
error it got to ``OUT.json.pK``.
"""

import argparse
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from helpers import SCALE_BUILDS, SCALE_DESIGN, SCALE_TOLERANCES  # noqa: E402

from encdesign import _distributed as dist  # noqa: E402


def run_checks(sds: bool = False) -> dict:
    """Results of the checks on the ``"builds"`` mesh in use (JSON-able):

    * ``values``, ``mean``, ``spec``, ``yield``: :func:`monte_carlo` of a build metric
      (``SCALE_BUILDS`` builds of the 3+1 model's normals: the last shard is short), its
      median as the spec, the yield at that spec. The metric is a small smooth function of
      the tolerances and a build's normals, not the encoder model: it checks the sharded
      Monte Carlo at a fraction of the model's compile time in each of the four processes
      (the model's Monte Carlo values on several devices: ``tests/test_cpu.py``);
    * ``grad``: the gradient of a differentiable Monte Carlo mean
      (:func:`expected_value`, the traced path partitioned by XLA) with respect to 7 scales.
      The function is a small smooth one of the scales and a build's normals, not the
      encoder model: it checks the partitioning and its transpose at a fraction of the
      model's compile time (the model's values are checked by ``values``);
    * ``again``: that mean at a point computed from ``grad`` (an output that lives on the
      mesh, as in every solver step); ``mean_mesh_input``: :func:`monte_carlo` of
      tolerances that live on the mesh;
    * ``sds`` (with ``sds``): :func:`sds_residuals` of 5 builds;
    * ``tasks``: 5 tasks dealt round-robin over the processes and gathered.
    """
    import jax
    import jax.numpy as jnp
    import numpy as np

    from encdesign.design._drivers import monte_carlo
    from encdesign.design._sampling import expected_value
    from encdesign.objectives import (
        EncoderDesign,
        SDSTolerances,
        Tolerances,
        n_build_normals,
        sds_residuals,
    )

    design = EncoderDesign(**SCALE_DESIGN)
    tol = Tolerances(**SCALE_TOLERANCES)
    key = jax.random.key(7)
    dim = n_build_normals(design)

    sig0 = np.asarray(list(SCALE_TOLERANCES.values()))

    def metric(t, z):
        r = t.vector() / sig0
        return jnp.sqrt(jnp.sum((r * z[:7]) ** 2) + 0.01 * jnp.sum(z[7:] ** 2))

    mc = monte_carlo(metric, tol, key=key, n=SCALE_BUILDS, dim=dim, chunk_size=32)
    spec = float(np.median(mc.values))
    y, y_se = mc.yield_fraction(spec)

    def toy(s, z):
        r = s / sig0
        return jnp.sum(jnp.log1p((r * z[:7]) ** 2)) + 0.1 * jnp.sin(r[0] * z[7])

    def mean_toy(s):
        return expected_value(toy, s, key=key, n=101, dim=8, chunk_size=16)

    sig = jnp.asarray(sig0)
    grad = jax.jit(jax.grad(mean_toy))(sig)
    again = jax.jit(mean_toy)(sig * (1.0 + 0.1 * jnp.tanh(grad * sig)))
    t_mesh = Tolerances(**dict(zip(SCALE_TOLERANCES, sig * (1.0 + 0.0 * grad))))
    mc_mesh = monte_carlo(metric, t_mesh, key=key, n=SCALE_BUILDS, dim=dim, chunk_size=32)
    tasks = [{"task": i, "by": dist.process_index()} for i in range(5) if dist.is_my_task(i)]
    out = {
        "gathers": _gathers(),
        "tasks": sorted(dist.allgather_objects(tasks), key=lambda t: t["task"]),
        "devices": dist.n_build_shards(),
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
    if sds:
        s = sds_residuals(3, 2, SDSTolerances(), key=key, n_builds=5, marks_per_rev=60, n_phi=8)
        out["sds"] = np.asarray(s).tolist()
    return out


def _gathers() -> dict:
    """Gathers of every size, each process's part made from its index: small ones through
    the runtime's key-value store (``_kv_gather``), one over its bound in compiled pieces."""
    import jax
    import numpy as np

    from encdesign import _kv_gather

    k, n = dist.process_index(), jax.process_count()
    g = dist.store_gather()
    before = (g.through_store, g.compiled) if g is not None else (0, 0)
    rows = dist.allgather_rows(np.arange(6.0).reshape(2, 3) + 10 * k, 2 * n)
    blobs = dist.allgather_bytes(f"p{k}".encode() * (k + 1))
    m = (_kv_gather.CHUNK_BYTES + 3 * _kv_gather.KV_BYTES_MAX) // 8  # two pieces
    big = dist.allgather_concat(
        np.arange(m + 5 * k, dtype=np.int64) + 7 * k, [m + 5 * p for p in range(n)]
    )
    after = (g.through_store, g.compiled) if g is not None else (0, 0)
    return {
        "rows": rows.tolist(),
        "bytes": [b.decode() for b in blobs],
        "big_size": int(big.size),
        "big_sum": int(big.sum()),
        "through_store": after[0] - before[0],
        "compiled": after[1] - before[1],
    }


def _mismatch(out: Path) -> None:
    """Process 0 gathers rows, process 1 bytes: each must raise a DistributedError."""
    import numpy as np

    from encdesign import DistributedError

    try:
        if dist.process_index() == 0:
            dist.allgather_rows(np.zeros((1, 2)), 2)
        else:
            dist.allgather_bytes(b"x")
        msg = "no error"
    except DistributedError as exc:
        msg = f"DistributedError: {exc}"
    Path(f"{out}.p{dist.process_index()}").write_text(msg)


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("out", type=Path)
    p.add_argument("--die", action="store_true")
    p.add_argument("--sds", action="store_true")
    p.add_argument("--mismatch", action="store_true")
    dist.add_launch_flags(p)
    args = p.parse_args()
    dist.initialize(dist.launch_from_args(args), timeout_s=60, heartbeat_s=10)
    if args.die:
        if dist.process_index() == 1:
            os._exit(7)
        dist.barrier("never-complete")
    if args.mismatch:
        _mismatch(args.out)
        dist.shutdown()
        return 0
    out = run_checks(sds=args.sds)
    if dist.is_main_process():
        args.out.write_text(json.dumps(out))
    dist.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
