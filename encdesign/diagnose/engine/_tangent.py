"""A term's nonlinear parameters as linear tangents at their fitted values (issue 44 C).

A profile over a located time refits the other terms' linear parameters at each time
(:meth:`._fit.Fitter.column_chi2`, a linear least-squares update). Their nonlinear
parameters held at the values fitted with the change at its fitted time favour that time:
on part of a turn a run's angle zero (``run_angle_offset_rad`` of the multihead base) takes
part of a step at the run's start, and held there it puts the profile's best some rows into
the run (training ``tests/test_order_step_part_turn.shift_record(7623)``: a shift in the
pause between runs, its interval a few rows inside the later run). The tangent term adds
``sum_q J_q d_q``, ``J_q`` the Jacobian of the term at its fitted values over a nonlinear
parameter ``q`` and ``d_q`` free linear scalars: with it the profile's refit is one
Gauss-Newton step of the whole model at each time (exact to first order in the moves).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ._candidates import Candidate, Param
from ._fit import Term, make_term

PREFIX = "tangent_"


@functools.lru_cache(maxsize=64)
def _tangent(cand: Candidate, names: tuple[str, ...]) -> Candidate:
    """``cand``'s tangent in the parameters ``names``: every parameter of ``cand`` held (its
    point), and per name a linear parameter ``tangent_<name>`` of the same shape."""
    own = {q.name: q for q in cand.params}

    def split(p: dict) -> tuple[dict, dict]:
        prim = {q.name: p[q.name] for q in cand.params}
        d = {n: p[PREFIX + n] for n in names}
        return prim, d

    def fn(p: dict, x: dict):
        prim, d = split(p)
        tang = {k: (d[k] if k in d else jnp.zeros_like(v)) for k, v in prim.items()}
        return jax.jvp(lambda q: cand.fn(q, x), (prim,), (tang,))[1]

    valjac = None
    if cand.valjac is not None:
        hand = cand.valjac

        def valjac(p: dict, x: dict):
            prim, d = split(p)
            _, J = hand(prim, x)
            v = sum(jnp.tensordot(J[n], d[n], axes=jnp.ndim(d[n])) for n in names)
            return v, {PREFIX + n: J[n] for n in names}

    held = tuple(
        Param(q.name, q.unit, q.shape, linear=False, fit=False, scale=q.scale) for q in cand.params
    )
    moves = tuple(
        Param(PREFIX + n, own[n].unit, own[n].shape, scale=own[n].scale, description=f"move of {n}")
        for n in names
    )
    return Candidate(
        name=f"{cand.name}.tangent",
        fn=fn,
        params=(*held, *moves),
        explanation=f"{cand.name}'s nonlinear parameters moved to first order (a profile)",
        valjac=valjac,
    )


def tangent_names(term: Term) -> tuple[str, ...]:
    """The nonlinear parameters of ``term`` that are fitted (some scalar free), not a located
    time nor a first run (a step's time has no useful tangent)."""
    return tuple(
        q.name
        for q in term.cand.params
        if not q.linear
        and q.fit
        and not q.global_time
        and not q.first_run
        and bool(np.any(term.free[q.name]))
    )


def tangent_terms(prep, terms: list[Term]) -> list[Term]:
    """Per term of ``terms`` with fitted nonlinear parameters (:func:`tangent_names`), its
    tangent term at its values, the moves free where the parameter is (zero: the tangent
    adds nothing to the prediction, only columns)."""
    out = []
    for t in terms:
        names = tangent_names(t)
        if not names:
            continue
        tm = make_term(_tangent(t.cand, names), prep, dict(t.values))
        for n in names:
            tm.free[PREFIX + n] = np.asarray(t.free[n], bool).copy()
            tm.values[PREFIX + n][...] = 0.0
        out.append(tm)
    return out
