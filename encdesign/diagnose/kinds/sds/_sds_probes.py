"""Detection-bound probes of the sds kind's platform and motor effects (issue 44 F):
``axis_tilt``, ``bearing_wobble``, ``beam_tilt_axial`` and ``coil_mismatch``, each a unit-size
effect with its nonlinear parameters held at a stated value (``Probe.at``), attached to the
catalog candidates of :mod:`._sds_terms` that offer none (``engine._bounds`` computes the
bounds; the delay step's and the drift's probes live with their terms).

These effects reach the values the noise levels are estimated from (their run means, and the
wobble's revolution contrasts), so each probe says how much of the effect those estimates
take by re-running them with the effect added (``_seen``)."""

from __future__ import annotations

import dataclasses
import functools
import math

import numpy as np

from ...engine._candidates import Candidate, Context, Probe
from ._sds_noise import BEAM_ORDERS, levels_of, noise_info

TILT_PROBE_RAD = 2e-3
"""The tilt the axis tilt's probe is evaluated at (rad): its error ``T`` is ``beta^2 / 4``
times ``sin 2(x - chi)`` to ``beta^2 / 4`` relative, so the bound, on ``beta^2 / 4``, is
linear there."""

TILT_PROBE_AZIMUTHS_RAD = (0.0, np.pi / 8, np.pi / 4, 3 * np.pi / 8)
"""Azimuths of the tilt probed (the worst of them): the order-2 pattern in cosine and in
sine phase and half way between (the pattern repeats every 90 deg of azimuth, with its
sign flipped). Their own bounds differ by up to ~1.7x on 8-run benches (``each``): an
effect of a known azimuth is read against the nearest one."""

WOBBLE_PROBE_RATIO = 0.45
"""The frequency ratio of the bearing wobble probed: the upper end of a ball bearing's cage
ratios (0.35-0.45), where the window's ``sinc`` attenuates it most (probing both ends, the
upper one was the larger bound; one probe halves the matched view's cost)."""


def _seen_of(ctx: Context):
    """``seen_of(e, lam_unit) -> seen(lam)`` (:class:`Probe`) of an effect whose model residual
    is ``e`` (n, C) on the kept rows: the effect inflates the kind's two noise levels (run
    means, revolution contrasts), so at each trial ``lam`` the noise stage's own estimate
    (``levels_of``: the saturated fit, its step and outlier tests, the robust contrast
    scales, the widening for its dof) is re-run on the base residual plus ``e`` at the size
    giving ``lam``; the tests see each channel's share of ``lam`` at the squared ratio of the
    base levels to the inflated ones. No first-order variance approximation: an effect
    several times the level widens it as much as the estimator does."""
    levels = levels_of(ctx)
    base = noise_info(ctx).base_resid
    noise = np.asarray(ctx.noise, float)

    def seen_of(e: np.ndarray, lam_unit: float):
        e = np.asarray(e, float)
        share = np.sum((e / noise[None, :]) ** 2, 0)
        total = float(share.sum())
        if levels is None or base is None or base.shape != e.shape or not total > 0:
            return None
        share = share / total
        estimate, resid0 = levels, base  # narrowed: not None past the check above
        s0 = estimate(resid0)

        @functools.lru_cache(maxsize=4096)
        def seen(lam: float) -> float:
            if lam <= 0:
                return 0.0
            s1 = estimate(resid0 + math.sqrt(lam / total) * e)
            return float(lam * np.sum(share * (s0 / s1) ** 2))

        return seen

    return seen_of


def _probe(ctx: Context, cand: Candidate, values: dict, parameter: str, unit: str, **kw):
    return Probe(values, parameter, unit, seen_of=_seen_of(ctx), **kw)


def _worst(probes: list[Probe]) -> list[Probe]:
    return [dataclasses.replace(probes[0], worst_of=tuple(probes[1:]))] if probes else []


def _tilt_probes(cand: Candidate, ctx: Context) -> list[Probe]:
    """An axis tilt with ``beta^2 / 4`` of 1 rad (evaluated at :data:`TILT_PROBE_RAD`), at
    the worst of :data:`TILT_PROBE_AZIMUTHS_RAD`."""
    size = TILT_PROBE_RAD**2 / 4
    at = "any azimuth (the worst of 0, 22.5, 45 and 67.5 deg); the tilt is 2 sqrt(bound) rad"
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
                label=f"azimuth {math.degrees(chi):g} deg",
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
                label=f"order {orders[j]}",
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
