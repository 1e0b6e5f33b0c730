"""Reference mapping of a multi-head encoder, and its comparison with self-compensation
(Cramer, seed ``000_…`` §VI: a 3+1 encoder against a Heidenhain RON-901).

*Reference mapping*: the symmetric heads' averaged reading minus a reference angle,
``y(θ) = mean_k reading_k − θ_ref``, fitted by least squares with a trigonometric sum of
the orders asked (default ``1 … M``; the map of an N-head average should hold the
degenerate orders ``N, 2N, …`` plus placement leakage), constant removed. The standard
errors of the coefficients come from the residual scatter (white-noise assumption; a
coloured residual makes them optimistic, which :attr:`ReferenceMap.residual_rms_rad`
and the residual's own spectrum let the user judge).

*Self-compensation* (:func:`encdesign.physics.self_compensate`, :func:`encoder_map`)
builds the same map from head differences alone. :func:`compare_maps_on_recording`
does both on a ``multihead`` recording with ``theta_ref`` and reports their difference.

What limits the agreement: the reference angle is the true angle plus the reference
encoder's own errors and those of the coupling between the shafts. Orders of the
reference error that are not in the map's orders drop out of the fit; those at the
degenerate orders pass straight into the reference map (a three-point clamp or a coupling
with three screws puts order 3 there, exactly the order a 3-head map holds).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from .._errors import input_error

__all__ = [
    "MapComparison",
    "ReferenceMap",
    "compare_maps",
    "compare_maps_on_recording",
    "reference_map",
]


@dataclasses.dataclass(frozen=True)
class ReferenceMap:
    """A map from reference mapping (rad).

    Attributes:
        status: ``"ok"``.
        orders: the orders fitted.
        sin_rad, cos_rad: coefficients of those orders, rad.
        sin_se_rad, cos_se_rad: their standard errors, rad.
        offset_rad: fitted constant (the heads' zero against the reference), rad.
        residual_rms_rad: RMS of the fit residual, rad.
        n_samples: samples used.
    """

    status: str
    orders: list[int]
    sin_rad: np.ndarray
    cos_rad: np.ndarray
    sin_se_rad: np.ndarray
    cos_se_rad: np.ndarray
    offset_rad: float
    residual_rms_rad: float
    n_samples: int
    covariance_rad2: np.ndarray

    def __call__(self, theta_rad: np.ndarray) -> np.ndarray:
        """The map ``m(θ)`` (no constant), rad."""
        th = np.asarray(theta_rad, dtype=float)
        j = np.asarray(self.orders, dtype=float)
        return np.sin(th[..., None] * j) @ self.sin_rad + np.cos(th[..., None] * j) @ self.cos_rad

    def band_rad(self, theta_rad: np.ndarray) -> np.ndarray:
        """Standard error of ``m(θ)``, rad."""
        th = np.asarray(theta_rad, dtype=float)
        j = np.asarray(self.orders, dtype=float)
        x = np.concatenate([np.sin(th[..., None] * j), np.cos(th[..., None] * j)], axis=-1)
        c = self.covariance_rad2
        return np.sqrt(np.clip(np.einsum("...i,ij,...j->...", x, c, x), 0.0, None))


def reference_map(
    theta_ref_rad: np.ndarray,
    averaged_reading_rad: np.ndarray,
    max_order: int,
    *,
    orders: Sequence[int] | None = None,
) -> ReferenceMap:
    """Map the averaged reading against a reference angle (see module doc).

    Args:
        theta_ref_rad: reference angle per sample, rad, ``(n,)``.
        averaged_reading_rad: the symmetric heads' averaged reading, rad, ``(n,)``
            (unwrapped like ``theta_ref``).
        max_order: highest order (used when ``orders`` is not given: ``1 … max_order``).
        orders: the orders to fit (e.g. ``[3, 6, 9]`` for the degenerate modes).

    Returns:
        :class:`ReferenceMap`.
    """
    th = np.asarray(theta_ref_rad, dtype=float).reshape(-1)
    y = np.asarray(averaged_reading_rad, dtype=float).reshape(-1) - th
    if th.size != y.size:
        raise input_error("reference_map", f"{th.size} angles, {y.size} readings", "equal sizes")
    if not (np.all(np.isfinite(th)) and np.all(np.isfinite(y))):
        raise input_error("reference_map", "non-finite angle or reading", "finite samples")
    ords = list(range(1, int(max_order) + 1)) if orders is None else [int(k) for k in orders]
    if not ords or min(ords) < 1 or len(set(ords)) != len(ords):
        raise input_error("reference_map orders", f"got {ords}", "distinct orders >= 1")
    n_par = 2 * len(ords) + 1
    if th.size < n_par + 2:
        raise input_error("reference_map", f"{th.size} samples", f"at least {n_par + 2}")
    j = np.asarray(ords, dtype=float)
    x = np.concatenate([np.sin(th[:, None] * j), np.cos(th[:, None] * j), np.ones((th.size, 1))], 1)
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    resid = y - x @ coef
    dof = th.size - n_par
    s2 = float(resid @ resid) / dof
    cov = s2 * np.linalg.pinv(x.T @ x)
    m = len(ords)
    se = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    return ReferenceMap(
        status="ok",
        orders=ords,
        sin_rad=coef[:m],
        cos_rad=coef[m : 2 * m],
        sin_se_rad=se[:m],
        cos_se_rad=se[m : 2 * m],
        offset_rad=float(coef[-1]),
        residual_rms_rad=float(math.sqrt(np.mean(resid**2))),
        n_samples=int(th.size),
        covariance_rad2=cov[: 2 * m, : 2 * m],
    )


@dataclasses.dataclass(frozen=True)
class MapComparison:
    """Self-compensation against reference mapping (rad; curves on ``theta_rad``).

    Attributes:
        theta_rad: angles of the curves.
        raw_error_rad: one symmetric head's error against the reference (constant removed).
        selfcomp_map_rad, reference_map_rad: the two maps (constant removed).
        reference_band_rad: standard error of the reference map.
        difference_rad: ``selfcomp − reference``.
        raw_amplitude_rad, selfcomp_amplitude_rad, reference_amplitude_rad: half
            peak-to-peak of the curves.
        max_difference_rad: ``max |difference|``.
    """

    theta_rad: np.ndarray
    raw_error_rad: np.ndarray
    selfcomp_map_rad: np.ndarray
    reference_map_rad: np.ndarray
    reference_band_rad: np.ndarray
    difference_rad: np.ndarray
    raw_amplitude_rad: float
    selfcomp_amplitude_rad: float
    reference_amplitude_rad: float
    max_difference_rad: float


def _half_pp(x: np.ndarray) -> float:
    return float(0.5 * (np.max(x) - np.min(x)))


def compare_maps(
    theta_ref_rad: np.ndarray,
    readings_rad: np.ndarray,
    head_angles_rad: Sequence[float],
    reference_head: int,
    *,
    max_order: int = 12,
    n_curve: int = 720,
) -> MapComparison:
    """Build the map by self-compensation and by reference mapping and compare them.

    Args:
        theta_ref_rad: reference angle per sample, rad, ``(n,)``; samples should cover
            whole revolutions.
        readings_rad: head readings, rad, ``(n, H)``.
        head_angles_rad: nominal azimuths of the ``H`` heads, rad.
        reference_head: index of the asymmetric reference head; the others are averaged.
        max_order: highest order of both maps.
        n_curve: points of the returned curves over one turn.
    """
    import jax.numpy as jnp

    from ..physics._selfcomp import encoder_map, self_compensate

    y = np.asarray(readings_rad, dtype=float)
    angles = np.asarray(head_angles_rad, dtype=float).reshape(-1)
    th = np.asarray(theta_ref_rad, dtype=float).reshape(-1)
    if y.ndim != 2 or y.shape != (th.size, angles.size):
        raise input_error(
            "compare_maps readings_rad", f"shape {y.shape}", f"({th.size}, {angles.size})"
        )
    if not 0 <= reference_head < angles.size or angles.size < 3:
        raise input_error(
            "compare_maps reference_head",
            f"got {reference_head} with {angles.size} heads",
            "an index of one of >= 3 heads",
        )
    sym = [k for k in range(angles.size) if k != reference_head]
    avg = y[:, sym].mean(axis=1)
    sc = self_compensate(
        jnp.asarray(avg), jnp.asarray(y), jnp.asarray(angles), reference_head, max_order
    )
    emap = encoder_map(sc, jnp.asarray(angles[sym]))
    rmap = reference_map(th, avg, max_order)
    grid = 2 * np.pi * np.arange(n_curve) / n_curve
    m_sc = np.asarray(emap(jnp.asarray(grid)))
    m_ref = rmap(grid)
    m_sc = m_sc - m_sc.mean()
    m_ref = m_ref - m_ref.mean()
    raw = reference_map(th, y[:, sym[0]], max_order)(grid)
    raw = raw - raw.mean()
    diff = m_sc - m_ref
    return MapComparison(
        theta_rad=grid,
        raw_error_rad=raw,
        selfcomp_map_rad=m_sc,
        reference_map_rad=m_ref,
        reference_band_rad=rmap.band_rad(grid),
        difference_rad=diff,
        raw_amplitude_rad=_half_pp(raw),
        selfcomp_amplitude_rad=_half_pp(m_sc),
        reference_amplitude_rad=_half_pp(m_ref),
        max_difference_rad=float(np.max(np.abs(diff))),
    )


def compare_maps_on_recording(rec, *, max_order: int = 12, n_curve: int = 720) -> MapComparison:
    """:func:`compare_maps` on a ``multihead`` recording with ``theta_ref`` and a
    ``reference_head`` (runs concatenated; each head's constant is irrelevant)."""
    where = str(rec.path) if rec.path is not None else "recording"
    if rec.kind != "multihead":
        raise input_error(where, f"kind {rec.kind!r}", "a multihead recording")
    if "theta_ref" not in rec.columns:
        raise input_error(where, "no theta_ref column", "a reference angle (theta_ref)")
    enc = rec.encoder
    if "reference_head" not in enc:
        raise input_error(f"{where}: [encoder]", "no reference_head", "the asymmetric head")
    angles = np.deg2rad(np.asarray(enc["head_angles_deg"], dtype=float))
    return compare_maps(
        rec.columns["theta_ref"],
        rec.heads(),
        angles,
        int(enc["reference_head"]),
        max_order=max_order,
        n_curve=n_curve,
    )
