"""The ``time`` view's best single step over a run's block means (issue 44 C, session 25).

The view (:func:`._views.view_time`) tests each run and channel's block means (each
``~N(0, 1)`` in white noise) for any structure: their chi-square less the run constant,
``nb - 1`` dof. A step spreads over those dof: a one-head step of 60-120 whitened
chi-square on a run of 32 blocks sits near that test's threshold (about 65 at 31 dof),
though as one step (1 dof) it is far beyond chance (training ``change_points.py --seed
7923`` ``mh_bench_jump`` record 7: block chi-square 58 against 64.6, its best step 48).
Beside the block test the view therefore tests the best single step over the block edges,
Bonferroni over its edges, runs and channels, at ``FinderSettings.time_step_alpha``; the
two tests together have a family-wise false-alarm rate of at most ``alpha +
time_step_alpha``. On block means, not rows: structure within a block (a line, a
vibration) averages out there, as in the block test.

A finding is a step (``shape``, and so a ``located_time``) where its best step takes
``step_shape_share`` of the block means' power, or where what the step leaves of it is
within chance (``nb - 2`` dof at ``alpha``, Bonferroni over the view's runs and channels).
The share alone compares the step with a power that holds ``nb - 2`` dof of noise (about
30 on 32 blocks): a step of 40-80 chi-square was read ``transient_or_drift`` and had no
located time; a transient or a drift leaves beyond chance what one step does not take.

The best step is the edge of largest chi-square, ``S_j^2 nb / (j (nb - j))`` with ``S_j``
the sum of the first ``j`` centred means; the largest ``|S_j|`` (the CUSUM's size, used
before) favours a run's middle, and a step a few blocks before a run's end was read at
the middle, as a transient.
"""

from __future__ import annotations

import numpy as np


def best_step(m: np.ndarray) -> tuple[int, float]:
    """``(jb, chi2)``: the block edge (``1 .. nb - 1``: the first block after the step) of
    the best single step over the block means ``m`` (nb,), and the chi-square (1 dof) it
    takes out of them, the run constant refitted."""
    nb = m.size
    cs, j = np.cumsum(m - m.mean())[:-1], np.arange(1, nb)
    stat = cs**2 * nb / (j * (nb - j))
    i = int(np.argmax(stat))
    return i + 1, float(stat[i])


def cusum_edge(m: np.ndarray) -> tuple[int, float]:
    """``(jb, chi2)`` as :func:`best_step`, at the edge of the CUSUM's largest size instead:
    where the best step is no step (a smooth structure, whose best-step edge sits at a
    run's first or last block and would rival what an order explains; the shared ODrive
    record ``odrive_comp`` lost ``coil_mismatch`` to such a step, s25-edge25), the edge
    the ``time`` view used before session 25, which favours a run's middle."""
    nb = m.size
    cs, j = np.cumsum(m - m.mean())[:-1], np.arange(1, nb)
    i = int(np.argmax(np.abs(cs)))  # (nb 2: the one edge)
    return i + 1, float(cs[i] ** 2 * nb / (j[i] * (nb - j[i])))


def order_change_fits_better(order_chi2: float, head_chi2: float, ratio: float) -> bool:
    """Whether a change of the disk's order 1 fits a record's change better than a step of
    one head's constant: its chi-square gain (likelihood ratio over the same base, same
    change points) exceeds ``ratio`` (``FinderSettings.order_step_head_ratio``) times the
    head step's. The one comparison of :mod:`...kinds.multihead._order_step_head` (the
    ``order_step`` view's located time) and of :func:`time_steps_beside_order_change`."""
    return order_chi2 > ratio * head_chi2


def time_steps_beside_order_change(found: list, settings) -> list:
    """The ``time`` view's steps kept out of structure an order change explains better
    (issue 44 C, sessions 25 and 26, symmetric to the ``order_step`` view's rule).

    On part of a turn an eccentricity shift (a change of the disk's order 1) does not
    average out of the block means; the base, fitted with one order 1 over the whole
    record, leaves in each run a smooth part of a turn of the order-1 change, and the
    ``time`` view reads it as one head's step at times that are not the change's (fresh
    6480 / 6481: ``mh_part_ref``, ``mh_ecc_shift``, ``mh_arcs_noref``; session 26, fresh
    records of session 25: the ``time`` view's located times on part-turn eccentricity
    shifts held the truth in 0 of 39, found by the block test and the share rule, at
    chi-square far beyond chance, in every run away from the change). Where the record's
    ``order_step`` finding fits better than the best step of one head's constant over
    every change point it scans (:func:`order_change_fits_better` on its
    ``detail.order_change_chi2`` and ``head_step_chi2``), no one-head step at any of those
    times fits as well as the order change, and a ``time`` step is a one-head step (a
    constant of one channel from a row of one run on; the base's per-run constants take
    what it leaves after the run). So:

    * a step found only by the best-step test or rule (``detail.by_best_step``) is read as
      the block test and the share rule alone read it: dropped where the block test did
      not find it (``detail.block_test``), else a ``transient_or_drift`` with no located
      time (session 25);
    * a step the block test and the share rule find stays a step (its shape and its test
      are what candidates and nuisances read, unchanged) but states no located time of its
      own: the located time of that change is the ``order_step`` finding's, which the
      record favours (``detail.order_change_explains``, session 26). A step of one head
      beside the order change is located again on the residual of the model that explains
      the order change, where no ``order_step`` finding fits better.

    Where no order change fits better (a count jump, one head's step) every step stands."""
    ratio = settings.order_step_head_ratio
    if not any(
        f.view == "order_step"
        and "order_change_chi2" in f.detail
        and order_change_fits_better(
            f.detail["order_change_chi2"], f.detail["head_step_chi2"], ratio
        )
        for f in found
    ):
        return found
    out = []
    for f in found:
        if f.view == "time" and f.detail.get("by_best_step"):
            if not f.detail.get("block_test"):
                continue
            f.detail["shape"] = "transient_or_drift"
            f.detail["by_best_step"] = False
            f.located_time = None
        elif f.view == "time" and f.located_time is not None:
            f.detail["order_change_explains"] = True
            f.located_time = None
        out.append(f)
    return out


def findings_listed(found: list, n: int) -> list:
    """The findings a document lists (``findings_before``, ``unexplained``): the first
    ``n`` (strongest first), and beyond them any ``order_step`` finding whose located time
    a listed ``time`` step defers to (``detail.order_change_explains``,
    :func:`time_steps_beside_order_change`). On part of a turn the base leaves the shift in
    every run at chi-square beyond the p-value's floor, and the first ``n`` can be all
    ``time`` findings (training ``change_points.py --seed 7951`` ``mh_arcs_noref`` 0): the
    change's located time must not leave the document with them."""
    listed = found[:n]
    if not any(f.view == "time" and f.detail.get("order_change_explains") for f in listed):
        return listed
    return listed + [f for f in found[n:] if f.view == "order_step" and f.located_time]
