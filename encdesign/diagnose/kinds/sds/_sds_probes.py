"""Detection-bound probes of the sds kind's platform and motor effects (issue 44 F):
``axis_tilt``, ``bearing_wobble``, ``beam_tilt_axial`` and ``coil_mismatch``, each a unit-size
effect with its nonlinear parameters held at a stated value (``Probe.at``), attached to the
catalog candidates of :mod:`._sds_terms` that offer none (``engine._bounds`` computes the
bounds; the delay step's and the drift's probes live with their terms).

These effects are constant over a run's revolutions or nearly so (a function of the platform
angle ``phi + psi_m``): their run means are what the run-mean noise level is estimated from,
so each probe says how much of it that estimate takes (``_run_mean_seen``, of the effect's
own run means)."""

from __future__ import annotations

import dataclasses
import functools

import jax.numpy as jnp
import numpy as np

from ...engine._candidates import Candidate, Context, Probe
from ._sds_noise import BEAM_ORDERS, _sensor_helmert
from ._sds_terms import _jx, _run_mean_seen

TILT_PROBE_RAD = 2e-3
"""The tilt the axis tilt's probe is evaluated at (rad): its error ``T`` is ``beta^2 / 4``
times ``sin 2(x - chi)`` to ``beta^2 / 4`` relative, so the bound, on ``beta^2 / 4``, is
linear there."""

TILT_PROBE_AZIMUTHS_RAD = (0.0, np.pi / 4)
"""Azimuths of the tilt probed (the worst of them): the order-2 pattern in cosine and in
sine phase."""

WOBBLE_PROBE_RATIO = 0.45
"""The frequency ratio of the bearing wobble probed: the upper end of a ball bearing's cage
ratios (0.35-0.45), where the window's ``sinc`` attenuates it most (probing both ends, the
upper one was the larger bound; one probe halves the matched view's cost)."""


def _contrast_parts(v: np.ndarray, M: int) -> list[tuple[float, int]]:
    """``(power, values)`` of the whitened revolution contrasts ``v[:, M:]`` in each part
    the contrast level is estimated from (``_level_sigma``: common to the moving sensors,
    and their differences)."""
    R, C = v.shape
    if C <= M:
        return []
    z = v[:, M:].reshape(R, C // M - 1, M) @ _sensor_helmert(M)
    parts = [z[..., :1]] + ([z[..., 1:]] if M > 1 else [])
    return [(float(np.sum(x * x)), int(x.size)) for x in parts]


def _seen(ctx: Context, cand: Candidate, values: dict):
    """``seen(lam)`` of the effect at ``values``, whose two noise levels it inflates: its
    run means (a share ``s`` of its whitened power) as ``_run_mean_seen`` says (a smooth
    pattern, not caught by the level's step test); its revolution contrasts through their
    level, a robust scale of ``n`` values per part (common, differences; the larger is
    used), which an effect carrying ``lam_p`` there widens by ``1 + lam_p / n`` in variance
    (the tests then see ``lam_c / max_p(1 + lam_p / n_p)`` of them)."""
    M = int(ctx.consts["psi_m"].size)
    p = {k: jnp.asarray(v, float) for k, v in values.items()}
    v = np.asarray(cand.fn(p, _jx(ctx))) / np.asarray(ctx.noise, float)[None, :]
    total = float(np.sum(v * v))
    if not total > 0:
        return None
    inner = _run_mean_seen(ctx, v[:, :M], caught=False)
    s = float(np.sum(v[:, :M] ** 2)) / total
    parts = [(pw / total, n) for pw, n in _contrast_parts(v, M) if n > 0]

    def seen(lam: float) -> float:
        widen = max([1.0] + [1.0 + f * lam / n for f, n in parts])
        run_means = s * lam if inner is None else inner(s * lam) if s > 0 else 0.0
        return (1.0 - s) * lam / widen + run_means

    return seen


def _probe(ctx: Context, cand: Candidate, values: dict, parameter: str, unit: str, **kw):
    return Probe(values, parameter, unit, seen=_seen(ctx, cand, values), **kw)


def _worst(probes: list[Probe]) -> list[Probe]:
    return [dataclasses.replace(probes[0], worst_of=tuple(probes[1:]))] if probes else []


def _tilt_probes(cand: Candidate, ctx: Context) -> list[Probe]:
    """An axis tilt with ``beta^2 / 4`` of 1 rad (evaluated at :data:`TILT_PROBE_RAD`), at
    the worst of :data:`TILT_PROBE_AZIMUTHS_RAD`."""
    size = TILT_PROBE_RAD**2 / 4
    at = "any azimuth (the worst of 0 and 45 deg); the tilt is 2 sqrt(bound) rad"
    return _worst(
        [
            _probe(
                ctx,
                cand,
                {"tilt_rad": np.asarray(TILT_PROBE_RAD), "azimuth_rad": np.asarray(chi)},
                "tilt_squared_over_4_rad",
                "rad",
                at=at,
                size=size,
            )
            for chi in TILT_PROBE_AZIMUTHS_RAD
        ]
    )


def _wobble_probes(cand: Candidate, ctx: Context) -> list[Probe]:
    """A bearing wobble of amplitude 1 rad (before the window's ``sinc`` attenuation, as
    ``amplitude_rad`` is reported) in every run, at :data:`WOBBLE_PROBE_RATIO`."""
    rho = WOBBLE_PROBE_RATIO
    at = f"frequency ratio {rho:g} (a cage ratio's upper end: the most attenuated), every run"
    vals = {
        "frequency_ratio": np.asarray(rho),
        "sin_rad": np.asarray(1.0),
        "cos_rad": np.asarray(0.0),
        "first_run": np.asarray(0.0),
    }
    return [_probe(ctx, cand, vals, "amplitude_rad", "rad", at=at)]


def _order_probes(cand: Candidate, ctx: Context, orders: list[int], what: str) -> list[Probe]:
    """An error of 1 rad (cosine) at each of ``orders`` of the candidate's Fourier term, the
    worst of them."""
    n = cand.size(1, 1) // 2  # cos_rad and sin_rad, one per order
    at = f"{what} (the worst of orders {', '.join(str(o) for o in orders)})"
    return _worst(
        [
            _probe(
                ctx,
                cand,
                {"cos_rad": np.eye(n)[j], "sin_rad": np.zeros(n)},
                "amplitude_rad",
                "rad",
                at=at,
            )
            for j in range(len(orders))
        ]
    )


def _beam_probes(cand: Candidate, ctx: Context) -> list[Probe]:
    """Beam tilt x axial runout at each of its orders in ``phi``, the worst of them."""
    return _order_probes(cand, ctx, list(BEAM_ORDERS), "an error common to the moving sensors")


def _coil_probes(cand: Candidate, ctx: Context) -> list[Probe]:
    """Coil mismatch at its lowest order (1: the largest of a torque ripple's speed ripple,
    about ripple / (order x inertia))."""
    return _order_probes(cand, ctx, [1], "order 1 of phi + psi_m")


PROBES = {
    "axis_tilt": _tilt_probes,
    "bearing_wobble": _wobble_probes,
    "beam_tilt_axial": _beam_probes,
    "coil_mismatch": _coil_probes,
}
"""The probes this module gives, by candidate name."""


@functools.lru_cache(maxsize=32)
def with_probes(cands: tuple[Candidate, ...]) -> tuple[Candidate, ...]:
    """``cands`` with the probes of :data:`PROBES` attached to those that offer none (the
    same objects on every call for one catalog: one compiled Jacobian per candidate)."""
    return tuple(
        dataclasses.replace(c, probes=functools.partial(PROBES[c.name], c))
        if c.probes is None and c.name in PROBES
        else c
        for c in cands
    )


__all__ = ["PROBES", "with_probes"]
