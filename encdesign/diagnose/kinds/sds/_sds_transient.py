"""SDS: one-run transients in the base run means (split from :mod:`._sds_noise`, session 37).

A moving sensor's run mean that deviates in one run only (a bracket shifted and restored: the
benchmark's out-of-catalog ``run_step``) is no catalog effect; a smooth candidate fitted to
such a record would take a part of it. :func:`transient_cells` finds them, :func:`_transient`
is the smooth candidates' doubt, and ``_sds_terms._transient_rivals`` their test.
"""

from __future__ import annotations

import numpy as np

from ...engine._candidates import Context
from ...engine._views import chi2_threshold as _thr
from ._sds_noise import noise_info


def transient_cells(ctx: Context) -> list[tuple[int, int, float, float]]:
    """``(sensor, run index, chi-square, the sensor's chi-square)`` of each moving sensor
    whose base run means a one-run transient dominates, the largest first: its largest
    single-run deviation is significant (1 dof, Bonferroni over sensors × runs), fits better
    than any step and holds over ``sds_transient_share`` of the sensor's power."""
    ch = noise_info(ctx).run_change_power
    if not ch:
        return []
    R = int(ctx.n_runs)
    thr = _thr(ctx.settings.alpha, 1, 2 * len(ch) * max(R - 1, 1))
    out = [
        (m, int(jo), float(po), float(tot))
        for m, (ps, _, po, jo, tot) in enumerate(ch)
        if po > thr and po > ps and po > ctx.settings.sds_transient_share * tot
    ]
    return sorted(out, key=lambda c: -c[2])


def _shared(ctx: Context, m: int, j: int) -> bool:
    """Whether the deviation of run ``j`` on moving sensor ``m`` (its base run means less
    their mean, rad) is common to the moving sensors: another one carries, with the same
    sign, over ``sds_delay_shared_max`` of it in that run (as a delay step shared by the
    sensors is not one sensor's delay)."""
    base = noise_info(ctx).base_resid
    M = int(np.asarray(ctx.consts["psi_m"]).size)
    if base is None or M < 2 or not 0 <= j < base.shape[0]:
        return False
    dev = base[:, :M] - base[:, :M].mean(0, keepdims=True)
    own = float(dev[j, m])
    other = np.delete(dev[j], m) * np.sign(own)
    return bool(np.any(other > ctx.settings.sds_delay_shared_max * abs(own)))


def _transient(ctx: Context) -> str | None:
    """A one-run transient on one sensor dominates the base residual
    (:func:`transient_cells`). A smooth effect fitted to such a record would take a part of
    the transient; it is not named (a doubt; the candidate must also keep its gain beside
    the transients' own offsets: ``Candidate.rivals``, a test). A run's deviation that the
    moving sensors share (:func:`_shared`) is not one sensor's transient but a pattern of
    the platform angle, which the base residual of a smooth common structure (orders of
    phi on golden-angle positions: beam tilt x axial runout) can concentrate on one run:
    no doubt then, the rivals' test alone decides (training seed 6708 record 11: a 40x
    ``beam_tilt_axial``, whose run means follow orders 1 and 3 to 3 nrad of 530, refused
    for "run index 10" on all three moving sensors)."""
    cells = [c for c in transient_cells(ctx) if not _shared(ctx, c[0], c[1])]
    if not cells:
        return None
    m, jo, po, tot = cells[0]
    return (
        f"the base residual is dominated by one run's deviation on m{m} (run index "
        f"{jo}, chi-square {po:.0f} of the sensor's {tot:.0f}): a transient no "
        "catalog effect makes, reported as unexplained"
    )


def _no_transient(fn=None):
    def plausible(ctx: Context, params: dict) -> str | None:
        return _transient(ctx) or (fn(ctx, params) if fn is not None else None)

    plausible.__doc__ = (fn.__doc__ or "") + " Refused, too, when :func:`_transient` says so."
    return plausible
