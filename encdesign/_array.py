"""Array helpers shared by every layer (base, like ``_errors``)."""

from __future__ import annotations

from collections.abc import Sequence

import jax.numpy as jnp
from jax import Array
from jax.core import Tracer
from jax.typing import ArrayLike


def f64(x: ArrayLike | Sequence[ArrayLike] | Sequence[Sequence[ArrayLike]]) -> Array:
    """``x`` as a float64 JAX array (encdesign computes in float64 throughout); ``x`` may be
    an array, a scalar or a (nested) sequence of numbers."""
    return jnp.asarray(x, dtype=jnp.float64)


def is_traced(x: object) -> bool:
    """Whether ``x`` is a JAX tracer (inside ``jit``/``grad``): value checks are skipped then."""
    return isinstance(x, Tracer)


def wrap_rad(x: ArrayLike) -> Array:
    """An angle wrapped to ``[-pi, pi)``, rad."""
    return jnp.mod(x + jnp.pi, 2 * jnp.pi) - jnp.pi
