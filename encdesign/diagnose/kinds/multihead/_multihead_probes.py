"""Detection-bound probes of the multihead kind's runout effects (issue 44 F):
``beam_tilt_axial``, ``bearing_wobble`` and ``eccentricity_shift``, each a unit-size effect
with its nonlinear parameters held at a stated value (``Probe.at``), attached to the
catalog candidates of :mod:`._multihead_terms` (``engine._bounds`` computes the bounds)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ...engine._candidates import Context, Probe
from ...engine._normal import register_factors
from ._beam_tilt import bt_factors
from ._multihead_terms import BEAM_TILT_AXIAL as _BT
from ._multihead_terms import BEAM_TILT_AXIAL_NO_REF as _BT_NO_REF
from ._multihead_terms import BEARING_WOBBLE as _WB
from ._multihead_terms import ECCENTRICITY_SHIFT as _ES

WOBBLE_PROBE_FRACTION = 0.5
"""The bearing wobble's bound is stated at a fractional order ``n + 0.5`` (half way between
the integer orders the base model fits), ``n`` the smallest whole number for which the
longest run holds ``wobble_cycles_min`` cycles of it (the finder's own rule)."""

SHIFT_PROBE_QUANTILES = (0.25, 0.5, 0.75)
"""An eccentricity shift's bound is stated for a shift anywhere in the middle half of the
kept samples (in file order): the worst of its ends and its middle."""


def _names(ctx: Context) -> list[str]:
    C = ctx.n_channels
    return list(ctx.data.channel_names) if ctx.data is not None else [f"h{k}" for k in range(C)]


def _bt_probes(ctx: Context) -> list[Probe]:
    """Per head, an axial-runout error of 1 rad at runout order 1 (``cos(theta)``, no
    head-angle phase) on that head alone, the finder's fitted orders held at order 1 (those
    its views locate); the bound is on its head-specific part (what the base's disk error,
    and without theta_ref the head mean, cannot take)."""
    C = ctx.n_channels
    out = []
    for k, name in enumerate(_names(ctx)):
        vals = {f"{cs}{j}_rad": np.zeros(C) for cs in ("cos", "sin") for j in (1, 2, 3)}
        vals["cos1_rad"] = np.eye(C)[k]
        vals["orders_on"] = np.array([1.0, 0.0, 0.0])
        at = "runout order 1 (orders fitted held at those located: order 1)"
        out.append(Probe(vals, "amplitude_rad", "rad", where=name, at=at))
    return out


def wobble_probe_ratio(ctx: Context) -> float:
    """The fractional order the bearing wobble's bound is stated at
    (:data:`WOBBLE_PROBE_FRACTION`)."""
    revs = float(np.max(ctx.revolutions))
    if not revs > 0:
        return WOBBLE_PROBE_FRACTION
    n = max(0, math.ceil(ctx.settings.wobble_cycles_min / revs - WOBBLE_PROBE_FRACTION))
    return n + WOBBLE_PROBE_FRACTION


def _wb_probes(ctx: Context) -> list[Probe]:
    """A radial runout of 1 m (``runout_a_m``, every run its own phase: the same size in
    every run) at a fractional order (:func:`wobble_probe_ratio`), seen by every head."""
    R = ctx.n_runs
    nu = wobble_probe_ratio(ctx)
    vals = {
        "frequency_ratio": np.asarray(nu),
        "runout_a_m": np.ones(R),
        "runout_b_m": np.zeros(R),
    }
    return [Probe(vals, "runout_m", "m", at=f"order {nu:g} (frequency ratio, held)")]


def _es_probes(ctx: Context) -> list[Probe]:
    """A shift of the disk centre by 1 m (x, and the worst of x and y) at a time in the
    middle half of the kept samples (:data:`SHIFT_PROBE_QUANTILES`, the worst of them),
    seen by every head."""
    tau = np.sort(np.asarray(ctx.rows["tau"], float))
    if not tau.size:
        return []
    times = [float(tau[int(q * (tau.size - 1))]) for q in SHIFT_PROBE_QUANTILES]
    probes = [
        Probe(
            {"shift_time_s": np.asarray(ts), "shift_x_m": np.asarray(x), "shift_y_m": y},
            "shift_m",
            "m",
            at="a shift in the middle half of the samples (the worst of its ends and middle, "
            "in x or y; its time held)",
            label=f"at {ts:.6g} s in {'x' if x else 'y'}",
        )
        for ts in times
        for x, y in ((1.0, np.asarray(0.0)), (0.0, np.asarray(1.0)))
    ]
    return [dataclasses.replace(probes[0], worst_of=tuple(probes[1:]))]


BEAM_TILT_AXIAL = dataclasses.replace(_BT, probes=_bt_probes)
BEAM_TILT_AXIAL_NO_REF = dataclasses.replace(_BT_NO_REF, probes=_bt_probes)
register_factors(BEAM_TILT_AXIAL, bt_factors(False))  # issue 43: J = X W, never compiled
register_factors(BEAM_TILT_AXIAL_NO_REF, bt_factors(True))
BEARING_WOBBLE = dataclasses.replace(_WB, probes=_wb_probes)
ECCENTRICITY_SHIFT = dataclasses.replace(_ES, probes=_es_probes)

__all__ = [
    "BEAM_TILT_AXIAL",
    "BEAM_TILT_AXIAL_NO_REF",
    "BEARING_WOBBLE",
    "ECCENTRICITY_SHIFT",
    "wobble_probe_ratio",
]
