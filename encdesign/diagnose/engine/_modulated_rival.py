"""A located order of one channel that grows or switches as the rival of a catalog effect
of the run means (stage 4, :mod:`._select`; issue 41, session 26).

On an SDS record an order-5 pattern of one moving sensor that grows over the record or
switches on at one time moves that sensor's run means in steps from run to run, and the
catalog's ``sensor_delay_step`` (a step of one sensor's run-mean delay, order 0 from one
run on) takes a part of it: on the fresh seeds 20261415-17 four of the eleven SDS misses of
the discovery benchmark (a slow growth or a step at order 5 on one sensor, 5x the noise)
were named ``sensor_delay_step``, the structure never reaching discovery (and on training
seed 20261420 a step at order 5 on one sensor was named ``bearing_wobble``, a wobble of the
axis from one run on: the same pattern). The
``modulated_orders`` view locates that growth or switch on its channel; here it is fitted
as a term of its own (:func:`_modulated_term`) and the two compared by a likelihood ratio
at the finder's own ``alpha``: where the located form fits better than the catalog effect
(a larger chi-square gain beside the same base) and the catalog effect beside it no longer
gains what a term of its degrees of freedom needs (``chi2_threshold(alpha, dof, 1)``), the
catalog name is refused with that reason and the structure goes on to discovery. A true
catalog effect (a constant delay step from one run on) is not an order of the platform
angle: the located form takes a part of it at most, and the effect keeps its name."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from ._candidates import Candidate, Param
from ._fit import make_term
from ._spill import TRIAL_STEPS
from ._stats_pass import drive_many
from ._views import chi2_threshold

RIVAL_OF = ("run_step",)
"""Signature views of the catalog effects this rival is asked of (those of the run means);
and of every effect that changes from one run on (a ``first_run`` parameter)."""

SHAPES = ("growth", "decay", "switch_on", "switch_off")
"""The ``modulated_orders`` view's amplitude shapes (:mod:`._views_modulated`)."""


@functools.lru_cache(maxsize=32)
def _modulated_term(shape: str, n_channels: int, theta: str) -> Candidate:
    """A line at shaft order ``order`` on channel ``channel`` alone (rad, ``cos_rad`` /
    ``sin_rad`` of ``order theta``), times the amplitude shape the ``modulated_orders`` view
    located: ``growth`` linear from 0 at the global time ``t0_s`` (s) to 1 at ``t1_s``,
    ``decay`` 1 minus that, ``switch_on`` 0 before ``t0_s`` and 1 from it, ``switch_off`` the
    reverse. The order, channel and times are held parameters: one compiled function per
    shape serves every located form."""

    def fn(p, x):
        tau = x["tau"]
        if shape in ("growth", "decay"):
            g = jnp.clip((tau - p["t0_s"]) / (p["t1_s"] - p["t0_s"]), 0.0, 1.0)
            g = g if shape == "growth" else 1.0 - g
        else:
            on = jnp.where(tau >= p["t0_s"], 1.0, 0.0)
            g = on if shape == "switch_on" else 1.0 - on
        arg = p["order"] * x[theta]
        v = g * (jnp.cos(arg) * p["cos_rad"] + jnp.sin(arg) * p["sin_rad"])
        mask = (jnp.arange(n_channels) == p["channel"]).astype(float)
        return v[:, None] * mask[None, :]

    def held(name: str, unit: str, what: str) -> Param:
        return Param(name, unit, linear=False, fit=False, description=what)

    return Candidate(
        f"the located order {shape.replace('_', ' ')} of one channel",
        fn,
        (
            Param("cos_rad", "rad"),
            Param("sin_rad", "rad"),
            held("order", "1", "the shaft order"),
            held("channel", "1", "the channel"),
            held("t0_s", "s", "global time of the change (growth: its start)"),
            held("t1_s", "s", "global time of the growth's end"),
        ),
        explanation="an order of one channel that grows or switches over the record (the "
        "alternative a catalog effect of the run means must beat where the modulated_orders "
        "view located one)",
    )


def _rivals(prep, findings) -> list[tuple[int, int, str, float, float]]:
    """``(order, channel, shape, t0, t1)`` of each growth or switch the ``modulated_orders``
    view located on one channel (``findings``)."""
    tau = np.asarray(prep.rows["tau"], float)[np.asarray(prep.keep, bool)]
    if not tau.size:
        return []
    lo, hi = float(tau.min()), float(tau.max())
    if not hi > lo:  # no span of time for a growth
        return []
    out = []
    for f in findings:
        d = f.detail or {}
        if f.view != "modulated_orders" or d.get("modulation") not in SHAPES:
            continue
        orders, heads = f.where.get("orders") or [], f.where.get("heads") or []
        if len(orders) != 1 or float(orders[0]) != round(float(orders[0])):
            continue
        shape = d["modulation"]
        t0 = float(d["global_step_time_s"]) if shape.startswith("switch") else lo
        for h in heads:
            out.append((round(float(orders[0])), int(h), shape, t0, hi))
    return out


def _dof(term) -> int:
    """The term's fitted values (its degrees of freedom)."""
    return int(sum(np.sum(v) for v in term.free.values()))


def modulated_rival_rule(prep, fitter, cand: Candidate, findings, base: list, term):
    """Rule ``located_share_min`` of a catalog effect of the run means (``RIVAL_OF`` in its
    signature) or one that changes from one run on (a ``first_run`` parameter:
    ``bearing_wobble``, ``sensor_delay_step``), not a discovered or exported one, against
    each growth or switch of an order on one channel the ``modulated_orders`` view located
    (``findings``): ``(rule, reason)`` where that located form, fitted beside ``base`` as a
    term of its own, gains more chi-square than the fitted ``term`` and ``term`` beside it
    gains less than ``chi2_threshold(alpha, dof, 1)`` (the finder's own ``alpha``, ``dof``
    its fitted values), else ``None``."""
    changes = set(cand.signature) & set(RIVAL_OF) or any(q.first_run for q in cand.params)
    if not changes or cand.name.startswith("discovered_"):
        return None
    rows = prep.rows
    theta = "theta_eff" if "theta_eff" in rows else "theta"
    if theta not in rows or "tau" not in rows:
        return None
    located = _rivals(prep, findings)
    if not located:
        return None
    need = chi2_threshold(prep.settings.alpha, _dof(term), 1)
    C = int(prep.n_channels)
    located = [r for r in located if r[1] < C]
    if not located:
        return None
    # every fit side by side, in one pass over the rows per round (issue 43): the base and
    # the base with the candidate once, each located form beside the base without and with it
    fits = [list(base), [*base, term]]
    for order, ch, shape, t0, t1 in located:
        at = {"order": order, "channel": ch, "t0_s": t0, "t1_s": t1}
        rival = make_term(_modulated_term(shape, C, theta), prep, at)
        fits += [[*base, rival], [*base, rival, term]]
    done = drive_many([fitter.fit_steps(f, max_steps=TRIAL_STEPS) for f in fits])
    f0, f1 = done[:2]
    a = f0.chi2 - f1.chi2
    for i, (order, ch, shape, _, _) in enumerate(located):
        fo, f2 = done[2 + 2 * i : 4 + 2 * i]
        b, beside = f0.chi2 - fo.chi2, fo.chi2 - f2.chi2
        if b > a and beside < need:
            return (
                "located_share_min",
                f"the order-{order} {shape.replace('_', ' ')} located on channel {ch} fits "
                f"better: chi2 {b:.1f} vs {a:.1f} for this effect, which beside it gains "
                f"{beside:.1f} (needs {need:.1f} at alpha {prep.settings.alpha:g})",
            )
    return None
