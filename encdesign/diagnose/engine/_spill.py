"""Whether a candidate's gain is its own or a part of a larger located structure it leaves
(stage 4, :mod:`._select`): its gain once that structure is fitted with the model."""

from __future__ import annotations

import jax.numpy as jnp

from ._candidates import Candidate, Param
from ._fit import make_term
from ._fit_memo import remembered_steps
from ._stats_pass import drive_many
from ._views import chi2_threshold

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
    lines = make_term(_lines(sorted(orders), prep.n_channels, theta), prep)
    return _kept(fitter, base, term, lines)


def _kept(fitter, base: list, term, other) -> float | None:
    """The share of its chi-square gain beside ``base`` that ``term`` keeps once ``other``
    (a term) is fitted with them; ``None`` without a gain."""
    return _kept_fit(fitter, base, term, other)[0]


def _kept_fit(
    fitter, base: list, term, other, alpha: float | None = None
) -> tuple[float | None, dict | None]:
    """:func:`_kept`, and the values ``other`` takes fitted beside ``base`` alone (where it
    takes what it shares with ``term``); ``(None, None)`` without a gain.

    With ``alpha``, ``(1.0, values)`` where ``term`` holds ``other``'s structure and more
    (:func:`_nested`): ``other`` keeps nothing beside it."""
    fits = [list(base), [*base, term], [*base, other], [*base, other, term]]
    # the four fits side by side (issue 43): one pass over the rows per round for all, the
    # model's Jacobian at its start made once per chunk; each gets the numbers it gets alone
    # (a fit the selection made before, or makes again, is made once: _fit_memo)
    f0, f1, fo, f2 = drive_many([remembered_steps(fitter, f, TRIAL_STEPS) for f in fits])
    g0 = f0.chi2 - f1.chi2
    if g0 <= 0:
        return None, None
    g1 = fo.chi2 - f2.chi2
    if alpha is not None and _nested(f1, fo, f2, alpha):
        return 1.0, dict(fo.terms[-1].values)
    return g1 / g0, dict(fo.terms[-1].values)


def _nested(f1, fo, f2, alpha: float) -> bool:
    """Whether the candidate's fit ``f1`` (the model with it) holds all the structure of the
    rival's ``fo`` (the model with the rival) and more: beside the candidate the rival lowers
    chi-square by less than ``chi2_threshold(alpha, k_r, 1)`` (``k_r`` its parameters: no
    structure of its own), while beside the rival the candidate lowers it by more than
    ``chi2_threshold(alpha, k_c, 1)`` (a significant structure the rival leaves). Then the
    rival's located structure is a part of the candidate's, not the reverse: the candidate's
    smaller share beside it says only that the base left most of the candidate's pattern
    where the rival sits (a smooth pattern of the platform angle on golden-angle positions,
    which the base's orders take elsewhere, can leave its residual in one run)."""
    k_r = f2.n_params - f1.n_params
    k_c = f2.n_params - fo.n_params
    if k_r <= 0 or k_c <= 0:
        return False
    rival_own = f1.chi2 - f2.chi2
    cand_own = fo.chi2 - f2.chi2
    return bool(
        rival_own < chi2_threshold(alpha, k_r, 1) and cand_own > chi2_threshold(alpha, k_c, 1)
    )


def rival_rule(prep, fitter, cand: Candidate, base: list, term) -> tuple[str, str] | None:
    """Rule ``located_share_min`` against the candidate's rivals (``Candidate.rivals``:
    located structure of the record that no catalog effect makes, as terms of their own):
    ``(rule, reason)`` where the fitted candidate ``term`` keeps less than
    ``located_share_min`` of its gain beside ``base`` once a rival is fitted with it, else
    ``None``.

    A smooth effect with many parameters fitted to a one-run transient on one SDS sensor
    (its coil orders in ``phi + psi_m`` reach every single value) takes most of it and
    lowers the criterion far more than any other candidate, so the transient's doubt was
    overruled and the effect named (issue 44, session 21); the transient's own offset takes
    that gain back. An effect of its own beside a transient keeps its gain.

    A rival with a ``plausible`` hook that refuses the values it takes beside ``base`` (where
    it takes what it shares with the candidate) cannot make that structure and refuses
    nothing: the quantization staircase with a fundamental beyond what its LSB makes is not
    the staircase (issue 44, session 22).

    A rival that keeps no significant gain beside the candidate, which keeps a significant
    one beside the rival (:func:`_nested`), refuses nothing: its structure is a part of the
    candidate's. A 40x ``beam_tilt_axial`` (orders 1 and 3 of the platform angle, 12
    golden-angle positions) left by the base mostly in one run on every moving sensor kept
    17 % of its gain beside that run's offsets, but closed the fit (chi-square 98 of 180
    values) where the offsets left 2057, and they lowered it by 0.9 beside it: the record
    read ``coil_mismatch`` (training seed 6804, record 11; issue 41, session 41)."""
    if cand.rivals is None:
        return None
    share = prep.settings.located_share_min
    for rival in cand.rivals(prep.ctx):
        kept, values = _kept_fit(
            fitter, base, term, make_term(rival, prep), alpha=prep.settings.alpha
        )
        if rival.plausible is not None and values is not None:
            if rival.plausible(prep.ctx, values) is not None:
                continue
        if kept is not None and kept < share:
            return (
                "located_share_min",
                f"keeps only {100 * max(kept, 0.0):.0f}% of its gain when fitted together "
                f"with {rival.name} ({rival.explanation}): a part of that structure (needs "
                f"{100 * share:.0f}%)",
            )
    return None


def same_place(f, g) -> bool:
    """Whether findings ``f`` and ``g`` share a head and a run (or one of them names none)."""
    for key in ("heads", "runs"):
        a, b = f.where.get(key) or [], g.where.get(key) or []
        if a and b and not set(a) & set(b):
            return False
    return True


def band_share(findings, after, own) -> tuple[float, float] | None:
    """``(share, power)``: the share of the excess chi-square of the broad bands located
    before a candidate's fit (``findings``, view ``band``) that contain a line of its own
    fitted error (``own``: a ``spectrum`` finding of that error alone, on the band's head and
    run) which is gone after its fit (``after``), and those bands' excess before it; ``None``
    where no such band was located.

    A line fixed in Hz fitted to a slice of a broadband structure (a chirp sweeping through
    its frequency) clears that slice's spectrum lines but leaves the band it sits in nearly
    whole; a line of its own is most of the band it sits in, and its fit clears it. The
    selection asks it of lines fixed in Hz only (no ``orders`` in the signature): a set of
    shaft orders among a motor's many lines (ODrive's cogging at order 84) is judged by the
    orders it leaves, not by the band of other lines it sits in."""
    lines = [
        (g, x) for g in own if g.view == "spectrum" for x in g.where.get("frequencies_hz") or []
    ]
    a = b = 0.0
    for f in findings:
        lo_hi = f.where.get("frequencies_hz") or []
        if f.view != "band" or not lo_hi:
            continue
        if not any(lo_hi[0] <= x <= lo_hi[-1] and same_place(f, g) for g, x in lines):
            continue
        a += max(f.power - f.dof, 0.0)
        for h in after:
            if h.view == "band" and h.where.get("frequencies_hz") == lo_hi and same_place(h, f):
                b += max(h.power - h.dof, 0.0)
    if a <= 0:
        return None
    return max(1.0 - b / a, 0.0), a


def edge_beyond(orders, own, findings, left, key) -> tuple[int, list[int], float] | None:
    """``(top, beyond, power)`` where a candidate that is a set of lines at integer
    ``orders`` has its own fitted error (``own``) mostly at its top order ``top`` (more
    excess chi-square there than at all its other orders together), and the integer orders
    above ``top`` located before its fit that it leaves (``left``) carry ``power``; else
    ``None``. ``key(finding)``: a finding's integer order, or ``None``.

    A comb that continues beyond a catalog effect's orders (an out-of-catalog radial order
    with its sidebands) lends it the one tooth inside its range: its fit is then that tooth,
    its top order, while the larger rest of the comb stays above it."""
    if not orders:
        return None
    top = max(orders)
    own_p: dict = {}
    for g in own:
        k = key(g)
        if k is not None and k in orders:
            own_p[k] = own_p.get(k, 0.0) + max(g.power - g.dof, 0.0)
    at_top = own_p.get(top, 0.0)
    if at_top <= sum(own_p.values()) - at_top:
        return None
    beyond: dict = {}
    for f in findings:
        k = key(f)
        if k is not None and k > top and k in left:
            beyond[k] = beyond.get(k, 0.0) + max(f.power - f.dof, 0.0)
    return top, sorted(beyond), float(sum(beyond.values()))
