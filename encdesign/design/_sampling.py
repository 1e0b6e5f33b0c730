"""Sampling: the common random numbers of Monte Carlo builds, grids and Latin hypercubes.

Build ``i`` of key ``k`` is always the same standard-normal vector ``normal(fold_in(k, i))``,
whatever the chunking, so expected objectives (:func:`expected_value`) are smooth,
deterministic functions of the design and can be differentiated.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from numpy.typing import ArrayLike

from .._distributed import shard_builds

MC_CHUNK = 4096
"""Default builds per device in one compiled Monte Carlo chunk."""


def build_normals(key: jax.Array, index: jax.Array, dim: int) -> jax.Array:
    """Standard-normal vectors of builds ``index`` (any shape) for ``key``: ``[..., dim]``.

    Build ``i`` is ``normal(fold_in(key, i), (dim,))``: the same for any chunking, which
    is what makes the random numbers common between designs.
    """
    flat = jnp.ravel(index)
    z = jax.vmap(lambda i: jax.random.normal(jax.random.fold_in(key, i), (dim,)))(flat)
    # materialise z: without the barrier XLA may fuse the random-number generation into
    # every elementwise consumer and recompute it per reading (measured: the Monte Carlo
    # objective ran 1.8x slower)
    return jax.lax.optimization_barrier(z.reshape((*jnp.shape(index), dim)))


VECTOR_BUILDS = 8  # builds vectorised together: a working set that stays in the CPU caches


def values_of_normals(fn_z: Callable[[jax.Array], jax.Array], z: jax.Array, vector: int):
    """``fn_z`` on every row of ``z [B, dim]`` (``B`` a multiple of ``vector``): ``lax.map``
    over groups of ``vector`` rows, ``vmap`` within a group; returns ``[B]``."""
    groups = z.reshape(-1, vector, z.shape[-1])
    return jax.lax.map(jax.vmap(fn_z), groups).reshape(-1)


def map_builds(
    fn_z: Callable[[jax.Array], jax.Array],
    key: jax.Array,
    n: int,
    dim: int,
    *,
    first: int = 0,
    block: int = 512,
    vector: int = VECTOR_BUILDS,
    manual: bool = False,
) -> jax.Array:
    """Traceable per-build values ``fn_z(z_i)`` for builds ``first … first + n - 1`` of
    ``key`` (:func:`build_normals`), ``[n]``.

    Memory is bounded at any ``n``: the random numbers are drawn ``block`` builds at a
    time (rounded up to a multiple of ``vector``) and the builds are vectorised ``vector``
    at a time (small groups keep the working set in the CPU caches: measured fastest for
    values and gradients alike). Drawing the numbers per block rather than inside the
    innermost loop matters: XLA compiles that loop markedly slower (1.8x) when it also
    draws random numbers.

    The builds are split over the devices of the ``"builds"`` mesh (all devices of all
    processes, or the one set with :func:`jax.set_mesh`;
    :func:`encdesign.design.shard_builds`): each device evaluates ``ceil(n / D)``
    consecutive builds in the same blocks, and the values are gathered in build order.
    Build ``i`` depends only on ``fold_in(key, first + i)``, so the result is that of one
    device (to rounding in the compiled code). With one device nothing changes.
    ``manual``: the ``shard_map`` path of :func:`~encdesign.design.shard_builds` (only when
    ``fn_z`` closes over no array that lives on a mesh).
    """
    return shard_builds(
        lambda offset, m: local_builds(fn_z, key, m, dim, first + offset, block, vector),
        n,
        manual=manual,
    )


def local_builds(fn_z, key, n: int, dim: int, first: Any, block: int, vector: int):
    """:func:`map_builds` on one device: builds ``first … first + n - 1`` (``first`` may be
    traced)."""
    vector = int(max(1, min(vector, n)))
    n_groups = -(-n // vector)
    per_block = int(max(1, min(n_groups, -(-int(block) // vector))))
    size = per_block * vector
    n_blocks = -(-n // size)

    def one_block(b):
        z = build_normals(key, first + b * size + jnp.arange(size), dim)
        return values_of_normals(fn_z, z, vector)

    return jax.lax.map(one_block, jnp.arange(n_blocks)).reshape(-1)[:n]


def _chunked_values(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int,
) -> jax.Array:
    """Per-build values ``fn(theta, z_i)`` for builds ``0 … n-1`` (:func:`map_builds`:
    random numbers drawn ``chunk_size`` builds at a time, so memory is bounded by one
    chunk)."""
    return map_builds(lambda z: fn(theta, z), key, n, dim, block=chunk_size)


def expected_value(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    *,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int = MC_CHUNK,
) -> jax.Array:
    """Differentiable Monte Carlo mean of ``fn(theta, z)`` over builds ``0 … n-1`` of ``key``.

    Traceable (use inside ``jax.grad``/``jax.jit``); chunked with ``lax.map`` so memory is
    bounded by one chunk. The builds are common random numbers (see
    :func:`build_normals`), so the estimate is a smooth function of ``theta``.
    """
    return jnp.mean(_chunked_values(fn, theta, key, n, dim, chunk_size))


def expected_values(
    fn: Callable[[Any, jax.Array], jax.Array],
    theta: Any,
    *,
    key: jax.Array,
    n: int,
    dim: int,
    chunk_size: int = MC_CHUNK,
) -> jax.Array:
    """Traceable per-build values ``[n]`` of ``fn(theta, z_i)`` (see :func:`expected_value`)."""
    return _chunked_values(fn, theta, key, n, dim, chunk_size)


def grid_points(lower: ArrayLike, upper: ArrayLike, n_per_dim: ArrayLike) -> np.ndarray:
    """Full-factorial grid ``[prod(n), d]`` between ``lower`` and ``upper`` (inclusive)."""
    lo = np.atleast_1d(np.asarray(lower, dtype=np.float64))
    hi = np.atleast_1d(np.asarray(upper, dtype=np.float64))
    ns = np.broadcast_to(np.asarray(n_per_dim, dtype=int), lo.shape)
    axes = [np.linspace(a, b, int(k)) for a, b, k in zip(lo, hi, ns)]
    return np.array(list(itertools.product(*axes)), dtype=np.float64).reshape(-1, lo.size)


def latin_hypercube(key: jax.Array, lower: ArrayLike, upper: ArrayLike, n: int) -> np.ndarray:
    """Latin hypercube sample ``[n, d]``: each variable's range cut into ``n`` equal strata,
    one point per stratum, strata paired at random (``key``), uniform inside a stratum."""
    lo = np.atleast_1d(np.asarray(lower, dtype=np.float64))
    hi = np.atleast_1d(np.asarray(upper, dtype=np.float64))
    d = lo.size
    k_perm, k_u = jax.random.split(key)
    perms = jax.vmap(lambda k: jax.random.permutation(k, n))(jax.random.split(k_perm, d))
    u = jax.random.uniform(k_u, (d, n), dtype=jnp.float64)
    frac = (np.asarray(perms).astype(np.float64) + np.asarray(u)) / n
    return lo + frac.T * (hi - lo)
