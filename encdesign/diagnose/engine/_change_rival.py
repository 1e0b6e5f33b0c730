"""A located change of an order at one time as the rival of a stationary candidate (stage 4,
:mod:`._select`): a term that does not change in time must keep its gain once the located
change is fitted as a term of its own (issue 44, session 21)."""

from __future__ import annotations

import functools

import jax.numpy as jnp
import numpy as np

from ._candidates import Candidate, Param
from ._fit import make_term
from ._spill import _kept, rival_rule

ORDER_STEP_ORDER = 1
"""The shaft order whose change the ``order_step`` view locates (a disk moved on its hub)."""

CHANGE_VIEWS = ("time", "order_step", "run_step", "drift")
"""Signature views of a candidate that changes in time (it is not a stationary one)."""


@functools.lru_cache(maxsize=32)
def _order_change(order: int, theta: str) -> Candidate:
    """A line at shaft ``order`` switched on from the global time ``tau_s`` (s, runs end to
    end), one size and phase (``cos_rad``, ``sin_rad``, rad) every channel sees at its own
    angle ``order (theta - alpha_k)`` (a multihead record's head angles ``alpha``; one
    channel at its shaft angle elsewhere): the change the ``order_step`` view scans, a
    displacement of the disk on its hub, as a term of its own, not a catalog effect."""

    def fn(p, x):
        on = jnp.where(x["tau"] >= p["tau_s"], 1.0, 0.0)[:, None]
        alpha = x["alpha"][None, :] if "alpha" in x else 0.0
        arg = order * (x[theta][:, None] - alpha)
        return on * (jnp.cos(arg) * p["cos_rad"] + jnp.sin(arg) * p["sin_rad"])

    return Candidate(
        f"the order-{order} change located at one time",
        fn,
        (
            Param("cos_rad", "rad"),
            Param("sin_rad", "rad"),
            Param("tau_s", "s", linear=False, fit=False, description="global time of the change"),
        ),
        explanation="a change of a shaft order at one instant (the alternative a stationary "
        "term must beat where the order_step view located one)",
    )


def _at(t_s, tau: float) -> str:
    if t_s is not None:
        return f"located at t = {float(t_s):.6g} s"
    return f"the model holds at global time {tau:.6g} s"


def change_rival_rule(prep, fitter, cand: Candidate, findings, base: list, term):
    """Rule ``located_share_min`` of a stationary candidate (no view of a change in time in
    its signature, :data:`CHANGE_VIEWS`) against each change of an order at one time the
    ``order_step`` view located (``findings``) and each the model holds (a term of that
    view's signature at its fitted global time): ``(rule, reason)`` where the fitted
    ``term`` keeps less than ``located_share_min`` of its gain beside ``base`` once that
    change is fitted with it (:func:`_order_change`: one size and phase, from that time
    on), else ``None``. Free per channel the change took a real beam tilt's gain on part
    of a turn (generated control 7596); one displacement cannot.

    On part of a turn the base spans one quadrature of an eccentricity shift's order-1 step
    and a beam tilt's static orders 1-3 per head fit what it leaves better than the shift
    itself (``short_arcs.py --set effects --seed 6215`` record 1): a static term cannot make
    a change in time, so fitted beside the change it keeps little. A stationary effect of its
    own keeps its gain beside it."""
    if set(cand.signature) & set(CHANGE_VIEWS):
        return None
    rows = prep.rows
    theta = "theta_eff" if "theta_eff" in rows else "theta"
    if theta not in rows or "tau" not in rows:
        return None
    share = prep.settings.located_share_min
    changes = [
        (int(f.detail["order"]), float(f.detail["global_step_time_s"]), f.detail["step_time_s"])
        for f in findings
        if f.view == "order_step" and {"global_step_time_s", "order"} <= set(f.detail)
    ]
    # and the changes the model holds: a term fitted to the order_step view's change (its
    # signature), at its fitted global time; what it leaves a stationary term may fit
    for t in base:
        if "order_step" in t.cand.signature:
            for q in t.cand.params:
                if q.global_time:
                    tau = float(np.asarray(t.values[q.name]).reshape(-1)[0])
                    changes.append((ORDER_STEP_ORDER, tau, None))
    for order, tau, t_s in changes:
        rival = make_term(_order_change(order, theta), prep, {"tau_s": np.asarray(tau)})
        kept = _kept(fitter, base, term, rival)
        if kept is not None and kept < share:
            return (
                "located_share_min",
                f"keeps only {100 * max(kept, 0.0):.0f}% of its gain once the order-{order} "
                f"change {_at(t_s, tau)} is fitted with it as a term of its own: a term that "
                f"does not change in time cannot make that change "
                f"(needs {100 * share:.0f}%)",
            )
    return None


def rivals_rule(prep, fitter, cand: Candidate, findings, base: list, term):
    """:func:`._spill.rival_rule` (the candidate's own rivals), then
    :func:`change_rival_rule`: the first ``(rule, reason)`` that refuses ``term``, else
    ``None``."""
    return rival_rule(prep, fitter, cand, base, term) or change_rival_rule(
        prep, fitter, cand, findings, base, term
    )
