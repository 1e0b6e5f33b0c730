"""Sobol first-order and total indices of a per-build output by tolerance group
(``scipy.stats.sobol_indices`` on encdesign builds): which tolerances the residual's
variance comes from."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error

ValuesFn = Callable[[jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True)
class SobolIndices:
    """Sobol first-order and total indices of a per-build output, per tolerance group.

    Attributes:
        names: group names.
        first: first-order index ``S_g`` (share of the variance explained by group ``g``
            alone), variance-weighted over the output's components.
        total: total index ``S_Tg`` (share involving group ``g``, interactions included).
        n: base samples (``n (d + 2)`` builds were evaluated).
        n_builds: builds evaluated.
    """

    names: tuple[str, ...]
    first: np.ndarray
    total: np.ndarray
    n: int
    n_builds: int

    def as_dict(self) -> dict[str, dict[str, float]]:
        """``{"first": {name: S}, "total": {name: S_T}}``."""
        return {
            "first": {k: float(v) for k, v in zip(self.names, self.first)},
            "total": {k: float(v) for k, v in zip(self.names, self.total)},
        }


def sobol_indices(
    outputs_z: Callable[[jax.Array], jax.Array],
    groups: Sequence[int],
    names: Sequence[str],
    *,
    key: jax.Array,
    n: int = 512,
    chunk_size: int = 256,
) -> SobolIndices:
    """Sobol indices of ``outputs_z(z)`` (a per-build vector, e.g. the residual at every
    shaft angle, rad) with respect to tolerance groups, by :func:`scipy.stats.sobol_indices`.

    The group ``g`` of a build is the set of components ``z_c`` with ``groups[c] == g``
    (``-1``: none); the Saltelli matrices are built per group (``AB_g`` = ``A`` with group
    ``g``'s columns from ``B``), evaluated with encdesign's vectorised builds and handed to
    scipy as precomputed evaluations. Indices of the output's components are combined
    weighted by their variances, so for an output linear in the deviations the first-order
    index equals the variance share of :func:`contributions` (``V = E[mean-square]``);
    interactions make ``first < total``.

    Args:
        outputs_z: per-build outputs ``[s]`` of a standard-normal vector ``z [dim]`` (JAX).
        groups: group index of each component of ``z``.
        names: group names (``len = d``).
        key: PRNG key of ``A`` and ``B``.
        n: base samples, a power of two (scipy's requirement).
        chunk_size: builds per jitted call.
    """
    from scipy.stats import sobol_indices as _scipy_sobol

    from ._sampling import build_normals

    gidx = np.asarray(groups, dtype=int)
    dim, d = gidx.size, len(names)
    if n < 2 or n & (n - 1):
        raise input_error("sobol_indices.n", f"{n!r}", "a power of two >= 2")
    ka, kb = jax.random.split(key)
    a = np.asarray(build_normals(ka, jnp.arange(n), dim))
    b = np.asarray(build_normals(kb, jnp.arange(n), dim))
    vec = 8
    size = -(-chunk_size // vec) * vec
    f = jax.jit(lambda zc: values_of_normals_vec(outputs_z, zc, vec))

    def run(z: np.ndarray) -> np.ndarray:  # -> (s, n)
        out = []
        for s0 in range(0, z.shape[0], size):
            zc = z[s0 : s0 + size]
            pad = size - zc.shape[0]
            zc = np.concatenate([zc, np.zeros((pad, dim))]) if pad else zc
            out.append(np.asarray(f(jnp.asarray(zc)))[: size - pad])
        return np.concatenate(out).T

    f_a, f_b = run(a), run(b)
    f_ab = []
    for g in range(d):
        ab = a.copy()
        cols = gidx == g
        ab[:, cols] = b[:, cols]
        f_ab.append(run(ab))
    res = _scipy_sobol(func={"f_A": f_a, "f_B": f_b, "f_AB": np.stack(f_ab)}, n=n)
    var = np.var(np.concatenate([f_a, f_b], axis=1), axis=1)  # (s,)
    wts = var / np.sum(var)
    first = np.asarray(res.first_order).reshape(-1, d)
    total = np.asarray(res.total_order).reshape(-1, d)
    return SobolIndices(tuple(names), wts @ first, wts @ total, n, n * (d + 2))


def values_of_normals_vec(fn_z: Callable[[jax.Array], jax.Array], z: jax.Array, vector: int):
    """Vector-valued :func:`~encdesign.design._drivers.values_of_normals`: ``fn_z`` on every
    row of ``z [B, dim]``, ``lax.map`` over groups of ``vector`` rows; returns ``[B, s]``."""
    groups = z.reshape(-1, vector, z.shape[-1])
    out = jax.lax.map(jax.vmap(fn_z), groups)
    return out.reshape(-1, out.shape[-1])
