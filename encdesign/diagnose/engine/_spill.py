"""Whether a candidate's gain is its own or a part of a larger located structure it leaves
(stage 4, :mod:`._select`): its gain once that structure is fitted with the model."""

from __future__ import annotations

import jax.numpy as jnp

from ._candidates import Candidate, Param
from ._fit import make_term

TRIAL_STEPS = 12
"""Levenberg-Marquardt steps of each fit (as the trial fits of stage 4)."""


def _lines(orders: list[int], n_channels: int, theta: str) -> Candidate:
    """Free lines at integer shaft ``orders`` on every channel (cos / sin per order and
    channel): another effect's located orders, not a catalog effect."""
    m = jnp.asarray(orders, dtype=float)
    shape = (len(orders), n_channels)

    def fn(p, x):
        arg = x[theta][:, None] * m[None, :]
        return jnp.cos(arg) @ p["cos_rad"] + jnp.sin(arg) @ p["sin_rad"]

    return Candidate(
        "located lines",
        fn,
        (Param("cos_rad", "rad", shape), Param("sin_rad", "rad", shape)),
        signature=("orders",),
    )


def kept_gain_share(prep, fitter, base: list, term, orders) -> float | None:
    """The share of the chi-square ``term`` (a fitted candidate) takes out beside ``base``
    (the model so far, its parameters free as in its own fit) that it still takes once free
    lines at the integer shaft ``orders`` are fitted with them; ``None`` without orders, a
    shaft angle or a gain.

    A small structure that a larger unmodelled one makes through the base model (an
    out-of-catalog order on one head, without a reference, moves the fitted shaft angle and
    shows at the disk error's orders less its own) is gone once the larger one is fitted: a
    candidate fitted to it keeps little of its gain. A structure of its own keeps it."""
    rows = prep.rows
    theta = "theta_eff" if "theta_eff" in rows else "theta"
    if not orders or theta not in rows:
        return None
    c0 = fitter.fit(list(base), max_steps=TRIAL_STEPS).chi2
    g0 = c0 - fitter.fit([*base, term], max_steps=TRIAL_STEPS).chi2
    if g0 <= 0:
        return None
    lines = make_term(_lines(sorted(orders), prep.n_channels, theta), prep)
    c1 = fitter.fit([*base, lines], max_steps=TRIAL_STEPS).chi2
    g1 = c1 - fitter.fit([*base, lines, term], max_steps=TRIAL_STEPS).chi2
    return g1 / g0
