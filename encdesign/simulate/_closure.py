"""Dual-closure bench simulator: the readings of a polygon-and-autocollimator closure test
(``docs/calibration.md``) on an instrument with a given error function.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import input_error
from ..calibrate._closure import closure_null_angles

__all__ = ["simulate_closure_readings"]


def simulate_closure_readings(
    instrument_error: Callable[[np.ndarray], np.ndarray],
    n_faces: int,
    setting_positions: Sequence[int] | np.ndarray,
    *,
    face_error_rad: np.ndarray,
    setting_offset_rad: np.ndarray,
    sigma_reading_rad: float,
    key: jax.Array,
) -> np.ndarray:
    """Readings of a simulated dual-closure test, ``(S, N + 1)``, rad in ``[0, 2π)``.

    Each null: the true platform angle (:func:`closure_null_angles`) plus the
    instrument's error there (``instrument_error(angles_rad) -> error_rad``, any shape)
    plus white reading noise of standard deviation ``sigma_reading_rad`` drawn from
    ``key``.
    """
    phi = closure_null_angles(n_faces, setting_positions, face_error_rad, setting_offset_rad)
    err = np.asarray(instrument_error(phi), dtype=float)
    if err.shape != phi.shape or not np.all(np.isfinite(err)):
        raise input_error(
            "simulate_closure_readings instrument_error",
            f"returned shape {err.shape} (finite: {bool(np.all(np.isfinite(err)))})",
            f"finite errors of shape {phi.shape}",
        )
    noise = np.asarray(jax.random.normal(key, phi.shape, dtype=jnp.float64))
    return np.mod(phi + err + sigma_reading_rad * noise, 2 * np.pi)
