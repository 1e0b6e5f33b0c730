"""A candidate's screened starts side by side (issue 43).

A trial fit screens each of a candidate's starts (:attr:`._candidates.Candidate.start`)
with its nonlinear parameters held: a linear fit on top of the frozen base model, one pass
over the rows (and one from the kept normal equations) each. One after another, a
candidate with four starts took four rounds of the selection's passes. :func:`side_by_side`
runs the screening fits of all of them at once: every round it hands
:func:`._stats_pass.drive_many` the next request of each (a :class:`._stats_pass.Many`),
answered in the round's one pass beside the other candidates' requests. Each fit makes the
same requests and gets the same answers as alone (a request that would find Gram matrices
an earlier request of the round keeps waits a round, as there), so the screened
chi-squares, and the start each candidate's full fit begins from, are the same to the bit.
"""

from __future__ import annotations

from collections.abc import Generator, Sequence

from ._stats_pass import FitSteps, Many, StatsRequest


def side_by_side(all_steps: Sequence[FitSteps]) -> Generator[Many, list, list]:
    """Several fits (generators of single statistics requests) as one generator that
    yields all their pending requests at once (:class:`._stats_pass.Many`) and is sent the
    answers in order (``None``: that request waits a round); it returns the fits' results,
    in order."""
    out: list = [None] * len(all_steps)
    reqs: dict[int, StatsRequest] = {}
    for i, steps in enumerate(all_steps):
        try:
            reqs[i] = next(steps)
        except StopIteration as stop:
            out[i] = stop.value
    while reqs:
        keys = list(reqs)
        answers = yield Many(reqs[i] for i in keys)
        for i, ans in zip(keys, answers):
            if ans is None:
                continue  # (asked again next round)
            try:
                reqs[i] = all_steps[i].send(ans)
            except StopIteration as stop:
                out[i] = stop.value
                del reqs[i]
    return out


def screened_starts(fitter, base: list, held: Sequence) -> Generator[Many, list, list]:
    """The fits of the frozen ``base`` terms with each of ``held`` (a candidate's terms at
    its starts, nonlinear parameters held) side by side: their :class:`._fit.FitResult` s,
    in order."""
    return side_by_side([fitter.fit_steps([*base, h]) for h in held])


__all__ = ["screened_starts", "side_by_side"]
